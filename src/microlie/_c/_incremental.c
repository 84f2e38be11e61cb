/* microlie._c._incremental: the Bayes tree operations of microlie.optim.online.bayes_tree
 * (IncrementalSmoother) in one C call each: detach the top, re-eliminate it, back-substitute.
 *
 * The tree is the Python module's: per node the int64 arrays parent, child (first child), sib
 * (next sibling), dof, off (step offset), pos (elimination position); per node the Python lists
 * sep (int64 arrays), Rinv (d x d), T (d x s), c (d), Hs (s x s), bs (s), all C-contiguous
 * float64, s the separator's columns; per row rnodes (int64 arrays, None when removed), rH, rb.
 * The conditional of node j is x_j = Rinv_j (c_j - T_j x_sep). Scratch arrays (mark, loc, chg,
 * rseen) are 0 / -1 / 0 / 0 between calls and are restored before returning.
 *
 * Elimination is multifrontal by cliques: a node and the nodes after it in its front that come
 * next in the order and add no node of their own (each nested in the next, chain = 1; they keep
 * no Schur complement) are one front of K frontal columns and s separator columns, assembled
 * column-major (lower triangle) and factored by front_factor: dpotrf, dtrsm, dsyrk, dtrsv and
 * dgemv of the BLAS/LAPACK SciPy ships from BLAS_MIN entries of the panel (else loops):
 * L11, L21, F_22 -= L21 L21^T, y = L11^-1 g_1, g_2 -= L21 y. Each frontal variable's
 * conditional is then Rinv = L_ii^-T, T = its columns of L below its block (transposed),
 * c = its part of y; the clique root's Schur complement Hs keeps its upper triangle
 * (row-major; the lower is 0): the same numbers as the
 * NumPy fallback's one-variable fronts (bayes_tree.BayesTree.eliminate) up to rounding. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <numpy/arrayobject.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "dispatch.h"

typedef npy_int64 i64;

/* The BLAS and LAPACK SciPy links (Fortran convention, 32-bit integers, no hidden string
 * lengths: scipy.linalg.cython_blas / cython_lapack), from the capsules set_blas receives
 * (bayes_tree.py, once). NULL: the plain loops below. */
typedef void (*potrf_t)(char *, int *, double *, int *, int *);
typedef void (*trsm_t)(char *, char *, char *, char *, int *, int *, double *, double *, int *,
                       double *, int *);
typedef void (*syrk_t)(char *, char *, int *, int *, double *, double *, int *, double *,
                       double *, int *);
typedef void (*gemv_t)(char *, int *, int *, double *, double *, int *, double *, int *,
                       double *, double *, int *);
typedef void (*trsv_t)(char *, char *, char *, int *, double *, int *, double *, int *);
static potrf_t g_potrf = NULL;
static trsm_t g_trsm = NULL;
static syrk_t g_syrk = NULL;
static gemv_t g_gemv = NULL;
static trsv_t g_trsv = NULL;
/* fronts of fewer than this many frontal columns times front width take the loops (the five
 * calls' fixed cost wins below: factor_front, blas True / False, crosses over near K w = 600
 * for K = 6 .. 18) */
#define BLAS_MIN 640

/* The partial Cholesky of a front of width w with K frontal columns, in place: the front
 * [A11 .; A21 A22] (lower triangles read and written) is held as the panel P = [A11; A21]
 * (column-major, w x K, leading dimension w) and the trailing block S = A22 (column-major,
 * s x s, leading dimension lds, s = w - K); g = [g1; g2]. A11 = L11 L11^T, L21 = A21 L11^-T,
 * A22 -= L21 L21^T, y = L11^-1 g1 (in g1), g2 -= L21 y. use_blas: dpotrf, dtrsm, dsyrk, dtrsv,
 * dgemv when set_blas ran (else the loops). Returns -1, or the first frontal column whose
 * pivot is not positive (the front then partly overwritten). */
LM_HOT static i64 front_factor(double *P, double *S, i64 lds, double *g, i64 w, i64 K,
                               int use_blas) {
    i64 s = w - K;
    if (K <= 0) return -1;
    if (use_blas && g_potrf && w <= 46340 && lds <= 46340) { /* 32-bit BLAS integers */
        char cL = 'L', cR = 'R', cT = 'T', cN = 'N';
        int k_ = (int)K, s_ = (int)s, ld = (int)w, ldS = (int)(lds > 0 ? lds : 1), info = 0,
            inc = 1;
        double one = 1.0, mone = -1.0;
        g_potrf(&cL, &k_, P, &ld, &info);
        if (info != 0) return info > 0 ? (i64)info - 1 : 0;
        g_trsv(&cL, &cN, &cN, &k_, P, &ld, g, &inc);
        if (s > 0) {
            g_trsm(&cR, &cL, &cT, &cN, &s_, &k_, &one, P, &ld, P + K, &ld);
            g_syrk(&cL, &cN, &s_, &k_, &mone, P + K, &ld, &one, S, &ldS);
            g_gemv(&cN, &s_, &k_, &mone, P + K, &ld, g, &inc, &one, g + K, &inc);
        }
        return -1;
    }
    /* right-looking by columns: column c scaled, then the frontal columns after it updated
     * (contiguous), then the trailing block by a rank-1 update of its columns */
    for (i64 c = 0; c < K; c++) {
        double *Ac = P + c * w;
        double dv = Ac[c];
        if (!(dv > 0.0)) return c;
        dv = sqrt(dv);
        Ac[c] = dv;
        double r = 1.0 / dv;
        for (i64 a = c + 1; a < w; a++) Ac[a] *= r;
        g[c] *= r;
        double y = g[c];
        for (i64 a = c + 1; a < w; a++) g[a] -= Ac[a] * y;
        for (i64 c2 = c + 1; c2 < K; c2++) {
            double *Ad = P + c2 * w;
            double l = Ac[c2];
            for (i64 a = c2; a < w; a++) Ad[a] -= l * Ac[a];
        }
        const double *Lc = Ac + K;
        for (i64 c2 = 0; c2 < s; c2++) {
            double *Sd = S + c2 * lds;
            double l = Lc[c2];
            for (i64 a = c2; a < s; a++) Sd[a] -= l * Lc[a];
        }
    }
    return -1;
}

/* ------------------------------------------------------------------ helpers */

static void *arr(PyObject *o, int type, const char *what, i64 *size) {
    if (!PyArray_Check(o) || PyArray_TYPE((PyArrayObject *)o) != type ||
        !PyArray_IS_C_CONTIGUOUS((PyArrayObject *)o)) {
        PyErr_Format(PyExc_TypeError, "%s must be a C-contiguous %s array", what,
                     type == NPY_FLOAT64 ? "float64" : "int64");
        return NULL;
    }
    if (size) { /* the product of the dimensions inline (PyArray_SIZE is a call) */
        PyArrayObject *a = (PyArrayObject *)o;
        i64 n = 1;
        for (int k = 0; k < PyArray_NDIM(a); k++) n *= (i64)PyArray_DIMS(a)[k];
        *size = n;
    }
    return PyArray_DATA((PyArrayObject *)o);
}

static int is_list(PyObject *o, const char *what) {
    if (!PyList_Check(o)) {
        PyErr_Format(PyExc_TypeError, "%s must be a list", what);
        return 0;
    }
    return 1;
}

/* a growable int64 buffer */
typedef struct {
    i64 *p;
    i64 n, cap;
} ibuf;

static int ipush(ibuf *b, i64 v) {
    if (b->n == b->cap) {
        i64 cap = b->cap ? 2 * b->cap : 64;
        i64 *p = realloc(b->p, (size_t)cap * sizeof(i64));
        if (!p) return -1;
        b->p = p;
        b->cap = cap;
    }
    b->p[b->n++] = v;
    return 0;
}

static PyObject *to_array(const ibuf *b) {
    npy_intp n = (npy_intp)b->n;
    PyObject *a = PyArray_SimpleNew(1, &n, NPY_INT64);
    if (a && n) memcpy(PyArray_DATA((PyArrayObject *)a), b->p, (size_t)n * sizeof(i64));
    return a;
}

/* the i64 data of list[k] (an int64 array), or NULL with an error */
static i64 *item_i64(PyObject *list, i64 k, const char *what, i64 *n) {
    if (k < 0 || k >= (i64)PyList_GET_SIZE(list)) {
        PyErr_Format(PyExc_IndexError, "%s: index %lld out of range", what, (long long)k);
        return NULL;
    }
    return arr(PyList_GET_ITEM(list, k), NPY_INT64, what, n);
}

static double *item_f64(PyObject *list, i64 k, const char *what, i64 want) {
    if (k < 0 || k >= (i64)PyList_GET_SIZE(list)) {
        PyErr_Format(PyExc_IndexError, "%s: index %lld out of range", what, (long long)k);
        return NULL;
    }
    i64 n = 0;
    double *p = arr(PyList_GET_ITEM(list, k), NPY_FLOAT64, what, &n);
    if (p && n != want) {
        PyErr_Format(PyExc_ValueError, "%s[%lld] has %lld entries, expected %lld", what,
                     (long long)k, (long long)n, (long long)want);
        return NULL;
    }
    return p;
}

/* ------------------------------------------------------------------ detach */

static PyObject *detach(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 9) {
        PyErr_SetString(PyExc_TypeError, "detach(marked, parent, child, sib, mark, rseen, "
                                         "node_rows, rnodes, chain)");
        return NULL;
    }
    i64 nm, N, nr;
    i64 *marked = arr(args[0], NPY_INT64, "marked", &nm);
    i64 *parent = marked ? arr(args[1], NPY_INT64, "parent", &N) : NULL;
    i64 *child = parent ? arr(args[2], NPY_INT64, "child", NULL) : NULL;
    i64 *sib = child ? arr(args[3], NPY_INT64, "sib", NULL) : NULL;
    i64 *mark = sib ? arr(args[4], NPY_INT64, "mark", NULL) : NULL;
    i64 *rseen = mark ? arr(args[5], NPY_INT64, "rseen", &nr) : NULL;
    if (!rseen || !is_list(args[6], "node_rows") || !is_list(args[7], "rnodes")) return NULL;
    i64 *chain = arr(args[8], NPY_INT64, "chain", NULL);
    if (!chain) return NULL;
    PyObject *node_rows = args[6], *rnodes = args[7];
    ibuf top = {0}, orph = {0}, rows = {0}, seen = {0};
    PyObject *out = NULL;
    int err = 0;
    for (i64 q = 0; q < nm && !err; q++) {
        i64 n = marked[q];
        if (n < -1 || n >= N) {
            PyErr_SetString(PyExc_IndexError, "marked: node out of range");
            err = 1;
            break;
        }
        while (n >= 0 && !mark[n]) {
            mark[n] = 1;
            if (ipush(&top, n)) err = 1;
            n = parent[n];
        }
    }
    for (i64 q = 0; q < top.n && !err; q++) /* whole cliques: the nested children too */
        for (i64 ch = child[top.p[q]]; ch >= 0 && !err; ch = sib[ch])
            if (chain[ch] && !mark[ch]) {
                mark[ch] = 1;
                if (ipush(&top, ch)) err = 1;
            }
    for (i64 q = 0; q < top.n && !err; q++) {
        i64 n = top.p[q];
        for (i64 ch = child[n]; ch >= 0;) {
            i64 next = sib[ch];
            if (!mark[ch]) {
                if (ipush(&orph, ch)) err = 1;
                parent[ch] = -1;
                sib[ch] = -1;
            }
            ch = next;
        }
        if (n >= (i64)PyList_GET_SIZE(node_rows)) {
            PyErr_SetString(PyExc_IndexError, "node_rows: node out of range");
            err = 1;
            break;
        }
        PyObject *lst = PyList_GET_ITEM(node_rows, n);
        if (!is_list(lst, "node_rows[n]")) {
            err = 1;
            break;
        }
        for (Py_ssize_t a = 0; a < PyList_GET_SIZE(lst) && !err; a++) {
            i64 r = PyLong_AsLongLong(PyList_GET_ITEM(lst, a));
            if (r < 0 || r >= nr) {
                if (!PyErr_Occurred()) PyErr_SetString(PyExc_IndexError, "row out of range");
                err = 1;
                break;
            }
            if (rseen[r]) continue;
            rseen[r] = 1;
            if (ipush(&seen, r)) {
                err = 1;
                break;
            }
            i64 k;
            i64 *nd = item_i64(rnodes, r, "rnodes", &k);
            if (!nd) {
                err = 1;
                break;
            }
            int all = 1;
            for (i64 t = 0; t < k; t++)
                if (nd[t] < 0 || nd[t] >= N || !mark[nd[t]]) {
                    all = 0;
                    break;
                }
            if (all && ipush(&rows, r)) err = 1;
        }
    }
    for (i64 q = 0; q < top.n; q++) { /* after every child list was read */
        i64 n = top.p[q];
        child[n] = parent[n] = sib[n] = -1;
        mark[n] = 0;
    }
    for (i64 q = 0; q < seen.n; q++) rseen[seen.p[q]] = 0;
    if (!err) {
        PyObject *a = to_array(&top), *b = to_array(&orph), *c = to_array(&rows);
        if (a && b && c) out = PyTuple_Pack(3, a, b, c);
        Py_XDECREF(a);
        Py_XDECREF(b);
        Py_XDECREF(c);
    } else if (!PyErr_Occurred())
        PyErr_NoMemory();
    free(top.p);
    free(orph.p);
    free(rows.p);
    free(seen.p);
    return out;
}

/* ------------------------------------------------------------------ eliminate */

typedef struct {
    const i64 *nodes;
    i64 nn;
    const double *H, *b;
    i64 who, next; /* who: the node whose subtree this is (-1: a factor row) */
} item;

static PyObject *new2(i64 r, i64 c) {
    npy_intp dims[2] = {(npy_intp)r, (npy_intp)c};
    return PyArray_SimpleNew(2, dims, NPY_FLOAT64);
}
static PyObject *new1(i64 n, int type) {
    npy_intp dims[1] = {(npy_intp)n};
    return PyArray_SimpleNew(1, dims, type);
}

/* list[k] when it is a C-contiguous array of this type and shape (ndim 1: r entries; 2: r x c)
 * owning its data and held by the list alone, with a new reference (the caller overwrites it:
 * no allocation); else a new array */
static PyObject *reuse(PyObject *list, i64 k, int type, int nd, i64 r, i64 c) {
    PyObject *o = PyList_GET_ITEM(list, k);
    if (o && PyArray_CheckExact(o) && Py_REFCNT(o) == 1) {
        PyArrayObject *a = (PyArrayObject *)o;
        if (PyArray_TYPE(a) == type && PyArray_NDIM(a) == nd && PyArray_BASE(a) == NULL &&
            PyArray_CHKFLAGS(a, NPY_ARRAY_OWNDATA | NPY_ARRAY_C_CONTIGUOUS | NPY_ARRAY_WRITEABLE) &&
            PyArray_DIMS(a)[0] == (npy_intp)r && (nd == 1 || PyArray_DIMS(a)[1] == (npy_intp)c)) {
            Py_INCREF(o);
            return o;
        }
    }
    return nd == 2 ? new2(r, c) : new1(r, type);
}

/* the column fc of the front (its rows from shift on): the panel's (fc < K) or the trailing
 * block's */
static inline double *front_col(double *P, i64 w, double *S, i64 s, i64 K, i64 fc, i64 *shift) {
    if (fc < K) {
        *shift = 0;
        return P + fc * w;
    }
    *shift = K;
    return S + (fc - K) * s;
}

/* front += H, g += b for an item: runs (item offset, front offset, length), in front order,
 * of item columns contiguous both in the item and in the front; the front as front_factor's
 * P (w x K) and S (s x s), lower triangles; H read in its row-major upper triangle only (a
 * run pair in the item's reverse order by columns of H, strided) */
LM_HOT static void add_runs(double *P, i64 w, double *S, i64 s, i64 K, double *g,
                            const double *H, const double *b, i64 m, const i64 *runs, i64 nr) {
    for (i64 q = 0; q < nr; q++) {
        i64 i0 = runs[3 * q], f0 = runs[3 * q + 1], len = runs[3 * q + 2];
        for (i64 r = 0; r < len; r++) {
            i64 ci = i0 + r, shift;
            const double *Hr = H + ci * m;
            double *Fc = front_col(P, w, S, s, K, f0 + r, &shift);
            for (i64 q2 = q; q2 < nr; q2++) {
                i64 skip = q2 == q ? r : 0, n = runs[3 * q2 + 2] - skip, j0 = runs[3 * q2] + skip;
                double *dst = Fc + runs[3 * q2 + 1] + skip - shift;
                if (j0 >= ci) {
                    const double *src = Hr + j0;
                    for (i64 t = 0; t < n; t++) dst[t] += src[t];
                } else {
                    const double *src = H + j0 * m + ci;
                    for (i64 t = 0; t < n; t++) dst[t] += src[t * m];
                }
            }
            g[f0 + r] += b[ci];
        }
    }
}

/* the front's scratch (the panel and g: w * K + w doubles), grown as needed and kept between
 * calls (the GIL is held throughout; at most twice the largest panel stays allocated) */
static double *g_front = NULL;
static i64 g_front_cap = 0;

static PyObject *eliminate(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 19) {
        PyErr_SetString(PyExc_TypeError,
                        "eliminate(order, rows, orphans, rnodes, rH, rb, sep, Rinv, T, c, Hs, "
                        "bs, parent, child, sib, dof, pos, loc, chain)");
        return NULL;
    }
    i64 no, nrw, nor, N;
    i64 *order = arr(args[0], NPY_INT64, "order", &no);
    i64 *rws = order ? arr(args[1], NPY_INT64, "rows", &nrw) : NULL;
    i64 *orph = rws ? arr(args[2], NPY_INT64, "orphans", &nor) : NULL;
    if (!orph) return NULL;
    for (int k = 3; k < 12; k++)
        if (!is_list(args[k], "rnodes, rH, rb, sep, Rinv, T, c, Hs and bs")) return NULL;
    PyObject *rnodes = args[3], *rH = args[4], *rb = args[5], *Lsep = args[6],
             *LRinv = args[7], *LT = args[8], *Lc = args[9], *LHs = args[10], *Lbs = args[11];
    i64 *parent = arr(args[12], NPY_INT64, "parent", &N);
    i64 *child = parent ? arr(args[13], NPY_INT64, "child", NULL) : NULL;
    i64 *sib = child ? arr(args[14], NPY_INT64, "sib", NULL) : NULL;
    i64 *dof = sib ? arr(args[15], NPY_INT64, "dof", NULL) : NULL;
    i64 *pos = dof ? arr(args[16], NPY_INT64, "pos", NULL) : NULL;
    i64 *loc = pos ? arr(args[17], NPY_INT64, "loc", NULL) : NULL;
    i64 *chain = loc ? arr(args[18], NPY_INT64, "chain", NULL) : NULL;
    if (!chain) return NULL;
    i64 nlist = (i64)PyList_GET_SIZE(Lsep);
    for (i64 q = 0; q < no; q++)
        if (order[q] < 0 || order[q] >= N || order[q] >= nlist) {
            PyErr_SetString(PyExc_IndexError, "order: node out of range");
            return NULL;
        }
    i64 cap = nrw + nor + no + 1;
    item *items = malloc((size_t)cap * sizeof(item));
    i64 *head = malloc((size_t)(N > 0 ? N : 1) * sizeof(i64));
    i64 *sepb = malloc((size_t)(N + 1) * sizeof(i64));
    i64 *io = malloc((size_t)(N > 0 ? N : 1) * sizeof(i64)); /* offsets inside an item */
    i64 *runs = malloc((size_t)(3 * (N > 0 ? N : 1)) * sizeof(i64)); /* add_runs' runs */
    i64 *perm = malloc((size_t)(N > 0 ? N : 1) * sizeof(i64));       /* an item's nodes by loc */
    double *F = g_front, *g = NULL, *Lm = NULL, *Li = NULL;
    i64 nit = 0, bad = -1;
    int err = 0;
    if (!items || !head || !sepb || !io || !runs || !perm) {
        err = 1;
        goto done;
    }
    for (i64 q = 0; q < no; q++) head[order[q]] = -1;
    /* every item waits at its first node (least pos) */
#define PUT(ND, NN, HH, BB, WHO)                                                               \
    do {                                                                                       \
        i64 first_ = -1;                                                                       \
        for (i64 t_ = 0; t_ < (NN); t_++)                                                      \
            if (first_ < 0 || pos[(ND)[t_]] < pos[first_]) first_ = (ND)[t_];                  \
        items[nit] = (item){(ND), (NN), (HH), (BB), (WHO), head[first_]};                      \
        head[first_] = nit++;                                                                  \
    } while (0)
    for (i64 q = 0; q < nrw; q++) {
        i64 r = rws[q], nn, m = 0;
        i64 *nd = item_i64(rnodes, r, "rnodes", &nn);
        if (!nd) {
            err = 1;
            goto done;
        }
        for (i64 t = 0; t < nn; t++) {
            if (nd[t] < 0 || nd[t] >= N) {
                PyErr_SetString(PyExc_IndexError, "rnodes: node out of range");
                err = 1;
                goto done;
            }
            m += dof[nd[t]];
        }
        double *H = item_f64(rH, r, "rH", m * m), *b = H ? item_f64(rb, r, "rb", m) : NULL;
        if (!b) {
            err = 1;
            goto done;
        }
        if (nn) PUT(nd, nn, H, b, -1);
    }
    for (i64 q = 0; q < nor; q++) {
        i64 o = orph[q], nn, m = 0;
        i64 *nd = item_i64(Lsep, o, "sep", &nn);
        if (!nd) {
            err = 1;
            goto done;
        }
        for (i64 t = 0; t < nn; t++) m += dof[nd[t]];
        double *H = item_f64(LHs, o, "Hs", m * m), *b = H ? item_f64(Lbs, o, "bs", m) : NULL;
        if (!b) {
            err = 1;
            goto done;
        }
        if (nn) PUT(nd, nn, H, b, o);
    }
    for (i64 q = 0; q < no; q++) {
        i64 j = order[q], ns = 0;
        /* the front: j and the union of its items' nodes, by pos */
        loc[j] = -2;
        for (i64 it = head[j]; it >= 0; it = items[it].next)
            for (i64 t = 0; t < items[it].nn; t++) {
                i64 n = items[it].nodes[t];
                if (loc[n] == -1) {
                    loc[n] = -2;
                    sepb[ns++] = n;
                }
            }
        for (i64 a = 1; a < ns; a++) { /* insertion sort by pos */
            i64 v = sepb[a], pv = pos[v], b = a - 1;
            while (b >= 0 && pos[sepb[b]] > pv) {
                sepb[b + 1] = sepb[b];
                b--;
            }
            sepb[b + 1] = v;
        }
        /* fnodes: the front's nodes, j first (sepb shifted by one) */
        for (i64 a = ns; a > 0; a--) sepb[a] = sepb[a - 1];
        sepb[0] = j;
        i64 nf = ns + 1, w = 0;
        for (i64 a = 0; a < nf; a++) {
            loc[sepb[a]] = w;
            w += dof[sepb[a]];
        }
        /* the clique: j and the nodes after it in the front that come next in the order and
         * whose own items add no node (each then nested in the next: one dense front) */
        i64 k = 1;
        while (k < nf && q + k < no && order[q + k] == sepb[k]) {
            int inside = 1;
            for (i64 it = head[sepb[k]]; it >= 0 && inside; it = items[it].next)
                for (i64 t = 0; t < items[it].nn; t++)
                    if (loc[items[it].nodes[t]] < 0) {
                        inside = 0;
                        break;
                    }
            if (!inside) break;
            k++;
        }
        i64 root = sepb[k - 1], K = loc[root] + dof[root], s = w - K;
        /* the panel (w x K) and g in the scratch, kept between calls (no fresh pages per
         * update); the trailing block directly in the root's Schur complement Hs (s x s) */
        if (w * K + w > g_front_cap) {
            free(g_front);
            g_front_cap = 2 * (w * K + w);
            F = g_front = malloc((size_t)g_front_cap * sizeof(double));
            if (!F) {
                g_front_cap = 0;
                err = 1;
                goto done;
            }
        }
        g = F + w * K;
        for (i64 c2 = 0; c2 < K; c2++) /* column-major, the lower triangle only is used */
            memset(F + c2 * w + c2, 0, (size_t)(w - c2) * sizeof(double));
        memset(g, 0, (size_t)w * sizeof(double));
        PyObject *oH = reuse(LHs, root, NPY_FLOAT64, 2, s, s),
                 *ob = oH ? reuse(Lbs, root, NPY_FLOAT64, 1, s, 0) : NULL;
        if (!ob) {
            Py_XDECREF(oH);
            err = 1;
            goto done;
        }
        double *Sm = PyArray_DATA((PyArrayObject *)oH);
        if (s) memset(Sm, 0, (size_t)(s * s) * sizeof(double));
        for (i64 f = 0; f < k; f++) {
            i64 nd = sepb[f];
            child[nd] = -1;
            for (i64 it = head[nd]; it >= 0; it = items[it].next) {
                const item *E = &items[it];
                i64 m = 0, nr = 0;
                for (i64 t = 0; t < E->nn; t++) { /* offsets; perm: the nodes by loc */
                    i64 n = E->nodes[t], u = t;
                    io[t] = m;
                    m += dof[n];
                    while (u > 0 && loc[E->nodes[perm[u - 1]]] > loc[n]) {
                        perm[u] = perm[u - 1];
                        u--;
                    }
                    perm[u] = t;
                }
                for (i64 u = 0; u < E->nn; u++) {
                    i64 t = perm[u], n = E->nodes[t];
                    if (nr && runs[3 * nr - 2] + runs[3 * nr - 1] == loc[n] &&
                        runs[3 * nr - 3] + runs[3 * nr - 1] == io[t])
                        runs[3 * nr - 1] += dof[n];
                    else {
                        runs[3 * nr] = io[t];
                        runs[3 * nr + 1] = loc[n];
                        runs[3 * nr + 2] = dof[n];
                        nr++;
                    }
                }
                add_runs(F, w, Sm, s, K, g, E->H, E->b, m, runs, nr);
                if (E->who >= 0) { /* a subtree hangs from nd */
                    parent[E->who] = nd;
                    sib[E->who] = child[nd];
                    child[nd] = E->who;
                }
            }
        }
        /* the partial Cholesky of the K frontal columns (BLAS-3 from BLAS_MIN) */
        i64 badcol = front_factor(F, Sm, s, g, w, K, K * w >= BLAS_MIN);
        if (badcol >= 0) {
            Py_DECREF(oH);
            Py_DECREF(ob);
            for (i64 f = 0; f < k; f++)
                if (badcol >= loc[sepb[f]] && badcol < loc[sepb[f]] + dof[sepb[f]]) bad = sepb[f];
            for (i64 a = 0; a < nf; a++) loc[sepb[a]] = -1;
            goto done;
        }
        /* each frontal variable's conditional: Rinv = L_ii^-T, T = (its columns of L below
         * its block)^T, c = its part of y */
        for (i64 f = 0; f < k; f++) {
            i64 cur = sepb[f], d = dof[cur], oi = loc[cur], si = w - oi - d, nsep = nf - f - 1;
            if (d * d * 2 > 0) {
                Lm = realloc(Lm, (size_t)(2 * d * d) * sizeof(double));
                if (!Lm) {
                    err = 1;
                    goto done;
                }
                Li = Lm + d * d;
            }
            for (i64 a = 0; a < d; a++)
                for (i64 bb = 0; bb < d; bb++)
                    Lm[a * d + bb] = bb <= a ? F[(oi + bb) * w + oi + a] : 0.0; /* oi < K */
            for (i64 a = 0; a < d; a++) { /* Li = L^-1 (lower) by forward substitution */
                for (i64 bb = 0; bb < d; bb++) Li[a * d + bb] = 0.0;
                Li[a * d + a] = 1.0 / Lm[a * d + a];
                for (i64 bb = 0; bb < a; bb++) {
                    double v = 0.0;
                    for (i64 t = bb; t < a; t++) v += Lm[a * d + t] * Li[t * d + bb];
                    Li[a * d + bb] = -v / Lm[a * d + a];
                }
            }
            PyObject *oR = reuse(LRinv, cur, NPY_FLOAT64, 2, d, d),
                     *oT = reuse(LT, cur, NPY_FLOAT64, 2, d, si),
                     *oc = reuse(Lc, cur, NPY_FLOAT64, 1, d, 0),
                     *os = reuse(Lsep, cur, NPY_INT64, 1, nsep, 0);
            if (!oR || !oT || !oc || !os) {
                Py_XDECREF(oR);
                Py_XDECREF(oT);
                Py_XDECREF(oc);
                Py_XDECREF(os);
                Py_DECREF(oH);
                Py_DECREF(ob);
                err = 1;
                goto done;
            }
            double *R = PyArray_DATA((PyArrayObject *)oR),
                   *T = PyArray_DATA((PyArrayObject *)oT),
                   *c = PyArray_DATA((PyArrayObject *)oc);
            i64 *sp = PyArray_DATA((PyArrayObject *)os);
            for (i64 a = 0; a < d; a++)
                for (i64 bb = 0; bb < d; bb++) R[a * d + bb] = Li[bb * d + a]; /* Li^T */
            for (i64 a = 0; a < d; a++)
                memcpy(T + a * si, F + (oi + a) * w + oi + d, (size_t)si * sizeof(double));
            for (i64 a = 0; a < d; a++) c[a] = g[oi + a];
            for (i64 a = 0; a < nsep; a++) sp[a] = sepb[f + 1 + a];
            PyList_SetItem(LRinv, cur, oR); /* steals the references */
            PyList_SetItem(LT, cur, oT);
            PyList_SetItem(Lc, cur, oc);
            PyList_SetItem(Lsep, cur, os);
            loc[cur] = -1;
            if (f + 1 < k) { /* nested in the next frontal variable */
                i64 nx = sepb[f + 1];
                Py_INCREF(Py_None);
                PyList_SetItem(LHs, cur, Py_None);
                Py_INCREF(Py_None);
                PyList_SetItem(Lbs, cur, Py_None);
                chain[cur] = 1;
                parent[cur] = nx;
                sib[cur] = child[nx];
                child[nx] = cur;
                continue;
            }
            /* the clique root keeps the Schur complement on its separator */
            chain[cur] = 0;
            parent[cur] = -1;
            double *Hs = Sm, *bs = PyArray_DATA((PyArrayObject *)ob);
            for (i64 p = 0; p < s; p++) bs[p] = g[K + p];
            PyList_SetItem(LHs, cur, oH); /* its row-major upper triangle = Sm's lower */
            PyList_SetItem(Lbs, cur, ob);
            for (i64 a = k; a < nf; a++) loc[sepb[a]] = -1;
            if (nsep) {
                if (nit >= cap) {
                    PyErr_SetString(PyExc_RuntimeError, "eliminate: item overflow");
                    err = 1;
                    goto done;
                }
                PUT(sp, nsep, Hs, bs, cur);
            }
        }
        q += k - 1;
    }
#undef PUT
done:
    free(items);
    free(head);
    free(sepb);
    free(io);
    free(runs);
    free(perm);
    free(Lm);
    if (err) {
        if (!PyErr_Occurred()) PyErr_NoMemory();
        return NULL;
    }
    return PyLong_FromLongLong((long long)bad);
}

/* ------------------------------------------------------------------ back-substitution */

typedef struct {
    double *dx;
    const i64 *off, *dof;
    PyObject *sep, *Rinv, *T, *c;
    double *chg;
    ibuf touched;
    double *xs; /* scratch: the separator's steps */
    i64 xcap;
} bctx;

LM_HOT static double dot(const double *a, const double *b, i64 n) {
    double acc = 0.0;
#pragma omp simd reduction(+ : acc)
    for (i64 i = 0; i < n; i++) acc += a[i] * b[i];
    return acc;
}

/* x_k = Rinv_k (c_k - T_k x_sep). keep: always keep the new value and mark k changed (a node
 * of the re-eliminated top); else keep it and mark k changed only when a component moved by
 * threshold or more, otherwise restore the old value (GTSAM's wildfire). -1 on error */
static int back_one(bctx *B, i64 k, int keep, double threshold) {
    i64 ns, d = B->dof[k];
    i64 *sp = item_i64(B->sep, k, "sep", &ns);
    if (!sp) return -1;
    if (d > 64) {
        PyErr_SetString(PyExc_ValueError, "backsubstitute: a variable of more than 64 dof");
        return -1;
    }
    i64 s = 0;
    for (i64 a = 0; a < ns; a++) s += B->dof[sp[a]];
    double *R = item_f64(B->Rinv, k, "Rinv", d * d);
    double *T = R ? item_f64(B->T, k, "T", d * s) : NULL;
    double *c = T ? item_f64(B->c, k, "c", d) : NULL;
    if (!c) return -1;
    if (s > B->xcap) {
        free(B->xs);
        B->xcap = 2 * s;
        B->xs = malloc((size_t)B->xcap * sizeof(double));
        if (!B->xs) {
            B->xcap = 0;
            PyErr_NoMemory();
            return -1;
        }
    }
    double v[64], nw[64], *xs = B->xs;
    for (i64 a = 0, col = 0; a < ns; a++) { /* the separator's steps, gathered */
        i64 n = sp[a], dn = B->dof[n];
        const double *xn = B->dx + B->off[n];
        for (i64 r = 0; r < dn; r++) xs[col + r] = xn[r];
        col += dn;
    }
    for (i64 a = 0; a < d; a++) v[a] = c[a] - dot(T + a * s, xs, s);
    double big = 0.0, *xk = B->dx + B->off[k];
    for (i64 i = 0; i < d; i++) {
        double t = 0.0;
        for (i64 a = 0; a < d; a++) t += R[i * d + a] * v[a];
        nw[i] = t;
        double e = fabs(t - xk[i]);
        if (e > big || e != e) big = e;
    }
    if (!keep && !(big >= threshold)) return 0; /* restored: not changed */
    for (i64 i = 0; i < d; i++) xk[i] = nw[i];
    B->chg[k] = 1.0;
    return ipush(&B->touched, k);
}

static PyObject *backsubstitute(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 13) {
        PyErr_SetString(PyExc_TypeError, "backsubstitute(order, orphans, dx, off, dof, sep, "
                                         "Rinv, T, c, child, sib, wildfire, chg)");
        return NULL;
    }
    i64 no, nor;
    i64 *order = arr(args[0], NPY_INT64, "order", &no);
    i64 *orph = order ? arr(args[1], NPY_INT64, "orphans", &nor) : NULL;
    double *dx = orph ? arr(args[2], NPY_FLOAT64, "dx", NULL) : NULL;
    i64 *off = dx ? arr(args[3], NPY_INT64, "off", NULL) : NULL;
    i64 *dof = off ? arr(args[4], NPY_INT64, "dof", NULL) : NULL;
    if (!dof) return NULL;
    for (int k = 5; k < 9; k++)
        if (!is_list(args[k], "sep, Rinv, T and c")) return NULL;
    i64 *child = arr(args[9], NPY_INT64, "child", NULL);
    i64 *sib = child ? arr(args[10], NPY_INT64, "sib", NULL) : NULL;
    if (!sib) return NULL;
    double wildfire = PyFloat_AsDouble(args[11]);
    if (PyErr_Occurred()) return NULL;
    double *chg = arr(args[12], NPY_FLOAT64, "chg", NULL);
    if (!chg) return NULL;
    bctx B = {dx, off, dof, args[5], args[6], args[7], args[8], chg, {0}, NULL, 0};
    ibuf stack = {0};
    i64 count = 0;
    int err = 0;
    for (i64 q = no - 1; q >= 0 && !err; q--, count++) /* the re-eliminated: root down */
        if (back_one(&B, order[q], 1, wildfire)) err = 1;
    for (i64 t = 0; t < nor && !err; t++)
        if (ipush(&stack, orph[t])) err = 1;
    while (stack.n > 0 && !err) { /* orphan subtrees: recomputed where a separator changed */
        i64 o = stack.p[--stack.n], ns;
        i64 *so = item_i64(B.sep, o, "sep", &ns);
        if (!so) {
            err = 1;
            break;
        }
        int dirty = 0;
        for (i64 a = 0; a < ns && !dirty; a++) dirty = chg[so[a]] != 0.0;
        if (!dirty) continue;
        if (back_one(&B, o, 0, wildfire)) {
            err = 1;
            break;
        }
        count++;
        for (i64 ch = child[o]; ch >= 0 && !err; ch = sib[ch])
            if (ipush(&stack, ch)) err = 1;
    }
    for (i64 q = 0; q < B.touched.n; q++) chg[B.touched.p[q]] = 0.0;
    free(B.touched.p);
    free(B.xs);
    free(stack.p);
    if (err) {
        if (!PyErr_Occurred()) PyErr_NoMemory();
        return NULL;
    }
    return PyLong_FromLongLong((long long)count);
}

/* ------------------------------------------------------------------ ordering graph */

/* the groups: the nodes of rows[q] (rnodes) and the separators of orphans[q] (sep) */
static i64 *group_nodes(PyObject *rnodes, PyObject *sep, const i64 *rows, i64 nr,
                        const i64 *orph, i64 q, i64 *nn) {
    return q < nr ? item_i64(rnodes, rows[q], "rnodes", nn)
                  : item_i64(sep, orph[q - nr], "sep", nn);
}

static PyObject *adjacency(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 6) {
        PyErr_SetString(PyExc_TypeError, "adjacency(rows, orphans, rnodes, sep, loc, nb)");
        return NULL;
    }
    i64 nr, no, N;
    i64 *rows = arr(args[0], NPY_INT64, "rows", &nr);
    i64 *orph = rows ? arr(args[1], NPY_INT64, "orphans", &no) : NULL;
    if (!orph || !is_list(args[2], "rnodes") || !is_list(args[3], "sep")) return NULL;
    i64 *loc = arr(args[4], NPY_INT64, "loc", &N);
    i64 nb = PyLong_AsLongLong(args[5]);
    if (!loc || PyErr_Occurred()) return NULL;
    npy_intp n1 = (npy_intp)nb + 1;
    PyObject *optr = PyArray_ZEROS(1, &n1, NPY_INT64, 0);
    if (!optr) return NULL;
    i64 *ptr = PyArray_DATA((PyArrayObject *)optr);
    for (int pass = 0; pass < 2; pass++) {
        PyObject *oind = NULL;
        i64 *ind = NULL, *fill = NULL;
        if (pass == 1) {
            for (i64 k = 0; k < nb; k++) ptr[k + 1] += ptr[k];
            npy_intp ne = (npy_intp)ptr[nb];
            oind = PyArray_SimpleNew(1, &ne, NPY_INT64);
            fill = malloc((size_t)(nb > 0 ? nb : 1) * sizeof(i64));
            if (!oind || !fill) {
                Py_XDECREF(oind);
                free(fill);
                Py_DECREF(optr);
                return PyErr_NoMemory();
            }
            ind = PyArray_DATA((PyArrayObject *)oind);
            memcpy(fill, ptr, (size_t)nb * sizeof(i64));
        }
        for (i64 q = 0; q < nr + no; q++) {
            i64 nn;
            i64 *nd = group_nodes(args[2], args[3], rows, nr, orph, q, &nn);
            if (!nd) {
                Py_XDECREF(oind);
                free(fill);
                Py_DECREF(optr);
                return NULL;
            }
            i64 k = 0;
            for (i64 t = 0; t < nn; t++)
                if (nd[t] >= 0 && nd[t] < N && loc[nd[t]] >= 0 && loc[nd[t]] < nb) k++;
            if (k < 2) continue;
            for (i64 t = 0; t < nn; t++) {
                if (nd[t] < 0 || nd[t] >= N) continue;
                i64 a = loc[nd[t]];
                if (a < 0 || a >= nb) continue;
                if (pass == 0) {
                    ptr[a + 1] += k - 1;
                    continue;
                }
                for (i64 u = 0; u < nn; u++) {
                    if (u == t || nd[u] < 0 || nd[u] >= N) continue;
                    i64 b = loc[nd[u]];
                    if (b >= 0 && b < nb) ind[fill[a]++] = b;
                }
            }
        }
        if (pass == 1) {
            free(fill);
            PyObject *out = PyTuple_Pack(2, optr, oind);
            Py_DECREF(optr);
            Py_DECREF(oind);
            return out;
        }
    }
    return NULL;
}

/* the function pointer of name in a __pyx_capi__ dict, or NULL with an error */
static void *capi(PyObject *dict, const char *name) {
    PyObject *cap = PyDict_Check(dict) ? PyDict_GetItemString(dict, name) : NULL;
    if (!cap || !PyCapsule_CheckExact(cap)) {
        PyErr_Format(PyExc_TypeError, "set_blas: no capsule %s (expected the __pyx_capi__ of "
                     "scipy.linalg.cython_blas and cython_lapack)", name);
        return NULL;
    }
    return PyCapsule_GetPointer(cap, PyCapsule_GetName(cap));
}

static PyObject *set_blas(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "set_blas(blas_capi, lapack_capi)");
        return NULL;
    }
    void *syrk = capi(args[0], "dsyrk"), *trsm = syrk ? capi(args[0], "dtrsm") : NULL;
    void *gemv = trsm ? capi(args[0], "dgemv") : NULL, *trsv = gemv ? capi(args[0], "dtrsv") : NULL;
    void *potrf = trsv ? capi(args[1], "dpotrf") : NULL;
    if (!potrf) return NULL;
    g_syrk = (syrk_t)syrk;
    g_trsm = (trsm_t)trsm;
    g_gemv = (gemv_t)gemv;
    g_trsv = (trsv_t)trsv;
    g_potrf = (potrf_t)potrf;
    Py_RETURN_NONE;
}

static PyObject *factor_front(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 4) {
        PyErr_SetString(PyExc_TypeError, "factor_front(A, g, K, blas)");
        return NULL;
    }
    PyObject *oA = args[0], *og = args[1];
    if (!PyArray_Check(oA) || PyArray_TYPE((PyArrayObject *)oA) != NPY_FLOAT64 ||
        PyArray_NDIM((PyArrayObject *)oA) != 2 || !PyArray_IS_F_CONTIGUOUS((PyArrayObject *)oA) ||
        !PyArray_ISWRITEABLE((PyArrayObject *)oA) ||
        PyArray_DIM((PyArrayObject *)oA, 0) != PyArray_DIM((PyArrayObject *)oA, 1)) {
        PyErr_SetString(PyExc_ValueError, "A must be a square, writeable, Fortran-ordered "
                                          "float64 array");
        return NULL;
    }
    i64 w = (i64)PyArray_DIM((PyArrayObject *)oA, 0), ng = 0;
    double *g = arr(og, NPY_FLOAT64, "g", &ng);
    if (!g) return NULL;
    if (ng != w || !PyArray_ISWRITEABLE((PyArrayObject *)og)) {
        PyErr_SetString(PyExc_ValueError, "g must be writeable with one entry per row of A");
        return NULL;
    }
    i64 K = PyLong_AsLongLong(args[2]);
    if (K == -1 && PyErr_Occurred()) return NULL;
    if (K < 1 || K > w) {
        PyErr_SetString(PyExc_ValueError, "K must be in 1 .. the width of A");
        return NULL;
    }
    int blas = PyObject_IsTrue(args[3]);
    if (blas < 0) return NULL;
    if (blas && !g_potrf) {
        PyErr_SetString(PyExc_ValueError, "blas=True: set_blas has not run");
        return NULL;
    }
    double *A = PyArray_DATA((PyArrayObject *)oA);
    i64 bad = front_factor(A, A + K * w + K, w, g, w, K, blas);
    return PyLong_FromLongLong((long long)bad);
}

static PyMethodDef methods[] = {
    {"set_blas", (PyCFunction)(void (*)(void))set_blas, METH_FASTCALL,
     "set_blas(blas_capi, lapack_capi): dsyrk, dtrsm, dgemv, dtrsv and dpotrf from the "
     "__pyx_capi__ of scipy.linalg.cython_blas and cython_lapack, for the wide fronts"},
    {"factor_front", (PyCFunction)(void (*)(void))factor_front, METH_FASTCALL,
     "factor_front(A, g, K, blas) -> -1, or the first column not positive definite: the "
     "partial Cholesky of eliminate's fronts, in place on the lower triangle of the "
     "Fortran-ordered A (w x w) and on g: A11 = L11 L11^T, A21 <- L21 = A21 L11^-T, "
     "A22 -= L21 L21^T, g1 <- y = L11^-1 g1, g2 -= L21 y; blas: SciPy's BLAS/LAPACK, else the "
     "loops"},
    {"detach", (PyCFunction)(void (*)(void))detach, METH_FASTCALL,
     "detach(marked, parent, child, sib, mark, rseen, node_rows, rnodes) -> (top, orphans, "
     "rows)"},
    {"eliminate", (PyCFunction)(void (*)(void))eliminate, METH_FASTCALL,
     "eliminate(order, rows, orphans, rnodes, rH, rb, sep, Rinv, T, c, Hs, bs, parent, child, "
     "sib, dof, pos, loc) -> -1, or the node whose front is not positive definite"},
    {"backsubstitute", (PyCFunction)(void (*)(void))backsubstitute, METH_FASTCALL,
     "backsubstitute(order, orphans, dx, off, dof, sep, Rinv, T, c, child, sib, wildfire, "
     "chg) -> nodes computed"},
    {"adjacency", (PyCFunction)(void (*)(void))adjacency, METH_FASTCALL,
     "adjacency(rows, orphans, rnodes, sep, loc, nb) -> (indptr, indices): the graph of the "
     "nodes with loc in [0, nb), an edge for two nodes of one row or orphan separator "
     "(repeated entries kept)"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef moddef = {PyModuleDef_HEAD_INIT, "_incremental",
                                    "The Bayes tree operations of IncrementalSmoother.", -1,
                                    methods};

PyMODINIT_FUNC PyInit__incremental(void) {
    import_array();
    return PyModule_Create(&moddef);
}
