/* The processor-in-the-loop main: reads a file of per-step readings and targets, calls
   mtwip_init once and mtwip_step once per record, writes every output and the SysTick ticks
   each mtwip_step took. The same file builds for the Cortex-M4F under QEMU (pil_target.c) and
   for the development machine (pil_host.c, -DMTWIP_PIL_HOST). The file formats are
   documented in twin/export/pil.py; every field is little-endian. */
#include <stdint.h>
#include <string.h>
#include "mtwip.h"
#include "pil_port.h"

#define IN_HEADER 40u
#define IN_RECORD 80u
#define OUT_HEADER 64u
#define OUT_TRAILER 24u
#define N_REAL 13u
#define OUT_RECORD (N_REAL * (uint32_t)sizeof(mtwip_real) + 8u)
#define N_LOOPS 4u

/* global, not static: the build reads their sizes off the object file (nm -S) */
mtwip_state_t pil_state;
mtwip_config_t pil_config;
mtwip_readings_t pil_readings;
mtwip_targets_t pil_targets;
mtwip_outputs_t pil_outputs;
mtwip_real pil_real;

static const uint32_t loop_counts[N_LOOPS] = {1u, 10u, 1000u, 100000u};

typedef void (*pil_step_fn)(mtwip_state_t *, const mtwip_readings_t *, const mtwip_targets_t *,
                            mtwip_outputs_t *);

/* the ticks of one call: the same code around every call, so that the call of pil_empty
   measures the overhead to take off */
static __attribute__((noinline)) uint32_t timed(pil_step_fn f) {
    uint32_t t0 = PIL_TICKS();
    f(&pil_state, &pil_readings, &pil_targets, &pil_outputs);
    uint32_t t1 = PIL_TICKS();
    return PIL_ELAPSED(t0, t1);
}

static void put_u32(uint8_t *p, uint32_t v) {
    p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); p[2] = (uint8_t)(v >> 16); p[3] = (uint8_t)(v >> 24);
}

static uint32_t get_u32(const uint8_t *p) {
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

static void put_f64(uint8_t *p, double x) {
    uint64_t u;
    memcpy(&u, &x, 8);
    put_u32(p, (uint32_t)u);
    put_u32(p + 4, (uint32_t)(u >> 32));
}

static double get_f64(const uint8_t *p) {
    uint64_t u = (uint64_t)get_u32(p) | (uint64_t)get_u32(p + 4) << 32;
    double x;
    memcpy(&x, &u, 8);
    return x;
}

static uint8_t *put_real(uint8_t *p, mtwip_real x) {
    if (sizeof(mtwip_real) == 4) {
        float f = (float)x;
        uint32_t u;
        memcpy(&u, &f, 4);
        put_u32(p, u);
    } else {
        put_f64(p, (double)x);
    }
    return p + sizeof(mtwip_real);
}

static void read_record(const uint8_t *p) {
    int i;
    for (i = 0; i < 3; i++) {
        pil_readings.gyro[i] = (mtwip_real)get_f64(p + 8 * i);
        pil_readings.accel[i] = (mtwip_real)get_f64(p + 24 + 8 * i);
    }
    pil_readings.encoder[0] = (int32_t)get_u32(p + 48);
    pil_readings.encoder[1] = (int32_t)get_u32(p + 52);
    pil_readings.gyro_valid = p[56];
    pil_readings.accel_valid = p[57];
    pil_readings.encoder_valid = p[58];
    pil_targets.has_position = p[59];
    pil_targets.has_heading = p[60];
    pil_targets.position = (mtwip_real)get_f64(p + 64);
    pil_targets.heading = (mtwip_real)get_f64(p + 72);
}

static void write_record(uint8_t *p, uint32_t ticks) {
    const mtwip_outputs_t *o = &pil_outputs;
    int i;
    p = put_real(p, o->duty[0]);
    p = put_real(p, o->duty[1]);
    p = put_real(p, o->torque[0]);
    p = put_real(p, o->torque[1]);
    p = put_real(p, o->u);
    p = put_real(p, o->theta_off);
    p = put_real(p, o->u_alpha);
    for (i = 0; i < 6; i++) p = put_real(p, o->estimate[i]);
    p[0] = o->saturated[0];
    p[1] = o->saturated[1];
    p[2] = 0;
    p[3] = 0;
    put_u32(p + 4, ticks);
}

static void write_or_fail(int out, const void *buffer, uint32_t n) {
    if (!pil_write(out, buffer, n)) pil_fail("PIL: cannot write the outputs file", PIL_EXIT_IO);
}

int main(int argc, char **argv) {
    static uint8_t in_buf[IN_RECORD];
    static uint8_t out_buf[OUT_HEADER + 8u * 13u + 8u];
    const char *in_name = argc > 2 ? argv[1] : PIL_IN_NAME;
    const char *out_name = argc > 2 ? argv[2] : PIL_OUT_NAME;
    uint32_t n, k, i, init_stack, step_stack;
    int32_t length;
    int in, out;

    in = pil_open(in_name, 0);
    if (in < 0) pil_fail("PIL: cannot open the readings file", PIL_EXIT_INPUT);
    length = pil_length(in);
    if (length < (int32_t)IN_HEADER || (uint32_t)(length - (int32_t)IN_HEADER) % IN_RECORD != 0u)
        pil_fail("PIL: the readings file is not a 40-byte header and 80-byte records", PIL_EXIT_INPUT);
    n = (uint32_t)(length - (int32_t)IN_HEADER) / IN_RECORD;
    if (!pil_read(in, in_buf, IN_HEADER)) pil_fail("PIL: cannot read the readings file", PIL_EXIT_IO);
    if (memcmp(in_buf, "MTWIPIN1", 8) != 0 || get_u32(in_buf + 12) != IN_RECORD)
        pil_fail("PIL: the readings file does not start with MTWIPIN1 and the record size 80", PIL_EXIT_INPUT);
    mtwip_default_config(&pil_config);
    if (get_u32(in_buf + 8) & 1u) {
        pil_config.gyro_scale = (mtwip_real)get_f64(in_buf + 16);
        pil_config.accel_scale = (mtwip_real)get_f64(in_buf + 24);
        pil_config.encoder_rad_per_count = (mtwip_real)get_f64(in_buf + 32);
    }

    out = pil_open(out_name, 1);
    if (out < 0) pil_fail("PIL: cannot create the outputs file", PIL_EXIT_IO);

    pil_clock_start();
    memset(out_buf, 0, sizeof out_buf);
    memcpy(out_buf, "MTWIPOU1", 8);
    put_u32(out_buf + 8, (uint32_t)sizeof(mtwip_real));
    put_u32(out_buf + 12, OUT_RECORD);
    put_u32(out_buf + 16, (uint32_t)sizeof(mtwip_state_t));
    put_u32(out_buf + 20, n);
    put_u32(out_buf + 24, pil_clock_hz());
    put_u32(out_buf + 28, timed(pil_empty));
    for (i = 0; i < N_LOOPS; i++) {
        pil_loop_n = loop_counts[i];
        put_u32(out_buf + 32 + 4 * i, timed(pil_loop));
    }
    put_f64(out_buf + 48, (double)(MTWIP_CONTROL_RATE_HZ));
    put_u32(out_buf + 56, (uint32_t)sizeof(mtwip_outputs_t));
    write_or_fail(out, out_buf, OUT_HEADER);

    pil_stack_paint();
    mtwip_init(&pil_state, &pil_config);
    init_stack = pil_stack_used();
    pil_stack_paint();
    for (k = 0; k < n; k++) {
        if (!pil_read(in, in_buf, IN_RECORD)) pil_fail("PIL: cannot read a record of the readings file", PIL_EXIT_IO);
        read_record(in_buf);
        memset(&pil_outputs, 0, sizeof pil_outputs);
        write_record(out_buf, timed(mtwip_step));
        write_or_fail(out, out_buf, OUT_RECORD);
    }
    step_stack = pil_stack_used();

    memset(out_buf, 0, OUT_TRAILER);
    memcpy(out_buf, "MTWIPEND", 8);
    put_u32(out_buf + 8, n);
    put_u32(out_buf + 12, init_stack);
    put_u32(out_buf + 16, step_stack);
    write_or_fail(out, out_buf, OUT_TRAILER);
    pil_close(out);
    pil_close(in);
    return PIL_EXIT_OK;
}
