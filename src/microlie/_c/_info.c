/* microlie._c._info: how the compiled extensions were built and which of their versions runs on
 * this CPU (see dispatch.h); read by microlie._fast.describe() (`microlie --version`). */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include "dispatch.h"

#ifndef LM_BASELINE
#define LM_BASELINE "compiler default"
#endif

static PyObject *info(PyObject *self, PyObject *unused) {
    (void)self;
    (void)unused;
#if defined(LM_CLONES) && defined(__x86_64__)
    const char *clones = "x86-64-v3,x86-64-v4";
#else
    const char *clones = "";
#endif
    return Py_BuildValue("{s:s,s:s,s:s}", "baseline", LM_BASELINE, "clones", clones, "active",
                         lm_cpu_level());
}

static PyMethodDef methods[] = {
    {"info", info, METH_NOARGS,
     "info() -> {'baseline': the ISA the extensions were compiled for, 'clones': the wider "
     "versions of the hot loops (comma-separated, '' when none), 'active': the version the "
     "loader chose on this CPU ('baseline', 'x86-64-v3' or 'x86-64-v4')}"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_info",
                                    "Build and dispatch information of microlie's compiled "
                                    "extensions.", -1, methods};

PyMODINIT_FUNC PyInit__info(void) { return PyModule_Create(&module); }
