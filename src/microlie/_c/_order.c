/* microlie._c._order: an approximate minimum degree ordering of a symmetric graph.
 *
 * The method of Amestoy, Davis and Duff (SIAM J. Matrix Anal. Appl. 17(4), 1996), written here
 * from the paper's description:
 *
 *  - the quotient graph: every node is a variable (not yet eliminated) or an element (an
 *    eliminated pivot standing for the clique its elimination made). A variable keeps the
 *    elements it belongs to (E_i) and the variables it still touches directly (A_i); an element
 *    keeps its variables (L_e). Eliminating a pivot p turns it into an element whose list is
 *    A_p united with the L_e of its elements, which are absorbed (their storage is freed).
 *  - approximate external degrees: for a variable i of the new element p,
 *        d_i = min(n - k, d_i_old + |L_p \ i|, |A_i \ i| + |L_p \ i| + sum_e |L_e \ L_p|)
 *    with |L_e \ L_p| found for all elements at once by one pass over L_p (the w counters);
 *  - aggressive absorption: an element with |L_e \ L_p| = 0 is inside L_p and is absorbed;
 *  - supervariables: variables of L_p with the same E_i and A_i (found by a hash, then
 *    compared) are merged and eliminated together; mass elimination: a variable whose only
 *    neighbour is the new element is eliminated with the pivot.
 *  - dense nodes (degree above max(16, 10 sqrt(n))) are left out and ordered last.
 *
 * Storage: one integer array holds every list; a new element list goes at its free end, and
 * when that end is reached the live lists are compacted to the front (each live list marks
 * its first slot with the negated node id so that one left-to-right pass finds them).
 *
 *  - ties: which of the variables of least degree is taken decides much on regular graphs
 *    (a sphere: 1.4x the flops of another rule). Both the most recently and the earliest
 *    updated are run, and the order with fewer factorisation flops kept; the flops are exact
 *    (the column of a pivot in L is its element's list, known when it is formed).
 *
 * Entry point: order(indptr, indices, n, ties=0) -> intp array, the order new -> old, for the
 * symmetric pattern given as CSR (any diagonal and repeated entries are ignored);
 * ValueError if the pattern is out of range or not symmetric. */

#define PY_SSIZE_T_CLEAN
#include <Python.h>
#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <numpy/arrayobject.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "array_args.h"

enum { VARIABLE = 0, ELEMENT = 1, DEAD = 2 };

typedef struct {
    ix n, cap, pfree;
    ix *iw;                    /* the lists */
    ix *pe, *len, *elen;       /* start, length, number of elements first (variables) */
    ix *nv;                    /* supervariable weight (0: merged away; < 0: in the new L_p) */
    ix *deg;                   /* variable: approximate external degree; element: |L_e| */
    ix *head, *next, *prev;    /* degree lists */
    ix *link;                  /* merged / mass-eliminated variable -> its representative */
    ix *hhead, *hnext, *hval;  /* hash buckets of supervariable detection */
    int64_t *w, wflg;          /* element counters |L_e \ L_p| + wflg; 0: absorbed */
    int64_t *mark, mflg;       /* stamp of the list comparison */
    ix *tail;                  /* degree lists' last nodes (fifo) */
    int fifo;                  /* ties: the most recent (0) or the earliest (1) of a degree */
    char *status;
} Amd;

static void dl_remove(Amd *a, ix i) {
    ix nx = a->next[i], pv = a->prev[i];
    if (nx < 0) a->tail[a->deg[i]] = pv;
    if (nx >= 0) a->prev[nx] = pv;
    if (pv >= 0) a->next[pv] = nx;
    else a->head[a->deg[i]] = nx;
}

static void dl_insert(Amd *a, ix i, ix d) {
    a->deg[i] = d;
    if (a->fifo) {
        ix t = a->tail[d];
        a->next[i] = -1;
        a->prev[i] = t;
        if (t >= 0) a->next[t] = i; else a->head[d] = i;
        a->tail[d] = i;
        return;
    }
    ix h = a->head[d];
    a->next[i] = h;
    a->prev[i] = -1;
    if (h >= 0) a->prev[h] = i;
    a->head[d] = i;
}

/* compact the live lists to the front of iw */
static void compact(Amd *a) {
    ix n = a->n, *iw = a->iw;
    for (ix j = 0; j < n; j++) {
        if (a->status[j] == DEAD || a->len[j] == 0) continue;
        if (a->status[j] == VARIABLE && a->nv[j] == 0) continue;
        ix p = a->pe[j];
        a->pe[j] = iw[p];    /* the first entry, kept while its slot carries the mark */
        iw[p] = -(j + 1);
    }
    ix dst = 0, src = 0;
    while (src < a->pfree) {
        if (iw[src] >= 0) { src++; continue; }
        ix j = -iw[src] - 1, l = a->len[j];
        iw[dst] = a->pe[j];
        a->pe[j] = dst;
        for (ix k = 1; k < l; k++) iw[dst + k] = iw[src + k];
        dst += l;
        src += l;
    }
    a->pfree = dst;
}

static void new_wflg(Amd *a) {
    a->wflg += a->n + 2;
    if (a->wflg > INT64_MAX / 4) {
        for (ix e = 0; e < a->n; e++)
            if (a->w[e] != 0) a->w[e] = 1;
        a->wflg = 2;
    }
}

/* the order (new -> old) of the graph whose deduplicated, diagonal-free adjacency is in
 * (ap, ai); dense nodes last. Returns 0, or -1 when out of memory. */
static int amd_order(ix n, const ix *ap, const ix *ai, int fifo, ix *order, double *flops_out) {
    *flops_out = 0.0;
    if (n == 0) return 0;
    double dth = 10.0 * sqrt((double)n);
    ix dense = (ix)(dth < 16.0 ? 16.0 : dth);
    Amd a;
    memset(&a, 0, sizeof a);
    a.n = n;
    ix nnz = ap[n];
    a.cap = nnz + nnz / 5 + 2 * n + 16;
    ix *q = malloc(sizeof(ix) * (size_t)(17 * n + 2));
    a.iw = malloc(sizeof(ix) * (size_t)a.cap);
    a.w = malloc(sizeof(int64_t) * (size_t)(2 * n));
    a.status = malloc((size_t)n);
    ix *step = malloc(sizeof(ix) * (size_t)(2 * n + 1));
    if (!q || !a.iw || !a.w || !a.status || !step) {
        free(q); free(a.iw); free(a.w); free(a.status); free(step);
        return -1;
    }
    a.pe = q; a.len = q + n; a.elen = q + 2 * n; a.nv = q + 3 * n; a.deg = q + 4 * n;
    a.head = q + 5 * n; a.next = q + 6 * n + 1; a.prev = q + 7 * n + 1; a.link = q + 8 * n + 1;
    a.hhead = q + 9 * n + 1; a.hnext = q + 10 * n + 1; a.hval = q + 11 * n + 1;
    ix *lp_tmp = q + 12 * n + 1;  /* the variables of the new element */
    ix *isdense = q + 13 * n + 1;
    ix *pivots = q + 14 * n + 1;
    ix *hlist = q + 15 * n + 1;   /* the hash buckets in use */
    a.tail = q + 16 * n + 1;      /* n + 1 */
    a.fifo = fifo;
    a.mark = a.w + n;

    /* the graph without its dense nodes */
    ix ndense = 0;
    for (ix i = 0; i < n; i++) {
        isdense[i] = (ap[i + 1] - ap[i]) > dense;
        ndense += isdense[i];
    }
    ix pos = 0;
    for (ix i = 0; i < n; i++) {
        a.pe[i] = pos;
        if (!isdense[i])
            for (ix p = ap[i]; p < ap[i + 1]; p++)
                if (!isdense[ai[p]]) a.iw[pos++] = ai[p];
        a.len[i] = pos - a.pe[i];
        a.elen[i] = 0;
        a.nv[i] = 1;
        a.link[i] = -1;
        a.w[i] = 1;
        a.mark[i] = 0;
        a.hhead[i] = -1;
        a.status[i] = isdense[i] ? DEAD : VARIABLE;
    }
    a.pfree = pos;
    a.wflg = 2;
    a.mflg = 0;
    for (ix d = 0; d <= n; d++) a.head[d] = -1, a.tail[d] = -1;
    for (ix i = 0; i < n; i++)
        if (!isdense[i]) dl_insert(&a, i, a.len[i]);

    ix nel = ndense, mindeg = 0, npiv = 0;
    double flops = 0.0;
    while (nel < n) {
        /* 1. the pivot: a variable of least approximate degree */
        while (mindeg <= n && a.head[mindeg] < 0) mindeg++;
        ix me = a.head[mindeg];
        dl_remove(&a, me);
        pivots[npiv++] = me;
        ix nvpiv = a.nv[me];
        nel += nvpiv;
        a.nv[me] = -nvpiv;

        /* 2. L_me: A_me and the variables of the elements of me (absorbed) */
        ix p0 = a.pe[me], le = a.len[me], ne = a.elen[me];
        ix lme = 0, degme = 0;
        for (ix k = 0; k < le; k++) {
            ix x = a.iw[p0 + k];
            if (k < ne) {  /* an element: its variables, then absorb it */
                if (a.w[x] == 0) continue;
                ix pe2 = a.pe[x];
                for (ix t = 0; t < a.len[x]; t++) {
                    ix v = a.iw[pe2 + t];
                    ix nvv = a.nv[v];
                    if (nvv <= 0) continue;
                    degme += nvv;
                    a.nv[v] = -nvv;
                    lp_tmp[lme++] = v;
                    dl_remove(&a, v);
                }
                a.w[x] = 0;
                a.status[x] = DEAD;
                a.len[x] = 0;
            } else {
                ix nvv = a.nv[x];
                if (nvv <= 0) continue;
                degme += nvv;
                a.nv[x] = -nvv;
                lp_tmp[lme++] = x;
                dl_remove(&a, x);
            }
        }
        /* me becomes an element; its old list is garbage */
        a.status[me] = ELEMENT;
        a.elen[me] = -1;
        a.len[me] = 0;
        if (a.pfree + lme > a.cap) {
            compact(&a);
            if (a.pfree + lme > a.cap) {  /* not expected (the new list fits in the freed) */
                ix c2 = a.pfree + lme + n;
                ix *iw2 = realloc(a.iw, sizeof(ix) * (size_t)c2);
                if (!iw2) { free(q); free(a.iw); free(a.w); free(a.status); free(step); return -1; }
                a.iw = iw2;
                a.cap = c2;
            }
        }
        ix start = a.pfree;
        memcpy(a.iw + start, lp_tmp, sizeof(ix) * (size_t)lme);
        a.pe[me] = start;
        a.len[me] = lme;
        a.pfree = start + lme;

        /* 3. |L_e \ L_me| for every element e touching L_me */
        new_wflg(&a);
        int64_t wflg = a.wflg;
        for (ix k = 0; k < lme; k++) {
            ix i = lp_tmp[k], nvi = -a.nv[i];
            ix pi = a.pe[i];
            for (ix t = 0; t < a.elen[i]; t++) {
                ix e = a.iw[pi + t];
                int64_t we = a.w[e];
                if (we >= wflg) a.w[e] = we - nvi;
                else if (we != 0) a.w[e] = a.deg[e] + wflg - nvi;
            }
        }

        /* 4. degree update, pruning, aggressive absorption, mass elimination, hashing */
        ix nhash = 0;
        for (ix k = 0; k < lme; k++) {
            ix i = lp_tmp[k], pi = a.pe[i], li = a.len[i], ei = a.elen[i];
            int64_t d = 0;
            uint64_t h = 0;
            ix dst = pi, ne2 = 0;
            for (ix t = 0; t < ei; t++) {
                ix e = a.iw[pi + t];
                int64_t we = a.w[e];
                if (we == 0) continue;
                int64_t ext = we - wflg;
                if (ext > 0) {
                    d += ext;
                    a.iw[dst++] = e;
                    ne2++;
                    h += (uint64_t)e;
                } else {  /* aggressive absorption: L_e inside L_me */
                    a.w[e] = 0;
                    a.status[e] = DEAD;
                    a.len[e] = 0;
                }
            }
            ix nvar = 0;
            for (ix t = ei; t < li; t++) {
                ix j = a.iw[pi + t], nvj = a.nv[j];
                if (nvj <= 0 || a.status[j] != VARIABLE) continue;
                d += nvj;
                a.iw[dst++] = j;
                nvar++;
                h += (uint64_t)j;
            }
            ix l2 = dst - pi;
            if (l2 >= li) {  /* no slot freed for me: the quotient graph is inconsistent */
                free(q); free(a.iw); free(a.w); free(a.status); free(step);
                return -2;
            }
            /* me first: the first kept variable to the end, the first element after the others */
            a.iw[pi + l2] = a.iw[pi + ne2];
            a.iw[pi + ne2] = a.iw[pi];
            a.iw[pi] = me;
            ne2++;
            a.elen[i] = ne2;
            a.len[i] = l2 + 1;
            if (ne2 == 1 && nvar == 0) {  /* mass elimination with me */
                ix nvi = -a.nv[i];
                degme -= nvi;
                nvpiv += nvi;
                nel += nvi;
                a.nv[i] = 0;
                a.status[i] = DEAD;
                a.link[i] = me;
                a.len[i] = 0;
                continue;
            }
            if (d < a.deg[i]) a.deg[i] = (ix)d;
            ix hv = (ix)(h % (uint64_t)n);
            if (a.hhead[hv] < 0) hlist[nhash++] = hv;
            a.hnext[i] = a.hhead[hv];
            a.hhead[hv] = i;
        }
        a.deg[me] = degme;

        /* 5. supervariables: the variables of a bucket with identical lists are merged */
        for (ix b = 0; b < nhash; b++) {
            ix hv = hlist[b];
            for (ix i = a.hhead[hv]; i >= 0; i = a.hnext[i]) {
                if (a.nv[i] == 0) continue;
                ix li = a.len[i], ei = a.elen[i], pi = a.pe[i];
                int marked = 0;
                for (ix j = a.hnext[i]; j >= 0; j = a.hnext[j]) {
                    if (a.nv[j] == 0 || a.len[j] != li || a.elen[j] != ei) continue;
                    if (!marked) {
                        a.mflg++;
                        for (ix t = 0; t < li; t++) a.mark[a.iw[pi + t]] = a.mflg;
                        marked = 1;
                    }
                    ix pj = a.pe[j], t = 0;
                    while (t < li && a.mark[a.iw[pj + t]] == a.mflg) t++;
                    if (t < li) continue;
                    a.nv[i] += a.nv[j];  /* both negative */
                    a.nv[j] = 0;
                    a.status[j] = DEAD;
                    a.link[j] = i;
                    a.len[j] = 0;
                }
            }
            a.hhead[hv] = -1;
        }

        /* 6. final degrees, back into the degree lists; L_me keeps its principal variables */
        ix keep = 0, pme = a.pe[me];
        for (ix k = 0; k < a.len[me]; k++) {
            ix i = a.iw[pme + k];
            if (a.nv[i] >= 0) continue;  /* merged or mass-eliminated */
            ix nvi = -a.nv[i];
            a.nv[i] = nvi;
            ix d = a.deg[i] + degme - nvi, cap = n - nel - nvi;
            if (d > cap) d = cap;
            if (d < 0) d = 0;
            dl_insert(&a, i, d);
            if (d < mindeg) mindeg = d;
            a.iw[pme + keep++] = i;
        }
        a.len[me] = keep;
        a.nv[me] = nvpiv;
        for (ix c = degme + 1; c <= degme + nvpiv; c++) flops += (double)c * (double)c;
        if (keep == 0) a.status[me] = DEAD, a.w[me] = 0;
        a.pfree = pme + keep;
    }

    /* the order: each pivot, then the variables merged into it or eliminated with it */
    for (ix i = 0; i < n; i++) step[i] = -1;
    for (ix k = 0; k < npiv; k++) step[pivots[k]] = k;
    ix *cnt = step + n;  /* npiv + 1 counters */
    for (ix k = 0; k <= npiv; k++) cnt[k] = 0;
    for (ix i = 0; i < n; i++) {  /* the pivot of each sparse node, with path compression */
        if (isdense[i]) continue;
        ix r = i;
        while (step[r] < 0) r = a.link[r];
        ix x = i;
        while (step[x] < 0) { ix nx = a.link[x]; a.link[x] = r; x = nx; }
        a.hval[i] = step[r];
        cnt[step[r] + 1]++;
    }
    for (ix k = 0; k < npiv; k++) cnt[k + 1] += cnt[k];
    for (ix k = 0; k < npiv; k++) order[cnt[k]++] = pivots[k];  /* the pivot first */
    for (ix i = 0; i < n; i++)
        if (!isdense[i] && step[i] < 0) order[cnt[a.hval[i]]++] = i;
    ix o = n - ndense;
    for (ix i = 0; i < n; i++)
        if (isdense[i]) order[o++] = i;
    for (ix k = 0; k < n - ndense; k++)  /* the dense nodes: in every column (a bound) */
        flops += (double)ndense * (2.0 * (double)ndense);
    for (ix c = 1; c <= ndense; c++) flops += (double)c * (double)c;
    *flops_out = flops;
    free(q); free(a.iw); free(a.w); free(a.status); free(step);
    return 0;
}

static PyObject *order_(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 3 && nargs != 4) {
        PyErr_SetString(PyExc_TypeError, "order(indptr, indices, n, ties=0)");
        return NULL;
    }
    long ties = nargs == 4 ? PyLong_AsLong(args[3]) : 0;
    if (ties == -1 && PyErr_Occurred()) return NULL;
    if (ties < 0 || ties > 2) {
        PyErr_SetString(PyExc_ValueError, "ties must be 0 (both, the better), 1 (latest) or 2 (earliest)");
        return NULL;
    }
    ix n = PyLong_AsSsize_t(args[2]);
    if (n == -1 && PyErr_Occurred()) return NULL;
    if (n < 0) {
        PyErr_SetString(PyExc_ValueError, "n must be >= 0");
        return NULL;
    }
    ix dims1[1] = {n + 1}, dimsx[1] = {-1};
    PyArrayObject *Pa = arg(args[0], "indptr", NPY_INTP, 1, dims1);
    if (!Pa) return NULL;
    PyArrayObject *Ia = arg(args[1], "indices", NPY_INTP, 1, dimsx);
    if (!Ia) return NULL;
    const ix *ap = PyArray_DATA(Pa), *ai = PyArray_DATA(Ia);
    ix m = PyArray_DIM(Ia, 0);
    if (ap[0] != 0 || ap[n] > m) {
        PyErr_SetString(PyExc_ValueError,
                        "indptr must start at 0 and end at most at len(indices)");
        return NULL;
    }
    for (ix i = 0; i < n; i++)
        if (ap[i + 1] < ap[i]) {
            PyErr_SetString(PyExc_ValueError, "indptr must be non-decreasing");
            return NULL;
        }
    ix nnz = ap[n];
    for (ix p = 0; p < nnz; p++)
        if (ai[p] < 0 || ai[p] >= n) {
            PyErr_Format(PyExc_ValueError, "indices must be in [0, %zd): found %zd",
                         (Py_ssize_t)n, (Py_ssize_t)ai[p]);
            return NULL;
        }
    npy_intp od[1] = {n};
    PyArrayObject *out = (PyArrayObject *)PyArray_SimpleNew(1, od, NPY_INTP);
    if (!out) return NULL;
    /* deduplicated, diagonal-free adjacency, and its transpose to check the symmetry */
    ix *bp = malloc(sizeof(ix) * (size_t)(2 * (n + 1))), *bi = malloc(sizeof(ix) * (size_t)(2 * nnz + 1));
    ix *mk = malloc(sizeof(ix) * (size_t)(n + 1));
    int bad = 0, rc = 0, oom = !bp || !bi || !mk;
    if (!oom) {
        ix *tp = bp + n + 1, *ti = bi + nnz, pos = 0;
        for (ix i = 0; i < n; i++) mk[i] = -1;
        for (ix i = 0; i < n; i++) {
            bp[i] = pos;
            for (ix p = ap[i]; p < ap[i + 1]; p++) {
                ix j = ai[p];
                if (j == i || mk[j] == i) continue;
                mk[j] = i;
                bi[pos++] = j;
            }
        }
        bp[n] = pos;
        for (ix i = 0; i <= n; i++) tp[i] = 0;
        for (ix p = 0; p < pos; p++) tp[bi[p] + 1]++;
        for (ix i = 0; i < n; i++) tp[i + 1] += tp[i];
        for (ix i = 0; i < n; i++) mk[i] = tp[i];
        for (ix i = 0; i < n; i++)
            for (ix p = bp[i]; p < bp[i + 1]; p++) ti[mk[bi[p]]++] = i;
        for (ix i = 0; i < n; i++) mk[i] = -1;
        for (ix i = 0; i < n && !bad; i++) {
            if (tp[i + 1] - tp[i] != bp[i + 1] - bp[i]) { bad = 1; break; }
            for (ix p = bp[i]; p < bp[i + 1]; p++) mk[bi[p]] = i;
            for (ix p = tp[i]; p < tp[i + 1]; p++)
                if (mk[ti[p]] != i) { bad = 1; break; }
        }
        free(mk);
        mk = NULL;
        if (!bad) {
            Py_BEGIN_ALLOW_THREADS
            /* ties among least degrees decide much on regular graphs: both rules, the one
             * with fewer factorisation flops (counted exactly from the elements) kept */
            ix *o2 = ties == 0 ? malloc(sizeof(ix) * (size_t)(n + 1)) : NULL;
            double f1 = 0, f2 = 0;
            if (ties == 0 && !o2) rc = -1;
            else rc = amd_order(n, bp, bi, ties == 2, PyArray_DATA(out), &f1);
            if (ties == 0 && rc == 0) {
                rc = amd_order(n, bp, bi, 1, o2, &f2);
                if (rc == 0 && f2 < f1)
                    memcpy(PyArray_DATA(out), o2, sizeof(ix) * (size_t)n);
            }
            free(o2);
            Py_END_ALLOW_THREADS
        }
    }
    free(bp); free(bi); free(mk);
    oom = oom || rc == -1;
    if (rc == -2) {
        Py_DECREF(out);
        PyErr_SetString(PyExc_RuntimeError, "_order: internal inconsistency (a bug)");
        return NULL;
    }
    if (oom || bad) {
        Py_DECREF(out);
        if (oom) return PyErr_NoMemory();
        PyErr_SetString(PyExc_ValueError,
                        "the pattern must be symmetric: (i, j) present iff (j, i) present");
        return NULL;
    }
    return (PyObject *)out;
}

/* postorder(parent) -> intp array: a postorder of the forest parent (-1: a root; any
 * labels), children before their parent, each subtree contiguous, children and roots in
 * ascending order */
static PyObject *postorder_(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 1) {
        PyErr_SetString(PyExc_TypeError, "postorder(parent)");
        return NULL;
    }
    ix dx[1] = {-1};
    PyArrayObject *Pa = arg(args[0], "parent", NPY_INTP, 1, dx);
    if (!Pa) return NULL;
    ix n = PyArray_DIM(Pa, 0);
    const ix *parent = PyArray_DATA(Pa);
    for (ix j = 0; j < n; j++)
        if (parent[j] < -1 || parent[j] >= n || parent[j] == j) {
            PyErr_SetString(PyExc_ValueError, "parent must hold -1 or another node's index");
            return NULL;
        }
    npy_intp od[1] = {n};
    PyArrayObject *out = (PyArrayObject *)PyArray_SimpleNew(1, od, NPY_INTP);
    if (!out) return NULL;
    ix *post = PyArray_DATA(out);
    ix *w = malloc(sizeof(ix) * (size_t)(3 * n + 1));
    if (!w) {
        Py_DECREF(out);
        return PyErr_NoMemory();
    }
    ix *head = w, *next = w + n + 1, *stack = w + 2 * n + 1, k = 0, bad = 0;
    for (ix j = 0; j <= n; j++) head[j] = -1;
    for (ix j = n - 1; j >= 0; j--) {  /* children lists in ascending order; roots under n */
        ix p = parent[j] < 0 ? n : parent[j];
        next[j] = head[p];
        head[p] = j;
    }
    for (ix r = head[n]; r >= 0; r = next[r]) {
        ix top = 0;
        stack[top++] = r;
        while (top > 0) {  /* head[] is consumed: the next child to visit */
            ix v = stack[top - 1], c = head[v];
            if (c >= 0) {
                head[v] = next[c];
                stack[top++] = c;
            } else {
                post[k++] = v;
                top--;
            }
        }
    }
    bad = k != n;  /* a cycle: nodes not reached from a root */
    free(w);
    if (bad) {
        Py_DECREF(out);
        PyErr_SetString(PyExc_ValueError, "parent must be a forest (it has a cycle)");
        return NULL;
    }
    return (PyObject *)out;
}

static PyMethodDef methods[] = {
    {"postorder", (PyCFunction)(void (*)(void))postorder_, METH_FASTCALL,
     "postorder(parent) -> intp array: a postorder of the forest (children ascending)."},
    {"order", (PyCFunction)(void (*)(void))order_, METH_FASTCALL,
     "order(indptr, indices, n, ties=0) -> intp array: approximate minimum degree order "
     "(new -> old) of the symmetric CSR pattern (n x n, intp arrays; diagonal and repeats "
     "ignored). ties: among variables of least degree take the latest updated (1), the "
     "earliest (2), or run both and keep the order of fewer factorisation flops (0)."},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_order",
                                    "Approximate minimum degree ordering.", -1, methods};

PyMODINIT_FUNC PyInit__order(void) {
    import_array();
    return PyModule_Create(&module);
}
