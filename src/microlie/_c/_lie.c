/* microlie._c._lie: compiled NumPy kernels for microlie's kernel registry.
 *
 * Each kernel takes C-contiguous arrays of shape (N, k_i), all float64 or all float32 (the caller
 * broadcasts and flattens batch axes), and returns a tuple of fresh arrays of that dtype, one per
 * output, of shape (N, k) or (N, r, c) (see microlie._kernels.KERNELS).
 *
 * Layout: rows of 3, 4, 6 or 7 components do not vectorise in GCC (interleaved groups of 6 or 7
 * are not supported), so each kernel works on blocks of S elements: the rows of a block are
 * copied into structure-of-arrays buffers (component i of element j at buf[i * S + j], converted
 * to double), an `omp simd` loop over the block evaluates the element formula of lie_math.h with
 * unit-stride accesses (vectorised; the block functions are LM_HOT: dispatch.h), and the
 * results are copied back to rows (rounded to float for float32 inputs). */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <numpy/arrayobject.h>
#include <stdint.h>
#include <stdlib.h>
#ifdef __linux__
#include <sys/mman.h>
#endif

#include "lie_math.h"
#include "sim3_math.h"

typedef npy_intp ix;
typedef void (*block_fn)(const double *restrict in, double *restrict out, ix m);
typedef void (*plain_fn)(const double *restrict a, const double *restrict b, double *restrict o,
                         ix n);

typedef struct {
    const char *name; /* the registry name, e.g. "SE3.exp" */
    int nin;
    int kin[2];      /* widths of the inputs */
    int nout;
    int rows[3];     /* output j has shape (N, rows[j]) if cols[j] == 0, else (N, rows, cols) */
    int cols[3];
    block_fn fn;
    plain_fn plain; /* a row loop for float64 (cheap formulas: the block copies would dominate) */
} kernel;

#define MAXW 112 /* total width of the outputs of one kernel, at most */
#define MAXK 8   /* width of one input, at most */

static int width(const kernel *k, int j) { return k->rows[j] * (k->cols[j] ? k->cols[j] : 1); }

/* AoS rows -> SoA block (double) and back, for float64 and float32 rows */
#define COPY_FUNCS(T, SUF)                                                                     \
    static void load_##SUF(const T *restrict x, int kw, ix m, double *restrict buf) {          \
        for (ix j = 0; j < m; j++)                                                              \
            for (int c = 0; c < kw; c++) buf[c * S + j] = (double)x[kw * j + c];              \
    }                                                                                          \
    static void store_##SUF(const double *restrict buf, int kw, ix m, T *restrict y) {         \
        for (ix j = 0; j < m; j++)                                                              \
            for (int c = 0; c < kw; c++) y[kw * j + c] = (T)buf[c * S + j];                   \
    }
COPY_FUNCS(double, f64)
COPY_FUNCS(float, f32)

/* rows with a constant width: the compiler unrolls the component loop */
#define LOADK(KW)                                                                              \
    static void load_f64_##KW(const double *restrict x, ix m, double *restrict buf) {          \
        for (ix j = 0; j < m; j++)                                                              \
            for (int c = 0; c < KW; c++) buf[c * S + j] = x[KW * j + c];                      \
    }
LOADK(3) LOADK(4) LOADK(6) LOADK(7) LOADK(8)

static void load_rows(int f32, const char *x, int kw, ix m, double *buf) {
    if (f32) { load_f32((const float *)x, kw, m, buf); return; }
    const double *d = (const double *)x;
    switch (kw) {
    case 3: load_f64_3(d, m, buf); break;
    case 4: load_f64_4(d, m, buf); break;
    case 6: load_f64_6(d, m, buf); break;
    case 7: load_f64_7(d, m, buf); break;
    case 8: load_f64_8(d, m, buf); break;
    default: load_f64(d, kw, m, buf);
    }
}

static void evaluate(const kernel *k, int f32, ix n, char *const *in, char *const *out) {
    if (k->plain && !f32) {
        k->plain((const double *)in[0], (const double *)in[k->nin - 1], (double *)out[0], n);
        return;
    }
    double ibuf[2 * MAXK * S] __attribute__((aligned(64)));
    double obuf[MAXW * S] __attribute__((aligned(64)));
    size_t es = f32 ? sizeof(float) : sizeof(double);
    int wo[3];
    for (int j = 0; j < k->nout; j++) wo[j] = width(k, j);
    for (ix i0 = 0; i0 < n; i0 += S) {
        ix m = n - i0 < S ? n - i0 : S;
        int off = 0;
        for (int a = 0; a < k->nin; a++) {
            load_rows(f32, in[a] + (size_t)(i0 * k->kin[a]) * es, k->kin[a], m, ibuf + off * S);
            off += k->kin[a];
        }
        k->fn(ibuf, obuf, m);
        off = 0;
        for (int j = 0; j < k->nout; j++) {
            char *y = out[j] + (size_t)(i0 * wo[j]) * es;
            if (f32) store_f32(obuf + off * S, wo[j], m, (float *)y);
            else store_f64(obuf + off * S, wo[j], m, (double *)y);
            off += wo[j];
        }
    }
}

/* ------------------------------------------------------------------ the output cache
 * A fresh output array of many megabytes costs a page fault per page on its first write (the
 * kernel zeroes each page): for the cheap operations that is as much as the formula (issue 11).
 * Large outputs therefore come from a small cache of blocks: when the array that owned a block
 * is freed, the block is kept (up to CACHE_SLOTS blocks and cache_limit bytes in all, the oldest
 * evicted first) and the next output of a fitting size reuses it with its pages already mapped.
 * The arrays are ordinary writable C-contiguous ndarrays whose base is a capsule returning the
 * block to the cache. Outputs below CACHE_MIN bytes use NumPy's own allocator. The limit is
 * MICROLIE_FAST_CACHE_MB (default 256; 0 disables the cache) or set_cache_limit(). A freed block
 * larger than the limit is kept too, alone, as the large block (`big`: the latest one, replacing
 * the previous; an SE3 log Jacobian of 1e6 elements is 288 MB and its fresh pages cost 1.3x the
 * call's CPU time, 1.4x its wall time at load 3: issue 19, item 17), so the cache never holds
 * more than the limit plus one block as large as the largest output the program held;
 * set_cache_limit() releases it. The cache is only touched with the GIL held (allocation here,
 * release in the capsule destructor). */
#define CACHE_MIN ((size_t)1 << 20)
#define CACHE_SLOTS 8
#define HUGE ((size_t)2 << 20) /* blocks are rounded up to whole 2 MiB (transparent huge) pages */

typedef struct {
    void *p;
    size_t cap;
} block;
static block cache[CACHE_SLOTS];
static block big; /* the large block (cap > cache_limit), or p == NULL */
static int ncache;
static size_t cache_bytes, cache_limit = (size_t)256 << 20;

static void big_release(void) {
    free(big.p);
    big.p = NULL;
    big.cap = 0;
}

static void cache_evict_oldest(void) {
    free(cache[0].p);
    cache_bytes -= cache[0].cap;
    for (int i = 1; i < ncache; i++) cache[i - 1] = cache[i];
    ncache--;
}

static void cache_put(void *p, size_t cap) {
    if (cap > cache_limit) {
        if (cache_limit == 0) {
            free(p);
            return;
        }
        big_release(); /* the latest large block replaces the previous one */
        big.p = p;
        big.cap = cap;
        return;
    }
    while (ncache > 0 && (ncache == CACHE_SLOTS || cache_bytes + cap > cache_limit))
        cache_evict_oldest();
    cache[ncache].p = p;
    cache[ncache].cap = cap;
    ncache++;
    cache_bytes += cap;
}

/* a block of at least n bytes: the smallest cached one that fits without wasting more than a
 * quarter, else a new one */
static void *cache_get(size_t n, size_t *cap) {
    if (big.p && big.cap >= n && big.cap - n <= n / 4 + HUGE) {
        void *p = big.p;
        *cap = big.cap;
        big.p = NULL;
        big.cap = 0;
        return p;
    }
    int best = -1;
    for (int i = 0; i < ncache; i++)
        if (cache[i].cap >= n && cache[i].cap - n <= n / 4 + HUGE &&
            (best < 0 || cache[i].cap < cache[best].cap))
            best = i;
    if (best >= 0) {
        void *p = cache[best].p;
        *cap = cache[best].cap;
        cache_bytes -= *cap;
        for (int i = best + 1; i < ncache; i++) cache[i - 1] = cache[i];
        ncache--;
        return p;
    }
    *cap = (n + HUGE - 1) / HUGE * HUGE;
    void *p = aligned_alloc(HUGE, *cap);
#if defined(__linux__) && defined(MADV_HUGEPAGE)
    if (p) madvise(p, *cap, MADV_HUGEPAGE);
#endif
    return p;
}

static void cache_release(PyObject *capsule) {
    void *p = PyCapsule_GetPointer(capsule, "microlie._c.block");
    size_t cap = (size_t)(uintptr_t)PyCapsule_GetContext(capsule);
    if (p) cache_put(p, cap);
}

static PyObject *new_output(int nd, npy_intp *dims, int type) {
    size_t n = (size_t)PyArray_MultiplyList(dims, nd) * (type == NPY_FLOAT ? 4 : 8);
    if (n < CACHE_MIN || cache_limit == 0) return PyArray_SimpleNew(nd, dims, type);
    size_t cap;
    void *p = cache_get(n, &cap);
    if (!p) return PyErr_NoMemory();
    PyObject *capsule = PyCapsule_New(p, "microlie._c.block", cache_release);
    if (!capsule || PyCapsule_SetContext(capsule, (void *)(uintptr_t)cap) < 0) {
        Py_XDECREF(capsule);
        cache_put(p, cap);
        return NULL;
    }
    PyObject *a = PyArray_New(&PyArray_Type, nd, dims, type, NULL, p, 0, NPY_ARRAY_CARRAY, NULL);
    if (!a) {
        Py_DECREF(capsule); /* returns the block */
        return NULL;
    }
    if (PyArray_SetBaseObject((PyArrayObject *)a, capsule) < 0) { /* steals capsule */
        Py_DECREF(a);
        return NULL;
    }
    return a;
}

static PyObject *set_cache_limit(PyObject *self, PyObject *arg) {
    (void)self;
    long long mb = PyLong_AsLongLong(arg);
    if (mb == -1 && PyErr_Occurred()) return NULL;
    if (mb < 0) {
        PyErr_SetString(PyExc_ValueError, "set_cache_limit: the limit (MB) must be >= 0");
        return NULL;
    }
    long long old = (long long)(cache_limit >> 20);
    cache_limit = (size_t)mb << 20;
    while (ncache > 0 && cache_bytes > cache_limit) cache_evict_oldest();
    big_release();
    return PyLong_FromLongLong(old);
}

static PyObject *cache_info(PyObject *self, PyObject *unused) {
    (void)self;
    (void)unused;
    return Py_BuildValue("{s:n,s:n,s:n,s:n}", "blocks", (Py_ssize_t)ncache, "bytes",
                         (Py_ssize_t)cache_bytes, "limit", (Py_ssize_t)cache_limit, "large",
                         (Py_ssize_t)big.cap);
}

static PyObject *call(const kernel *k, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != k->nin) {
        PyErr_Format(PyExc_TypeError, "%s: expected %d arguments, got %zd", k->name, k->nin,
                     nargs);
        return NULL;
    }
    ix n = -1;
    int type = -1;
    char *in[2];
    for (int a = 0; a < k->nin; a++) {
        PyObject *o = args[a];
        if (!PyArray_Check(o)) {
            PyErr_Format(PyExc_TypeError, "%s: argument %d is not a NumPy array", k->name, a);
            return NULL;
        }
        PyArrayObject *x = (PyArrayObject *)o;
        int t = PyArray_TYPE(x);
        if ((t != NPY_DOUBLE && t != NPY_FLOAT) || (type >= 0 && t != type) ||
            PyArray_NDIM(x) != 2 || PyArray_DIM(x, 1) != k->kin[a] ||
            !PyArray_IS_C_CONTIGUOUS(x) || (n >= 0 && PyArray_DIM(x, 0) != n)) {
            PyErr_Format(PyExc_ValueError,
                         "%s: argument %d must be a C-contiguous float64 or float32 array of "
                         "shape (N, %d), with the same N and dtype as the other arguments",
                         k->name, a, k->kin[a]);
            return NULL;
        }
        type = t;
        n = PyArray_DIM(x, 0);
        in[a] = PyArray_BYTES(x);
    }
    PyObject *res = PyTuple_New(k->nout);
    if (!res) return NULL;
    char *out[3];
    for (int j = 0; j < k->nout; j++) {
        npy_intp dims[3] = {n, k->rows[j], k->cols[j]};
        PyObject *o = new_output(k->cols[j] ? 3 : 2, dims, type);
        if (!o) {
            Py_DECREF(res);
            return NULL;
        }
        PyTuple_SET_ITEM(res, j, o);
        out[j] = PyArray_BYTES((PyArrayObject *)o);
    }
    int f32 = type == NPY_FLOAT;
    if (n > 4 * S) {
        Py_BEGIN_ALLOW_THREADS
        evaluate(k, f32, n, in, out);
        Py_END_ALLOW_THREADS
    } else {
        evaluate(k, f32, n, in, out);
    }
    return res;
}

/* the block function of an element operation of lie_math.h; input 0 occupies rows 0..KA-1 */
#define BLOCK(FN, KA)                                                                          \
    LM_HOT static void blk_##FN(const double *restrict in, double *restrict out, ix m) {               \
        _Pragma("omp simd") for (ix j = 0; j < m; j++) FN(in + j, in + (KA) * S + j, out + j);  \
    }

/* row loops of the cheap operations (quaternion products): as fast as the native loop, while
 * the copies to and from blocks would double their time */
#define PLAIN(FN, KA, KB, KO, BODY)                                                            \
    LM_HOT static void pl_##FN(const double *restrict a, const double *restrict b, double *restrict o,  \
                        ix n) {                                                                \
        (void)b;                                                                               \
        _Pragma("omp simd") for (ix i = 0; i < n; i++) {                                       \
            const double *x = a + (KA) * i, *y = b + (KB) * i;                                 \
            double *r = o + (KO) * i;                                                          \
            (void)y;                                                                           \
            BODY;                                                                              \
        }                                                                                      \
    }
PLAIN(so3_inverse, 4, 0, 4, quat_conj(x, r))
PLAIN(so3_compose, 4, 4, 4, quat_mul(x, y, r))
PLAIN(so3_between, 4, 4, 4, double c[4]; quat_conj(x, c); quat_mul(c, y, r))
PLAIN(se3_inverse, 7, 0, 7, se3_inverse_l(x, r))
PLAIN(se3_compose, 7, 7, 7, se3_compose_l(x, y, r))
PLAIN(se3_between, 7, 7, 7, double xi[7]; se3_inverse_l(x, xi); se3_compose_l(xi, y, r))
PLAIN(sim3_inverse, 8, 0, 8, sim3_inverse_l(x, r))
PLAIN(sim3_compose, 8, 8, 8, sim3_compose_l(x, y, r))
PLAIN(sim3_between, 8, 8, 8, double xi[8]; sim3_inverse_l(x, xi); sim3_compose_l(xi, y, r))
PLAIN(sim3_act, 8, 3, 3, sim3_act_l(x, y, r))
PLAIN(so3_exp, 3, 0, 4, so3_exp_l(x, r))
static inline void so3_log_row(const double *q, double *phi) {
    double kl, aw;
    quat_log(q, phi, &kl, &aw);
}
PLAIN(so3_log, 4, 0, 3, so3_log_row(x, r))
PLAIN(so3_act, 4, 3, 3, quat_rotate(x, y, r))
PLAIN(se3_act, 7, 3, 3, quat_rotate(x + 3, y, r); r[0] += x[0]; r[1] += x[1]; r[2] += x[2])

#define KERNELS(X)                                                                             \
    X(so3_log_jac, "SO3.log_jac", 1, 4, 0, 2, 3, 3, 0, 0, 3, 0, 0)                            \
    X(so3_matrix, "SO3.matrix", 1, 4, 0, 1, 3, 0, 0, 3, 0, 0, 0)                                \
    X(so3_adjoint, "SO3.adjoint", 1, 4, 0, 1, 3, 0, 0, 3, 0, 0, 0)                              \
    X(so3_adjoint_inv, "SO3.adjoint_inv", 1, 4, 0, 1, 3, 0, 0, 3, 0, 0, 0)                      \
    X(so3_plus, "SO3.plus", 2, 4, 3, 1, 4, 0, 0, 0, 0, 0, 0)                                    \
    X(se3_log_jac, "SE3.log_jac", 1, 7, 0, 2, 6, 6, 0, 0, 6, 0, 0)                              \
    X(se3_matrix, "SE3.matrix", 1, 7, 0, 1, 4, 0, 0, 4, 0, 0, 0)                                \
    X(se3_adjoint, "SE3.adjoint", 1, 7, 0, 1, 6, 0, 0, 6, 0, 0, 0)                              \
    X(se3_adjoint_inv, "SE3.adjoint_inv", 1, 7, 0, 1, 6, 0, 0, 6, 0, 0, 0)                      \
    X(se3_plus, "SE3.plus", 2, 7, 6, 1, 7, 0, 0, 0, 0, 0, 0)                                    \
    X(so3_lplus, "SO3.lplus", 2, 4, 3, 1, 4, 0, 0, 0, 0, 0, 0)                                  \
    X(so3_lminus, "SO3.lminus", 2, 4, 4, 1, 3, 0, 0, 0, 0, 0, 0)                                \
    X(so3_plus_jac, "SO3.plus_jac", 2, 4, 3, 3, 4, 3, 3, 0, 3, 3, 0)                            \
    X(so3_lplus_jac, "SO3.lplus_jac", 2, 4, 3, 2, 4, 3, 0, 0, 3, 0, 0)                          \
    X(so3_lminus_jac, "SO3.lminus_jac", 2, 4, 4, 3, 3, 3, 3, 0, 3, 3, 0)                        \
    X(se3_lplus, "SE3.lplus", 2, 7, 6, 1, 7, 0, 0, 0, 0, 0, 0)                                  \
    X(se3_lminus, "SE3.lminus", 2, 7, 7, 1, 6, 0, 0, 0, 0, 0, 0)                                \
    X(se3_plus_jac, "SE3.plus_jac", 2, 7, 6, 3, 7, 6, 6, 0, 6, 6, 0)                            \
    X(se3_lplus_jac, "SE3.lplus_jac", 2, 7, 6, 2, 7, 6, 0, 0, 6, 0, 0)                          \
    X(se3_lminus_jac, "SE3.lminus_jac", 2, 7, 7, 3, 6, 6, 6, 0, 6, 6, 0)                        \
    X(so3_exp, "SO3.exp", 1, 3, 0, 1, 4, 0, 0, 0, 0, 0, pl_so3_exp)                                     \
    X(so3_log, "SO3.log", 1, 4, 0, 1, 3, 0, 0, 0, 0, 0, pl_so3_log)                                     \
    X(so3_inverse, "SO3.inverse", 1, 4, 0, 1, 4, 0, 0, 0, 0, 0, pl_so3_inverse)                \
    X(so3_compose, "SO3.compose", 2, 4, 4, 1, 4, 0, 0, 0, 0, 0, pl_so3_compose)                \
    X(so3_between, "SO3.between", 2, 4, 4, 1, 4, 0, 0, 0, 0, 0, pl_so3_between)                \
    X(so3_act, "SO3.act", 2, 4, 3, 1, 3, 0, 0, 0, 0, 0, pl_so3_act)                                     \
    X(so3_minus, "SO3.minus", 2, 4, 4, 1, 3, 0, 0, 0, 0, 0, 0)                                 \
    X(so3_jr, "SO3.jr", 1, 3, 0, 1, 3, 0, 0, 3, 0, 0, 0)                                       \
    X(so3_jr_inv, "SO3.jr_inv", 1, 3, 0, 1, 3, 0, 0, 3, 0, 0, 0)                               \
    X(so3_exp_jac, "SO3.exp_jac", 1, 3, 0, 2, 4, 3, 0, 0, 3, 0, 0)                             \
    X(so3_act_jac, "SO3.act_jac", 2, 4, 3, 3, 3, 3, 3, 0, 3, 3, 0)                             \
    X(so3_inverse_jac, "SO3.inverse_jac", 1, 4, 0, 2, 4, 3, 0, 0, 3, 0, 0)                     \
    X(so3_compose_jac, "SO3.compose_jac", 2, 4, 4, 2, 4, 3, 0, 0, 3, 0, 0)                     \
    X(so3_between_jac, "SO3.between_jac", 2, 4, 4, 2, 4, 3, 0, 0, 3, 0, 0)                     \
    X(so3_minus_jac, "SO3.minus_jac", 2, 4, 4, 3, 3, 3, 3, 0, 3, 3, 0)                         \
    X(se3_exp, "SE3.exp", 1, 6, 0, 1, 7, 0, 0, 0, 0, 0, 0)                                     \
    X(se3_log, "SE3.log", 1, 7, 0, 1, 6, 0, 0, 0, 0, 0, 0)                                     \
    X(se3_inverse, "SE3.inverse", 1, 7, 0, 1, 7, 0, 0, 0, 0, 0, pl_se3_inverse)                \
    X(se3_compose, "SE3.compose", 2, 7, 7, 1, 7, 0, 0, 0, 0, 0, pl_se3_compose)                \
    X(se3_between, "SE3.between", 2, 7, 7, 1, 7, 0, 0, 0, 0, 0, pl_se3_between)                \
    X(se3_act, "SE3.act", 2, 7, 3, 1, 3, 0, 0, 0, 0, 0, pl_se3_act)                                     \
    X(se3_minus, "SE3.minus", 2, 7, 7, 1, 6, 0, 0, 0, 0, 0, 0)                                 \
    X(se3_jr, "SE3.jr", 1, 6, 0, 1, 6, 0, 0, 6, 0, 0, 0)                                       \
    X(se3_jr_inv, "SE3.jr_inv", 1, 6, 0, 1, 6, 0, 0, 6, 0, 0, 0)                               \
    X(se3_exp_jac, "SE3.exp_jac", 1, 6, 0, 2, 7, 6, 0, 0, 6, 0, 0)                             \
    X(se3_act_jac, "SE3.act_jac", 2, 7, 3, 3, 3, 3, 3, 0, 6, 3, 0)                             \
    X(se3_inverse_jac, "SE3.inverse_jac", 1, 7, 0, 2, 7, 6, 0, 0, 6, 0, 0)                     \
    X(se3_compose_jac, "SE3.compose_jac", 2, 7, 7, 2, 7, 6, 0, 0, 6, 0, 0)                     \
    X(se3_between_jac, "SE3.between_jac", 2, 7, 7, 2, 7, 6, 0, 0, 6, 0, 0)                     \
    X(se3_minus_jac, "SE3.minus_jac", 2, 7, 7, 3, 6, 6, 6, 0, 6, 6, 0)                         \
    X(sim3_exp, "Sim3.exp", 1, 7, 0, 1, 8, 0, 0, 0, 0, 0, 0)                                   \
    X(sim3_log, "Sim3.log", 1, 8, 0, 1, 7, 0, 0, 0, 0, 0, 0)                                   \
    X(sim3_compose, "Sim3.compose", 2, 8, 8, 1, 8, 0, 0, 0, 0, 0, pl_sim3_compose)                           \
    X(sim3_inverse, "Sim3.inverse", 1, 8, 0, 1, 8, 0, 0, 0, 0, 0, pl_sim3_inverse)                           \
    X(sim3_between, "Sim3.between", 2, 8, 8, 1, 8, 0, 0, 0, 0, 0, pl_sim3_between)                           \
    X(sim3_act, "Sim3.act", 2, 8, 3, 1, 3, 0, 0, 0, 0, 0, pl_sim3_act)                                   \
    X(sim3_minus, "Sim3.minus", 2, 8, 8, 1, 7, 0, 0, 0, 0, 0, 0)                               \
    X(sim3_plus, "Sim3.plus", 2, 8, 7, 1, 8, 0, 0, 0, 0, 0, 0)                                 \
    X(sim3_matrix, "Sim3.matrix", 1, 8, 0, 1, 4, 0, 0, 4, 0, 0, 0)                             \
    X(sim3_adjoint, "Sim3.adjoint", 1, 8, 0, 1, 7, 0, 0, 7, 0, 0, 0)                           \
    X(sim3_act_jac, "Sim3.act_jac", 2, 8, 3, 3, 3, 3, 3, 0, 7, 3, 0)                           \
    X(sim3_jr, "Sim3.jr", 1, 7, 0, 1, 7, 0, 0, 7, 0, 0, 0)                                     \
    X(sim3_jr_inv, "Sim3.jr_inv", 1, 7, 0, 1, 7, 0, 0, 7, 0, 0, 0)                             \
    X(sim3_exp_jac, "Sim3.exp_jac", 1, 7, 0, 2, 8, 7, 0, 0, 7, 0, 0)                           \
    X(sim3_log_jac, "Sim3.log_jac", 1, 8, 0, 2, 7, 7, 0, 0, 7, 0, 0)                           \
    X(sim3_minus_jac, "Sim3.minus_jac", 2, 8, 8, 3, 7, 7, 7, 0, 7, 7, 0)                       \
    X(sim3_between_jac, "Sim3.between_jac", 2, 8, 8, 2, 8, 7, 0, 0, 7, 0, 0)                   \
    X(sim3_compose_jac, "Sim3.compose_jac", 2, 8, 8, 2, 8, 7, 0, 0, 7, 0, 0)                   \
    X(sim3_adjoint_inv, "Sim3.adjoint_inv", 1, 8, 0, 1, 7, 0, 0, 7, 0, 0, 0)                   \
    X(sim3_inverse_jac, "Sim3.inverse_jac", 1, 8, 0, 2, 8, 7, 0, 0, 7, 0, 0)                   \
    X(sim3_lplus, "Sim3.lplus", 2, 8, 7, 1, 8, 0, 0, 0, 0, 0, 0)                               \
    X(sim3_lminus, "Sim3.lminus", 2, 8, 8, 1, 7, 0, 0, 0, 0, 0, 0)                             \
    X(sim3_plus_jac, "Sim3.plus_jac", 2, 8, 7, 3, 8, 7, 7, 0, 7, 7, 0)                         \
    X(sim3_lplus_jac, "Sim3.lplus_jac", 2, 8, 7, 2, 8, 7, 0, 0, 7, 0, 0)                       \
    X(sim3_lminus_jac, "Sim3.lminus_jac", 2, 8, 8, 3, 7, 7, 7, 0, 7, 7, 0)

#define DEFINE(FN, NAME, NIN, KA, KB, NOUT, R0, R1, R2, C0, C1, C2, PLAIN)                    \
    BLOCK(FN, KA)                                                                              \
    static const kernel k_##FN = {NAME, NIN, {KA, KB}, NOUT, {R0, R1, R2}, {C0, C1, C2},       \
                                  blk_##FN, PLAIN};                                            \
    static PyObject *py_##FN(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {       \
        (void)self;                                                                            \
        return call(&k_##FN, args, nargs);                                                     \
    }
KERNELS(DEFINE)

#define ENTRY(FN, NAME, ...) {#FN, (PyCFunction)(void (*)(void))py_##FN, METH_FASTCALL, NAME},
static PyMethodDef methods[] = {
    KERNELS(ENTRY)
    {"set_cache_limit", set_cache_limit, METH_O,
     "set_cache_limit(mb) -> the previous limit: bytes of freed large outputs kept for reuse "
     "(0: none), plus the latest freed block above it; also releases that block"},
    {"cache_info", cache_info, METH_NOARGS,
     "cache_info() -> {'blocks', 'bytes', 'limit', 'large'} of the output cache ('large': "
     "bytes of the kept block above the limit)"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_lie",
                                    "Compiled SO(3)/SE(3)/Sim(3) kernels for microlie.", -1, methods};

PyMODINIT_FUNC PyInit__lie(void) {
    import_array();
    PyObject *m = PyModule_Create(&module);
    if (!m) return NULL;
    const char *env = getenv("MICROLIE_FAST_CACHE_MB");
    if (env && *env) {
        char *end;
        long long mb = strtoll(env, &end, 10);
        if (*end || mb < 0) {
            PyErr_Format(PyExc_ValueError,
                         "MICROLIE_FAST_CACHE_MB must be a whole number of megabytes >= 0, got "
                         "'%s'", env);
            Py_DECREF(m);
            return NULL;
        }
        cache_limit = (size_t)mb << 20;
    }
    /* KERNELS: registry name -> function name, e.g. {"SE3.exp": "se3_exp"} */
    PyObject *d = PyDict_New();
    if (!d || PyModule_AddObject(m, "KERNELS", d) < 0) {
        Py_XDECREF(d);
        Py_DECREF(m);
        return NULL;
    }
#define ADD(FN, NAME, ...)                                                                     \
    {                                                                                          \
        PyObject *s = PyUnicode_FromString(#FN);                                               \
        if (!s || PyDict_SetItemString(d, NAME, s) < 0) {                                      \
            Py_XDECREF(s);                                                                     \
            Py_DECREF(m);                                                                      \
            return NULL;                                                                       \
        }                                                                                      \
        Py_DECREF(s);                                                                          \
    }
    KERNELS(ADD)
    return m;
}
