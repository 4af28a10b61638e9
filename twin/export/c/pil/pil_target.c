/* The PIL main's machine on a Cortex-M4F under QEMU (netduinoplus2: STM32F405, 168 MHz):
   the vector table and the reset handler, ARM semihosting (files, messages, the exit status),
   SysTick as the clock, the stack painted to measure its use, the calibration calls. */
#include <stdint.h>
#include <string.h>
#include "mtwip.h"
#include "pil_port.h"

#define SYS_OPEN 0x01u
#define SYS_CLOSE 0x02u
#define SYS_WRITE0 0x04u
#define SYS_WRITE 0x05u
#define SYS_READ 0x06u
#define SYS_FLEN 0x0Cu
#define SYS_EXIT_EXTENDED 0x20u
#define ADP_STOPPED_APPLICATION_EXIT 0x20026u

#define SYST_CSR (*(volatile uint32_t *)0xE000E010u)
#define SYST_RVR (*(volatile uint32_t *)0xE000E014u)
#define SYST_CVR (*(volatile uint32_t *)0xE000E018u)
#define SCB_CPACR (*(volatile uint32_t *)0xE000ED88u)
#define STACK_PATTERN 0xC5A5C5A5u
#define CLOCK_HZ 168000000u  /* QEMU's netduinoplus2: SYSCLK, SysTick's processor clock */

extern uint32_t _sidata[], _sdata[], _edata[], _sbss[], _ebss[], _estack[];
int main(int argc, char **argv);

volatile uint32_t pil_loop_n;
uint32_t *pil_stack_mark;

static uint32_t semihost(uint32_t op, const void *arg) {
    register uint32_t r0 __asm__("r0") = op;
    register const void *r1 __asm__("r1") = arg;
    __asm__ volatile("bkpt 0xAB" : "+r"(r0) : "r"(r1) : "memory");
    return r0;
}

static void semihost_exit(int status) {
    uint32_t block[2];
    block[0] = ADP_STOPPED_APPLICATION_EXIT;
    block[1] = (uint32_t)status;
    semihost(SYS_EXIT_EXTENDED, block);
    for (;;) {
    }
}

int pil_open(const char *name, int for_writing) {
    uint32_t block[3];
    block[0] = (uint32_t)name;
    block[1] = for_writing ? 5u : 1u; /* "wb", "rb" */
    block[2] = (uint32_t)strlen(name);
    return (int)semihost(SYS_OPEN, block);
}

int32_t pil_length(int handle) {
    uint32_t block[1];
    block[0] = (uint32_t)handle;
    return (int32_t)semihost(SYS_FLEN, block);
}

int pil_read(int handle, void *buffer, uint32_t n) {
    uint32_t block[3];
    block[0] = (uint32_t)handle;
    block[1] = (uint32_t)buffer;
    block[2] = n;
    return semihost(SYS_READ, block) == 0u; /* the bytes not read */
}

int pil_write(int handle, const void *buffer, uint32_t n) {
    uint32_t block[3];
    block[0] = (uint32_t)handle;
    block[1] = (uint32_t)buffer;
    block[2] = n;
    return semihost(SYS_WRITE, block) == 0u; /* the bytes not written */
}

void pil_close(int handle) {
    uint32_t block[1];
    block[0] = (uint32_t)handle;
    semihost(SYS_CLOSE, block);
}

void pil_fail(const char *message, int status) {
    semihost(SYS_WRITE0, message);
    semihost(SYS_WRITE0, "\n");
    semihost_exit(status);
}

void pil_clock_start(void) {
    SYST_CSR = 0u;
    SYST_RVR = 0xFFFFFFu;
    SYST_CVR = 0u;
    SYST_CSR = 5u; /* enabled, the processor clock, no interrupt */
}

uint32_t pil_clock_hz(void) { return CLOCK_HZ; }

/* Leaf functions in assembly, so that they have no frame of their own and exact instruction
   counts:
   pil_stack_paint: fills [_ebss, sp) with the pattern and marks sp (the caller's frame bottom);
   pil_stack_used: the bytes between the mark and the lowest word no longer the pattern;
   pil_empty: one instruction; pil_loop: 2 * pil_loop_n + 3 instructions. */
__asm__(
    "  .syntax unified\n"
    "  .thumb\n"
    "  .text\n"
    "  .global pil_stack_paint\n"
    "  .type pil_stack_paint, %function\n"
    "  .thumb_func\n"
    "pil_stack_paint:\n"
    "  ldr r1, =_ebss\n"
    "  mov r2, sp\n"
    "  ldr r3, =0xC5A5C5A5\n"
    "1: cmp r1, r2\n"
    "  bhs 2f\n"
    "  str r3, [r1], #4\n"
    "  b 1b\n"
    "2: ldr r1, =pil_stack_mark\n"
    "  str r2, [r1]\n"
    "  bx lr\n"
    "  .size pil_stack_paint, .-pil_stack_paint\n"
    "  .global pil_stack_used\n"
    "  .type pil_stack_used, %function\n"
    "  .thumb_func\n"
    "pil_stack_used:\n"
    "  ldr r1, =_ebss\n"
    "  ldr r2, =pil_stack_mark\n"
    "  ldr r2, [r2]\n"
    "  ldr r3, =0xC5A5C5A5\n"
    "1: cmp r1, r2\n"
    "  bhs 2f\n"
    "  ldr r0, [r1]\n"
    "  cmp r0, r3\n"
    "  bne 2f\n"
    "  adds r1, r1, #4\n"
    "  b 1b\n"
    "2: subs r0, r2, r1\n"
    "  bx lr\n"
    "  .size pil_stack_used, .-pil_stack_used\n"
    "  .global pil_empty\n"
    "  .type pil_empty, %function\n"
    "  .thumb_func\n"
    "pil_empty:\n"
    "  bx lr\n"
    "  .size pil_empty, .-pil_empty\n"
    "  .global pil_loop\n"
    "  .type pil_loop, %function\n"
    "  .thumb_func\n"
    "pil_loop:\n"
    "  ldr r0, =pil_loop_n\n"
    "  ldr r0, [r0]\n"
    "1: subs r0, r0, #1\n"
    "  bne 1b\n"
    "  bx lr\n"
    "  .size pil_loop, .-pil_loop\n"
    "  .ltorg\n");

void pil_reset(void) {
    uint32_t *src = _sidata, *dst = _sdata;
    while (dst < _edata) *dst++ = *src++;
    for (dst = _sbss; dst < _ebss; dst++) *dst = 0u;
    SCB_CPACR |= 0xFu << 20; /* CP10, CP11: the FPU, full access */
    __asm__ volatile("dsb\n\tisb" ::: "memory");
    semihost_exit(main(0, 0));
}

void pil_fault(void) {
    pil_fail("PIL: the processor faulted (HardFault, MemManage, BusFault or UsageFault)", PIL_EXIT_FAULT);
}

__attribute__((section(".vectors"), used)) static void (*const vectors[16])(void) = {
    (void (*)(void))_estack, pil_reset, pil_fault, pil_fault, pil_fault, pil_fault, pil_fault,
    0, 0, 0, 0, pil_fault, pil_fault, 0, pil_fault, pil_fault,
};
