/* microlie_fast._graph: the pose-graph edge loop of microlie.optim in one compiled pass.
 *
 * For a batch of SE(3) BetweenFactors r = Log((X_i Z)^-1 X_j) with square-root information L
 * (one per edge or one shared) it computes, per edge, the residual and its right Jacobians
 * (d r/d X_j = Jr^-1(r), d r/d X_i = -Jl^-1(r) Ad(Z^-1)), the whitened e = L r and A = L [J_i J_j],
 * optionally Ceres' robust correction (A <- sq (A - aos e (e^T A)), e <- scale e), the block
 * products A^T A and A^T e, and adds them straight into the CSC values of the problem's fixed
 * pattern and into the gradient. The group formulas are those of lie_math.h (the same as the
 * generic NumPy kernels); the Lie part runs on structure-of-arrays blocks of S edges (vectorised
 * like _lie.c), the products and the scatter per edge.
 *
 * Pattern addressing (microlie.optim.problem): entry (a, b) of the block (u, v) of H is at
 * start_uv + b * len_v + a, with start_uv the CSC position of its entry (0, 0) and len_v the
 * length of the columns of block column v; start -1 skips a block (a fixed variable), and a
 * gradient offset -1 skips that argument's gradient rows. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <numpy/arrayobject.h>

#define S 8 /* edges per block: one AVX-512 vector; the block buffers stay in L1 */
#include "lie_math.h"

typedef npy_intp ix;

/* ------------------------------------------------------------------ argument checks */

/* a C-contiguous array of the given type, ndim and trailing dims (-1: any) */
static int check(PyObject *o, const char *what, int type, int ndim, ix d0, ix d1, ix d2,
                 char **ptr) {
    if (!PyArray_Check(o)) {
        PyErr_Format(PyExc_TypeError, "%s must be a NumPy array", what);
        return 0;
    }
    PyArrayObject *a = (PyArrayObject *)o;
    ix want[3] = {d0, d1, d2};
    int ok = PyArray_TYPE(a) == type && PyArray_NDIM(a) == ndim && PyArray_IS_C_CONTIGUOUS(a);
    for (int k = 0; ok && k < ndim; k++)
        if (want[k] >= 0 && PyArray_DIM(a, k) != want[k]) ok = 0;
    if (!ok) {
        PyErr_Format(PyExc_ValueError,
                     "%s must be a C-contiguous %s array of %d dimensions (%zd, %zd, %zd)", what,
                     type == NPY_DOUBLE ? "float64" : "int64", ndim, d0, d1, d2);
        return 0;
    }
    *ptr = PyArray_BYTES(a);
    return 1;
}

static ix dim0(PyObject *o) { return PyArray_DIM((PyArrayObject *)o, 0); }

/* ------------------------------------------------------------------ the SE(3) edge */

#define D 6   /* residual dimension and dof */
#define DD 12 /* both arguments */

/* the Lie part of one block of m <= S edges: residual (6), Jr^-1 (36), -Jl^-1 (36), Ad(Z^-1) (36)
 * in SoA layout: component c of edge j at out[c * S + j] */
#define LIE_W (6 + 36 + 36 + 36)
static void lie_block(const double *restrict X, const int64_t *restrict ii,
                      const int64_t *restrict jj, const double *restrict Z, ix k0, ix m,
                      int need_jac, double *restrict buf, double *restrict out) {
    double *bi = buf, *bj = buf + 7 * S, *bz = buf + 14 * S, *bc = buf + 21 * S;
    for (ix j = 0; j < m; j++) {
        const double *xi = X + 7 * ii[k0 + j], *xj = X + 7 * jj[k0 + j], *z = Z + 7 * (k0 + j);
        for (int c = 0; c < 7; c++) {
            bi[c * S + j] = xi[c];
            bj[c * S + j] = xj[c];
            bz[c * S + j] = z[c];
        }
    }
    _Pragma("omp simd") for (ix j = 0; j < m; j++) se3_compose(bi + j, bz + j, bc + j);
    if (need_jac) {
        _Pragma("omp simd") for (ix j = 0; j < m; j++) se3_minus_jac(bj + j, bc + j, out + j);
        _Pragma("omp simd") for (ix j = 0; j < m; j++)
            se3_adjoint_inv(bz + j, bz + j, out + 78 * S + j);
    } else {
        _Pragma("omp simd") for (ix j = 0; j < m; j++) se3_minus(bj + j, bc + j, out + j);
    }
}

/* the whitened products of one edge, on SoA blocks like the element operations of lie_math.h
 * (called in an omp simd loop over the edges of a block): o = lie_block's output, Lb = L (36),
 * w = (sqrt(rho'), scale, alpha / s) when robust; h = A^T A row-major (144), A^T e (12),
 * |e|^2 before the correction (1) */
#define NH (DD * DD)
#define NOUT (NH + DD + 1)
LM_INLINE void edge_normal(const double *o, const double *Lb, const double *w, double *h,
                           int robust) {
    double r[D], J[D * DD], L[36], e[D], A[D * DD];
#pragma GCC unroll 64
    for (int c = 0; c < D; c++) r[c] = o[c * S];
#pragma GCC unroll 64
    for (int c = 0; c < 36; c++) L[c] = Lb[c * S];
    /* J = [-Jl^-1 Ad(Z^-1), Jr^-1]: d r / d X_i, d r / d X_j */
#pragma GCC unroll 64
    for (int a = 0; a < D; a++)
#pragma GCC unroll 64
        for (int b = 0; b < D; b++) {
            double acc = 0.0;
#pragma GCC unroll 64
            for (int c = 0; c < D; c++) acc += o[(42 + D * a + c) * S] * o[(78 + D * c + b) * S];
            J[DD * a + b] = acc;
            J[DD * a + D + b] = o[(6 + D * a + b) * S];
        }
    /* e = L r, A = L J */
#pragma GCC unroll 64
    for (int a = 0; a < D; a++) {
        double acc = 0.0;
#pragma GCC unroll 64
        for (int c = 0; c < D; c++) acc += L[D * a + c] * r[c];
        e[a] = acc;
#pragma GCC unroll 64
        for (int b = 0; b < DD; b++) {
            double t = 0.0;
#pragma GCC unroll 64
            for (int c = 0; c < D; c++) t += L[D * a + c] * J[DD * c + b];
            A[DD * a + b] = t;
        }
    }
    double ss = 0.0;
#pragma GCC unroll 64
    for (int c = 0; c < D; c++) ss += e[c] * e[c];
    h[(NH + DD) * S] = ss;
    if (robust) { /* Ceres' corrector: A <- sq (A - aos e (e^T A)), e <- scale e */
        double sq = w[0], scale = w[S], aos = w[2 * S];
#pragma GCC unroll 64
        for (int b = 0; b < DD; b++) {
            double eA = 0.0;
#pragma GCC unroll 64
            for (int a = 0; a < D; a++) eA += e[a] * A[DD * a + b];
#pragma GCC unroll 64
            for (int a = 0; a < D; a++) A[DD * a + b] = sq * (A[DD * a + b] - aos * e[a] * eA);
        }
#pragma GCC unroll 64
        for (int a = 0; a < D; a++) e[a] *= scale;
    }
#pragma GCC unroll 128
    for (int p = 0; p < DD; p++) {
#pragma GCC unroll 128
        for (int q = p; q < DD; q++) {
            double acc = 0.0;
#pragma GCC unroll 64
            for (int c = 0; c < D; c++) acc += A[DD * c + p] * A[DD * c + q];
            h[(DD * p + q) * S] = acc;
            h[(DD * q + p) * S] = acc;
        }
        double acc = 0.0;
#pragma GCC unroll 64
        for (int c = 0; c < D; c++) acc += A[DD * c + p] * e[c];
        h[(NH + p) * S] = acc;
    }
}

/* rows of m <= S (1 or m, 36) matrices into a SoA block */
static void load_L(const double *L, ix lstep, ix k0, ix m, double *Lb) {
    for (ix j = 0; j < m; j++) {
        const double *x = L + lstep * (k0 + j);
        for (int c = 0; c < 36; c++) Lb[c * S + j] = x[c];
    }
}

/* the cost terms s_k = |L_k r_k|^2 of every edge */
static void se3_cost_loop(const double *X, const int64_t *ii, const int64_t *jj, const double *Z,
                          const double *L, ix lstep, ix m, double *s) {
    double buf[28 * S] __attribute__((aligned(64)));
    double out[LIE_W * S] __attribute__((aligned(64)));
    double Lb[36 * S] __attribute__((aligned(64)));
    if (!lstep) load_L(L, 0, 0, S, Lb);
    for (ix k0 = 0; k0 < m; k0 += S) {
        ix n = m - k0 < S ? m - k0 : S;
        lie_block(X, ii, jj, Z, k0, n, 0, buf, out);
        if (lstep) load_L(L, lstep, k0, n, Lb);
        _Pragma("omp simd") for (ix j = 0; j < n; j++) {
            double acc = 0.0;
#pragma GCC unroll 64
            for (int a = 0; a < D; a++) {
                double t = 0.0;
#pragma GCC unroll 64
                for (int c = 0; c < D; c++) t += Lb[(D * a + c) * S + j] * out[c * S + j];
                acc += t * t;
            }
            s[k0 + j] = acc;
        }
    }
}

static void se3_normal_loop(const double *X, const int64_t *ii, const int64_t *jj,
                            const double *Z, const double *L, ix lstep, const double *wts, ix m,
                            const int64_t *starts, const int64_t *lens, const int64_t *goff,
                            double *s, double *data, double *grad) {
    double buf[28 * S] __attribute__((aligned(64)));
    double out[LIE_W * S] __attribute__((aligned(64)));
    double Lb[36 * S] __attribute__((aligned(64)));
    double wb[3 * S] __attribute__((aligned(64)));
    double h[NOUT * S] __attribute__((aligned(64)));
    if (!lstep) load_L(L, 0, 0, S, Lb);
    for (ix k0 = 0; k0 < m; k0 += S) {
        ix n = m - k0 < S ? m - k0 : S;
        lie_block(X, ii, jj, Z, k0, n, 1, buf, out);
        if (lstep) load_L(L, lstep, k0, n, Lb);
        if (wts) {
            for (ix j = 0; j < n; j++)
                for (int c = 0; c < 3; c++) wb[c * S + j] = wts[3 * (k0 + j) + c];
            _Pragma("omp simd") for (ix j = 0; j < n; j++)
                edge_normal(out + j, Lb + j, wb + j, h + j, 1);
        } else {
            _Pragma("omp simd") for (ix j = 0; j < n; j++)
                edge_normal(out + j, Lb + j, wb + j, h + j, 0);
        }
        /* scatter: blocks (i, i), (i, j), (j, i), (j, j) */
        for (ix j = 0; j < n; j++) {
            ix k = k0 + j;
            s[k] = h[(NH + DD) * S + j];
            const int64_t *st = starts + 4 * k, *ln = lens + 2 * k, *go = goff + 2 * k;
            for (int u = 0; u < 2; u++) {
                if (go[u] >= 0)
                    for (int a = 0; a < D; a++) grad[go[u] + a] += h[(NH + D * u + a) * S + j];
                for (int v = 0; v < 2; v++) {
                    int64_t s0 = st[2 * u + v];
                    if (s0 < 0) continue;
                    int64_t lv = ln[v];
                    for (int b = 0; b < D; b++) {
                        double *col = data + s0 + b * lv;
                        for (int a = 0; a < D; a++)
                            col[a] += h[(DD * (D * u + a) + D * v + b) * S + j];
                    }
                }
            }
        }
    }
}

/* ------------------------------------------------------------------ Python entry points */

/* common checks of (X, ii, jj, Z, L); returns m, or -1 with an exception set */
static ix edge_args(PyObject *const *args, char **X, char **ii, char **jj, char **Z, char **L,
                    ix *lstep) {
    if (!check(args[0], "X", NPY_DOUBLE, 2, -1, 7, 0, X)) return -1;
    ix m = PyArray_Check(args[1]) ? dim0(args[1]) : 0;
    if (!check(args[1], "ii", NPY_INT64, 1, m, 0, 0, ii)) return -1;
    if (!check(args[2], "jj", NPY_INT64, 1, m, 0, 0, jj)) return -1;
    if (!check(args[3], "Z", NPY_DOUBLE, 2, m, 7, 0, Z)) return -1;
    if (!check(args[4], "L", NPY_DOUBLE, 3, -1, D, D, L)) return -1;
    ix nl = dim0(args[4]);
    if (nl != 1 && nl != m) {
        PyErr_Format(PyExc_ValueError, "L must hold 1 or %zd matrices, got %zd", m, nl);
        return -1;
    }
    *lstep = nl == 1 ? 0 : D * D;
    ix n = dim0(args[0]);
    const int64_t *a = (const int64_t *)*ii, *b = (const int64_t *)*jj;
    for (ix k = 0; k < m; k++)
        if (a[k] < 0 || a[k] >= n || b[k] < 0 || b[k] >= n) {
            PyErr_Format(PyExc_IndexError, "edge %zd: variable index out of range [0, %zd)", k,
                         n);
            return -1;
        }
    return m;
}

static const char cost_doc[] =
    "se3_between_cost(X, ii, jj, Z, L, s)\n\n"
    "s[k] = |L_k Log((X[ii[k]] Z[k])^-1 X[jj[k]])|^2 for every edge k (X (n, 7), ii and jj\n"
    "(m,) int64, Z (m, 7), L (1 or m, 6, 6), s (m,) written).";

static PyObject *py_se3_cost(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 6) {
        PyErr_Format(PyExc_TypeError, "se3_between_cost: expected 6 arguments, got %zd", nargs);
        return NULL;
    }
    char *X, *ii, *jj, *Z, *L, *s;
    ix lstep;
    ix m = edge_args(args, &X, &ii, &jj, &Z, &L, &lstep);
    if (m < 0) return NULL;
    if (!check(args[5], "s", NPY_DOUBLE, 1, m, 0, 0, &s)) return NULL;
    Py_BEGIN_ALLOW_THREADS
    se3_cost_loop((const double *)X, (const int64_t *)ii, (const int64_t *)jj,
                  (const double *)Z, (const double *)L, lstep, m, (double *)s);
    Py_END_ALLOW_THREADS
    Py_RETURN_NONE;
}

static const char normal_doc[] =
    "se3_between_normal(X, ii, jj, Z, L, wts, starts, lens, goff, s, data, grad)\n\n"
    "Adds every edge's whitened A^T A into data (CSC values, nnz) and A^T e into grad (size,)\n"
    "and writes s[k] = |e_k|^2 (before the robust correction). wts: None or (m, 3) rows\n"
    "(sqrt(rho'), residual scale, alpha/s) of Ceres' corrector; starts (m, 4) int64: the CSC\n"
    "position of entry (0, 0) of the blocks (i, i), (i, j), (j, i), (j, j) or -1; lens (m, 2):\n"
    "the column lengths of the block columns of i and j; goff (m, 2): gradient offsets or -1.";

static PyObject *py_se3_normal(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 12) {
        PyErr_Format(PyExc_TypeError, "se3_between_normal: expected 12 arguments, got %zd",
                     nargs);
        return NULL;
    }
    char *X, *ii, *jj, *Z, *L, *w = NULL, *st, *ln, *go, *s, *data, *grad;
    ix lstep;
    ix m = edge_args(args, &X, &ii, &jj, &Z, &L, &lstep);
    if (m < 0) return NULL;
    if (args[5] != Py_None && !check(args[5], "wts", NPY_DOUBLE, 2, m, 3, 0, &w)) return NULL;
    if (!check(args[6], "starts", NPY_INT64, 2, m, 4, 0, &st) ||
        !check(args[7], "lens", NPY_INT64, 2, m, 2, 0, &ln) ||
        !check(args[8], "goff", NPY_INT64, 2, m, 2, 0, &go) ||
        !check(args[9], "s", NPY_DOUBLE, 1, m, 0, 0, &s) ||
        !check(args[10], "data", NPY_DOUBLE, 1, -1, 0, 0, &data) ||
        !check(args[11], "grad", NPY_DOUBLE, 1, -1, 0, 0, &grad))
        return NULL;
    /* every write must land inside data and grad */
    ix nnz = dim0(args[10]), size = dim0(args[11]);
    const int64_t *S4 = (const int64_t *)st, *L2 = (const int64_t *)ln, *G2 = (const int64_t *)go;
    for (ix k = 0; k < m; k++) {
        for (int u = 0; u < 2; u++) {
            if (G2[2 * k + u] >= 0 && G2[2 * k + u] + D > size) goto bad;
            for (int v = 0; v < 2; v++) {
                int64_t s0 = S4[4 * k + 2 * u + v];
                if (s0 >= 0 && (L2[2 * k + v] < D || s0 + (D - 1) * L2[2 * k + v] + D > nnz))
                    goto bad;
            }
        }
        continue;
    bad:
        PyErr_Format(PyExc_IndexError, "edge %zd: pattern positions outside data or grad", k);
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS
    se3_normal_loop((const double *)X, (const int64_t *)ii, (const int64_t *)jj,
                    (const double *)Z, (const double *)L, lstep, (const double *)w, m, S4, L2,
                    G2, (double *)s, (double *)data, (double *)grad);
    Py_END_ALLOW_THREADS
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"se3_between_cost", (PyCFunction)(void (*)(void))py_se3_cost, METH_FASTCALL, cost_doc},
    {"se3_between_normal", (PyCFunction)(void (*)(void))py_se3_normal, METH_FASTCALL,
     normal_doc},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_graph",
                                    "Compiled pose-graph edge loops for microlie.optim.", -1,
                                    methods};

PyMODINIT_FUNC PyInit__graph(void) {
    import_array();
    return PyModule_Create(&module);
}
