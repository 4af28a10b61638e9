/* Optional compiled path of the twin's EKF (estimation/ekf.py).

   The same algorithm as EKFEstimator's pure-Python path (which runs on filterpy's
   ExtendedKalmanFilter), for one filter step at a time; the Python wrapper keeps the
   bookkeeping (sample queues, counters, events). tests/test_estimator_kernel.py checks
   that both paths agree to rounding: the matrix products sum in another order than
   NumPy's, so the paths are close, not bit-identical; each is deterministic.

   Every constant and policy threshold comes from the configuration the filter is built with
   (estimation.ekf_config.KernelConfig, read by field name; the fields' list is the generated
   header _ekf_config.h): this file writes none of the policy's numbers (estimation.ekf_config
   says why the rules themselves are written here and in Python, and what holds them together).

     new(config)                       -> capsule holding the filter (see Core), config a KernelConfig
     config_fields()                   -> the configuration's field names, in the order read
     set_state(core, x, P, w, w_prev)  /  state(core) -> (x, P, w, w_prev) as tuples
     advance(core, imu, enc, last, T, command, in_row, acc_test)
         one step driven by an IMU sample (steps without one, or with one rejected, coast
         in Python: estimation.ekf_filter.Coasting).
         imu = (ω_y, ω_z, f_x, f_z), optionally followed by the variances (4,) the sample adds
         (point samples rebuilt as interval means); enc, last = (e_l, e_r) or None; T the time since the
         encoder sample ``last`` (s); command = (ul, ur) N·m held over the step; in_row the
         encoder samples rejected in a row so far (from max_rejects_in_row on the next is forced in).
         acc_test = (gate, b_x, b_z, may): gate > 0 computes the accelerometer half's innovation
         e against the model's (f_x, f_z); with may != 0 the half is an outlier (replaced by the
         model's) when (e − b)ᵀ S⁻¹ (e − b) > accel_variance_factor × gate, b the recent
         innovations' median
         -> (imu_code, saturated, enc_code, nis, dof, healthy, acc_out, e_x, e_z, inside)
            imu_code 1 used; 2 an outlier (the encoders fail the IMU gate with it and pass the
            normal gate with the model's sample): nothing changed, nis is the encoders' NIS
            with it, and the Python side coasts instead
            enc_code 0 no sample, 1 unchanged counts, 2 used, 3 rejected, 4 used although
            failing the gate (forced in after max_rejects_in_row rejections); healthy 0 if the state had to be restored
            (non-finite), -1 if it left the physical range (in_range: the Python side
            re-initialises it, estimation.ekf_fusion.Fusion.lost);
            inside the truncated updates that brought a wheel back into its unchanged count
     forward(core, commands) -> ([θ, θ̇, ψ, ψ̇, α, α̇] predicted over the commands, finite)
     state6(core) -> the filter's own [θ, θ̇, ψ, ψ̇, α, α̇]
     set_consider(core, mask)          mask (12,): 1.0 for a state the updates leave alone (Schmidt)
     innovation(core) -> (y, S)        the last encoder update's innovation (dof,) rad and its
                                       covariance (dof × dof, row-major) rad², for diagnostics()
     state_into(core, buffer[, row])   x then P as float64 into row `row` (default 0) of a buffer

   Built by setup.py with -ffp-contract=off like the other kernels. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdlib.h>
#include <stddef.h>
#include <string.h>

#include "_ekf_config.h"

#define NX 12
enum { TH, PS, V, AL, BY, BZ, C0, SY, H0, SZ, SAX, SAZ };
enum { ITH, ITHD, IPS, IPSD, IAL, IALD };

typedef struct {
    /* the configuration (estimation.ekf_config.KernelConfig, every field a double or an array of
       them, in the generated header's order; its units there): the filter's constants, the
       estimator's model (equation (1) with d_b + c_e, and the motors' driver) and the policy's
       thresholds (estimation.ekf_config.POLICY), none of which is written in this file */
#define CONFIG_SCALAR(name) double name;
#define CONFIG_ARRAY(name, n) double name[n];
    EKF_CONFIG(CONFIG_SCALAR, CONFIG_ARRAY)
#undef CONFIG_SCALAR
#undef CONFIG_ARRAY
    /* 1.0 for a consider state (Schmidt): kept in P, never corrected by a measurement */
    double consider[NX];
    /* state */
    double x[NX], P[NX * NX], w[2], w_prev[2];
    double xg[NX], Pg[NX * NX], wg[2], wpg[2];
    /* the last encoder update's innovation y (inn_dof,) and its covariance S: diagnostics only */
    double inn_y[2], inn_S[4];
    int inn_dof;
    /* point-sampled IMU rows (EKFEstimator.set_sampling): the covariance of the state's error with
       the last sample's noise n_k per axis (ω_y, ω_z, f_x, f_z), column-major by axis (NX per
       axis); the next interval's mean (n_k + n_{k+1}) / 2 shares n_k. Zero: nothing carried */
    double Cx[4 * NX];
} Core;

/* the configuration's fields by name: new() reads each from the KernelConfig it is given */
typedef struct {
    const char *name;
    size_t offset;
    Py_ssize_t n;
} ConfigField;

static const ConfigField config_fields[] = {
#define CONFIG_SCALAR(name) {#name, offsetof(Core, name), 1},
#define CONFIG_ARRAY(name, n) {#name, offsetof(Core, name), n},
    EKF_CONFIG(CONFIG_SCALAR, CONFIG_ARRAY)
#undef CONFIG_SCALAR
#undef CONFIG_ARRAY
};

static void core_free(PyObject *cap) { PyMem_Free(PyCapsule_GetPointer(cap, "ekf_core")); }

static Core *get(PyObject *cap) { return (Core *)PyCapsule_GetPointer(cap, "ekf_core"); }

static int floats(PyObject *seq, double *out, Py_ssize_t n, const char *what) {
    PyObject *f = PySequence_Fast(seq, what);
    if (!f) return -1;
    if (PySequence_Fast_GET_SIZE(f) != n) {
        PyErr_Format(PyExc_ValueError, "%s must have %zd numbers", what, n);
        Py_DECREF(f);
        return -1;
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        out[i] = PyFloat_AsDouble(PySequence_Fast_GET_ITEM(f, i));
        if (out[i] == -1.0 && PyErr_Occurred()) {
            Py_DECREF(f);
            return -1;
        }
    }
    Py_DECREF(f);
    return 0;
}

static PyObject *tuple_of(const double *v, int n) {
    PyObject *t = PyTuple_New(n);
    if (!t) return NULL;
    for (int i = 0; i < n; i++) {
        PyObject *f = PyFloat_FromDouble(v[i]);
        if (!f) {
            Py_DECREF(t);
            return NULL;
        }
        PyTuple_SET_ITEM(t, i, f);
    }
    return t;
}

/* ---- the model (estimation/model.py) ------------------------------------------------ */
static void rhs(const Core *c, const double *s, double ul, double ur, double *d) {
    double th = s[0], thd = s[1], psd = s[3], ald = s[5];
    double sn = sin(th), cs = cos(th);
    double drive = 2.0 * c->d_b * (thd - psd);
    double u = ul + ur;
    double rhs1 = c->m12 * (thd * thd + ald * ald) * sn - 2.0 * c->d_w * psd + drive + u + 0.0;
    double rhs2 = c->n_bla * ald * ald * sn * cs + c->g_b * sn - drive - u + 0.0;
    double mc = c->m12 * cs;
    double det = c->m11 * c->m22 - mc * mc;
    double yaw = -2.0 * c->n_bla * ald * thd * sn * cs - c->m12 * ald * psd * sn - c->yaw_damping * ald +
                 c->b_r * (ur - ul) + 0.0;
    d[0] = thd;
    d[1] = (c->m11 * rhs2 - c->m12 * cs * rhs1) / det;
    d[2] = psd;
    d[3] = (c->m22 * rhs1 - c->m12 * cs * rhs2) / det;
    d[4] = ald;
    d[5] = yaw / (c->m33 + c->n_bla * sn * sn);
}

static void model_step(const Core *c, double *s, double tl, double tr, int periods) {
    double k1[6], k2[6], k3[6], k4[6], y[6], dt = c->mdt / c->msub;
    int n = periods * (int)c->msub;
    for (int p = 0; p < n; p++) {
        rhs(c, s, tl, tr, k1);
        for (int i = 0; i < 6; i++) y[i] = s[i] + 0.5 * dt * k1[i];
        rhs(c, y, tl, tr, k2);
        for (int i = 0; i < 6; i++) y[i] = s[i] + 0.5 * dt * k2[i];
        rhs(c, y, tl, tr, k3);
        for (int i = 0; i < 6; i++) y[i] = s[i] + dt * k3[i];
        rhs(c, y, tl, tr, k4);
        for (int i = 0; i < 6; i++) s[i] = s[i] + (dt / 6.0) * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
    }
}

static double clip(double v, double lim) { return v > lim ? lim : (v < -lim ? -lim : v); }

static void delivered(const Core *c, const double *s, double ul, double ur, double *tl, double *tr) {
    if (c->has_motor == 0.0) {
        *tl = ul;
        *tr = ur;
        return;
    }
    ul = clip(ul, c->i_tau);
    ur = clip(ur, c->i_tau);
    if (c->compensates != 0.0) {
        double w = s[IPSD] - s[ITHD], h = c->b_r * s[IALD];
        ul += c->c_e * (w - h);
        ur += c->c_e * (w + h);
    }
    *tl = clip(ul, c->tau_max);
    *tr = clip(ur, c->tau_max);
}

static double torque_var(const Core *c, double tau) {
    double a = c->tol * tau;
    return c->sigma_tau * c->sigma_tau + a * a;
}

/* ---- the filter --------------------------------------------------------------------- */
static void state6(const Core *c, const double *x, double *s) {
    double wy = 1.5 * c->w[0] - 0.5 * c->w_prev[0], wz = 1.5 * c->w[1] - 0.5 * c->w_prev[1];
    double th = x[TH];
    double thd = (wy - x[BY]) / (1.0 + x[SY]);
    double ald = (wz - x[BZ]) / ((1.0 + x[SZ]) * cos(th));
    double dz = -c->xi * sin(th) + c->zi * cos(th);
    s[0] = th;
    s[1] = thd;
    s[2] = x[PS];
    s[3] = (x[V] - thd * dz) / c->r;
    s[4] = x[AL];
    s[5] = ald;
}

/* the IMU sample equation (1) predicts (as the sensor would read it) and its extra variances */
static void synthetic(const Core *c, const double *x, double ul, double ur, double *smp, double *extra) {
    double s[6], s1[6], tl, tr;
    int periods = (int)c->every;
    state6(c, x, s);
    delivered(c, s, ul, ur, &tl, &tr);
    memcpy(s1, s, sizeof s);
    model_step(c, s1, tl, tr, periods);
    double t = periods * c->mdt, xi = c->xi, zi = c->zi, r = c->r;
    double sn0 = sin(s[ITH]), cs0 = cos(s[ITH]), sn1 = sin(s1[ITH]), cs1 = cos(s1[ITH]);
    double dx0 = xi * cs0 + zi * sn0, dz0 = -xi * sn0 + zi * cs0;
    double dx1 = xi * cs1 + zi * sn1, dz1 = -xi * sn1 + zi * cs1;
    double u0 = r * s[IPSD] + s[ITHD] * dz0, w0 = -s[ITHD] * dx0;
    double u1 = r * s1[IPSD] + s1[ITHD] * dz1, w1 = -s1[ITHD] * dx1;
    double ald = (s1[IAL] - s[IAL]) / t;
    double Fx = (u1 - u0) / t - ald * ald * dx1;
    double Fz = (w1 - w0) / t + c->g;
    double fx = Fx * cs1 - Fz * sn1, fz = Fx * sn1 + Fz * cs1;
    double thm = (s1[ITH] - s[ITH]) / t;
    double mc = c->m12 * cs1;
    double det = c->m11 * c->m22 - mc * mc;
    double dthdd = -(c->m11 + c->m12 * cs1) / det, dpsdd = (c->m22 + c->m12 * cs1) / det;
    double var_tau = torque_var(c, tl) + torque_var(c, tr);
    double a = 0.5 * dthdd * t, b = r * dpsdd + zi * dthdd;
    double gv = a * a * var_tau, av = b * b * var_tau;
    double wz = ald * cos(0.5 * (s[ITH] + s1[ITH]));
    smp[0] = (1.0 + x[SY]) * thm + x[BY];
    smp[1] = (1.0 + x[SZ]) * wz + x[BZ];
    smp[2] = (1.0 + x[SAX]) * fx;
    smp[3] = (1.0 + x[SAZ]) * fz;
    extra[0] = extra[1] = gv;
    extra[2] = extra[3] = av;
}

/* one strapdown step: x1, F, Q from x and the sample (ω_y, ω_z, f_x, f_z) (see StrapdownFilter.propagate) */
static void propagate(const Core *c, const double *x, const double *smp, const double *extra, const double *half,
                      double *x1, double *F, double *Q, double *Cx_new) {
    double wy = smp[0], wz = smp[1], fx = smp[2], fz = smp[3];
    double dt = c->dt, r = c->r, xi = c->xi, zi = c->zi;
    double th = x[TH], v = x[V];
    double q = 1.0 / (1.0 + x[SY]), qz = 1.0 / (1.0 + x[SZ]), qax = 1.0 / (1.0 + x[SAX]), qaz = 1.0 / (1.0 + x[SAZ]);
    double thm = (wy - x[BY]) * q;
    double th1 = th + dt * thm;
    double thb = 0.5 * (th + th1);
    double s0 = sin(th), c0 = cos(th), s1 = sin(th1), c1 = cos(th1);
    double cb = cos(thb), tb = tan(thb);
    double ad = (wz - x[BZ]) * qz / cb;
    double dx0 = xi * c0 + zi * s0, dz0 = -xi * s0 + zi * c0;
    double dx1 = xi * c1 + zi * s1, dz1 = -xi * s1 + zi * c1;
    double fxt = fx * qax, fzt = fz * qaz;
    double Fx = c1 * fxt + s1 * fzt, Fz = -s1 * fxt + c1 * fzt;
    double v1 = v + dt * (Fx + ad * ad * dx1);
    memcpy(x1, x, NX * sizeof(double));
    x1[TH] = th1;
    x1[AL] = x[AL] + dt * ad;
    x1[V] = v1;
    x1[PS] = x[PS] + (0.5 * dt * (v + v1) - dx1 + dx0) / r;

    double dth1[NX] = {0}, dad[NX] = {0}, dFx[NX], dv1[NX];
    dth1[TH] = 1.0;
    dth1[BY] = -dt * q;
    dth1[SY] = -dt * thm * q;
    double ith1[4] = {dt * q, 0.0, 0.0, 0.0};
    double k = ad * tb * 0.5;
    for (int j = 0; j < NX; j++) dad[j] = k * ((j == TH) + dth1[j]);
    dad[BZ] -= qz / cb;
    dad[SZ] -= ad * qz;
    double iad[4] = {k * ith1[0], qz / cb, 0.0, 0.0};
    for (int j = 0; j < NX; j++) dFx[j] = Fz * dth1[j];
    dFx[SAX] -= c1 * fxt * qax;
    dFx[SAZ] -= s1 * fzt * qaz;
    double iFx[4] = {Fz * ith1[0], 0.0, c1 * qax, s1 * qaz};
    double a2 = 2.0 * ad * dx1, a3 = ad * ad * dz1;
    for (int j = 0; j < NX; j++) dv1[j] = (j == V) + dt * (dFx[j] + a2 * dad[j] + a3 * dth1[j]);
    double iv1[4], L[4][4]; /* rows TH, AL, V, PS of the noise map */
    for (int j = 0; j < 4; j++) iv1[j] = dt * (iFx[j] + a2 * iad[j] + a3 * ith1[j]);
    memset(F, 0, NX * NX * sizeof(double));
    for (int i = 0; i < NX; i++) F[i * NX + i] = 1.0;
    for (int j = 0; j < NX; j++) {
        F[TH * NX + j] = dth1[j];
        F[AL * NX + j] = (j == AL) + dt * dad[j];
        F[V * NX + j] = dv1[j];
        F[PS * NX + j] = ((j == PS) + (0.5 * dt * ((j == V) + dv1[j]) - dz1 * dth1[j] + dz0 * (j == TH)) / r);
    }
    for (int j = 0; j < 4; j++) {
        L[0][j] = ith1[j];
        L[1][j] = dt * iad[j];
        L[2][j] = iv1[j];
        L[3][j] = (0.5 * dt * iv1[j] - dz1 * ith1[j]) / r;
    }
    double base[4] = {c->g_var, c->g_var, c->a_var, c->a_var}, var[4];
    /* half[j]: the axis's mean is the trapezoid (n_{k-1} + n_k) / 2 of two point samples' noise:
       its own variance σ²/2, and its n_{k-1} half is correlated with the state through Cx */
    for (int j = 0; j < 4; j++) var[j] = (half && half[j] != 0.0 ? 0.5 : 1.0) * base[j] + (extra ? extra[j] : 0.0);
    static const int rows[4] = {TH, AL, V, PS};
    memset(Q, 0, NX * NX * sizeof(double));
    for (int a = 0; a < 4; a++)
        for (int b = 0; b < 4; b++) {
            double s = 0.0;
            for (int j = 0; j < 4; j++) s += L[a][j] * var[j] * L[b][j];
            Q[rows[a] * NX + rows[b]] = s;
        }
    if (half) {
        /* δx⁺ = F δx + L e, e_j = (n_{k-1,j} + n_{k,j}) / 2: Cov(F δx, L e) = Σ_j ½ (F Cx_j) L_jᵀ */
        for (int j = 0; j < 4; j++) {
            if (half[j] == 0.0) continue;
            const double *cj = c->Cx + j * NX;
            double G[NX];
            for (int i = 0; i < NX; i++) {
                double s = cj[i];
                if (i == TH || i == AL || i == V || i == PS) {
                    s = 0.0;
                    for (int k = 0; k < NX; k++) s += F[i * NX + k] * cj[k];
                }
                G[i] = s;
            }
            for (int a = 0; a < 4; a++) {
                double l = 0.5 * L[a][j];
                for (int i = 0; i < NX; i++) {
                    double v = G[i] * l;
                    Q[i * NX + rows[a]] += v;
                    Q[rows[a] * NX + i] += v;
                }
            }
        }
    }
    if (Cx_new) { /* Cov(δx⁺, n_k): the share (½ or all) of this sample's noise in the mean */
        memset(Cx_new, 0, 4 * NX * sizeof(double));
        for (int j = 0; j < 4; j++) {
            if (half[4 + j] == 0.0) continue; /* (half[4..7]: the axis is the reading's, not the model's) */
            double w = (half[j] != 0.0 ? 0.5 : 1.0) * base[j];
            for (int a = 0; a < 4; a++) Cx_new[j * NX + rows[a]] = L[a][j] * w;
        }
    }
    Q[BY * NX + BY] += c->bias_q;
    Q[BZ * NX + BZ] += c->bias_q;
    /* the trapezoid's error in psi: U(-1/2, 1/2) of dt |v1 - v| / r (StrapdownFilter.propagate) */
    double hv = dt * (v1 - v) / r;
    Q[PS * NX + PS] += hv * hv * c->trapezoid_var;
}

/* Pp = F P Fᵀ + Q; F is the identity outside rows TH, AL, V, PS */
static void cov_predict(const double *F, const double *P, const double *Q, double *Pp) {
    static const int rows[4] = {TH, AL, V, PS};
    int full[NX] = {0};
    double A[NX * NX];
    for (int a = 0; a < 4; a++) full[rows[a]] = 1;
    for (int i = 0; i < NX; i++) {
        if (!full[i]) {
            memcpy(A + i * NX, P + i * NX, NX * sizeof(double));
            continue;
        }
        for (int j = 0; j < NX; j++) {
            double s = 0.0;
            for (int k = 0; k < NX; k++) s += F[i * NX + k] * P[k * NX + j];
            A[i * NX + j] = s;
        }
    }
    for (int i = 0; i < NX; i++)
        for (int j = 0; j < NX; j++) {
            double s;
            if (!full[j])
                s = A[i * NX + j];
            else {
                s = 0.0;
                for (int k = 0; k < NX; k++) s += A[i * NX + k] * F[j * NX + k];
            }
            Pp[i * NX + j] = s + Q[i * NX + j];
        }
}

typedef struct {
    int dof;
    double z[2], off[2], R[2], H[2][NX];
    double y[2], S[2][2]; /* encoder_fit's innovation and its covariance (kept for diagnostics) */
} EncMeas;

/* the innovation y = z − h(x), P Hᵀ and S = H P Hᵀ + R of the rows of em */
static void innovation(const double *x, const double *P, const EncMeas *em, double *y, double PHt[NX][2],
                       double S[2][2]) {
    for (int a = 0; a < em->dof; a++) {
        double hx = em->off[a];
        for (int j = 0; j < NX; j++) hx += em->H[a][j] * x[j];
        y[a] = em->z[a] - hx;
        for (int i = 0; i < NX; i++) {
            double s = 0.0;
            for (int j = 0; j < NX; j++) s += P[i * NX + j] * em->H[a][j];
            PHt[i][a] = s;
        }
    }
    for (int a = 0; a < em->dof; a++)
        for (int b = 0; b < em->dof; b++) {
            double s = 0.0;
            for (int i = 0; i < NX; i++) s += em->H[a][i] * PHt[i][b];
            S[a][b] = s + (a == b ? em->R[a] : 0.0);
        }
}

/* the encoders' measurement against the prior (x, Pp) and its NIS; dof 0 if no count changed.
   test: unchanged counts give a row too (the reading, variance Δ²/12), for the IMU outlier test */
static double encoder_fit(const Core *c, const double *enc, const double *last, double T, const double *x,
                          const double *w, const double *Pp, int test, EncMeas *em) {
    double dlt = c->delta, b_r = c->b_r, r = c->r;
    double th = x[TH];
    double thd = (w[0] - x[BY]) / (1.0 + x[SY]);
    double dz = -c->xi * sin(th) + c->zi * cos(th);
    double wheel = (x[V] - thd * dz) / r - thd;
    double spin = b_r * (w[1] - x[BZ]) / ((1.0 + x[SZ]) * cos(th));
    double e = 1.0 + dz / r;
    double var_q = Pp[V * NX + V] / (r * r) + c->g_var * (e * e + b_r * b_r);
    em->dof = 0;
    for (int i = 0; i < 2; i++) {
        int same = enc[i] == last[i];
        if (same && !test) continue;
        double sgn = 2 * i - 1;
        int n = em->dof++;
        double cap = dlt * dlt / 12.0;
        if (same) {
            em->z[n] = enc[i];
            em->off[n] = -sgn * b_r * c->alpha0;
            em->R[n] = cap;
        } else {
            int up = enc[i] > last[i];
            double d = fabs(wheel + sgn * spin) * T;
            if (d > dlt) d = dlt;
            if (!up) d = -d;
            em->z[n] = up ? enc[i] - 0.5 * dlt : enc[i] + 0.5 * dlt;
            em->off[n] = -sgn * b_r * c->alpha0 - 0.5 * d;
            double R = d * d / 12.0 + var_q * T * T / 3.0;
            em->R[n] = R < cap ? R : cap;
        }
        memset(em->H[n], 0, sizeof em->H[n]);
        em->H[n][PS] = em->H[n][C0] = 1.0;
        em->H[n][TH] = -1.0;
        em->H[n][AL] = sgn * b_r;
        em->H[n][H0] = sgn;
    }
    if (em->dof == 0) return NAN;
    double PHt[NX][2];
    double *y = em->y, (*S)[2] = em->S;
    innovation(x, Pp, em, y, PHt, S);
    if (em->dof == 1) return y[0] * y[0] / S[0][0];
    double det = S[0][0] * S[1][1] - S[0][1] * S[1][0];
    return (y[0] * (S[1][1] * y[0] - S[0][1] * y[1]) + y[1] * (-S[1][0] * y[0] + S[0][0] * y[1])) / det;
}

/* the Kalman update (Joseph form, as filterpy) of x, P with the encoder measurement */
static int kalman_update(double *x, double *P, const EncMeas *em, const double *consider, double *Cx) {
    int m = em->dof;
    double PHt[NX][2], S[2][2], Si[2][2], K[NX][2], y[2];
    innovation(x, P, em, y, PHt, S);
    if (m == 1) {
        if (!(S[0][0] > 0.0)) return -1;
        Si[0][0] = 1.0 / S[0][0];
    } else {
        double det = S[0][0] * S[1][1] - S[0][1] * S[1][0];
        if (!(det > 0.0)) return -1;
        Si[0][0] = S[1][1] / det;
        Si[1][1] = S[0][0] / det;
        Si[0][1] = -S[0][1] / det;
        Si[1][0] = -S[1][0] / det;
    }
    for (int i = 0; i < NX; i++)
        for (int b = 0; b < m; b++) {
            double s = 0.0;
            for (int a = 0; a < m; a++) s += PHt[i][a] * Si[a][b];
            K[i][b] = consider[i] != 0.0 ? 0.0 : s; /* Schmidt: the Joseph form below stays exact */
        }
    for (int i = 0; i < NX; i++)
        for (int a = 0; a < m; a++) x[i] += K[i][a] * y[a];
    /* P = (I − K H) P (I − K H)ᵀ + K R Kᵀ */
    double IKH[NX * NX], A[NX * NX];
    for (int i = 0; i < NX; i++)
        for (int j = 0; j < NX; j++) {
            double s = (i == j);
            for (int a = 0; a < m; a++) s -= K[i][a] * em->H[a][j];
            IKH[i * NX + j] = s;
        }
    for (int i = 0; i < NX; i++)
        for (int j = 0; j < NX; j++) {
            double s = 0.0;
            for (int k = 0; k < NX; k++) s += IKH[i * NX + k] * P[k * NX + j];
            A[i * NX + j] = s;
        }
    for (int i = 0; i < NX; i++)
        for (int j = 0; j < NX; j++) {
            double s = 0.0;
            for (int k = 0; k < NX; k++) s += A[i * NX + k] * IKH[j * NX + k];
            for (int a = 0; a < m; a++) s += K[i][a] * em->R[a] * K[j][a];
            P[i * NX + j] = s;
        }
    if (Cx) /* Cov(δx, n) after the update: (I − K H) Cov(δx, n) (the measurement's noise is not n) */
        for (int j = 0; j < 4; j++) {
            double col[NX];
            for (int i = 0; i < NX; i++) {
                double s = 0.0;
                for (int k = 0; k < NX; k++) s += IKH[i * NX + k] * Cx[j * NX + k];
                col[i] = s;
            }
            memcpy(Cx + j * NX, col, sizeof col);
        }
    return 0;
}

/* (z, R) of the measurement whose update truncates the prior N(w, s2) to [lo, hi]; 0 if
   there is nothing to do (w inside, s2 not positive, w more than gate σ outside): as
   truncated_measurement in estimation/ekf_policies.py */
static int truncated_measurement(double w, double s2, double lo, double hi, double gate, double *z, double *R) {
    if (!(s2 > 0.0) || (lo <= w && w < hi)) return 0;
    double s = sqrt(s2), a = (lo - w) / s, b = (hi - w) / s, sign = 1.0;
    if (b <= 0.0) {
        double t = a;
        a = -b;
        b = -t;
        sign = -1.0;
    }
    if (a > gate) return 0;
    double pa = exp(-0.5 * a * a) / sqrt(2.0 * M_PI), pb = exp(-0.5 * b * b) / sqrt(2.0 * M_PI);
    double Z = 0.5 * (erfc(a / sqrt(2.0)) - erfc(b / sqrt(2.0)));
    if (!(Z > 0.0)) return 0;
    double mean = (pa - pb) / Z;
    double var = 1.0 + (a * pa - b * pb) / Z - mean * mean;
    if (!(var > 0.0 && var < 1.0)) return 0;
    double k = 1.0 - var;
    *z = w + sign * s * mean / k;
    *R = s2 * var / k;
    return 1;
}

/* the truncated updates of the wheels whose count is unchanged and whose estimate has left
   it (SensorFrontEnd.keep_inside); returns how many were made + 16 × the mask of the wheels
   (bit 0 left, 1 right) whose estimate lies more than stuck_sigmas σ outside (implausible: no
   update), −1 if one failed */
static int keep_inside(Core *c, const double *enc, const double *last) {
    int n = 0, implausible = 0;
    for (int i = 0; i < 2; i++) {
        if (enc[i] != last[i]) continue;
        double sgn = 2 * i - 1;
        EncMeas em;
        em.dof = 1;
        memset(em.H[0], 0, sizeof em.H[0]);
        em.H[0][PS] = em.H[0][C0] = 1.0;
        em.H[0][TH] = -1.0;
        em.H[0][AL] = sgn * c->b_r;
        em.H[0][H0] = sgn;
        em.off[0] = -sgn * c->b_r * c->alpha0;
        double w = em.off[0], s2 = 0.0;
        for (int j = 0; j < NX; j++) {
            w += em.H[0][j] * c->x[j];
            double t = 0.0;
            for (int k = 0; k < NX; k++) t += c->P[j * NX + k] * em.H[0][k];
            s2 += em.H[0][j] * t;
        }
        double lo = enc[i] - c->inside_half, hi = enc[i] + c->inside_half;
        if (s2 > 0.0 && (w < lo ? lo - w : w - hi) > c->stuck_sigmas * sqrt(s2)) {
            implausible |= 1 << i;
            continue;
        }
        if (!truncated_measurement(w, s2, lo, hi, c->stuck_sigmas, &em.z[0], &em.R[0]))
            continue;
        if (kalman_update(c->x, c->P, &em, c->consider, c->Cx)) return -1;
        n++;
    }
    return n + 16 * implausible;
}

static int healthy(const Core *c) {
    for (int i = 0; i < NX; i++)
        if (!isfinite(c->x[i]) || !(c->P[i * NX + i] > 0.0)) return 0;
    for (int i = 0; i < NX * NX; i++)
        if (!isfinite(c->P[i])) return 0;
    return 1;
}

/* every pivot of P's LDLᵀ elimination (no pivoting) positive and finite, the operations in the
   order of estimation/detlinalg.py positive_definite (elementwise numpy): the same verdict */
static int positive_definite(const double *P) {
    double W[NX * NX];
    memcpy(W, P, sizeof W);
    for (int k = 0; k < NX; k++) {
        double d = W[k * NX + k];
        if (!(d > 0.0 && d < INFINITY)) return 0;
        for (int i = k + 1; i < NX; i++) {
            double f = W[i * NX + k] / d;
            for (int j = k + 1; j < NX; j++) W[i * NX + j] -= f * W[k * NX + j];
        }
    }
    return 1;
}

/* the state within its physical range (StrapdownFilter.in_range): |θ| < tilt_limit (π/2), θ's variance
   below tilt_var_max (that of a tilt known only to lie in (−π/2, π/2)), P positive definite */
static int in_range(const Core *c) {
    return fabs(c->x[TH]) < c->tilt_limit && c->P[TH * NX + TH] < c->tilt_var_max && positive_definite(c->P);
}

static void restore(Core *c) {
    memset(c->Cx, 0, sizeof c->Cx);
    memcpy(c->x, c->xg, sizeof c->x);
    for (int i = 0; i < NX * NX; i++) c->P[i] = c->restore_inflation * c->Pg[i];
    for (int i = 0; i < NX; i++) c->P[i * NX + i] += c->restore_jitter;
    memcpy(c->w, c->wg, sizeof c->w);
    memcpy(c->w_prev, c->wpg, sizeof c->w_prev);
}

static void keep_good(Core *c) {
    memcpy(c->xg, c->x, sizeof c->x);
    memcpy(c->Pg, c->P, sizeof c->P);
    memcpy(c->wg, c->w, sizeof c->w);
    memcpy(c->wpg, c->w_prev, sizeof c->w_prev);
}

/* ---- Python interface ----------------------------------------------------------------- */
/* new(config) -> a filter built from config (an estimation.ekf_config.KernelConfig, or any object
   with its attributes): each field read by its name, a missing one an AttributeError */
static PyObject *new_core(PyObject *self, PyObject *arg) {
    Core *c = PyMem_Calloc(1, sizeof(Core));
    if (!c) return PyErr_NoMemory();
    for (size_t i = 0; i < sizeof config_fields / sizeof config_fields[0]; i++) {
        const ConfigField *f = &config_fields[i];
        double *out = (double *)((char *)c + f->offset);
        PyObject *v = PyObject_GetAttrString(arg, f->name);
        int bad = v == NULL;
        if (!bad && f->n == 1) {
            *out = PyFloat_AsDouble(v);
            bad = *out == -1.0 && PyErr_Occurred();
        } else if (!bad)
            bad = floats(v, out, f->n, f->name) != 0;
        Py_XDECREF(v);
        if (bad) {
            PyMem_Free(c);
            return NULL;
        }
    }
    PyObject *cap = PyCapsule_New(c, "ekf_core", core_free);
    if (!cap) PyMem_Free(c);
    return cap;
}

static PyObject *set_state(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    Core *c;
    if (nargs != 5 || !(c = get(args[0]))) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_TypeError, "set_state(core, x, P, w, w_prev)");
        return NULL;
    }
    if (floats(args[1], c->x, NX, "x") || floats(args[2], c->P, NX * NX, "P") || floats(args[3], c->w, 2, "w") ||
        floats(args[4], c->w_prev, 2, "w_prev"))
        return NULL;
    memset(c->Cx, 0, sizeof c->Cx); /* a state set from outside carries no correlation with the samples */
    if (healthy(c)) keep_good(c); /* a broken state is never kept as the one to restore */
    Py_RETURN_NONE;
}

static PyObject *set_consider(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    Core *c;
    if (nargs != 2 || !(c = get(args[0]))) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_TypeError, "set_consider(core, mask)");
        return NULL;
    }
    if (floats(args[1], c->consider, NX, "mask")) return NULL;
    Py_RETURN_NONE;
}

/* the period of the next steps (a log whose rows are its instants: EKFEstimator.set_sampling's
   periods = "rows"): the filter's and the model's step dt (s), the model's RK4 steps over it and
   the gyro bias's random-walk variance over it */
static PyObject *set_period(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    Core *c;
    double v[4];
    if (nargs != 2 || !(c = get(args[0]))) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_TypeError, "set_period(core, (dt, mdt, msub, bias_q))");
        return NULL;
    }
    if (floats(args[1], v, 4, "period")) return NULL;
    c->dt = v[0];
    c->mdt = v[1];
    c->msub = v[2];
    c->bias_q = v[3];
    Py_RETURN_NONE;
}

static PyObject *get_state(PyObject *self, PyObject *arg) {
    Core *c = get(arg);
    if (!c) return NULL;
    return Py_BuildValue("(NNNN)", tuple_of(c->x, NX), tuple_of(c->P, NX * NX), tuple_of(c->w, 2),
                         tuple_of(c->w_prev, 2));
}

static PyObject *py_state6(PyObject *self, PyObject *arg) {
    Core *c = get(arg);
    if (!c) return NULL;
    double s[6];
    state6(c, c->x, s);
    return tuple_of(s, 6);
}

/* the IMU sample as the filter uses it: an axis at the end of its range replaced by the
   model's prediction (syn, computed here) with its extra variance; with acc[0] > 0 the
   accelerometer half's innovation e against the model's (f_x, f_z) is computed and, with
   acc[3] != 0, the half is an outlier and replaced when e less the recent innovations' median
   (acc[1], acc[2]) fails the gate (Fusion.imu_sample); returns 1 if any axis was saturated
   (a guard: SensorFrontEnd.railed sends samples within 3 sigma of the rail to the Python coasting
   step before they reach the kernel) */
static int imu_sample(const Core *c, const double *cmd, const double *acc, double *smp, double *extra, double *syn,
                      double *syn_extra, int *acc_out, double *e) {
    int any = 0, sat[4], have_syn = 0;
    *acc_out = 0;
    e[0] = e[1] = NAN;
    for (int j = 0; j < 4; j++) /* extra[] arrives with the sample's own extra variances (0: none) */
        any |= sat[j] = fabs(smp[j]) >= c->lim[j];
    if (acc[0] > 0.0 && !sat[2] && !sat[3]) {
        synthetic(c, c->x, cmd[0], cmd[1], syn, syn_extra);
        have_syn = 1;
        const double *P = c->P;
        double g = c->g, fx = syn[2], fz = syn[3];
        double sx = c->a_var + syn_extra[2] + g * g * P[TH * NX + TH] + fx * fx * P[SAX * NX + SAX];
        double sz = c->a_var + syn_extra[3] + fz * fz * P[SAZ * NX + SAZ];
        e[0] = smp[2] - fx;
        e[1] = smp[3] - fz;
        double ex = e[0] - acc[1], ez = e[1] - acc[2];
        /* a push moves the specific force too, but also θ̈, which the gyro sees: an
           accelerometer outlier needs a gyro sample that agrees with the model */
        double eg = smp[0] - syn[0], sg = c->gyro_extrapolation_samples * c->g_var + syn_extra[0];
        *acc_out = acc[3] != 0.0 && ex * ex / sx + ez * ez / sz > c->accel_variance_factor * acc[0] &&
                   eg * eg / sg <= c->imu_gate[0];
    }
    if (!any && !*acc_out) return 0;
    if (!have_syn) synthetic(c, c->x, cmd[0], cmd[1], syn, syn_extra);
    for (int j = 0; j < 4; j++)
        if (sat[j] || (j >= 2 && *acc_out)) {
            smp[j] = syn[j];
            extra[j] = syn_extra[j];
        }
    return any;
}

/* advance(core, imu, enc, last, T, command, in_row, acc_test)
       -> (imu_code, saturated, enc_code, nis, dof, ok, acc_out, e_x, e_z):
   one strapdown step with an IMU sample (steps without one are the Python side's); imu_code 2:
   the sample is an outlier (the encoders fail the IMU gate with it and pass the normal gate with
   the model's sample), nothing changed, nis = the encoders' NIS with the sample */
static PyObject *advance(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    Core *c;
    if (nargs != 8 || !(c = get(args[0]))) {
        if (!PyErr_Occurred())
            PyErr_SetString(PyExc_TypeError, "advance(core, imu, enc, last, T, command, in_row, acc_test)");
        return NULL;
    }
    double smp[4], extra[4] = {0.0, 0.0, 0.0, 0.0}, syn[4], syn_extra[4], enc[2], last[2], cmd[2], T = 0.0;
    int has_enc = args[2] != Py_None && args[3] != Py_None;
    /* imu: (ω_y, ω_z, f_x, f_z), or those and the variances (4,) the sample's own rebuilding adds
       (point samples turned into interval means: EKFEstimator.set_sampling), or those and (4,)
       1.0 where the axis's mean is the trapezoid of two point samples (their noise shared with the
       previous interval's mean: Core.Cx) */
    Py_ssize_t n_imu = PySequence_Check(args[1]) ? PySequence_Size(args[1]) : -1;
    if (n_imu < 0) PyErr_Clear(); /* floats() below says what is wrong */
    int has_extra = n_imu == 8 || n_imu == 12, points = n_imu == 12;
    double half[8] = {0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0};
    if (has_extra) {
        double all[12];
        if (floats(args[1], all, n_imu, "imu")) return NULL;
        for (int j = 0; j < 4; j++) {
            smp[j] = all[j];
            extra[j] = all[4 + j];
            if (points) half[j] = all[8 + j];
        }
    } else if (floats(args[1], smp, 4, "imu")) return NULL;
    if (has_enc && (floats(args[2], enc, 2, "enc") || floats(args[3], last, 2, "last"))) return NULL;
    T = PyFloat_AsDouble(args[4]);
    if (T == -1.0 && PyErr_Occurred()) return NULL;
    if (floats(args[5], cmd, 2, "command")) return NULL;
    long in_row = PyLong_AsLong(args[6]);
    if (in_row == -1 && PyErr_Occurred()) return NULL;
    int may_reject = in_row < c->max_rejects_in_row; /* (EncoderGate.may_reject) */
    double acc[4], e[2];
    if (floats(args[7], acc, 4, "acc_test")) return NULL;
    int acc_out = 0;

    double x1[NX], F[NX * NX], Q[NX * NX], Pp[NX * NX];
    int enc_code = 0, ok = 1;
    double nis = NAN;
    EncMeas em;
    em.dof = 0;
    double smp0[4];
    memcpy(smp0, smp, sizeof smp0);
    int saturated = imu_sample(c, cmd, acc, smp, extra, syn, syn_extra, &acc_out, e);
    if (points)
        for (int j = 0; j < 4; j++)
            if (smp[j] != smp0[j] || (saturated && fabs(smp0[j]) >= c->lim[j]) || (j >= 2 && acc_out))
                half[j] = half[4 + j] = 0.0; /* the model's value stands in: the reading's noise is not in it */
    double Cx_new[4 * NX];
    propagate(c, c->x, smp, (saturated || acc_out || has_extra) ? extra : NULL, points ? half : NULL, x1, F, Q,
              points ? Cx_new : NULL);
    cov_predict(F, c->P, Q, Pp);
    if (has_enc) {
        double eps = encoder_fit(c, enc, last, T, x1, smp, Pp, 1, &em);
        if (!(eps <= c->imu_gate[em.dof - 1])) {
            double ax1[NX], aF[NX * NX], aQ[NX * NX], aPp[NX * NX];
            if (!saturated && !acc_out) synthetic(c, c->x, cmd[0], cmd[1], syn, syn_extra);
            propagate(c, c->x, syn, syn_extra, NULL, ax1, aF, aQ, NULL);
            cov_predict(aF, c->P, aQ, aPp);
            if (encoder_fit(c, enc, last, T, ax1, syn, aPp, 1, &em) <= c->gate[em.dof - 1]) {
                memset(c->Cx, 0, sizeof c->Cx); /* the sample is not used: its noise is in nothing */
                return Py_BuildValue("(iiidiiiddi)", 2, 0, 0, eps, 0, 1, acc_out, e[0], e[1], 0);
            }
        }
        em.dof = 0;
    }
    memcpy(c->x, x1, sizeof x1);
    memcpy(c->P, Pp, sizeof Pp);
    if (points)
        memcpy(c->Cx, Cx_new, sizeof Cx_new);
    else
        memset(c->Cx, 0, sizeof c->Cx);
    c->w_prev[0] = c->w[0];
    c->w_prev[1] = c->w[1];
    c->w[0] = smp[0];
    c->w[1] = smp[1];
    if (has_enc) nis = encoder_fit(c, enc, last, T, c->x, c->w, c->P, 0, &em);
    int dof = em.dof;
    if (dof > 0) { /* what innovation(core) reports: the update's y and S, as the NIS above used them */
        c->inn_dof = dof;
        for (int a = 0; a < 2; a++) {
            c->inn_y[a] = em.y[a];
            for (int b = 0; b < 2; b++) c->inn_S[2 * a + b] = em.S[a][b];
        }
    }
    int inside = 0;
    if (has_enc) {
        if (dof == 0)
            enc_code = 1;
        else if (!(nis <= c->gate[dof - 1]) && may_reject)
            enc_code = 3;
        else {
            enc_code = (nis <= c->gate[dof - 1]) ? 2 : 4;
            if (kalman_update(c->x, c->P, &em, c->consider, points ? c->Cx : NULL)) ok = 0;
        }
        if (ok && enc_code != 3) {
            inside = keep_inside(c, enc, last);
            if (inside < 0) {
                ok = 0;
                inside = 0;
            }
        }
    }
    for (int i = 0; i < NX; i++)
        for (int j = i + 1; j < NX; j++) {
            double s = 0.5 * (c->P[i * NX + j] + c->P[j * NX + i]);
            c->P[i * NX + j] = c->P[j * NX + i] = s;
        }
    if (ok && healthy(c)) {
        if (in_range(c))
            keep_good(c);
        else
            ok = -1; /* finite but out of range: the Python side re-initialises (Fusion.lost) */
    } else {
        restore(c);
        ok = 0;
    }
    return Py_BuildValue("(iiidiiiddi)", 1, saturated, enc_code, nis, dof, ok, acc_out, e[0], e[1], inside);
}

/* innovation(core) -> (y, S): the last encoder update's innovation y (dof,) rad and its covariance
   S (dof × dof, row-major) rad², dof 0 (empty tuples) before any */
static PyObject *py_innovation(PyObject *self, PyObject *arg) {
    Core *c = get(arg);
    if (!c) return NULL;
    int m = c->inn_dof;
    double S[4];
    for (int a = 0; a < m; a++)
        for (int b = 0; b < m; b++) S[a * m + b] = c->inn_S[2 * a + b];
    return Py_BuildValue("(NN)", tuple_of(c->inn_y, m), tuple_of(S, m * m));
}

static PyObject *forward(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    Core *c;
    if (nargs != 2 || !(c = get(args[0]))) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_TypeError, "forward(core, commands)");
        return NULL;
    }
    PyObject *seq = PySequence_Fast(args[1], "commands");
    if (!seq) return NULL;
    double s0[6], s[6], cmd[2], tl, tr;
    state6(c, c->x, s0);
    memcpy(s, s0, sizeof s);
    for (Py_ssize_t i = 0; i < PySequence_Fast_GET_SIZE(seq); i++) {
        if (floats(PySequence_Fast_GET_ITEM(seq, i), cmd, 2, "command")) {
            Py_DECREF(seq);
            return NULL;
        }
        delivered(c, s, cmd[0], cmd[1], &tl, &tr);
        model_step(c, s, tl, tr, 1);
    }
    Py_DECREF(seq);
    int finite = 1;
    for (int i = 0; i < 6; i++) finite &= isfinite(s[i]) != 0;
    return Py_BuildValue("(NN)", tuple_of(finite ? s : s0, 6), PyBool_FromLong(finite));
}

/* state_into(core, buffer[, row]): x (12) then P (144) as float64 into row `row` (default 0) of a
   writable C-contiguous float64 buffer of rows of 156 (for estimation.consistency.RunningConsistency) */
static PyObject *state_into(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 2 && nargs != 3) { PyErr_SetString(PyExc_TypeError, "state_into(core, buffer[, row])"); return NULL; }
    Core *c = get(args[0]);
    if (!c) return NULL;
    Py_ssize_t row = nargs == 3 ? PyLong_AsSsize_t(args[2]) : 0;
    if (row == -1 && PyErr_Occurred()) return NULL;
    Py_buffer view;
    if (PyObject_GetBuffer(args[1], &view, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS) < 0) return NULL;
    Py_ssize_t need = (row + 1) * (Py_ssize_t)(NX + NX * NX) * (Py_ssize_t)sizeof(double);
    if (row < 0 || view.len < need) {
        PyBuffer_Release(&view);
        PyErr_SetString(PyExc_IndexError, "state_into: row outside the buffer");
        return NULL;
    }
    double *out = (double *)view.buf + row * (NX + NX * NX);
    memcpy(out, c->x, NX * sizeof(double));
    memcpy(out + NX, c->P, NX * NX * sizeof(double));
    PyBuffer_Release(&view);
    Py_RETURN_NONE;
}

/* ---- the latency watch's check (estimation.ekf_policies.LatencyWatch.observe), bit for bit ----
 * The same arithmetic as the NumPy code, in its order: NumPy's sums of a 1-d array or along
 * the rows of a C-ordered array are pairwise (eight accumulators up to 128 numbers, halves
 * beyond), along the rows of an F-ordered one (what a column mask makes) sequential from 0.0,
 * as estimation.detlinalg's rowsums are; the medians are order statistics (a sort gives
 * NumPy's partition's values). Compiled with -ffp-contract=off, like the rest. */
#define WATCH_MAX_N 512

static double pairwise(const double *a, Py_ssize_t n) {
    if (n < 8) {
        double res = 0.;
        for (Py_ssize_t i = 0; i < n; i++) res += a[i];
        return res;
    } else if (n <= 128) {
        double r[8];
        Py_ssize_t i, j;
        for (j = 0; j < 8; j++) r[j] = a[j];
        for (i = 8; i < n - (n % 8); i += 8)
            for (j = 0; j < 8; j++) r[j] += a[i + j];
        double res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
        for (; i < n; i++) res += a[i];
        return res;
    } else {
        Py_ssize_t n2 = n / 2;
        n2 -= n2 % 8;
        return pairwise(a, n2) + pairwise(a + n2, n - n2);
    }
}

static int cmp_double(const void *x, const void *y) {
    double a = *(const double *)x, b = *(const double *)y;
    return (a > b) - (a < b);
}

static double median_of(const double *a, Py_ssize_t m, double *tmp) {
    memcpy(tmp, a, (size_t)m * sizeof(double));
    qsort(tmp, (size_t)m, sizeof(double), cmp_double);
    Py_ssize_t k = m / 2;
    if (m % 2) return tmp[k];
    return (tmp[k - 1] + tmp[k]) / 2.0;
}

/* watch_rho(y, u, window, max_lag, clip, sign) -> tuple of max_lag + 1 correlations, or None
 * when fewer than window // 2 rows hold a measurement. y, u: n = window + max_lag + 5 numbers. */
static PyObject *watch_rho(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 6) {
        PyErr_SetString(PyExc_TypeError, "watch_rho takes y, u, window, max_lag, clip, sign");
        return NULL;
    }
    Py_ssize_t W = PyLong_AsSsize_t(args[2]), L = PyLong_AsSsize_t(args[3]);
    double clip = PyFloat_AsDouble(args[4]), sign = PyFloat_AsDouble(args[5]);
    if (PyErr_Occurred()) return NULL;
    Py_ssize_t n = W + L + 5, R = L + 1;
    if (W < 2 || L < 0 || n > WATCH_MAX_N) {
        PyErr_SetString(PyExc_ValueError, "watch_rho: window or max_lag out of range");
        return NULL;
    }
    double y[WATCH_MAX_N], u[WATCH_MAX_N], y2[WATCH_MAX_N], yy[WATCH_MAX_N], tmp[WATCH_MAX_N];
    double dk[WATCH_MAX_N], row[WATCH_MAX_N], zy[WATCH_MAX_N];
    Py_ssize_t idx[WATCH_MAX_N];
    if (floats(args[0], y, n, "y") < 0 || floats(args[1], u, n, "u") < 0) return NULL;
    Py_ssize_t r0 = n - 1 - W, used = 0;
    for (Py_ssize_t j = 0; j < W; j++) {
        y2[j] = (y[r0 + j] - 2.0 * y[r0 - 1 + j]) + y[r0 - 2 + j];
        if (isfinite(y2[j])) {
            idx[used] = j;
            yy[used++] = y2[j];
        }
    }
    if (used < W / 2) Py_RETURN_NONE;
    for (Py_ssize_t i = 0; i + 3 < n; i++) dk[i] = ((u[i + 3] + u[i + 2]) - u[i + 1]) - u[i];
    double med = median_of(yy, used, tmp);
    for (Py_ssize_t j = 0; j < used; j++) tmp[j] = fabs(yy[j] - med);
    double lim = clip * 1.4826 * median_of(tmp, used, row);
    double lo = med - lim, hi = med + lim;
    for (Py_ssize_t j = 0; j < used; j++) {
        double v = yy[j] > lo ? yy[j] : lo; /* np.maximum, then np.minimum (no NaN here) */
        yy[j] = v < hi ? v : hi;
    }
    double mean = pairwise(yy, used) / (double)used;
    for (Py_ssize_t j = 0; j < used; j++) yy[j] = yy[j] - mean;
    double syy = 0.0;
    for (Py_ssize_t j = 0; j < used; j++) syy += yy[j] * yy[j];
    PyObject *out = PyTuple_New(R);
    if (!out) return NULL;
    for (Py_ssize_t l = 0; l < R; l++) {
        for (Py_ssize_t j = 0; j < used; j++) row[j] = dk[L + 2 - l + idx[j]];
        double zsum = 0.0;
        if (used == W) { /* NumPy's Z is C-ordered then: each row's sum pairwise */
            zsum = pairwise(row, used);
        } else { /* a column mask leaves Z F-ordered: its rows are summed in turn */
            for (Py_ssize_t j = 0; j < used; j++) zsum += row[j];
        }
        double zmean = zsum / (double)used;
        double szy = 0.0, szz = 0.0;
        for (Py_ssize_t j = 0; j < used; j++) {
            double z = row[j] - zmean;
            zy[j] = z;
            szy += z * yy[j];
        }
        for (Py_ssize_t j = 0; j < used; j++) szz += zy[j] * zy[j];
        double den = sqrt(syy * szz);
        double rho = sign * szy / (den > 0 ? den : INFINITY);
        PyObject *f = PyFloat_FromDouble(rho);
        if (!f) {
            Py_DECREF(out);
            return NULL;
        }
        PyTuple_SET_ITEM(out, l, f);
    }
    return out;
}

/* config_fields() -> the names of the configuration's fields, in order (KernelConfig's, checked) */
static PyObject *py_config_fields(PyObject *self, PyObject *unused) {
    Py_ssize_t n = (Py_ssize_t)(sizeof config_fields / sizeof config_fields[0]);
    PyObject *t = PyTuple_New(n);
    if (!t) return NULL;
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *s = PyUnicode_FromString(config_fields[i].name);
        if (!s) {
            Py_DECREF(t);
            return NULL;
        }
        PyTuple_SET_ITEM(t, i, s);
    }
    return t;
}

static PyMethodDef methods[] = {
    {"config_fields", py_config_fields, METH_NOARGS, "The configuration's field names, in order."},
    {"watch_rho", (PyCFunction)(void (*)(void))watch_rho, METH_FASTCALL, "The latency watch's correlations."},
    {"new", new_core, METH_O, "A filter from its configuration (KernelConfig)."},
    {"set_state", (PyCFunction)(void (*)(void))set_state, METH_FASTCALL, "Set x, P and the last gyro rates."},
    {"state", get_state, METH_O, "(x, P, w, w_prev) as tuples."},
    {"state_into", (PyCFunction)(void (*)(void))state_into, METH_FASTCALL, "x, P into a row of a buffer."},
    {"set_consider", (PyCFunction)(void (*)(void))set_consider, METH_FASTCALL, "Set the consider-state mask."},
    {"set_period", (PyCFunction)(void (*)(void))set_period, METH_FASTCALL, "Set the period of the next steps."},
    {"state6", py_state6, METH_O, "The filter's [θ, θ̇, ψ, ψ̇, α, α̇]."},
    {"advance", (PyCFunction)(void (*)(void))advance, METH_FASTCALL, "One filter step with an IMU sample."},
    {"forward", (PyCFunction)(void (*)(void))forward, METH_FASTCALL, "Predict the state over commands."},
    {"innovation", py_innovation, METH_O, "The last encoder update's (y, S)."},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_ekf", "Compiled path of the twin's EKF.", -1, methods};

PyMODINIT_FUNC PyInit__ekf(void) { return PyModule_Create(&module); }
