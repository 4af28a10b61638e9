"""The EKF as C (:mod:`twin.export.ekf`): compiled with the host's compiler, it gives the twin's
estimates step for step on the readings and commands of a twin run (paper-exp3; sensor-faults
through its gyro spikes, which the filter rejects and coasts over, and its 0.2 s IMU dropout); the
float32 build compiles clean; the same estimator gives the same bytes; an option the C does not
implement is refused in one line; the arithmetic arranged for speed (the structural zeros left out, the
median by selection) gives the plain loops' bits in both precisions."""
from __future__ import annotations

import ctypes
import dataclasses
import shutil
import subprocess
from importlib import resources

import numpy as np
import pytest

from twin.errors import TwinError
from twin.export import ekf as ekf_export
from twin.scenarios import load_scenario
from twin.sim.simulate import simulate

COMPILERS = [c for c in ("cc", "gcc", "clang") if shutil.which(c)]
pytestmark = pytest.mark.skipif(not COMPILERS, reason="no C compiler (cc, gcc or clang) on this machine")
STRICT = ["-std=c99", "-O2", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror", "-pedantic"]

# a stand-in for the generated mtwip_params.h: the precision and the math functions the EKF uses
PARAMS = """#ifndef MTWIP_PARAMS_H
#define MTWIP_PARAMS_H
#include <math.h>
typedef %(real)s mtwip_real;
#define MTWIP_R(x) ((mtwip_real)(x))
#define MTWIP_FLOAT32 %(f32)d
#define MTWIP_SIN sin%(s)s
#define MTWIP_COS cos%(s)s
#define MTWIP_TAN tan%(s)s
#define MTWIP_ATAN2 atan2%(s)s
#define MTWIP_SQRT sqrt%(s)s
#define MTWIP_FABS fabs%(s)s
#define MTWIP_EXP exp%(s)s
#define MTWIP_POW pow%(s)s
#define MTWIP_ERFC erfc%(s)s
#define MTWIP_HYPOT hypot%(s)s
#define MTWIP_ISFINITE(x) isfinite(x)
#include "mtwip_estimator.h"
#endif
"""

# the readings and commands of a run in, the estimates out: mtwip_estimator_start, then _step
DRIVER = r"""#include <string.h>
#include "mtwip.h"
static mtwip_estimator_t E;
int ekf_replay(int n, const double *gyro, const double *accel, const double *enc, const unsigned char *has,
               const double *cmd, double *out) {
    int k, i;
    mtwip_estimator_init(&E);
    for (k = 0; k < n; k++) {
        mtwip_sample_t s;
        mtwip_real c[2], x[6];
        memset(&s, 0, sizeof s);
        for (i = 0; i < 3; i++) {
            s.gyro[i] = (mtwip_real)gyro[3 * k + i];
            s.accel[i] = (mtwip_real)accel[3 * k + i];
        }
        s.encoder[0] = (mtwip_real)enc[2 * k];
        s.encoder[1] = (mtwip_real)enc[2 * k + 1];
        s.has_gyro = has[3 * k];
        s.has_accel = has[3 * k + 1];
        s.has_encoder = has[3 * k + 2];
        c[0] = (mtwip_real)cmd[2 * k];
        c[1] = (mtwip_real)cmd[2 * k + 1];
        if (k == 0)
            mtwip_estimator_start(&E, &s, x);
        else
            mtwip_estimator_step(&E, &s, c, x);
        for (i = 0; i < 6; i++) out[6 * k + i] = (double)x[i];
    }
    return 0;
}
"""


class Recording:
    """The twin's EKF, recording what the loop gives it and what it answers."""

    def __init__(self, inner):
        self.inner = inner
        self.log = []

    def start(self, meas):
        est = self.inner.start(meas)
        self.log.append((meas.gyro, meas.accel, meas.encoders, None, tuple(est)))
        return est

    def step(self, meas, command):
        est = self.inner.step(meas, command)
        self.log.append((meas.gyro, meas.accel, meas.encoders, (float(command[0]), float(command[1])), tuple(est)))
        return est

    def __getattr__(self, name):
        return getattr(self.inner, name)


def _run(scenario: str, seconds: float, controller: str = "it2"):
    """(a fresh EKF as the twin builds it for the run, the recording, the run's EKF)"""
    spec = dataclasses.replace(load_scenario(scenario).run_spec(controller), duration=seconds)
    rec = Recording(spec.build_estimator())
    simulate(spec, estimator=rec)
    return spec.build_estimator(), rec.log, rec.inner


def _write(estimator, precision: str, d, arithmetic: str = "exact"):
    f32 = precision == "float32"
    for name, text in ekf_export.emit(estimator, precision, arithmetic).items():
        (d / name).write_text(text)
    (d / "mtwip.h").write_text(resources.files("twin.export").joinpath("c", "mtwip.h").read_text(encoding="utf-8"))
    (d / "mtwip_params.h").write_text(PARAMS % {"real": "float" if f32 else "double", "f32": int(f32),
                                                "s": "f" if f32 else ""})
    (d / "driver.c").write_text(DRIVER)


def _replay(lib, log) -> np.ndarray:
    n = len(log)
    gyro, accel, enc = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 2))
    has, cmd, out = np.zeros((n, 3), np.uint8), np.zeros((n, 2)), np.zeros((n, 6))
    for k, (g, a, e, c, _) in enumerate(log):
        for j, (v, dst) in enumerate(((g, gyro), (a, accel), (e, enc))):
            if v is not None:
                dst[k], has[k, j] = v, 1
        if c is not None:
            cmd[k] = c
    p = [np.ascontiguousarray(v).ctypes.data_as(ctypes.c_void_p) for v in (gyro, accel, enc, has, cmd, out)]
    lib.ekf_replay(ctypes.c_int(n), *p)
    return out


def _c_estimates(estimator, log, d, arithmetic: str = "exact") -> np.ndarray:
    """The float64 C build of ``estimator`` (with ``arithmetic``) replayed over a recording: its estimates."""
    _write(estimator, "float64", d, arithmetic)
    so = d / "libekf.so"
    r = subprocess.run([COMPILERS[0], *STRICT, "-fPIC", "-shared", "-I", str(d), str(d / "mtwip_estimator.c"),
                        str(d / "driver.c"), "-o", str(so), "-lm"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return _replay(ctypes.CDLL(str(so)), log)


@pytest.mark.parametrize("scenario, seconds", [("paper-exp3", 2.5), ("sensor-faults", 5.5)])
def test_the_c_gives_the_twins_estimates_step_for_step(scenario, seconds, tmp_path):
    fresh, log, run = _run(scenario, seconds)
    if scenario == "sensor-faults":  # the faults were there: rejected gyro spikes and the dropout, coasted over
        stats = run.stats()
        assert stats["rejected"]["gyro"] > 0, stats
        assert stats["predict_only_steps"] - stats["unchanged_encoder_samples"] >= 40, stats
    c = _c_estimates(fresh, log, tmp_path)
    twin = np.array([x for *_, x in log])
    diff = np.abs(c - twin)
    worst = diff.max(axis=0)
    assert worst.max() <= 1e-9, (f"{scenario}: C against the twin's EKF, worst |diff| per state {worst}, first at step "
                                 f"{int(np.argmax(diff.max(axis=1) > 1e-9))}")


@pytest.mark.parametrize("arithmetic", ekf_export.ARITHMETICS)
def test_the_float32_build_compiles_clean(arithmetic, tmp_path):
    fresh = load_scenario("sensor-faults").run_spec("it2").build_estimator()
    _write(fresh, "float32", tmp_path, arithmetic)
    for cc in {shutil.which(c) for c in COMPILERS}:
        r = subprocess.run([cc, *STRICT, "-Wdouble-promotion", "-c", "-I", str(tmp_path),
                            str(tmp_path / "mtwip_estimator.c"), "-o", str(tmp_path / "ekf.o")],
                           capture_output=True, text=True)
        assert r.returncode == 0, f"{cc}: {r.stderr}"


# the lean arithmetic is the same filter: in float64 its estimates stay within 1e-6 of the twin's where it
# coasts over sensor-faults' gyro spikes and dropout (measured: 5.8e-8 rad/s at worst with IT2; the forward
# differences' truncation). A wrong derivative in its chain rule does not:
# leaving out α̇'s term in θ moved them by 2.6e-4 on sensor-faults, ψ̇'s sign turned by 0.14
LEAN_TOLERANCE = 1e-6


@pytest.mark.parametrize("scenario, seconds, controller", [("sensor-faults", 5.5, "it2"), ("sensor-faults", 5.5, "lqr")])
def test_the_lean_arithmetic_is_the_same_filter(scenario, seconds, controller, tmp_path):
    fresh, log, run = _run(scenario, seconds, controller)
    stats = run.stats()
    assert stats["predict_only_steps"] - stats["unchanged_encoder_samples"] >= 20, stats  # it coasted
    c = _c_estimates(fresh, log, tmp_path, "lean")
    assert "#define MTWIP_EKF_LEAN 1" in (tmp_path / "mtwip_estimator.h").read_text()
    twin = np.array([x for *_, x in log])
    worst = np.abs(c - twin).max(axis=0)
    assert worst.max() <= LEAN_TOLERANCE, f"{scenario}: lean C against the twin's EKF, worst |diff| per state {worst}"
    assert np.any(c != twin), "the lean build gave the exact build's bits: its coasting arithmetic did not run"


def test_the_same_estimator_gives_the_same_bytes_and_options_are_refused():
    spec = load_scenario("paper-exp3").run_spec("it2")
    a, b = spec.build_estimator(), spec.build_estimator()
    for precision in ("float64", "float32"):
        assert ekf_export.emit(a, precision) == ekf_export.emit(b, precision)
    source = ekf_export.emit(a, "float64")["mtwip_estimator.c"]
    assert "static const mtwip_ekf_config_t mtwip_ekf_config = {" in source
    b.set_sampling(imu="point")
    with pytest.raises(TwinError, match="set_sampling.*allowed"):
        ekf_export.emit(b, "float64")
    from estimation.ekf import EKFEstimator

    with pytest.raises(TwinError, match="compiled=False.*allowed"):
        ekf_export.emit(EKFEstimator(a.model, compiled=False), "float64")
    with pytest.raises(TwinError, match="unknown EKF arithmetic 'fast'; allowed: exact, lean"):
        ekf_export.emit(a, "float64", "fast")


# The arranged arithmetic against the plain one, bit for bit, on random numbers: the covariance's prediction,
# the innovation, the Kalman update and the keep-inside truncation (which leave out the exact zeros of F's, H's
# and I − K H's structure when P is known finite) against the kernel's plain loops they were rearranged from
# (copied below as ref_*), the coasting step's J Pa Jᵀ and augmented update against their plain loops, and the
# latency watch's median by selection against the insertion sort it replaced;
# zeros of both signs, ties and sorted runs among the inputs, huge covariances that overflow part way (the
# general path), and select_kth's heap fallback forced (MTWIP_EKF_SELECT_SLACK).
UNIT = r"""#include <float.h>
#include <stdio.h>
#include "mtwip_estimator.c"
#if MTWIP_FLOAT32
#define BIG ((real)FLT_MAX)
#else
#define BIG ((real)DBL_MAX)
#endif

/* ---- the plain loops (the kernel's) ---- */

/* the coasting step's products as they were: J Pa Jᵀ (J's unit rows and its nontrivial rows Jr) and the
   augmented update, their plain loops */
static int ref_j_kind(int i) {
    if (i < NX) return ROW_OF[i] >= 0 ? ROW_OF[i] : -1 - i;
    if (i < NX + 2) return 4 + (i - NX);
    if (i < NX + 4) return -1 - (i - 2);
    return -1 - i;
}

static void ref_aug_jpj(real *Pa, real Jr[6][NA]) {
    real col[NA];
    int i, j, l;
    for (l = 0; l < NA; l++) {
        for (i = 0; i < NA; i++) {
            int kind = ref_j_kind(i);
            if (kind < 0)
                col[i] = Pa[(-1 - kind) * NA + l];
            else {
                real s = ZERO;
                for (j = 0; j < NA; j++) s += Jr[kind][j] * Pa[j * NA + l];
                col[i] = s;
            }
        }
        for (i = 0; i < NA; i++) Pa[i * NA + l] = col[i];
    }
    for (i = 0; i < NA; i++) {
        for (l = 0; l < NA; l++) {
            int kind = ref_j_kind(l);
            if (kind < 0)
                col[l] = Pa[i * NA + (-1 - kind)];
            else {
                real s = ZERO;
                for (j = 0; j < NA; j++) s += Pa[i * NA + j] * Jr[kind][j];
                col[l] = s;
            }
        }
        for (l = 0; l < NA; l++) Pa[i * NA + l] = col[l];
    }
}

static int ref_coast_update(mtwip_estimator_t *e, const meas_t *em) {
    real *Pa = e->aug, PHt[NA][2], S[2][2], Kg[NA][2], y[2], za[NA], row[NA], Rm[2][2];
    int m = em->dof, i, j, a, b, k;
    for (i = 0; i < NA; i++)
        for (a = 0; a < m; a++) {
            real s = ZERO;
            for (j = 0; j < NX; j++) s += Pa[i * NA + j] * em->H[a][j];
            PHt[i][a] = s;
        }
    for (a = 0; a < m; a++)
        for (b = 0; b < m; b++) {
            real s = ZERO;
            for (i = 0; i < NX; i++) s += em->H[a][i] * PHt[i][b];
            Rm[a][b] = a == b ? em->R[a] : ZERO;
            S[a][b] = s + Rm[a][b];
        }
    if (m == 1) {
        if (S[0][0] == ZERO || S[0][0] != S[0][0]) return EKF_FAILED;
        for (i = 0; i < NA; i++) Kg[i][0] = PHt[i][0] / S[0][0];
    } else {
        int p = MTWIP_FABS(S[1][0]) > MTWIP_FABS(S[0][0]);
        real r0[2], r1[2], f;
        if (S[p][0] == ZERO || S[p][0] != S[p][0]) return EKF_FAILED;
        r0[0] = S[p][0];
        r0[1] = S[p][1];
        r1[0] = S[1 - p][0];
        r1[1] = S[1 - p][1];
        f = r1[0] / r0[0];
        if (f != ZERO) r1[1] -= f * r0[1];
        if (r1[1] == ZERO || r1[1] != r1[1]) return EKF_FAILED;
        for (i = 0; i < NA; i++) {
            real b0 = PHt[i][p], b1 = PHt[i][1 - p], x1, s;
            if (f != ZERO) b1 -= f * b0;
            x1 = b1 / r1[1];
            s = b0;
            s -= r0[1] * x1;
            Kg[i][0] = s / r0[0];
            Kg[i][1] = x1;
        }
    }
    for (i = 0; i < NX; i++)
        if (e->consider[i]) Kg[i][0] = Kg[i][1] = ZERO;
    for (a = 0; a < m; a++) {
        real s = ZERO;
        for (j = 0; j < NX; j++) s += em->H[a][j] * e->x[j];
        y[a] = em->z[a] - (s + em->off[a]);
    }
    memcpy(za, e->x, NX * sizeof(real));
    za[NX] = e->w[0];
    za[NX + 1] = e->w[1];
    za[NX + 2] = e->w_prev[0];
    za[NX + 3] = e->w_prev[1];
    for (i = 0; i < NK; i++) za[NX + 4 + i] = e->dp[i];
    for (i = 0; i < NA; i++) {
        real s = ZERO;
        for (a = 0; a < m; a++) s += Kg[i][a] * y[a];
        za[i] = za[i] + s;
    }
    for (j = 0; j < NA; j++) { /* A = (I − K H) Pa, column by column */
        for (i = 0; i < NA; i++) {
            real s = ZERO;
            for (k = 0; k < NX; k++) s += ikh_aug(Kg, em, i, k) * Pa[k * NA + j];
            if (i >= NX) s += Pa[i * NA + j];
            row[i] = s;
        }
        for (i = 0; i < NA; i++) Pa[i * NA + j] = row[i];
    }
    for (i = 0; i < NA; i++) { /* Pa = A (I − K H)ᵀ + K R Kᵀ, row by row */
        for (j = 0; j < NA; j++) {
            real s = ZERO, t = ZERO;
            for (k = 0; k < NX; k++) s += Pa[i * NA + k] * ikh_aug(Kg, em, j, k);
            if (j >= NX) s += Pa[i * NA + j];
            for (b = 0; b < m; b++) {
                real kr = ZERO;
                for (a = 0; a < m; a++) kr += Kg[i][a] * Rm[a][b];
                t += kr * Kg[j][b];
            }
            row[j] = s + t;
        }
        for (j = 0; j < NA; j++) Pa[i * NA + j] = row[j];
    }
    symmetrise(Pa, NA);
    memcpy(e->x, za, NX * sizeof(real));
    for (i = 0; i < NX; i++)
        for (j = 0; j < NX; j++) e->P[i * NX + j] = Pa[i * NA + j];
    e->w[0] = za[NX];
    e->w[1] = za[NX + 1];
    e->w_prev[0] = za[NX + 2];
    e->w_prev[1] = za[NX + 3];
    for (i = 0; i < NK; i++) e->dp[i] = za[NX + 4 + i];
    return EKF_OK;
}

static void ref_cov_predict(const step_t *st, const real *P, real *Pp) {
    real A4[4][NX];
    int a, i, j, k;
    for (a = 0; a < 4; a++)
        for (j = 0; j < NX; j++) {
            real s = ZERO;
            for (k = 0; k < NX; k++) s += st->F4[a][k] * P[k * NX + j];
            A4[a][j] = s;
        }
    for (i = 0; i < NX; i++) {
        const real *Ai = ROW_OF[i] >= 0 ? A4[ROW_OF[i]] : P + i * NX;
        for (j = 0; j < NX; j++) {
            real s;
            if (ROW_OF[j] < 0)
                s = Ai[j];
            else {
                const real *Fj = st->F4[ROW_OF[j]];
                s = ZERO;
                for (k = 0; k < NX; k++) s += Ai[k] * Fj[k];
            }
            Pp[i * NX + j] = s + q_entry(st, i, j);
        }
    }
}

static void ref_innovation(const real *x, const real *P, const meas_t *em, real *y, real PHt[NX][2], real S[2][2]) {
    int a, b, i, j;
    for (a = 0; a < em->dof; a++) {
        real hx = em->off[a];
        for (j = 0; j < NX; j++) hx += em->H[a][j] * x[j];
        y[a] = em->z[a] - hx;
        for (i = 0; i < NX; i++) {
            real s = ZERO;
            for (j = 0; j < NX; j++) s += P[i * NX + j] * em->H[a][j];
            PHt[i][a] = s;
        }
    }
    for (a = 0; a < em->dof; a++)
        for (b = 0; b < em->dof; b++) {
            real s = ZERO;
            for (i = 0; i < NX; i++) s += em->H[a][i] * PHt[i][b];
            S[a][b] = s + (a == b ? em->R[a] : ZERO);
        }
}

static int ref_kalman_update(real *x, real *P, const meas_t *em, const uint8_t *consider) {
    int m = em->dof, i, j, k, a, b;
    real PHt[NX][2], S[2][2], Si[2][2], K[NX][2], y[2], tmp[NX];
    ref_innovation(x, P, em, y, PHt, S);
    if (m == 1) {
        if (!(S[0][0] > ZERO)) return -1;
        Si[0][0] = ONE / S[0][0];
    } else {
        real det = S[0][0] * S[1][1] - S[0][1] * S[1][0];
        if (!(det > ZERO)) return -1;
        Si[0][0] = S[1][1] / det;
        Si[1][1] = S[0][0] / det;
        Si[0][1] = -S[0][1] / det;
        Si[1][0] = -S[1][0] / det;
    }
    for (i = 0; i < NX; i++)
        for (b = 0; b < m; b++) {
            real s = ZERO;
            for (a = 0; a < m; a++) s += PHt[i][a] * Si[a][b];
            K[i][b] = consider[i] ? ZERO : s;
        }
    for (i = 0; i < NX; i++)
        for (a = 0; a < m; a++) x[i] += K[i][a] * y[a];
    for (j = 0; j < NX; j++) {
        for (i = 0; i < NX; i++) {
            real s = ZERO;
            for (k = 0; k < NX; k++) s += ikh12(K, em, i, k) * P[k * NX + j];
            tmp[i] = s;
        }
        for (i = 0; i < NX; i++) P[i * NX + j] = tmp[i];
    }
    for (i = 0; i < NX; i++) {
        for (j = 0; j < NX; j++) {
            real s = ZERO;
            for (k = 0; k < NX; k++) s += P[i * NX + k] * ikh12(K, em, j, k);
            for (a = 0; a < m; a++) s += K[i][a] * em->R[a] * K[j][a];
            tmp[j] = s;
        }
        for (j = 0; j < NX; j++) P[i * NX + j] = tmp[j];
    }
    return 0;
}

static int ref_keep_inside(mtwip_estimator_t *e, const real *enc) {
    int n = 0, implausible = 0, i, j, k;
    for (i = 0; i < 2; i++) {
        meas_t em;
        real w, s2 = ZERO, lo, hi, sgn = (real)(2 * i - 1);
        if (enc[i] != e->last_enc[i]) continue;
        em.dof = 1;
        h_row(i, em.H[0]);
        em.off[0] = -sgn * C->b_r * C->alpha0;
        w = em.off[0];
        for (j = 0; j < NX; j++) {
            real t = ZERO;
            w += em.H[0][j] * e->x[j];
            for (k = 0; k < NX; k++) t += e->P[j * NX + k] * em.H[0][k];
            s2 += em.H[0][j] * t;
        }
        lo = enc[i] - C->inside_half;
        hi = enc[i] + C->inside_half;
        if (s2 > ZERO && (w < lo ? lo - w : w - hi) > C->stuck_sigmas * MTWIP_SQRT(s2)) {
            implausible |= 1 << i;
            continue;
        }
        if (!truncated_measurement(w, s2, lo, hi, C->stuck_sigmas, &em.z[0], &em.R[0])) continue;
        if (ref_kalman_update(e->x, e->P, &em, e->consider) != 0) return -1;
        n++;
    }
    return n + 16 * implausible;
}

static real ref_median(const real *a, int n) { /* the insertion sort's */
    real t[128];
    int i, j;
    memcpy(t, a, (size_t)n * sizeof(real));
    for (i = 1; i < n; i++) {
        real v = t[i];
        for (j = i; j > 0 && t[j - 1] > v; j--) t[j] = t[j - 1];
        t[j] = v;
    }
    return n % 2 ? t[n / 2] : (t[n / 2 - 1] + t[n / 2]) / TWO;
}

/* ---- random numbers ---- */
static uint32_t rs = 2463534242u;
static long bad, trials, fast;
static uint32_t rnd(void) {
    rs ^= rs << 13;
    rs ^= rs >> 17;
    rs ^= rs << 5;
    return rs;
}
static real uni(void) { return (real)((double)rnd() / 4294967296.0 * 2.0 - 1.0); }
static real sparse(real scale) { /* one in five an exact zero of either sign */
    uint32_t u = rnd() % 10;
    return u == 0 ? ZERO : u == 1 ? -ZERO : scale * uni();
}
static void check(int same, const char *what, long trial) {
    trials++;
    if (!same && bad++ < 10) printf("%s differs (trial %ld)\n", what, trial);
}
static int same(const void *a, const void *b, size_t n) { return memcmp(a, b, n) == 0; }
/* the same bits, a NaN for a NaN whatever its sign and payload (which the compiler's order of a commutative
   operation's operands decides, not the source) */
static int same_r(const real *a, const real *b, size_t n) {
    size_t i;
    for (i = 0; i < n; i++)
        if (memcmp(a + i, b + i, sizeof *a) != 0 && !(a[i] != a[i] && b[i] != b[i])) return 0;
    return 1;
}

static void medians(void) {
    static const real few[5] = {MTWIP_R(-1.0), -ZERO, ZERO, MTWIP_R(1.0), MTWIP_R(2.0)};
    real a[128], h[128], m1, m2;
    long t;
    int i;
    for (t = 0; t < 20000; t++) {
        int n = 1 + (int)(rnd() % 128), kind = (int)(t % 7);
        for (i = 0; i < n; i++) {
            switch (kind) {
            case 0: a[i] = uni(); break;
            case 1: a[i] = few[rnd() % 5]; break;
            case 2: a[i] = (real)i; break;
            case 3: a[i] = (real)(n - i); break;
            case 4: a[i] = (real)(i < n / 2 ? i : n - i); break;
            case 5: a[i] = rnd() % 2 ? ZERO : -ZERO; break;
            default: a[i] = (real)(rnd() % 3) * (rnd() % 2 ? ONE : -ONE); break;
            }
        }
        m1 = median_of(a, h, n);
        m2 = ref_median(a, n);
        check(same(&m1, &m2, sizeof m1), "median", t);
    }
}

/* B Bᵀ + I (symmetric, positive definite; or, one in three, B itself) scaled, a few entries zeros */
static void random_P(real *P, real scale) {
    real B[NX * NX];
    int i, j, k, n = (int)(rnd() % 8), plain = rnd() % 3 == 0;
    for (i = 0; i < NX * NX; i++) B[i] = sparse(ONE);
    for (i = 0; i < NX; i++)
        for (j = 0; j < NX; j++) {
            real s = i == j ? ONE : ZERO;
            if (plain)
                s = B[i * NX + j];
            else
                for (k = 0; k < NX; k++) s += B[i * NX + k] * B[j * NX + k];
            P[i * NX + j] = scale * s;
        }
    for (i = 0; i < n; i++) P[rnd() % (NX * NX)] = rnd() % 2 ? ZERO : -ZERO;
}

static void random_meas(meas_t *em, real scale) {
    int a;
    em->dof = 1 + (int)(rnd() % 2);
    for (a = 0; a < em->dof; a++) {
        h_row(em->dof == 2 ? a : (int)(rnd() % 2), em->H[a]);
        em->z[a] = uni();
        em->off[a] = sparse(ONE);
        em->R[a] = scale * (ONE + uni()) / MTWIP_R(100.0);
    }
}

static mtwip_estimator_t E1, E0;

static void products(void) {
    static const real scales[5] = {MTWIP_R(1.0), MTWIP_R(1e-3), MTWIP_R(1.0) / MTWIP_R(4096.0), MTWIP_R(1.0) / MTWIP_R(64.0),
                                   MTWIP_R(1.0) / MTWIP_R(4.0)};
    long t;
    int i, j;
    for (t = 0; t < 10000; t++) {
        real scale = t % 5 < 2 ? scales[t % 5] : BIG * scales[t % 5];
        real P[NX * NX], P1[NX * NX], P0[NX * NX], x1[NX], x0[NX], y[2], PHt[NX][2], S[2][2];
        uint8_t cons[NX];
        step_t st;
        meas_t em;
        innov_t in1;
        int r1, r0, f1, fin;
        random_P(P, scale);
        fin = finite_matrix(P); /* (the callers' flag: P known finite) */
        for (i = 0; i < 4; i++) { /* F's rows; every other time with F's zero columns (c, h) */
            for (j = 0; j < NX; j++) st.F4[i][j] = t % 2 && (j == C0 || j == H0) ? ZERO : sparse(MTWIP_R(2.0));
            for (j = 0; j < 4; j++) st.Q4[i][j] = uni();
        }
        r1 = cov_predict(&st, P, P1, fin);
        ref_cov_predict(&st, P, P0);
        check(same(P1, P0, sizeof P1), "cov_predict", t);
        for (i = 0; i < NX * NX; i++) check(!r1 || MTWIP_ISFINITE(P0[i]), "cov_predict's finite", t);
        random_meas(&em, scale);
        for (i = 0; i < NX; i++) {
            x1[i] = x0[i] = uni();
            cons[i] = (uint8_t)(rnd() % 3 == 0);
        }
        innovation(x1, P, &em, fin, &in1);
        ref_innovation(x0, P, &em, y, PHt, S);
        check(same(in1.y, y, (size_t)em.dof * sizeof(real)), "innovation y", t);
        for (i = 0; i < NX; i++) check(same(in1.PHt[i], PHt[i], (size_t)em.dof * sizeof(real)), "innovation P Ht", t);
        for (i = 0; i < em.dof; i++) check(same(in1.S[i], S[i], (size_t)em.dof * sizeof(real)), "innovation S", t);
        memcpy(P1, P, sizeof P);
        memcpy(P0, P, sizeof P);
        r1 = kalman_update(x1, P1, &em, cons, fin, &f1, t % 2 ? &in1 : NULL);
        r0 = ref_kalman_update(x0, P0, &em, cons);
        check(r1 == r0 && same(x1, x0, sizeof x1) && same(P1, P0, sizeof P1), "kalman_update", t);
        for (i = 0; i < NX * NX; i++) check(!f1 || MTWIP_ISFINITE(P0[i]), "kalman_update's finite", t);
        fast += f1;
        memset(&E1, 0, sizeof E1);
        for (i = 0; i < NX; i++) {
            E1.x[i] = uni();
            E1.consider[i] = cons[i];
        }
        memcpy(E1.P, P, sizeof P);
        E1.last_enc[0] = E1.x[PS] + (real)(rnd() % 3) * MTWIP_R(0.01) * uni();
        E1.last_enc[1] = E1.x[PS] + (real)(rnd() % 3) * MTWIP_R(0.01) * uni();
        E0 = E1;
        r1 = keep_inside(&E1, E1.last_enc, 0, fin);
        r0 = ref_keep_inside(&E0, E0.last_enc);
        check(r1 == r0 && same(E1.x, E0.x, sizeof E1.x) && same(E1.P, E0.P, sizeof E1.P), "keep_inside", t);
    }
}

/* an NA × NA covariance: random_P's kind of matrix on the first NX, the rest sparse; now and then an
   entry huge, infinite or NaN (the general paths) */
static void random_aug(real *Pa, real scale, long t) {
    real P[NX * NX];
    int i, j;
    random_P(P, scale);
    for (i = 0; i < NA; i++)
        for (j = 0; j < NA; j++) Pa[i * NA + j] = i < NX && j < NX ? P[i * NX + j] : sparse(scale);
    if (t % 17 == 5) Pa[rnd() % (NA * NA)] = BIG;
    if (t % 29 == 7) Pa[rnd() % (NA * NA)] = (real)INFINITY;
    if (t % 31 == 9) Pa[rnd() % (NA * NA)] = nan_value();
}

static void coasting(void) {
    static real Pa1[NA * NA], Pa0[NA * NA];
    long t;
    int i, j;
    for (t = 0; t < 6000; t++) {
        real scale = t % 3 ? ONE : BIG / MTWIP_R(16.0), Jr[6][NA];
        meas_t em;
        int r1, r0;
        random_aug(Pa1, scale, t);
        memcpy(Pa0, Pa1, sizeof Pa0);
        for (i = 0; i < 6; i++) /* J's rows; every other time zero at the columns the differences skip */
            for (j = 0; j < NA; j++)
                Jr[i][j] = t % 2 && (j == PS || j == AL || j == C0 || j == H0) && i >= 4 ? ZERO : sparse(MTWIP_R(2.0));
        if (t % 4 == 1)
            for (i = 0; i < 6; i++) Jr[i][C0] = t % 8 == 1 ? ZERO : -ZERO;
        aug_jpj(Pa1, Jr);
        ref_aug_jpj(Pa0, Jr);
        check(same_r(Pa1, Pa0, NA * NA), "aug_jpj", t);
        /* the augmented update: h_row's H (the unrolled sums), or with a zero or an extra column */
        memset(&E1, 0, sizeof E1);
        random_aug(E1.aug, t % 3 ? ONE : BIG / MTWIP_R(16.0), t + 3);
        for (i = 0; i < NX; i++) {
            E1.x[i] = uni();
            E1.consider[i] = (uint8_t)(rnd() % 3 == 0);
        }
        for (i = 0; i < 2; i++) {
            E1.w[i] = uni();
            E1.w_prev[i] = uni();
        }
        for (i = 0; i < NK; i++) E1.dp[i] = uni();
        random_meas(&em, t % 5 ? ONE : BIG);
        if (t % 6 == 2) em.H[0][AL] = t % 12 == 2 ? ZERO : -ZERO;   /* four columns */
        if (t % 6 == 4) em.H[em.dof - 1][SY] = uni();                /* six: the general sums */
        E0 = E1;
        r1 = coast_update(&E1, &em);
        r0 = ref_coast_update(&E0, &em);
        check(r1 == r0 && same_r(E1.x, E0.x, NX) && same_r(E1.w, E0.w, 2) && same_r(E1.w_prev, E0.w_prev, 2) &&
                  same_r(E1.dp, E0.dp, NK) && same_r(E1.aug, E0.aug, NA * NA) && same_r(E1.P, E0.P, NX * NX),
              "coast_update", t);
    }
}

int main(void) {
    medians();
    products();
    coasting();
    if (bad) return 1;
    printf("ok: %ld comparisons (%ld updates on the fast path to the end)\n", trials, fast);
    return 0;
}
"""


@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_the_arranged_arithmetic_gives_the_plain_loops_bits(precision, tmp_path):
    _write(load_scenario("paper-exp3").run_spec("it2").build_estimator(), precision, tmp_path)
    (tmp_path / "unit.c").write_text(UNIT)
    for slack in (None, -1000):  # -1000: select_kth's heap from its first round on
        exe = tmp_path / "unit"
        flags = [] if slack is None else [f"-DMTWIP_EKF_SELECT_SLACK={slack}"]
        r = subprocess.run([COMPILERS[0], *STRICT, *flags, "-I", str(tmp_path), str(tmp_path / "unit.c"), "-o",
                            str(exe), "-lm"], capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        r = subprocess.run([str(exe)], capture_output=True, text=True, timeout=120)
        assert r.returncode == 0 and r.stdout.startswith("ok"), r.stdout + r.stderr


def test_the_lean_arithmetic_is_the_same_filter_on_a_log_the_twin_did_not_write(tmp_path):
    """The independent simulator's log (tests/foreign/robot_sim.py, its gyro clipping as the robot
    swings: the model stands in for the clipped axis) replayed through the exact and the lean float64
    exports of paper-exp1's EKF: the same estimates to 1e-6 (measured: 4.2e-8 rad/s over 4 s)."""
    import csv

    from click.testing import CliRunner

    from foreign.robot_sim import generate
    from twin.cli import main
    from twin.workflows.export import export

    log = tmp_path / "clip"
    generate(log, "A", 0, variant="clip", duration=4.0)
    kinds = []
    for arithmetic in ekf_export.ARITHMETICS:
        d = tmp_path / arithmetic
        export("paper-exp1", "it2", "ekf", "float64", d, seconds=0.05, arithmetic=arithmetic)
        kinds.append(f"export:{d}")
    r = CliRunner().invoke(main, ["replay", str(log), "--estimator", ",".join(kinds), "--out", str(tmp_path / "r")])
    assert r.exit_code == 0, r.output
    assert "the gyro clipped" in r.output  # the log holds clipped gyro samples: coasting steps
    by = {}
    for row in list(csv.reader((tmp_path / "r" / "estimates.csv").open()))[1:]:
        by.setdefault(row[1], []).append([float(v) for v in row[3:]])
    exact, lean = (np.array(by[k]) for k in kinds)
    assert len(exact) > 700
    worst = np.abs(lean - exact).max()
    assert 0 < worst <= LEAN_TOLERANCE, worst
