/* microlie._c._reproj: the compiled linearisation of BAL reprojection factors
 * (microlie.optim.ReprojectionFactor with the "bal" model and an SO3 x R(3) world-to-camera
 * pose; microlie.optim.core.compiled.ReprojectionPlan), the compiled form of the NumPy path
 * (ReprojectionFactor.evaluate_into, then Problem.linearize's whitening, robust correction
 * and products), which stays the reference and the fallback.
 *
 * Per observation o with rows (ir, it, ix, ik) = idx[o] of R (nr, 3, 3), t (nt, 3), X (nx, 3)
 * and K (nk, 3) = (f, k1, k2):
 *   P = R X + t, p = -P_xy / P_z, r2 = |p|^2, d = 1 + k1 r2 + k2 r2^2,
 *   e = f d p - obs[o] (pixels), and the right Jacobians in argument order
 *   [dphi (R Exp(dphi)), dt, dX, dK] (2 x 12): A = d uv / d P, J_X = A R, J_dt = A,
 *   row i of J_dphi = X x (J_X row i), J_K = (d p, f r2 p, f r2^2 p);
 *   with drop != 0, points with P_z >= 0 get e = 0 and J = 0 (behind="drop");
 *   whitened by L (nL = 1 or m, 2, 2): [A e] <- L [J e], s[o] = |L e|^2;
 *   with wts (m, 3) = (sqrt(rho'), residual scale, alpha / s) Triggs' correction:
 *   A <- sqrt(rho') (A - (alpha / s) e (e^T A)), e <- scale e;
 *   then data[starts[o, 4 k + l] + b lens[o, l] + a] += (A^T A)[3 k + a, 3 l + b] for the
 *   argument pairs whose start is >= 0 (the CSC block of nodes (k, l): every scalar column of
 *   block column l holds lens[o, l] rows), grad[goff[o, k] + a] += (A^T e)[3 k + a] (>= 0).
 *
 * cost(R, t, X, K, idx, obs, L, drop, s): s only.
 * normal(R, t, X, K, idx, obs, L, drop, wts or None, starts, lens, goff, s, data, grad).
 * All float64; index arrays intp. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <math.h>
#include <numpy/arrayobject.h>

#include "array_args.h"

/* one observation: the whitened residual e (2) and, when J != NULL, the whitened Jacobian
 * J (2 x 12, row-major); returns s = |e|^2 */
static inline __attribute__((always_inline)) double observe(
    const double *R, const double *t, const double *X, const double *K, const double *obs,
    const double *L, int drop, double *e, double *J) {
    double P0 = R[0] * X[0] + R[1] * X[1] + R[2] * X[2] + t[0];
    double P1 = R[3] * X[0] + R[4] * X[1] + R[5] * X[2] + t[1];
    double P2 = R[6] * X[0] + R[7] * X[1] + R[8] * X[2] + t[2];
    if (drop && !(P2 < 0.0)) {
        e[0] = e[1] = 0.0;
        if (J)
            for (int q = 0; q < 24; q++) J[q] = 0.0;
        return 0.0;
    }
    double f = K[0], k1 = K[1], k2 = K[2];
    double iz = -1.0 / P2;
    double px = P0 * iz, py = P1 * iz;
    double r2 = px * px + py * py;
    double d = 1.0 + r2 * (k1 + k2 * r2);
    double fd = f * d;
    double r0 = fd * px - obs[0], r1 = fd * py - obs[1];
    e[0] = L[0] * r0 + L[1] * r1;
    e[1] = L[2] * r0 + L[3] * r1;
    if (J) {
        double g = 2.0 * f * (k1 + 2.0 * k2 * r2);
        double a00 = fd + g * px * px, a01 = g * px * py, a11 = fd + g * py * py;
        double A[2][3] = {{a00 * iz, a01 * iz, (a00 * px + a01 * py) * iz},
                          {a01 * iz, a11 * iz, (a01 * px + a11 * py) * iz}};
        double fr2 = f * r2;
        double JK[2][3] = {{d * px, fr2 * px, fr2 * r2 * px}, {d * py, fr2 * py, fr2 * r2 * py}};
        double U[2][12];
        for (int i = 0; i < 2; i++) {
            double j0 = A[i][0] * R[0] + A[i][1] * R[3] + A[i][2] * R[6];
            double j1 = A[i][0] * R[1] + A[i][1] * R[4] + A[i][2] * R[7];
            double j2 = A[i][0] * R[2] + A[i][1] * R[5] + A[i][2] * R[8];
            U[i][0] = X[1] * j2 - X[2] * j1;  /* X x (A R)_i */
            U[i][1] = X[2] * j0 - X[0] * j2;
            U[i][2] = X[0] * j1 - X[1] * j0;
            U[i][3] = A[i][0], U[i][4] = A[i][1], U[i][5] = A[i][2];
            U[i][6] = j0, U[i][7] = j1, U[i][8] = j2;
            U[i][9] = JK[i][0], U[i][10] = JK[i][1], U[i][11] = JK[i][2];
        }
        for (int c = 0; c < 12; c++) {
            J[c] = L[0] * U[0][c] + L[1] * U[1][c];
            J[12 + c] = L[2] * U[0][c] + L[3] * U[1][c];
        }
    }
    return e[0] * e[0] + e[1] * e[1];
}

typedef struct {
    PyArrayObject *R, *t, *X, *K, *idx, *obs, *L, *s;
    ix m, nL;
    int drop;
} common;

/* the arguments both functions share; 0 on success */
static int common_args(PyObject *const *args, common *c) {
    ix d33[3] = {-1, 3, 3}, d3[2] = {-1, 3};
    if (!(c->R = arg(args[0], "R", NPY_DOUBLE, 3, d33)) ||
        !(c->t = arg(args[1], "t", NPY_DOUBLE, 2, d3)) ||
        !(c->X = arg(args[2], "X", NPY_DOUBLE, 2, d3)) ||
        !(c->K = arg(args[3], "K", NPY_DOUBLE, 2, d3)))
        return -1;
    ix di[2] = {-1, 4};
    if (!(c->idx = arg(args[4], "idx", NPY_INTP, 2, di))) return -1;
    c->m = PyArray_DIM(c->idx, 0);
    ix dobs[2] = {c->m, 2}, dL[3] = {-1, 2, 2};
    if (!(c->obs = arg(args[5], "obs", NPY_DOUBLE, 2, dobs)) ||
        !(c->L = arg(args[6], "L", NPY_DOUBLE, 3, dL)))
        return -1;
    c->nL = PyArray_DIM(c->L, 0);
    if (c->nL != 1 && c->nL != c->m) {
        PyErr_SetString(PyExc_ValueError, "L must hold 1 or m square-root informations");
        return -1;
    }
    c->drop = PyObject_IsTrue(args[7]);
    if (c->drop < 0) return -1;
    const ix *ip = (const ix *)PyArray_DATA(c->idx);
    ix lim[4] = {PyArray_DIM(c->R, 0), PyArray_DIM(c->t, 0), PyArray_DIM(c->X, 0),
                 PyArray_DIM(c->K, 0)};
    for (ix o = 0; o < c->m; o++)
        for (int k = 0; k < 4; k++)
            if (ip[4 * o + k] < 0 || ip[4 * o + k] >= lim[k]) {
                PyErr_SetString(PyExc_ValueError, "idx holds a row outside R, t, X or K");
                return -1;
            }
    return 0;
}

#define PTRS(c)                                                                           \
    const double *Rp = PyArray_DATA((c).R), *tp = PyArray_DATA((c).t),                    \
                 *Xp = PyArray_DATA((c).X), *Kp = PyArray_DATA((c).K),                    \
                 *op = PyArray_DATA((c).obs), *Lp = PyArray_DATA((c).L);                  \
    const ix *ip = PyArray_DATA((c).idx);                                                 \
    double *sp = PyArray_DATA((c).s)

static PyObject *cost_(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 9) {
        PyErr_SetString(PyExc_TypeError, "cost(R, t, X, K, idx, obs, L, drop, s) takes 9 "
                                         "arguments");
        return NULL;
    }
    common c;
    if (common_args(args, &c)) return NULL;
    ix ds[1] = {c.m};
    if (!(c.s = arg(args[8], "s", NPY_DOUBLE, 1, ds))) return NULL;
    PTRS(c);
    ix m = c.m, lstep = c.nL == 1 ? 0 : 4;
    int drop = c.drop;
    Py_BEGIN_ALLOW_THREADS
    for (ix o = 0; o < m; o++) {
        const ix *q = ip + 4 * o;
        double e[2];
        sp[o] = observe(Rp + 9 * q[0], tp + 3 * q[1], Xp + 3 * q[2], Kp + 3 * q[3], op + 2 * o,
                        Lp + lstep * o, drop, e, NULL);
    }
    Py_END_ALLOW_THREADS
    Py_RETURN_NONE;
}

static PyObject *normal_(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 15) {
        PyErr_SetString(PyExc_TypeError, "normal(R, t, X, K, idx, obs, L, drop, wts, starts, "
                                         "lens, goff, s, data, grad) takes 15 arguments");
        return NULL;
    }
    common c;
    if (common_args(args, &c)) return NULL;
    ix m = c.m, any1[1] = {-1};
    ix dw[2] = {m, 3}, d16[2] = {m, 16}, d4[2] = {m, 4}, ds[1] = {m};
    PyArrayObject *wts = NULL, *st, *ln, *go, *data, *grad;
    if (args[8] != Py_None && !(wts = arg(args[8], "wts", NPY_DOUBLE, 2, dw))) return NULL;
    if (!(st = arg(args[9], "starts", NPY_INTP, 2, d16)) ||
        !(ln = arg(args[10], "lens", NPY_INTP, 2, d4)) ||
        !(go = arg(args[11], "goff", NPY_INTP, 2, d4)) ||
        !(c.s = arg(args[12], "s", NPY_DOUBLE, 1, ds)) ||
        !(data = arg(args[13], "data", NPY_DOUBLE, 1, any1)) ||
        !(grad = arg(args[14], "grad", NPY_DOUBLE, 1, any1)))
        return NULL;
    const ix *stp = PyArray_DATA(st), *lnp = PyArray_DATA(ln), *gop = PyArray_DATA(go);
    ix nd = PyArray_DIM(data, 0), ng = PyArray_DIM(grad, 0);
    for (ix o = 0; o < m; o++) {  /* every position written is inside data and grad */
        for (int k = 0; k < 4; k++) {
            ix g = gop[4 * o + k];
            if (g >= 0 && g + 3 > ng) {
                PyErr_SetString(PyExc_ValueError, "goff holds a position outside grad");
                return NULL;
            }
            for (int l = 0; l < 4; l++) {
                ix s0 = stp[16 * o + 4 * k + l];
                if (s0 >= 0 && (lnp[4 * o + l] < 3 || s0 + 2 * lnp[4 * o + l] + 3 > nd)) {
                    PyErr_SetString(PyExc_ValueError, "starts holds a block outside data");
                    return NULL;
                }
            }
        }
    }
    PTRS(c);
    const double *wp = wts ? PyArray_DATA(wts) : NULL;
    double *D = PyArray_DATA(data), *G = PyArray_DATA(grad);
    ix lstep = c.nL == 1 ? 0 : 4;
    int drop = c.drop;
    Py_BEGIN_ALLOW_THREADS
    for (ix o = 0; o < m; o++) {
        const ix *q = ip + 4 * o;
        double e[2], J[24];
        sp[o] = observe(Rp + 9 * q[0], tp + 3 * q[1], Xp + 3 * q[2], Kp + 3 * q[3], op + 2 * o,
                        Lp + lstep * o, drop, e, J);
        if (wp) {
            double sq = wp[3 * o], scale = wp[3 * o + 1], aos = wp[3 * o + 2];
            double ae0 = aos * e[0], ae1 = aos * e[1];
            for (int col = 0; col < 12; col++) {
                double eA = e[0] * J[col] + e[1] * J[12 + col];
                J[col] = sq * (J[col] - ae0 * eA);
                J[12 + col] = sq * (J[12 + col] - ae1 * eA);
            }
            e[0] *= scale;
            e[1] *= scale;
        }
        const ix *so = stp + 16 * o, *lo = lnp + 4 * o, *go_ = gop + 4 * o;
        for (int k = 0; k < 4; k++) {
            const double *u0 = J + 3 * k, *u1 = J + 12 + 3 * k;
            if (go_[k] >= 0) {
                double *gg = G + go_[k];
                for (int a = 0; a < 3; a++) gg[a] += u0[a] * e[0] + u1[a] * e[1];
            }
            for (int l = 0; l < 4; l++) {
                ix s0 = so[4 * k + l];
                if (s0 < 0) continue;
                const double *v0 = J + 3 * l, *v1 = J + 12 + 3 * l;
                ix cl = lo[l];
                for (int b = 0; b < 3; b++) {
                    double *col = D + s0 + b * cl;
                    double y0 = v0[b], y1 = v1[b];
                    for (int a = 0; a < 3; a++) col[a] += u0[a] * y0 + u1[a] * y1;
                }
            }
        }
    }
    Py_END_ALLOW_THREADS
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"cost", (PyCFunction)(void (*)(void))cost_, METH_FASTCALL,
     "cost(R, t, X, K, idx, obs, L, drop, s) -> None: the squared whitened BAL reprojection "
     "residuals (see the module source)"},
    {"normal", (PyCFunction)(void (*)(void))normal_, METH_FASTCALL,
     "normal(R, t, X, K, idx, obs, L, drop, wts, starts, lens, goff, s, data, grad) -> None: "
     "the BAL reprojection factors' A^T A and A^T e added into H's CSC values and the "
     "gradient (see the module source)"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_reproj",
                                    "The compiled linearisation of BAL reprojection factors.",
                                    -1, methods};

PyMODINIT_FUNC PyInit__reproj(void) {
    import_array();
    return PyModule_Create(&module);
}
