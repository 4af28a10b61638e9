/* What the processor-in-the-loop main needs of the machine it runs on: files, a clock, the stack.
   Two ports: pil_target.c (a Cortex-M4F under QEMU: ARM semihosting, SysTick) and pil_host.c
   (the development machine: stdio, no clock). The record formats are in twin/export/pil.py. */
#ifndef PIL_PORT_H
#define PIL_PORT_H

#include <stdint.h>
#include "mtwip.h"

#define PIL_IN_NAME "pil_in.bin"    /* the files the target opens (QEMU's working directory) */
#define PIL_OUT_NAME "pil_out.bin"

/* exit statuses (also the QEMU process's, through semihosting SYS_EXIT_EXTENDED) */
#define PIL_EXIT_OK 0
#define PIL_EXIT_INPUT 2   /* the readings file is missing or malformed */
#define PIL_EXIT_IO 4      /* a read or a write failed */
#define PIL_EXIT_FAULT 5   /* the processor faulted (target only) */

int pil_open(const char *name, int for_writing);   /* a handle >= 0, or -1 */
int32_t pil_length(int handle);                     /* bytes, or -1 */
int pil_read(int handle, void *buffer, uint32_t n);  /* 1: n bytes read */
int pil_write(int handle, const void *buffer, uint32_t n);  /* 1: n bytes written */
void pil_close(int handle);
void pil_fail(const char *message, int status);     /* one line to stderr, then exit(status) */

void pil_clock_start(void);
uint32_t pil_clock_hz(void);   /* the tick rate of PIL_TICKS (0: no clock) */
void pil_stack_paint(void);    /* fill the free stack below the caller's frame with a pattern */
uint32_t pil_stack_used(void); /* bytes below the painting caller's frame written since */

/* the measured calls: same signature as mtwip_step */
void pil_empty(mtwip_state_t *s, const mtwip_readings_t *r, const mtwip_targets_t *t, mtwip_outputs_t *o);
void pil_loop(mtwip_state_t *s, const mtwip_readings_t *r, const mtwip_targets_t *t, mtwip_outputs_t *o);
extern volatile uint32_t pil_loop_n;  /* pil_loop runs exactly 2 * pil_loop_n + 3 instructions */

#ifdef MTWIP_PIL_HOST
#define PIL_TICKS() 0u
#define PIL_ELAPSED(t0, t1) ((t1) - (t0))
#else
/* SysTick's current value: a 24-bit down-counter at the processor clock */
#define PIL_TICKS() (*(volatile uint32_t *)0xE000E018u)
#define PIL_ELAPSED(t0, t1) (((t0) - (t1)) & 0xFFFFFFu)
#endif

#endif
