/* Compiled kernel of the two-input Mamdani FLS (min t-norm; BMM or Nie–Tan).
 *
 * The same arithmetic as twin/fuzzy/mamdani.py (evaluate_scalar) in the same order,
 * so the pure-Python path is its reference and fallback. Built as an optional
 * extension: if it cannot be compiled, twin falls back to pure Python.
 *
 * Python API:
 *   make(lower1, upper1, lower2, upper2, y, reducer, m, n) -> capsule
 *       lowerX/upperX: bytes of K*4 doubles (peak, 1/(peak-left), 1/(right-peak), height),
 *       0 slope on a shoulder side; y: bytes of K1*K2 doubles (row-major consequents);
 *       reducer 0 = BMM, 1 = Nie–Tan.
 *   evaluate(capsule, x1, x2) -> float          (finite inputs; checked by the caller)
 *   evaluate_many(capsule, x1, x2, out)         (contiguous float64 buffers of equal length)
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#define MAX_SETS 64

typedef struct {
    int k1, k2, reducer;
    double m, n;
    double lo1[MAX_SETS * 4], up1[MAX_SETS * 4], lo2[MAX_SETS * 4], up2[MAX_SETS * 4];
    double *y;
} fls_t;

static const char *CAPSULE = "twin.fuzzy._kernel.fls";

static void fls_free(PyObject *cap) {
    fls_t *f = (fls_t *)PyCapsule_GetPointer(cap, CAPSULE);
    if (f) {
        free(f->y);
        free(f);
    }
}

static void memberships(const double *p, int k, double x, double *out) {
    for (int i = 0; i < k; i++) {
        double d = x - p[4 * i];
        double v = 1.0 + d * p[4 * i + 1];
        double w = 1.0 - d * p[4 * i + 2];
        if (w < v) v = w;
        out[i] = v > 0.0 ? p[4 * i + 3] * v : 0.0;
    }
}

/* Σ f and Σ f·y over the rules (i, j) that fire, f = min(a_i, b_j), row-major. */
static void min_firing_sums(const fls_t *f, const double *a, const double *b, double *s, double *w) {
    double ss = 0.0, ww = 0.0;
    for (int i = 0; i < f->k1; i++) {
        if (a[i] <= 0.0) continue;
        const double *row = f->y + (size_t)i * f->k2;
        for (int j = 0; j < f->k2; j++) {
            if (b[j] <= 0.0) continue;
            double v = a[i] < b[j] ? a[i] : b[j];
            ss += v;
            ww += v * row[j];
        }
    }
    *s = ss;
    *w = ww;
}

static double eval_one(const fls_t *f, double x1, double x2) {
    double a_lo[MAX_SETS], a_up[MAX_SETS], b_lo[MAX_SETS], b_up[MAX_SETS];
    memberships(f->lo1, f->k1, x1, a_lo);
    memberships(f->up1, f->k1, x1, a_up);
    memberships(f->lo2, f->k2, x2, b_lo);
    memberships(f->up2, f->k2, x2, b_up);
    double s_up, w_up, s_lo, w_lo;
    /* upper sums first, then lower: the Python path's order */
    min_firing_sums(f, a_up, b_up, &s_up, &w_up);
    min_firing_sums(f, a_lo, b_lo, &s_lo, &w_lo);
    if (f->reducer == 1) return (w_lo + w_up) / (s_lo + s_up);
    if (s_lo > 0.0) return f->m * w_lo / s_lo + f->n * w_up / s_up;
    return (f->m + f->n) * w_up / s_up;
}

static int copy_sets(PyObject *obj, double *dst, int *k) {
    char *buf;
    Py_ssize_t len;
    if (PyBytes_AsStringAndSize(obj, &buf, &len) < 0) return -1;
    if (len % (4 * sizeof(double)) != 0 || len / (Py_ssize_t)(4 * sizeof(double)) > MAX_SETS || len == 0) {
        PyErr_SetString(PyExc_ValueError, "set parameters must be 1..64 sets of 4 doubles");
        return -1;
    }
    int kk = (int)(len / (4 * sizeof(double)));
    if (*k >= 0 && *k != kk) {
        PyErr_SetString(PyExc_ValueError, "lower and upper parameters must describe the same number of sets");
        return -1;
    }
    *k = kk;
    memcpy(dst, buf, (size_t)len);
    return 0;
}

static PyObject *make(PyObject *self, PyObject *args) {
    PyObject *lo1, *up1, *lo2, *up2, *y;
    int reducer;
    double m, n;
    if (!PyArg_ParseTuple(args, "OOOOOidd", &lo1, &up1, &lo2, &up2, &y, &reducer, &m, &n)) return NULL;
    if (reducer != 0 && reducer != 1) {
        PyErr_SetString(PyExc_ValueError, "reducer must be 0 (BMM) or 1 (Nie-Tan)");
        return NULL;
    }
    if (!isfinite(m) || !isfinite(n) || m < 0.0 || n < 0.0 || m + n <= 0.0) {
        PyErr_SetString(PyExc_ValueError, "BMM weights m, n must be finite, >= 0 and not both 0");
        return NULL;
    }
    fls_t *f = (fls_t *)calloc(1, sizeof(fls_t));
    if (!f) return PyErr_NoMemory();
    f->k1 = -1;
    f->k2 = -1;
    if (copy_sets(lo1, f->lo1, &f->k1) < 0 || copy_sets(up1, f->up1, &f->k1) < 0 ||
        copy_sets(lo2, f->lo2, &f->k2) < 0 || copy_sets(up2, f->up2, &f->k2) < 0) {
        free(f);
        return NULL;
    }
    char *buf;
    Py_ssize_t len;
    if (PyBytes_AsStringAndSize(y, &buf, &len) < 0) {
        free(f);
        return NULL;
    }
    if (len != (Py_ssize_t)(sizeof(double) * f->k1 * f->k2)) {
        free(f);
        PyErr_SetString(PyExc_ValueError, "consequents must be K1*K2 doubles");
        return NULL;
    }
    f->y = (double *)malloc((size_t)len);
    if (!f->y) {
        free(f);
        return PyErr_NoMemory();
    }
    memcpy(f->y, buf, (size_t)len);
    f->reducer = reducer;
    f->m = m;
    f->n = n;
    PyObject *cap = PyCapsule_New(f, CAPSULE, fls_free);
    if (!cap) {
        free(f->y);
        free(f);
    }
    return cap;
}

static PyObject *evaluate(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 3) {
        PyErr_SetString(PyExc_TypeError, "evaluate(capsule, x1, x2)");
        return NULL;
    }
    fls_t *f = (fls_t *)PyCapsule_GetPointer(args[0], CAPSULE);
    if (!f) return NULL;
    double x1 = PyFloat_AsDouble(args[1]);
    if (x1 == -1.0 && PyErr_Occurred()) return NULL;
    double x2 = PyFloat_AsDouble(args[2]);
    if (x2 == -1.0 && PyErr_Occurred()) return NULL;
    return PyFloat_FromDouble(eval_one(f, x1, x2));
}

/* A C-contiguous buffer of float64 ("d"); writable if asked. Returns 0 or -1 with an error set. */
static int get_doubles(PyObject *obj, Py_buffer *view, int writable, const char *name) {
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, view, flags) < 0) return -1;
    if (view->itemsize != (Py_ssize_t)sizeof(double) || view->format == NULL || strcmp(view->format, "d") != 0) {
        PyErr_Format(PyExc_TypeError, "%s must be a contiguous float64 buffer", name);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}

static PyObject *evaluate_many(PyObject *self, PyObject *args) {
    PyObject *cap, *o1, *o2, *oo;
    Py_buffer b1, b2, bo;
    if (!PyArg_ParseTuple(args, "OOOO", &cap, &o1, &o2, &oo)) return NULL;
    fls_t *f = (fls_t *)PyCapsule_GetPointer(cap, CAPSULE);
    if (!f) return NULL;
    if (get_doubles(o1, &b1, 0, "x1") < 0) return NULL;
    if (get_doubles(o2, &b2, 0, "x2") < 0) {
        PyBuffer_Release(&b1);
        return NULL;
    }
    if (get_doubles(oo, &bo, 1, "out") < 0) {
        PyBuffer_Release(&b1);
        PyBuffer_Release(&b2);
        return NULL;
    }
    PyObject *result = NULL;
    if (b2.len != b1.len || bo.len != b1.len) {
        PyErr_SetString(PyExc_ValueError, "x1, x2 and out must have the same length");
    } else {
        Py_ssize_t n = b1.len / (Py_ssize_t)sizeof(double);
        const double *x1 = (const double *)b1.buf, *x2 = (const double *)b2.buf;
        double *out = (double *)bo.buf;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t i = 0; i < n; i++) out[i] = eval_one(f, x1[i], x2[i]);
        Py_END_ALLOW_THREADS
        result = Py_None;
        Py_INCREF(result);
    }
    PyBuffer_Release(&b1);
    PyBuffer_Release(&b2);
    PyBuffer_Release(&bo);
    return result;
}

static PyMethodDef methods[] = {
    {"make", make, METH_VARARGS, "Compile a two-input Mamdani FLS; returns a capsule."},
    {"evaluate", (PyCFunction)(void (*)(void))evaluate, METH_FASTCALL, "evaluate(capsule, x1, x2) -> float"},
    {"evaluate_many", evaluate_many, METH_VARARGS, "evaluate_many(capsule, x1, x2, out)"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_kernel", "Compiled Mamdani FLS kernel.", -1, methods};

PyMODINIT_FUNC PyInit__kernel(void) { return PyModule_Create(&module); }
