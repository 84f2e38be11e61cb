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
 * All arrays are C-contiguous int64; ids are checked against the array lengths. The NumPy
 * fallback (incremental.py) computes the same. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <numpy/arrayobject.h>
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

static PyMethodDef methods[] = {
    {"split_order", (PyCFunction)(void (*)(void))split_order, METH_FASTCALL,
     "split_order(top, last, pos, mark, start) -> (order, nb)"},
    {"rows_of", (PyCFunction)(void (*)(void))rows_of, METH_FASTCALL,
     "rows_of(extra, nodes, node_rows, rnodes, rmark) -> (rows, touched)"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef moddef = {PyModuleDef_HEAD_INIT, "_online",
                                    "IncrementalSmoother's per-update bookkeeping", -1, methods,
                                    NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__online(void) {
    import_array();
    return PyModule_Create(&moddef);
}
