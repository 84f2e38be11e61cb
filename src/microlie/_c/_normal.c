/* microlie._c._normal: two numeric loops of the engine's normal equations, the compiled
 * forms of NumPy loops that stay the reference and the fallback.
 *
 * products(A, dest, y): the assembly of H and g from the factors of the NumPy path
 * (microlie.optim.core.problem.Problem.linearize): A (m, r, c) the whitened [J e] of one factor
 * batch, dest (m c c,) the position in y of each entry of each [J e]^T [J e] (row-major), y
 * (ny,) in and out: y[dest] += the products, in the order of dest (the symmetric pairs are
 * formed twice: writing in the order of H's columns is faster than sharing them).
 *
 * form(...): the Schur complement of linear_solver="schur", formed from the blocks of H (the
 * loop of microlie.optim.linalg.schur_solver.SchurSolver.factorize):
 *
 * form(dz, cidx, bidx, p0, nd, cl, S, Li, V, piv) -> int, one group of m eliminated nodes of
 * d unknowns each, with k neighbouring unknowns in dg neighbouring nodes:
 *   dz (N,): H's data followed by one zero (the entries not stored);
 *   cidx (m, d, d), bidx (m, k, d): positions in dz of C_e and of B_e (row t: neighbouring
 *   unknown t, in the order of the neighbours);
 *   p0 (m, dg, dg): the position in S of entry (0, 0) of block (j1, j2) (rows of neighbour
 *   j1, columns of neighbour j2); nd (m, dg): the unknowns of each neighbour; cl (m, dg): the
 *   length of each neighbour's scalar columns in S (entry (a, b) of block (j1, j2) is at
 *   p0 + b cl[j2] + a);
 *   S (nS,), in and out: S -= V_e V_e^T for every node e, in the blocks (j1, j2) with
 *   j1 <= j2 only (the neighbours come in increasing order: S's upper block triangle; the
 *   caller mirrors it);
 *   Li (m, d, d) out: L_e^-1 (lower triangular, C_e = L_e L_e^T); V (m, k, d) out:
 *   B_e L_e^-T; piv (m, d) out: the squared pivots of the Cholesky factorisations.
 *   Points (d = 3) whose neighbours all have 9 unknowns (camera supernodes) take a path with
 *   fixed 9 x 9 blocks formed straight into S.
 * Returns -1, or the first node whose block C_e is not positive definite (S is then partly
 * updated). All float64. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <math.h>
#include <numpy/arrayobject.h>
#include <stdlib.h>

#include "array_args.h"
#include "dispatch.h"

/* the products of one neighbour unknown t2 (V row vb) with the unknowns 0..lim-1:
 * tmp[t] = W[:, t] . vb (W = V^T, d x k): contiguous in t, vectorised */
static inline __attribute__((always_inline)) void column(
    const double *W, const double *vb, double *tmp, ix lim, ix k, ix d) {
    for (ix t = 0; t < lim; t++) tmp[t] = W[t] * vb[0];
    for (ix c = 1; c < d; c++) {
        const double *w = W + c * k;
        double x = vb[c];
        for (ix t = 0; t < lim; t++) tmp[t] += w[t] * x;
    }
}

/* S's 9 x 9 block at B (column stride c2) -= W[:, f1:f1+9]^T V2^T, W = V^T (3 x k), V2 the 9
 * rows (3 each) of V of the block's column neighbour */
static inline __attribute__((always_inline)) void block9(
    const double *W, const double *V2, double *B, ix f1, ix k, ix c2) {
    const double *w0 = W + f1, *w1 = W + k + f1, *w2 = W + 2 * k + f1;
    for (int b = 0; b < 9; b++) {
        double x0 = V2[3 * b], x1 = V2[3 * b + 1], x2 = V2[3 * b + 2];
        double *col = B + b * c2;
        for (int a = 0; a < 9; a++) col[a] -= w0[a] * x0 + w1[a] * x1 + w2[a] * x2;
    }
}

/* one node: Cholesky of C (d x d, from dz[cidx]), its inverse, V = B L^-T, S -= V V^T;
 * 0 on success, -1 when C is not positive definite */
static inline __attribute__((always_inline)) int node(
    const double *dz, const ix *ci, const ix *bi, const ix *p0, const ix *nd, const ix *cl,
    double *S, double *Li, double *V, double *piv, ix d, ix k, ix dg, double *L,
    double *W, double *tmp) {
    for (ix j = 0; j < d; j++) {
        double s = dz[ci[j * d + j]];
        for (ix c = 0; c < j; c++) s -= L[j * d + c] * L[j * d + c];
        piv[j] = s;
        if (!(s > 0.0) || !isfinite(s)) {
            for (ix q = j; q < d; q++) piv[q] = NAN;
            return -1;
        }
        double ljj = sqrt(s);
        L[j * d + j] = ljj;
        for (ix i = j + 1; i < d; i++) {
            double t = dz[ci[i * d + j]];
            for (ix c = 0; c < j; c++) t -= L[i * d + c] * L[j * d + c];
            L[i * d + j] = t / ljj;
        }
    }
    for (ix j = 0; j < d; j++) {
        for (ix i = 0; i < j; i++) Li[i * d + j] = 0.0;
        Li[j * d + j] = 1.0 / L[j * d + j];
        for (ix i = j + 1; i < d; i++) {
            double t = 0.0;
            for (ix c = j; c < i; c++) t += L[i * d + c] * Li[c * d + j];
            Li[i * d + j] = -t / L[i * d + i];
        }
    }
    for (ix t = 0; t < k; t++)
        for (ix a = 0; a < d; a++) {
            double s = 0.0;
            for (ix c = 0; c <= a; c++) s += dz[bi[t * d + c]] * Li[a * d + c];
            V[t * d + a] = s;
        }
    /* W = V^T; S's block column j2 gets, for each of its unknowns b, the products with the
     * unknowns of the neighbours j1 <= j2, written as runs of n1 rows */
    for (ix t = 0; t < k; t++)
        for (ix a = 0; a < d; a++) W[a * k + t] = V[t * d + a];
    if (d == 3 && k == 9 * dg) {
        int all9 = 1;
        for (ix j = 0; j < dg; j++) all9 &= nd[j] == 9;
        if (all9) {  /* 9 x 9 blocks (BA cameras), each formed straight into S */
            for (ix j2 = 0; j2 < dg; j2++)
                for (ix j1 = 0; j1 <= j2; j1++)
                    block9(W, V + 27 * j2, S + p0[j1 * dg + j2], 9 * j1, k, cl[j2]);
            return 0;
        }
    }
    ix f2 = 0;
    for (ix j2 = 0; j2 < dg; j2++) {
        ix n2 = nd[j2], c2 = cl[j2];
        for (ix b = 0; b < n2; b++) {
            column(W, V + (f2 + b) * d, tmp, f2 + n2, k, d);
            ix f1 = 0;
            for (ix j1 = 0; j1 <= j2; j1++) {
                ix n1 = nd[j1];
                double *col = S + p0[j1 * dg + j2] + b * c2;
                for (ix a = 0; a < n1; a++) col[a] -= tmp[f1 + a];
                f1 += n1;
            }
        }
        f2 += n2;
    }
    return 0;
}

/* the nodes of form(), one function per dispatched ISA (LM_HOT: dispatch.h); returns -1, or
 * the first node whose block is not positive definite */
LM_HOT static ix form_loop(ix m, const double *z, const ix *cip, const ix *bip, const ix *pp,
                           const ix *ndp, const ix *clp, double *Sp, double *Lip, double *Vp,
                           double *pv, ix d, ix k, ix dg, double *L, double *W, double *tmp) {
    for (ix e = 0; e < m; e++) {
        int r;
        if (d == 3)  /* points: the constant size lets the compiler unroll */
            r = node(z, cip + e * 9, bip + e * k * 3, pp + e * dg * dg, ndp + e * dg,
                     clp + e * dg, Sp, Lip + e * 9, Vp + e * k * 3, pv + e * 3, 3, k, dg, L, W, tmp);
        else
            r = node(z, cip + e * d * d, bip + e * k * d, pp + e * dg * dg, ndp + e * dg,
                     clp + e * dg, Sp, Lip + e * d * d, Vp + e * k * d, pv + e * d, d, k, dg,
                     L, W, tmp);
        if (r) return e;
    }
    return -1;
}

/* y[dest] += the products of products(), one function per dispatched ISA; 1 when a position
 * lies outside y */
LM_HOT static int products_loop(const double *a, const ix *de, double *yp, ix ny, ix m, ix r,
                                ix c) {
    for (ix i = 0; i < m; i++) {
        const double *ai = a + i * r * c;
        const ix *di = de + i * c * c;
        for (ix q = 0; q < c; q++)
            for (ix p = 0; p < c; p++) {
                double s = 0.0;
                for (ix t = 0; t < r; t++) s = fma(ai[t * c + p], ai[t * c + q], s);
                ix u = di[p * c + q];
                if (u < 0 || u >= ny) return 1;
                yp[u] += s;
            }
    }
    return 0;
}

static PyObject *form_(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 10) {
        PyErr_SetString(PyExc_TypeError,
                        "form(dz, cidx, bidx, p0, nd, cl, S, Li, V, piv) takes 10 arguments");
        return NULL;
    }
    ix any1[1] = {-1}, any3[3] = {-1, -1, -1};
    PyArrayObject *dz = arg(args[0], "dz", NPY_DOUBLE, 1, any1);
    PyArrayObject *ci = dz ? arg(args[1], "cidx", NPY_INTP, 3, any3) : NULL;
    if (!ci) return NULL;
    ix m = PyArray_DIM(ci, 0), d = PyArray_DIM(ci, 1);
    ix dc[3] = {m, d, d};
    if (!arg(args[1], "cidx", NPY_INTP, 3, dc)) return NULL;
    ix db[3] = {m, -1, d};
    PyArrayObject *bi = arg(args[2], "bidx", NPY_INTP, 3, db);
    if (!bi) return NULL;
    ix k = PyArray_DIM(bi, 1);
    ix dp[3] = {m, -1, -1};
    PyArrayObject *p0 = arg(args[3], "p0", NPY_INTP, 3, dp);
    if (!p0) return NULL;
    ix dg = PyArray_DIM(p0, 1);
    ix dpp[3] = {m, dg, dg}, dn[2] = {m, dg}, dv[3] = {m, k, d}, dpv[2] = {m, d};
    PyArrayObject *nd = NULL, *cl = NULL, *S = NULL, *Li = NULL, *V = NULL, *piv = NULL;
    if (!arg(args[3], "p0", NPY_INTP, 3, dpp) ||
        !(nd = arg(args[4], "nd", NPY_INTP, 2, dn)) ||
        !(cl = arg(args[5], "cl", NPY_INTP, 2, dn)) ||
        !(S = arg(args[6], "S", NPY_DOUBLE, 1, any1)) ||
        !(Li = arg(args[7], "Li", NPY_DOUBLE, 3, dc)) ||
        !(V = arg(args[8], "V", NPY_DOUBLE, 3, dv)) ||
        !(piv = arg(args[9], "piv", NPY_DOUBLE, 2, dpv)))
        return NULL;
    if (d < 1 || d > 64) {
        PyErr_SetString(PyExc_ValueError, "cidx: the eliminated nodes must have 1 to 64 unknowns");
        return NULL;
    }
    const ix *ndp = (const ix *)PyArray_DATA(nd);
    for (ix e = 0; e < m; e++) {
        ix sum = 0;
        for (ix j = 0; j < dg; j++) sum += ndp[e * dg + j];
        if (sum != k) {
            PyErr_SetString(PyExc_ValueError, "nd: the neighbours' unknowns must add up to k");
            return NULL;
        }
    }
    /* the positions are not checked here: SchurSolver.analyse computes them in range */
    const double *z = (const double *)PyArray_DATA(dz);
    const ix *cip = (const ix *)PyArray_DATA(ci), *bip = (const ix *)PyArray_DATA(bi);
    const ix *pp = (const ix *)PyArray_DATA(p0), *clp = (const ix *)PyArray_DATA(cl);
    double *Sp = (double *)PyArray_DATA(S), *Lip = (double *)PyArray_DATA(Li);
    double *Vp = (double *)PyArray_DATA(V), *pv = (double *)PyArray_DATA(piv);
    double L[64 * 64];
    double *W = (double *)malloc(sizeof(double) * (size_t)((d + 1) * k + 1)), *tmp = W + d * k;
    if (!W) return PyErr_NoMemory();
    ix bad;
    Py_BEGIN_ALLOW_THREADS
    bad = form_loop(m, z, cip, bip, pp, ndp, clp, Sp, Lip, Vp, pv, d, k, dg, L, W, tmp);
    Py_END_ALLOW_THREADS
    free(W);
    return PyLong_FromSsize_t((Py_ssize_t)bad);
}

/* each product accumulates by fused multiply-adds from zero, as the BLAS kernels behind
 * NumPy's matmul do on x86-64 (measured: bit for bit with the NumPy path) */
static PyObject *products_(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 3) {
        PyErr_SetString(PyExc_TypeError, "products(A, dest, y) takes 3 arguments");
        return NULL;
    }
    ix any1[1] = {-1}, any3[3] = {-1, -1, -1};
    PyArrayObject *A = arg(args[0], "A", NPY_DOUBLE, 3, any3);
    if (!A) return NULL;
    ix m = PyArray_DIM(A, 0), r = PyArray_DIM(A, 1), c = PyArray_DIM(A, 2);
    ix dd[1] = {m * c * c};
    PyArrayObject *dest = arg(args[1], "dest", NPY_INTP, 1, dd);
    PyArrayObject *y = dest ? arg(args[2], "y", NPY_DOUBLE, 1, any1) : NULL;
    if (!y) return NULL;
    const double *a = (const double *)PyArray_DATA(A);
    const ix *de = (const ix *)PyArray_DATA(dest);
    double *yp = (double *)PyArray_DATA(y);
    ix ny = PyArray_DIM(y, 0);
    int bad;
    Py_BEGIN_ALLOW_THREADS
    bad = products_loop(a, de, yp, ny, m, r, c);
    Py_END_ALLOW_THREADS
    if (bad) {
        PyErr_SetString(PyExc_ValueError, "dest holds a position outside y");
        return NULL;
    }
    Py_RETURN_NONE;
}

/* rhs(Li, V, rows, be, y, r): the eliminated nodes' part of the reduced right-hand side, one
 * group: y_e = L_e^-1 b_e (y (m, d) out), r[rows[e, t]] -= V_e[t] . y_e (r in and out).
 * back(Li, V, rows, y, xr, xe): x_e = L_e^-T (y_e - V_e^T xr[rows_e]) (xe (m, d) out). */
static int solve_args(PyObject *const *args, PyArrayObject **Li, PyArrayObject **V,
                      PyArrayObject **rows, PyArrayObject **a, PyArrayObject **b,
                      PyArrayObject **c, ix *m, ix *d, ix *k, int back) {
    ix any1[1] = {-1}, any3[3] = {-1, -1, -1};
    if (!(*Li = arg(args[0], "Li", NPY_DOUBLE, 3, any3))) return -1;
    *m = PyArray_DIM(*Li, 0), *d = PyArray_DIM(*Li, 1);
    ix dv[3] = {*m, -1, *d};
    if (!(*V = arg(args[1], "V", NPY_DOUBLE, 3, dv))) return -1;
    *k = PyArray_DIM(*V, 1);
    ix dr[2] = {*m, *k}, de[2] = {*m, *d};
    if (!(*rows = arg(args[2], "rows", NPY_INTP, 2, dr)) ||
        !(*a = arg(args[3], back ? "y" : "be", NPY_DOUBLE, 2, de)) ||
        !(*b = arg(args[4], back ? "xr" : "y", NPY_DOUBLE, back ? 1 : 2, back ? any1 : de)) ||
        !(*c = arg(args[5], back ? "xe" : "r", NPY_DOUBLE, back ? 2 : 1, back ? de : any1)))
        return -1;
    ix nr = PyArray_DIM(back ? *b : *c, 0);
    const ix *rp = (const ix *)PyArray_DATA(*rows);
    for (ix q = 0; q < *m * *k; q++)
        if (rp[q] < 0 || rp[q] >= nr) {
            PyErr_SetString(PyExc_ValueError, "rows holds an unknown outside the reduced system");
            return -1;
        }
    return 0;
}

static PyObject *rhs_(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 6) {
        PyErr_SetString(PyExc_TypeError, "rhs(Li, V, rows, be, y, r) takes 6 arguments");
        return NULL;
    }
    PyArrayObject *Li, *V, *rows, *be, *y, *r;
    ix m, d, k;
    if (solve_args(args, &Li, &V, &rows, &be, &y, &r, &m, &d, &k, 0)) return NULL;
    const double *L = PyArray_DATA(Li), *Vp = PyArray_DATA(V), *b = PyArray_DATA(be);
    const ix *rp = PyArray_DATA(rows);
    double *yp = PyArray_DATA(y), *rr = PyArray_DATA(r);
    for (ix e = 0; e < m; e++) {
        const double *Le = L + e * d * d, *bb = b + e * d, *Ve = Vp + e * k * d;
        double *ye = yp + e * d;
        for (ix a = 0; a < d; a++) {
            double s = 0.0;
            for (ix c = 0; c <= a; c++) s += Le[a * d + c] * bb[c];
            ye[a] = s;
        }
        for (ix t = 0; t < k; t++) {
            double s = 0.0;
            for (ix a = 0; a < d; a++) s += Ve[t * d + a] * ye[a];
            rr[rp[e * k + t]] -= s;
        }
    }
    Py_RETURN_NONE;
}

static PyObject *back_(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 6) {
        PyErr_SetString(PyExc_TypeError, "back(Li, V, rows, y, xr, xe) takes 6 arguments");
        return NULL;
    }
    PyArrayObject *Li, *V, *rows, *y, *xr, *xe;
    ix m, d, k;
    if (solve_args(args, &Li, &V, &rows, &y, &xr, &xe, &m, &d, &k, 1)) return NULL;
    if (d > 64) {
        PyErr_SetString(PyExc_ValueError, "Li: at most 64 unknowns per node");
        return NULL;
    }
    const double *L = PyArray_DATA(Li), *Vp = PyArray_DATA(V), *yp = PyArray_DATA(y);
    const double *x = PyArray_DATA(xr);
    const ix *rp = PyArray_DATA(rows);
    double *out = PyArray_DATA(xe);
    double z[64];
    for (ix e = 0; e < m; e++) {
        const double *Le = L + e * d * d, *Ve = Vp + e * k * d;
        for (ix a = 0; a < d; a++) z[a] = yp[e * d + a];
        for (ix t = 0; t < k; t++) {
            double xt = x[rp[e * k + t]];
            for (ix a = 0; a < d; a++) z[a] -= Ve[t * d + a] * xt;
        }
        for (ix c = 0; c < d; c++) {
            double s = 0.0;
            for (ix a = c; a < d; a++) s += Le[a * d + c] * z[a];
            out[e * d + c] = s;
        }
    }
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"rhs", (PyCFunction)(void (*)(void))rhs_, METH_FASTCALL,
     "rhs(Li, V, rows, be, y, r) -> None: y = L^-1 b_e and r[rows] -= V y for one group of "
     "eliminated nodes"},
    {"back", (PyCFunction)(void (*)(void))back_, METH_FASTCALL,
     "back(Li, V, rows, y, xr, xe) -> None: xe = L^-T (y - V^T xr[rows]) for one group of "
     "eliminated nodes"},
    {"products", (PyCFunction)(void (*)(void))products_, METH_FASTCALL,
     "products(A, dest, y) -> None: y[dest] += the products [J e]^T [J e] of one factor batch "
     "(see the module source)"},
    {"form", (PyCFunction)(void (*)(void))form_, METH_FASTCALL,
     "form(dz, cidx, bidx, p0, nd, cl, S, Li, V, piv) -> int: one group's part of the Schur "
     "complement S -= B C^-1 B^T (see the module source); -1, or the first node whose block "
     "is not positive definite"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_normal",
                                    "The engine's normal equations: assembly and Schur complement, compiled.",
                                    -1, methods};

PyMODINIT_FUNC PyInit__normal(void) {
    import_array();
    return PyModule_Create(&module);
}
