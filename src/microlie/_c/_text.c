/* microlie._c._text: a compiled reader of numeric text tables (trajectory files).
 *
 * parse_table(data: bytes, ncols: int, comma: bool, at_least: bool) -> ndarray | None
 *
 * The float64 matrix (rows, ncols) of the data lines of `data`, or None when anything falls
 * outside the plain grammar below; the caller then re-reads the file with its careful path, which
 * names the bad line. Grammar (ASCII only):
 *
 *   - lines end at '\n' (a '\r' right before it is dropped); any other line break of
 *     str.splitlines ('\r' alone, '\v', '\f', '\x1c'-'\x1e'), any other control byte but '\t',
 *     or a byte >= 0x80 gives None;
 *   - a line that is blank or whose first non-blank byte is '#' or '%' is skipped;
 *   - fields: separated by runs of ' ' / '\t' (comma == 0; a ',' anywhere gives None), or by
 *     ',' with optional ' ' / '\t' around (comma == 1);
 *   - a field is [+-] digits [. digits] [(e|E) [+-] digits], at least one mantissa digit (the
 *     subset of Python's float() syntax without '_', inf and nan);
 *   - every data line has exactly ncols fields (at_least: at least ncols; the fields after the
 *     first ncols are not read).
 *
 * Values are bit-identical to Python's float() (and so to numpy.loadtxt): a field whose
 * decimal mantissa M has at most 19 significant digits, M <= 2^53 and a decimal exponent k with
 * |k| <= 22 is M * 10^k or M / 10^-k, one IEEE operation on two exact doubles, hence the
 * correctly rounded value (Clinger's fast path); every other field is converted by
 * PyOS_string_to_double, the function float() uses. A non-finite result gives None. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <numpy/arrayobject.h>

#include <stdint.h>
#include <string.h>

static const double POW10[23] = {1e0,  1e1,  1e2,  1e3,  1e4,  1e5,  1e6,  1e7,
                                 1e8,  1e9,  1e10, 1e11, 1e12, 1e13, 1e14, 1e15,
                                 1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22};

#define MAX_SLOW_FIELD 512 /* longer fields than this in the slow path: None */

/* 0: no byte that sends the file to the careful path; else 1. Counts the '\n' bytes. Blocks of
 * 255 bytes with byte-wide counters, so that the compiler vectorises the inner loop. */
static int prescan(const unsigned char *s, Py_ssize_t n, Py_ssize_t *newlines, int comma) {
    Py_ssize_t nl = 0;
    unsigned cr = 0, bad = 0, commas = 0;
    for (Py_ssize_t i = 0; i < n; i += 255) {
        Py_ssize_t len = n - i < 255 ? n - i : 255;
        const unsigned char *b = s + i;
        unsigned char nlb = 0, crb = 0, badb = 0, cmb = 0;
        for (Py_ssize_t j = 0; j < len; j++) {
            unsigned char c = b[j];
            nlb += c == '\n';
            crb |= c == '\r';
            cmb |= c == ',';
            badb |= (c >= 0x80) | ((c < 0x20) & (c != '\t') & (c != '\n') & (c != '\r'));
        }
        nl += nlb;
        cr |= crb;
        bad |= badb;
        commas |= cmb;
    }
    if (bad || (!comma && commas)) return 1;
    if (cr) { /* every '\r' must end a line ("\r\n") */
        for (Py_ssize_t i = 0; i < n; i++)
            if (s[i] == '\r' && (i + 1 == n || s[i + 1] != '\n')) return 1;
    }
    *newlines = nl;
    return 0;
}

static inline int is_digit(unsigned char c) { return (unsigned char)(c - '0') < 10; }

static const uint64_t POW10U[9] = {1, 10, 100, 1000, 10000, 100000, 1000000, 10000000,
                                   100000000};

/* A run of decimal digits at p: accumulate at most 19 significant digits into *m (*nd counts
 * them, leading zeros may be counted), *slow = 1 beyond; *count += the run length, *scale -=
 * the run length when `frac` (digits after the point). Eight bytes at a time where the buffer
 * allows (little-endian SWAR: the digits of one 8-byte word are combined with three
 * multiplications), byte by byte otherwise. Returns the end of the run. */
static inline const unsigned char *digit_run(const unsigned char *p, const unsigned char *bufend,
                                             uint64_t *m, int *nd, int *count, long *scale,
                                             int frac, int *slow) {
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
    while (p + 8 <= bufend) {
        uint64_t v;
        memcpy(&v, p, 8);
        uint64_t t = v ^ 0x3030303030303030ULL; /* digits -> 0..9 */
        uint64_t bad = (((t & 0x7F7F7F7F7F7F7F7FULL) + 0x7676767676767676ULL) | t) &
                       0x8080808080808080ULL; /* high bit of each byte that is not a digit */
        int k = bad ? __builtin_ctzll(bad) >> 3 : 8;
        if (k == 0) return p;
        if (*nd + k > 19) break; /* near the 19-digit limit: byte by byte */
        if (k < 8) t <<= 8 * (8 - k); /* the k digits as the last k of 8, zeros before */
        t = t * 10 + (t >> 8);
        t = (((t & 0x000000FF000000FFULL) * (100 + (1000000ULL << 32))) +
             (((t >> 16) & 0x000000FF000000FFULL) * (1 + (10000ULL << 32)))) >>
            32;
        uint64_t val = t & 0xFFFFFFFFULL;
        if (*m || val) *nd += k;
        *m = *m * POW10U[k] + val;
        *count += k;
        if (frac) *scale -= k;
        p += k;
        if (k < 8) return p;
    }
#endif
    while (p < bufend && is_digit(*p)) {
        unsigned d = *p++ - '0';
        (*count)++;
        if (*nd < 19) {
            if (*m || d) {
                *m = *m * 10 + d;
                (*nd)++;
            }
            if (frac) (*scale)--;
        } else {
            *slow = 1; /* more than 19 significant digits: PyOS_string_to_double */
        }
    }
    return p;
}

/* Parse one field at *pp (fields end before le, a non-digit byte or the buffer end bufend);
 * store its value. 0 on success, 1 for "not plain". */
static int parse_field(const unsigned char **pp, const unsigned char *le,
                       const unsigned char *bufend, double *out) {
    const unsigned char *p = *pp, *start = p;
    /* the sign without a branch (signs are random in most columns); le[0] is readable */
    int neg = p < le && *p == '-';
    p += neg | (p < le && *p == '+');
    uint64_t m = 0;
    int nd = 0, digits = 0, slow = 0;
    long e10 = 0;
    p = digit_run(p, bufend, &m, &nd, &digits, &e10, 0, &slow);
    if (p < le && *p == '.') p = digit_run(p + 1, bufend, &m, &nd, &digits, &e10, 1, &slow);
    if (!digits) return 1;
    if (p < le && (*p == 'e' || *p == 'E')) {
        p++;
        int eneg = 0;
        if (p < le && (*p == '-' || *p == '+')) {
            eneg = *p == '-';
            p++;
        }
        if (!(p < le && is_digit(*p))) return 1;
        long ev = 0;
        while (p < le && is_digit(*p)) {
            if (ev < 100000) ev = ev * 10 + (*p - '0');
            p++;
        }
        e10 += eneg ? -ev : ev;
    }
    if (p > le) return 1; /* cannot happen: le is not a digit */
    double v;
    if (!slow && m <= ((uint64_t)1 << 53) && e10 >= -22 && e10 <= 22) {
        /* the sign on the exact mantissa (a select, before the one rounding operation, which
         * is symmetric; "-0" gives -0.0 as float() does) */
        double dm = (double)m;
        dm = neg ? -dm : dm;
        v = e10 < 0 ? dm / POW10[-e10] : dm * POW10[e10];
    } else {
        char buf[MAX_SLOW_FIELD + 1];
        Py_ssize_t len = p - start;
        if (len > MAX_SLOW_FIELD) return 1;
        memcpy(buf, start, (size_t)len);
        buf[len] = '\0';
        char *stop = NULL;
        v = PyOS_string_to_double(buf, &stop, NULL);
        if (PyErr_Occurred()) {
            PyErr_Clear();
            return 1;
        }
        if (stop != buf + len) return 1;
        if (!(v - v == 0.0)) return 1; /* inf: the careful path reports it */
    }
    *out = v; /* the fast path is finite: |M| <= 2^53, 10^-22 <= 10^k <= 10^22 */
    *pp = p;
    return 0;
}

/* Parse the data lines into out (room for max_rows * ncols); the number of rows or -1. */
static Py_ssize_t parse_lines(const unsigned char *s, Py_ssize_t n, int ncols, int comma,
                              int at_least, double *out, Py_ssize_t max_rows) {
    const unsigned char *p = s, *end = s + n;
    Py_ssize_t rows = 0;
    while (p < end) {
        const unsigned char *eol = memchr(p, '\n', (size_t)(end - p));
        if (!eol) eol = end;
        const unsigned char *le = eol; /* line end without a final '\r' */
        if (le > p && le[-1] == '\r') le--;
        while (p < le && (*p == ' ' || *p == '\t')) p++;
        if (p == le || *p == '#' || *p == '%') { /* blank or comment line */
            p = eol + 1;
            continue;
        }
        if (rows >= max_rows) return -1;
        double *row = out + rows * ncols;
        int k = 0;
        for (;;) {
            if (k < ncols) {
                if (parse_field(&p, le, end, row + k)) return -1;
            } else if (at_least) {
                break; /* further fields are not read */
            } else {
                return -1; /* too many fields */
            }
            k++;
            while (p < le && (*p == ' ' || *p == '\t')) p++;
            if (p == le) break;
            if (comma) {
                if (*p != ',') return -1;
                p++;
                while (p < le && (*p == ' ' || *p == '\t')) p++;
                if (p == le && k < ncols) return -1; /* trailing ',' : an empty field */
            } else if (p[-1] != ' ' && p[-1] != '\t') {
                return -1; /* no separator after the field */
            }
        }
        if (k < ncols) return -1;
        rows++;
        p = eol + 1;
    }
    return rows;
}

static PyObject *parse_table(PyObject *self, PyObject *args) {
    (void)self;
    Py_buffer buf;
    int ncols, comma, at_least;
    if (!PyArg_ParseTuple(args, "y*ipp", &buf, &ncols, &comma, &at_least)) return NULL;
    if (ncols < 1) {
        PyBuffer_Release(&buf);
        PyErr_SetString(PyExc_ValueError, "ncols must be at least 1");
        return NULL;
    }
    const unsigned char *s = buf.buf;
    Py_ssize_t n = buf.len, newlines = 0, rows = -1;
    PyArrayObject *arr = NULL;
    if (prescan(s, n, &newlines, comma)) goto none;
    npy_intp dims[2] = {newlines + 1, ncols};
    arr = (PyArrayObject *)PyArray_SimpleNew(2, dims, NPY_FLOAT64);
    if (!arr) {
        PyBuffer_Release(&buf);
        return NULL;
    }
    /* the GIL is kept: the slow path calls PyOS_string_to_double */
    rows = parse_lines(s, n, ncols, comma, at_least, (double *)PyArray_DATA(arr), dims[0]);
    if (rows <= 0) goto none;
    PyBuffer_Release(&buf);
    if (rows < dims[0]) {
        npy_intp shape[2] = {rows, ncols};
        PyArray_Dims newshape = {shape, 2};
        PyObject *r = PyArray_Resize(arr, &newshape, 0, NPY_CORDER);
        if (!r) {
            Py_DECREF(arr);
            return NULL;
        }
        Py_DECREF(r); /* PyArray_Resize returns None (the array is resized in place) */
    }
    return (PyObject *)arr;
none:
    Py_XDECREF(arr);
    PyBuffer_Release(&buf);
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"parse_table", parse_table, METH_VARARGS,
     "parse_table(data, ncols, comma, at_least) -> float64 array (rows, ncols) or None"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_text",
                                    "Compiled reader of numeric text tables for microlie.", -1,
                                    methods};

PyMODINIT_FUNC PyInit__text(void) {
    import_array();
    return PyModule_Create(&module);
}
