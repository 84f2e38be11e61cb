/* microlie._c._online: the per-update bookkeeping of microlie.optim.online.incremental
 * (IncrementalSmoother) around the Bayes tree's own calls, one C call each instead of a dozen
 * NumPy calls on arrays of a few elements:
 *
 *   split_order(top, last, pos, mark, start) -> (order, nb)
 *       the detached nodes `top` ordered as the smoother wants before its minimum degree step:
 *       the nodes not in any array of the list `last` first (`nb` of them), then those in it,
 *       each part by increasing `pos`; pos[order[q]] = start + q. `mark` is int64 scratch, 0
 *       between calls (restored).
 *   rows_of(extra, nodes, node_rows, rnodes, rmark) -> (rows, touched)
 *       the distinct rows among `extra` (row ids) and the rows of the nodes (node_rows: a list
 *       of lists of row ids per node), in first-seen order, and the concatenation of their
 *       nodes (rnodes: a list of int64 arrays per row). `rmark` is int64 scratch per row, 0
 *       between calls (restored).
 *
 *   backsubstitute_cliques(order, orphans, dx, off, dof, sep, Rinv, T, c, child, sib, chain,
 *                          wildfire, chg) -> count
 *       GTSAM's wildfire by cliques (ISAM2's optimizeWildfire): the step of the re-eliminated
 *       nodes `order` from the root down (all changed), then down the orphan subtrees clique by
 *       clique (a clique: a node with chain 0 and the chain of nested children below it): a
 *       clique is recomputed when a variable of its separator changed; it keeps its new steps,
 *       all marked changed, when one of its frontal components moved by `wildfire` or more,
 *       else it keeps its old steps; the cliques below a recomputed one are visited. The tree
 *       is bayes_tree.BayesTree's (x_j = Rinv_j (c_j - T_j x_sep)); `chg` is float64 scratch
 *       per node, 0 between calls (restored). Returns the number of nodes computed.
 *
 * All arrays are C-contiguous (int64 ids, float64 values); ids are checked against the array
 * lengths. The NumPy fallbacks (incremental.py, wildfire.py) compute the same. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <numpy/arrayobject.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

typedef npy_int64 i64;

static i64 *arr(PyObject *o, const char *what, i64 *size) {
    if (!PyArray_Check(o) || PyArray_TYPE((PyArrayObject *)o) != NPY_INT64 ||
        PyArray_NDIM((PyArrayObject *)o) != 1 || !PyArray_IS_C_CONTIGUOUS((PyArrayObject *)o)) {
        PyErr_Format(PyExc_ValueError, "%s must be a C-contiguous 1-D int64 array", what);
        return NULL;
    }
    *size = (i64)PyArray_DIM((PyArrayObject *)o, 0);
    return (i64 *)PyArray_DATA((PyArrayObject *)o);
}

static PyObject *new1(i64 n) {
    npy_intp d = (npy_intp)n;
    return PyArray_SimpleNew(1, &d, NPY_INT64);
}

/* sort a[0..n) by key[a[k]] (keys distinct in use; ties keep the input order) */
static const i64 *g_key;
static int cmp_key(const void *x, const void *y) {
    i64 a = g_key[*(const i64 *)x], b = g_key[*(const i64 *)y];
    return (a > b) - (a < b);
}

static void sort_by(i64 *a, i64 n, const i64 *key) {
    if (n <= 24) { /* insertion sort: stable */
        for (i64 k = 1; k < n; k++) {
            i64 v = a[k], kv = key[v], q = k - 1;
            while (q >= 0 && key[a[q]] > kv) {
                a[q + 1] = a[q];
                q--;
            }
            a[q + 1] = v;
        }
        return;
    }
    g_key = key;
    qsort(a, (size_t)n, sizeof(i64), cmp_key);
}

static PyObject *split_order(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 5) {
        PyErr_SetString(PyExc_TypeError, "split_order(top, last, pos, mark, start)");
        return NULL;
    }
    i64 n, npos, nmark;
    i64 *top = arr(args[0], "top", &n);
    if (!top) return NULL;
    if (!PyList_Check(args[1])) {
        PyErr_SetString(PyExc_ValueError, "last must be a list of int64 arrays");
        return NULL;
    }
    i64 *pos = arr(args[2], "pos", &npos);
    if (!pos) return NULL;
    i64 *mark = arr(args[3], "mark", &nmark);
    if (!mark) return NULL;
    i64 start = (i64)PyLong_AsLongLong(args[4]);
    if (start == -1 && PyErr_Occurred()) return NULL;
    for (i64 k = 0; k < n; k++)
        if (top[k] < 0 || top[k] >= npos || top[k] >= nmark) {
            PyErr_SetString(PyExc_ValueError, "top: node id out of range");
            return NULL;
        }
    Py_ssize_t nl = PyList_GET_SIZE(args[1]);
    for (int pass = 0; pass < 2; pass++) { /* check every array before marking */
        for (Py_ssize_t q = 0; q < nl; q++) {
            i64 m;
            i64 *a = arr(PyList_GET_ITEM(args[1], q), "last[k]", &m);
            if (!a) return NULL;
            for (i64 k = 0; k < m; k++) {
                if (pass == 0 && (a[k] < 0 || a[k] >= nmark)) {
                    PyErr_SetString(PyExc_ValueError, "last: node id out of range");
                    return NULL;
                }
                if (pass == 1) mark[a[k]] = 1;
            }
        }
    }
    PyObject *out = new1(n);
    if (!out) goto unmark;
    i64 *o = (i64 *)PyArray_DATA((PyArrayObject *)out);
    i64 nb = 0, nt = 0;
    for (i64 k = 0; k < n; k++) /* head from the front, tail from the back (reversed) */
        if (!mark[top[k]]) o[nb++] = top[k];
    for (i64 k = n - 1; k >= 0; k--)
        if (mark[top[k]]) o[n - 1 - nt++] = top[k];
    sort_by(o, nb, pos);
    sort_by(o + nb, nt, pos);
    for (i64 k = 0; k < n; k++) pos[o[k]] = start + k;
unmark:
    for (Py_ssize_t q = 0; q < nl; q++) {
        i64 m;
        i64 *a = (i64 *)PyArray_DATA((PyArrayObject *)PyList_GET_ITEM(args[1], q));
        m = (i64)PyArray_DIM((PyArrayObject *)PyList_GET_ITEM(args[1], q), 0);
        for (i64 k = 0; k < m; k++) mark[a[k]] = 0;
    }
    if (!out) return NULL;
    return Py_BuildValue("(NL)", out, (long long)nb);
}

static PyObject *rows_of(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 5) {
        PyErr_SetString(PyExc_TypeError, "rows_of(extra, nodes, node_rows, rnodes, rmark)");
        return NULL;
    }
    i64 n, nmark, ne;
    i64 *extra = arr(args[0], "extra", &ne);
    if (!extra) return NULL;
    i64 *nodes = arr(args[1], "nodes", &n);
    if (!nodes) return NULL;
    args++; /* the rest as in the four-argument form */
    PyObject *node_rows = args[1], *rnodes = args[2];
    if (!PyList_Check(node_rows) || !PyList_Check(rnodes)) {
        PyErr_SetString(PyExc_ValueError, "node_rows and rnodes must be lists");
        return NULL;
    }
    i64 *rmark = arr(args[3], "rmark", &nmark);
    if (!rmark) return NULL;
    Py_ssize_t nn = PyList_GET_SIZE(node_rows), nr = PyList_GET_SIZE(rnodes);
    /* pass 1: count distinct rows and their nodes */
    i64 cap = ne, nrow = 0, ntouch = 0;
    for (i64 k = 0; k < n; k++) {
        if (nodes[k] < 0 || nodes[k] >= nn) {
            PyErr_SetString(PyExc_ValueError, "nodes: node id out of range");
            return NULL;
        }
        PyObject *lst = PyList_GET_ITEM(node_rows, nodes[k]);
        if (!PyList_Check(lst)) {
            PyErr_SetString(PyExc_ValueError, "node_rows must hold lists");
            return NULL;
        }
        cap += PyList_GET_SIZE(lst);
    }
    i64 *rows = (i64 *)malloc(sizeof(i64) * (size_t)(cap > 0 ? cap : 1));
    if (!rows) return PyErr_NoMemory();
    PyObject *err = NULL;
    for (i64 k = -1; k < n && !err; k++) { /* k = -1: the extra rows */
        PyObject *lst = k >= 0 ? PyList_GET_ITEM(node_rows, nodes[k]) : NULL;
        Py_ssize_t len = k >= 0 ? PyList_GET_SIZE(lst) : (Py_ssize_t)ne;
        for (Py_ssize_t q = 0; q < len; q++) {
            i64 r = k >= 0 ? (i64)PyLong_AsLongLong(PyList_GET_ITEM(lst, q)) : extra[q];
            if ((r == -1 && PyErr_Occurred()) || r < 0 || r >= nr || r >= nmark) {
                if (!PyErr_Occurred())
                    PyErr_SetString(PyExc_ValueError, "node_rows: row id out of range");
                err = Py_None;
                break;
            }
            if (rmark[r]) continue;
            rmark[r] = 1;
            rows[nrow++] = r;
            PyObject *a = PyList_GET_ITEM(rnodes, r);
            i64 m;
            if (!arr(a, "rnodes[r]", &m)) {
                err = Py_None;
                break;
            }
            ntouch += m;
        }
    }
    PyObject *ro = NULL, *to = NULL;
    if (!err) {
        ro = new1(nrow);
        to = new1(ntouch);
    }
    if (ro && to) {
        i64 *rd = (i64 *)PyArray_DATA((PyArrayObject *)ro);
        i64 *td = (i64 *)PyArray_DATA((PyArrayObject *)to);
        i64 t = 0;
        for (i64 k = 0; k < nrow; k++) {
            PyArrayObject *a = (PyArrayObject *)PyList_GET_ITEM(rnodes, rows[k]);
            i64 m = (i64)PyArray_DIM(a, 0);
            memcpy(td + t, PyArray_DATA(a), sizeof(i64) * (size_t)m);
            t += m;
            rd[k] = rows[k];
        }
    }
    for (i64 k = 0; k < nrow; k++) rmark[rows[k]] = 0;
    free(rows);
    if (!ro || !to) {
        Py_XDECREF(ro);
        Py_XDECREF(to);
        return NULL;
    }
    return Py_BuildValue("(NN)", ro, to);
}


/* ------------------------------------------------------------------ wildfire by cliques */

static double *f64(PyObject *o, const char *what, i64 size) {
    if (!PyArray_Check(o) || PyArray_TYPE((PyArrayObject *)o) != NPY_FLOAT64 ||
        !PyArray_IS_C_CONTIGUOUS((PyArrayObject *)o) ||
        (size >= 0 && (i64)PyArray_SIZE((PyArrayObject *)o) != size)) {
        PyErr_Format(PyExc_ValueError, "%s must be a C-contiguous float64 array of the node's "
                     "size", what);
        return NULL;
    }
    return (double *)PyArray_DATA((PyArrayObject *)o);
}

typedef struct {
    double *dx, *chg;
    const i64 *off, *dof, *child, *sib, *chain;
    i64 n, ndx;
    PyObject *sep, *Rinv, *T, *c;
    i64 *buf; /* int64 stack / scratch */
    i64 nbuf, cap;
} wctx;

static int wpush(wctx *W, i64 v) {
    if (W->nbuf == W->cap) {
        i64 cap = W->cap ? 2 * W->cap : 256;
        i64 *p = (i64 *)realloc(W->buf, sizeof(i64) * (size_t)cap);
        if (!p) {
            PyErr_NoMemory();
            return -1;
        }
        W->buf = p;
        W->cap = cap;
    }
    W->buf[W->nbuf++] = v;
    return 0;
}

static int node_ok(const wctx *W, i64 k) {
    if (k < 0 || k >= W->n || W->off[k] < 0 || W->off[k] + W->dof[k] > W->ndx || W->dof[k] > 64) {
        PyErr_SetString(PyExc_ValueError, "backsubstitute_cliques: bad node");
        return 0;
    }
    return 1;
}

/* x_k = Rinv_k (c_k - T_k x_sep) into dx; its largest change into *moved. -1 on error */
static int solve_node(wctx *W, i64 k, double *moved) {
    if (!node_ok(W, k)) return -1;
    PyObject *so = PyList_GET_ITEM(W->sep, k);
    i64 ns, d = W->dof[k];
    i64 *sp = arr(so, "sep[k]", &ns);
    if (!sp) return -1;
    i64 s = 0;
    for (i64 a = 0; a < ns; a++) {
        if (!node_ok(W, sp[a])) return -1;
        s += W->dof[sp[a]];
    }
    double *R = f64(PyList_GET_ITEM(W->Rinv, k), "Rinv[k]", d * d);
    double *T = R ? f64(PyList_GET_ITEM(W->T, k), "T[k]", d * s) : NULL;
    double *c = T ? f64(PyList_GET_ITEM(W->c, k), "c[k]", d) : NULL;
    if (!c) return -1;
    double v[64];
    for (i64 a = 0; a < d; a++) v[a] = c[a];
    i64 col = 0;
    for (i64 a = 0; a < ns; a++) {
        const double *xs = W->dx + W->off[sp[a]];
        for (i64 r = 0; r < W->dof[sp[a]]; r++, col++)
            for (i64 i = 0; i < d; i++) v[i] -= T[i * s + col] * xs[r];
    }
    double *xk = W->dx + W->off[k], big = *moved;
    for (i64 i = 0; i < d; i++) {
        double t = 0.0;
        for (i64 a = 0; a < d; a++) t += R[i * d + a] * v[a];
        double e = fabs(t - xk[i]);
        if (e > big || e != e) big = e;
        xk[i] = t;
    }
    *moved = big;
    return 0;
}

static PyObject *backsubstitute_cliques(PyObject *self, PyObject *const *args,
                                        Py_ssize_t nargs) {
    (void)self;
    if (nargs != 14) {
        PyErr_SetString(PyExc_TypeError, "backsubstitute_cliques(order, orphans, dx, off, dof, "
                                         "sep, Rinv, T, c, child, sib, chain, wildfire, chg)");
        return NULL;
    }
    i64 no, nor, ndx, n, n2, n3, n4, n5, n6;
    i64 *order = arr(args[0], "order", &no);
    i64 *orph = order ? arr(args[1], "orphans", &nor) : NULL;
    if (!orph) return NULL;
    double *dx = f64(args[2], "dx", -1);
    if (!dx) return NULL;
    ndx = (i64)PyArray_SIZE((PyArrayObject *)args[2]);
    i64 *off = arr(args[3], "off", &n);
    i64 *dof = off ? arr(args[4], "dof", &n2) : NULL;
    i64 *child = dof ? arr(args[9], "child", &n3) : NULL;
    i64 *sib = child ? arr(args[10], "sib", &n4) : NULL;
    i64 *chain = sib ? arr(args[11], "chain", &n5) : NULL;
    if (!chain) return NULL;
    for (int k = 5; k < 9; k++)
        if (!PyList_Check(args[k])) {
            PyErr_SetString(PyExc_ValueError, "sep, Rinv, T and c must be lists");
            return NULL;
        }
    double wildfire = PyFloat_AsDouble(args[12]);
    if (wildfire == -1.0 && PyErr_Occurred()) return NULL;
    double *chg = f64(args[13], "chg", -1);
    if (!chg) return NULL;
    n6 = (i64)PyArray_SIZE((PyArrayObject *)args[13]);
    i64 nn = n;
    i64 lens[] = {n2, n3, n4, n5, n6, (i64)PyList_GET_SIZE(args[5]),
                  (i64)PyList_GET_SIZE(args[6]), (i64)PyList_GET_SIZE(args[7]),
                  (i64)PyList_GET_SIZE(args[8])};
    for (int k = 0; k < 9; k++)
        if (lens[k] < nn) nn = lens[k];
    wctx W = {dx, chg, off, dof, child, sib, chain, nn, ndx, args[5], args[6], args[7], args[8],
              NULL, 0, 0};
    i64 count = 0, ntouched = 0;
    int err = 0;
    double old[64 * 64];
    /* the touched nodes (chg set) are kept at the bottom of W.buf; the stack above them */
    for (i64 q = no - 1; q >= 0 && !err; q--) { /* the re-eliminated: root down, all changed */
        double moved = 0.0;
        if (solve_node(&W, order[q], &moved) || wpush(&W, order[q])) err = 1;
        else chg[order[q]] = 1.0;
        count++;
    }
    ntouched = W.nbuf;
    for (i64 t = 0; t < nor && !err; t++)
        if (!node_ok(&W, orph[t]) || wpush(&W, orph[t])) err = 1;
    while (W.nbuf > ntouched && !err) {
        i64 r = W.buf[--W.nbuf], ns;
        i64 *sr = arr(PyList_GET_ITEM(W.sep, r), "sep[k]", &ns);
        if (!sr) {
            err = 1;
            break;
        }
        int dirty = 0;
        for (i64 a = 0; a < ns && !dirty; a++) dirty = sr[a] >= 0 && sr[a] < nn && chg[sr[a]] != 0.0;
        if (!dirty) continue;
        /* the clique's frontal nodes: r and its chain of nested children (at most 64 here;
           a longer chain is split into cliques of 64, each deciding on its own) */
        i64 F[64], nf = 0;
        for (i64 j = r; j >= 0 && nf < 64;) {
            F[nf++] = j;
            i64 next = -1;
            for (i64 ch = child[j]; ch >= 0; ch = sib[ch])
                if (ch < nn && chain[ch]) next = ch;
            j = next;
        }
        double moved = 0.0;
        i64 o = 0;
        for (i64 a = 0; a < nf && !err; a++) { /* keep the old steps, then solve root down */
            const double *x = dx + off[F[a]];
            for (i64 i = 0; i < dof[F[a]] && o < 64 * 64; i++) old[o++] = x[i];
            if (o >= 64 * 64) {
                PyErr_SetString(PyExc_ValueError, "backsubstitute_cliques: clique too wide");
                err = 1;
            }
        }
        for (i64 a = 0; a < nf && !err; a++)
            if (solve_node(&W, F[a], &moved)) err = 1;
        if (err) break;
        count += nf;
        /* the stack top is above the touched part: insert the touched frontals below it */
        i64 above = W.nbuf - ntouched;
        if (!(moved < wildfire)) { /* changed (NaN too): marked; kept at the bottom */
            for (i64 a = 0; a < nf && !err; a++) {
                chg[F[a]] = 1.0;
                if (wpush(&W, 0)) err = 1;
            }
            if (err) break;
            memmove(W.buf + ntouched + nf, W.buf + ntouched, sizeof(i64) * (size_t)above);
            for (i64 a = 0; a < nf; a++) W.buf[ntouched + a] = F[a];
            ntouched += nf;
        } else { /* restored */
            o = 0;
            for (i64 a = 0; a < nf; a++) {
                double *x = dx + off[F[a]];
                for (i64 i = 0; i < dof[F[a]]; i++) x[i] = old[o++];
            }
        }
        for (i64 a = 0; a < nf && !err; a++) /* the cliques below: non-chain children */
            for (i64 ch = child[F[a]]; ch >= 0 && !err; ch = sib[ch]) {
                if (ch >= nn) {
                    PyErr_SetString(PyExc_ValueError, "backsubstitute_cliques: bad child");
                    err = 1;
                } else if (!(a + 1 < nf && ch == F[a + 1]) && wpush(&W, ch)) {
                    err = 1; /* every child but the next frontal roots a clique below */
                }
            }
    }
    for (i64 q = 0; q < ntouched; q++) chg[W.buf[q]] = 0.0;
    free(W.buf);
    if (err) {
        if (!PyErr_Occurred()) PyErr_NoMemory();
        return NULL;
    }
    return PyLong_FromLongLong((long long)count);
}

static PyMethodDef methods[] = {
    {"split_order", (PyCFunction)(void (*)(void))split_order, METH_FASTCALL,
     "split_order(top, last, pos, mark, start) -> (order, nb)"},
    {"rows_of", (PyCFunction)(void (*)(void))rows_of, METH_FASTCALL,
     "rows_of(extra, nodes, node_rows, rnodes, rmark) -> (rows, touched)"},
    {"backsubstitute_cliques", (PyCFunction)(void (*)(void))backsubstitute_cliques,
     METH_FASTCALL, "backsubstitute_cliques(order, orphans, dx, off, dof, sep, Rinv, T, c, "
     "child, sib, chain, wildfire, chg) -> count"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef moddef = {PyModuleDef_HEAD_INIT, "_online",
                                    "IncrementalSmoother's per-update bookkeeping", -1, methods,
                                    NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__online(void) {
    import_array();
    return PyModule_Create(&moddef);
}
