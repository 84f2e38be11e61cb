/* microlie._c: the argument check the array-taking modules share (_normal.c, _reproj.c).
 * Include after Python.h and numpy/arrayobject.h. */
#ifndef MICROLIE_FAST_ARRAY_ARGS_H
#define MICROLIE_FAST_ARRAY_ARGS_H

typedef npy_intp ix;

/* o as a C-contiguous array of type t with nd axes; dims[k] >= 0 must match */
static PyArrayObject *arg(PyObject *o, const char *name, int t, int nd, const ix *dims) {
    if (!PyArray_Check(o) || PyArray_TYPE((PyArrayObject *)o) != t ||
        PyArray_NDIM((PyArrayObject *)o) != nd || !PyArray_IS_C_CONTIGUOUS((PyArrayObject *)o)) {
        PyErr_Format(PyExc_ValueError, "%s must be a C-contiguous %s array with %d axes",
                     name, t == NPY_DOUBLE ? "float64" : t == NPY_BOOL ? "bool" : "intp", nd);
        return NULL;
    }
    PyArrayObject *a = (PyArrayObject *)o;
    for (int k = 0; k < nd; k++)
        if (dims[k] >= 0 && PyArray_DIM(a, k) != dims[k]) {
            PyErr_Format(PyExc_ValueError, "%s has length %zd on axis %d, expected %zd",
                         name, (Py_ssize_t)PyArray_DIM(a, k), k, (Py_ssize_t)dims[k]);
            return NULL;
        }
    return a;
}

#endif
