/* Optional compiled hot path of the PyBullet twin (twin/plant/bullet.py).

   Two functions doing exactly the arithmetic of their Python counterparts, in the same
   order, so that results are bit-identical (tests/test_twin_fastpath.py checks it):

     truth(cls, pose, vel, joints, alpha_prev, com_local, r, t) -> (GroundTruth, axle_dir)
         = BulletTwin._truth_from_states
     motors(ul, ur, wl, wr, kt, R, vs, imax, steps, comp, dead)
         -> (duty_l, duty_r, torque_l, torque_r, sat_l, sat_r, tau0_l, tau0_r)
         = MotorDriver.update for both wheels
     windows(S0, tau0, out, consts, k) -> None
         = twin.calibrate.model.step_windows's PyBullet stepping with the held torques tau0
         given (W windows of N periods; float64 C-contiguous buffers S0 (W, 6), tau0 (W, N, 2),
         out (W, N + 1, 6) written; consts = (m11, m12, m22, n_bla, g_b, d_b + c_e, d_w,
         yaw damping of the joint, b / r, m33, h))

   Built by setup.py with -ffp-contract=off (no fused multiply-adds, which would round
   differently). Python's round() rounds half to even like nearbyint() in the default
   rounding mode; "+ 0.0" turns nearbyint's -0.0 into the 0.0 that round() gives. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>

static int floats(PyObject *seq, double *out, Py_ssize_t n, const char *what) {
    if (!PyTuple_Check(seq) || PyTuple_GET_SIZE(seq) < n) {
        PyErr_Format(PyExc_TypeError, "%s must be a tuple of at least %zd numbers", what, n);
        return -1;
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        out[i] = PyFloat_AsDouble(PyTuple_GET_ITEM(seq, i));
        if (out[i] == -1.0 && PyErr_Occurred()) return -1;
    }
    return 0;
}

static int pair(PyObject *seq, PyObject **a, PyObject **b, const char *what) {
    if (!PyTuple_Check(seq) || PyTuple_GET_SIZE(seq) != 2) {
        PyErr_Format(PyExc_TypeError, "%s must be a pair", what);
        return -1;
    }
    *a = PyTuple_GET_ITEM(seq, 0);
    *b = PyTuple_GET_ITEM(seq, 1);
    return 0;
}

static PyObject *truth(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 8) {
        PyErr_SetString(PyExc_TypeError, "truth takes 8 arguments");
        return NULL;
    }
    if (!PyType_Check(args[0]) || !PyType_IsSubtype((PyTypeObject *)args[0], &PyTuple_Type)) {
        PyErr_SetString(PyExc_TypeError, "truth needs a tuple subclass");
        return NULL;
    }
    PyTypeObject *cls = (PyTypeObject *)args[0];
    double com[3], q[4], w[3], cl[3], jl[2], jr[2];
    PyObject *a, *b;
    if (pair(args[1], &a, &b, "pose") || floats(a, com, 3, "position") || floats(b, q, 4, "quaternion")) return NULL;
    if (pair(args[2], &a, &b, "velocity") || floats(b, w, 3, "angular velocity")) return NULL;
    if (pair(args[3], &a, &b, "joint states") || floats(a, jl, 2, "left joint") || floats(b, jr, 2, "right joint"))
        return NULL;
    if (floats(args[5], cl, 3, "com_local")) return NULL;
    double r = PyFloat_AsDouble(args[6]);
    if (r == -1.0 && PyErr_Occurred()) return NULL;
    double t = PyFloat_AsDouble(args[7]);
    if (t == -1.0 && PyErr_Occurred()) return NULL;

    double x = q[0], y = q[1], z = q[2], qw = q[3];
    double r01 = 2 * (x * y - z * qw);
    double r11 = 1 - 2 * (x * x + z * z);
    double r20 = 2 * (x * z - y * qw);
    double r21 = 2 * (y * z + x * qw);
    double r22 = 1 - 2 * (x * x + y * y);
    double theta = atan2(-r20, r22);
    double roll = asin(r21 > 1.0 ? 1.0 : (r21 < -1.0 ? -1.0 : r21));
    double yaw = atan2(-r01, r11);
    double alpha;
    if (args[4] == Py_None) {
        alpha = yaw;
    } else {
        double a0 = PyFloat_AsDouble(args[4]);
        if (a0 == -1.0 && PyErr_Occurred()) return NULL;
        alpha = a0 + remainder(yaw - a0, 2.0 * M_PI);
    }
    double ca = cos(alpha), sa = sin(alpha);
    double cr = cos(roll);
    double theta_dot = cr > 1e-9 ? (-sa * w[0] + ca * w[1]) / cr : 0.0;
    double alpha_dot = w[2] - theta_dot * r21;
    double psi_l = jl[0] + theta, psi_r = jr[0] + theta;
    double psi_l_dot = jl[1] + theta_dot, psi_r_dot = jr[1] + theta_dot;
    double psi = 0.5 * (psi_l + psi_r);
    double r00 = 1 - 2 * (y * y + z * z);
    double r02 = 2 * (x * z + y * qw);
    double r10 = 2 * (x * y + z * qw);
    double r12 = 2 * (y * z - x * qw);
    double v[15] = {t, theta, theta_dot, psi_l, psi_r, psi, 0.5 * (psi_l_dot + psi_r_dot), alpha, alpha_dot,
                    r * psi, com[0] - (r00 * cl[0] + r01 * cl[1] + r02 * cl[2]),
                    com[1] - (r10 * cl[0] + r11 * cl[1] + r12 * cl[2]), roll, psi_l_dot, psi_r_dot};
    PyObject *gt = cls->tp_alloc(cls, 15);
    if (!gt) return NULL;
    for (int i = 0; i < 15; i++) {
        PyObject *f = PyFloat_FromDouble(v[i]);
        if (!f) {
            Py_DECREF(gt);
            return NULL;
        }
        PyTuple_SET_ITEM(gt, i, f);
    }
    return Py_BuildValue("(N(ddd))", gt, r01, r11, r21);
}

static void motor(double cmd, double omega, double kt, double R, double vs, double imax, double steps, int comp,
                  double dead, double *duty, int *sat, double *tau0, double *torque) {
    double i_cmd = cmd / kt;
    int saturated = fabs(i_cmd) > imax;
    if (saturated) i_cmd = copysign(imax, i_cmd);
    double v = R * i_cmd;
    if (comp) v += kt * omega;
    double d = v / vs;
    if (d > 1.0 || d < -1.0) {
        saturated = 1;
        d = d > 0 ? 1.0 : -1.0;
    }
    if (fabs(d) < dead)
        d = 0.0;
    else
        d = (nearbyint(d * steps) + 0.0) / steps;
    double t0 = kt * d * vs / R;
    *duty = d;
    *sat = saturated;
    *tau0 = t0;
    *torque = t0 - kt * kt * omega / R;
}

static PyObject *motors(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 11) {
        PyErr_SetString(PyExc_TypeError, "motors takes 11 arguments");
        return NULL;
    }
    double a[11];
    for (int i = 0; i < 11; i++) {
        a[i] = PyFloat_AsDouble(args[i]);
        if (a[i] == -1.0 && PyErr_Occurred()) return NULL;
    }
    double dl, dr, t0l, t0r, ql, qr;
    int sl, sr;
    motor(a[0], a[2], a[4], a[5], a[6], a[7], a[8], a[9] != 0.0, a[10], &dl, &sl, &t0l, &ql);
    motor(a[1], a[3], a[4], a[5], a[6], a[7], a[8], a[9] != 0.0, a[10], &dr, &sr, &t0r, &qr);
    return Py_BuildValue("(ddddNNdd)", dl, dr, ql, qr, PyBool_FromLong(sl), PyBool_FromLong(sr), t0l, t0r);
}

/* equation (1)'s accelerations as twin/plant/analytic.py's _accelerations with t1 = t3 = 0 and the
   joint's d_w = 0, operation for operation */
static void accelerations(const double *x, double ul, double ur, double t2, const double *c, double *a) {
    const double m11 = c[0], m12 = c[1], m22 = c[2], n_bla = c[3], g_b = c[4], d_b = c[5], yd = c[7], b_r = c[8],
                 m33 = c[9];
    double th_d = x[1], ps_d = x[3], al_d = x[5];
    double s = sin(x[0]), co = cos(x[0]);
    double drive = 2.0 * d_b * (th_d - ps_d);
    double u = ul + ur;
    double rhs1 = m12 * (th_d * th_d + al_d * al_d) * s - 2.0 * 0.0 * ps_d + drive + u + 0.0;
    double rhs2 = n_bla * al_d * al_d * s * co + g_b * s - drive - u + t2;
    double mc = m12 * co;
    double det = m11 * m22 - mc * mc;
    a[1] = (m11 * rhs2 - m12 * co * rhs1) / det;
    a[3] = (m22 * rhs1 - m12 * co * rhs2) / det;
    double yaw = -2.0 * n_bla * al_d * th_d * s * co - m12 * al_d * ps_d * s - yd * al_d + b_r * (ur - ul) + 0.0;
    a[5] = yaw / (m33 + n_bla * s * s);
}

static PyObject *windows(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 5) {
        PyErr_SetString(PyExc_TypeError, "windows takes 5 arguments");
        return NULL;
    }
    double c[11];
    if (floats(args[3], c, 11, "consts") < 0) return NULL;
    long k = PyLong_AsLong(args[4]);
    if (k == -1 && PyErr_Occurred()) return NULL;
    Py_buffer b0, bt, bo;
    if (PyObject_GetBuffer(args[0], &b0, PyBUF_C_CONTIGUOUS) < 0) return NULL;
    if (PyObject_GetBuffer(args[1], &bt, PyBUF_C_CONTIGUOUS) < 0) { PyBuffer_Release(&b0); return NULL; }
    if (PyObject_GetBuffer(args[2], &bo, PyBUF_C_CONTIGUOUS | PyBUF_WRITABLE) < 0) {
        PyBuffer_Release(&b0); PyBuffer_Release(&bt); return NULL;
    }
    Py_ssize_t W = b0.len / (Py_ssize_t)(6 * sizeof(double));
    Py_ssize_t N = W ? bt.len / (Py_ssize_t)(2 * sizeof(double)) / W : 0;
    if (b0.len != W * 6 * (Py_ssize_t)sizeof(double) || bt.len != W * N * 2 * (Py_ssize_t)sizeof(double) ||
        bo.len != W * (N + 1) * 6 * (Py_ssize_t)sizeof(double)) {
        PyBuffer_Release(&b0); PyBuffer_Release(&bt); PyBuffer_Release(&bo);
        PyErr_SetString(PyExc_ValueError, "windows: buffers of shapes (W, 6), (W, N, 2), (W, N + 1, 6) needed");
        return NULL;
    }
    const double *S0 = (const double *)b0.buf, *tau0 = (const double *)bt.buf;
    double *out = (double *)bo.buf;
    const double d_w = c[6], b_r = c[8], h = c[10];
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t w = 0; w < W; w++) {
        double x[6], a[6];
        for (int i = 0; i < 6; i++) x[i] = out[w * (N + 1) * 6 + i] = S0[w * 6 + i];
        for (Py_ssize_t n = 0; n < N; n++) {
            double rate_l = x[3] - b_r * x[5], rate_r = x[3] + b_r * x[5];
            double hold_l = -d_w * rate_l, hold_r = -d_w * rate_r;
            double t2 = hold_l + hold_r;
            double ul = tau0[(w * N + n) * 2] + hold_l, ur = tau0[(w * N + n) * 2 + 1] + hold_r;
            for (long j = 0; j < k; j++) {
                accelerations(x, ul, ur, t2, c, a);
                x[1] += h * a[1];
                x[3] += h * a[3];
                x[5] += h * a[5];
                x[0] += h * x[1];
                x[2] += h * x[3];
                x[4] += h * x[5];
            }
            for (int i = 0; i < 6; i++) out[(w * (N + 1) + n + 1) * 6 + i] = x[i];
        }
    }
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&b0); PyBuffer_Release(&bt); PyBuffer_Release(&bo);
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"truth", (PyCFunction)(void (*)(void))truth, METH_FASTCALL, "Ground truth from PyBullet's state tuples."},
    {"motors", (PyCFunction)(void (*)(void))motors, METH_FASTCALL, "PWM update of both motors."},
    {"windows", (PyCFunction)(void (*)(void))windows, METH_FASTCALL, "The twin's stepping of many windows."},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_fastpath", "Compiled hot path of the twin.", -1,
                                    methods};

PyMODINIT_FUNC PyInit__fastpath(void) { return PyModule_Create(&module); }
