/* microlie._c._symbolic: the symbolic analysis of microlie.optim.linalg.cholesky in C.
 *
 * Everything works on the block graph (one node per dense block of unknowns) and int64 arrays.
 *
 * supernodes(indptr, indices, perm, relax) -> (perm, parent, counts, bstart, brptr, brow)
 *   indptr, indices: the symmetric adjacency of the block graph (CSR or CSC: the same;
 *   diagonal entries and duplicates are ignored); perm: a fill-reducing order, new -> old.
 *   1. the elimination tree of A[perm][:, perm] (Liu's algorithm with path compression);
 *   2. its postorder (children in ascending order, roots ascending), which becomes the order
 *      (the same fill, subtrees contiguous) and relabels the tree;
 *   3. the column counts of L, diagonal included (Gilbert, Ng and Peyton: each row subtree
 *      counted at its leaves, minus its least common ancestors of consecutive leaves, found
 *      with a disjoint-set forest; then summed over subtrees);
 *   4. fundamental supernodes (a column joins its parent when it is the parent's only child
 *      and has one more entry), then relaxed amalgamation: a supernode merges into the next
 *      one when that is its parent and the merged one stays small or adds few explicit zeros
 *      (relax: the three (max columns, max zero fraction) pairs, CHOLMOD's defaults);
 *   5. the block row structure of every supernode: its columns, then (sorted) the rows below
 *      its last column of its columns of A and of its children's structures.
 *   Returns the order, the tree and counts (in that order), the supernodes' first columns,
 *   and their structures as a CSR (brptr: ns + 1 offsets into brow).
 *
 * updates(brptr, brow, bstart, nb) -> (pptr, pt, pa, pb, relptr, rel)
 *   The update pairs of the right-looking factorisation: for supernode s, the rows below its
 *   diagonal block are grouped by the supernode t owning them (ascending t); pair p = (s, t)
 *   covers s's below rows pa[p] .. pb[p]-1, and rel[relptr[p] + i] is the position in t's
 *   structure of s's below row pa[p] + i (i = 0 .. u_s - pa[p] - 1: to the end of s's rows).
 *
 * amap(bptr, bidx, inv, sn_of, brptr, brow, bstart, px, bs, nx) -> amap
 *   The place in the panels of every run of bs rows (one scalar column of one block) of the
 *   scalar CSC of a pattern of dense bs x bs blocks (bptr, bidx: the block CSC, rows sorted):
 *   run cc of block (u, v) with inv[u] >= inv[v] goes to its supernode's panel (rows rr of a
 *   diagonal block above its diagonal land in the panel's upper triangle, never read), the
 *   blocks of the strict upper triangle to the dump slot nx (bs entries). One entry per run:
 *   1/bs of a map per entry. int32 when nx < 2^31 - 1, else int64. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <numpy/arrayobject.h>
#include <stdlib.h>
#include <string.h>

#include "array_args.h"

typedef npy_int64 i64;

static i64 *ints(PyObject *o, const char *name, ix len) {
    ix dims[1] = {len};
    PyArrayObject *a = arg(o, name, NPY_INT64, 1, dims);
    return a ? (i64 *)PyArray_DATA(a) : NULL;
}

static PyArrayObject *new_ints(i64 n) {
    npy_intp d[1] = {(npy_intp)n};
    return (PyArrayObject *)PyArray_SimpleNew(1, d, NPY_INT64);
}

static int cmp_i64(const void *a, const void *b) {
    i64 x = *(const i64 *)a, y = *(const i64 *)b;
    return (x > y) - (x < y);
}

/* the root of q's set, compressing the path */
static i64 find(i64 *anc, i64 q) {
    i64 r = q;
    while (anc[r] != r) r = anc[r];
    while (anc[q] != r) {
        i64 nx = anc[q];
        anc[q] = r;
        q = nx;
    }
    return r;
}

static PyObject *supernodes(PyObject *self, PyObject *args) {
    PyObject *optr, *oidx, *operm;
    double r0, z0, r1, z1, r2, z2;
    if (!PyArg_ParseTuple(args, "OOO(dddddd)", &optr, &oidx, &operm, &r0, &z0, &r1, &z1,
                          &r2, &z2))
        return NULL;
    i64 *perm0 = ints(operm, "perm", -1);
    if (!perm0) return NULL;
    i64 n = (i64)PyArray_SIZE((PyArrayObject *)operm);
    i64 *ip = ints(optr, "indptr", n + 1);
    i64 *ix_ = ip ? ints(oidx, "indices", -1) : NULL;
    if (!ix_) return NULL;
    i64 nnz = (i64)PyArray_SIZE((PyArrayObject *)oidx);
    if (ip[0] != 0 || ip[n] > nnz) {
        PyErr_SetString(PyExc_ValueError, "indptr does not fit indices");
        return NULL;
    }
    for (i64 j = 0; j < n; j++)
        if (ip[j + 1] < ip[j]) {
            PyErr_SetString(PyExc_ValueError, "indptr must be non-decreasing");
            return NULL;
        }
    for (i64 p = 0; p < ip[n]; p++)
        if (ix_[p] < 0 || ix_[p] >= n) {
            PyErr_SetString(PyExc_ValueError, "indices out of range");
            return NULL;
        }
    /* work: 8 arrays of n (+1) */
    i64 *w = PyMem_Malloc((size_t)(8 * (n + 1) + 1) * sizeof(i64));
    if (!w) return PyErr_NoMemory();
    i64 *inv = w, *parent = w + (n + 1), *anc = w + 2 * (n + 1), *head = w + 3 * (n + 1),
        *next = w + 4 * (n + 1), *post = w + 5 * (n + 1), *first = w + 6 * (n + 1),
        *delta = w + 7 * (n + 1);
    for (i64 i = 0; i < n; i++) inv[i] = -1;
    for (i64 i = 0; i < n; i++) {
        i64 o = perm0[i];
        if (o < 0 || o >= n || inv[o] >= 0) {
            PyMem_Free(w);
            PyErr_Format(PyExc_ValueError, "perm must be a permutation of 0..%lld",
                         (long long)(n - 1));
            return NULL;
        }
        inv[o] = i;
    }
    PyArrayObject *operm2 = new_ints(n), *oparent = new_ints(n), *ocount = new_ints(n);
    PyArrayObject *obstart = NULL, *obrptr = NULL, *obrow = NULL;
    PyObject *ret = NULL;
    i64 *sn = NULL;
    if (!operm2 || !oparent || !ocount) goto done;
    i64 *perm = PyArray_DATA(operm2), *par = PyArray_DATA(oparent),
        *count = PyArray_DATA(ocount);
    /* 1. elimination tree (new numbering of perm0) */
    for (i64 i = 0; i < n; i++) {
        parent[i] = -1;
        anc[i] = -1;
        i64 o = perm0[i];
        for (i64 p = ip[o]; p < ip[o + 1]; p++) {
            i64 k = inv[ix_[p]];
            while (k != -1 && k < i) {
                i64 a = anc[k];
                anc[k] = i;
                if (a == -1) parent[k] = i;
                k = a;
            }
        }
    }
    /* 2. postorder: children lists in ascending order, depth first from each root */
    for (i64 j = 0; j <= n; j++) head[j] = -1;
    for (i64 j = n - 1; j >= 0; j--) {
        i64 q = parent[j] >= 0 ? parent[j] : n; /* n: the virtual root */
        next[j] = head[q];
        head[q] = j;
    }
    {
        i64 k = 0, top = 0;
        i64 *stack = anc; /* reused */
        stack[top++] = n;
        while (top) {
            i64 q = stack[top - 1], c = head[q];
            if (c == -1) {
                top--;
                if (q != n) post[k++] = q;
            } else {
                head[q] = next[c];
                stack[top++] = c;
            }
        }
    }
    /* relabel: new index k is old-new post[k]; inv maps the graph's nodes to it */
    for (i64 k = 0; k < n; k++) first[post[k]] = k; /* first: temporarily ipost */
    for (i64 k = 0; k < n; k++) {
        perm[k] = perm0[post[k]];
        i64 q = parent[post[k]];
        par[k] = q < 0 ? -1 : first[q];
    }
    for (i64 k = 0; k < n; k++) inv[perm[k]] = k;
    /* 3. column counts */
    for (i64 j = 0; j < n; j++) first[j] = -1;
    for (i64 k = 0; k < n; k++)
        for (i64 j = k; j != -1 && first[j] == -1; j = par[j]) first[j] = k;
    i64 *maxfirst = head, *prevleaf = next; /* reused */
    for (i64 j = 0; j < n; j++) {
        delta[j] = first[j] == j; /* a leaf of the tree */
        maxfirst[j] = -1;
        prevleaf[j] = -1;
        anc[j] = j;
    }
    for (i64 j = 0; j < n; j++) {
        if (par[j] != -1) delta[par[j]]--;
        i64 o = perm[j];
        for (i64 p = ip[o]; p < ip[o + 1]; p++) {
            i64 i = inv[ix_[p]]; /* entry (i, j) of the lower triangle: j in row subtree i */
            if (i <= j || first[j] <= maxfirst[i]) continue; /* not a leaf of it */
            maxfirst[i] = first[j];
            i64 jprev = prevleaf[i];
            prevleaf[i] = j;
            delta[j]++;
            if (jprev != -1) delta[find(anc, jprev)]--; /* their least common ancestor */
        }
        if (par[j] != -1) anc[j] = par[j];
    }
    for (i64 j = 0; j < n; j++) {
        count[j] = delta[j];
    }
    for (i64 j = 0; j < n; j++)
        if (par[j] != -1) count[par[j]] += count[j];
    /* 4. fundamental supernodes, then relaxed amalgamation (a stack of merged supernodes) */
    i64 *nchild = delta; /* reused */
    for (i64 j = 0; j < n; j++) nchild[j] = 0;
    for (i64 j = 0; j < n; j++)
        if (par[j] >= 0) nchild[par[j]]++;
    i64 *st_a = post, *st_b = first, *st_true = maxfirst, *st_fb = prevleaf; /* reused */
    i64 top = 0;
    for (i64 a = 0; a < n;) {
        i64 b = a + 1;
        while (b < n && par[b - 1] == b && nchild[b] == 1 && count[b - 1] == count[b] + 1) b++;
        i64 nbel = count[b - 1] - 1, fb = par[b - 1], k = b - a;
        i64 ca = a, ctrue = k * (k + 1) / 2 + k * nbel;
        while (top) {
            i64 pa = st_a[top - 1], pb = st_b[top - 1];
            if (pb != a || st_fb[top - 1] != a) break;
            i64 k2 = b - pa;
            double total = (double)(k2 * (k2 + 1) / 2 + k2 * nbel);
            double zeros = 1.0 - (double)(st_true[top - 1] + ctrue) / total;
            if (!((k2 <= r0 && zeros <= z0) || (k2 <= r1 && zeros <= z1) ||
                  (k2 <= r2 && zeros <= z2)))
                break;
            top--;
            ca = pa;
            ctrue += st_true[top];
        }
        st_a[top] = ca;
        st_b[top] = b;
        st_true[top] = ctrue;
        st_fb[top] = fb;
        top++;
        a = b;
    }
    i64 ns = top;
    obstart = new_ints(ns);
    obrptr = new_ints(ns + 1);
    if (!obstart || !obrptr) goto done;
    i64 *bstart = PyArray_DATA(obstart), *brptr = PyArray_DATA(obrptr);
    sn = PyMem_Malloc((size_t)(2 * n + 2 * ns + 2) * sizeof(i64));
    if (!sn) {
        PyErr_NoMemory();
        goto done;
    }
    i64 *shead = sn + n, *snext = sn + n + ns + 1, *mark = anc; /* anc reused */
    brptr[0] = 0;
    for (i64 s = 0; s < ns; s++) {
        bstart[s] = st_a[s];
        i64 e = s + 1 < ns ? st_a[s + 1] : n;
        for (i64 j = st_a[s]; j < e; j++) sn[j] = s;
        brptr[s + 1] = brptr[s] + (e - st_a[s]) + count[e - 1] - 1;
    }
    obrow = new_ints(brptr[ns]);
    if (!obrow) goto done;
    i64 *brow = PyArray_DATA(obrow);
    /* 5. structures: the children of each supernode (the owner of its last column's parent) */
    for (i64 s = 0; s <= ns; s++) shead[s] = -1;
    for (i64 s = ns - 1; s >= 0; s--) {
        i64 e = s + 1 < ns ? bstart[s + 1] : n;
        i64 q = par[e - 1];
        if (q >= 0) {
            snext[s] = shead[sn[q]];
            shead[sn[q]] = s;
        }
    }
    for (i64 j = 0; j < n; j++) mark[j] = -1;
    int bad = 0;
    for (i64 s = 0; s < ns && !bad; s++) {
        i64 a = bstart[s], e = s + 1 < ns ? bstart[s + 1] : n, last = e - 1;
        i64 *out = brow + brptr[s], len = 0, cap = brptr[s + 1] - brptr[s];
        for (i64 j = a; j < e; j++) out[len++] = j;
        for (i64 j = a; j < e && !bad; j++) {
            i64 o = perm[j];
            for (i64 p = ip[o]; p < ip[o + 1]; p++) {
                i64 r = inv[ix_[p]];
                if (r > last && mark[r] != s) {
                    if (len == cap) {
                        bad = 1;
                        break;
                    }
                    mark[r] = s;
                    out[len++] = r;
                }
            }
        }
        for (i64 c = shead[s]; c != -1 && !bad; c = snext[c]) {
            for (i64 p = brptr[c]; p < brptr[c + 1]; p++) {
                i64 r = brow[p];
                if (r > last && mark[r] != s) {
                    if (len == cap) {
                        bad = 1;
                        break;
                    }
                    mark[r] = s;
                    out[len++] = r;
                }
            }
        }
        if (len != cap) bad = 1;
        else qsort(out + (e - a), (size_t)(len - (e - a)), sizeof(i64), cmp_i64);
    }
    if (bad) {
        PyErr_SetString(PyExc_AssertionError,
                        "supernodal analysis: structures disagree with the column counts");
        goto done;
    }
    ret = Py_BuildValue("NNNNNN", operm2, oparent, ocount, obstart, obrptr, obrow);
    operm2 = oparent = ocount = obstart = obrptr = obrow = NULL;
done:
    PyMem_Free(w);
    PyMem_Free(sn);
    Py_XDECREF(operm2);
    Py_XDECREF(oparent);
    Py_XDECREF(ocount);
    Py_XDECREF(obstart);
    Py_XDECREF(obrptr);
    Py_XDECREF(obrow);
    return ret;
}

/* position of r in the sorted a[0 .. len), or -1 */
static i64 bsearch_i64(const i64 *a, i64 len, i64 r) {
    i64 lo = 0, hi = len;
    while (lo < hi) {
        i64 mid = lo + (hi - lo) / 2;
        if (a[mid] < r) lo = mid + 1;
        else hi = mid;
    }
    return lo < len && a[lo] == r ? lo : -1;
}

static PyObject *updates(PyObject *self, PyObject *args) {
    PyObject *obrptr, *obrow, *obstart;
    Py_ssize_t n;
    if (!PyArg_ParseTuple(args, "OOOn", &obrptr, &obrow, &obstart, &n)) return NULL;
    i64 *bstart = ints(obstart, "bstart", -1);
    if (!bstart) return NULL;
    i64 ns = (i64)PyArray_SIZE((PyArrayObject *)obstart);
    i64 *brptr = ints(obrptr, "brptr", ns + 1);
    i64 *brow = brptr ? ints(obrow, "brow", brptr[ns]) : NULL;
    if (!brow) return NULL;
    i64 *sn = PyMem_Malloc((size_t)(n + 1) * sizeof(i64));
    if (!sn) return PyErr_NoMemory();
    for (i64 s = 0; s < ns; s++) {
        i64 e = s + 1 < ns ? bstart[s + 1] : n;
        for (i64 j = bstart[s]; j < e; j++) sn[j] = s;
    }
    /* count the pairs and the rel entries */
    i64 npair = 0, nrel = 0;
    for (i64 s = 0; s < ns; s++) {
        i64 k = (s + 1 < ns ? bstart[s + 1] : n) - bstart[s];
        const i64 *below = brow + brptr[s] + k;
        i64 u = brptr[s + 1] - brptr[s] - k;
        for (i64 i = 0; i < u; i++)
            if (i == 0 || sn[below[i]] != sn[below[i - 1]]) {
                npair++;
                nrel += u - i;
            }
    }
    PyArrayObject *opptr = new_ints(ns + 1), *opt = new_ints(npair), *opa = new_ints(npair),
                  *opb = new_ints(npair), *orelptr = new_ints(npair + 1), *orel = new_ints(nrel);
    PyObject *ret = NULL;
    if (!opptr || !opt || !opa || !opb || !orelptr || !orel) goto done;
    i64 *pptr = PyArray_DATA(opptr), *pt = PyArray_DATA(opt), *pa = PyArray_DATA(opa),
        *pb = PyArray_DATA(opb), *relptr = PyArray_DATA(orelptr), *rel = PyArray_DATA(orel);
    i64 p = 0, q = 0;
    int bad = 0;
    relptr[0] = 0;
    for (i64 s = 0; s < ns && !bad; s++) {
        pptr[s] = p;
        i64 k = (s + 1 < ns ? bstart[s + 1] : n) - bstart[s];
        const i64 *below = brow + brptr[s] + k;
        i64 u = brptr[s + 1] - brptr[s] - k;
        for (i64 i = 0; i < u && !bad; i++) {
            if (i > 0 && sn[below[i]] == sn[below[i - 1]]) continue;
            i64 t = sn[below[i]], j = i + 1;
            while (j < u && sn[below[j]] == t) j++;
            pt[p] = t;
            pa[p] = i;
            pb[p] = j;
            /* s's rows from i on, merged into t's sorted structure */
            const i64 *ts = brow + brptr[t];
            i64 tl = brptr[t + 1] - brptr[t], at = 0;
            for (i64 r = i; r < u; r++) {
                while (at < tl && ts[at] < below[r]) at++;
                if (at == tl || ts[at] != below[r]) {
                    bad = 1;
                    break;
                }
                rel[q++] = at;
            }
            p++;
            relptr[p] = q;
        }
    }
    pptr[ns] = p;
    if (bad) {
        PyErr_SetString(PyExc_AssertionError, "supernodal analysis: an update outside its target");
        goto done;
    }
    ret = Py_BuildValue("NNNNNN", opptr, opt, opa, opb, orelptr, orel);
    opptr = opt = opa = opb = orelptr = orel = NULL;
done:
    PyMem_Free(sn);
    Py_XDECREF(opptr);
    Py_XDECREF(opt);
    Py_XDECREF(opa);
    Py_XDECREF(opb);
    Py_XDECREF(orelptr);
    Py_XDECREF(orel);
    return ret;
}

static PyObject *amap(PyObject *self, PyObject *args) {
    PyObject *obptr, *obidx, *oinv, *osn, *obrptr, *obrow, *obstart, *opx;
    Py_ssize_t bs, nx;
    if (!PyArg_ParseTuple(args, "OOOOOOOOnn", &obptr, &obidx, &oinv, &osn, &obrptr, &obrow,
                          &obstart, &opx, &bs, &nx))
        return NULL;
    i64 *inv = ints(oinv, "inv", -1);
    if (!inv) return NULL;
    i64 nb = (i64)PyArray_SIZE((PyArrayObject *)oinv);
    i64 *bptr = ints(obptr, "bptr", nb + 1);
    i64 *bidx = bptr ? ints(obidx, "bidx", -1) : NULL;
    i64 *sn = bidx ? ints(osn, "sn_of", nb) : NULL;
    i64 *bstart = sn ? ints(obstart, "bstart", -1) : NULL;
    if (!bstart) return NULL;
    i64 ns = (i64)PyArray_SIZE((PyArrayObject *)obstart);
    i64 *brptr = ints(obrptr, "brptr", ns + 1);
    i64 *brow = brptr ? ints(obrow, "brow", brptr[ns]) : NULL;
    i64 *px = brow ? ints(opx, "px", ns) : NULL;
    if (!px) return NULL;
    i64 nblk = (i64)PyArray_SIZE((PyArrayObject *)obidx);
    if (bs < 1 || bptr[0] != 0 || bptr[nb] != nblk) {
        PyErr_SetString(PyExc_ValueError, "bptr does not fit bidx, or bs < 1");
        return NULL;
    }
    /* int32 when every place (and the dump slot) fits: half the memory */
    int small = nx < 2147483647;
    npy_intp dim[1] = {(npy_intp)(nblk * bs)};
    PyArrayObject *oout = (PyArrayObject *)PyArray_SimpleNew(1, dim, small ? NPY_INT32 : NPY_INT64);
    if (!oout) return NULL;
    i64 *out64 = PyArray_DATA(oout);
    npy_int32 *out32 = PyArray_DATA(oout);
#define PUT(x) (small ? (void)(out32[e++] = (npy_int32)(x)) : (void)(out64[e++] = (x)))
    int bad = 0;
    Py_BEGIN_ALLOW_THREADS
    i64 e = 0;
    for (i64 v = 0; v < nb && !bad; v++) {
        i64 V = inv[v], s = sn[V], c0 = bstart[s] * bs;
        i64 m = (brptr[s + 1] - brptr[s]) * bs;
        const i64 *st = brow + brptr[s];
        i64 sl = brptr[s + 1] - brptr[s];
        for (i64 cc = 0; cc < bs && !bad; cc++)
            for (i64 b = bptr[v]; b < bptr[v + 1]; b++) {
                i64 u = bidx[b];
                if (u < 0 || u >= nb) {
                    bad = 1;
                    break;
                }
                i64 U = inv[u];
                if (U < V) {
                    PUT(nx);
                    continue;
                }
                i64 pos = bsearch_i64(st, sl, U);
                if (pos < 0) {
                    bad = 2;
                    break;
                }
                i64 base = px[s] + (V * bs + cc - c0) * m + pos * bs;
                PUT(base);
            }
    }
    Py_END_ALLOW_THREADS
#undef PUT
    if (bad) {
        Py_DECREF(oout);
        PyErr_SetString(bad == 1 ? PyExc_ValueError : PyExc_AssertionError,
                        bad == 1 ? "bidx out of range"
                                 : "supernodal analysis: an entry outside its supernode");
        return NULL;
    }
    return (PyObject *)oout;
}

static PyMethodDef methods[] = {
    {"supernodes", supernodes, METH_VARARGS,
     "supernodes(indptr, indices, perm, relax) -> (perm, parent, counts, bstart, brptr, brow)"},
    {"updates", updates, METH_VARARGS,
     "updates(brptr, brow, bstart, nb) -> (pptr, pt, pa, pb, relptr, rel)"},
    {"amap", amap, METH_VARARGS,
     "amap(bptr, bidx, inv, sn_of, brptr, brow, bstart, px, bs, nx) -> amap"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef moddef = {PyModuleDef_HEAD_INIT, "_symbolic",
                                    "Symbolic supernodal Cholesky analysis (microlie).", -1,
                                    methods};

PyMODINIT_FUNC PyInit__symbolic(void) {
    import_array();
    return PyModule_Create(&moddef);
}
