/* microlie._c._one: one-element entry points of SO(3) and SE(3) for microlie's single-element
 * fast path (microlie/groups/_single.py).
 *
 * A call on one element costs mostly what surrounds the formula: dispatch, reading the inputs,
 * building the output array and object. Each function here takes the element objects (and a
 * tangent vector or a point) themselves, reads the parameters straight from the element's
 * `params` slot, evaluates the element operation of lie_math.h (the very formulas of the batched
 * kernels of _lie.c, with a block stride of 1), and returns the new element object (read-only
 * float64 parameters, built with one allocation each) or a fresh writable float64 array.
 *
 * Contract (the same as the Python functions of microlie.groups._single): a function returns
 * None unless its inputs are exactly what it handles: elements of exactly its group whose
 * `params` is a one-dimensional, aligned, contiguous, native float64 NumPy array (the ones
 * microlie makes), and finite one-dimensional float64 NumPy vectors of the right length. On a
 * non-finite result of exp or plus it returns None too. The caller then takes the generic path,
 * which raises the errors. `setup` is called once by microlie with the member descriptors of
 * the `params` and `_floats` slots and the SO3 and SE3 classes. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <structmember.h> /* PyMemberDef (Python 3.11) */
#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <numpy/arrayobject.h>

#define S 1 /* one element: the element operations of lie_math.h read with stride 1 */
#include "lie_math.h"

typedef void (*el_fn)(const double *a, const double *b, double *o);

enum { G_SO3, G_SE3, NGROUPS };
static const int PARAM_DIM[NGROUPS] = {4, 7};

typedef struct {
    int group;
    const char *ins; /* "t" tangent, "e" element, "ee" two elements, "et", "ev" */
    int kin;         /* width of the vector input ("t", "v"), 0 if none */
    int out_element; /* 1: the output is an element, 0: a vector of width kout */
    int kout;
    int finite; /* a tangent input: check the result for NaN/inf (as the generic kernel) */
    el_fn fn;
} op;

static Py_ssize_t params_off = -1, floats_off = -1;
static PyTypeObject *types[NGROUPS];

/* the parameters of x, if x is a single float64 element of exactly group g */
static inline const double *element_data(PyObject *x, int g) {
    if (Py_TYPE(x) != types[g]) return NULL;
    PyObject *p = *(PyObject **)((char *)x + params_off);
    if (!p || !PyArray_CheckExact(p)) return NULL;
    PyArrayObject *a = (PyArrayObject *)p;
    if (PyArray_NDIM(a) != 1 || PyArray_DIM(a, 0) != PARAM_DIM[g] ||
        PyArray_TYPE(a) != NPY_DOUBLE || !PyArray_ISCARRAY_RO(a))
        return NULL;
    return (const double *)PyArray_DATA(a);
}

/* the entries of v, if v is one finite float64 vector of length k */
static inline const double *vector_data(PyObject *v, int k) {
    if (!PyArray_CheckExact(v)) return NULL;
    PyArrayObject *a = (PyArrayObject *)v;
    if (PyArray_NDIM(a) != 1 || PyArray_DIM(a, 0) != k || PyArray_TYPE(a) != NPY_DOUBLE ||
        !PyArray_ISCARRAY_RO(a))
        return NULL;
    const double *d = (const double *)PyArray_DATA(a);
    double s = 0.0;
    for (int i = 0; i < k; i++) s += d[i] * 0.0; /* NaN for NaN or inf entries */
    return s == 0.0 ? d : NULL;
}

static PyObject *call(const op *k, PyObject *const *args, Py_ssize_t nargs) {
    int nin = (int)strlen(k->ins);
    if (nargs != nin) {
        PyErr_Format(PyExc_TypeError, "expected %d arguments, got %zd", nin, nargs);
        return NULL;
    }
    if (params_off < 0) {
        PyErr_SetString(PyExc_RuntimeError, "microlie._c._one.setup was not called");
        return NULL;
    }
    const double *a = NULL, *b = NULL;
    if (k->ins[0] == 't') {
        a = vector_data(args[0], k->kin);
    } else {
        a = element_data(args[0], k->group);
        if (a && nin == 2)
            b = k->ins[1] == 'e' ? element_data(args[1], k->group)
                                 : vector_data(args[1], k->kin);
        if (nin == 2 && !b) a = NULL;
    }
    if (!a) Py_RETURN_NONE;
    double r[8];
    k->fn(a, b, r);
    if (k->finite) {
        double s = 0.0;
        for (int i = 0; i < k->kout; i++) s += r[i] * 0.0;
        if (s != 0.0) Py_RETURN_NONE;
    }
    npy_intp n = k->kout;
    PyObject *arr = PyArray_SimpleNew(1, &n, NPY_DOUBLE);
    if (!arr) return NULL;
    memcpy(PyArray_DATA((PyArrayObject *)arr), r, sizeof(double) * (size_t)k->kout);
    if (!k->out_element) return arr;
    PyArray_CLEARFLAGS((PyArrayObject *)arr, NPY_ARRAY_WRITEABLE);
    PyTypeObject *t = types[k->group];
    PyObject *obj = t->tp_alloc(t, 0);
    if (!obj) {
        Py_DECREF(arr);
        return NULL;
    }
    *(PyObject **)((char *)obj + params_off) = arr; /* the new reference moves in */
    Py_INCREF(Py_None);
    *(PyObject **)((char *)obj + floats_off) = Py_None;
    return obj;
}

/* name, group, inputs, vector width, output is an element, output width, finite, function */
#define OPS(X)                                                                                 \
    X(so3_exp, G_SO3, "t", 3, 1, 4, 1, so3_exp)                                                \
    X(so3_log, G_SO3, "e", 0, 0, 3, 0, so3_log)                                                \
    X(so3_inverse, G_SO3, "e", 0, 1, 4, 0, so3_inverse)                                        \
    X(so3_compose, G_SO3, "ee", 0, 1, 4, 0, so3_compose)                                       \
    X(so3_between, G_SO3, "ee", 0, 1, 4, 0, so3_between)                                       \
    X(so3_act, G_SO3, "ev", 3, 0, 3, 0, so3_act)                                               \
    X(so3_plus, G_SO3, "et", 3, 1, 4, 1, so3_plus)                                             \
    X(so3_minus, G_SO3, "ee", 0, 0, 3, 0, so3_minus)                                           \
    X(se3_exp, G_SE3, "t", 6, 1, 7, 1, se3_exp)                                                \
    X(se3_log, G_SE3, "e", 0, 0, 6, 0, se3_log)                                                \
    X(se3_inverse, G_SE3, "e", 0, 1, 7, 0, se3_inverse)                                        \
    X(se3_compose, G_SE3, "ee", 0, 1, 7, 0, se3_compose)                                       \
    X(se3_between, G_SE3, "ee", 0, 1, 7, 0, se3_between)                                       \
    X(se3_act, G_SE3, "ev", 3, 0, 3, 0, se3_act)                                               \
    X(se3_plus, G_SE3, "et", 6, 1, 7, 1, se3_plus)                                             \
    X(se3_minus, G_SE3, "ee", 0, 0, 6, 0, se3_minus)

/* the element operations as plain functions (lie_math.h's are always inlined) */
#define WRAP(NAME, G, INS, KIN, OUTE, KOUT, FIN, FN)                                           \
    static void el_##NAME(const double *a, const double *b, double *o) { FN(a, b, o); }       \
    static const op k_##NAME = {G, INS, KIN, OUTE, KOUT, FIN, el_##NAME};                     \
    static PyObject *py_##NAME(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {    \
        (void)self;                                                                            \
        return call(&k_##NAME, args, nargs);                                                   \
    }
OPS(WRAP)

static Py_ssize_t slot_offset(PyObject *d, const char *what) {
    if (!PyObject_TypeCheck(d, &PyMemberDescr_Type)) {
        PyErr_Format(PyExc_TypeError, "setup: %s must be a slot's member descriptor", what);
        return -1;
    }
    return ((PyMemberDescrObject *)d)->d_member->offset;
}

static PyObject *setup(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 4) {
        PyErr_SetString(PyExc_TypeError,
                        "setup(params_descriptor, floats_descriptor, SO3, SE3)");
        return NULL;
    }
    Py_ssize_t po = slot_offset(args[0], "params_descriptor");
    Py_ssize_t fo = po < 0 ? -1 : slot_offset(args[1], "floats_descriptor");
    if (fo < 0) return NULL;
    for (int g = 0; g < NGROUPS; g++) {
        PyObject *t = args[2 + g];
        if (!PyType_Check(t) || ((PyTypeObject *)t)->tp_basicsize < (po > fo ? po : fo) +
                                                                      (Py_ssize_t)sizeof(void *)) {
            PyErr_SetString(PyExc_TypeError, "setup: SO3 and SE3 must be the element classes");
            return NULL;
        }
    }
    for (int g = 0; g < NGROUPS; g++) {
        Py_INCREF(args[2 + g]);
        Py_XSETREF(types[g], (PyTypeObject *)args[2 + g]);
    }
    params_off = po;
    floats_off = fo;
    Py_RETURN_NONE;
}

#define ENTRY(NAME, ...) {#NAME, (PyCFunction)(void (*)(void))py_##NAME, METH_FASTCALL, NULL},
static PyMethodDef methods[] = {
    {"setup", (PyCFunction)(void (*)(void))setup, METH_FASTCALL,
     "setup(params_descriptor, floats_descriptor, SO3, SE3): the element layout and classes."},
    OPS(ENTRY){NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_one",
                                    "One-element SO(3)/SE(3) entry points for microlie.", -1,
                                    methods};

PyMODINIT_FUNC PyInit__one(void) {
    import_array();
    PyObject *m = PyModule_Create(&module);
    if (!m) return NULL;
    /* OPS: {"SE3": {"exp": "se3_exp", ...}, "SO3": {...}} */
    PyObject *d = PyDict_New();
    if (!d || PyModule_AddObject(m, "OPS", d) < 0) {
        Py_XDECREF(d);
        Py_DECREF(m);
        return NULL;
    }
    static const char *const names[] = {
#define NAME(N, ...) #N,
        OPS(NAME)
#undef NAME
    };
    for (size_t i = 0; i < sizeof(names) / sizeof(names[0]); i++) {
        const char *n = names[i]; /* "se3_exp" -> group "SE3", operation "exp" */
        char group[4] = {(char)(n[0] - 32), (char)(n[1] - 32), n[2], 0};
        PyObject *g = PyDict_GetItemString(d, group);
        if (!g) {
            g = PyDict_New();
            if (!g || PyDict_SetItemString(d, group, g) < 0) {
                Py_XDECREF(g);
                Py_DECREF(m);
                return NULL;
            }
            Py_DECREF(g); /* d holds it */
        }
        PyObject *s = PyUnicode_FromString(n);
        if (!s || PyDict_SetItemString(g, n + 4, s) < 0) {
            Py_XDECREF(s);
            Py_DECREF(m);
            return NULL;
        }
        Py_DECREF(s);
    }
    return m;
}
