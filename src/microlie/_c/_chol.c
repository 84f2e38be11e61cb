/* microlie._c._chol: the numeric supernodal Cholesky of microlie.optim.cholesky in one C call.
 *
 * The symbolic analysis (supernodes, panels, row structures, the assembly map and the update
 * pairs) is microlie's (NumPy); this file runs the loops over it. There is no link-time BLAS:
 * at import, the OpenBLAS that NumPy itself loaded (its wheels' scipy_openblas64_, 64-bit
 * integers) is looked up among the process's shared libraries (Linux), so that the solve needs
 * no SciPy (whose import costs some 0.2 s of CPU and 30 MB); elsewhere, or when NumPy's BLAS
 * is not such a library, SciPy's own from the function-pointer capsules of
 * scipy.linalg.cython_blas and cython_lapack (Fortran calling convention, 32-bit integers).
 * The module's BLAS attribute says which ("numpy" or "scipy").
 *
 * Storage: supernode s owns the m_s x k_s column-major panel at Lx + px[s] (rows rows[rptr[s] ..
 * rptr[s] + m_s), the first k_s of them its own columns c0[s] .. c0[s] + k_s).
 *
 * factor: Lx[amap[e]] = data[e] for every pattern entry e (or, when amap has one entry per run
 * of bs rows, Lx[amap[q] + r] = data[q bs + r]; Lx holds bs slots after the panels, the
 * dump), then for each supernode in order:
 * potrf on the diagonal block, trsm for the rows below (L21 = A21 L11^-T), W = L21 L21^T (syrk,
 * lower; plain loops instead of these three BLAS calls for supernodes of at most SMALL_K
 * columns), and for each update pair p of s (ancestor t, W columns pa[p] .. pb[p] owned by t)
 * the subtraction of W[i, j] (i >= j) from t's panel at column rows(s, k + j) - c0[t] and local
 * row bs rel[relptr[p] + q] + rr for i = pa[p] + bs q + rr (rel: the block rows, in t's
 * structure, of s's below rows from pa[p] on, in runs of bs). amap is int32 or int64. Returns
 * 0, or 1 + s for a pivot of supernode s that is not positive.
 *
 * solve: y (n x nrhs, column-major, permuted) <- L^-T L^-1 y. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <numpy/arrayobject.h>
#include <math.h>
#include <string.h>

#include "dispatch.h"

typedef npy_int64 i64;
typedef void (*potrf_t)(char *, int *, double *, int *, int *);
typedef void (*trsm_t)(char *, char *, char *, char *, int *, int *, double *, double *, int *,
                       double *, int *);
typedef void (*syrk_t)(char *, char *, int *, int *, double *, double *, int *, double *,
                       double *, int *);
typedef void (*gemm_t)(char *, char *, int *, int *, int *, double *, double *, int *, double *,
                       int *, double *, double *, int *);

static potrf_t f_potrf;
static trsm_t f_trsm;
static syrk_t f_syrk;
static gemm_t f_gemm;

static void *capsule_fn(PyObject *mod, const char *name) {
    PyObject *capi = PyObject_GetAttrString(mod, "__pyx_capi__");
    if (!capi) return NULL;
    PyObject *cap = PyDict_GetItemString(capi, name); /* borrowed */
    void *p = NULL;
    if (!cap)
        PyErr_Format(PyExc_ImportError, "scipy's __pyx_capi__ has no %s", name);
    else
        p = PyCapsule_GetPointer(cap, PyCapsule_GetName(cap));
    Py_DECREF(capi);
    return p;
}

static int load_scipy_blas(void) {
    PyObject *lapack = PyImport_ImportModule("scipy.linalg.cython_lapack");
    if (!lapack) return -1;
    PyObject *blas = PyImport_ImportModule("scipy.linalg.cython_blas");
    if (!blas) {
        Py_DECREF(lapack);
        return -1;
    }
    f_potrf = (potrf_t)capsule_fn(lapack, "dpotrf");
    f_trsm = f_potrf ? (trsm_t)capsule_fn(blas, "dtrsm") : NULL;
    f_syrk = f_trsm ? (syrk_t)capsule_fn(blas, "dsyrk") : NULL;
    f_gemm = f_syrk ? (gemm_t)capsule_fn(blas, "dgemm") : NULL;
    Py_DECREF(lapack);
    Py_DECREF(blas);
    return f_gemm ? 0 : -1;
}

static const char *blas_source = "scipy";

#if defined(__linux__)
#include <dlfcn.h>
#include <link.h>

/* NumPy's OpenBLAS with 64-bit integers, called through 32-bit-integer wrappers */
typedef void (*potrf64_t)(char *, i64 *, double *, i64 *, i64 *);
typedef void (*trsm64_t)(char *, char *, char *, char *, i64 *, i64 *, double *, double *,
                         i64 *, double *, i64 *);
typedef void (*syrk64_t)(char *, char *, i64 *, i64 *, double *, double *, i64 *, double *,
                         double *, i64 *);
typedef void (*gemm64_t)(char *, char *, i64 *, i64 *, i64 *, double *, double *, i64 *,
                         double *, i64 *, double *, double *, i64 *);
static potrf64_t g_potrf;
static trsm64_t g_trsm;
static syrk64_t g_syrk;
static gemm64_t g_gemm;

static void w_potrf(char *u, int *n, double *a, int *lda, int *info) {
    i64 N = *n, LA = *lda, info64 = 0;
    g_potrf(u, &N, a, &LA, &info64);
    *info = (int)info64;
}
static void w_trsm(char *sd, char *u, char *t, char *d, int *m, int *n, double *al, double *a,
                   int *lda, double *b, int *ldb) {
    i64 M = *m, N = *n, LA = *lda, LB = *ldb;
    g_trsm(sd, u, t, d, &M, &N, al, a, &LA, b, &LB);
}
static void w_syrk(char *u, char *t, int *n, int *k, double *al, double *a, int *lda,
                   double *be, double *c, int *ldc) {
    i64 N = *n, K = *k, LA = *lda, LC = *ldc;
    g_syrk(u, t, &N, &K, al, a, &LA, be, c, &LC);
}
static void w_gemm(char *ta, char *tb, int *m, int *n, int *k, double *al, double *a, int *lda,
                   double *b, int *ldb, double *be, double *c, int *ldc) {
    i64 M = *m, N = *n, K = *k, LA = *lda, LB = *ldb, LC = *ldc;
    g_gemm(ta, tb, &M, &N, &K, al, a, &LA, b, &LB, be, c, &LC);
}

/* dl_iterate_phdr callback: an already loaded OpenBLAS with the ILP64 symbols */
static int find_numpy_blas(struct dl_phdr_info *info, size_t size, void *data) {
    (void)size;
    (void)data;
    const char *name = info->dlpi_name;
    if (!name || !strstr(name, "openblas64_")) return 0;
    void *h = dlopen(name, RTLD_LAZY | RTLD_NOLOAD);
    if (!h) return 0;
    static const char *prefix[] = {"scipy_", ""};
    for (int q = 0; q < 2; q++) {
        char sym[64];
        snprintf(sym, sizeof sym, "%sdpotrf_64_", prefix[q]);
        void *a = dlsym(h, sym);
        snprintf(sym, sizeof sym, "%sdtrsm_64_", prefix[q]);
        void *b = dlsym(h, sym);
        snprintf(sym, sizeof sym, "%sdsyrk_64_", prefix[q]);
        void *c = dlsym(h, sym);
        snprintf(sym, sizeof sym, "%sdgemm_64_", prefix[q]);
        void *d = dlsym(h, sym);
        if (a && b && c && d) {  /* the handle stays open: the library stays loaded */
            g_potrf = (potrf64_t)a;
            g_trsm = (trsm64_t)b;
            g_syrk = (syrk64_t)c;
            g_gemm = (gemm64_t)d;
            return 1;
        }
    }
    dlclose(h);
    return 0;
}
#endif

static int load_blas(void) {
#if defined(__linux__)
    const char *env = getenv("MICROLIE_FAST_BLAS");
    if (!(env && strcmp(env, "scipy") == 0) && dl_iterate_phdr(find_numpy_blas, NULL)) {
        f_potrf = w_potrf;
        f_trsm = w_trsm;
        f_syrk = w_syrk;
        f_gemm = w_gemm;
        blas_source = "numpy";
        return 0;
    }
#endif
    return load_scipy_blas();
}

/* Supernodes with at most SMALL_K columns skip BLAS (whose per-call cost dominates on tiny
 * blocks): the panel's Cholesky and the rows below in one right-looking loop, and W by columns.
 * Measured (CPU time per factorisation, BLAS for all -> SMALL_K 16): ais2klinik 6.8 -> 4.0 ms,
 * kitti_00 1.6 -> 1.0 ms, sphere2500 and parking-garage unchanged (8 and 32 were no better). */
#define SMALL_K 16

LM_HOT static int small_panel(int k, int m, double *restrict P) {
    for (int j = 0; j < k; j++) {
        double *restrict cj = P + (i64)j * m;
        double d = cj[j];
        if (!(d > 0.0)) return j + 1;
        d = sqrt(d);
        cj[j] = d;
        double r = 1.0 / d;
        for (int i = j + 1; i < m; i++) cj[i] *= r;
        for (int c = j + 1; c < k; c++) {
            double *restrict cc = P + (i64)c * m;
            double l = cj[c];
            for (int i = c; i < m; i++) cc[i] -= l * cj[i];
        }
    }
    return 0;
}

LM_HOT static void small_syrk(int u, int k, const double *restrict A, int lda, double *restrict W) {
    for (int j = 0; j < u; j++) { /* W[j:, j] = A[j:, :] A[j, :]^T */
        double *restrict w = W + (i64)j * u;
        for (int i = j; i < u; i++) w[i] = 0.0;
        for (int p = 0; p < k; p++) {
            const double *restrict a = A + (i64)p * lda;
            double l = a[j];
            for (int i = j; i < u; i++) w[i] += l * a[i];
        }
    }
}

/* a C-contiguous array of the given type with at least `len` entries (len < 0: any) */
static void *arr(PyObject *o, int type, i64 len, const char *what, i64 *size) {
    if (!PyArray_Check(o) || PyArray_TYPE((PyArrayObject *)o) != type ||
        !PyArray_IS_C_CONTIGUOUS((PyArrayObject *)o)) {
        PyErr_Format(PyExc_TypeError, "%s must be a C-contiguous %s array", what,
                     type == NPY_FLOAT64 ? "float64" : "int64");
        return NULL;
    }
    i64 n = (i64)PyArray_SIZE((PyArrayObject *)o);
    if (len >= 0 && n < len) {
        PyErr_Format(PyExc_ValueError, "%s has %lld entries, expected at least %lld", what,
                     (long long)n, (long long)len);
        return NULL;
    }
    if (size) *size = n;
    return PyArray_DATA((PyArrayObject *)o);
}

static PyObject *factor(PyObject *self, PyObject *args) {
    PyObject *oLx, *odata, *oamap, *oc0, *ok, *om, *opx, *orows, *orptr, *opptr, *opt, *opa,
        *opb, *orelptr, *orel;
    Py_ssize_t wsize, bs;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOOOOOOnn", &oLx, &odata, &oamap, &oc0, &ok, &om,
                          &opx, &orows, &orptr, &opptr, &opt, &opa, &opb, &orelptr, &orel,
                          &wsize, &bs))
        return NULL;
    if (bs < 1) {
        PyErr_SetString(PyExc_ValueError, "bs must be positive");
        return NULL;
    }
    i64 nx = 0, ne = 0, ns = 0, np_ = 0;
    double *Lx = arr(oLx, NPY_FLOAT64, -1, "Lx", &nx);
    double *data = Lx ? arr(odata, NPY_FLOAT64, -1, "data", &ne) : NULL;
    /* amap: int32 (half the memory) or int64; one entry per pattern entry, or per run of bs */
    int a32 = PyArray_Check(oamap) && PyArray_TYPE((PyArrayObject *)oamap) == NPY_INT32;
    i64 na = PyArray_Check(oamap) ? (i64)PyArray_SIZE((PyArrayObject *)oamap) : -1;
    i64 run = na == ne ? 1 : bs;
    if (data && na * run != ne) {
        PyErr_SetString(PyExc_ValueError, "amap must have one entry per entry of data or per "
                                          "run of bs entries");
        return NULL;
    }
    void *amap = data ? arr(oamap, a32 ? NPY_INT32 : NPY_INT64, na, "amap", NULL) : NULL;
    const npy_int32 *amap32 = amap;
    const i64 *amap64 = amap;
    i64 *c0 = amap ? arr(oc0, NPY_INT64, -1, "c0", &ns) : NULL;
    i64 *kk = c0 ? arr(ok, NPY_INT64, ns, "k", NULL) : NULL;
    i64 *mm = kk ? arr(om, NPY_INT64, ns, "m", NULL) : NULL;
    i64 *px = mm ? arr(opx, NPY_INT64, ns, "px", NULL) : NULL;
    i64 *rows = px ? arr(orows, NPY_INT64, -1, "rows", NULL) : NULL;
    i64 *rptr = rows ? arr(orptr, NPY_INT64, ns + 1, "rptr", NULL) : NULL;
    i64 *pptr = rptr ? arr(opptr, NPY_INT64, ns + 1, "pptr", NULL) : NULL;
    i64 *pt = pptr ? arr(opt, NPY_INT64, -1, "pt", &np_) : NULL;
    i64 *pa = pt ? arr(opa, NPY_INT64, np_, "pa", NULL) : NULL;
    i64 *pb = pa ? arr(opb, NPY_INT64, np_, "pb", NULL) : NULL;
    i64 *relptr = pb ? arr(orelptr, NPY_INT64, np_ + 1, "relptr", NULL) : NULL;
    i64 *rel = relptr ? arr(orel, NPY_INT64, -1, "rel", NULL) : NULL;
    if (!rel) return NULL;
    for (i64 e = 0; e < na; e++) {
        i64 at = a32 ? (i64)amap32[e] : amap64[e];
        if (at < 0 || at + run > nx) {
            PyErr_SetString(PyExc_ValueError, "amap out of range");
            return NULL;
        }
    }
    double *W = PyMem_Malloc((size_t)(wsize > 0 ? wsize : 1) * sizeof(double));
    if (!W) return PyErr_NoMemory();
    i64 bad = 0;
    Py_BEGIN_ALLOW_THREADS
    memset(Lx, 0, (size_t)nx * sizeof(double));
    if (run > 1)
        for (i64 q = 0; q < na; q++) {
            double *dst = Lx + (a32 ? (i64)amap32[q] : amap64[q]);
            const double *src = data + q * run;
            for (i64 r = 0; r < run; r++) dst[r] = src[r];
        }
    else if (a32)
        for (i64 e = 0; e < ne; e++) Lx[amap32[e]] = data[e];
    else
        for (i64 e = 0; e < ne; e++) Lx[amap64[e]] = data[e];
    /* the entries of the strict upper triangle went to the dump block after the panels */
    char cL = 'L', cR = 'R', cT = 'T', cN = 'N';
    double one = 1.0, zero = 0.0;
    for (i64 s = 0; s < ns; s++) {
        int k = (int)kk[s], m = (int)mm[s], u = m - k, info = 0;
        double *P = Lx + px[s];
        if (k <= SMALL_K) {
            if (small_panel(k, m, P)) {
                bad = s + 1;
                break;
            }
            if (u == 0) continue;
            small_syrk(u, k, P + k, m, W);
        } else {
            f_potrf(&cL, &k, P, &m, &info);
            if (info != 0) {
                bad = s + 1;
                break;
            }
            if (u == 0) continue;
            f_trsm(&cR, &cL, &cT, &cN, &u, &k, &one, P, &m, P + k, &m);
            f_syrk(&cL, &cN, &u, &k, &one, P + k, &m, &zero, W, &u);
        }
        const i64 *below = rows + rptr[s] + k;
        for (i64 p = pptr[s]; p < pptr[s + 1]; p++) {
            i64 t = pt[p], a = pa[p], b = pb[p], mt = mm[t];
            const i64 *rb = rel + relptr[p]; /* block rows from a, in t */
            double *Pt = Lx + px[t];
            for (i64 j = a; j < b; j++) {
                double *dst = Pt + (below[j] - c0[t]) * mt;
                const double *w = W + j * (i64)u;
                /* rows come in runs of bs consecutive local rows from a: the rest of j's run
                 * one by one, then whole runs as contiguous vectors */
                i64 q0 = (j - a) / bs, rr = (j - a) % bs, i = j;
                double *d0 = dst + rb[q0] * bs;
                for (; rr < bs; rr++, i++) d0[rr] -= w[i];
                const i64 *rq = rb + q0 + 1;
                if (bs == 6)
                    for (; i < u; i += 6) {
                        double *d = dst + 6 * *rq++;
                        for (int q = 0; q < 6; q++) d[q] -= w[i + q];
                    }
                else if (bs == 3)
                    for (; i < u; i += 3) {
                        double *d = dst + 3 * *rq++;
                        for (int q = 0; q < 3; q++) d[q] -= w[i + q];
                    }
                else
                    for (; i < u; i += bs) {
                        double *d = dst + bs * *rq++;
                        for (i64 q = 0; q < bs; q++) d[q] -= w[i + q];
                    }
            }
        }
    }
    Py_END_ALLOW_THREADS
    PyMem_Free(W);
    return PyLong_FromLongLong((long long)bad);
}

static PyObject *solve(PyObject *self, PyObject *args) {
    PyObject *oLx, *oy, *oc0, *ok, *om, *opx, *orows, *orptr;
    Py_ssize_t usize;
    if (!PyArg_ParseTuple(args, "OOOOOOOOn", &oLx, &oy, &oc0, &ok, &om, &opx, &orows, &orptr,
                          &usize))
        return NULL;
    if (!PyArray_Check(oy) || PyArray_TYPE((PyArrayObject *)oy) != NPY_FLOAT64 ||
        PyArray_NDIM((PyArrayObject *)oy) != 2 ||
        !PyArray_IS_F_CONTIGUOUS((PyArrayObject *)oy)) {
        PyErr_SetString(PyExc_TypeError, "y must be a 2-D Fortran-ordered float64 array");
        return NULL;
    }
    i64 ns;
    double *Lx = arr(oLx, NPY_FLOAT64, -1, "Lx", NULL);
    i64 *c0 = Lx ? arr(oc0, NPY_INT64, -1, "c0", &ns) : NULL;
    i64 *kk = c0 ? arr(ok, NPY_INT64, ns, "k", NULL) : NULL;
    i64 *mm = kk ? arr(om, NPY_INT64, ns, "m", NULL) : NULL;
    i64 *px = mm ? arr(opx, NPY_INT64, ns, "px", NULL) : NULL;
    i64 *rows = px ? arr(orows, NPY_INT64, -1, "rows", NULL) : NULL;
    i64 *rptr = rows ? arr(orptr, NPY_INT64, ns + 1, "rptr", NULL) : NULL;
    if (!rptr) return NULL;
    double *y = PyArray_DATA((PyArrayObject *)oy);
    int n = (int)PyArray_DIM((PyArrayObject *)oy, 0), nr = (int)PyArray_DIM((PyArrayObject *)oy, 1);
    double *T = PyMem_Malloc((size_t)(usize > 0 ? usize : 1) * (size_t)(nr > 0 ? nr : 1) *
                             sizeof(double));
    if (!T) return PyErr_NoMemory();
    Py_BEGIN_ALLOW_THREADS
    char cL = 'L', cT = 'T', cN = 'N';
    double one = 1.0, zero = 0.0, mone = -1.0;
    for (i64 s = 0; s < ns; s++) { /* forward: L y = b */
        int k = (int)kk[s], m = (int)mm[s], u = m - k;
        double *P = Lx + px[s], *ys = y + c0[s];
        f_trsm(&cL, &cL, &cN, &cN, &k, &nr, &one, P, &m, ys, &n);
        if (u == 0) continue;
        f_gemm(&cN, &cN, &u, &nr, &k, &one, P + k, &m, ys, &n, &zero, T, &u);
        const i64 *below = rows + rptr[s] + k;
        for (int c = 0; c < nr; c++) {
            double *yc = y + (i64)c * n;
            const double *tc = T + (i64)c * u;
            for (int i = 0; i < u; i++) yc[below[i]] -= tc[i];
        }
    }
    for (i64 s = ns - 1; s >= 0; s--) { /* backward: L^T x = y */
        int k = (int)kk[s], m = (int)mm[s], u = m - k;
        double *P = Lx + px[s], *ys = y + c0[s];
        if (u > 0) {
            const i64 *below = rows + rptr[s] + k;
            for (int c = 0; c < nr; c++) {
                const double *yc = y + (i64)c * n;
                double *tc = T + (i64)c * u;
                for (int i = 0; i < u; i++) tc[i] = yc[below[i]];
            }
            f_gemm(&cT, &cN, &k, &nr, &u, &mone, P + k, &m, T, &u, &one, ys, &n);
        }
        f_trsm(&cL, &cL, &cT, &cN, &k, &nr, &one, P, &m, ys, &n);
    }
    Py_END_ALLOW_THREADS
    PyMem_Free(T);
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"factor", factor, METH_VARARGS,
     "factor(Lx, data, amap, c0, k, m, px, rows, rptr, pptr, pt, pa, pb, relptr, rel, wsize, "
     "bs) -> 0, or 1 + the supernode whose pivot is not positive"
},
    {"solve", solve, METH_VARARGS,
     "solve(Lx, y, c0, k, m, px, rows, rptr, usize): y <- L^-T L^-1 y in place"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef moddef = {PyModuleDef_HEAD_INIT, "_chol",
                                    "The numeric supernodal Cholesky loop of microlie.optim.",
                                    -1, methods};

PyMODINIT_FUNC PyInit__chol(void) {
    import_array();
    if (load_blas() < 0) return NULL;
    PyObject *m = PyModule_Create(&moddef);
    if (m && PyModule_AddStringConstant(m, "BLAS", blas_source) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
