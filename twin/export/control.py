"""The controllers and the motors' driver as C: ``mtwip_control.c`` and ``mtwip_motor.c``.

The arithmetic is the Python path's, operation for operation and in its order
(:class:`twin.controllers.cascade.FuzzyCascade`, :class:`twin.controllers.balance.PDCBalanceController`,
the fuzzy kernel ``twin/fuzzy/_kernel.c``, :class:`twin.controllers.lqr.LQRController`,
:class:`twin.actuators.dc_motor.MotorDriver`), so that a float64 export compiled without fused
multiply-adds (``-ffp-contract=off``) gives the twin's numbers bit for bit.
"""
from __future__ import annotations

import numpy as np

from twin.errors import TwinError
from twin.export.literals import array, literal

_CASCADE = """
%(flags)s

#if MTWIP_HAS_POSITION || MTWIP_HAS_DIRECTION
typedef struct {
    int k1, k2, reducer; /* sets per input; reducer 0 BMM (m, n), 1 Nie-Tan */
    mtwip_real m, n;
    const mtwip_real *lo1, *up1, *lo2, *up2, *y; /* sets (centre, 1/left, 1/right, height) and rule outputs */
    mtwip_real r1, r2, out; /* the inputs' and the output's ranges */
} fls_t;
#endif

%(data)s

#if MTWIP_HAS_POSITION || MTWIP_HAS_DIRECTION
#define MAX_SETS 16

static void memberships(const mtwip_real *p, int k, mtwip_real x, mtwip_real *out) {
    int i;
    for (i = 0; i < k; i++) {
        mtwip_real d = x - p[4 * i];
        mtwip_real v = MTWIP_R(1.0) + d * p[4 * i + 1];
        mtwip_real w = MTWIP_R(1.0) - d * p[4 * i + 2];
        if (w < v) v = w;
        out[i] = v > MTWIP_R(0.0) ? p[4 * i + 3] * v : MTWIP_R(0.0);
    }
}

/* the rules' min firing strengths: their sum and their sum weighted by the rules' outputs */
static void firing_sums(const fls_t *f, const mtwip_real *a, const mtwip_real *b, mtwip_real *s, mtwip_real *w) {
    mtwip_real ss = MTWIP_R(0.0), ww = MTWIP_R(0.0);
    int i, j;
    for (i = 0; i < f->k1; i++) {
        const mtwip_real *row = f->y + i * f->k2;
        if (a[i] <= MTWIP_R(0.0)) continue;
        for (j = 0; j < f->k2; j++) {
            mtwip_real v;
            if (b[j] <= MTWIP_R(0.0)) continue;
            v = a[i] < b[j] ? a[i] : b[j];
            ss += v;
            ww += v * row[j];
        }
    }
    *s = ss;
    *w = ww;
}

static mtwip_real fls(const fls_t *f, mtwip_real x1, mtwip_real x2) {
    mtwip_real a_lo[MAX_SETS], a_up[MAX_SETS], b_lo[MAX_SETS], b_up[MAX_SETS];
    mtwip_real s_up, w_up, s_lo, w_lo, y;
    mtwip_real a = x1 / f->r1, b = x2 / f->r2;
    a = a > MTWIP_R(1.0) ? MTWIP_R(1.0) : (a < MTWIP_R(-1.0) ? MTWIP_R(-1.0) : a);
    b = b > MTWIP_R(1.0) ? MTWIP_R(1.0) : (b < MTWIP_R(-1.0) ? MTWIP_R(-1.0) : b);
    memberships(f->lo1, f->k1, a, a_lo);
    memberships(f->up1, f->k1, a, a_up);
    memberships(f->lo2, f->k2, b, b_lo);
    memberships(f->up2, f->k2, b, b_up);
    firing_sums(f, a_up, b_up, &s_up, &w_up);
    firing_sums(f, a_lo, b_lo, &s_lo, &w_lo);
    if (f->reducer == 1) y = (w_lo + w_up) / (s_lo + s_up);
    else if (s_lo > MTWIP_R(0.0)) y = f->m * w_lo / s_lo + f->n * w_up / s_up;
    else y = (f->m + f->n) * w_up / s_up;
    return f->out * y;
}
#endif

/* the balance PDC: u = m1(theta) G1 x + (1 - m1(theta)) G2 x, x = [theta - theta_off, theta_dot, psi_e, psi_dot] */
static mtwip_real pdc(mtwip_real theta, mtwip_real theta_dot, mtwip_real psi, mtwip_real psi_dot, mtwip_real theta_off) {
    mtwip_real a = MTWIP_FABS(theta);
    mtwip_real l = MTWIP_R(1.0) - a / PDC_LO, u = MTWIP_R(1.0) - a / PDC_UP;
    mtwip_real m1 = MTWIP_R(0.5) * ((l > MTWIP_R(0.0) ? l : MTWIP_R(0.0)) + (u > MTWIP_R(0.0) ? u : MTWIP_R(0.0)));
    mtwip_real th = theta - theta_off;
    mtwip_real u1 = G1[0] * th + G1[1] * theta_dot + G1[2] * psi + G1[3] * psi_dot;
    mtwip_real u2 = G2[0] * th + G2[1] * theta_dot + G2[2] * psi + G2[3] * psi_dot;
    return m1 * u1 + (MTWIP_R(1.0) - m1) * u2;
}

void mtwip_control(const mtwip_real x[6], const mtwip_targets_t *t, mtwip_real out[5]) {
    mtwip_real theta_off = MTWIP_R(0.0), psi_e = x[2], u_alpha = MTWIP_R(0.0), u, u_p;
#if MTWIP_HAS_POSITION
    if (t->has_position) {
        mtwip_real e = x[2] - t->position / WHEEL_RADIUS;
        theta_off = fls(&POSITION, WHEEL_RADIUS * x[2] - t->position, x[1]);
        psi_e = e > PSI_LIMIT ? PSI_LIMIT : (e < -PSI_LIMIT ? -PSI_LIMIT : e);
    }
#endif
    u = pdc(x[0], x[1], psi_e, x[3], theta_off);
#if MTWIP_HAS_DIRECTION
    if (t->has_heading) u_alpha = fls(&DIRECTION, x[4] - t->heading, x[5]);
#endif
    (void)t;
    u_p = MTWIP_R(0.5) * u;
    out[0] = u_p - u_alpha;
    out[1] = u_p + u_alpha;
    out[2] = u;
    out[3] = theta_off;
    out[4] = u_alpha;
}
"""

_LQR = """
%(data)s

void mtwip_control(const mtwip_real x[6], const mtwip_targets_t *t, mtwip_real out[5]) {
    mtwip_real psi_e = x[2], u_alpha = MTWIP_R(0.0), u, u_p;
    if (t->has_position) {
        mtwip_real e = x[2] - t->position / WHEEL_RADIUS;
        psi_e = e < -PSI_LIMIT ? -PSI_LIMIT : e;
        psi_e = psi_e > PSI_LIMIT ? PSI_LIMIT : psi_e;
    }
    u = K[0] * x[0] + K[1] * x[1] + K[2] * psi_e + K[3] * x[3];
    if (t->has_heading) u_alpha = K_YAW[0] * (x[4] - t->heading) + K_YAW[1] * x[5];
    u_p = MTWIP_R(0.5) * u;
    out[0] = u_p - u_alpha;
    out[1] = u_p + u_alpha;
    out[2] = u;
    out[3] = MTWIP_R(0.0);
    out[4] = u_alpha;
}
"""

_MOTOR = """/* The motors' driver (twin.actuators.dc_motor.MotorDriver.duty): torque command -> PWM duty.
   Generated by twin export. */
#include <math.h>
#include "mtwip.h"

%(data)s

uint8_t mtwip_motor_duty(mtwip_real torque, mtwip_real omega, mtwip_real *duty) {
#if MTWIP_HAS_MOTOR
    mtwip_real i_cmd = torque / KT, v, d;
    uint8_t saturated = MTWIP_FABS(i_cmd) > IMAX;
    if (saturated) i_cmd = i_cmd < MTWIP_R(0.0) ? -IMAX : IMAX;
    v = RESISTANCE * i_cmd;
    if (BACK_EMF_COMPENSATION) v += KT * omega;
    d = v / SUPPLY;
    if (d > MTWIP_R(1.0) || d < MTWIP_R(-1.0)) {
        saturated = 1;
        d = d > MTWIP_R(0.0) ? MTWIP_R(1.0) : MTWIP_R(-1.0);
    }
    if (MTWIP_FABS(d) < DEAD_BAND)
        d = MTWIP_R(0.0);
    else
        d = (MTWIP_NEARBYINT(d * PWM_STEPS) + MTWIP_R(0.0)) / PWM_STEPS;
    *duty = d;
    return saturated;
#else
    (void)torque;
    (void)omega;
    *duty = MTWIP_R(0.0); /* ideal torque sources: the torque command is what the wheels get */
    return 0;
#endif
}
"""

_HEAD = """/* The controllers (%(what)s). Generated by twin export: the same arithmetic as the twin's
   Python path, in the same order; compile with -ffp-contract=off. */
#include <math.h>
#include "mtwip.h"
"""


def _sets(buf: bytes) -> np.ndarray:
    return np.frombuffer(buf, dtype=float).reshape(-1, 4)


def _fls_data(name: str, scaled, precision: str) -> list[str]:
    f = scaled.fls
    i1, i2 = f.input1, f.input2
    if max(len(i1), len(i2)) > 16:
        raise TwinError(f"the {name.lower()} controller has {max(len(i1), len(i2))} sets on an input; the export "
                        f"allows at most 16")
    lit = lambda v: literal(v, precision)  # noqa: E731
    reducer = {"bmm": 0, "nt": 1}.get(f.type_reduction)
    if reducer is None:
        raise TwinError(f"type reduction {f.type_reduction!r} cannot be exported; allowed: bmm, nt")
    return [array(f"{name}_LO1", _sets(i1.kernel_lower), precision),
            array(f"{name}_UP1", _sets(i1.kernel_upper), precision),
            array(f"{name}_LO2", _sets(i2.kernel_lower), precision),
            array(f"{name}_UP2", _sets(i2.kernel_upper), precision),
            array(f"{name}_Y", f.y, precision),
            f"static const fls_t {name} = {{{len(i1)}, {len(i2)}, {reducer}, {lit(f.m)}, {lit(f.n)}, "
            f"{name}_LO1, {name}_UP1, {name}_LO2, {name}_UP2, {name}_Y, {lit(scaled.input_ranges[0])}, "
            f"{lit(scaled.input_ranges[1])}, {lit(scaled.output_range)}}};"]


def control_source(controller, precision: str) -> str:
    """``mtwip_control.c`` for a built controller: the fuzzy cascade (``it2``, ``t1``) or the LQR."""
    # only: the controllers' classes, to tell which one was built
    from twin.controllers.cascade import FuzzyCascade
    from twin.controllers.lqr import LQRController

    lit = lambda v: literal(v, precision)  # noqa: E731
    if isinstance(controller, FuzzyCascade):
        b = controller.balance
        lo, up = b.half_widths
        data = [array("G1", b.G[0], precision), array("G2", b.G[1], precision),
                f"#define PDC_LO {lit(lo)}", f"#define PDC_UP {lit(up)}",
                f"#define WHEEL_RADIUS {lit(controller.r)}", f"#define PSI_LIMIT {lit(controller.psi_error_limit)}"]
        flags = [f"#define MTWIP_HAS_POSITION {int(controller.position is not None)}",
                 f"#define MTWIP_HAS_DIRECTION {int(controller.direction is not None)}"]
        if controller.position is not None:
            data += _fls_data("POSITION", controller.position, precision)
        if controller.direction is not None:
            data += _fls_data("DIRECTION", controller.direction, precision)
        what = f"the {b.kind} fuzzy cascade: balance PDC, Mamdani position and direction"
        return _HEAD % {"what": what} + _CASCADE % {"data": "\n".join(data), "flags": "\n".join(flags)}
    if isinstance(controller, LQRController):
        # u = -K x: the controller's own negated gains (negation is exact)
        data = [array("K", -controller.K[0], precision), array("K_YAW", -controller.K_yaw[0], precision),
                f"#define WHEEL_RADIUS {lit(controller.params.r)}", f"#define PSI_LIMIT {lit(controller.psi_error_limit)}"]
        return _HEAD % {"what": "LQR balance, position and heading"} + _LQR % {"data": "\n".join(data)}
    raise TwinError(f"controller {type(controller).__module__}.{type(controller).__qualname__} cannot be exported "
                    f"to C: only the built-in it2, t1 and lqr can")


def motor_source(motor, precision: str) -> str:
    """``mtwip_motor.c``: :class:`twin.actuators.dc_motor.MotorDriver`'s duty law for ``motor``
    (a :class:`~twin.actuators.DCMotorParams`; None: ideal torque sources, no duty)."""
    if motor is None:
        return _MOTOR % {"data": "#define MTWIP_HAS_MOTOR 0"}
    # only: the driver's derived constants, exactly as the twin computes them
    from twin.actuators.dc_motor import MotorDriver

    d = MotorDriver(motor)
    kt, R, vs, imax, steps, comp, dead = d.constants
    lit = lambda v: literal(v, precision)  # noqa: E731
    data = ["#define MTWIP_HAS_MOTOR 1",
            f"#define KT {lit(kt)}          /* N·m/A */", f"#define RESISTANCE {lit(R)}  /* ohm */",
            f"#define SUPPLY {lit(vs)}      /* V */", f"#define IMAX {lit(imax)}        /* A */",
            f"#define PWM_STEPS {lit(steps)}", f"#define BACK_EMF_COMPENSATION {int(comp)}",
            f"#define DEAD_BAND {lit(dead)}"]
    return _MOTOR % {"data": "\n".join(data)}


__all__ = ["control_source", "motor_source"]
