/* microlie._c._graph: the pose-graph edge loop of microlie.optim in one compiled pass.
 *
 * For a batch of SE(3) or SE(2) BetweenFactors r = Log((X_i Z)^-1 X_j) with square-root
 * information L
 * (one per edge or one shared) it computes, per edge, the residual and its right Jacobians
 * (d r/d X_j = Jr^-1(r), d r/d X_i = -Jl^-1(r) Ad(Z^-1)), the whitened e = L r and A = L [J_i J_j],
 * optionally Ceres' robust correction (A <- sq (A - aos e (e^T A)), e <- scale e), the block
 * products A^T A and A^T e, and adds them straight into the CSC values of the problem's fixed
 * pattern and into the gradient. The group formulas are those of lie_math.h (the same as the
 * generic NumPy kernels; SE(2)'s, which lie_math.h does not have, are written below in the same
 * form from microlie/groups/se2.py); the Lie part and the products run on structure-of-arrays
 * blocks of S edges (vectorised like _lie.c), the scatter per edge.
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

/* ------------------------------------------------------------------ SE(2) on SoA blocks */

/* h cot h, |h| <= pi/2 (se2.half_cot); X_COT = microlie.groups._math.X_COT */
static const double X_COT[3] = {1.0, -1.0 / 3.0, -1.0 / 45.0};
LM_INLINE double half_cot(double h) {
    double h2 = h * h, small = h2 < TINY2 ? 1.0 : 0.0, hs = h + small;
    double closed = hs * cos(hs) / sin(hs);
    return small != 0.0 ? horner(h2, X_COT, 3) : closed;
}

/* Jr^-1(tau) of SE(2), row-major 3x3 (se2._jr_inv) */
LM_INLINE void se2_jr_inv_l(double r1, double r2, double th, double *J) {
    double t2 = th * th, h = 0.5 * th, k = half_cot(h), hs, hc;
    half_angle(t2, &hs, &hc);
    double d1 = th * coef_b(t2, hs, hc), d2 = 2.0 * hs * hs;
    double v1 = r1 * d1 - r2 * d2, v2 = r1 * d2 + r2 * d1;
    J[0] = k; J[1] = -h; J[2] = -(k * v1 - h * v2);
    J[3] = h; J[4] = k; J[5] = -(h * v1 + k * v2);
    J[6] = 0.0; J[7] = 0.0; J[8] = 1.0;
}

/* element operations with the block stride S: (x, y, cos, sin) parameters */
EL(se2_compose_s) {
    double c = a[2 * S], s = a[3 * S];
    o[0] = a[0] + c * b[0] - s * b[S];
    o[S] = a[S] + s * b[0] + c * b[S];
    o[2 * S] = c * b[2 * S] - s * b[3 * S];
    o[3 * S] = s * b[2 * S] + c * b[3 * S];
}

/* Log(X^-1 Y) of inputs (Y, X): (rho_x, rho_y, theta) (se2._log of se2._compose(inverse)) */
LM_INLINE void se2_minus_l(const double *a, const double *b, double *t) {
    double x = b[0], y = b[S], c = b[2 * S], s = b[3 * S];
    double ix = -(c * x + s * y), iy = s * x - c * y; /* X^-1 = (ix, iy, c, -s) */
    double zx = ix + c * a[0] + s * a[S], zy = iy - s * a[0] + c * a[S];
    double zc = c * a[2 * S] + s * a[3 * S], zs = -s * a[2 * S] + c * a[3 * S];
    double th = atan2(zs, zc), h = 0.5 * th, k = half_cot(h);
    t[0] = k * zx + h * zy;
    t[1] = -h * zx + k * zy;
    t[2] = th;
}

EL(se2_minus) {
    double t[3];
    se2_minus_l(a, b, t);
    ST(o, t, 3);
}

/* (tau, Jr^-1(tau), -Jl^-1(tau)) with Jl^-1(tau) = Jr^-1(-tau) */
EL(se2_minus_jac) {
    double t[3], J[9], L[9];
    se2_minus_l(a, b, t);
    se2_jr_inv_l(t[0], t[1], t[2], J);
    se2_jr_inv_l(-t[0], -t[1], -t[2], L);
    NEG(L, 9);
    ST(o, t, 3); ST(o + 3 * S, J, 9); ST(o + 12 * S, L, 9);
}

/* Ad(Z^-1) = [[c, s, y'], [-s, c, -x'], [0, 0, 1]] with Z^-1 = (x', y', c, -s) */
EL(se2_adjoint_inv) {
    (void)b;
    double x = a[0], y = a[S], c = a[2 * S], s = a[3 * S];
    double ix = -(c * x + s * y), iy = s * x - c * y;
    double J[9] = {c, s, iy, -s, c, -ix, 0.0, 0.0, 1.0};
    ST(o, J, 9);
}

/* ------------------------------------------------------------------ the edge, both groups */

enum { SE2 = 0, SE3 = 1 };
#define PDIM(g) ((g) == SE3 ? 7 : 4)
#define DOF(g) ((g) == SE3 ? 6 : 3)
#define MAXD 6

/* the Lie part of one block of m <= S edges, in SoA layout (component c of edge j at
 * out[c * S + j]): residual (D), Jr^-1 (D^2), -Jl^-1 (D^2), Ad(Z^-1) (D^2), or the residual
 * alone without need_jac */
#define LIE_W (MAXD + 3 * MAXD * MAXD)
LM_INLINE void lie_block(int g, const double *restrict X, const int64_t *restrict ii,
                         const int64_t *restrict jj, const double *restrict Z, ix k0, ix m,
                         int need_jac, double *restrict buf, double *restrict out) {
    const int P = PDIM(g), D = DOF(g);
    double *bi = buf, *bj = buf + 7 * S, *bz = buf + 14 * S, *bc = buf + 21 * S;
    for (ix j = 0; j < m; j++) {
        const double *xi = X + P * ii[k0 + j], *xj = X + P * jj[k0 + j], *z = Z + P * (k0 + j);
        for (int c = 0; c < P; c++) {
            bi[c * S + j] = xi[c];
            bj[c * S + j] = xj[c];
            bz[c * S + j] = z[c];
        }
    }
    double *ad = out + (D + 2 * D * D) * S;
    if (g == SE3) {
        _Pragma("omp simd") for (ix j = 0; j < m; j++) se3_compose(bi + j, bz + j, bc + j);
        if (need_jac) {
            _Pragma("omp simd") for (ix j = 0; j < m; j++) se3_minus_jac(bj + j, bc + j, out + j);
            _Pragma("omp simd") for (ix j = 0; j < m; j++) se3_adjoint_inv(bz + j, bz + j, ad + j);
        } else {
            _Pragma("omp simd") for (ix j = 0; j < m; j++) se3_minus(bj + j, bc + j, out + j);
        }
    } else {
        _Pragma("omp simd") for (ix j = 0; j < m; j++) se2_compose_s(bi + j, bz + j, bc + j);
        if (need_jac) {
            _Pragma("omp simd") for (ix j = 0; j < m; j++) se2_minus_jac(bj + j, bc + j, out + j);
            _Pragma("omp simd") for (ix j = 0; j < m; j++) se2_adjoint_inv(bz + j, bz + j, ad + j);
        } else {
            _Pragma("omp simd") for (ix j = 0; j < m; j++) se2_minus(bj + j, bc + j, out + j);
        }
    }
}

/* the whitened products of one edge (D = 3 or 6, a constant after inlining), on SoA blocks
 * like the element operations of lie_math.h (called in an omp simd loop over the edges of a
 * block): o = lie_block's output, Lb = L (D^2), w = (sqrt(rho'), scale, alpha / s) when robust;
 * h = A^T A row-major ((2D)^2), A^T e (2D), |e|^2 before the correction (1) */
#define HOUT (4 * MAXD * MAXD + 2 * MAXD + 1)
LM_INLINE void edge_normal(const int D, const double *o, const double *Lb, const double *w,
                           double *h, int robust) {
    const int DD = 2 * D, NH = DD * DD;
    double r[MAXD], J[MAXD * 2 * MAXD], L[MAXD * MAXD], e[MAXD], A[MAXD * 2 * MAXD];
#pragma GCC unroll 64
    for (int c = 0; c < D; c++) r[c] = o[c * S];
#pragma GCC unroll 64
    for (int c = 0; c < D * D; c++) L[c] = Lb[c * S];
    /* J = [-Jl^-1 Ad(Z^-1), Jr^-1]: d r / d X_i, d r / d X_j */
    const double *jr = o + D * S, *njl = o + (D + D * D) * S, *ad = o + (D + 2 * D * D) * S;
#pragma GCC unroll 64
    for (int a = 0; a < D; a++)
#pragma GCC unroll 64
        for (int b = 0; b < D; b++) {
            double acc = 0.0;
#pragma GCC unroll 64
            for (int c = 0; c < D; c++) acc += njl[(D * a + c) * S] * ad[(D * c + b) * S];
            J[DD * a + b] = acc;
            J[DD * a + D + b] = jr[(D * a + b) * S];
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

/* rows of m <= S (1 or m, D^2) matrices into a SoA block */
static void load_L(int D2, const double *L, ix lstep, ix k0, ix m, double *Lb) {
    for (ix j = 0; j < m; j++) {
        const double *x = L + lstep * (k0 + j);
        for (int c = 0; c < D2; c++) Lb[c * S + j] = x[c];
    }
}

/* the cost terms s_k = |L_k r_k|^2 of every edge */
LM_INLINE void cost_loop(int g, const double *X, const int64_t *ii, const int64_t *jj,
                         const double *Z, const double *L, ix lstep, ix m, double *s) {
    const int D = DOF(g);
    double buf[28 * S] __attribute__((aligned(64)));
    double out[LIE_W * S] __attribute__((aligned(64)));
    double Lb[MAXD * MAXD * S] __attribute__((aligned(64)));
    if (!lstep) load_L(D * D, L, 0, 0, S, Lb);
    for (ix k0 = 0; k0 < m; k0 += S) {
        ix n = m - k0 < S ? m - k0 : S;
        lie_block(g, X, ii, jj, Z, k0, n, 0, buf, out);
        if (lstep) load_L(D * D, L, lstep, k0, n, Lb);
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

LM_INLINE void normal_loop(int g, const double *X, const int64_t *ii, const int64_t *jj,
                           const double *Z, const double *L, ix lstep, const double *wts, ix m,
                           const int64_t *starts, const int64_t *lens, const int64_t *goff,
                           double *s, double *data, double *grad) {
    const int D = DOF(g), DD = 2 * D, NH = DD * DD;
    double buf[28 * S] __attribute__((aligned(64)));
    double out[LIE_W * S] __attribute__((aligned(64)));
    double Lb[MAXD * MAXD * S] __attribute__((aligned(64)));
    double wb[3 * S] __attribute__((aligned(64)));
    double h[HOUT * S] __attribute__((aligned(64)));
    if (!lstep) load_L(D * D, L, 0, 0, S, Lb);
    for (ix k0 = 0; k0 < m; k0 += S) {
        ix n = m - k0 < S ? m - k0 : S;
        lie_block(g, X, ii, jj, Z, k0, n, 1, buf, out);
        if (lstep) load_L(D * D, L, lstep, k0, n, Lb);
        if (wts) {
            for (ix j = 0; j < n; j++)
                for (int c = 0; c < 3; c++) wb[c * S + j] = wts[3 * (k0 + j) + c];
            _Pragma("omp simd") for (ix j = 0; j < n; j++)
                edge_normal(D, out + j, Lb + j, wb + j, h + j, 1);
        } else {
            _Pragma("omp simd") for (ix j = 0; j < n; j++)
                edge_normal(D, out + j, Lb + j, wb + j, h + j, 0);
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

/* the loops of both groups, one function per dispatched ISA (LM_HOT: dispatch.h) */
LM_HOT static void cost_any(int g, const double *X, const int64_t *ii, const int64_t *jj,
                            const double *Z, const double *L, ix lstep, ix m, double *s) {
    if (g == SE3) cost_loop(SE3, X, ii, jj, Z, L, lstep, m, s);
    else cost_loop(SE2, X, ii, jj, Z, L, lstep, m, s);
}

LM_HOT static void normal_any(int g, const double *X, const int64_t *ii, const int64_t *jj,
                              const double *Z, const double *L, ix lstep, const double *wts,
                              ix m, const int64_t *starts, const int64_t *lens,
                              const int64_t *goff, double *s, double *data, double *grad) {
    if (g == SE3)
        normal_loop(SE3, X, ii, jj, Z, L, lstep, wts, m, starts, lens, goff, s, data, grad);
    else
        normal_loop(SE2, X, ii, jj, Z, L, lstep, wts, m, starts, lens, goff, s, data, grad);
}

/* ------------------------------------------------------------------ Python entry points */

static const char *const GNAME[2] = {"se2", "se3"};

/* common checks of (X, ii, jj, Z, L); returns m, or -1 with an exception set */
static ix edge_args(int g, PyObject *const *args, char **X, char **ii, char **jj, char **Z,
                    char **L, ix *lstep) {
    const int P = PDIM(g), D = DOF(g);
    if (!check(args[0], "X", NPY_DOUBLE, 2, -1, P, 0, X)) return -1;
    ix m = PyArray_Check(args[1]) ? dim0(args[1]) : 0;
    if (!check(args[1], "ii", NPY_INT64, 1, m, 0, 0, ii)) return -1;
    if (!check(args[2], "jj", NPY_INT64, 1, m, 0, 0, jj)) return -1;
    if (!check(args[3], "Z", NPY_DOUBLE, 2, m, P, 0, Z)) return -1;
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

static PyObject *between_cost(int g, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 6) {
        PyErr_Format(PyExc_TypeError, "%s_between_cost: expected 6 arguments, got %zd",
                     GNAME[g], nargs);
        return NULL;
    }
    char *X, *ii, *jj, *Z, *L, *s;
    ix lstep;
    ix m = edge_args(g, args, &X, &ii, &jj, &Z, &L, &lstep);
    if (m < 0) return NULL;
    if (!check(args[5], "s", NPY_DOUBLE, 1, m, 0, 0, &s)) return NULL;
    const double *x = (const double *)X, *z = (const double *)Z, *l = (const double *)L;
    const int64_t *a = (const int64_t *)ii, *b = (const int64_t *)jj;
    Py_BEGIN_ALLOW_THREADS
    cost_any(g, x, a, b, z, l, lstep, m, (double *)s);
    Py_END_ALLOW_THREADS
    Py_RETURN_NONE;
}

static PyObject *between_normal(int g, PyObject *const *args, Py_ssize_t nargs) {
    const int D = DOF(g);
    if (nargs != 12) {
        PyErr_Format(PyExc_TypeError, "%s_between_normal: expected 12 arguments, got %zd",
                     GNAME[g], nargs);
        return NULL;
    }
    char *X, *ii, *jj, *Z, *L, *w = NULL, *st, *ln, *go, *s, *data, *grad;
    ix lstep;
    ix m = edge_args(g, args, &X, &ii, &jj, &Z, &L, &lstep);
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
        int ok = 1;
        for (int u = 0; u < 2; u++) {
            if (G2[2 * k + u] >= 0 && G2[2 * k + u] + D > size) ok = 0;
            for (int v = 0; v < 2; v++) {
                int64_t s0 = S4[4 * k + 2 * u + v];
                if (s0 >= 0 && (L2[2 * k + v] < D || s0 + (D - 1) * L2[2 * k + v] + D > nnz))
                    ok = 0;
            }
        }
        if (!ok) {
            PyErr_Format(PyExc_IndexError, "edge %zd: pattern positions outside data or grad",
                         k);
            return NULL;
        }
    }
    const double *x = (const double *)X, *z = (const double *)Z, *l = (const double *)L;
    const double *wt = (const double *)w;
    const int64_t *a = (const int64_t *)ii, *b = (const int64_t *)jj;
    Py_BEGIN_ALLOW_THREADS
    normal_any(g, x, a, b, z, l, lstep, wt, m, S4, L2, G2, (double *)s, (double *)data,
               (double *)grad);
    Py_END_ALLOW_THREADS
    Py_RETURN_NONE;
}

#define ENTRY(G, g)                                                                            \
    static PyObject *py_##G##_cost(PyObject *self, PyObject *const *args, Py_ssize_t n) {      \
        (void)self;                                                                            \
        return between_cost(g, args, n);                                                       \
    }                                                                                          \
    static PyObject *py_##G##_normal(PyObject *self, PyObject *const *args, Py_ssize_t n) {    \
        (void)self;                                                                            \
        return between_normal(g, args, n);                                                     \
    }
ENTRY(se2, SE2)
ENTRY(se3, SE3)

static const char cost_doc[] =
    "{se3,se2}_between_cost(X, ii, jj, Z, L, s)\n\n"
    "s[k] = |L_k Log((X[ii[k]] Z[k])^-1 X[jj[k]])|^2 for every edge k (X (n, P), ii and jj\n"
    "(m,) int64, Z (m, P), L (1 or m, D, D), s (m,) written; P, D = 7, 6 or 4, 3).";

static const char normal_doc[] =
    "{se3,se2}_between_normal(X, ii, jj, Z, L, wts, starts, lens, goff, s, data, grad)\n\n"
    "Adds every edge's whitened A^T A into data (CSC values, nnz) and A^T e into grad (size,)\n"
    "and writes s[k] = |e_k|^2 (before the robust correction). wts: None or (m, 3) rows\n"
    "(sqrt(rho'), residual scale, alpha/s) of Ceres' corrector; starts (m, 4) int64: the CSC\n"
    "position of entry (0, 0) of the blocks (i, i), (i, j), (j, i), (j, j) or -1; lens (m, 2):\n"
    "the column lengths of the block columns of i and j; goff (m, 2): gradient offsets or -1.";

#define FN(f) (PyCFunction)(void (*)(void))(f)
static PyMethodDef methods[] = {
    {"se3_between_cost", FN(py_se3_cost), METH_FASTCALL, cost_doc},
    {"se3_between_normal", FN(py_se3_normal), METH_FASTCALL, normal_doc},
    {"se2_between_cost", FN(py_se2_cost), METH_FASTCALL, cost_doc},
    {"se2_between_normal", FN(py_se2_normal), METH_FASTCALL, normal_doc},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_graph",
                                    "Compiled pose-graph edge loops for microlie.optim.", -1,
                                    methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__graph(void) {
    import_array();
    PyObject *m = PyModule_Create(&module);
    if (!m) return NULL;
    /* the series of h cot h used below TINY2 (checked against microlie.groups._math) */
    PyObject *t = Py_BuildValue("(ddd)", X_COT[0], X_COT[1], X_COT[2]);
    if (!t || PyModule_AddObject(m, "X_COT", t) < 0) {
        Py_XDECREF(t);
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
