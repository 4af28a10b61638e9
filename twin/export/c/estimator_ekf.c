/* The twin's EKF (estimation/ekf.py EKFEstimator) as the twin runs it by default: the IMU-driven
   step of the compiled kernel (estimation/_ekf.c advance), the coasting step where equation (1)
   stands in for the IMU (estimation/ekf_filter.py Coasting), the sensor front end
   (estimation/ekf_frontend.py), the fusion step's decisions (estimation/ekf_fusion.py), the
   policies (estimation/ekf_policies.py: the gates, the accelerometer test, the truncation into an
   unchanged count, the latency watch) and the forward prediction across the latency. Every sum runs
   in the order of the path it ports (the kernel's C loops, or the Python path's ascending-index
   products of estimation/detlinalg.py), so that the float64 build gives the twin's numbers bit for
   bit when compiled without FMA contraction (-ffp-contract=off).

   Where that costs time on a microcontroller the arithmetic is arranged, never changed: the products
   of the covariance's prediction and update and of the innovation leave out the terms whose factor is an
   exact zero of F's, H's or I − K H's structure when every number involved is finite (each such term is
   ±0, and a sum that starts at +0 is never −0, so adding ±0 leaves it as it is; otherwise the full sums),
   their sums run in twelve accumulators each taking its terms in the original order, the latency watch's
   medians come from a selection instead of a sort (the same order statistic, a zero's sign as the stable
   sort leaves it) and its command differences are formed once per check. The coasting step's products
   take the same care: J Pa Jᵀ leaves out the columns where J's six nontrivial rows are all zero, the six
   rows' sums side by side; the augmented update's (I − K H) Pa (I − K H)ᵀ runs over H's nonzero columns and
   the diagonal's 1 in its place (I − K H's other entries are exact zeros and ones when K is finite), and
   K R Kᵀ's entries are +0 where a row of K is zero; the model's differences for the accelerometer's scale
   factors, which the model's state does not read, reuse its sample.

   Copied by twin export as mtwip_estimator.c; the configuration (every number of the filter) is
   generated in place of the marker below (twin/export/ekf.py). Only the default sampling is
   ported (IMU rows the means over their period, commands held, a constant period). */
#include <math.h>
#include <stdint.h>
#include <string.h>
#include "mtwip.h"

/* @MTWIP_EKF_CONFIG@ */

#ifndef MTWIP_ERFC
#if defined(MTWIP_FLOAT32) && MTWIP_FLOAT32
#define MTWIP_ERFC erfcf
#else
#define MTWIP_ERFC erfc
#endif
#endif
#ifndef MTWIP_POW
#if defined(MTWIP_FLOAT32) && MTWIP_FLOAT32
#define MTWIP_POW powf
#else
#define MTWIP_POW pow
#endif
#endif
#ifndef MTWIP_HYPOT
#if defined(MTWIP_FLOAT32) && MTWIP_FLOAT32
#define MTWIP_HYPOT hypotf
#else
#define MTWIP_HYPOT hypot
#endif
#endif

typedef mtwip_real real;
typedef mtwip_ekf_model_t model_t;

/* a function kept out of its caller: its locals then stay off the caller's deeper calls' stack (the
   worst stack is what a microcontroller's RAM must hold) */
#if defined(__GNUC__)
#define NOINLINE __attribute__((noinline))
#else
#define NOINLINE
#endif

#define NX MTWIP_EKF_NX
#define NA MTWIP_EKF_NA
#define NK MTWIP_EKF_NK
#define RING MTWIP_EKF_RING
#define ZERO MTWIP_R(0.0)
#define ONE MTWIP_R(1.0)
#define HALF MTWIP_R(0.5)
#define TWO MTWIP_R(2.0)
#define EMPTY INT32_MIN

enum { TH, PS, V, AL, BY, BZ, C0, SY, H0, SZ, SAX, SAZ }; /* (TH, PS, V, AL first: cov_predict) */
enum { ITH, ITHD, IPS, IPSD, IAL, IALD };
enum { EKF_OK = 0, EKF_FAILED = 1 }; /* EKF_FAILED: where the Python path raises (a singular solve) */

static const mtwip_ekf_config_t *const C = &mtwip_ekf_config;

/* the rows of the strapdown step's F and noise map that are not the identity's, TH, AL, V, PS: their
   index among them (−1: an identity row) */
static const int ROW_OF[NX] = {0, 3, 2, 1, -1, -1, -1, -1, -1, -1, -1, -1};

static real nan_value(void) { return (real)NAN; }

static int finite_n(const real *v, int n) {
    int i;
    for (i = 0; i < n; i++)
        if (!MTWIP_ISFINITE(v[i])) return 0;
    return 1;
}

/* 1 if the NX × NX matrix P is all finite: its sum is (0 also where a sum of finite numbers overflows; the
   callers then take their general path, which gives the same numbers) */
static int finite_matrix(const real *P) {
    real s0 = ZERO, s1 = ZERO, s2 = ZERO, s3 = ZERO;
    int i;
    for (i = 0; i < NX * NX; i += 4) { /* (NX * NX: a multiple of 4) */
        s0 += P[i];
        s1 += P[i + 1];
        s2 += P[i + 2];
        s3 += P[i + 3];
    }
    return MTWIP_ISFINITE((s0 + s1) + (s2 + s3)) != 0;
}

static int packed(int i, int j) { /* the upper triangle, by rows */
    if (i > j) {
        int t = i;
        i = j;
        j = t;
    }
    return i * NX - i * (i - 1) / 2 + (j - i);
}

#if MTWIP_EKF_LEAN
static real pow2(real a) { return a * a; } /* (the lean build need not round as the Python path does) */
#else
/* a square as the Python path takes it, x ** 2: libm's pow, which differs from x * x in the last bit
   for about one argument in a thousand (the kernel's C multiplies) */
static real pow2(real a) { return MTWIP_POW(a, C->square); }
#endif

/* ---- the model (estimation/model.py, twin/plant/analytic.py; the kernel's rhs, model_step, delivered).
   py: the Python path's arithmetic (x ** 2), else the kernel's -------------------------------------- */
/* sin and cos of a */
static void sin_cos(real a, real *sn, real *cs) {
    *sn = MTWIP_SIN(a);
    *cs = MTWIP_COS(a);
}

static void rhs(const model_t *p, const real *s, real ul, real ur, real *d, int py) {
    real th = s[0], thd = s[1], psd = s[3], ald = s[5], sn = MTWIP_SIN(th), cs = MTWIP_COS(th);
    real drive = TWO * p->d_b * (thd - psd);
    real u = ul + ur;
    real rhs1 = p->m12 * (thd * thd + ald * ald) * sn - TWO * p->d_w * psd + drive + u + ZERO;
    real rhs2 = p->n_bla * ald * ald * sn * cs + p->g_b * sn - drive - u + ZERO;
    real mc = p->m12 * cs;
    real det = p->m11 * p->m22 - (py ? pow2(mc) : mc * mc);
    real yaw = -TWO * p->n_bla * ald * thd * sn * cs - p->m12 * ald * psd * sn - p->yaw_damping * ald +
               p->b_r * (ur - ul) + ZERO;
    d[0] = thd;
    d[1] = (p->m11 * rhs2 - p->m12 * cs * rhs1) / det;
    d[2] = psd;
    d[3] = (p->m22 * rhs1 - p->m12 * cs * rhs2) / det;
    d[4] = ald;
    d[5] = yaw / (p->m33 + p->n_bla * sn * sn);
}

/* RK4 over `periods` control periods; inc (NULL: none): the increments of s summed on their own */
static void model_step(const model_t *p, real *s, real tl, real tr, int periods, int py, real *inc) {
    real k1[6], k2[6], k3[6], k4[6], y[6], dt = p->dt / (real)p->msub;
    int n = periods * (int)p->msub, q, i;
    for (q = 0; q < n; q++) {
        rhs(p, s, tl, tr, k1, py);
        for (i = 0; i < 6; i++) y[i] = s[i] + HALF * dt * k1[i];
        rhs(p, y, tl, tr, k2, py);
        for (i = 0; i < 6; i++) y[i] = s[i] + HALF * dt * k2[i];
        rhs(p, y, tl, tr, k3, py);
        for (i = 0; i < 6; i++) y[i] = s[i] + dt * k3[i];
        rhs(p, y, tl, tr, k4, py);
        for (i = 0; i < 6; i++) {
            real d = (dt / MTWIP_R(6.0)) * (k1[i] + TWO * k2[i] + TWO * k3[i] + k4[i]);
            s[i] = s[i] + d;
            if (inc) inc[i] += d;
        }
    }
}

static real clip(real v, real lim) { return v > lim ? lim : (v < -lim ? -lim : v); }

static void delivered(const model_t *p, const real *s, real ul, real ur, real *tl, real *tr) {
    if (!p->has_motor) {
        *tl = ul;
        *tr = ur;
        return;
    }
    ul = clip(ul, p->i_tau);
    ur = clip(ur, p->i_tau);
    if (p->compensates) {
        real w = s[IPSD] - s[ITHD], h = p->b_r * s[IALD];
        ul += p->c_e * (w - h);
        ur += p->c_e * (w + h);
    }
    *tl = clip(ul, p->tau_max);
    *tr = clip(ur, p->tau_max);
}

/* the IMU sample equation (1) predicts `periods` periods after s (true rates and specific force:
   raw) and the variances the torque's uncertainty adds (gyro, accelerometer). py: the torque's
   variance as the Python path makes it (its σ squared, EstimatorModel.synthetic_imu), else as the
   kernel's synthetic (the variance itself). With the configuration's `increments` (the float32 build)
   the sample is formed from the RK4 increments, not from differences of the states a period apart,
   which in float32 lose the rates to rounding (α of a few rad differenced over 5 ms: 2.4e-5 rad/s) */
static void synthetic_raw(const model_t *p, const real *s, const real *cmd, int periods, int py, real *raw,
                          real *var) {
    real s1[6], inc[6], tl, tr, var_tau;
    int i;
    real t, xi = p->xi, zi = p->zi, r = p->r;
    real sn0, cs0, sn1, cs1, dx0, dz0, dx1, dz1, u0, w0, u1, w1, ald, Fx, Fz, mc, det, dthdd, dpsdd, a, b;
    real mid, smid = ZERO, cmid = ZERO;
    delivered(p, s, cmd[0], cmd[1], &tl, &tr);
    memcpy(s1, s, sizeof s1);
    for (i = 0; i < 6; i++) inc[i] = ZERO;
    model_step(p, s1, tl, tr, periods, py, C->increments ? inc : NULL);
    t = (real)periods * p->dt;
    sin_cos(s[ITH], &sn0, &cs0);
    sin_cos(s1[ITH], &sn1, &cs1);
    dx0 = xi * cs0 + zi * sn0;
    dz0 = -xi * sn0 + zi * cs0;
    dx1 = xi * cs1 + zi * sn1;
    dz1 = -xi * sn1 + zi * cs1;
    mid = HALF * (s[ITH] + s1[ITH]);
    if (C->increments) { /* u1 − u0 = r Δψ̇ + Δθ̇ dz1 + θ̇0 (dz1 − dz0), w1 − w0 = −(Δθ̇ dx1 + θ̇0 (dx1 − dx0)) */
        real hs = MTWIP_SIN(HALF * inc[ITH]), dsn, dcs, ddx, ddz;
        sin_cos(mid, &smid, &cmid);
        dsn = TWO * cmid * hs;
        dcs = -TWO * smid * hs;
        ddx = xi * dcs + zi * dsn;
        ddz = -xi * dsn + zi * dcs;
        (void)dx0;
        (void)dz0;
        ald = inc[IAL] / t;
        Fx = (r * inc[IPSD] + inc[ITHD] * dz1 + s[ITHD] * ddz) / t - ald * ald * dx1;
        Fz = -(inc[ITHD] * dx1 + s[ITHD] * ddx) / t + p->g;
        raw[0] = inc[ITH] / t;
    } else {
        u0 = r * s[IPSD] + s[ITHD] * dz0;
        w0 = -s[ITHD] * dx0;
        u1 = r * s1[IPSD] + s1[ITHD] * dz1;
        w1 = -s1[ITHD] * dx1;
        ald = (s1[IAL] - s[IAL]) / t;
        Fx = (u1 - u0) / t - ald * ald * dx1;
        Fz = (w1 - w0) / t + p->g;
        raw[0] = (s1[ITH] - s[ITH]) / t;
    }
    raw[2] = Fx * cs1 - Fz * sn1;
    raw[3] = Fx * sn1 + Fz * cs1;
    raw[1] = ald * (C->increments ? cmid : MTWIP_COS(mid));
    mc = p->m12 * cs1;
    det = p->m11 * p->m22 - (py ? pow2(mc) : mc * mc);
    dthdd = -(p->m11 + p->m12 * cs1) / det;
    dpsdd = (p->m22 + p->m12 * cs1) / det;
    a = HALF * dthdd * t;
    b = r * dpsdd + zi * dthdd;
    if (py) { /* EstimatorModel.torque_sigma, squared */
        real sl = MTWIP_SQRT(pow2(p->sigma_tau) + pow2(p->tol * tl));
        real sr = MTWIP_SQRT(pow2(p->sigma_tau) + pow2(p->tol * tr));
        var_tau = pow2(sl) + pow2(sr);
        var[0] = pow2(a) * var_tau;
        var[1] = pow2(b) * var_tau;
    } else { /* the kernel's torque_var */
        real al = p->tol * tl, ar = p->tol * tr;
        var_tau = (p->sigma_tau * p->sigma_tau + al * al) + (p->sigma_tau * p->sigma_tau + ar * ar);
        var[0] = a * a * var_tau;
        var[1] = b * b * var_tau;
    }
}

/* the model's sample as the sensor would read it with the state's scale factors and biases */
static void scaled(const real *x, const real *raw, const real *var, real *smp, real *extra) {
    smp[0] = (ONE + x[SY]) * raw[0] + x[BY];
    smp[1] = (ONE + x[SZ]) * raw[1] + x[BZ];
    smp[2] = (ONE + x[SAX]) * raw[2];
    smp[3] = (ONE + x[SAZ]) * raw[3];
    extra[0] = extra[1] = var[0];
    extra[2] = extra[3] = var[1];
}

/* [θ, θ̇, ψ, ψ̇, α, α̇] of state x with the gyro's last two rates w, wp (StrapdownFilter.state6) */
static void state6(const real *x, const real *w, const real *wp, real *s) {
    real wy = MTWIP_R(1.5) * w[0] - HALF * wp[0], wz = MTWIP_R(1.5) * w[1] - HALF * wp[1];
    real th = x[TH];
    real thd = (wy - x[BY]) / (ONE + x[SY]);
    real ald = (wz - x[BZ]) / ((ONE + x[SZ]) * MTWIP_COS(th));
    real dz = -C->xi * MTWIP_SIN(th) + C->zi * MTWIP_COS(th);
    s[0] = th;
    s[1] = thd;
    s[2] = x[PS];
    s[3] = (x[V] - thd * dz) / C->r;
    s[4] = x[AL];
    s[5] = ald;
}

/* StrapdownFilter.synthetic of state x with gyro history w, wp */
static void synthetic(const real *x, const real *w, const real *wp, const real *cmd, int py, real *smp, real *extra) {
    real s[6], raw[4], var[2];
    state6(x, w, wp, s);
    synthetic_raw(&C->model, s, cmd, (int)C->every, py, raw, var);
    scaled(x, raw, var, smp, extra);
}

/* ---- the strapdown step ------------------------------------------------------------------ */
/* F's rows TH, AL, V, PS (the others are the identity's), the noise map's, and Q on them */
typedef struct {
    real F4[4][NX], L[4][4], Q4[4][4];
} step_t;

/* one strapdown step (StrapdownFilter.propagate and the kernel's propagate, which differ in one
   product's association: py selects the Python one) */
static void propagate(const real *x, const real *smp, const real *extra, int py, real *x1, step_t *st) {
    real wy = smp[0], wz = smp[1], fx = smp[2], fz = smp[3];
    real dt = C->dt, r = C->r, xi = C->xi, zi = C->zi;
    real th = x[TH], v = x[V];
    real q = ONE / (ONE + x[SY]), qz = ONE / (ONE + x[SZ]), qax = ONE / (ONE + x[SAX]), qaz = ONE / (ONE + x[SAZ]);
    real thm = (wy - x[BY]) * q;
    real th1 = th + dt * thm;
    real thb = HALF * (th + th1);
    real s0 = MTWIP_SIN(th), c0 = MTWIP_COS(th), s1 = MTWIP_SIN(th1), c1 = MTWIP_COS(th1);
    real cb = MTWIP_COS(thb), tb = MTWIP_TAN(thb);
    real ad = (wz - x[BZ]) * qz / cb;
    real dx0 = xi * c0 + zi * s0, dz0 = -xi * s0 + zi * c0;
    real dx1 = xi * c1 + zi * s1, dz1 = -xi * s1 + zi * c1;
    real fxt = fx * qax, fzt = fz * qaz;
    real Fx = c1 * fxt + s1 * fzt, Fz = -s1 * fxt + c1 * fzt;
    real v1 = v + dt * (Fx + ad * ad * dx1);
    real ith1[4], iad[4], iFx[4], iv1[4], k, a2, a3, hv, var[4];
    int j, a, b;
    memcpy(x1, x, NX * sizeof(real));
    x1[TH] = th1;
    x1[AL] = x[AL] + dt * ad;
    x1[V] = v1;
    x1[PS] = x[PS] + (HALF * dt * (v + v1) - dx1 + dx0) / r;

    /* F's rows column by column (each entry's operations as the kernel's, one column's θ₁, α̇, F_x, v₁
       derivatives at a time: no arrays of them on the stack) */
    k = ad * tb * HALF;
    a2 = TWO * ad * dx1;
    a3 = ad * ad * dz1;
    for (j = 0; j < NX; j++) {
        real dth1 = j == TH ? ONE : j == BY ? -dt * q : j == SY ? (py ? -(dt * (thm * q)) : -dt * thm * q) : ZERO;
        real dad = k * ((j == TH ? ONE : ZERO) + dth1), dFx = Fz * dth1, dv1;
        if (j == BZ) dad -= qz / cb;
        if (j == SZ) dad -= ad * qz;
        if (j == SAX) dFx -= c1 * fxt * qax;
        if (j == SAZ) dFx -= s1 * fzt * qaz;
        dv1 = (j == V ? ONE : ZERO) + dt * (dFx + a2 * dad + a3 * dth1);
        st->F4[0][j] = dth1;
        st->F4[1][j] = (j == AL ? ONE : ZERO) + dt * dad;
        st->F4[2][j] = dv1;
        st->F4[3][j] = (j == PS ? ONE : ZERO) +
                       (HALF * dt * ((j == V ? ONE : ZERO) + dv1) - dz1 * dth1 + dz0 * (j == TH ? ONE : ZERO)) / r;
    }
    ith1[0] = dt * q;
    ith1[1] = ith1[2] = ith1[3] = ZERO;
    iad[0] = k * ith1[0];
    iad[1] = qz / cb;
    iad[2] = iad[3] = ZERO;
    iFx[0] = Fz * ith1[0];
    iFx[1] = ZERO;
    iFx[2] = c1 * qax;
    iFx[3] = s1 * qaz;
    for (j = 0; j < 4; j++) iv1[j] = dt * (iFx[j] + a2 * iad[j] + a3 * ith1[j]);
    for (j = 0; j < 4; j++) {
        st->L[0][j] = ith1[j];
        st->L[1][j] = dt * iad[j];
        st->L[2][j] = iv1[j];
        st->L[3][j] = (HALF * dt * iv1[j] - dz1 * ith1[j]) / r;
    }
    var[0] = var[1] = C->g_var;
    var[2] = var[3] = C->a_var;
    for (j = 0; j < 4; j++) var[j] = (py ? var[j] : ONE * var[j]) + (extra ? extra[j] : ZERO);
    for (a = 0; a < 4; a++)
        for (b = 0; b < 4; b++) {
            real s = ZERO;
            for (j = 0; j < 4; j++) s += st->L[a][j] * var[j] * st->L[b][j];
            st->Q4[a][b] = s;
        }
    hv = dt * (v1 - v) / r;
    st->Q4[3][3] += hv * hv * C->trapezoid_var;
}

/* Q's entry (i, j): the 4 × 4 block, and the gyro biases' random walk */
static real q_entry(const step_t *st, int i, int j) {
    int a = ROW_OF[i], b = ROW_OF[j];
    if (a >= 0 && b >= 0) return st->Q4[a][b];
    if (i == j && (i == BY || i == BZ)) return C->bias_q;
    return ZERO;
}

/* an operation on each of the twelve accumulators a0 … a11 (NX = 12) */
#define EACH12(M) M(0) M(1) M(2) M(3) M(4) M(5) M(6) M(7) M(8) M(9) M(10) M(11)
/* P (NX × NX) = the augmented covariance's first NX rows and columns: row by row, each unrolled (a
   loop here becomes a library call per row on some compilers, slower than the copy itself) */
static void block_of(real *P, const real *Pa) {
    int i;
    for (i = 0; i < NX; i++) {
        real *d = P + i * NX;
        const real *a = Pa + i * NA;
#define CP(r) d[r] = a[r];
        EACH12(CP)
#undef CP
    }
}
#define ACC_DECL(r) real a##r = ZERO;
#define ACC_COL(r) a##r += p * c[r];
#define ACC_DIAG(r) \
    case r:         \
        a##r += p * dg[r]; \
        break;
#define ACC_KRK(r) a##r += kr * K[r][b];

/* Pp = F P Fᵀ + Q (the kernel's and estimation.ekf_steps' cov_predict); pfin: P is finite. Every entry is
   the kernel's sum over k ascending from +0; with P finite (and A = F P too, for the second product) the
   sums leave out the terms whose F entry is zero (±0): such a term is ±0, and a sum that starts at +0 is
   never −0, so adding ±0 leaves it as it is. Returns 1 if Pp is finite */
static int cov_predict(const step_t *st, const real *P, real *Pp, int pfin) {
    static const real zero4[4] = {ZERO, ZERO, ZERO, ZERO};
    real A4[4][NX], chk = ZERO;
    uint8_t nz[4][NX], any[NX];
    int cnt[4], n_any = 0, a, i, j, k, t;
    for (a = 0; a < 4; a++) {
        cnt[a] = 0;
        for (k = 0; k < NX; k++)
            if (!pfin || st->F4[a][k] != ZERO) nz[a][cnt[a]++] = (uint8_t)k;
    }
    for (a = 0; a < 4; a++) { /* A's rows TH, AL, V, PS (F's others: the identity's) */
        const real *F = st->F4[a];
        EACH12(ACC_DECL)
        for (t = 0; t < cnt[a]; t++) {
            const real p0 = F[nz[a][t]], *c = P + nz[a][t] * NX;
#define ACC_ROW(r) a##r += p0 * c[r];
            EACH12(ACC_ROW)
#undef ACC_ROW
        }
#define ACC_PUT(r) \
    A4[a][r] = a##r; \
    chk += a##r;
        EACH12(ACC_PUT)
#undef ACC_PUT
    }
    pfin = pfin && MTWIP_ISFINITE(chk);
    for (k = 0; k < NX; k++) /* the columns where some row of F4 is nonzero (all of them unless sparse) */
        if (!pfin || st->F4[0][k] != ZERO || st->F4[1][k] != ZERO || st->F4[2][k] != ZERO || st->F4[3][k] != ZERO)
            any[n_any++] = (uint8_t)k;
    chk = ZERO;
    for (i = 0; i < NX; i++) {
        const real *Ai = ROW_OF[i] >= 0 ? A4[ROW_OF[i]] : P + i * NX;
        real *Pi = Pp + i * NX, s0 = ZERO, s1 = ZERO, s2 = ZERO, s3 = ZERO; /* (A Fᵀ)[i] at F4's rows */
        const real *Qi = ROW_OF[i] >= 0 ? st->Q4[ROW_OF[i]] : zero4;
        if (MTWIP_EKF_LEAN && ROW_OF[i] < 0) { /* (F P Fᵀ)[i][F4's rows] = (F P)[F4's rows][i]: P is symmetric */
            s0 = A4[0][i];
            s1 = A4[1][i];
            s2 = A4[2][i];
            s3 = A4[3][i];
        } else
            for (t = 0; t < n_any; t++) {
                real v = Ai[any[t]];
                k = any[t];
                s0 += v * st->F4[0][k];
                s1 += v * st->F4[1][k];
                s2 += v * st->F4[2][k];
                s3 += v * st->F4[3][k];
            }
        /* + Q: its 4 × 4 block on F4's rows and columns (TH, AL, V, PS: ROW_OF), the gyro biases' random
           walk, +0 elsewhere (which the rows of F's identity rows take too, as the kernel's sums) */
        Pi[TH] = s0 + Qi[0];
        Pi[PS] = s3 + Qi[3];
        Pi[V] = s2 + Qi[2];
        Pi[AL] = s1 + Qi[1];
        for (j = 4; j < NX; j++) Pi[j] = Ai[j] + (i == j && (i == BY || i == BZ) ? C->bias_q : ZERO);
        for (j = 0; j < NX; j++) chk += Pi[j];
    }
    return MTWIP_ISFINITE(chk) != 0;
}

/* ---- the encoders' measurement ----------------------------------------------------------- */
typedef struct {
    int dof;
    real z[2], off[2], R[2], H[2][NX];
} meas_t;

/* a measurement's innovation against a state (x, P): y = z − (off + H x), P Hᵀ, S = H P Hᵀ + R */
typedef struct {
    real y[2], PHt[NX][2], S[2][2];
} innov_t;

/* wheel i's row of H: e = ψ − θ + c ∓ ((b/r)(α − α0) + h) */
static void h_row(int i, real *h) {
    real sgn = (real)(2 * i - 1);
    int j;
    for (j = 0; j < NX; j++) h[j] = ZERO;
    h[PS] = h[C0] = ONE;
    h[TH] = -ONE;
    h[AL] = sgn * C->b_r;
    h[H0] = sgn;
}

/* the innovation y = z − (off + H x), P Hᵀ and S = H P Hᵀ + R (the kernel's innovation); pfin: P is finite
   (−1: not known), and then P Hᵀ's sums skip the terms of H's zeros (±0 each: see cov_predict) */
static void innovation(const real *x, const real *P, const meas_t *em, int pfin, innov_t *in) {
    int a, b, i, j;
    if (pfin < 0) pfin = finite_matrix(P);
    for (a = 0; a < em->dof; a++) {
        const real *H = em->H[a];
        real hx = em->off[a];
        EACH12(ACC_DECL)
        for (j = 0; j < NX; j++) hx += H[j] * x[j];
        in->y[a] = em->z[a] - hx;
        for (j = 0; j < NX; j++) { /* P Hᵀ's column a: a_i = Σ_j P[i][j] H[j] */
            const real h = H[j], *c = P + j;
            if (pfin && h == ZERO) continue;
#define ACC_PH(r) a##r += c[r * NX] * h;
            EACH12(ACC_PH)
#undef ACC_PH
        }
#define ACC_PUT(r) in->PHt[r][a] = a##r;
        EACH12(ACC_PUT)
#undef ACC_PUT
    }
    for (a = 0; a < em->dof; a++)
        for (b = 0; b < em->dof; b++) {
            real s = ZERO;
            for (i = 0; i < NX; i++) s += em->H[a][i] * in->PHt[i][b];
            in->S[a][b] = s + (a == b ? em->R[a] : ZERO);
        }
}

enum { FIT_TEST = 1, FIT_PY = 2, FIT_FINITE = 4 };

/* the encoders' measurement against the prior (x, P) with the gyro's rates w, and its NIS (NaN:
   no count changed, dof 0). how: FIT_TEST, an unchanged count gives a row too (the IMU outlier test);
   FIT_PY, the Python path's squares; FIT_FINITE, P is known finite. *zero_div: the NIS's divisor is 0
   (where the Python path raises); the innovation into *out (NULL: not wanted) */
static real encoder_fit(const real *enc, const real *last, real T, const real *x, const real *w, const real *P,
                        int how, meas_t *em, int *zero_div, innov_t *out) {
    int test = how & FIT_TEST, py = how & FIT_PY;
    real dlt = C->delta, b_r = C->b_r, r = C->r;
    real th = x[TH];
    real thd = (w[0] - x[BY]) / (ONE + x[SY]);
    real dz = -C->xi * MTWIP_SIN(th) + C->zi * MTWIP_COS(th);
    real wheel = (x[V] - thd * dz) / r - thd;
    real spin = b_r * (w[1] - x[BZ]) / ((ONE + x[SZ]) * MTWIP_COS(th));
    real e = ONE + dz / r;
    real var_q = py ? P[V * NX + V] / pow2(r) + C->g_var * (pow2(e) + b_r * b_r)
                    : P[V * NX + V] / (r * r) + C->g_var * (e * e + b_r * b_r);
    innov_t own, *in = out ? out : &own;
    real det, (*S)[2] = in->S, *y = in->y;
    int i;
    em->dof = 0;
    if (zero_div) *zero_div = 0;
    for (i = 0; i < 2; i++) {
        int same = enc[i] == last[i], n;
        real sgn = (real)(2 * i - 1), cap = dlt * dlt / MTWIP_R(12.0);
        if (same && !test) continue;
        n = em->dof++;
        if (same) {
            em->z[n] = enc[i];
            em->off[n] = -sgn * b_r * C->alpha0;
            em->R[n] = cap;
        } else {
            int up = enc[i] > last[i];
            real d = MTWIP_FABS(wheel + sgn * spin) * T, R;
            if (d > dlt) d = dlt;
            if (!up) d = -d;
            em->z[n] = up ? enc[i] - HALF * dlt : enc[i] + HALF * dlt;
            em->off[n] = -sgn * b_r * C->alpha0 - HALF * d;
            R = d * d / MTWIP_R(12.0) + var_q * T * T / MTWIP_R(3.0);
            em->R[n] = R < cap ? R : cap;
        }
        h_row(i, em->H[n]);
    }
    if (em->dof == 0) return nan_value();
    innovation(x, P, em, how & FIT_FINITE ? 1 : -1, in);
    if (em->dof == 1) {
        if (zero_div && S[0][0] == ZERO) *zero_div = 1;
        return y[0] * y[0] / S[0][0];
    }
    det = S[0][0] * S[1][1] - S[0][1] * S[1][0];
    if (zero_div && det == ZERO) *zero_div = 1;
    return (y[0] * (S[1][1] * y[0] - S[0][1] * y[1]) + y[1] * (-S[1][0] * y[0] + S[0][0] * y[1])) / det;
}

/* (I − K H)[i][k] of the kernel's update */
static real ikh12(real K[NX][2], const meas_t *em, int i, int k) {
    real s = i == k ? ONE : ZERO;
    int a;
    for (a = 0; a < em->dof; a++) s -= K[i][a] * em->H[a][k];
    return s;
}

#define ACT_MAX 6 /* H's nonzero columns the fast update takes (the encoders': 5) */

/* the kernel's Kalman update (Joseph form, the consider states' gain rows zeroed), in place:
   (I − K H) P column by column, then its product with (I − K H)ᵀ row by row; −1 if S is not
   positive. pre: em's innovation at x, P (NULL: formed here); pfin: P is finite (−1: not known).
   Returns 1 in *pfin_out (if not NULL) if the updated P is known to be finite.

   Every entry of the products is the kernel's sum over k ascending from +0, bit for bit. With P and K
   finite the sums leave out the terms of (I − K H)'s zeros off H's columns: (I − K H)[i][k] for k neither
   one of H's nonzero columns nor i is 0 − K[i]·(±0) = +0 exactly, its term ±0, and a sum that starts at +0
   is never −0, so that adding ±0 leaves it unchanged. The second product leaves them out only where
   A = (I − K H) P came out finite too. Otherwise (a non-finite number anywhere) the kernel's full sums.
   The fast sums run with twelve accumulators (one per row of a column, or column of a row) over k
   ascending: each accumulator takes its terms in the kernel's order */
static int kalman_update(real *x, real *P, const meas_t *em, const uint8_t *consider, int pfin, int *pfin_out,
                         const innov_t *pre) {
    int m = em->dof, i, j, k, a, b, n_act = 0, fast;
    real Si[2][2], K[NX][2], chk = ZERO, *tmp;
    innov_t own;
    const innov_t *in = pre;
    real ikhT[ACT_MAX][NX], dg[NX]; /* (I − K H)'s columns at H's nonzero columns; its diagonal */
    signed char slot[NX];           /* column k's row in ikhT, −1: not one of H's */
    tmp = dg;                       /* (the general path's row or column: dg is the fast path's) */
    if (pfin < 0) pfin = finite_matrix(P);
    if (pfin_out) *pfin_out = 0;
    if (!in) {
        innovation(x, P, em, pfin, &own);
        in = &own;
    }
    if (m == 1) {
        if (!(in->S[0][0] > ZERO)) return -1;
        Si[0][0] = ONE / in->S[0][0];
    } else {
        real det = in->S[0][0] * in->S[1][1] - in->S[0][1] * in->S[1][0];
        if (!(det > ZERO)) return -1;
        Si[0][0] = in->S[1][1] / det;
        Si[1][1] = in->S[0][0] / det;
        Si[0][1] = -in->S[0][1] / det;
        Si[1][0] = -in->S[1][0] / det;
    }
    for (i = 0; i < NX; i++)
        for (b = 0; b < m; b++) {
            real s = ZERO;
            for (a = 0; a < m; a++) s += in->PHt[i][a] * Si[a][b];
            K[i][b] = consider[i] ? ZERO : s;
            chk += K[i][b];
        }
    for (i = 0; i < NX; i++)
        for (a = 0; a < m; a++) x[i] += K[i][a] * in->y[a];
    fast = pfin && MTWIP_ISFINITE(chk);
    for (k = 0; k < NX; k++) { /* H's nonzero columns */
        int on = 0;
        for (a = 0; a < m; a++) on |= em->H[a][k] != ZERO;
        slot[k] = -1;
        if (!on) continue;
        if (n_act == ACT_MAX) {
            fast = 0;
            break;
        }
        slot[k] = (signed char)n_act++;
    }
    if (!fast) { /* the kernel's sums in full */
        for (j = 0; j < NX; j++) { /* A = (I − K H) P */
            for (i = 0; i < NX; i++) {
                real s = ZERO;
                for (k = 0; k < NX; k++) s += ikh12(K, em, i, k) * P[k * NX + j];
                tmp[i] = s;
            }
            for (i = 0; i < NX; i++) P[i * NX + j] = tmp[i];
        }
        for (i = 0; i < NX; i++) { /* P = A (I − K H)ᵀ + K R Kᵀ */
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
    for (k = 0; k < NX; k++) { /* ikh12's entries */
        if (slot[k] >= 0) {
            real *c = ikhT[slot[k]];
            for (i = 0; i < NX; i++) {
                real v = i == k ? ONE : ZERO;
                for (a = 0; a < m; a++) v -= K[i][a] * em->H[a][k];
                c[i] = v;
            }
            dg[k] = c[k];
        } else {
            real v = ONE;
            for (a = 0; a < m; a++) v -= K[k][a] * em->H[a][k];
            dg[k] = v;
        }
    }
    chk = ZERO;
    for (j = 0; j < NX; j++) { /* A = (I − K H) P, column by column: a_i = Σ_k (I − K H)[i][k] P[k][j] */
        EACH12(ACC_DECL)
        for (k = 0; k < NX; k++) {
            real p = P[k * NX + j];
            if (slot[k] >= 0) {
                const real *c = ikhT[slot[k]];
                EACH12(ACC_COL)
            } else
                switch (k) { EACH12(ACC_DIAG) }
        }
#define ACC_PUT_COL(r) \
    P[r * NX + j] = a##r; \
    chk += a##r;
        EACH12(ACC_PUT_COL)
#undef ACC_PUT_COL
    }
    fast = MTWIP_ISFINITE(chk) != 0;
    chk = ZERO;
    for (i = 0; i < NX; i++) { /* P = A (I − K H)ᵀ + K R Kᵀ, row by row: a_j = Σ_k A[i][k] (I − K H)[j][k] + … */
        real *Ai = P + i * NX;
        if (!fast) {
            for (j = 0; j < NX; j++) {
                real s = ZERO;
                for (k = 0; k < NX; k++) s += Ai[k] * ikh12(K, em, j, k);
                for (a = 0; a < m; a++) s += K[i][a] * em->R[a] * K[j][a];
                tmp[j] = s;
            }
            for (j = 0; j < NX; j++) chk += Ai[j] = tmp[j];
        } else {
            EACH12(ACC_DECL)
            for (k = 0; k < NX; k++) {
                real p = Ai[k];
                if (slot[k] >= 0) {
                    const real *c = ikhT[slot[k]];
                    EACH12(ACC_COL)
                } else
                    switch (k) { EACH12(ACC_DIAG) }
            }
            for (b = 0; b < m; b++) {
                real kr = K[i][b] * em->R[b];
                EACH12(ACC_KRK)
            }
#define ACC_PUT_ROW(r) \
    Ai[r] = a##r;      \
    chk += a##r;
            EACH12(ACC_PUT_ROW)
#undef ACC_PUT_ROW
        }
    }
    if (pfin_out) *pfin_out = MTWIP_ISFINITE(chk) != 0;
    return 0;
}

/* (z, R) of the measurement whose update truncates the prior N(w, s2) to [lo, hi]; 0: nothing to do
   (truncated_measurement) */
static int truncated_measurement(real w, real s2, real lo, real hi, real gate, real *z, real *R) {
    real s, a, b, sign = ONE, pa, pb, Z, mean, var, k;
    if (!(s2 > ZERO) || (lo <= w && w < hi)) return 0;
    s = MTWIP_SQRT(s2);
    a = (lo - w) / s;
    b = (hi - w) / s;
    if (b <= ZERO) {
        real t = a;
        a = -b;
        b = -t;
        sign = -ONE;
    }
    if (a > gate) return 0;
    pa = MTWIP_EXP(-HALF * a * a) / C->sqrt_2pi;
    pb = MTWIP_EXP(-HALF * b * b) / C->sqrt_2pi;
    Z = HALF * (MTWIP_ERFC(a / C->sqrt_2) - MTWIP_ERFC(b / C->sqrt_2));
    if (!(Z > ZERO)) return 0;
    mean = (pa - pb) / Z;
    var = ONE + (a * pa - b * pb) / Z - mean * mean;
    if (!(var > ZERO && var < ONE)) return 0;
    k = ONE - var;
    *z = w + sign * s * mean / k;
    *R = s2 * var / k;
    return 1;
}

/* ---- the filter's health --------------------------------------------------------------------- */
static int healthy(const real *x, const real *P) {
    int i;
    for (i = 0; i < NX; i++)
        if (!MTWIP_ISFINITE(x[i]) || !(P[i * NX + i] > ZERO)) return 0;
    if (finite_matrix(P)) return 1;
    for (i = 0; i < NX * NX; i++)
        if (!MTWIP_ISFINITE(P[i])) return 0;
    return 1;
}

/* every pivot of W's LDLᵀ elimination (no pivoting) positive and finite; W (a copy of P) is overwritten.
   The lean build eliminates on the upper triangle (W is symmetric) */
static int positive_definite(real *W) {
    int i, j, k;
    for (k = 0; k < NX; k++) {
        real d = W[k * NX + k];
        if (!(d > ZERO && MTWIP_ISFINITE(d))) return 0;
        for (i = k + 1; i < NX; i++) {
            real f = (MTWIP_EKF_LEAN ? W[k * NX + i] : W[i * NX + k]) / d;
            for (j = MTWIP_EKF_LEAN ? i : k + 1; j < NX; j++) W[i * NX + j] -= f * W[k * NX + j];
        }
    }
    return 1;
}

/* the state within its physical range (StrapdownFilter.in_range); W: P itself or a copy, overwritten */
static int in_range(const real *x, real *W) {
    return MTWIP_FABS(x[TH]) < C->tilt_limit && W[TH * NX + TH] < C->tilt_var_max && positive_definite(W);
}

static void symmetrise(real *P, int n) {
    int i, j;
    for (i = 0; i < n; i++)
        for (j = i + 1; j < n; j++) {
            real s = HALF * (P[i * n + j] + P[j * n + i]);
            P[i * n + j] = P[j * n + i] = s;
        }
}

static void keep_good(mtwip_estimator_t *e) {
    int i, p = NX * (NX + 1) / 2;
    memcpy(e->xg, e->x, sizeof e->xg);
    for (i = NX - 1; i >= 0; i--) { /* packed: the upper triangle by rows. Row i's entries j >= i go to
        Pg[p_i .. p_i + NX - i); the whole row is copied, unrolled (a loop here becomes a library call per row
        on some compilers), its first i entries onto the rows before it, which are written after it */
        const real *src = e->P + i * NX;
        real *dst;
        p -= NX - i;
        dst = e->Pg + p - i;
#define CP(r) dst[r] = src[r];
        EACH12(CP)
#undef CP
    }
    memcpy(e->wg, e->w, sizeof e->wg);
    memcpy(e->wpg, e->w_prev, sizeof e->wpg);
}

/* the last good state, its covariance inflated */
static void restore(mtwip_estimator_t *e) {
    int i, j;
    memcpy(e->x, e->xg, sizeof e->x);
    for (i = 0; i < NX; i++)
        for (j = 0; j < NX; j++) e->P[i * NX + j] = C->restore_inflation * e->Pg[packed(i, j)];
    for (i = 0; i < NX; i++) e->P[i * NX + i] += C->restore_jitter;
    memcpy(e->w, e->wg, sizeof e->w);
    memcpy(e->w_prev, e->wpg, sizeof e->w_prev);
}

/* the core's set_state: a state written by the Python side is kept as good if it is healthy */
static void push(mtwip_estimator_t *e) {
    if (healthy(e->x, e->P)) keep_good(e);
}

/* ---- the prior and the re-initialisation --------------------------------------------------------- */
/* StrapdownFilter.prior into e->x, e->P: from the accelerometer reading acc (NULL: none) */
static void prior(mtwip_estimator_t *e, const real *acc, int moving) {
    real theta0, var_theta, sc, diag[NX];
    real *x = e->x, *P = e->P;
    int i;
    if (!acc) {
        theta0 = ZERO;
        var_theta = C->tilt_var_max;
        sc = ZERO;
    } else {
        real fx = acc[0], fz = acc[2], g, gm;
        theta0 = MTWIP_ATAN2(-fx, fz);
        g = MTWIP_HYPOT(fx, fz);
        sc = MTWIP_SIN(theta0) * MTWIP_COS(theta0);
        gm = g < ONE ? ONE : g; /* max(g, 1.0) */
        var_theta = C->a_var / pow2(gm) + TWO * sc * sc * C->a_sf;
        if (moving) {
            real dev = (g - C->model.g) / C->model.g, v = var_theta + dev * dev;
            var_theta = C->tilt_var_max < v ? C->tilt_var_max : v;
        }
    }
    for (i = 0; i < NX; i++) x[i] = ZERO;
    x[TH] = x[C0] = theta0;
    x[AL] = C->alpha0;
    diag[TH] = var_theta;
    diag[PS] = C->prior_tiny;
    diag[V] = moving ? C->prior_v_var_moving : C->prior_tiny;
    diag[AL] = C->prior_tiny;
    diag[BY] = diag[BZ] = C->prior_bias_var;
    diag[C0] = var_theta + C->prior_edge_var;
    diag[SY] = diag[SZ] = C->prior_g_sf;
    diag[H0] = C->prior_edge_var;
    diag[SAX] = diag[SAZ] = C->prior_a_sf;
    for (i = 0; i < NX * NX; i++) P[i] = ZERO;
    for (i = 0; i < NX; i++) P[i * NX + i] = diag[i];
    P[TH * NX + C0] = P[C0 * NX + TH] = var_theta;
    for (i = TH; i <= C0; i += C0 - TH) {
        P[i * NX + SAX] = P[SAX * NX + i] = -sc * C->a_sf;
        P[i * NX + SAZ] = P[SAZ * NX + i] = sc * C->a_sf;
    }
}

static const mtwip_ekf_slot_t *ring_get(const mtwip_ekf_slot_t *ring, int32_t key);

/* Fusion.lost: re-initialised from the accelerometer at the filter's time (StrapdownFilter.reinitialise) */
static void lost(mtwip_estimator_t *e) {
    const mtwip_ekf_slot_t *s = ring_get(e->acc, e->at);
    real a3[3];
    const real *acc = e->has_last_a ? e->last_a : NULL;
    real ps = e->x[PS], al = e->x[AL], pa = e->P[AL * NX + AL], *x = e->x, *P = e->P;
    if (s) {
        a3[0] = s->v[0];
        a3[1] = ZERO;
        a3[2] = s->v[1];
        acc = a3;
    }
    prior(e, acc, 1);
    if (MTWIP_ISFINITE(ps)) x[PS] = ps;
    if (MTWIP_ISFINITE(al)) x[AL] = al;
    P[AL * NX + AL] = pa > ZERO ? (C->heading_var_max < pa ? C->heading_var_max : pa) : C->heading_var_max;
    if (e->has_last_enc) {
        const real *enc = e->last_enc;
        x[C0] = HALF * (enc[0] + enc[1]) - x[PS] + x[TH];
        x[H0] = HALF * (enc[1] - enc[0]) - C->b_r * (x[AL] - C->alpha0);
        P[H0 * NX + H0] += C->b_r * C->b_r * P[AL * NX + AL];
        P[H0 * NX + AL] = P[AL * NX + H0] = -C->b_r * P[AL * NX + AL];
    }
    e->aug_on = 0;
}

/* ---- the queues ------------------------------------------------------------------------ */
static int ring_index(int32_t key) {
    int32_t i = key % RING;
    return (int)(i < 0 ? i + RING : i);
}

static const mtwip_ekf_slot_t *ring_get(const mtwip_ekf_slot_t *ring, int32_t key) {
    const mtwip_ekf_slot_t *s = &ring[ring_index(key)];
    return s->key == key ? s : NULL;
}

static void ring_put(mtwip_ekf_slot_t *ring, int32_t key, real a, real b) {
    mtwip_ekf_slot_t *s = &ring[ring_index(key)];
    s->key = key;
    s->v[0] = a;
    s->v[1] = b;
}

/* the samples with a time after m move d sample times earlier (those landing at m or before are
   dropped): SensorFrontEnd.latency_changed */
static void ring_shift(mtwip_ekf_slot_t *ring, int32_t m, int32_t d) {
    mtwip_ekf_slot_t moved[RING];
    int n = 0, i;
    for (i = 0; i < RING; i++)
        if (ring[i].key != EMPTY && ring[i].key > m) {
            moved[n++] = ring[i];
            ring[i].key = EMPTY;
        }
    for (i = 0; i < n; i++)
        if (moved[i].key - d > m) ring_put(ring, moved[i].key - d, moved[i].v[0], moved[i].v[1]);
}

static void command_of(const mtwip_estimator_t *e, int32_t key, real *u) {
    const mtwip_ekf_slot_t *c = &e->cmd[ring_index(key)];
    if (c->key == key) {
        u[0] = c->v[0];
        u[1] = c->v[1];
    } else
        u[0] = u[1] = ZERO;
}

/* ---- the latency watch (estimation.ekf_policies.LatencyWatch; its check, the kernel's watch_rho) ---- */
#define WW MTWIP_EKF_WATCH_W
#define WN MTWIP_EKF_WATCH_ALLOC

/* NumPy's pairwise sum of n <= 128 numbers (its eight partial sums, then the rest in order) */
static real pairwise(const real *a, int n) {
    real res, r0, r1, r2, r3, r4, r5, r6, r7;
    int i;
    if (n < 8) {
        res = ZERO;
        for (i = 0; i < n; i++) res += a[i];
        return res;
    }
    r0 = a[0];
    r1 = a[1];
    r2 = a[2];
    r3 = a[3];
    r4 = a[4];
    r5 = a[5];
    r6 = a[6];
    r7 = a[7];
    for (i = 8; i < n - (n % 8); i += 8) {
        r0 += a[i];
        r1 += a[i + 1];
        r2 += a[i + 2];
        r3 += a[i + 3];
        r4 += a[i + 4];
        r5 += a[i + 5];
        r6 += a[i + 6];
        r7 += a[i + 7];
    }
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7));
    for (; i < n; i++) res += a[i];
    return res;
}

static void swap_r(real *a, int i, int j) {
    real t = a[i];
    a[i] = a[j];
    a[j] = t;
}

/* max-heap h[0..m): the entry at i sifted down */
static void sift_down(real *h, int m, int i) {
    real v = h[i];
    for (;;) {
        int c = 2 * i + 1;
        if (c >= m) break;
        if (c + 1 < m && h[c + 1] > h[c]) c++;
        if (!(h[c] > v)) break;
        h[i] = h[c];
        i = c;
    }
    h[i] = v;
}

#ifndef MTWIP_EKF_SELECT_SLACK
#define MTWIP_EKF_SELECT_SLACK 4 /* select_kth's rounds of quickselect beyond 2 log2(n) before its heap */
#endif

/* h[0..n) (no NaN) rearranged so that h[k] holds the k-th smallest, those before it none larger and those
   after it none smaller: quickselect (Hoare's partition about the median of three), and should it take
   more than 2 log2(n) + 4 rounds, on what is left the k − lo + 1 smallest kept in a max-heap (a bound on
   the worst case: about n log2(n) comparisons) */
static void select_kth(real *h, int n, int k) {
    int lo = 0, hi = n - 1, rounds = 0, bound = MTWIP_EKF_SELECT_SLACK, i, j;
    for (i = n; i > 1; i >>= 1) bound += 2;
    while (hi - lo >= 8) {
        int mid = lo + (hi - lo) / 2;
        real pivot;
        if (++rounds > bound) { /* the heap on h[lo..hi] for its (k − lo)-th, then that one put at k */
            real *s = h + lo;
            int m = k - lo + 1, len = hi - lo + 1;
            for (i = m / 2 - 1; i >= 0; i--) sift_down(s, m, i);
            for (i = m; i < len; i++)
                if (s[i] < s[0]) {
                    swap_r(s, 0, i);
                    sift_down(s, m, 0);
                }
            swap_r(s, 0, m - 1);
            return;
        }
        if (h[mid] < h[lo]) swap_r(h, mid, lo);
        if (h[hi] < h[lo]) swap_r(h, hi, lo);
        if (h[hi] < h[mid]) swap_r(h, hi, mid);
        pivot = h[mid];
        i = lo;
        j = hi;
        while (i <= j) {
            while (h[i] < pivot) i++;
            while (pivot < h[j]) j--;
            if (i <= j) {
                swap_r(h, i, j);
                i++;
                j--;
            }
        }
        if (k <= j)
            hi = j;
        else if (k >= i)
            lo = i;
        else
            return; /* j < k < i: h[k] equals the pivot */
    }
    for (i = lo + 1; i <= hi; i++) { /* a few left: insertion */
        real v = h[i];
        for (j = i; j > lo && h[j - 1] > v; j--) h[j] = h[j - 1];
        h[j] = v;
    }
}

/* of a zero at position p of a[0..n) sorted stably (the insertion sort the Python path's order
   statistics were ported with: equal values keep their order), the zero itself: its sign */
static real zero_at(const real *a, int n, int p) {
    int i, below = 0;
    for (i = 0; i < n; i++) below += a[i] < ZERO;
    for (i = 0; i < n; i++)
        if (a[i] == ZERO && p-- == below) return a[i];
    return ZERO; /* (not reached) */
}

/* the median of a[0..n), n >= 1, no NaN among them, as the middle of the values sorted: the k-th order
   statistic (k = n / 2) by select_kth in h (scratch of n), the (k − 1)-th the largest before it; a zero
   one takes its sign from a's order (zero_at) */
static real median_of(const real *a, real *h, int n) {
    int k = n / 2, i;
    real hi, lo;
    memcpy(h, a, (size_t)n * sizeof(real));
    select_kth(h, n, k);
    hi = h[k];
    if (hi == ZERO) hi = zero_at(a, n, k);
    if (n % 2) return hi;
    lo = h[0];
    for (i = 1; i < k; i++)
        if (h[i] > lo) lo = h[i];
    if (lo == ZERO) lo = zero_at(a, n, k - 1);
    return (lo + hi) / TWO;
}

/* n rows of a watch ring (N slots) from its slot `first` on, in order */
static void ring_rows(real *dst, const real *ring, int first, int n) {
    int a = WN - first < n ? WN - first : n;
    memcpy(dst, ring + first, (size_t)a * sizeof(real));
    memcpy(dst + a, ring, (size_t)(n - a) * sizeof(real));
}

#if MTWIP_EKF_LEAN
#define LAGS_AT_ONCE 7
/* zy[a] = Σ_j z[base − a + idx_j] y[j] over the `used` rows (idx NULL: row j is j), for the n ≤ 7 lags a */
static void lag_products(const real *z, int base, const real *y, const int16_t *idx, int used, int n, real *zy) {
    real c0 = ZERO, c1 = ZERO, c2 = ZERO, c3 = ZERO, c4 = ZERO, c5 = ZERO, c6 = ZERO;
    int j;
    if (n >= LAGS_AT_ONCE && base >= LAGS_AT_ONCE - 1)
        for (j = 0; j < used; j++) {
            const real *zj = z + base + (idx ? idx[j] : j), v = y[j];
            c0 += zj[0] * v;
            c1 += zj[-1] * v;
            c2 += zj[-2] * v;
            c3 += zj[-3] * v;
            c4 += zj[-4] * v;
            c5 += zj[-5] * v;
            c6 += zj[-6] * v;
        }
    else {
        int a;
        for (a = 0; a < n && a < LAGS_AT_ONCE; a++) {
            real s = ZERO;
            for (j = 0; j < used; j++) s += z[base - a + (idx ? idx[j] : j)] * y[j];
            zy[a] = s;
        }
        return;
    }
    zy[0] = c0;
    zy[1] = c1;
    zy[2] = c2;
    zy[3] = c3;
    zy[4] = c4;
    zy[5] = c5;
    zy[6] = c6;
}
#endif

/* lag l's correlation ρ from its sums; the best so far (np.argmax: the first largest, the first NaN) */
static void lag_verdict(int l, real syy, real szy, real szz, int assumed, int *have_nan, int *best, real *rho_best,
                        real *rho_assumed) {
    real den = MTWIP_SQRT(syy * szz);
    real rho = den > ZERO ? C->torque_sign * szy / den : C->torque_sign * szy / (real)INFINITY;
    if (l == assumed) *rho_assumed = rho;
    if (*have_nan) return;
    if (rho != rho) {
        *have_nan = 1;
        *best = l;
        *rho_best = rho;
    } else if (l == 0 || rho > *rho_best) {
        *best = l;
        *rho_best = rho;
    }
}

/* the correlations at latencies 0 … max_lag; the best (np.argmax: the first largest, the first NaN)
   in *best with its ρ, the assumed latency's in *rho_assumed; 0 when fewer than half the window's
   rows hold a measurement. The rows of the ring read in order (rows i of the watch: ring slot
   (head + i) mod N); every sum in the order of the Python path's */
static int watch_check(const mtwip_estimator_t *e, int assumed, int *best, real *rho_best, real *rho_assumed) {
    real yy[WW], tmp[WW], dk[WN];
    int16_t idx[WW];
    int W = (int)C->watch_window, L = (int)C->watch_max_lag, n = W + L + 5, r0 = n - 1 - W, used = 0, j, l;
    int have_nan = 0, h = e->w_head;
    real med, lim, lo, hi, mean, syy = ZERO;
    /* the gyro's rows r0 − 2 … r0 + W − 1 in order (in dk, free until the commands' differences) */
    ring_rows(dk, e->wy, (h + r0 - 2) % WN, W + 2);
    for (j = 0; j < W; j++) {
        real y2 = (dk[j + 2] - TWO * dk[j + 1]) + dk[j];
        if (MTWIP_ISFINITE(y2)) {
            idx[used] = (int16_t)j;
            yy[used++] = y2;
        }
    }
    if (used < W / 2) return 0;
    med = median_of(yy, tmp, used);
    for (j = 0; j < used; j++) tmp[j] = MTWIP_FABS(yy[j] - med);
    lim = C->watch_clip * C->mad_scale * median_of(tmp, dk, used);
    lo = med - lim;
    hi = med + lim;
    for (j = 0; j < used; j++) {
        real v = yy[j] > lo ? yy[j] : lo;
        yy[j] = v < hi ? v : hi;
    }
    mean = pairwise(yy, used) / (real)used;
    for (j = 0; j < used; j++) {
        yy[j] = yy[j] - mean;
        syy += yy[j] * yy[j];
    }
    /* the commands' differences: row i's ((u[i+3] + u[i+2]) − u[i+1]) − u[i], the rows in order first */
    ring_rows(dk, e->wu, h, n);
    for (j = 0; j + 3 < n; j++) dk[j] = ((dk[j + 3] + dk[j + 2]) - dk[j + 1]) - dk[j];
    *best = 0;
#if MTWIP_EKF_LEAN
    /* Σ (z − z̄) y = Σ z y − z̄ Σ y and Σ (z − z̄)² = Σ z² − z̄ Σ z, Σ z and Σ z² carried from lag to lag as
       the window slides by one row when every row is used: a pass of one product per row and lag */
    {
        real ysum = ZERO, zs = ZERO, zq = ZERO;
        for (j = 0; j < used; j++) ysum += yy[j];
        if (used == W)
            for (j = 0; j < W; j++) {
                real v = dk[L + 2 + j];
                zs += v;
                zq += v * v;
            }
        real zy[LAGS_AT_ONCE];
        for (l = 0; l <= L; l++) {
            const real *z = dk + (L + 2 - l);
            real szy, szz, zmean;
            const int a = l % LAGS_AT_ONCE;
            if (a == 0) /* Σ z y for the lags l … l + 6 together, y read once a row */
                lag_products(dk, L + 2 - l, yy, used == W ? NULL : idx, used, L - l + 1, zy);
            if (used == W) {
                if (l > 0) { /* the window one row earlier */
                    real in = z[0], out = z[W];
                    zs += in - out;
                    zq += in * in - out * out;
                }
            } else {
                zs = zq = ZERO;
                for (j = 0; j < used; j++) {
                    real v = z[idx[j]];
                    zs += v;
                    zq += v * v;
                }
            }
            zmean = zs / (real)used;
            szy = zy[a] - zmean * ysum;
            szz = zq - zmean * zs;
            if (szz < ZERO) szz = ZERO;
            lag_verdict(l, syy, szy, szz, assumed, &have_nan, best, rho_best, rho_assumed);
        }
    }
    return 1;
#else
    for (l = 0; l <= L; l++) {
        real zsum = ZERO, zmean, szy = ZERO, szz = ZERO;
        const real *z = dk + (L + 2 - l);
        if (used == W) /* every row: idx[j] = j */
            zsum = pairwise(z, used);
        else {
            for (j = 0; j < used; j++) zsum += tmp[j] = z[idx[j]];
            z = tmp;
        }
        zmean = zsum / (real)used;
        for (j = 0; j + 4 <= used; j += 4) { /* (four rows a round: each sum still row by row) */
            real d0 = z[j] - zmean, d1 = z[j + 1] - zmean, d2 = z[j + 2] - zmean, d3 = z[j + 3] - zmean;
            szy += d0 * yy[j];
            szz += d0 * d0;
            szy += d1 * yy[j + 1];
            szz += d1 * d1;
            szy += d2 * yy[j + 2];
            szz += d2 * d2;
            szy += d3 * yy[j + 3];
            szz += d3 * d3;
        }
        for (; j < used; j++) {
            real d = z[j] - zmean;
            szy += d * yy[j];
            szz += d * d;
        }
        lag_verdict(l, syy, szy, szz, assumed, &have_nan, best, rho_best, rho_assumed);
    }
    return 1;
#endif
}

/* LatencyWatch.filter_verdicts: the gyro samples the filter rejected since the last call are forgotten */
static void watch_verdicts(mtwip_estimator_t *e, int32_t m, uint32_t outliers, int32_t latency) {
    if (outliers != e->w_vn) {
        int32_t len = e->w_len, j = e->w_vm + 1 > m - len ? e->w_vm + 1 : m - len;
        for (; j <= m; j++) {
            int32_t i = len - 1 - (e->w_k - (j + latency));
            if (i >= 0 && i < len) e->wy[(e->w_head + i) % WN] = nan_value();
        }
    }
    e->w_vm = m;
    e->w_vn = outliers;
}

static void watch_gap(int32_t gaps[][2], int32_t *n, int32_t k, int32_t gap) {
    if (*n == MTWIP_EKF_GAPS) {
        memmove(gaps[0], gaps[1], (size_t)(MTWIP_EKF_GAPS - 1) * sizeof gaps[0]);
        (*n)--;
    }
    gaps[*n][0] = k;
    gaps[*n][1] = gap;
    (*n)++;
}

static int watch_decide(mtwip_estimator_t *e, int32_t assumed, int32_t *found);

/* LatencyWatch.observe: 1 with the new latency when a change is declared */
static int watch_observe(mtwip_estimator_t *e, int32_t k, const real *gyro, int a_ok, const real *cmd,
                         int32_t assumed, int usable, int32_t *found) {
    int N = WN;
    int32_t slot;
    if (e->w_len < N)
        slot = (e->w_head + e->w_len++) % N;
    else {
        slot = e->w_head;
        e->w_head = (e->w_head + 1) % N;
    }
    e->wy[slot] = gyro && usable ? gyro[1] : nan_value();
    e->wu[slot] = cmd[0] + cmd[1];
    e->w_k = k;
    if (gyro) {
        if (k - e->w_last_g - 1 > 0) watch_gap(e->gaps_g, &e->n_gaps_g, k, k - e->w_last_g - 1);
        e->w_last_g = k;
    }
    if (a_ok) {
        if (k - e->w_last_a - 1 > 0) watch_gap(e->gaps_a, &e->n_gaps_a, k, k - e->w_last_a - 1);
        e->w_last_a = k;
    }
    if (k % C->watch_every || e->w_len < N || e->w_hold_until > k) return 0;
    if (MTWIP_EKF_LEAN) { /* the lean build checks after the filter's step, on one that does not coast */
        e->w_due = 1;
        return 0;
    }
    return watch_decide(e, assumed, found);
}

/* LatencyWatch.observe's check and its votes: 1 with the new latency when a change is declared */
static int watch_decide(mtwip_estimator_t *e, int32_t assumed, int32_t *found) {
    int best;
    real rb = ZERO, ra = ZERO;
    if (!watch_check(e, (int)assumed, &best, &rb, &ra)) return 0;
    if (best != assumed && rb >= C->watch_rho && rb - ra >= C->watch_margin) {
        int32_t votes = e->w_votes_lag == best ? e->w_votes + 1 : 1;
        e->w_votes_lag = best;
        e->w_votes = votes;
        if (votes >= C->watch_persist) {
            *found = best;
            return 1;
        }
    } else
        e->w_votes_lag = e->w_votes = 0;
    return 0;
}

/* LatencyWatch.accel_gapped: the accelerometer stopped arriving for delta samples when the gyro did */
static int accel_gapped(const mtwip_estimator_t *e, int32_t delta) {
    int i, j;
    if (delta <= 0) return 0;
    for (i = 0; i < e->n_gaps_a; i++) {
        if (e->gaps_a[i][1] != delta) continue;
        for (j = 0; j < e->n_gaps_g; j++) {
            int32_t d = e->gaps_a[i][0] - e->gaps_g[j][0];
            if (e->gaps_g[j][1] == delta && d <= 1 && d >= -1) return 1;
        }
    }
    return 0;
}

/* SensorFrontEnd.latency_changed: the samples not yet used re-aligned */
static void latency_changed(mtwip_estimator_t *e, int32_t k, int32_t m, int32_t latency) {
    int32_t delta = latency - e->d_gyro, lag;
    int acc = accel_gapped(e, delta);
    if (delta) ring_shift(e->gyro, m, delta);
    if (acc && delta) ring_shift(e->acc, m, delta);
    e->d_gyro = latency;
    if (acc) e->d_acc += delta;
    lag = e->d_gyro > e->d_acc ? e->d_gyro : e->d_acc;
    e->lag = lag > C->d_enc ? lag : C->d_enc;
    e->w_votes_lag = e->w_votes = 0;
    e->w_hold_until = k + C->watch_window;
}

/* ---- the sensor front end --------------------------------------------------------------- */
/* SensorFrontEnd.store: screen and queue the readings of instant k (the filter at m) */
static void store(mtwip_estimator_t *e, const mtwip_sample_t *s, int32_t k, int32_t m, const real *cmd, int watch) {
    int g_ok = s->has_gyro && finite_n(s->gyro, 3), a_ok = s->has_accel && finite_n(s->accel, 3);
    int e_ok = s->has_encoder && finite_n(s->encoder, 2), g_stale = 0;
    if (g_ok || a_ok) {
        int a_stale;
        g_stale = C->stale_check[0] && g_ok && e->has_last_g && s->gyro[0] == e->last_g[0] &&
                  s->gyro[1] == e->last_g[1] && s->gyro[2] == e->last_g[2];
        a_stale = C->stale_check[1] && a_ok && e->has_last_a && s->accel[0] == e->last_a[0] &&
                  s->accel[1] == e->last_a[1] && s->accel[2] == e->last_a[2];
        if (g_stale || a_stale) {
            /* stale: treated as missing (not queued) */
        } else {
            if (g_ok && k - e->d_gyro > m) ring_put(e->gyro, k - e->d_gyro, s->gyro[1], s->gyro[2]);
            if (a_ok && k - e->d_acc > m) ring_put(e->acc, k - e->d_acc, s->accel[0], s->accel[2]);
        }
        if (g_ok) {
            memcpy(e->last_g, s->gyro, sizeof e->last_g);
            e->has_last_g = 1;
        }
        if (a_ok) {
            memcpy(e->last_a, s->accel, sizeof e->last_a);
            e->has_last_a = 1;
        }
    }
    if (watch && C->watches && k > 0) {
        int32_t found;
        watch_verdicts(e, m, e->imu_outliers, e->d_gyro);
        if (watch_observe(e, k, g_ok ? s->gyro : NULL, a_ok, cmd, e->d_gyro,
                          g_ok && !g_stale && MTWIP_FABS(s->gyro[1]) < C->rails[0], &found))
            latency_changed(e, k, m, found);
    }
    if (e_ok) {
        if (-C->enc_range <= s->encoder[0] && s->encoder[0] <= C->enc_range && -C->enc_range <= s->encoder[1] &&
            s->encoder[1] <= C->enc_range)
            ring_put(e->enc, k - C->d_enc, s->encoder[0], s->encoder[1]);
    }
}

static real span(int32_t a, int32_t b) { return (real)(b - a) * C->model.dt; }

/* SensorFrontEnd.count_check */
static void count_check(mtwip_estimator_t *e, int implausible) {
    if (!implausible) {
        e->still = 0;
        return;
    }
    e->still++;
    if (e->still >= C->max_rejects_in_row && !e->stuck) e->stuck = 1;
}

/* StrapdownFilter.rebase_encoders: the encoders' zeros c, h re-based onto reading enc */
static void rebase_encoders(mtwip_estimator_t *e, const real *enc) {
    real H[2][NX], HP[NX], S[2][2], y[2], off[2];
    real *x = e->x, *P = e->P;
    int a, b, i, j, k;
    h_row(0, H[0]);
    h_row(1, H[1]);
    off[0] = C->b_r * C->alpha0;
    off[1] = -C->b_r * C->alpha0;
    for (a = 0; a < 2; a++) {
        real s = ZERO;
        for (j = 0; j < NX; j++) s += H[a][j] * x[j];
        y[a] = enc[a] - (s + off[a]);
        for (j = 0; j < NX; j++) { /* row a of H P */
            real t = ZERO;
            for (k = 0; k < NX; k++) t += H[a][k] * P[k * NX + j];
            HP[j] = t;
        }
        for (b = 0; b < 2; b++) {
            real t = ZERO;
            for (j = 0; j < NX; j++) t += HP[j] * H[b][j];
            S[a][b] = t + (a == b ? C->rebase_var : ZERO);
        }
    }
    x[C0] += HALF * (y[0] + y[1]);
    x[H0] += HALF * (y[1] - y[0]);
    for (i = 0; i < NX; i++) P[C0 * NX + i] = P[i * NX + C0] = P[H0 * NX + i] = P[i * NX + H0] = ZERO;
    P[C0 * NX + C0] = MTWIP_R(0.25) * (S[0][0] + S[1][1] + TWO * S[0][1]);
    P[H0 * NX + H0] = MTWIP_R(0.25) * (S[0][0] + S[1][1] - TWO * S[0][1]);
    if (e->aug_on) {
        for (i = 0; i < NX; i++)
            for (j = 0; j < NX; j++) e->aug[i * NA + j] = P[i * NX + j];
        for (i = NX; i < NA; i++)
            e->aug[C0 * NA + i] = e->aug[i * NA + C0] = e->aug[H0 * NA + i] = e->aug[i * NA + H0] = ZERO;
    }
    push(e);
}

/* SensorFrontEnd.screen_encoders: the reading of sample time m, or NULL (implausible, or stuck) */
static const real *screen_encoders(mtwip_estimator_t *e, const real *enc, int32_t m) {
    real T, limit, j0, j1, jump;
    if (!enc) return NULL;
    if (!e->has_last_enc) {
        memcpy(e->last_enc, enc, sizeof e->last_enc);
        e->has_last_enc = 1;
        e->last_enc_m = m;
        return enc;
    }
    if (e->stuck) {
        if (enc[0] == e->last_enc[0] || enc[1] == e->last_enc[1]) return NULL;
        e->stuck = 0;
        e->still = 0;
    }
    T = span(e->last_enc_m, m);
    limit = C->max_wheel_rate * T + TWO * C->delta;
    j0 = MTWIP_FABS(enc[0] - e->last_enc[0]);
    j1 = MTWIP_FABS(enc[1] - e->last_enc[1]);
    jump = j1 > j0 ? j1 : j0;
    if (jump <= limit) {
        e->implausible = 0;
        return enc;
    }
    e->implausible++;
    if (e->implausible >= C->max_rejects_in_row) {
        rebase_encoders(e, enc);
        memcpy(e->last_enc, enc, sizeof e->last_enc);
        e->last_enc_m = m;
        e->implausible = 0;
    }
    return NULL;
}

/* ---- the accelerometer test (AccelOutlierTest) ------------------------------------------------- */
static real pymax(real a, real b) { return b > a ? b : a; }
static real pymin(real a, real b) { return b < a ? b : a; }

static void accel_test(const mtwip_estimator_t *e, real *acc) {
    acc[0] = C->imu_gate[1];
    acc[1] = acc[2] = acc[3] = ZERO;
    if (e->acc_n == 3) {
        const real(*h)[2] = e->acc_hist;
        acc[1] = pymax(pymin(h[0][0], h[1][0]), pymin(pymax(h[0][0], h[1][0]), h[2][0]));
        acc[2] = pymax(pymin(h[0][1], h[1][1]), pymin(pymax(h[0][1], h[1][1]), h[2][1]));
        acc[3] = e->acc_in_row < C->accel_max_in_row ? ONE : ZERO;
    }
}

static void accel_seen(mtwip_estimator_t *e, const real *err, int outlier) {
    if (err && MTWIP_ISFINITE(err[0]) && MTWIP_ISFINITE(err[1])) {
        if (e->acc_n == 3) {
            memmove(e->acc_hist[0], e->acc_hist[1], 2 * sizeof e->acc_hist[0]);
            e->acc_n = 2;
        }
        e->acc_hist[e->acc_n][0] = err[0];
        e->acc_hist[e->acc_n][1] = err[1];
        e->acc_n++;
    }
    e->acc_in_row = outlier ? e->acc_in_row + 1 : 0;
}

/* ---- the keep-inside truncation (SensorFrontEnd.keep_inside; the kernel's keep_inside) ---------- */
static int coast_update(mtwip_estimator_t *e, const meas_t *em);

/* the truncated updates of the wheels whose count is unchanged and whose estimate has left it. coast:
   the coasting step's augmented update (an error where the Python path raises), else the kernel's
   update. Returns the updates made + 16 × the implausible wheels' mask, −1 if an update failed. pfin: P
   is finite (−1: not known); with P finite, P Hᵀ's sums skip the terms of H's zeros (see cov_predict) */
static int keep_inside(mtwip_estimator_t *e, const real *enc, int coast, int pfin) {
    int n = 0, implausible = 0, i, j, k;
    for (i = 0; i < 2; i++) {
        meas_t em;
        real w, s2 = ZERO, lo, hi, sgn = (real)(2 * i - 1);
        uint8_t nz[NX];
        int cnt = 0;
        if (enc[i] != e->last_enc[i]) continue;
        em.dof = 1;
        h_row(i, em.H[0]);
        em.off[0] = -sgn * C->b_r * C->alpha0;
        w = em.off[0];
        if (pfin < 0) pfin = finite_matrix(e->P);
        for (k = 0; k < NX; k++)
            if (!pfin || em.H[0][k] != ZERO) nz[cnt++] = (uint8_t)k;
        for (j = 0; j < NX; j++) {
            real t = ZERO;
            w += em.H[0][j] * e->x[j];
            for (k = 0; k < cnt; k++) t += e->P[j * NX + nz[k]] * em.H[0][nz[k]];
            s2 += em.H[0][j] * t;
        }
        lo = enc[i] - C->inside_half;
        hi = enc[i] + C->inside_half;
        if (s2 > ZERO && (w < lo ? lo - w : w - hi) > C->stuck_sigmas * MTWIP_SQRT(s2)) {
            implausible |= 1 << i;
            continue;
        }
        if (!truncated_measurement(w, s2, lo, hi, C->stuck_sigmas, &em.z[0], &em.R[0])) continue;
        if (coast) {
            if (coast_update(e, &em) != EKF_OK) return -1;
            pfin = -1;
        } else if (kalman_update(e->x, e->P, &em, e->consider, pfin, &pfin, NULL) != 0)
            return -1;
        n++;
    }
    return n + 16 * implausible;
}

/* ---- the IMU-driven step (the kernel's advance, and Fusion.imu_step_fused) ------------------------ */
/* the IMU sample as the filter uses it (the kernel's imu_sample): 1 if an axis was saturated */
static int imu_sample(const mtwip_estimator_t *e, const real *cmd, const real *acc, real *smp, real *extra,
                      real *syn, real *syn_extra, int *acc_out, real *err) {
    int any = 0, sat[4], have_syn = 0, j;
    *acc_out = 0;
    err[0] = err[1] = nan_value();
    for (j = 0; j < 4; j++) any |= sat[j] = MTWIP_FABS(smp[j]) >= C->lim[j];
    if (acc[0] > ZERO && !sat[2] && !sat[3]) {
        const real *P = e->P;
        real g = C->model.g, fx, fz, sx, sz, ex, ez, eg, sg;
        synthetic(e->x, e->w, e->w_prev, cmd, 0, syn, syn_extra);
        have_syn = 1;
        fx = syn[2];
        fz = syn[3];
        sx = C->a_var + syn_extra[2] + g * g * P[TH * NX + TH] + fx * fx * P[SAX * NX + SAX];
        sz = C->a_var + syn_extra[3] + fz * fz * P[SAZ * NX + SAZ];
        err[0] = smp[2] - fx;
        err[1] = smp[3] - fz;
        ex = err[0] - acc[1];
        ez = err[1] - acc[2];
        eg = smp[0] - syn[0];
        sg = C->gyro_extrapolation_samples * C->g_var + syn_extra[0];
        *acc_out = acc[3] != ZERO && ex * ex / sx + ez * ez / sz > C->accel_variance_factor * acc[0] &&
                   eg * eg / sg <= C->imu_gate[0];
    }
    if (!any && !*acc_out) return 0;
    if (!have_syn) synthetic(e->x, e->w, e->w_prev, cmd, 0, syn, syn_extra);
    for (j = 0; j < 4; j++)
        if (sat[j] || (j >= 2 && *acc_out)) {
            smp[j] = syn[j];
            extra[j] = syn_extra[j];
        }
    return any;
}

/* one IMU-driven step with sample smp (ω_y, ω_z, f_x, f_z); enc NULL: no encoder sample. Returns 1
   if the sample is an outlier (nothing changed: the caller coasts instead) */
static int imu_step(mtwip_estimator_t *e, const real *smp_in, const real *enc, const real *cmd, int *acc_out,
                    real *err) {
    real smp[4], extra[4], syn[4], syn_extra[4], acc[4], x1[NX], nis = ZERO, T = ZERO;
    union { /* the prior's covariance, then the update's innovation, then the range test's elimination */
        real P[NX * NX];
        innov_t in;
    } buf;
    real *Pp = buf.P;
    step_t st;
    meas_t em;
    int saturated, has_enc = enc != NULL, enc_code = 0, ok = 1, inside = 0, dof, may_reject, j, pfin, ppfin;
    const real *last = e->last_enc;
    memcpy(smp, smp_in, sizeof smp);
    for (j = 0; j < 4; j++) extra[j] = ZERO;
    accel_test(e, acc);
    may_reject = e->in_row < C->max_rejects_in_row;
    if (has_enc) T = span(e->last_enc_m, e->at);
    saturated = imu_sample(e, cmd, acc, smp, extra, syn, syn_extra, acc_out, err);
    propagate(e->x, smp, (saturated || *acc_out) ? extra : NULL, 0, x1, &st);
    pfin = finite_matrix(e->P);
    ppfin = cov_predict(&st, e->P, Pp, pfin);
    em.dof = 0;
    if (has_enc) {
        real eps = encoder_fit(enc, last, T, x1, smp, Pp, FIT_TEST | (ppfin ? FIT_FINITE : 0), &em, NULL, NULL);
        if (!(eps <= C->imu_gate[em.dof - 1])) { /* the alternative: the model's sample instead */
            if (!saturated && !*acc_out) synthetic(e->x, e->w, e->w_prev, cmd, 0, syn, syn_extra);
            propagate(e->x, syn, syn_extra, 0, x1, &st);
            ppfin = cov_predict(&st, e->P, Pp, pfin);
            if (encoder_fit(enc, last, T, x1, syn, Pp, FIT_TEST | (ppfin ? FIT_FINITE : 0), &em, NULL, NULL) <=
                C->gate[em.dof - 1])
                return 1;
            propagate(e->x, smp, (saturated || *acc_out) ? extra : NULL, 0, x1, &st); /* the sample's again */
            ppfin = cov_predict(&st, e->P, Pp, pfin);
        }
        em.dof = 0;
    }
    memcpy(e->x, x1, sizeof x1);
    memcpy(e->P, Pp, sizeof buf.P); /* (Pp free from here to the range test) */
    e->w_prev[0] = e->w[0];
    e->w_prev[1] = e->w[1];
    e->w[0] = smp[0];
    e->w[1] = smp[1];
    if (has_enc) nis = encoder_fit(enc, last, T, e->x, e->w, e->P, ppfin ? FIT_FINITE : 0, &em, NULL, &buf.in);
    dof = em.dof;
    if (has_enc) {
        if (dof == 0)
            enc_code = 1;
        else if (!(nis <= C->gate[dof - 1]) && may_reject)
            enc_code = 3;
        else {
            enc_code = (nis <= C->gate[dof - 1]) ? 2 : 4;
            if (kalman_update(e->x, e->P, &em, e->consider, ppfin, &ppfin, &buf.in)) ok = 0;
        }
        if (ok && enc_code != 3) {
            inside = keep_inside(e, enc, 0, ppfin);
            if (inside < 0) {
                ok = 0;
                inside = 0;
            }
        }
    }
    symmetrise(e->P, NX);
    if (ok && healthy(e->x, e->P)) {
        memcpy(Pp, e->P, sizeof buf.P); /* (the prior's buffer, free now: the range test's elimination) */
        if (in_range(e->x, Pp))
            keep_good(e);
        else
            ok = -1;
    } else {
        restore(e);
        ok = 0;
    }
    /* Fusion.imu_step_fused: the kernel's decisions */
    if (has_enc && (inside > 15 || e->still)) count_check(e, inside >> 4);
    if (enc_code == 1)
        e->last_enc_m = e->at;
    else if (enc_code == 3)
        e->in_row++;
    else if (enc_code >= 2) {
        e->in_row = 0;
        memcpy(e->last_enc, enc, sizeof e->last_enc);
        e->last_enc_m = e->at;
    }
    if (ok < 0) {
        lost(e);
        push(e);
    }
    return 0;
}

/* ---- the coasting step (estimation.ekf_filter.Coasting, the Python path's arithmetic) ------------- */
/* the nontrivial rows of J, TH, AL, V, PS (F + L D) and ω_y, ω_z (D), in the order of ROW_OF's rows
   (TH, AL, V, PS: 0..3) and 4, 5; the other rows of J are unit rows. D's rows are stored in Jr (row i of D
   in Jr[JD[i]]) until Jr's first four rows are formed from them column by column (j_entry's sums) */
static const int JD[4] = {4, 5, 2, 3};

#if !MTWIP_EKF_LEAN /* (the exact build's products leave out ±0 terms where every number is finite) */
/* 1 if the NA × NA matrix M is all finite: its sum is (0 also where that sum overflows: the general path) */
static int finite_aug(const real *M) {
    real s0 = ZERO, s1 = ZERO, s2 = ZERO, s3 = ZERO;
    int i;
    for (i = 0; i + 3 < NA * NA; i += 4) {
        s0 += M[i];
        s1 += M[i + 1];
        s2 += M[i + 2];
        s3 += M[i + 3];
    }
    for (; i < NA * NA; i++) s0 += M[i];
    return MTWIP_ISFINITE((s0 + s1) + (s2 + s3)) != 0;
}
#endif

/* out[a] = Σ_t row[nz[t]] Jr[a][nz[t]] for J's six nontrivial rows a, each sum in ascending t from +0 */
static void row_by_jr(const real *row, real Jr[6][NA], const uint8_t *nz, int cnt, real out[6]) {
    real s0 = ZERO, s1 = ZERO, s2 = ZERO, s3 = ZERO, s4 = ZERO, s5 = ZERO;
    int t;
    for (t = 0; t < cnt; t++) {
        const int k = nz[t];
        const real m = row[k];
        s0 += m * Jr[0][k];
        s1 += m * Jr[1][k];
        s2 += m * Jr[2][k];
        s3 += m * Jr[3][k];
        s4 += m * Jr[4][k];
        s5 += m * Jr[5][k];
    }
    out[0] = s0;
    out[1] = s1;
    out[2] = s2;
    out[3] = s3;
    out[4] = s4;
    out[5] = s5;
}

#if MTWIP_EKF_LEAN
/* Pa = J Pa Jᵀ in place (Jr: J's nontrivial rows; Pa symmetric, and so is the result). M = J Pa column by
   column, two at a time (a column read whole before it is written: M's rows RN are Jr's rows times Pa,
   ω₋₁'s rows ω's, the others Pa's); then M Jᵀ: J's unit rows pick M's columns (ω₋₁'s ω's), the block
   between J's nontrivial rows is M's rows times Jr's, and the rest mirrors across the diagonal */
NOINLINE static void aug_jpj(real *Pa, real Jr[6][NA]) {
    static const int RN[6] = {TH, AL, V, PS, NX, NX + 1}; /* Jr's rows in J */
    real B[6][6];
    uint8_t nz[NA], in_n[NA];
    int cnt = 0, a, b, t, i, l;
    for (t = 0; t < NA; t++) {
        in_n[t] = 0;
        if (Jr[0][t] != ZERO || Jr[1][t] != ZERO || Jr[2][t] != ZERO || Jr[3][t] != ZERO || Jr[4][t] != ZERO ||
            Jr[5][t] != ZERO)
            nz[cnt++] = (uint8_t)t;
    }
    for (a = 0; a < 6; a++) in_n[RN[a]] = 1;
    for (l = 0; l < NA; l += 3) { /* M = J Pa, columns l … l + 2 (each read whole before it is written) */
        const int w = NA - l < 3 ? NA - l : 3;
        real s0 = ZERO, s1 = ZERO, s2 = ZERO, s3 = ZERO, s4 = ZERO, s5 = ZERO;
        real u0 = ZERO, u1 = ZERO, u2 = ZERO, u3 = ZERO, u4 = ZERO, u5 = ZERO;
        real v0 = ZERO, v1 = ZERO, v2 = ZERO, v3 = ZERO, v4 = ZERO, v5 = ZERO;
        for (t = 0; t < cnt; t++) {
            const int k = nz[t];
            const real *Pk = Pa + k * NA + l;
            const real p = Pk[0], q = w > 1 ? Pk[1] : ZERO, r = w > 2 ? Pk[2] : ZERO;
            const real j0 = Jr[0][k], j1 = Jr[1][k], j2 = Jr[2][k], j3 = Jr[3][k], j4 = Jr[4][k], j5 = Jr[5][k];
            s0 += j0 * p;
            s1 += j1 * p;
            s2 += j2 * p;
            s3 += j3 * p;
            s4 += j4 * p;
            s5 += j5 * p;
            u0 += j0 * q;
            u1 += j1 * q;
            u2 += j2 * q;
            u3 += j3 * q;
            u4 += j4 * q;
            u5 += j5 * q;
            v0 += j0 * r;
            v1 += j1 * r;
            v2 += j2 * r;
            v3 += j3 * r;
            v4 += j4 * r;
            v5 += j5 * r;
        }
#define PUT(c, x0, x1, x2, x3, x4, x5)                      \
    Pa[(NX + 2) * NA + (c)] = Pa[NX * NA + (c)];           \
    Pa[(NX + 3) * NA + (c)] = Pa[(NX + 1) * NA + (c)];     \
    Pa[TH * NA + (c)] = x0;                                \
    Pa[AL * NA + (c)] = x1;                                \
    Pa[V * NA + (c)] = x2;                                 \
    Pa[PS * NA + (c)] = x3;                                \
    Pa[NX * NA + (c)] = x4;                                \
    Pa[(NX + 1) * NA + (c)] = x5;
        PUT(l, s0, s1, s2, s3, s4, s5)
        if (w > 1) {
            PUT(l + 1, u0, u1, u2, u3, u4, u5)
        }
        if (w > 2) {
            PUT(l + 2, v0, v1, v2, v3, v4, v5)
        }
#undef PUT
    }
    for (a = 0; a < 6; a++) row_by_jr(Pa + RN[a] * NA, Jr, nz, cnt, B[a]); /* M's rows RN times Jr's rows */
    for (a = 0; a < 6; a++) /* (symmetric: the upper triangle's) */
        for (b = 0; b < a; b++) B[a][b] = B[b][a];
    for (i = 0; i < NA; i++) { /* J's unit rows ω₋₁ pick M's columns ω */
        Pa[i * NA + NX + 2] = Pa[i * NA + NX];
        Pa[i * NA + NX + 3] = Pa[i * NA + NX + 1];
    }
    for (a = 0; a < 6; a++) {
        for (b = 0; b < 6; b++) Pa[RN[a] * NA + RN[b]] = B[a][b];
        for (i = 0; i < NA; i++)
            if (!in_n[i]) Pa[i * NA + RN[a]] = Pa[RN[a] * NA + i];
    }
}

#else
/* Pa = J Pa Jᵀ in place (Jr: J's nontrivial rows). Each entry is the Python path's sum over j ascending
   from +0; with the factor multiplying J finite the sums leave out the terms at the columns where all six
   rows of J are zero (±0 terms: a sum that starts at +0 is never −0, so adding ±0 leaves it as it is),
   the six rows' sums running side by side. The unit rows (columns) copy their source: ω₋₁ takes ω's,
   every other its own */
static void aug_jpj(real *Pa, real Jr[6][NA]) {
    uint8_t nz[NA];
    int cnt = 0, fin = finite_aug(Pa), t, i, l;
    for (t = 0; t < NA; t++)
        if (!fin || Jr[0][t] != ZERO || Jr[1][t] != ZERO || Jr[2][t] != ZERO || Jr[3][t] != ZERO ||
            Jr[4][t] != ZERO || Jr[5][t] != ZERO)
            nz[cnt++] = (uint8_t)t;
    for (l = 0; l < NA; l++) { /* A = J Pa, column by column */
        real s0 = ZERO, s1 = ZERO, s2 = ZERO, s3 = ZERO, s4 = ZERO, s5 = ZERO;
        for (t = 0; t < cnt; t++) {
            const int j = nz[t];
            const real p = Pa[j * NA + l];
            s0 += Jr[0][j] * p;
            s1 += Jr[1][j] * p;
            s2 += Jr[2][j] * p;
            s3 += Jr[3][j] * p;
            s4 += Jr[4][j] * p;
            s5 += Jr[5][j] * p;
        }
        Pa[(NX + 2) * NA + l] = Pa[NX * NA + l];
        Pa[(NX + 3) * NA + l] = Pa[(NX + 1) * NA + l];
        Pa[TH * NA + l] = s0;
        Pa[AL * NA + l] = s1;
        Pa[V * NA + l] = s2;
        Pa[PS * NA + l] = s3;
        Pa[NX * NA + l] = s4;
        Pa[(NX + 1) * NA + l] = s5;
    }
    if (fin && !finite_aug(Pa))
        for (cnt = 0; cnt < NA; cnt++) nz[cnt] = (uint8_t)cnt;
    for (i = 0; i < NA; i++) { /* Pa = A Jᵀ, row by row */
        real *Ai = Pa + i * NA, v[6];
        row_by_jr(Ai, Jr, nz, cnt, v);
        Ai[NX + 2] = Ai[NX];
        Ai[NX + 3] = Ai[NX + 1];
        Ai[TH] = v[0];
        Ai[AL] = v[1];
        Ai[V] = v[2];
        Ai[PS] = v[3];
        Ai[NX] = v[4];
        Ai[NX + 1] = v[5];
    }
}
#endif

#if MTWIP_EKF_LEAN
/* J's rows of the synthetic sample by z = (x, ω, ω₋₁) (D's first 16 columns, in Jr[JD[i]]; 0 for the axes the
   model does not stand in for) by the chain rule: the model's raw sample by the four inputs of state6's
   output it reads (θ, θ̇, ψ̇, α̇; not ψ or α) in forward differences, state6 and scaled differentiated in
   closed form. Four model evaluations instead of the exact build's ten (one per input of the sample that
   moves it); the two differ by the forward differences' truncation, of the order of fd_step */
static void sample_jacobian(const real *z, const real *s6, const real *raw, const real *cmd, const int *rep,
                            real Jr[6][NA]) {
    static const int SC[4] = {ITH, ITHD, IPSD, IALD};
    real dr[4][4], f[4];
    real sn = MTWIP_SIN(z[TH]), cs = MTWIP_COS(z[TH]), qy = ONE / (ONE + z[SY]);
    real qz = ONE / ((ONE + z[SZ]) * cs), dz = -C->xi * sn + C->zi * cs;
    int c, i, j;
    for (c = 0; c < 4; c++) { /* ∂raw/∂(θ, θ̇, ψ̇, α̇) */
        real sp[6], rp[4], vp[2], a = MTWIP_FABS(s6[SC[c]]), h = C->fd_step * (a > ONE ? a : ONE);
        memcpy(sp, s6, sizeof sp);
        sp[SC[c]] += h;
        h = sp[SC[c]] - s6[SC[c]]; /* (the step as the number holds it) */
        synthetic_raw(&C->model, sp, cmd, (int)C->every, 1, rp, vp);
        for (i = 0; i < 4; i++) dr[i][c] = (rp[i] - raw[i]) / h;
    }
    f[0] = ONE + z[SY];
    f[1] = ONE + z[SZ];
    f[2] = ONE + z[SAX];
    f[3] = ONE + z[SAZ];
    for (j = 0; j < 16; j++) { /* column j: ∂(θ, θ̇, ψ̇, α̇)/∂z_j (state6), then the chain */
        real d[4] = {ZERO, ZERO, ZERO, ZERO};
        switch (j) {
        case TH:
            d[0] = ONE;
            d[2] = s6[ITHD] * (C->xi * cs + C->zi * sn) / C->r;
            d[3] = s6[IALD] * sn / cs;
            break;
        case V: d[2] = ONE / C->r; break;
        case BY: d[1] = -qy; break;
        case SY: d[1] = -s6[ITHD] * qy; break;
        case NX: d[1] = MTWIP_R(1.5) * qy; break;
        case NX + 2: d[1] = -HALF * qy; break;
        case BZ: d[3] = -qz; break;
        case SZ: d[3] = -s6[IALD] / (ONE + z[SZ]); break;
        case NX + 1: d[3] = MTWIP_R(1.5) * qz; break;
        case NX + 3: d[3] = -HALF * qz; break;
        default: break;
        }
        if (d[1] != ZERO) d[2] = -dz / C->r * d[1]; /* (ψ̇ through θ̇) */
        for (i = 0; i < 4; i++)
            Jr[JD[i]][j] = rep[i] ? f[i] * (((dr[i][0] * d[0] + dr[i][1] * d[1]) + dr[i][2] * d[2]) + dr[i][3] * d[3])
                                  : ZERO;
    }
    /* scaled's own factors and offsets */
    if (rep[0]) {
        Jr[JD[0]][SY] += raw[0];
        Jr[JD[0]][BY] += ONE;
    }
    if (rep[1]) {
        Jr[JD[1]][SZ] += raw[1];
        Jr[JD[1]][BZ] += ONE;
    }
    if (rep[2]) Jr[JD[2]][SAX] += raw[2];
    if (rep[3]) Jr[JD[3]][SAZ] += raw[3];
}
#endif

/* the coasting step's prediction with command cmd held; rail_v/rail_rep: the reading and which of its
   axes the model stands in for (NULL: all four) */
static int coast_predict(mtwip_estimator_t *e, const real *cmd, const real *rail_v, const uint8_t *rail_rep) {
    real *Pa = e->aug, *x = e->x;
    real s6[6], raw[4], rvar[2], syn[4], value[4], extra[4], z[16], Jr[6][NA];
    step_t st;
    int fresh = !e->aug_on, rep[4], i, j, l;
    if (fresh) {
        for (i = 0; i < NA * NA; i++) Pa[i] = ZERO;
        for (i = 0; i < NX; i++)
            for (j = 0; j < NX; j++) Pa[i * NA + j] = e->P[i * NX + j];
        for (i = 0; i < 4; i++) Pa[(NX + i) * NA + NX + i] = C->g_var;
        for (i = 0; i < NK; i++) Pa[(NX + 4 + i) * NA + NX + 4 + i] = C->unc_var[i];
        for (i = 0; i < NK; i++) e->dp[i] = ZERO;
    }
    for (i = 0; i < 4; i++) rep[i] = rail_rep ? rail_rep[i] : 1;
    for (i = 0; i < 2; i++)
        if (rep[i] && (fresh || !e->model_rate[i])) {
            real dw = e->w[i] - e->w_prev[i];
            Pa[(NX + 2 + i) * NA + NX + 2 + i] += dw * dw / MTWIP_R(3.0);
        }
    e->model_rate[0] = (uint8_t)rep[0];
    e->model_rate[1] = (uint8_t)rep[1];
    state6(x, e->w, e->w_prev, s6);
    synthetic_raw(&C->model, s6, cmd, (int)C->every, 1, raw, rvar);
    scaled(x, raw, rvar, syn, extra);
    if (!MTWIP_EKF_LEAN) /* (the lean build writes every column below) */
        for (i = 0; i < 4; i++)
            for (l = 0; l < NA; l++) Jr[JD[i]][l] = ZERO;
    for (j = 0; j < NK; j++) { /* EstimatorModel.sensitivity: forward differences (D's last columns) */
        real hi[4], hv[2];
        synthetic_raw(&C->perturbed[j], s6, cmd, (int)C->every, 1, hi, hv);
        for (i = 0; i < 4; i++) Jr[JD[i]][NX + 4 + j] = (hi[i] - raw[i]) / C->sens_step;
    }
    for (i = 0; i < 4; i++) {
        real f = i == 0 ? ONE + x[SY] : i == 1 ? ONE + x[SZ] : i == 2 ? ONE + x[SAX] : ONE + x[SAZ];
        for (j = 0; j < NK; j++) Jr[JD[i]][NX + 4 + j] = rep[i] ? Jr[JD[i]][NX + 4 + j] * f : ZERO;
    }
    for (i = 0; i < 4; i++) {
        real s = ZERO;
        for (j = 0; j < NK; j++) s += Jr[JD[i]][NX + 4 + j] * e->dp[j];
        value[i] = rep[i] ? syn[i] + s : rail_v[i];
        if (!rep[i]) extra[i] = syn[i] = ZERO; /* (syn: the sample the differences are taken from) */
    }
    memcpy(z, x, NX * sizeof(real));
    z[NX] = e->w[0];
    z[NX + 1] = e->w[1];
    z[NX + 2] = e->w_prev[0];
    z[NX + 3] = e->w_prev[1];
    propagate(z, value, extra, 1, x, &st); /* (x: the state after the step; z keeps the one before) */
#if MTWIP_EKF_LEAN
    sample_jacobian(z, s6, raw, cmd, rep, Jr);
#else
    for (j = 0; j < NX + 4; j++) { /* the sample by (x, ω, ω₋₁): forward differences */
        real zp[16], smp[4], sx[4], az = MTWIP_FABS(z[j]), h;
        if (j == PS || j == AL || j == C0 || j == H0) continue;
        h = C->fd_step * (az > ONE ? az : ONE);
        memcpy(zp, z, sizeof zp);
        zp[j] += h;
        if (j == SAX || j == SAZ) /* (state6 does not read them: the model's raw sample is the one above) */
            scaled(zp, raw, rvar, smp, sx);
        else
            synthetic(zp, zp + NX, zp + NX + 2, cmd, 1, smp, sx);
        for (i = 0; i < 4; i++) Jr[JD[i]][j] = ((rep[i] ? smp[i] : ZERO) - syn[i]) / h;
    }
#endif
    for (l = 0; l < NA; l++) { /* J's rows TH, AL, V, PS at column l: F + L D */
        real d[4], v[4];
        int a;
        for (i = 0; i < 4; i++) d[i] = Jr[JD[i]][l];
        for (a = 0; a < 4; a++) {
            real s = ZERO;
            for (i = 0; i < 4; i++) s += st.L[a][i] * d[i];
            v[a] = (l < NX ? st.F4[a][l] : ZERO) + s;
        }
        for (a = 0; a < 4; a++) Jr[a][l] = v[a];
    }
    aug_jpj(Pa, Jr);
#if MTWIP_EKF_LEAN
    for (i = 0; i < NX; i++) /* (Q on the upper triangle: Pa stays symmetric) */
        for (j = i; j < NX; j++) Pa[i * NA + j] = Pa[j * NA + i] = Pa[i * NA + j] + q_entry(&st, i, j);
#else
    for (i = 0; i < NX; i++)
        for (j = 0; j < NX; j++) Pa[i * NA + j] += q_entry(&st, i, j);
#endif
    Pa[NX * NA + NX] += rep[0] ? extra[0] : C->g_var;
    Pa[(NX + 1) * NA + NX + 1] += rep[1] ? extra[1] : C->g_var;
    block_of(e->P, Pa);
    e->w_prev[0] = e->w[0];
    e->w_prev[1] = e->w[1];
    e->w[0] = value[0];
    e->w[1] = value[1];
    e->aug_on = 1;
    return EKF_OK;
}

/* Kg (P Hᵀ on entry) := P Hᵀ S⁻¹ by Gaussian elimination with partial pivoting (detlinalg.solve), the
   consider states' rows zeroed; EKF_FAILED where that finds S singular */
static int aug_gain(const mtwip_estimator_t *e, const meas_t *em, real S[2][2], real Kg[NA][2]) {
    int i;
    if (em->dof == 1) {
        if (S[0][0] == ZERO || S[0][0] != S[0][0]) return EKF_FAILED;
        for (i = 0; i < NA; i++) Kg[i][0] = Kg[i][0] / S[0][0];
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
            real b0 = Kg[i][p], b1 = Kg[i][1 - p], x1, s;
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
    return EKF_OK;
}

/* the augmented state (x, ω, ω₋₁, δp) += K (z − (off + H x)), in place */
static void aug_state_update(mtwip_estimator_t *e, const meas_t *em, real Kg[NA][2]) {
    real y[2];
    int m = em->dof, i, j, a;
    for (a = 0; a < m; a++) {
        real s = ZERO;
        for (j = 0; j < NX; j++) s += em->H[a][j] * e->x[j];
        y[a] = em->z[a] - (s + em->off[a]);
    }
    for (i = 0; i < NA; i++) {
        real s = ZERO, *v = i < NX ? e->x + i : i < NX + 2 ? e->w + (i - NX) : i < NX + 4 ? e->w_prev + (i - NX - 2)
                                                                                         : e->dp + (i - NX - 4);
        for (a = 0; a < m; a++) s += Kg[i][a] * y[a];
        *v = *v + s;
    }
}

#if MTWIP_EKF_LEAN
/* Coasting.update: the augmented state's update in the Joseph form, (I − K H) Pa (I − K H)ᵀ + K R Kᵀ (the
   consider states' gain rows zeroed), factored: with B = Pa Hᵀ and G = B − K S it is Pa − K Bᵀ − G Kᵀ
   (G is zero but for the consider states' rows when K is the optimal gain), taken on the upper triangle
   (Pa is symmetric, and so is the result). The gain by Gaussian elimination with partial pivoting;
   EKF_FAILED where that finds S singular */
static int coast_update(mtwip_estimator_t *e, const meas_t *em) {
    real *Pa = e->aug, Kg[NA][2], B[NA][2], G[NA][2], S[2][2], h[2][NX];
    int m = em->dof, u[NX], nu = 0, i, j, a, b, t;
    for (j = 0; j < NX; j++) /* H's columns that are not zero */
        for (a = 0; a < m; a++)
            if (em->H[a][j] != ZERO) {
                u[nu++] = j;
                break;
            }
    for (a = 0; a < 2; a++) /* H's nonzero entries, gathered */
        for (t = 0; t < nu; t++) h[a][t] = a < m ? em->H[a][u[t]] : ZERO;
    for (i = 0; i < NA; i++) { /* B = Pa Hᵀ */
        const real *Pi = Pa + i * NA;
        real s0 = ZERO, s1 = ZERO;
        for (t = 0; t < nu; t++) {
            const real p = Pi[u[t]];
            s0 += p * h[0][t];
            s1 += p * h[1][t];
        }
        Kg[i][0] = B[i][0] = s0;
        Kg[i][1] = B[i][1] = s1;
    }
    for (a = 0; a < m; a++)
        for (b = 0; b < m; b++) {
            real s = ZERO;
            for (t = 0; t < nu; t++) s += em->H[a][u[t]] * B[u[t]][b];
            S[a][b] = s + (a == b ? em->R[a] : ZERO);
        }
    if (aug_gain(e, em, S, Kg) != EKF_OK) return EKF_FAILED;
    aug_state_update(e, em, Kg);
    for (i = 0; i < NA; i++)
        for (a = 0; a < m; a++) {
            real s = B[i][a];
            for (b = 0; b < m; b++) s -= Kg[i][b] * S[b][a];
            G[i][a] = s;
        }
    for (i = 0; i < NA; i++) {
        const real k0 = Kg[i][0], g0 = G[i][0], k1 = m > 1 ? Kg[i][1] : ZERO, g1 = m > 1 ? G[i][1] : ZERO;
        real *Pi = Pa + i * NA;
        if (m > 1)
            for (j = i; j < NA; j++) {
                const real v = Pi[j] - ((k0 * B[j][0] + g0 * Kg[j][0]) + (k1 * B[j][1] + g1 * Kg[j][1]));
                Pi[j] = Pa[j * NA + i] = v;
            }
        else
            for (j = i; j < NA; j++) {
                const real v = Pi[j] - (k0 * B[j][0] + g0 * Kg[j][0]);
                Pi[j] = Pa[j * NA + i] = v;
            }
    }
    block_of(e->P, Pa);
    return EKF_OK;
}
#else
#define NU 5    /* the most columns of H that are not zero (h_row: TH, PS, AL, C0, H0; coast_update's sums unrolled) */
#define UNIT 255 /* coast_update: a row of I − K H that is the identity's */
#define DG s += q; /* coast_update: the diagonal's term, 1 × q */
/* the sum of GT(0) … GT(4) (H's five nonzero columns) with the diagonal's term DG in its place, at
   position `at` (UNIT: the row is the identity's, its diagonal alone; else past the five) */
#define FIVE_TERMS(at)                                                   \
    switch (at) {                                                        \
    case 0: DG GT(0) GT(1) GT(2) GT(3) GT(4) break;                      \
    case 1: GT(0) DG GT(1) GT(2) GT(3) GT(4) break;                      \
    case 2: GT(0) GT(1) DG GT(2) GT(3) GT(4) break;                      \
    case 3: GT(0) GT(1) GT(2) DG GT(3) GT(4) break;                      \
    case 4: GT(0) GT(1) GT(2) GT(3) DG GT(4) break;                      \
    case 5: GT(0) GT(1) GT(2) GT(3) GT(4) DG break;                      \
    case UNIT: DG break;                                                 \
    default: GT(0) GT(1) GT(2) GT(3) GT(4) break;                        \
    }

/* where the diagonal's term of row i < NX goes among H's nonzero columns u (NU + 1: it is one of them) */
static int diagonal_at(const int *u, int nu, int i) {
    int t;
    for (t = 0; t < nu && u[t] < i; t++)
        ;
    return t < nu && u[t] == i ? NU + 1 : t;
}

/* (I − Kg Ha)[i][l] of the augmented update (Ha: H's rows, zero beyond the 12 states) */
static real ikh_aug(real Kg[NA][2], const meas_t *em, int i, int l) {
    real kh = ZERO;
    int a;
    if (l >= NX) return i == l ? ONE : ZERO;
    for (a = 0; a < em->dof; a++) kh += Kg[i][a] * em->H[a][l];
    return (i == l ? ONE : ZERO) - kh;
}

/* Coasting.update: the augmented state's update (Joseph form, the consider states' gain rows zeroed),
   the gain by Gaussian elimination with partial pivoting (detlinalg.solve); EKF_FAILED where that
   finds S singular */
static int coast_update(mtwip_estimator_t *e, const meas_t *em) {
    real *Pa = e->aug, Kg[NA][2], S[2][2], row[NA], Rm[2][2], G[NA][NU];
    uint8_t dg[NA], kz[NA];
    int m = em->dof, u[NU], nu = 0, fin, i, j, a, b, k, t;
    for (k = 0; k < NX; k++) { /* H's columns that are not zero */
        int on = 0;
        for (a = 0; a < m; a++) on |= em->H[a][k] != ZERO;
        if (on) {
            if (nu == NU) break;
            u[nu++] = k;
        }
    }
    /* with Pa finite, P Hᵀ's sums leave out the terms of H's zero columns (see cov_predict) */
    fin = k == NX && finite_aug(Pa);
    for (i = 0; i < NA; i++) /* P Hᵀ (in Kg, which takes the gain in its place) */
        for (a = 0; a < m; a++) {
            real s = ZERO;
            if (fin)
                for (t = 0; t < nu; t++) s += Pa[i * NA + u[t]] * em->H[a][u[t]];
            else
                for (j = 0; j < NX; j++) s += Pa[i * NA + j] * em->H[a][j];
            Kg[i][a] = s;
        }
    for (a = 0; a < m; a++)
        for (b = 0; b < m; b++) {
            real s = ZERO;
            for (i = 0; i < NX; i++) s += em->H[a][i] * Kg[i][b];
            Rm[a][b] = a == b ? em->R[a] : ZERO;
            S[a][b] = s + Rm[a][b];
        }
    if (aug_gain(e, em, S, Kg) != EKF_OK) return EKF_FAILED;
    aug_state_update(e, em, Kg);
    /* I − K H's entries at H's nonzero columns u (as ikh_aug). With K finite, its entries at the other
       columns are exact: +0 off the diagonal (0 − a sum of ±0 from +0), 1 on it; with Pa (then A) finite
       too, the products' sums leave out the +0 terms and take the diagonal's 1 × P as P, each in its place
       of the ascending order. Otherwise the full sums */
    for (i = 0; i < NA && fin; i++)
        for (a = 0; a < m; a++) fin = MTWIP_ISFINITE(Kg[i][a]) != 0;
    /* dg: where row i's diagonal 1 goes among u (NU + 1: none, or its place is one of u's), or UNIT: the
       row is the identity's (its entries at u +0 but the diagonal's 1); kz: row i of K is zero */
    for (i = 0; i < NA; i++) {
        int unit = i < NX;
        dg[i] = NU + 1;
        for (t = 0; t < nu; t++) {
            G[i][t] = ikh_aug(Kg, em, i, u[t]);
            if (G[i][t] != (u[t] == i ? ONE : ZERO)) unit = 0;
        }
        if (i < NX) dg[i] = (uint8_t)diagonal_at(u, nu, i);
        if (unit) dg[i] = UNIT;
        kz[i] = 1;
        for (a = 0; a < m; a++)
            if (Kg[i][a] != ZERO) kz[i] = 0;
    }
    if (fin && nu == NU) { /* the sums unrolled: u's five terms, the diagonal's in its place */
        for (j = 0; j < NA; j++) { /* A = (I − K H) Pa, column by column */
            const real p0 = Pa[u[0] * NA + j], p1 = Pa[u[1] * NA + j], p2 = Pa[u[2] * NA + j],
                       p3 = Pa[u[3] * NA + j], p4 = Pa[u[4] * NA + j];
            for (i = 0; i < NA; i++) {
                const real *Gi = G[i], q = Pa[i * NA + j];
                real s = ZERO;
#define GT(t) s += Gi[t] * p##t;
                FIVE_TERMS(dg[i])
#undef GT
                if (i >= NX) s += q;
                row[i] = s;
            }
            for (i = 0; i < NA; i++) Pa[i * NA + j] = row[i];
        }
    } else
        for (j = 0; j < NA; j++) { /* A = (I − K H) Pa, column by column */
            for (i = 0; i < NA; i++) {
                real s = ZERO;
                if (fin) {
                    const real *Gi = G[i], *Pj = Pa + j;
                    int d = dg[i] == UNIT ? diagonal_at(u, nu, i) : dg[i];
                    for (t = 0; t < nu && t < d; t++) s += Gi[t] * Pj[u[t] * NA];
                    if (d <= NU) {
                        s += Pj[i * NA];
                        for (; t < nu; t++) s += Gi[t] * Pj[u[t] * NA];
                    }
                } else
                    for (k = 0; k < NX; k++) s += ikh_aug(Kg, em, i, k) * Pa[k * NA + j];
                if (i >= NX) s += Pa[i * NA + j];
                row[i] = s;
            }
            for (i = 0; i < NA; i++) Pa[i * NA + j] = row[i];
        }
    fin = fin && finite_aug(Pa);
    for (i = 0; i < NA; i++) { /* Pa = A (I − K H)ᵀ + K R Kᵀ, row by row */
        const real *Ai = Pa + i * NA;
        real kr[2] = {ZERO, ZERO};
        int kzero, kfin;
        for (b = 0; b < m; b++) {
            kr[b] = ZERO;
            for (a = 0; a < m; a++) kr[b] += Kg[i][a] * Rm[a][b];
        }
        /* K R Kᵀ's entry, the sum over b from +0: +0 where row i's kr or (kr finite) row j of K is zero,
           every term ±0 then (K is finite on this path) */
        kzero = kr[0] == ZERO && (m < 2 || kr[1] == ZERO);
        kfin = 1;
        for (b = 0; b < m; b++) kfin = kfin && MTWIP_ISFINITE(kr[b]);
        if (fin && nu == NU) {
            const real a0 = Ai[u[0]], a1 = Ai[u[1]], a2 = Ai[u[2]], a3 = Ai[u[3]], a4 = Ai[u[4]];
            for (j = 0; j < NA; j++) {
                const real *Gj = G[j], q = Ai[j];
                real s = ZERO, t2 = ZERO;
#define GT(t) s += a##t * Gj[t];
                FIVE_TERMS(dg[j])
#undef GT
                if (j >= NX) s += q;
                if (!kzero && !(kfin && kz[j])) {
                    t2 += kr[0] * Kg[j][0];
                    if (m > 1) t2 += kr[1] * Kg[j][1];
                }
                row[j] = s + t2;
            }
        } else
            for (j = 0; j < NA; j++) {
                real s = ZERO, t2 = ZERO;
                if (fin) {
                    const real *Gj = G[j];
                    int d = dg[j] == UNIT ? diagonal_at(u, nu, j) : dg[j];
                    for (t = 0; t < nu && t < d; t++) s += Ai[u[t]] * Gj[t];
                    if (d <= NU) {
                        s += Ai[j];
                        for (; t < nu; t++) s += Ai[u[t]] * Gj[t];
                    }
                } else
                    for (k = 0; k < NX; k++) s += Ai[k] * ikh_aug(Kg, em, j, k);
                if (j >= NX) s += Ai[j];
                for (b = 0; b < m; b++) t2 += kr[b] * Kg[j][b];
                row[j] = s + t2;
            }
        for (j = 0; j < NA; j++) Pa[i * NA + j] = row[j];
    }
    symmetrise(Pa, NA);
    block_of(e->P, Pa);
    return EKF_OK;
}
#endif

/* Fusion.encoder_step after a coasting prediction */
static int coast_encoders(mtwip_estimator_t *e, const real *enc) {
    meas_t em;
    real eps;
    int zero_div, r;
    if (!enc) return EKF_OK;
    eps = encoder_fit(enc, e->last_enc, span(e->last_enc_m, e->at), e->x, e->w, e->P, FIT_PY, &em, &zero_div, NULL);
    if (em.dof == 0) { /* unchanged counts: the wheels are still inside them */
        e->last_enc_m = e->at;
        r = keep_inside(e, enc, 1, -1);
        if (r < 0) return EKF_FAILED;
        count_check(e, r >> 4);
        return EKF_OK;
    }
    if (zero_div) return EKF_FAILED;
    if (!(eps <= C->gate[em.dof - 1])) { /* Fusion.passes */
        if (e->in_row < C->max_rejects_in_row) {
            e->in_row++;
            return EKF_OK;
        }
    }
    e->in_row = 0;
    if (coast_update(e, &em) != EKF_OK) return EKF_FAILED;
    r = keep_inside(e, enc, 1, -1);
    if (r < 0) return EKF_FAILED;
    count_check(e, r >> 4);
    memcpy(e->last_enc, enc, sizeof e->last_enc);
    e->last_enc_m = e->at;
    return EKF_OK;
}

/* Fusion.coast: equation (1) stands in for the IMU (rail: the reading and its censored axes) */
static void coast(mtwip_estimator_t *e, const real *enc, const real *cmd, const real *rail_v, const uint8_t *rail_rep) {
    int rc;
    e->coasted = 1;
    keep_good(e); /* the core's take_over: the state as it is now is the last good one */
    rc = coast_predict(e, cmd, rail_v, rail_rep);
    if (rc == EKF_OK) rc = coast_encoders(e, enc);
    if (rc == EKF_OK) { /* Fusion.finish (the lean build's P is symmetric as made) */
        if (!MTWIP_EKF_LEAN) symmetrise(e->P, NX);
        if (healthy(e->x, e->P)) {
            int inside = in_range(e->x, e->P); /* (eliminates in P: P is the augmented block, symmetrised) */
            block_of(e->P, e->aug);
            if (!MTWIP_EKF_LEAN) symmetrise(e->P, NX);
            if (!inside) lost(e);
            keep_good(e);
            return; /* (the core's push would keep the same state again) */
        }
        restore(e);
        e->aug_on = 0;
    } else { /* where the Python path raises: EKFEstimator.step restores the last good state */
        restore(e);
        e->aug_on = 0;
    }
    push(e);
}

/* Fusion.advance: the step of sample time e->at with the IMU sample (gyro: ω_y, ω_z; accel: f_x, f_z;
   NULL: none) */
static void advance(mtwip_estimator_t *e, const real *gyro, const real *accel, const real *enc, const real *cmd) {
    if (gyro) {
        real v[4];
        uint8_t rep[4];
        int acc_out, j, railed = 0;
        real err[2];
        v[0] = gyro[0];
        v[1] = gyro[1];
        v[2] = accel[0];
        v[3] = accel[1];
        for (j = 0; j < 4; j++) {
            rep[j] = MTWIP_FABS(v[j]) >= C->rails[j];
            railed |= rep[j];
        }
        if (railed) { /* SensorFrontEnd.railed: the model stands in for the clipped axes */
            accel_seen(e, NULL, 0);
            coast(e, enc, cmd, v, rep);
            return;
        }
        if (!imu_step(e, v, enc, cmd, &acc_out, err)) {
            accel_seen(e, err, acc_out);
            e->aug_on = 0; /* a real sample: ω is a reading again */
            return;
        }
        accel_seen(e, err, acc_out);
        e->imu_outliers++;
    }
    coast(e, enc, cmd, NULL, NULL);
}

/* ---- the interface ------------------------------------------------------------------------ */
static void clear(mtwip_estimator_t *e) {
    int i;
    memset(e, 0, sizeof *e);
    e->k = -1;
    for (i = 0; i < RING; i++) e->gyro[i].key = e->acc[i].key = e->enc[i].key = e->cmd[i].key = EMPTY;
    e->d_gyro = e->d_acc = C->d_imu;
    e->lag = C->d_imu > C->d_enc ? C->d_imu : C->d_enc;
}

void mtwip_estimator_init(mtwip_estimator_t *e) { clear(e); }

/* EKFEstimator.start: the first readings, the robot at rest. (The Python side refuses a start without
   a finite gyro and accelerometer reading; here the accelerometer's absence leaves θ unknown in
   (−π/2, π/2) and the gyro's takes the rates as 0.) */
void mtwip_estimator_start(mtwip_estimator_t *e, const mtwip_sample_t *sample, mtwip_real estimate[6]) {
    int acc_ok = sample->has_accel && finite_n(sample->accel, 3);
    int gyro_ok = sample->has_gyro && finite_n(sample->gyro, 3);
    int i;
    real zero_cmd[2];
    clear(e);
    prior(e, acc_ok ? sample->accel : NULL, 0);
    e->w[0] = e->w_prev[0] = gyro_ok ? sample->gyro[1] : ZERO;
    e->w[1] = e->w_prev[1] = gyro_ok ? sample->gyro[2] : ZERO;
    push(e);
    e->k = 0;
    e->m = 0;
    zero_cmd[0] = zero_cmd[1] = ZERO;
    store(e, sample, 0, 0, zero_cmd, 0);
    if (sample->has_encoder && finite_n(sample->encoder, 2)) {
        memcpy(e->last_enc, sample->encoder, sizeof e->last_enc);
        e->has_last_enc = 1;
        e->last_enc_m = -C->d_enc;
    }
    for (i = 0; i < NX; i++) e->consider[i] = C->untaught[i];
    keep_good(e);
    state6(e->x, e->w, e->w_prev, estimate);
    memcpy(e->last_estimate, estimate, sizeof e->last_estimate);
}

/* EKFEstimator.step: the readings that arrived now and the torques (N m) commanded over the period
   that just ended; the estimate predicted forward to now across the filter's lag */
void mtwip_estimator_step(mtwip_estimator_t *e, const mtwip_sample_t *sample, const mtwip_real command[2],
                          mtwip_real estimate[6]) {
    mtwip_ekf_slot_t *slot;
    real s[6], s0[6], u[2];
    int32_t k, m, j;
    int i, finite = 1;
    if (e->k < 0) { /* (the Python side refuses a step before start) */
        mtwip_estimator_start(e, sample, estimate);
        return;
    }
    k = ++e->k;
    e->coasted = 0;
    slot = &e->cmd[ring_index(k - 1)];
    slot->key = k - 1;
    slot->v[0] = command[0];
    slot->v[1] = command[1];
    store(e, sample, k, e->m, command, 1);
    for (m = e->m + C->every; m <= k - e->lag; m += C->every) {
        const mtwip_ekf_slot_t *g, *a, *en;
        const real *enc;
        real t = (real)k / C->control_rate - (real)(k - m) * C->model.dt;
        if (!e->holding && C->has_hold && t >= C->hold_from) {
            e->holding = 1;
            for (i = 0; i < NX; i++) e->consider[i] = C->consider[i];
        }
        e->at = m;
        g = ring_get(e->gyro, m);
        a = ring_get(e->acc, m);
        en = ring_get(e->enc, m);
        enc = screen_encoders(e, en ? en->v : NULL, m);
        command_of(e, m - C->every, u);
        advance(e, g && a ? g->v : NULL, g && a ? a->v : NULL, enc, u);
        e->m = m;
    }
    /* the lean build's latency watch: a check that fell due runs once the filter has taken a step without
       coasting (a coasting step has the most work of any; the check waits for one with less) */
    if (MTWIP_EKF_LEAN && e->w_due && !e->coasted && e->w_len == WN) {
        int32_t found;
        e->w_due = 0;
        if (watch_decide(e, e->d_gyro, &found)) latency_changed(e, k, e->m, found);
    }
    /* the forward prediction across the lag (the kernel's forward) */
    state6(e->x, e->w, e->w_prev, s0);
    memcpy(s, s0, sizeof s);
    for (j = e->m; j < k; j++) {
        real tl, tr;
        command_of(e, j, u);
        delivered(&C->model, s, u[0], u[1], &tl, &tr);
        model_step(&C->model, s, tl, tr, 1, 0, NULL);
    }
    for (i = 0; i < 6; i++) finite &= MTWIP_ISFINITE(s[i]) != 0;
    if (!finite) {
        memcpy(s, s0, sizeof s);
        if (!finite_n(s, 6)) memcpy(s, e->last_estimate, sizeof s);
    }
    memcpy(e->last_estimate, s, sizeof s);
    memcpy(estimate, s, sizeof s);
}
