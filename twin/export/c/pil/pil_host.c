/* The PIL main's machine on the development machine: stdio files named on the command line
   (pil IN OUT), no clock (every step's ticks are 0), no stack measure. */
#include <stdio.h>
#include <stdlib.h>
#include "mtwip.h"
#include "pil_port.h"

#define MAX_FILES 4
static FILE *files[MAX_FILES];
volatile uint32_t pil_loop_n;

int pil_open(const char *name, int for_writing) {
    int h;
    for (h = 0; h < MAX_FILES; h++) {
        if (files[h] == NULL) {
            files[h] = fopen(name, for_writing ? "wb" : "rb");
            return files[h] == NULL ? -1 : h;
        }
    }
    return -1;
}

int32_t pil_length(int handle) {
    long here = ftell(files[handle]), length;
    if (here < 0 || fseek(files[handle], 0, SEEK_END) != 0) return -1;
    length = ftell(files[handle]);
    if (fseek(files[handle], here, SEEK_SET) != 0 || length > 0x7FFFFFFFL) return -1;
    return (int32_t)length;
}

int pil_read(int handle, void *buffer, uint32_t n) { return fread(buffer, 1, n, files[handle]) == n; }

int pil_write(int handle, const void *buffer, uint32_t n) { return fwrite(buffer, 1, n, files[handle]) == n; }

void pil_close(int handle) {
    if (fclose(files[handle]) != 0) pil_fail("PIL: cannot write the outputs file", PIL_EXIT_IO);
    files[handle] = NULL;
}

void pil_fail(const char *message, int status) {
    fprintf(stderr, "%s\n", message);
    exit(status);
}

void pil_clock_start(void) {}
uint32_t pil_clock_hz(void) { return 0u; }
void pil_stack_paint(void) {}
uint32_t pil_stack_used(void) { return 0u; }

void pil_empty(mtwip_state_t *s, const mtwip_readings_t *r, const mtwip_targets_t *t, mtwip_outputs_t *o) {
    (void)s; (void)r; (void)t; (void)o;
}

void pil_loop(mtwip_state_t *s, const mtwip_readings_t *r, const mtwip_targets_t *t, mtwip_outputs_t *o) {
    (void)s; (void)r; (void)t; (void)o;
}
