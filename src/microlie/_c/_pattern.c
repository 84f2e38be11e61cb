/* microlie._c._pattern: the block pattern of H = J^T J of microlie.optim.core.problem in C.
 *
 * block_pattern(nn, pairs, dof) -> (bptr, brow, bstart, collen)
 *   nn nodes (free variables); pairs: a list of (a, b) intp arrays of one length, the node
 *   pairs that share a factor (a negative node, a fixed variable, is skipped). The symmetric
 *   block pattern with every diagonal block: block column v holds the rows u (sorted, no
 *   repeats) with (u, v) or (v, u) a pair, and v. Returns its pointers bptr (int64, nn + 1)
 *   and rows brow (int64), and, for the scalar CSC of H in full symmetric storage with node v
 *   of dof[v] unknowns (int64 dof), the position bstart (int64) of entry (0, 0) of each stored
 *   block and the rows collen[v] of every scalar column of block column v (int64): entry
 *   (r, c) of block (u, v) is at bstart + c * collen[v] + r. Two passes over the pairs
 *   (count, fill), then one sort per column: O(pairs + nnz log degree).
 *
 * positions(bptr, brow, bstart, a, b) -> int64 array
 *   bstart of the blocks (a[k], b[k]) (binary search of row a[k] in column b[k]); -1 where
 *   a[k] or b[k] is negative. ValueError naming the block when it is not in the pattern.
 *
 * plan(bptr, brow, bstart, collen, node_off, nodes) -> (starts, lens, goff)
 *   What a compiled factor loop needs of the pattern for a batch of factors with K arguments,
 *   nodes (m, K) intp (-1: fixed or constant): starts (m, K * K) int64, the bstart of block
 *   (nodes[r, k], nodes[r, l]) at k * K + l (-1 when either is fixed); lens (m, K), the collen of
 *   each argument's column (0 when fixed); goff (m, K), its first unknown node_off (-1 when
 *   fixed). ValueError when a block is not in the pattern.
 *
 * components(bptr, brow) -> (ncomp, label)
 *   The connected components of the pattern's graph (a disjoint-set forest with path halving):
 *   label (int64) numbers them 0 .. ncomp - 1 in the order of each one's smallest node. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <numpy/arrayobject.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "array_args.h"

typedef npy_int64 i64;
typedef npy_int32 i32;

static PyArrayObject *new_arr(ix n, int type) {
    npy_intp d[1] = {(npy_intp)n};
    return (PyArrayObject *)PyArray_SimpleNew(1, d, type);
}

static int cmp_i32(const void *a, const void *b) {
    i32 x = *(const i32 *)a, y = *(const i32 *)b;
    return (x > y) - (x < y);
}

/* sort r[0..len) ascending and drop repeats; the new length */
static ix sort_unique(i32 *r, ix len) {
    if (len > 24) {
        qsort(r, (size_t)len, sizeof(i32), cmp_i32);
    } else {
        for (ix i = 1; i < len; i++) {
            i32 x = r[i];
            ix j = i - 1;
            while (j >= 0 && r[j] > x) {
                r[j + 1] = r[j];
                j--;
            }
            r[j + 1] = x;
        }
    }
    ix out = 0;
    for (ix i = 0; i < len; i++)
        if (out == 0 || r[out - 1] != r[i]) r[out++] = r[i];
    return out;
}

static PyObject *block_pattern(PyObject *self, PyObject *args) {
    Py_ssize_t nn_in;
    PyObject *pairs, *dof_o;
    if (!PyArg_ParseTuple(args, "nO!O", &nn_in, &PyList_Type, &pairs, &dof_o)) return NULL;
    ix nn = (ix)nn_in;
    if (nn < 0 || nn >= INT32_MAX) {
        PyErr_Format(PyExc_ValueError, "nn must be in [0, 2**31 - 1), got %zd", nn_in);
        return NULL;
    }
    ix dd[1] = {nn};
    PyArrayObject *dof_a = arg(dof_o, "dof", NPY_INT64, 1, dd);
    if (!dof_a) return NULL;
    const i64 *dof = PyArray_DATA(dof_a);
    Py_ssize_t np_ = PyList_GET_SIZE(pairs);
    const ix **pa = malloc(sizeof(ix *) * (size_t)(np_ + 1) * 2);
    ix *pm = malloc(sizeof(ix) * (size_t)(np_ + 1));
    i64 *cnt = calloc((size_t)nn + 1, sizeof(i64));
    if (!pa || !pm || !cnt) {
        free(pa); free(pm); free(cnt);
        return PyErr_NoMemory();
    }
    for (Py_ssize_t p = 0; p < np_; p++) {
        PyObject *t = PyList_GET_ITEM(pairs, p);
        if (!PyTuple_Check(t) || PyTuple_GET_SIZE(t) != 2) {
            PyErr_SetString(PyExc_ValueError, "pairs must hold (a, b) tuples of intp arrays");
            goto fail;
        }
        ix d[1] = {-1};
        PyArrayObject *a = arg(PyTuple_GET_ITEM(t, 0), "a", NPY_INTP, 1, d);
        if (!a) goto fail;
        d[0] = PyArray_DIM(a, 0);
        PyArrayObject *b = arg(PyTuple_GET_ITEM(t, 1), "b", NPY_INTP, 1, d);
        if (!b) goto fail;
        pa[2 * p] = PyArray_DATA(a);
        pa[2 * p + 1] = PyArray_DATA(b);
        pm[p] = d[0];
        const ix *x = pa[2 * p], *y = pa[2 * p + 1];
        for (ix k = 0; k < d[0]; k++) {
            if (x[k] >= nn || y[k] >= nn) {
                PyErr_Format(PyExc_ValueError, "pair %zd, entry %zd: node (%zd, %zd) outside "
                             "[0, %zd)", (Py_ssize_t)p, (Py_ssize_t)k, (Py_ssize_t)x[k],
                             (Py_ssize_t)y[k], (Py_ssize_t)nn);
                goto fail;
            }
            if (x[k] >= 0 && y[k] >= 0 && x[k] != y[k]) {
                cnt[x[k] + 1]++;
                cnt[y[k] + 1]++;
            }
        }
    }
    /* column pointers with the diagonal; fill; sort and compact each column */
    for (ix v = 0; v < nn; v++) cnt[v + 1] += cnt[v] + 1;
    i64 tot = cnt[nn];
    i32 *tmp = malloc(sizeof(i32) * (size_t)(tot + 1));
    i64 *fill = malloc(sizeof(i64) * (size_t)(nn + 1));
    if (!tmp || !fill) {
        free(tmp); free(fill);
        PyErr_NoMemory();
        goto fail;
    }
    for (ix v = 0; v < nn; v++) {
        tmp[cnt[v]] = (i32)v;
        fill[v] = cnt[v] + 1;
    }
    for (Py_ssize_t p = 0; p < np_; p++) {
        const ix *x = pa[2 * p], *y = pa[2 * p + 1];
        for (ix k = 0; k < pm[p]; k++)
            if (x[k] >= 0 && y[k] >= 0 && x[k] != y[k]) {
                tmp[fill[y[k]]++] = (i32)x[k];
                tmp[fill[x[k]]++] = (i32)y[k];
            }
    }
    free(fill);
    free(pa);
    free(pm);
    pa = NULL;
    pm = NULL;
    PyArrayObject *bptr = new_arr(nn + 1, NPY_INT64), *collen = new_arr(nn, NPY_INT64);
    if (!bptr || !collen) {
        Py_XDECREF(bptr); Py_XDECREF(collen);
        free(tmp);
        goto fail;
    }
    i64 *bp = PyArray_DATA(bptr), *cl = PyArray_DATA(collen);
    i64 w = 0;
    bp[0] = 0;
    for (ix v = 0; v < nn; v++) {
        ix len = sort_unique(tmp + cnt[v], (ix)(cnt[v + 1] - cnt[v]));
        if (w != cnt[v]) memmove(tmp + w, tmp + cnt[v], sizeof(i32) * (size_t)len);
        w += len;
        bp[v + 1] = w;
    }
    free(cnt);
    cnt = NULL;
    PyArrayObject *brow = new_arr((ix)w, NPY_INT64), *bstart = new_arr((ix)w, NPY_INT64);
    if (!brow || !bstart) {
        Py_DECREF(bptr); Py_DECREF(collen); Py_XDECREF(brow); Py_XDECREF(bstart);
        free(tmp);
        return NULL;
    }
    i64 *br = PyArray_DATA(brow);
    i64 *bs = PyArray_DATA(bstart);
    for (i64 k = 0; k < w; k++) br[k] = tmp[k];
    free(tmp);
    i64 base = 0;
    for (ix v = 0; v < nn; v++) {
        i64 rows = 0;
        for (i64 k = bp[v]; k < bp[v + 1]; k++) {
            bs[k] = base + rows;
            rows += dof[br[k]];
        }
        cl[v] = rows;
        base += rows * dof[v];
    }
    return Py_BuildValue("NNNN", bptr, brow, bstart, collen);
fail:
    free(pa);
    free(pm);
    free(cnt);
    return NULL;
}

static i64 lookup(const i64 *bp, const i64 *br, const i64 *bs, ix u, ix v);

static PyObject *positions(PyObject *self, PyObject *args) {
    PyObject *o[5];
    if (!PyArg_ParseTuple(args, "OOOOO", &o[0], &o[1], &o[2], &o[3], &o[4])) return NULL;
    ix d[1] = {-1};
    PyArrayObject *bptr = arg(o[0], "bptr", NPY_INT64, 1, d);
    if (!bptr) return NULL;
    ix nn = PyArray_DIM(bptr, 0) - 1;
    const i64 *bp = PyArray_DATA(bptr);
    d[0] = nn >= 0 ? bp[nn] : 0;
    PyArrayObject *brow = arg(o[1], "brow", NPY_INT64, 1, d);
    PyArrayObject *bstart = brow ? arg(o[2], "bstart", NPY_INT64, 1, d) : NULL;
    if (!bstart) return NULL;
    d[0] = -1;
    PyArrayObject *a = arg(o[3], "a", NPY_INTP, 1, d);
    if (!a) return NULL;
    d[0] = PyArray_DIM(a, 0);
    PyArrayObject *b = arg(o[4], "b", NPY_INTP, 1, d);
    if (!b) return NULL;
    const i64 *br = PyArray_DATA(brow);
    const i64 *bs = PyArray_DATA(bstart);
    const ix *x = PyArray_DATA(a), *y = PyArray_DATA(b);
    ix m = d[0];
    PyArrayObject *out = new_arr(m, NPY_INT64);
    if (!out) return NULL;
    i64 *r = PyArray_DATA(out);
    for (ix k = 0; k < m; k++) {
        ix u = x[k], v = y[k];
        if (u < 0 || v < 0) {
            r[k] = -1;
            continue;
        }
        if (u >= nn || v >= nn || (r[k] = lookup(bp, br, bs, u, v)) == -2) goto missing;
        continue;
    missing:
        PyErr_Format(PyExc_ValueError, "block (%zd, %zd) is not in the pattern",
                     (Py_ssize_t)u, (Py_ssize_t)v);
        Py_DECREF(out);
        return NULL;
    }
    return (PyObject *)out;
}

/* the bstart of block (u, v), or -2 when it is not stored */
static i64 lookup(const i64 *bp, const i64 *br, const i64 *bs, ix u, ix v) {
    i64 lo = bp[v], hi = bp[v + 1];
    while (lo < hi) {
        i64 mid = lo + (hi - lo) / 2;
        if (br[mid] < u) lo = mid + 1;
        else hi = mid;
    }
    return lo < bp[v + 1] && br[lo] == u ? bs[lo] : -2;
}

static PyObject *plan(PyObject *self, PyObject *args) {
    PyObject *o[6];
    if (!PyArg_ParseTuple(args, "OOOOOO", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5]))
        return NULL;
    ix d[2] = {-1, -1};
    PyArrayObject *bptr = arg(o[0], "bptr", NPY_INT64, 1, d);
    if (!bptr) return NULL;
    ix nn = PyArray_DIM(bptr, 0) - 1;
    const i64 *bp = PyArray_DATA(bptr);
    d[0] = nn >= 0 ? bp[nn] : 0;
    PyArrayObject *brow = arg(o[1], "brow", NPY_INT64, 1, d);
    PyArrayObject *bstart = brow ? arg(o[2], "bstart", NPY_INT64, 1, d) : NULL;
    if (!bstart) return NULL;
    d[0] = nn;
    PyArrayObject *collen = arg(o[3], "collen", NPY_INT64, 1, d);
    if (!collen) return NULL;
    d[0] = nn + 1;
    PyArrayObject *noff = arg(o[4], "node_off", NPY_INT64, 1, d);
    if (!noff) return NULL;
    d[0] = -1;
    PyArrayObject *nodes = arg(o[5], "nodes", NPY_INTP, 2, d);
    if (!nodes) return NULL;
    ix m = PyArray_DIM(nodes, 0), K = PyArray_DIM(nodes, 1);
    const i64 *br = PyArray_DATA(brow), *bs = PyArray_DATA(bstart);
    const i64 *cl = PyArray_DATA(collen), *off = PyArray_DATA(noff);
    const ix *nd = PyArray_DATA(nodes);
    npy_intp ds[2] = {m, K * K}, dl[2] = {m, K};
    PyArrayObject *st = (PyArrayObject *)PyArray_SimpleNew(2, ds, NPY_INT64);
    PyArrayObject *ln = (PyArrayObject *)PyArray_SimpleNew(2, dl, NPY_INT64);
    PyArrayObject *go = (PyArrayObject *)PyArray_SimpleNew(2, dl, NPY_INT64);
    if (!st || !ln || !go) {
        Py_XDECREF(st); Py_XDECREF(ln); Py_XDECREF(go);
        return NULL;
    }
    i64 *S = PyArray_DATA(st), *L = PyArray_DATA(ln), *G = PyArray_DATA(go);
    for (ix r = 0; r < m; r++) {
        const ix *x = nd + r * K;
        for (ix k = 0; k < K; k++) {
            if (x[k] >= nn) {
                PyErr_Format(PyExc_ValueError, "nodes[%zd, %zd] = %zd outside [-1, %zd)",
                             (Py_ssize_t)r, (Py_ssize_t)k, (Py_ssize_t)x[k], (Py_ssize_t)nn);
                goto fail;
            }
            L[r * K + k] = x[k] >= 0 ? cl[x[k]] : 0;
            G[r * K + k] = x[k] >= 0 ? off[x[k]] : -1;
            for (ix l = 0; l < K; l++) {
                i64 p = -1;
                if (x[k] >= 0 && x[l] >= 0) {
                    p = lookup(bp, br, bs, x[k], x[l]);
                    if (p == -2) {
                        PyErr_Format(PyExc_ValueError, "block (%zd, %zd) is not in the pattern",
                                     (Py_ssize_t)x[k], (Py_ssize_t)x[l]);
                        goto fail;
                    }
                }
                S[r * K * K + k * K + l] = p;
            }
        }
    }
    return Py_BuildValue("NNN", st, ln, go);
fail:
    Py_DECREF(st); Py_DECREF(ln); Py_DECREF(go);
    return NULL;
}

static ix find(ix *parent, ix i) {
    while (parent[i] != i) {
        parent[i] = parent[parent[i]];
        i = parent[i];
    }
    return i;
}

static PyObject *components(PyObject *self, PyObject *args) {
    PyObject *o[2];
    if (!PyArg_ParseTuple(args, "OO", &o[0], &o[1])) return NULL;
    ix d[1] = {-1};
    PyArrayObject *bptr = arg(o[0], "bptr", NPY_INT64, 1, d);
    if (!bptr) return NULL;
    ix nn = PyArray_DIM(bptr, 0) - 1;
    if (nn < 0) {
        PyErr_SetString(PyExc_ValueError, "bptr must have at least one entry");
        return NULL;
    }
    const i64 *bp = PyArray_DATA(bptr);
    d[0] = bp[nn];
    PyArrayObject *brow = arg(o[1], "brow", NPY_INT64, 1, d);
    if (!brow) return NULL;
    const i64 *br = PyArray_DATA(brow);
    PyArrayObject *out = new_arr(nn, NPY_INT64);
    ix *parent = malloc(sizeof(ix) * (size_t)(nn + 1));
    if (!out || !parent) {
        Py_XDECREF(out);
        free(parent);
        return PyErr_NoMemory();
    }
    for (ix i = 0; i < nn; i++) parent[i] = i;
    for (ix v = 0; v < nn; v++)
        for (i64 k = bp[v]; k < bp[v + 1]; k++) {
            ix u = br[k];
            if (u < 0 || u >= nn) {
                PyErr_Format(PyExc_ValueError, "brow: row %zd outside [0, %zd)", (Py_ssize_t)u,
                             (Py_ssize_t)nn);
                Py_DECREF(out);
                free(parent);
                return NULL;
            }
            ix ru = find(parent, u), rv = find(parent, v);
            if (ru != rv) {  /* the smaller root stays the root */
                if (ru < rv) parent[rv] = ru;
                else parent[ru] = rv;
            }
        }
    /* roots are the smallest nodes of their components: number them in node order */
    i64 *label = PyArray_DATA(out);
    i64 nc = 0;
    for (ix i = 0; i < nn; i++) {
        ix r = find(parent, i);
        label[i] = r == i ? nc++ : label[r];
    }
    free(parent);
    return Py_BuildValue("LN", (long long)nc, out);
}

static PyMethodDef methods[] = {
    {"block_pattern", block_pattern, METH_VARARGS,
     "block_pattern(nn, pairs, dof) -> (bptr, brow, bstart, collen)"},
    {"positions", positions, METH_VARARGS, "positions(bptr, brow, bstart, a, b) -> int64"},
    {"plan", plan, METH_VARARGS,
     "plan(bptr, brow, bstart, collen, node_off, nodes) -> (starts, lens, goff)"},
    {"components", components, METH_VARARGS, "components(bptr, brow) -> (ncomp, label)"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef moddef = {PyModuleDef_HEAD_INIT, "_pattern",
                                    "The block pattern of a least-squares problem (microlie).",
                                    -1, methods};

PyMODINIT_FUNC PyInit__pattern(void) {
    import_array();
    return PyModule_Create(&moddef);
}
