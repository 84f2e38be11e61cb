/* microlie_fast._lie: compiled NumPy kernels for microlie's kernel registry.
 *
 * Each function takes C-contiguous float64 arrays of shape (N, k) (rows are elements; the
 * caller broadcasts and flattens batch axes) and returns a tuple of fresh float64 arrays, one per
 * output, of shape (N, k) or (N, r, c). The element formulas live in lie_math.h; the loops here
 * are `omp simd` loops that GCC vectorises, with glibc's libmvec for tan, sin, cos and atan2. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <numpy/arrayobject.h>

#include "lie_math.h"

/* a borrowed view of argument i as a C-contiguous (n, k) float64 array, or NULL with an error */
static PyArrayObject *arg2d(PyObject *const *args, int i, npy_intp k, npy_intp *n) {
    PyObject *o = args[i];
    if (!PyArray_Check(o)) {
        PyErr_Format(PyExc_TypeError, "argument %d: expected a NumPy array", i);
        return NULL;
    }
    PyArrayObject *a = (PyArrayObject *)o;
    if (PyArray_TYPE(a) != NPY_DOUBLE || PyArray_NDIM(a) != 2 || PyArray_DIM(a, 1) != k ||
        !PyArray_IS_C_CONTIGUOUS(a)) {
        PyErr_Format(PyExc_ValueError,
                     "argument %d: expected a C-contiguous float64 array of shape (N, %zd)", i,
                     (Py_ssize_t)k);
        return NULL;
    }
    if (*n < 0) *n = PyArray_DIM(a, 0);
    else if (PyArray_DIM(a, 0) != *n) {
        PyErr_SetString(PyExc_ValueError, "arguments have different numbers of rows");
        return NULL;
    }
    return a;
}

static PyObject *new_out(npy_intp n, npy_intp r, npy_intp c) {
    npy_intp dims[3] = {n, r, c};
    return PyArray_SimpleNew(c > 0 ? 3 : 2, dims, NPY_DOUBLE);
}

#define D(a) ((double *)PyArray_DATA((PyArrayObject *)(a)))

#define CHECK_NARGS(want)                                                                   \
    if (nargs != (want)) {                                                                  \
        PyErr_Format(PyExc_TypeError, "expected %d arguments, got %zd", (want), nargs);     \
        return NULL;                                                                        \
    }

/* two inputs of widths KA, KB, one output of width KO */
#define BINARY(NAME, KA, KB, KO, FN)                                                        \
    static PyObject *NAME(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {        \
        CHECK_NARGS(2);                                                                     \
        npy_intp n = -1;                                                                    \
        PyArrayObject *a = arg2d(args, 0, KA, &n);                                          \
        if (!a) return NULL;                                                                \
        PyArrayObject *b = arg2d(args, 1, KB, &n);                                          \
        if (!b) return NULL;                                                                \
        PyObject *o = new_out(n, KO, 0);                                                    \
        if (!o) return NULL;                                                                \
        const double *x = (const double *)PyArray_DATA(a), *z = (const double *)PyArray_DATA(b); \
        double *y = D(o);                                                                   \
        _Pragma("omp simd") for (npy_intp i = 0; i < n; i++)                                \
            FN(x + KA * i, z + KB * i, y + KO * i);                                         \
        PyObject *t = PyTuple_Pack(1, o);                                                   \
        Py_DECREF(o);                                                                       \
        return t;                                                                           \
    }

static PyObject *pack1(PyObject *o) {
    PyObject *t = PyTuple_Pack(1, o);
    Py_DECREF(o);
    return t;
}
#define UNARY(NAME, KI, KO, FN)                                                             \
    static PyObject *NAME(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {        \
        CHECK_NARGS(1);                                                                     \
        npy_intp n = -1;                                                                    \
        PyArrayObject *a = arg2d(args, 0, KI, &n);                                          \
        if (!a) return NULL;                                                                \
        PyObject *o = new_out(n, KO, 0);                                                    \
        if (!o) return NULL;                                                                \
        const double *x = (const double *)PyArray_DATA(a);                                  \
        double *y = D(o);                                                                   \
        _Pragma("omp simd") for (npy_intp i = 0; i < n; i++) FN(x + KI * i, y + KO * i);    \
        return pack1(o);                                                                    \
    }

/* one input of width KI, one (N, R, C) matrix output */
#define UNARY_MAT(NAME, KI, R, C, FN)                                                       \
    static PyObject *NAME(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {        \
        CHECK_NARGS(1);                                                                     \
        npy_intp n = -1;                                                                    \
        PyArrayObject *a = arg2d(args, 0, KI, &n);                                          \
        if (!a) return NULL;                                                                \
        PyObject *o = new_out(n, R, C);                                                     \
        if (!o) return NULL;                                                                \
        const double *x = (const double *)PyArray_DATA(a);                                  \
        double *y = D(o);                                                                   \
        _Pragma("omp simd") for (npy_intp i = 0; i < n; i++) FN(x + KI * i, y + (R * C) * i); \
        return pack1(o);                                                                    \
    }

LM_INLINE void so3_compose(const double *p, const double *q, double *o) { quat_mul(p, q, o); }
LM_INLINE void so3_act(const double *q, const double *v, double *o) { quat_rotate(q, v, o); }
LM_INLINE void so3_jr3(const double *w, double *J) { so3_jr(w, J, 3); }
LM_INLINE void so3_jr_inv3(const double *w, double *J) { so3_jr_inv(w, J, 3); }

UNARY(k_so3_exp, 3, 4, so3_exp)
UNARY(k_so3_log, 4, 3, so3_log)
UNARY(k_so3_inverse, 4, 4, so3_inverse)
BINARY(k_so3_compose, 4, 4, 4, so3_compose)
BINARY(k_so3_act, 4, 3, 3, so3_act)
UNARY_MAT(k_so3_jr, 3, 3, 3, so3_jr3)
UNARY_MAT(k_so3_jr_inv, 3, 3, 3, so3_jr_inv3)
UNARY(k_se3_exp, 6, 7, se3_exp)
UNARY(k_se3_log, 7, 6, se3_log)
UNARY(k_se3_inverse, 7, 7, se3_inverse)
BINARY(k_se3_compose, 7, 7, 7, se3_compose)
BINARY(k_se3_act, 7, 3, 3, se3_act)
UNARY_MAT(k_se3_jr, 6, 6, 6, se3_jr)
UNARY_MAT(k_se3_jr_inv, 6, 6, 6, se3_jr_inv)

/* act with both Jacobians: (p (N,KP), v (N,3)) -> (out (N,3), JX (N,3,DOF), Jv (N,3,3)) */
#define ACT_JAC(NAME, KP, DOF, FN)                                                          \
    static PyObject *NAME(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {        \
        CHECK_NARGS(2);                                                                     \
        npy_intp n = -1;                                                                    \
        PyArrayObject *a = arg2d(args, 0, KP, &n);                                          \
        if (!a) return NULL;                                                                \
        PyArrayObject *b = arg2d(args, 1, 3, &n);                                           \
        if (!b) return NULL;                                                                \
        PyObject *o = new_out(n, 3, 0), *jx = new_out(n, 3, DOF), *jv = new_out(n, 3, 3);   \
        if (!o || !jx || !jv) {                                                             \
            Py_XDECREF(o); Py_XDECREF(jx); Py_XDECREF(jv);                                  \
            return NULL;                                                                    \
        }                                                                                   \
        const double *p = (const double *)PyArray_DATA(a), *v = (const double *)PyArray_DATA(b); \
        double *po = D(o), *pjx = D(jx), *pjv = D(jv);                                      \
        _Pragma("omp simd") for (npy_intp i = 0; i < n; i++)                                \
            FN(p + KP * i, v + 3 * i, po + 3 * i, pjx + 3 * DOF * i, pjv + 9 * i);          \
        PyObject *t = PyTuple_Pack(3, o, jx, jv);                                           \
        Py_DECREF(o); Py_DECREF(jx); Py_DECREF(jv);                                         \
        return t;                                                                           \
    }

ACT_JAC(k_se3_act_jac, 7, 6, se3_act_jac)
ACT_JAC(k_so3_act_jac, 4, 3, so3_act_jac)

/* exp with its right Jacobian: tau (N,DOF) -> (params (N,KP), Jr (N,DOF,DOF)) */
#define EXP_JAC(NAME, DOF, KP, EXPF, JRF)                                                   \
    static PyObject *NAME(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {        \
        CHECK_NARGS(1);                                                                     \
        npy_intp n = -1;                                                                    \
        PyArrayObject *a = arg2d(args, 0, DOF, &n);                                         \
        if (!a) return NULL;                                                                \
        PyObject *o = new_out(n, KP, 0), *j = new_out(n, DOF, DOF);                         \
        if (!o || !j) {                                                                     \
            Py_XDECREF(o); Py_XDECREF(j);                                                   \
            return NULL;                                                                    \
        }                                                                                   \
        const double *x = (const double *)PyArray_DATA(a);                                  \
        double *po = D(o), *pj = D(j);                                                      \
        _Pragma("omp simd") for (npy_intp i = 0; i < n; i++) {                              \
            EXPF(x + DOF * i, po + KP * i);                                                 \
            JRF(x + DOF * i, pj + DOF * DOF * i);                                           \
        }                                                                                   \
        PyObject *t = PyTuple_Pack(2, o, j);                                                \
        Py_DECREF(o); Py_DECREF(j);                                                         \
        return t;                                                                           \
    }

EXP_JAC(k_se3_exp_jac, 6, 7, se3_exp, se3_jr)
EXP_JAC(k_so3_exp_jac, 3, 4, so3_exp, so3_jr3)

#define ENTRY(name, fn, doc) {name, (PyCFunction)(void (*)(void))fn, METH_FASTCALL, doc}
static PyMethodDef methods[] = {
    ENTRY("so3_exp", k_so3_exp, "SO3 Exp: tau (N,3) -> (q (N,4),)"),
    ENTRY("so3_log", k_so3_log, "SO3 Log: q (N,4) -> (phi (N,3),)"),
    ENTRY("so3_inverse", k_so3_inverse, "SO3 inverse: q (N,4) -> (q (N,4),)"),
    ENTRY("so3_compose", k_so3_compose, "SO3 compose: (q, r) (N,4) -> (q r (N,4),)"),
    ENTRY("so3_act", k_so3_act, "SO3 act: (q (N,4), v (N,3)) -> (R v (N,3),)"),
    ENTRY("so3_jr", k_so3_jr, "SO3 Jr: phi (N,3) -> (Jr (N,3,3),)"),
    ENTRY("so3_jr_inv", k_so3_jr_inv, "SO3 Jr^-1: phi (N,3) -> (Jr^-1 (N,3,3),)"),
    ENTRY("so3_act_jac", k_so3_act_jac, "SO3 act with Jacobians -> (Rv, d/dR, d/dv)"),
    ENTRY("so3_exp_jac", k_so3_exp_jac, "SO3 Exp with Jr -> (q, Jr)"),
    ENTRY("se3_exp", k_se3_exp, "SE3 Exp: tau (N,6) -> (p (N,7),)"),
    ENTRY("se3_log", k_se3_log, "SE3 Log: p (N,7) -> (tau (N,6),)"),
    ENTRY("se3_inverse", k_se3_inverse, "SE3 inverse: p (N,7) -> (p (N,7),)"),
    ENTRY("se3_compose", k_se3_compose, "SE3 compose: (p, q) (N,7) -> (p q (N,7),)"),
    ENTRY("se3_act", k_se3_act, "SE3 act: (p (N,7), v (N,3)) -> (R v + t (N,3),)"),
    ENTRY("se3_jr", k_se3_jr, "SE3 Jr: tau (N,6) -> (Jr (N,6,6),)"),
    ENTRY("se3_jr_inv", k_se3_jr_inv, "SE3 Jr^-1: tau (N,6) -> (Jr^-1 (N,6,6),)"),
    ENTRY("se3_act_jac", k_se3_act_jac, "SE3 act with Jacobians -> (Tv, d/dT, d/dv)"),
    ENTRY("se3_exp_jac", k_se3_exp_jac, "SE3 Exp with Jr -> (p, Jr)"),
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_lie",
                                    "Compiled SO(3)/SE(3) kernels for microlie.", -1, methods};

PyMODINIT_FUNC PyInit__lie(void) {
    import_array();
    return PyModule_Create(&module);
}
