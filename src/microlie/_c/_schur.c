/* microlie._c._schur: the dense reduced camera system of bundle adjustment (the Schur
 * complement of the points), the compiled form of the dense path of
 * microlie.optim.schur.NormalEquations.reduced_system, which stays the reference and the fallback.
 *
 * reduce(Jc, Jp, V, gp, U, gc, cam, point_ptr, point_obs) -> (S, rhs, Ci), or None when a point
 * block is not positive definite:
 *   Jc (n, 2, d), Jp (n, 2, 3): the observations' camera and point Jacobians (weighted);
 *   V (np, 6): the damped point blocks (v00, v01, v02, v11, v12, v22); gp (np, 3);
 *   U (nc, d, d), gc (nc, d): the camera blocks and gradients;
 *   cam (n,): the camera of each observation; point_ptr (np + 1,), point_obs (n,): the
 *   observations of each point (CSR);
 *   S (nc d, nc d) = blockdiag(U) - sum_j W_j V_j^-1 W_j^T (no camera damping, no held rows:
 *   the caller adds those), rhs (nc d) = -gc + sum_j W_j V_j^-1 gp_j, Ci (6, np) the inverse
 *   Cholesky factors (i00, i10, i11, i20, i21, i22) of the V_j.
 * Per point j with inverse Cholesky factor C_j^-1: Z_a = C_j^-1 Jp_a^T Jc_a (3 x d) for each of
 * its observations a, then S[c_a, c_b] -= Z_a^T Z_b for every pair (a, b) of them (the upper
 * triangle, mirrored at the end) and rhs[c_a] += Z_a^T C_j^-1 gp_j. All float64. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <math.h>
#include <numpy/arrayobject.h>
#include <string.h>

#include "array_args.h"
#include "dispatch.h"

/* the d x d block of S at (r0, c0) -= A^T B (A, B: 3 x d, row-major), or -= (A^T B)^T when tr */
static inline __attribute__((always_inline)) void sub_block(double *S, ix N, ix r0, ix c0,
                                                            const double *A, const double *B,
                                                            int d, int tr) {
    for (int i = 0; i < d; i++) {
        double a0 = A[i], a1 = A[d + i], a2 = A[2 * d + i];
        if (!tr) {
            double *row = S + (r0 + i) * N + c0;
            for (int j = 0; j < d; j++) row[j] -= a0 * B[j] + a1 * B[d + j] + a2 * B[2 * d + j];
        } else {
            for (int j = 0; j < d; j++)
                S[(r0 + j) * N + c0 + i] -= a0 * B[j] + a1 * B[d + j] + a2 * B[2 * d + j];
        }
    }
}

/* the formation; always inlined into calls with a constant camera dimension, so that the
 * block products unroll and vectorise for the common sizes */
static inline __attribute__((always_inline)) int form(
    const double *Jc, const double *Jp, const double *V, const double *Gp, const double *U,
    const double *Gc, const ix *C, const ix *P, const ix *O, ix nc, ix np_, double *S,
    double *rhs, double *Ci, double *Z, const int d) {
    ix N = nc * d;
    int ok = 1;
    for (ix c = 0; c < nc; c++)
        for (int i = 0; i < d; i++) {
            memcpy(S + (c * d + i) * N + c * d, U + (c * d + i) * d, sizeof(double) * d);
            rhs[c * d + i] = -Gc[c * d + i];
        }
    for (ix j = 0; j < np_ && ok; j++) {
        const double *vj = V + 6 * j;
        /* the inverse of the lower Cholesky factor, as schur._chol3_inv */
        double c00 = sqrt(vj[0]), c10 = vj[1] / c00, c20 = vj[2] / c00;
        double c11 = sqrt(vj[3] - c10 * c10), c21 = (vj[4] - c20 * c10) / c11;
        double c22 = sqrt(vj[5] - c20 * c20 - c21 * c21);
        double i00 = 1.0 / c00, i11 = 1.0 / c11, i22 = 1.0 / c22;
        double i10 = -c10 * i00 * i11, i21 = -c21 * i11 * i22;
        double i20 = -(c20 * i00 + c21 * i10) * i22;
        if (!(isfinite(i00) && isfinite(i10) && isfinite(i11) && isfinite(i20) &&
              isfinite(i21) && isfinite(i22))) {
            ok = 0;
            break;
        }
        Ci[j] = i00; Ci[np_ + j] = i10; Ci[2 * np_ + j] = i11;
        Ci[3 * np_ + j] = i20; Ci[4 * np_ + j] = i21; Ci[5 * np_ + j] = i22;
        const double *g = Gp + 3 * j;
        double h[3] = {i00 * g[0], i10 * g[0] + i11 * g[1], i20 * g[0] + i21 * g[1] + i22 * g[2]};
        ix m = P[j + 1] - P[j];
        const ix *oj = O + P[j];
        for (ix k = 0; k < m; k++) {
            ix a = oj[k];
            const double *jp_ = Jp + 6 * a, *jc_ = Jc + 2 * (size_t)d * a;
            /* G = Jp_a Ci^T (2 x 3); Z_a = G^T Jc_a (3 x d) */
            double G[2][3];
            for (int r = 0; r < 2; r++) {
                const double *x = jp_ + 3 * r;
                G[r][0] = x[0] * i00;
                G[r][1] = x[0] * i10 + x[1] * i11;
                G[r][2] = x[0] * i20 + x[1] * i21 + x[2] * i22;
            }
            double *z = Z + 3 * (size_t)d * k;
            for (int q = 0; q < 3; q++)
                for (int col = 0; col < d; col++)
                    z[q * d + col] = G[0][q] * jc_[col] + G[1][q] * jc_[d + col];
            double *rc = rhs + C[a] * d;
            for (int col = 0; col < d; col++)
                rc[col] += z[col] * h[0] + z[d + col] * h[1] + z[2 * d + col] * h[2];
        }
        for (ix k1 = 0; k1 < m; k1++) {
            ix ca = C[oj[k1]];
            const double *za = Z + 3 * (size_t)d * k1;
            for (ix k2 = k1; k2 < m; k2++) {
                ix cb = C[oj[k2]];
                const double *zb = Z + 3 * (size_t)d * k2;
                if (ca <= cb) sub_block(S, N, ca * d, cb * d, za, zb, d, 0);
                else sub_block(S, N, cb * d, ca * d, za, zb, d, 1);  /* (Za^T Zb)^T */
                if (k2 != k1 && ca == cb) sub_block(S, N, ca * d, ca * d, za, zb, d, 1);
            }
        }
    }
    if (ok) /* the lower triangle from the upper one */
        for (ix r = 0; r < N; r++)
            for (ix c = r + 1; c < N; c++) S[c * N + r] = S[r * N + c];
    return ok;
}

LM_HOT static int form_any(const double *Jc, const double *Jp, const double *V, const double *Gp,
                    const double *U, const double *Gc, const ix *C, const ix *P, const ix *O,
                    ix nc, ix np_, double *S, double *rhs, double *Ci, double *Z, int d) {
    switch (d) { /* BAL cameras (9), poses (6), pinhole with 4 or 8 intrinsics (10, 14) */
    case 9: return form(Jc, Jp, V, Gp, U, Gc, C, P, O, nc, np_, S, rhs, Ci, Z, 9);
    case 6: return form(Jc, Jp, V, Gp, U, Gc, C, P, O, nc, np_, S, rhs, Ci, Z, 6);
    case 10: return form(Jc, Jp, V, Gp, U, Gc, C, P, O, nc, np_, S, rhs, Ci, Z, 10);
    default: return form(Jc, Jp, V, Gp, U, Gc, C, P, O, nc, np_, S, rhs, Ci, Z, d);
    }
}

static PyObject *reduce_(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 9) {
        PyErr_Format(PyExc_TypeError, "reduce: expected 9 arguments, got %zd", nargs);
        return NULL;
    }
    ix any3[3] = {-1, 2, -1};
    PyArrayObject *jc = arg(args[0], "Jc", NPY_DOUBLE, 3, any3);
    if (!jc) return NULL;
    ix n = PyArray_DIM(jc, 0), dd = PyArray_DIM(jc, 2);
    if (dd < 1 || dd > 64) {
        PyErr_SetString(PyExc_ValueError, "reduce: camera dimension must be 1..64");
        return NULL;
    }
    int d = (int)dd;
    ix djp[3] = {n, 2, 3}, dv[2] = {-1, 6};
    PyArrayObject *jp = arg(args[1], "Jp", NPY_DOUBLE, 3, djp);
    PyArrayObject *v = jp ? arg(args[2], "V", NPY_DOUBLE, 2, dv) : NULL;
    if (!v) return NULL;
    ix np_ = PyArray_DIM(v, 0);
    ix dgp[2] = {np_, 3}, du[3] = {-1, d, d};
    PyArrayObject *gp = arg(args[3], "gp", NPY_DOUBLE, 2, dgp);
    PyArrayObject *u = gp ? arg(args[4], "U", NPY_DOUBLE, 3, du) : NULL;
    if (!u) return NULL;
    ix nc = PyArray_DIM(u, 0);
    ix dgc[2] = {nc, d}, dcam[1] = {n}, dptr[1] = {np_ + 1}, dobs[1] = {n};
    PyArrayObject *gc = arg(args[5], "gc", NPY_DOUBLE, 2, dgc);
    PyArrayObject *cam = gc ? arg(args[6], "cam", NPY_INTP, 1, dcam) : NULL;
    PyArrayObject *ptr = cam ? arg(args[7], "point_ptr", NPY_INTP, 1, dptr) : NULL;
    PyArrayObject *obs = ptr ? arg(args[8], "point_obs", NPY_INTP, 1, dobs) : NULL;
    if (!obs) return NULL;
    const double *Jc = PyArray_DATA(jc), *Jp = PyArray_DATA(jp), *V = PyArray_DATA(v);
    const double *Gp = PyArray_DATA(gp), *U = PyArray_DATA(u), *Gc = PyArray_DATA(gc);
    const ix *C = PyArray_DATA(cam), *P = PyArray_DATA(ptr), *O = PyArray_DATA(obs);
    /* the index arrays are trusted only after this check */
    if (P[0] != 0 || P[np_] != n) {
        PyErr_SetString(PyExc_ValueError, "reduce: point_ptr must run from 0 to n");
        return NULL;
    }
    ix maxc = 0;
    for (ix j = 0; j < np_; j++) {
        ix m = P[j + 1] - P[j];
        if (m < 0) {
            PyErr_SetString(PyExc_ValueError, "reduce: point_ptr must be non-decreasing");
            return NULL;
        }
        if (m > maxc) maxc = m;
    }
    for (ix a = 0; a < n; a++)
        if (O[a] < 0 || O[a] >= n || C[a] < 0 || C[a] >= nc) {
            PyErr_SetString(PyExc_ValueError, "reduce: an observation or camera index is out "
                                              "of range");
            return NULL;
        }
    ix N = nc * d;
    npy_intp ds[2] = {N, N}, dr[1] = {N}, dci[2] = {6, np_};
    PyObject *So = PyArray_ZEROS(2, ds, NPY_DOUBLE, 0);
    PyObject *ro = PyArray_SimpleNew(1, dr, NPY_DOUBLE);
    PyObject *cio = PyArray_SimpleNew(2, dci, NPY_DOUBLE);
    double *Z = PyMem_Malloc(sizeof(double) * (size_t)(maxc > 0 ? maxc : 1) * 3 * (size_t)d);
    if (!So || !ro || !cio || !Z) {
        Py_XDECREF(So); Py_XDECREF(ro); Py_XDECREF(cio); PyMem_Free(Z);
        return PyErr_NoMemory();
    }
    double *S = PyArray_DATA((PyArrayObject *)So), *rhs = PyArray_DATA((PyArrayObject *)ro);
    double *Ci = PyArray_DATA((PyArrayObject *)cio);
    int ok;
    Py_BEGIN_ALLOW_THREADS
    ok = form_any(Jc, Jp, V, Gp, U, Gc, C, P, O, nc, np_, S, rhs, Ci, Z, d);
    Py_END_ALLOW_THREADS
    PyMem_Free(Z);
    if (!ok) {
        Py_DECREF(So); Py_DECREF(ro); Py_DECREF(cio);
        Py_RETURN_NONE;
    }
    PyObject *res = PyTuple_Pack(3, So, ro, cio);
    Py_DECREF(So); Py_DECREF(ro); Py_DECREF(cio);
    return res;
}

/* the sums of blocks(); inlined with a constant camera dimension for the common sizes */
static inline __attribute__((always_inline)) void sums(
    const double *restrict Jc, const double *restrict Jp, const double *restrict R,
    const ix *restrict C, const ix *restrict P, ix n, double *restrict V, double *restrict Gp,
    double *restrict U, double *restrict Gc, const int d) {
    for (ix a = 0; a < n; a++) {
        const double *x = Jp + 6 * a, *y = x + 3, *ra = R + 2 * a;
        double *v = V + 6 * P[a], *g = Gp + 3 * P[a];
        v[0] += x[0] * x[0] + y[0] * y[0];
        v[1] += x[0] * x[1] + y[0] * y[1];
        v[2] += x[0] * x[2] + y[0] * y[2];
        v[3] += x[1] * x[1] + y[1] * y[1];
        v[4] += x[1] * x[2] + y[1] * y[2];
        v[5] += x[2] * x[2] + y[2] * y[2];
        for (int i = 0; i < 3; i++) g[i] += x[i] * ra[0] + y[i] * ra[1];
        const double *j0 = Jc + 2 * (size_t)d * a, *j1 = j0 + d;
        double *u = U + (size_t)d * d * C[a], *gc = Gc + (size_t)d * C[a];
        for (int i = 0; i < d; i++) {
            double a0 = j0[i], a1 = j1[i];
            for (int k = 0; k < d; k++) u[i * d + k] += a0 * j0[k] + a1 * j1[k];
            gc[i] += a0 * ra[0] + a1 * ra[1];
        }
    }
}

LM_HOT static void sums_any(const double *Jc, const double *Jp, const double *R, const ix *C,
                     const ix *P, ix n, double *V, double *Gp, double *U, double *Gc, int d) {
    switch (d) {
    case 9: sums(Jc, Jp, R, C, P, n, V, Gp, U, Gc, 9); break;
    case 6: sums(Jc, Jp, R, C, P, n, V, Gp, U, Gc, 6); break;
    case 10: sums(Jc, Jp, R, C, P, n, V, Gp, U, Gc, 10); break;
    default: sums(Jc, Jp, R, C, P, n, V, Gp, U, Gc, d);
    }
}

/* blocks(Jc, Jp, r, cam, pt, n_cameras, n_points) -> (V, gp, U, gc): the blocks of the normal
 * equations, V (np, 6) = sum over a point's observations of Jp^T Jp (v00, v01, v02, v11, v12,
 * v22), gp (np, 3) = sum Jp^T r, U (nc, d, d) = sum over a camera's of Jc^T Jc, gc (nc, d) =
 * sum Jc^T r (the compiled form of NormalEquations.__post_init__'s sums) */
static PyObject *blocks_(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 7) {
        PyErr_Format(PyExc_TypeError, "blocks: expected 7 arguments, got %zd", nargs);
        return NULL;
    }
    long long ncl = PyLong_AsLongLong(args[5]), npl = PyLong_AsLongLong(args[6]);
    if ((ncl == -1 || npl == -1) && PyErr_Occurred()) return NULL;
    if (ncl < 0 || npl < 0) {
        PyErr_SetString(PyExc_ValueError, "blocks: n_cameras and n_points must be >= 0");
        return NULL;
    }
    ix nc = (ix)ncl, np_ = (ix)npl;
    ix any3[3] = {-1, 2, -1};
    PyArrayObject *jc = arg(args[0], "Jc", NPY_DOUBLE, 3, any3);
    if (!jc) return NULL;
    ix n = PyArray_DIM(jc, 0);
    int d = (int)PyArray_DIM(jc, 2);
    ix djp[3] = {n, 2, 3}, dr[2] = {n, 2}, dn[1] = {n};
    PyArrayObject *jp = arg(args[1], "Jp", NPY_DOUBLE, 3, djp);
    PyArrayObject *rr = jp ? arg(args[2], "r", NPY_DOUBLE, 2, dr) : NULL;
    PyArrayObject *cam = rr ? arg(args[3], "cam", NPY_INTP, 1, dn) : NULL;
    PyArrayObject *pt = cam ? arg(args[4], "pt", NPY_INTP, 1, dn) : NULL;
    if (!pt) return NULL;
    const double *Jc = PyArray_DATA(jc), *Jp = PyArray_DATA(jp), *R = PyArray_DATA(rr);
    const ix *C = PyArray_DATA(cam), *P = PyArray_DATA(pt);
    for (ix a = 0; a < n; a++)
        if (C[a] < 0 || C[a] >= nc || P[a] < 0 || P[a] >= np_) {
            PyErr_SetString(PyExc_ValueError, "blocks: a camera or point index is out of range");
            return NULL;
        }
    npy_intp dv[2] = {np_, 6}, dg[2] = {np_, 3}, du[3] = {nc, d, d}, dgc[2] = {nc, d};
    PyObject *vo = PyArray_ZEROS(2, dv, NPY_DOUBLE, 0), *go = PyArray_ZEROS(2, dg, NPY_DOUBLE, 0);
    PyObject *uo = PyArray_ZEROS(3, du, NPY_DOUBLE, 0), *gco = PyArray_ZEROS(2, dgc, NPY_DOUBLE, 0);
    if (!vo || !go || !uo || !gco) {
        Py_XDECREF(vo); Py_XDECREF(go); Py_XDECREF(uo); Py_XDECREF(gco);
        return PyErr_NoMemory();
    }
    double *V = PyArray_DATA((PyArrayObject *)vo), *Gp = PyArray_DATA((PyArrayObject *)go);
    double *U = PyArray_DATA((PyArrayObject *)uo), *Gc = PyArray_DATA((PyArrayObject *)gco);
    Py_BEGIN_ALLOW_THREADS
    sums_any(Jc, Jp, R, C, P, n, V, Gp, U, Gc, d);
    Py_END_ALLOW_THREADS
    PyObject *res = PyTuple_Pack(4, vo, go, uo, gco);
    Py_DECREF(vo); Py_DECREF(go); Py_DECREF(uo); Py_DECREF(gco);
    return res;
}

/* back(Jc, Jp, dc, cam, pt, gp, Ci, held) -> (dp, y): the back substitution of the points,
 * y (n, 2) = Jc_a dc_(cam a) per observation, w = gp + sum Jp^T y per point (0 where held),
 * dp (np, 3) = -V^-1 w = -Ci^T Ci w */
static PyObject *back_(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 8) {
        PyErr_Format(PyExc_TypeError, "back: expected 8 arguments, got %zd", nargs);
        return NULL;
    }
    ix any3[3] = {-1, 2, -1};
    PyArrayObject *jc = arg(args[0], "Jc", NPY_DOUBLE, 3, any3);
    if (!jc) return NULL;
    ix n = PyArray_DIM(jc, 0), d = PyArray_DIM(jc, 2);
    ix djp[3] = {n, 2, 3}, ddc[2] = {-1, d}, dn[1] = {n}, dgp[2] = {-1, 3};
    PyArrayObject *jp = arg(args[1], "Jp", NPY_DOUBLE, 3, djp);
    PyArrayObject *dco = jp ? arg(args[2], "dc", NPY_DOUBLE, 2, ddc) : NULL;
    PyArrayObject *cam = dco ? arg(args[3], "cam", NPY_INTP, 1, dn) : NULL;
    PyArrayObject *pt = cam ? arg(args[4], "pt", NPY_INTP, 1, dn) : NULL;
    PyArrayObject *gpo = pt ? arg(args[5], "gp", NPY_DOUBLE, 2, dgp) : NULL;
    if (!gpo) return NULL;
    ix nc = PyArray_DIM(dco, 0), np_ = PyArray_DIM(gpo, 0);
    ix dci[2] = {6, np_}, dh[1] = {np_};
    PyArrayObject *cio = arg(args[6], "Ci", NPY_DOUBLE, 2, dci);
    PyArrayObject *ho = cio ? arg(args[7], "held", NPY_BOOL, 1, dh) : NULL;
    if (!ho) return NULL;
    const double *Jc = PyArray_DATA(jc), *Jp = PyArray_DATA(jp), *dc = PyArray_DATA(dco);
    const double *gp = PyArray_DATA(gpo), *Ci = PyArray_DATA(cio);
    const ix *C = PyArray_DATA(cam), *P = PyArray_DATA(pt);
    const npy_bool *held = PyArray_DATA(ho);
    for (ix a = 0; a < n; a++)
        if (C[a] < 0 || C[a] >= nc || P[a] < 0 || P[a] >= np_) {
            PyErr_SetString(PyExc_ValueError, "back: a camera or point index is out of range");
            return NULL;
        }
    npy_intp dp_dims[2] = {np_, 3}, dy[2] = {n, 2};
    PyObject *dpo = PyArray_SimpleNew(2, dp_dims, NPY_DOUBLE), *yo = PyArray_SimpleNew(2, dy, NPY_DOUBLE);
    if (!dpo || !yo) {
        Py_XDECREF(dpo); Py_XDECREF(yo);
        return PyErr_NoMemory();
    }
    double *dp = PyArray_DATA((PyArrayObject *)dpo), *y = PyArray_DATA((PyArrayObject *)yo);
    Py_BEGIN_ALLOW_THREADS
    memcpy(dp, gp, sizeof(double) * 3 * (size_t)np_); /* w, accumulated in dp */
    for (ix a = 0; a < n; a++) {
        const double *j0 = Jc + 2 * (size_t)d * a, *j1 = j0 + d, *x = dc + (size_t)d * C[a];
        double y0 = 0.0, y1 = 0.0;
        for (ix k = 0; k < d; k++) {
            y0 += j0[k] * x[k];
            y1 += j1[k] * x[k];
        }
        y[2 * a] = y0;
        y[2 * a + 1] = y1;
        const double *q = Jp + 6 * a;
        double *w = dp + 3 * P[a];
        for (int i = 0; i < 3; i++) w[i] += q[i] * y0 + q[3 + i] * y1;
    }
    for (ix j = 0; j < np_; j++) {
        double *w = dp + 3 * j;
        if (held[j]) {
            w[0] = w[1] = w[2] = 0.0;
            continue;
        }
        double i00 = Ci[j], i10 = Ci[np_ + j], i11 = Ci[2 * np_ + j];
        double i20 = Ci[3 * np_ + j], i21 = Ci[4 * np_ + j], i22 = Ci[5 * np_ + j];
        double u0 = i00 * w[0], u1 = i10 * w[0] + i11 * w[1];
        double u2 = i20 * w[0] + i21 * w[1] + i22 * w[2];
        w[0] = -(i00 * u0 + i10 * u1 + i20 * u2);
        w[1] = -(i11 * u1 + i21 * u2);
        w[2] = -(i22 * u2);
    }
    Py_END_ALLOW_THREADS
    PyObject *res = PyTuple_Pack(2, dpo, yo);
    Py_DECREF(dpo); Py_DECREF(yo);
    return res;
}

static PyMethodDef methods[] = {
    {"back", (PyCFunction)(void (*)(void))back_, METH_FASTCALL,
     "back(Jc, Jp, dc, cam, pt, gp, Ci, held) -> (dp, y): the back substitution of the points"},
    {"blocks", (PyCFunction)(void (*)(void))blocks_, METH_FASTCALL,
     "blocks(Jc, Jp, r, cam, pt, n_cameras, n_points) -> (V, gp, U, gc): the point and camera "
     "blocks and gradients of the normal equations"},
    {"reduce", (PyCFunction)(void (*)(void))reduce_, METH_FASTCALL,
     "reduce(Jc, Jp, V, gp, U, gc, cam, point_ptr, point_obs) -> (S, rhs, Ci) or None: the "
     "dense reduced camera system of bundle adjustment (see the module source)"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_schur",
                                    "The Schur complement of bundle adjustment, compiled.", -1,
                                    methods};

PyMODINIT_FUNC PyInit__schur(void) {
    import_array();
    return PyModule_Create(&module);
}
