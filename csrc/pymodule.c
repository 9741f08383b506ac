/*
 * skinkit._core: the CPython binding of the C core, built against the stable ABI (Py_LIMITED_API 3.11)
 * so that one binary loads in every Blender from 4.2 on. Arrays cross through the buffer protocol
 * (no numpy C API); the Python layer (skinkit/_native.py) allocates destinations and checks shapes,
 * this layer re-checks element types and counts so that no call can read or write out of bounds.
 * Every C call runs with the GIL released.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <string.h>

#include "skinkit.h"

#define SK_STRINGIFY(x) #x
#define SK_VERSION_TEXT(a, b, c) SK_STRINGIFY(a) "." SK_STRINGIFY(b) "." SK_STRINGIFY(c)
#define SK_VERSION_STRING SK_VERSION_TEXT(SK_VERSION_MAJOR, SK_VERSION_MINOR, SK_VERSION_PATCH)

static PyObject *skinkit_error_type; /* skinkit._core.Error, a ValueError */

typedef struct array_view {
    Py_buffer buffer;
    int held;
    char type; /* 'd' double, 'f' float, 'i' int32 */
    size_t count;
} array_view;

static char element_type(const Py_buffer *buffer)
{
    const char *format = buffer->format ? buffer->format : "B";
    if (*format == '<' || *format == '=' || *format == '@')
        ++format;
    if (format[0] == '\0' || format[1] != '\0')
        return '?';
    if (*format == 'd' && buffer->itemsize == 8)
        return 'd';
    if (*format == 'f' && buffer->itemsize == 4)
        return 'f';
    if ((*format == 'i' || *format == 'l') && buffer->itemsize == 4)
        return 'i';
    if ((*format == 'B' || *format == '?') && buffer->itemsize == 1)
        return 'B';
    return '?';
}

/* Acquires a C-contiguous buffer of the wanted element types (a string such as "df"). */
static int acquire(array_view *view, PyObject *object, const char *name, const char *types, int writable)
{
    memset(view, 0, sizeof *view);
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(object, &view->buffer, flags) != 0) {
        PyErr_Format(PyExc_TypeError, "%s must be a C-contiguous%s array", name, writable ? " writable" : "");
        return 0;
    }
    view->held = 1;
    view->type = element_type(&view->buffer);
    if (view->type == '?' || !strchr(types, view->type)) {
        PyErr_Format(PyExc_TypeError, "%s has element type '%s', expected one of '%s'", name,
                     view->buffer.format ? view->buffer.format : "B", types);
        return 0;
    }
    view->count = (size_t)(view->buffer.len / view->buffer.itemsize);
    return 1;
}

static void release(array_view *views, size_t count)
{
    for (size_t i = 0; i < count; ++i)
        if (views[i].held)
            PyBuffer_Release(&views[i].buffer);
}

static int expect_count(const array_view *view, const char *name, size_t expected)
{
    if (view->count == expected)
        return 1;
    PyErr_Format(PyExc_ValueError, "%s has %zu elements, expected %zu", name, view->count, expected);
    return 0;
}

static int expect_multiple(const array_view *view, const char *name, size_t factor, size_t *quotient)
{
    if (view->count % factor == 0) {
        *quotient = view->count / factor;
        return 1;
    }
    PyErr_Format(PyExc_ValueError, "%s has %zu elements, not a multiple of %zu", name, view->count, factor);
    return 0;
}

static int expect_same_type(const array_view *a, const array_view *b, const char *a_name, const char *b_name)
{
    if (a->type == b->type)
        return 1;
    PyErr_Format(PyExc_TypeError, "%s and %s must have the same precision", a_name, b_name);
    return 0;
}

static PyObject *raise_status(const sk_error *error)
{
    PyObject *type = error->status == SK_ERROR_MEMORY ? PyExc_MemoryError : skinkit_error_type;
    PyErr_Format(type, "%s: %s", sk_status_name(error->status), error->message);
    return NULL;
}

/* None for success, else the exception the status maps to. */
static PyObject *outcome(sk_status status, const sk_error *error)
{
    return status == SK_OK ? Py_NewRef(Py_None) : raise_status(error);
}

/* offsets and bones describe vertex_count vertices; returns 0 with an exception set otherwise. */
static int influence_counts(const array_view *offsets, size_t *vertex_count)
{
    if (offsets->count < 1) {
        PyErr_SetString(PyExc_ValueError, "offsets needs at least one element");
        return 0;
    }
    *vertex_count = offsets->count - 1;
    return 1;
}

static PyObject *py_validate_skeleton(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *parents_object, *rest_object;
    if (!PyArg_ParseTuple(args, "OO", &parents_object, &rest_object))
        return NULL;
    array_view views[2];
    memset(views, 0, sizeof views);
    PyObject *result = NULL;
    sk_error error = {0};
    if (acquire(&views[0], parents_object, "parents", "i", 0) &&
        (rest_object == Py_None || acquire(&views[1], rest_object, "rest_frames", "d", 0)) &&
        (rest_object == Py_None || expect_count(&views[1], "rest_frames", 16 * views[0].count))) {
        sk_status status;
        Py_BEGIN_ALLOW_THREADS
        status = sk_validate_skeleton(views[0].buffer.buf, views[1].held ? views[1].buffer.buf : NULL,
                                      views[0].count, &error);
        Py_END_ALLOW_THREADS
        result = outcome(status, &error);
    }
    release(views, 2);
    return result;
}

static PyObject *py_validate_influences(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *offsets_object, *bones_object;
    Py_ssize_t bone_count;
    if (!PyArg_ParseTuple(args, "OOn", &offsets_object, &bones_object, &bone_count))
        return NULL;
    array_view views[2];
    PyObject *result = NULL;
    sk_error error = {0};
    size_t vertex_count = 0;
    memset(views, 0, sizeof views);
    if (bone_count < 0) {
        PyErr_SetString(PyExc_ValueError, "bone_count must not be negative");
    } else if (acquire(&views[0], offsets_object, "offsets", "i", 0) &&
               acquire(&views[1], bones_object, "bones", "i", 0) &&
               influence_counts(&views[0], &vertex_count)) {
        sk_status status;
        Py_BEGIN_ALLOW_THREADS
        status = sk_validate_influences(&(sk_influences){views[0].buffer.buf, views[1].buffer.buf, vertex_count,
                                                          views[1].count},
                                        (size_t)bone_count, &error);
        Py_END_ALLOW_THREADS
        result = outcome(status, &error);
    }
    release(views, 2);
    return result;
}

static PyObject *py_validate_triangles(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *triangles_object;
    Py_ssize_t vertex_count;
    if (!PyArg_ParseTuple(args, "On", &triangles_object, &vertex_count))
        return NULL;
    array_view view;
    PyObject *result = NULL;
    sk_error error = {0};
    size_t triangle_count = 0;
    if (vertex_count < 0) {
        memset(&view, 0, sizeof view);
        PyErr_SetString(PyExc_ValueError, "vertex_count must not be negative");
    } else if (acquire(&view, triangles_object, "triangles", "i", 0) &&
               expect_multiple(&view, "triangles", 3, &triangle_count)) {
        sk_status status;
        Py_BEGIN_ALLOW_THREADS
        status = sk_validate_triangles(&(sk_triangle_mesh){view.buffer.buf, triangle_count, (size_t)vertex_count}, &error);
        Py_END_ALLOW_THREADS
        result = outcome(status, &error);
    }
    release(&view, 1);
    return result;
}

static PyObject *py_lbs_to_animation_space(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objects[6];
    double homogeneous;
    if (!PyArg_ParseTuple(args, "OOdOOOO", &objects[0], &objects[1], &homogeneous, &objects[2], &objects[3],
                          &objects[4], &objects[5]))
        return NULL;
    enum { DEST, VECTORS, OFFSETS, BONES, WEIGHTS, REST };
    array_view v[6];
    memset(v, 0, sizeof v);
    PyObject *result = NULL;
    sk_error error = {0};
    size_t vertex_count = 0, bone_count = 0;
    if (acquire(&v[DEST], objects[0], "destination", "d", 1) && acquire(&v[VECTORS], objects[1], "vectors", "d", 0) &&
        acquire(&v[OFFSETS], objects[2], "offsets", "i", 0) && acquire(&v[BONES], objects[3], "bones", "i", 0) &&
        acquire(&v[WEIGHTS], objects[4], "weights", "d", 0) && acquire(&v[REST], objects[5], "rest_frames", "d", 0) &&
        influence_counts(&v[OFFSETS], &vertex_count) &&
        expect_count(&v[VECTORS], "vectors", 3 * vertex_count) &&
        expect_count(&v[WEIGHTS], "weights", v[BONES].count) &&
        expect_count(&v[DEST], "destination", 4 * v[BONES].count) &&
        expect_multiple(&v[REST], "rest_frames", 16, &bone_count)) {
        sk_status status;
        Py_BEGIN_ALLOW_THREADS
        status = sk_lbs_to_animation_space(v[DEST].buffer.buf,
                                           &(sk_influences){v[OFFSETS].buffer.buf, v[BONES].buffer.buf, vertex_count,
                                                            v[BONES].count},
                                           v[VECTORS].buffer.buf, homogeneous, v[WEIGHTS].buffer.buf,
                                           v[REST].buffer.buf, bone_count, &error);
        Py_END_ALLOW_THREADS
        result = outcome(status, &error);
    }
    release(v, 6);
    return result;
}

static PyObject *py_skinning_matrices(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objects[3];
    if (!PyArg_ParseTuple(args, "OOO", &objects[0], &objects[1], &objects[2]))
        return NULL;
    array_view v[3];
    memset(v, 0, sizeof v);
    PyObject *result = NULL;
    sk_error error = {0};
    size_t bone_count = 0;
    if (acquire(&v[0], objects[0], "destination", "d", 1) && acquire(&v[1], objects[1], "poses", "d", 0) &&
        acquire(&v[2], objects[2], "rest_frames", "d", 0) && expect_multiple(&v[2], "rest_frames", 16, &bone_count) &&
        expect_count(&v[1], "poses", v[2].count) && expect_count(&v[0], "destination", v[2].count)) {
        sk_status status;
        Py_BEGIN_ALLOW_THREADS
        status = sk_skinning_matrices(v[0].buffer.buf, v[1].buffer.buf, v[2].buffer.buf, bone_count, &error);
        Py_END_ALLOW_THREADS
        result = outcome(status, &error);
    }
    release(v, 3);
    return result;
}

static PyObject *py_animation_space_evaluate(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objects[5];
    int thread_count;
    if (!PyArg_ParseTuple(args, "OOOOOi", &objects[0], &objects[1], &objects[2], &objects[3], &objects[4],
                          &thread_count))
        return NULL;
    enum { DEST, OFFSETS, BONES, COORDINATES, POSES };
    array_view v[5];
    memset(v, 0, sizeof v);
    PyObject *result = NULL;
    sk_error error = {0};
    size_t vertex_count = 0, bone_count = 0;
    if (acquire(&v[DEST], objects[0], "destination", "df", 1) && acquire(&v[OFFSETS], objects[1], "offsets", "i", 0) &&
        acquire(&v[BONES], objects[2], "bones", "i", 0) &&
        acquire(&v[COORDINATES], objects[3], "coordinates", "df", 0) &&
        acquire(&v[POSES], objects[4], "poses", "df", 0) &&
        expect_same_type(&v[DEST], &v[COORDINATES], "destination", "coordinates") &&
        expect_same_type(&v[DEST], &v[POSES], "destination", "poses") &&
        influence_counts(&v[OFFSETS], &vertex_count) &&
        expect_count(&v[DEST], "destination", 3 * vertex_count) &&
        expect_count(&v[COORDINATES], "coordinates", 4 * v[BONES].count) &&
        expect_multiple(&v[POSES], "poses", 16, &bone_count)) {
        sk_status status;
        const int32_t *offsets = v[OFFSETS].buffer.buf, *bones = v[BONES].buffer.buf;
        Py_BEGIN_ALLOW_THREADS
        if (v[DEST].type == 'd')
            status = sk_animation_space_evaluate_f64(v[DEST].buffer.buf,
                                                     &(sk_influences){offsets, bones, vertex_count, v[BONES].count},
                                                     v[COORDINATES].buffer.buf, v[POSES].buffer.buf, bone_count,
                                                     thread_count, &error);
        else
            status = sk_animation_space_evaluate_f32(v[DEST].buffer.buf,
                                                     &(sk_influences){offsets, bones, vertex_count, v[BONES].count},
                                                     v[COORDINATES].buffer.buf, v[POSES].buffer.buf, bone_count,
                                                     thread_count, &error);
        Py_END_ALLOW_THREADS
        result = outcome(status, &error);
    }
    release(v, 5);
    return result;
}

static PyObject *py_lbs_evaluate(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objects[6];
    double homogeneous;
    int thread_count;
    if (!PyArg_ParseTuple(args, "OOdOOOOi", &objects[0], &objects[1], &homogeneous, &objects[2], &objects[3],
                          &objects[4], &objects[5], &thread_count))
        return NULL;
    enum { DEST, VECTORS, OFFSETS, BONES, WEIGHTS, MATRICES };
    array_view v[6];
    memset(v, 0, sizeof v);
    PyObject *result = NULL;
    sk_error error = {0};
    size_t vertex_count = 0, bone_count = 0;
    if (acquire(&v[DEST], objects[0], "destination", "df", 1) && acquire(&v[VECTORS], objects[1], "vectors", "df", 0) &&
        acquire(&v[OFFSETS], objects[2], "offsets", "i", 0) && acquire(&v[BONES], objects[3], "bones", "i", 0) &&
        acquire(&v[WEIGHTS], objects[4], "weights", "df", 0) &&
        acquire(&v[MATRICES], objects[5], "skinning_matrices", "df", 0) &&
        expect_same_type(&v[DEST], &v[VECTORS], "destination", "vectors") &&
        expect_same_type(&v[DEST], &v[WEIGHTS], "destination", "weights") &&
        expect_same_type(&v[DEST], &v[MATRICES], "destination", "skinning_matrices") &&
        influence_counts(&v[OFFSETS], &vertex_count) &&
        expect_count(&v[DEST], "destination", 3 * vertex_count) &&
        expect_count(&v[VECTORS], "vectors", 3 * vertex_count) &&
        expect_count(&v[WEIGHTS], "weights", v[BONES].count) &&
        expect_multiple(&v[MATRICES], "skinning_matrices", 16, &bone_count)) {
        sk_status status;
        const int32_t *offsets = v[OFFSETS].buffer.buf, *bones = v[BONES].buffer.buf;
        Py_BEGIN_ALLOW_THREADS
        if (v[DEST].type == 'd')
            status = sk_lbs_evaluate_f64(v[DEST].buffer.buf, &(sk_influences){offsets, bones, vertex_count, v[BONES].count},
                                         v[VECTORS].buffer.buf, homogeneous, v[WEIGHTS].buffer.buf,
                                         v[MATRICES].buffer.buf, bone_count, thread_count, &error);
        else
            status = sk_lbs_evaluate_f32(v[DEST].buffer.buf, &(sk_influences){offsets, bones, vertex_count, v[BONES].count},
                                         v[VECTORS].buffer.buf, (float)homogeneous, v[WEIGHTS].buffer.buf,
                                         v[MATRICES].buffer.buf, bone_count, thread_count, &error);
        Py_END_ALLOW_THREADS
        result = outcome(status, &error);
    }
    release(v, 6);
    return result;
}

/* ---- fitting ------------------------------------------------------------------------------------ */

/* Calls a Python progress callable from a solver thread; a true result, an exception or Ctrl-C cancels. */
static int python_progress(void *user, double fraction)
{
    PyGILState_STATE state = PyGILState_Ensure();
    int cancel = PyErr_CheckSignals() != 0;
    if (!cancel && user) {
        PyObject *result = PyObject_CallFunction((PyObject *)user, "d", fraction);
        cancel = result == NULL || PyObject_IsTrue(result) == 1;
        Py_XDECREF(result);
    }
    if (cancel)
        PyErr_Clear(); /* the caller raises a clear "cancelled" error instead */
    PyGILState_Release(state);
    return cancel;
}

static PyObject *report_dict(const sk_lsqr_report *r)
{
    return Py_BuildValue("{s:i,s:i,s:d,s:d,s:d,s:d,s:d,s:d}", "stop_reason", r->stop_reason, "iterations",
                         r->iterations, "residual_norm", r->residual_norm, "normal_residual", r->normal_residual,
                         "matrix_norm", r->matrix_norm, "condition", r->condition, "solution_norm",
                         r->solution_norm, "initial_residual_norm", r->initial_residual_norm);
}

/* Checks the shared fitting inputs; sets vertex_count and bone_count. */
static int fit_counts(const array_view *offsets, const array_view *poses, const array_view *examples,
                      Py_ssize_t example_count, size_t *vertex_count, size_t *bone_count)
{
    if (example_count < 1) {
        PyErr_SetString(PyExc_ValueError, "example_count must be at least 1");
        return 0;
    }
    if (!influence_counts(offsets, vertex_count) ||
        !expect_multiple(poses, "poses", 16 * (size_t)example_count, bone_count) ||
        !expect_count(examples, "examples", 3 * (size_t)example_count * *vertex_count))
        return 0;
    return 1;
}

static PyObject *py_fit_per_vertex(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objects[6];
    Py_ssize_t example_count;
    double lambda;
    int thread_count;
    if (!PyArg_ParseTuple(args, "OOOOOndOi", &objects[0], &objects[1], &objects[2], &objects[3], &objects[4],
                          &example_count, &lambda, &objects[5], &thread_count))
        return NULL;
    enum { DEST, OFFSETS, BONES, POSES, EXAMPLES, PRIOR };
    array_view v[6];
    memset(v, 0, sizeof v);
    PyObject *result = NULL;
    sk_error error = {0};
    size_t vertex_count = 0, bone_count = 0;
    if (acquire(&v[DEST], objects[0], "coordinates", "d", 1) && acquire(&v[OFFSETS], objects[1], "offsets", "i", 0) &&
        acquire(&v[BONES], objects[2], "bones", "i", 0) && acquire(&v[POSES], objects[3], "poses", "d", 0) &&
        acquire(&v[EXAMPLES], objects[4], "examples", "d", 0) &&
        fit_counts(&v[OFFSETS], &v[POSES], &v[EXAMPLES], example_count, &vertex_count, &bone_count) &&
        expect_count(&v[DEST], "coordinates", 4 * v[BONES].count) &&
        (objects[5] == Py_None || (acquire(&v[PRIOR], objects[5], "prior", "d", 0) &&
                                   expect_count(&v[PRIOR], "prior", 4 * v[BONES].count)))) {
        sk_status status;
        const double *prior = v[PRIOR].held ? v[PRIOR].buffer.buf : NULL;
        Py_BEGIN_ALLOW_THREADS
        status = sk_fit_per_vertex(v[DEST].buffer.buf,
                                   &(sk_influences){v[OFFSETS].buffer.buf, v[BONES].buffer.buf, vertex_count,
                                                    v[BONES].count},
                                   &(sk_examples){v[POSES].buffer.buf, v[EXAMPLES].buffer.buf, (size_t)example_count,
                                                  bone_count},
                                   prior, lambda, thread_count, &error);
        Py_END_ALLOW_THREADS
        result = outcome(status, &error);
    }
    release(v, 6);
    return result;
}

static PyObject *py_fit_global(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objects[7], *progress;
    Py_ssize_t example_count;
    sk_lsqr_settings settings;
    int thread_count;
    if (!PyArg_ParseTuple(args, "OOOOOnOO(dddip)iO", &objects[0], &objects[1], &objects[2], &objects[3], &objects[4],
                          &example_count, &objects[5], &objects[6], &settings.atol, &settings.btol, &settings.conlim,
                          &settings.iteration_limit, &settings.precondition, &thread_count, &progress))
        return NULL;
    enum { DEST, OFFSETS, BONES, POSES, EXAMPLES, EDGES, EDGE_WEIGHTS };
    array_view v[7];
    memset(v, 0, sizeof v);
    PyObject *result = NULL;
    sk_error error = {0};
    sk_lsqr_report report = {0};
    size_t vertex_count = 0, bone_count = 0, edge_count = 0;
    if (acquire(&v[DEST], objects[0], "coordinates", "d", 1) && acquire(&v[OFFSETS], objects[1], "offsets", "i", 0) &&
        acquire(&v[BONES], objects[2], "bones", "i", 0) && acquire(&v[POSES], objects[3], "poses", "d", 0) &&
        acquire(&v[EXAMPLES], objects[4], "examples", "d", 0) && acquire(&v[EDGES], objects[5], "edges", "i", 0) &&
        acquire(&v[EDGE_WEIGHTS], objects[6], "edge_weights", "d", 0) &&
        fit_counts(&v[OFFSETS], &v[POSES], &v[EXAMPLES], example_count, &vertex_count, &bone_count) &&
        expect_count(&v[DEST], "coordinates", 4 * v[BONES].count) &&
        expect_multiple(&v[EDGES], "edges", 2, &edge_count) &&
        expect_count(&v[EDGE_WEIGHTS], "edge_weights", edge_count)) {
        sk_status status;
        void *user = progress == Py_None ? NULL : progress;
        Py_BEGIN_ALLOW_THREADS
        settings.thread_count = thread_count;
        status = sk_fit_global(v[DEST].buffer.buf, &report,
                               &(sk_influences){v[OFFSETS].buffer.buf, v[BONES].buffer.buf, vertex_count,
                                                v[BONES].count},
                               &(sk_examples){v[POSES].buffer.buf, v[EXAMPLES].buffer.buf, (size_t)example_count,
                                              bone_count},
                               v[EDGES].buffer.buf, v[EDGE_WEIGHTS].buffer.buf, edge_count, &settings,
                               python_progress, user, &error);
        Py_END_ALLOW_THREADS
        result = status == SK_OK ? report_dict(&report) : raise_status(&error);
    }
    release(v, 7);
    return result;
}

typedef struct dense_matrix {
    const double *values;
    size_t rows, cols;
} dense_matrix;

static void dense_apply(void *user, int transpose, const double *in, double *out)
{
    const dense_matrix *a = user;
    const size_t out_count = transpose ? a->cols : a->rows;
    for (size_t i = 0; i < out_count; ++i)
        out[i] = 0.0;
    for (size_t r = 0; r < a->rows; ++r)
        for (size_t c = 0; c < a->cols; ++c) {
            if (transpose)
                out[c] += a->values[r * a->cols + c] * in[r];
            else
                out[r] += a->values[r * a->cols + c] * in[c];
        }
}

static PyObject *py_lsqr_dense(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objects[3];
    Py_ssize_t rows, cols;
    sk_lsqr_settings settings = {0};
    if (!PyArg_ParseTuple(args, "OOOnn(dddi)", &objects[0], &objects[1], &objects[2], &rows, &cols, &settings.atol,
                          &settings.btol, &settings.conlim, &settings.iteration_limit))
        return NULL;
    array_view v[3];
    memset(v, 0, sizeof v);
    PyObject *result = NULL;
    sk_error error = {0};
    sk_lsqr_report report = {0};
    if (rows < 1 || cols < 1) {
        PyErr_SetString(PyExc_ValueError, "rows and cols must be at least 1");
    } else if (acquire(&v[0], objects[0], "x", "d", 1) && acquire(&v[1], objects[1], "matrix", "d", 0) &&
               acquire(&v[2], objects[2], "b", "d", 0) && expect_count(&v[0], "x", (size_t)cols) &&
               expect_count(&v[1], "matrix", (size_t)(rows * cols)) && expect_count(&v[2], "b", (size_t)rows)) {
        dense_matrix matrix = {v[1].buffer.buf, (size_t)rows, (size_t)cols};
        sk_status status;
        Py_BEGIN_ALLOW_THREADS
        status = sk_lsqr(v[0].buffer.buf, v[2].buffer.buf, (size_t)rows, (size_t)cols, dense_apply, &matrix, &settings,
                         &report, NULL, NULL, &error);
        Py_END_ALLOW_THREADS
        result = status == SK_OK ? report_dict(&report) : raise_status(&error);
    }
    release(v, 3);
    return result;
}

static PyObject *py_fit_lbs_weights(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objects[6];
    Py_ssize_t example_count;
    int thread_count;
    if (!PyArg_ParseTuple(args, "OOOOOOni", &objects[0], &objects[1], &objects[2], &objects[3], &objects[4],
                          &objects[5], &example_count, &thread_count))
        return NULL;
    enum { DEST, OFFSETS, BONES, MATRICES, REST, EXAMPLES };
    array_view v[6];
    memset(v, 0, sizeof v);
    PyObject *result = NULL;
    sk_error error = {0};
    size_t vertex_count = 0, bone_count = 0;
    if (acquire(&v[DEST], objects[0], "weights", "d", 1) && acquire(&v[OFFSETS], objects[1], "offsets", "i", 0) &&
        acquire(&v[BONES], objects[2], "bones", "i", 0) &&
        acquire(&v[MATRICES], objects[3], "skinning_matrices", "d", 0) &&
        acquire(&v[REST], objects[4], "rest_positions", "d", 0) && acquire(&v[EXAMPLES], objects[5], "examples", "d", 0) &&
        fit_counts(&v[OFFSETS], &v[MATRICES], &v[EXAMPLES], example_count, &vertex_count, &bone_count) &&
        expect_count(&v[DEST], "weights", v[BONES].count) && expect_count(&v[REST], "rest_positions", 3 * vertex_count)) {
        sk_status status;
        Py_BEGIN_ALLOW_THREADS
        status = sk_fit_lbs_weights(v[DEST].buffer.buf,
                                    &(sk_influences){v[OFFSETS].buffer.buf, v[BONES].buffer.buf, vertex_count,
                                                     v[BONES].count},
                                    &(sk_examples){v[MATRICES].buffer.buf, v[EXAMPLES].buffer.buf,
                                                   (size_t)example_count, bone_count},
                                    v[REST].buffer.buf, thread_count, &error);
        Py_END_ALLOW_THREADS
        result = outcome(status, &error);
    }
    release(v, 6);
    return result;
}

/* ---- metrics ------------------------------------------------------------------------------------ */

static PyObject *py_joint_statistics(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objects[4];
    if (!PyArg_ParseTuple(args, "OOOO", &objects[0], &objects[1], &objects[2], &objects[3]))
        return NULL;
    array_view v[4];
    memset(v, 0, sizeof v);
    PyObject *result = NULL;
    sk_error error = {0};
    size_t sample_count = 0;
    if (acquire(&v[0], objects[0], "expected_local", "d", 1) && acquire(&v[1], objects[1], "expected_gram", "d", 1) &&
        acquire(&v[2], objects[2], "local", "d", 0) && acquire(&v[3], objects[3], "parents", "i", 0) &&
        expect_count(&v[0], "expected_local", 16 * v[3].count) && expect_count(&v[1], "expected_gram", 16 * v[3].count) &&
        expect_multiple(&v[2], "local", 16 * (v[3].count ? v[3].count : 1), &sample_count)) {
        sk_status status;
        Py_BEGIN_ALLOW_THREADS
        status = sk_joint_statistics(v[0].buffer.buf, v[1].buffer.buf, v[2].buffer.buf, v[3].buffer.buf, sample_count,
                                     v[3].count, &error);
        Py_END_ALLOW_THREADS
        result = outcome(status, &error);
    }
    release(v, 4);
    return result;
}

/* expected_local, expected_gram (bone_count * 16 each) and parents, checked against each other. */
static int acquire_statistics(array_view *v, PyObject *local, PyObject *gram, PyObject *parents)
{
    return acquire(&v[0], local, "expected_local", "d", 0) && acquire(&v[1], gram, "expected_gram", "d", 0) &&
           acquire(&v[2], parents, "parents", "i", 0) && expect_count(&v[0], "expected_local", 16 * v[2].count) &&
           expect_count(&v[1], "expected_gram", 16 * v[2].count);
}

static PyObject *py_expectation_block(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objects[4];
    Py_ssize_t j, k;
    if (!PyArg_ParseTuple(args, "OOOOnn", &objects[0], &objects[1], &objects[2], &objects[3], &j, &k))
        return NULL;
    array_view v[4];
    memset(v, 0, sizeof v);
    PyObject *result = NULL;
    sk_error error = {0};
    if (j < 0 || k < 0) {
        PyErr_SetString(PyExc_ValueError, "bone indices must not be negative");
    } else if (acquire(&v[3], objects[0], "block", "d", 1) && expect_count(&v[3], "block", 16) &&
               acquire_statistics(v, objects[1], objects[2], objects[3])) {
        sk_status status;
        Py_BEGIN_ALLOW_THREADS
        status = sk_expectation_block(v[3].buffer.buf, v[0].buffer.buf, v[1].buffer.buf, v[2].buffer.buf, v[2].count,
                                      (size_t)j, (size_t)k, &error);
        Py_END_ALLOW_THREADS
        result = outcome(status, &error);
    }
    release(v, 4);
    return result;
}

static PyObject *py_expectation_blocks(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objects[4];
    if (!PyArg_ParseTuple(args, "OOOO", &objects[0], &objects[1], &objects[2], &objects[3]))
        return NULL;
    array_view v[4];
    memset(v, 0, sizeof v);
    PyObject *result = NULL;
    sk_error error = {0};
    if (acquire(&v[3], objects[0], "blocks", "d", 1) && acquire_statistics(v, objects[1], objects[2], objects[3]) &&
        expect_count(&v[3], "blocks", 16 * v[2].count * v[2].count)) {
        sk_status status;
        Py_BEGIN_ALLOW_THREADS
        status = sk_expectation_blocks(v[3].buffer.buf, v[0].buffer.buf, v[1].buffer.buf, v[2].buffer.buf, v[2].count,
                                       &error);
        Py_END_ALLOW_THREADS
        result = outcome(status, &error);
    }
    release(v, 4);
    return result;
}

static PyObject *py_linear_norms(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objects[2];
    if (!PyArg_ParseTuple(args, "OO", &objects[0], &objects[1]))
        return NULL;
    array_view v[2];
    memset(v, 0, sizeof v);
    PyObject *result = NULL;
    sk_error error = {0};
    size_t matrix_count = 0;
    if (acquire(&v[0], objects[0], "destination", "d", 1) && acquire(&v[1], objects[1], "matrices", "d", 0) &&
        expect_multiple(&v[1], "matrices", 16, &matrix_count) && expect_count(&v[0], "destination", matrix_count)) {
        sk_status status;
        Py_BEGIN_ALLOW_THREADS
        status = sk_linear_norms(v[0].buffer.buf, v[1].buffer.buf, matrix_count, &error);
        Py_END_ALLOW_THREADS
        result = outcome(status, &error);
    }
    release(v, 2);
    return result;
}

static PyObject *py_mean_distances(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objects[9];
    int thread_count;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOi", &objects[0], &objects[1], &objects[2], &objects[3], &objects[4],
                          &objects[5], &objects[6], &objects[7], &objects[8], &thread_count))
        return NULL;
    enum { LOCAL, GRAM, PARENTS, DEST, OFFSETS, BONES, VECTORS, CACHE, CACHED };
    array_view v[9];
    memset(v, 0, sizeof v);
    PyObject *result = NULL;
    sk_error error = {0};
    size_t vector_count = 0;
    if (acquire(&v[DEST], objects[0], "destination", "d", 1) && acquire(&v[OFFSETS], objects[1], "offsets", "i", 0) &&
        acquire(&v[BONES], objects[2], "bones", "i", 0) && acquire(&v[VECTORS], objects[3], "vectors", "d", 0) &&
        acquire_statistics(v, objects[4], objects[5], objects[6]) &&
        acquire(&v[CACHE], objects[7], "block_cache", "d", 1) && acquire(&v[CACHED], objects[8], "cached", "B", 1) &&
        influence_counts(&v[OFFSETS], &vector_count) && expect_count(&v[DEST], "destination", vector_count) &&
        expect_count(&v[VECTORS], "vectors", 4 * v[BONES].count) &&
        expect_count(&v[CACHE], "block_cache", 16 * v[PARENTS].count * v[PARENTS].count) &&
        expect_count(&v[CACHED], "cached", v[PARENTS].count * v[PARENTS].count)) {
        sk_status status;
        Py_BEGIN_ALLOW_THREADS
        status = sk_mean_distances(v[DEST].buffer.buf,
                                   &(sk_influences){v[OFFSETS].buffer.buf, v[BONES].buffer.buf, vector_count,
                                                    v[BONES].count},
                                   v[VECTORS].buffer.buf, v[LOCAL].buffer.buf, v[GRAM].buffer.buf,
                                   v[PARENTS].buffer.buf, v[PARENTS].count, v[CACHE].buffer.buf, v[CACHED].buffer.buf,
                                   thread_count, &error);
        Py_END_ALLOW_THREADS
        result = outcome(status, &error);
    }
    release(v, 9);
    return result;
}

static PyObject *py_max_distances(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objects[8];
    int thread_count;
    if (!PyArg_ParseTuple(args, "OOOOOOOOi", &objects[0], &objects[1], &objects[2], &objects[3], &objects[4],
                          &objects[5], &objects[6], &objects[7], &thread_count))
        return NULL;
    enum { DEST, OFFSETS, BONES, VECTORS, PARENTS, LINEAR, CENTRE, RADIUS };
    array_view v[8];
    memset(v, 0, sizeof v);
    PyObject *result = NULL;
    sk_error error = {0};
    size_t vector_count = 0;
    if (acquire(&v[DEST], objects[0], "destination", "d", 1) && acquire(&v[OFFSETS], objects[1], "offsets", "i", 0) &&
        acquire(&v[BONES], objects[2], "bones", "i", 0) && acquire(&v[VECTORS], objects[3], "vectors", "d", 0) &&
        acquire(&v[PARENTS], objects[4], "parents", "i", 0) && acquire(&v[LINEAR], objects[5], "linear_bound", "d", 0) &&
        acquire(&v[CENTRE], objects[6], "translation_centre", "d", 0) &&
        acquire(&v[RADIUS], objects[7], "translation_radius", "d", 0) &&
        influence_counts(&v[OFFSETS], &vector_count) && expect_count(&v[DEST], "destination", vector_count) &&
        expect_count(&v[VECTORS], "vectors", 4 * v[BONES].count) &&
        expect_count(&v[LINEAR], "linear_bound", v[PARENTS].count) &&
        expect_count(&v[CENTRE], "translation_centre", 3 * v[PARENTS].count) &&
        expect_count(&v[RADIUS], "translation_radius", v[PARENTS].count)) {
        sk_status status;
        Py_BEGIN_ALLOW_THREADS
        status = sk_max_distances(v[DEST].buffer.buf,
                                  &(sk_influences){v[OFFSETS].buffer.buf, v[BONES].buffer.buf, vector_count,
                                                   v[BONES].count},
                                  v[VECTORS].buffer.buf, v[PARENTS].buffer.buf, v[LINEAR].buffer.buf,
                                  v[CENTRE].buffer.buf, v[RADIUS].buffer.buf, v[PARENTS].count, thread_count, &error);
        Py_END_ALLOW_THREADS
        result = outcome(status, &error);
    }
    release(v, 8);
    return result;
}

/* ---- Segmentation (sk_segment.c) ---- */

static int segment_counts(const array_view *embedding, const array_view *triangles, Py_ssize_t dimension,
                          size_t *vertex_count, size_t *triangle_count)
{
    if (dimension < 1) {
        PyErr_SetString(PyExc_ValueError, "dimension must be positive");
        return 0;
    }
    return expect_multiple(embedding, "embedding", (size_t)dimension, vertex_count) &&
           expect_multiple(triangles, "triangles", 3, triangle_count);
}

static PyObject *py_segment(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objects[4];
    Py_ssize_t dimension, chart_count;
    int mode;
    double threshold, rho;
    if (!PyArg_ParseTuple(args, "OOnOOindd", &objects[0], &objects[1], &dimension, &objects[2], &objects[3], &mode,
                          &chart_count, &threshold, &rho))
        return NULL;
    enum { CHARTS, EMBEDDING, TRIANGLES, SEAMS };
    array_view v[4];
    memset(v, 0, sizeof v);
    PyObject *result = NULL;
    sk_error error = {0};
    size_t vertex_count = 0, triangle_count = 0, seam_count = 0;
    if (chart_count < 0) {
        PyErr_SetString(PyExc_ValueError, "chart_count must not be negative");
    } else if (acquire(&v[CHARTS], objects[0], "charts", "i", 1) &&
               acquire(&v[EMBEDDING], objects[1], "embedding", "d", 0) &&
               acquire(&v[TRIANGLES], objects[2], "triangles", "i", 0) &&
               acquire(&v[SEAMS], objects[3], "seams", "i", 0) &&
               segment_counts(&v[EMBEDDING], &v[TRIANGLES], dimension, &vertex_count, &triangle_count) &&
               expect_multiple(&v[SEAMS], "seams", 2, &seam_count) &&
               expect_count(&v[CHARTS], "charts", triangle_count)) {
        const sk_segment_options options = {(sk_segment_mode)mode, (size_t)chart_count, threshold, rho};
        sk_segment_report report = {0};
        sk_status status;
        Py_BEGIN_ALLOW_THREADS
        status = sk_segment(v[CHARTS].buffer.buf, &report,
                            &(sk_triangle_mesh){v[TRIANGLES].buffer.buf, triangle_count, vertex_count},
                            v[EMBEDDING].buffer.buf, (size_t)dimension, v[SEAMS].buffer.buf, seam_count, &options,
                            &error);
        Py_END_ALLOW_THREADS
        result = status == SK_OK ? Py_BuildValue("ndn", (Py_ssize_t)report.chart_count, report.mesh_metric,
                                                 (Py_ssize_t)report.component_count)
                                 : raise_status(&error);
    }
    release(v, 4);
    return result;
}

static PyObject *py_segment_corners(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objects[4];
    Py_ssize_t dimension, vertex_count;
    if (!PyArg_ParseTuple(args, "OOOOnn", &objects[0], &objects[1], &objects[2], &objects[3], &dimension,
                          &vertex_count))
        return NULL;
    enum { CORNERS, TRIANGLES, CHARTS, EMBEDDING };
    array_view v[4];
    memset(v, 0, sizeof v);
    PyObject *result = NULL;
    sk_error error = {0};
    size_t triangle_count = 0;
    if (vertex_count < 0 || dimension < 0) {
        PyErr_SetString(PyExc_ValueError, "vertex_count and dimension must not be negative");
    } else if (acquire(&v[CORNERS], objects[0], "corners", "B", 1) &&
               acquire(&v[TRIANGLES], objects[1], "triangles", "i", 0) &&
               acquire(&v[CHARTS], objects[2], "charts", "i", 0) &&
               (objects[3] == Py_None || acquire(&v[EMBEDDING], objects[3], "embedding", "d", 0)) &&
               expect_multiple(&v[TRIANGLES], "triangles", 3, &triangle_count) &&
               expect_count(&v[CHARTS], "charts", triangle_count) &&
               expect_count(&v[CORNERS], "corners", (size_t)vertex_count) &&
               (!v[EMBEDDING].held || expect_count(&v[EMBEDDING], "embedding", (size_t)(vertex_count * dimension)))) {
        sk_status status;
        Py_BEGIN_ALLOW_THREADS
        status = sk_chart_corners(v[CORNERS].buffer.buf,
                                  &(sk_triangle_mesh){v[TRIANGLES].buffer.buf, triangle_count, (size_t)vertex_count},
                                  v[CHARTS].buffer.buf, v[EMBEDDING].held ? v[EMBEDDING].buffer.buf : NULL,
                                  (size_t)dimension, &error);
        Py_END_ALLOW_THREADS
        result = outcome(status, &error);
    }
    release(v, 4);
    return result;
}

static PyObject *py_segment_straighten(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objects[4];
    Py_ssize_t dimension;
    double ratio, rho;
    if (!PyArg_ParseTuple(args, "OOOnOdd", &objects[0], &objects[1], &objects[2], &dimension, &objects[3], &ratio,
                          &rho))
        return NULL;
    enum { CHARTS, CORNERS, EMBEDDING, TRIANGLES };
    array_view v[4];
    memset(v, 0, sizeof v);
    PyObject *result = NULL;
    sk_error error = {0};
    size_t vertex_count = 0, triangle_count = 0;
    if (acquire(&v[CHARTS], objects[0], "charts", "i", 1) && acquire(&v[CORNERS], objects[1], "corners", "B", 1) &&
        acquire(&v[EMBEDDING], objects[2], "embedding", "d", 0) &&
        acquire(&v[TRIANGLES], objects[3], "triangles", "i", 0) &&
        segment_counts(&v[EMBEDDING], &v[TRIANGLES], dimension, &vertex_count, &triangle_count) &&
        expect_count(&v[CHARTS], "charts", triangle_count) && expect_count(&v[CORNERS], "corners", vertex_count)) {
        sk_straighten_report report = {0};
        sk_status status;
        Py_BEGIN_ALLOW_THREADS
        status = sk_straighten_charts(v[CHARTS].buffer.buf, v[CORNERS].buffer.buf, &report,
                                      &(sk_triangle_mesh){v[TRIANGLES].buffer.buf, triangle_count, vertex_count},
                                      v[EMBEDDING].buffer.buf, (size_t)dimension,
                                      &(sk_straighten_options){ratio, rho}, &error);
        Py_END_ALLOW_THREADS
        result = status == SK_OK ? Py_BuildValue("nnnn", (Py_ssize_t)report.paths, (Py_ssize_t)report.shortest,
                                                 (Py_ssize_t)report.constrained, (Py_ssize_t)report.kept)
                                 : raise_status(&error);
    }
    release(v, 4);
    return result;
}

static PyObject *py_segment_cut(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objects[4];
    Py_ssize_t vertex_count;
    if (!PyArg_ParseTuple(args, "OOOOn", &objects[0], &objects[1], &objects[2], &objects[3], &vertex_count))
        return NULL;
    enum { CUT, SOURCE, TRIANGLES, SEAMS };
    array_view v[4];
    memset(v, 0, sizeof v);
    PyObject *result = NULL;
    sk_error error = {0};
    size_t triangle_count = 0, seam_count = 0, cut_vertex_count = 0;
    if (vertex_count < 0) {
        PyErr_SetString(PyExc_ValueError, "vertex_count must not be negative");
    } else if (acquire(&v[CUT], objects[0], "cut_triangles", "i", 1) &&
               acquire(&v[SOURCE], objects[1], "source_vertex", "i", 1) &&
               acquire(&v[TRIANGLES], objects[2], "triangles", "i", 0) &&
               acquire(&v[SEAMS], objects[3], "seams", "i", 0) &&
               expect_multiple(&v[TRIANGLES], "triangles", 3, &triangle_count) &&
               expect_multiple(&v[SEAMS], "seams", 2, &seam_count) &&
               expect_count(&v[CUT], "cut_triangles", 3 * triangle_count) &&
               expect_count(&v[SOURCE], "source_vertex", 3 * triangle_count)) {
        sk_status status;
        Py_BEGIN_ALLOW_THREADS
        status = sk_cut_along_seams(v[CUT].buffer.buf, v[SOURCE].buffer.buf, &cut_vertex_count,
                                    &(sk_triangle_mesh){v[TRIANGLES].buffer.buf, triangle_count, (size_t)vertex_count},
                                    v[SEAMS].buffer.buf, seam_count, &error);
        Py_END_ALLOW_THREADS
        result = status == SK_OK ? PyLong_FromSize_t(cut_vertex_count) : raise_status(&error);
    }
    release(v, 4);
    return result;
}

/* ---- Flattening and packing (sk_flatten.c, sk_pack.c) ---- */

static PyObject *flatten_report_dict(const sk_flatten_report *r)
{
    return Py_BuildValue("{s:n,s:n,s:n,s:n,s:n,s:n,s:n,s:n,s:n,s:n,s:n,s:n}", "chart_count", (Py_ssize_t)r->chart_count,
                         "split_count", (Py_ssize_t)r->split_count, "flip_splits", (Py_ssize_t)r->flip_splits,
                         "straight_charts", (Py_ssize_t)r->straight_charts,
                         "circle_charts", (Py_ssize_t)r->circle_charts, "free_charts", (Py_ssize_t)r->free_charts,
                         "extra_corners", (Py_ssize_t)r->extra_corners, "tutte_charts", (Py_ssize_t)r->tutte_charts,
                         "invalid_triangles", (Py_ssize_t)r->invalid_triangles, "overlapping_charts",
                         (Py_ssize_t)r->overlapping_charts, "solver_iterations", (Py_ssize_t)r->solver_iterations,
                         "optimisation_sweeps", (Py_ssize_t)r->optimisation_sweeps);
}

static PyObject *py_flatten_charts(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objects[6];
    sk_flatten_options options;
    if (!PyArg_ParseTuple(args, "OOOOOO(iidii)", &objects[0], &objects[1], &objects[2], &objects[3], &objects[4],
                          &objects[5], &options.straight, &options.optimise, &options.stretch_limit,
                          &options.sweep_limit, &options.thread_count))
        return NULL;
    enum { UV, CHARTS_OUT, TRIANGLES, LENGTHS, CHARTS, CORNERS };
    array_view v[6];
    memset(v, 0, sizeof v);
    PyObject *result = NULL;
    sk_error error = {0};
    size_t triangle_count = 0;
    if (acquire(&v[UV], objects[0], "uv", "d", 1) && acquire(&v[CHARTS_OUT], objects[1], "charts_out", "i", 1) &&
        acquire(&v[TRIANGLES], objects[2], "triangles", "i", 0) &&
        acquire(&v[LENGTHS], objects[3], "edge_lengths_sq", "d", 0) && acquire(&v[CHARTS], objects[4], "charts", "i", 0) &&
        acquire(&v[CORNERS], objects[5], "corners", "B", 0) &&
        expect_multiple(&v[TRIANGLES], "triangles", 3, &triangle_count) &&
        expect_count(&v[UV], "uv", 6 * triangle_count) && expect_count(&v[CHARTS_OUT], "charts_out", triangle_count) &&
        expect_count(&v[LENGTHS], "edge_lengths_sq", 3 * triangle_count) &&
        expect_count(&v[CHARTS], "charts", triangle_count)) {
        sk_flatten_report report = {0};
        sk_status status;
        Py_BEGIN_ALLOW_THREADS
        status = sk_flatten(v[UV].buffer.buf, v[CHARTS_OUT].buffer.buf, &report,
                            &(sk_triangle_mesh){v[TRIANGLES].buffer.buf, triangle_count, v[CORNERS].count},
                            v[LENGTHS].buffer.buf, v[CHARTS].buffer.buf, v[CORNERS].buffer.buf, &options, &error);
        Py_END_ALLOW_THREADS
        result = status == SK_OK ? flatten_report_dict(&report) : raise_status(&error);
    }
    release(v, 6);
    return result;
}

/* Acquires uv (6 per triangle) and edge_lengths_sq (3 per triangle); sets triangle_count. */
static int stretch_inputs(array_view *uv, array_view *lengths, PyObject *uv_object, PyObject *lengths_object,
                          size_t *triangle_count)
{
    return acquire(uv, uv_object, "uv", "d", 0) && acquire(lengths, lengths_object, "edge_lengths_sq", "d", 0) &&
           expect_multiple(lengths, "edge_lengths_sq", 3, triangle_count) &&
           expect_count(uv, "uv", 6 * *triangle_count);
}

static PyObject *py_stretch_triangles(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objects[3];
    if (!PyArg_ParseTuple(args, "OOO", &objects[0], &objects[1], &objects[2]))
        return NULL;
    array_view v[3];
    memset(v, 0, sizeof v);
    PyObject *result = NULL;
    sk_error error = {0};
    size_t triangle_count = 0;
    if (acquire(&v[0], objects[0], "destination", "d", 1) &&
        stretch_inputs(&v[1], &v[2], objects[1], objects[2], &triangle_count) &&
        expect_count(&v[0], "destination", triangle_count)) {
        sk_status status;
        Py_BEGIN_ALLOW_THREADS
        status = sk_triangle_stretch(v[0].buffer.buf, v[1].buffer.buf, v[2].buffer.buf, triangle_count, &error);
        Py_END_ALLOW_THREADS
        result = outcome(status, &error);
    }
    release(v, 3);
    return result;
}

static PyObject *py_stretch_mesh(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objects[2];
    if (!PyArg_ParseTuple(args, "OO", &objects[0], &objects[1]))
        return NULL;
    array_view v[2];
    memset(v, 0, sizeof v);
    PyObject *result = NULL;
    sk_error error = {0};
    size_t triangle_count = 0;
    if (stretch_inputs(&v[0], &v[1], objects[0], objects[1], &triangle_count)) {
        double stretch = 0.0;
        sk_status status;
        Py_BEGIN_ALLOW_THREADS
        status = sk_mesh_stretch(&stretch, v[0].buffer.buf, v[1].buffer.buf, triangle_count, &error);
        Py_END_ALLOW_THREADS
        result = status == SK_OK ? PyFloat_FromDouble(stretch) : raise_status(&error);
    }
    release(v, 2);
    return result;
}

static PyObject *py_pack_charts(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objects[4];
    sk_pack_options options;
    if (!PyArg_ParseTuple(args, "OOOOid", &objects[0], &objects[1], &objects[2], &objects[3], &options.texture_size,
                          &options.margin))
        return NULL;
    enum { DEST, UV, CHARTS, AREA };
    array_view v[4];
    memset(v, 0, sizeof v);
    PyObject *result = NULL;
    sk_error error = {0};
    size_t triangle_count = 0;
    if (acquire(&v[DEST], objects[0], "destination", "d", 1) && acquire(&v[UV], objects[1], "uv", "d", 0) &&
        acquire(&v[CHARTS], objects[2], "charts", "i", 0) &&
        (objects[3] == Py_None || acquire(&v[AREA], objects[3], "surface_area", "d", 0)) &&
        expect_multiple(&v[UV], "uv", 6, &triangle_count) && expect_count(&v[DEST], "destination", 6 * triangle_count) &&
        expect_count(&v[CHARTS], "charts", triangle_count) &&
        (objects[3] == Py_None || expect_count(&v[AREA], "surface_area", triangle_count))) {
        sk_pack_report report = {0};
        sk_status status;
        Py_BEGIN_ALLOW_THREADS
        status = sk_pack(v[DEST].buffer.buf, &report, v[UV].buffer.buf, v[CHARTS].buffer.buf,
                         v[AREA].held ? v[AREA].buffer.buf : NULL, triangle_count, &options, &error);
        Py_END_ALLOW_THREADS
        result = status == SK_OK ? Py_BuildValue("{s:n,s:d,s:d}", "chart_count", (Py_ssize_t)report.chart_count,
                                                 "scale", report.scale, "packing_efficiency",
                                                 report.packing_efficiency)
                                 : raise_status(&error);
    }
    release(v, 4);
    return result;
}

/* ---- skinning a mesh sequence without a rig ---------------------------------------------------- */

static PyObject *py_fit_core_motions(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objects[5];
    Py_ssize_t frame_count;
    if (!PyArg_ParseTuple(args, "OOOOOn", &objects[0], &objects[1], &objects[2], &objects[3], &objects[4], &frame_count))
        return NULL;
    enum { DEST, OFFSETS, CORES, REST, FRAMES };
    array_view v[5];
    memset(v, 0, sizeof v);
    PyObject *result = NULL;
    sk_error error = {0};
    size_t bone_count = 0, vertex_count = 0;
    if (frame_count < 1) {
        PyErr_SetString(PyExc_ValueError, "frame_count must be at least 1");
        return NULL;
    }
    if (acquire(&v[DEST], objects[0], "motions", "d", 1) && acquire(&v[OFFSETS], objects[1], "core_offsets", "i", 0) &&
        acquire(&v[CORES], objects[2], "core_vertices", "i", 0) && acquire(&v[REST], objects[3], "rest_positions", "d", 0) &&
        acquire(&v[FRAMES], objects[4], "frames", "d", 0) && influence_counts(&v[OFFSETS], &bone_count) &&
        expect_multiple(&v[REST], "rest_positions", 3, &vertex_count) &&
        expect_count(&v[FRAMES], "frames", 3 * vertex_count * (size_t)frame_count) &&
        expect_count(&v[DEST], "motions", 16 * bone_count * (size_t)frame_count)) {
        sk_status status;
        Py_BEGIN_ALLOW_THREADS
        status = sk_fit_core_motions(v[DEST].buffer.buf, v[OFFSETS].buffer.buf, v[CORES].buffer.buf, v[REST].buffer.buf,
                                     v[FRAMES].buffer.buf, vertex_count, v[CORES].count, (size_t)frame_count, bone_count,
                                     &error);
        Py_END_ALLOW_THREADS
        result = outcome(status, &error);
    }
    release(v, 5);
    return result;
}

static PyObject *py_fit_rest_joints(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objects[4];
    double lambda;
    if (!PyArg_ParseTuple(args, "OOOOd", &objects[0], &objects[1], &objects[2], &objects[3], &lambda))
        return NULL;
    enum { DEST, MOTIONS, PARENTS, APPROXIMATE };
    array_view v[4];
    memset(v, 0, sizeof v);
    PyObject *result = NULL;
    sk_error error = {0};
    size_t frame_count = 0;
    if (acquire(&v[DEST], objects[0], "joints", "d", 1) && acquire(&v[MOTIONS], objects[1], "motions", "d", 0) &&
        acquire(&v[PARENTS], objects[2], "parents", "i", 0) &&
        acquire(&v[APPROXIMATE], objects[3], "approximate_joints", "d", 0) &&
        expect_count(&v[DEST], "joints", 3 * v[PARENTS].count) &&
        expect_count(&v[APPROXIMATE], "approximate_joints", 3 * v[PARENTS].count) &&
        expect_multiple(&v[MOTIONS], "motions", 16 * (v[PARENTS].count ? v[PARENTS].count : 1), &frame_count)) {
        sk_status status;
        Py_BEGIN_ALLOW_THREADS
        status = sk_fit_rest_joints(v[DEST].buffer.buf, v[MOTIONS].buffer.buf, v[PARENTS].buffer.buf,
                                    v[APPROXIMATE].buffer.buf, frame_count, v[PARENTS].count, lambda, &error);
        Py_END_ALLOW_THREADS
        result = outcome(status, &error);
    }
    release(v, 4);
    return result;
}

static PyObject *py_solve_rigid_poses(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objects[6];
    Py_ssize_t frame_count;
    int sweeps, thread_count;
    if (!PyArg_ParseTuple(args, "OOOOOOnii", &objects[0], &objects[1], &objects[2], &objects[3], &objects[4],
                          &objects[5], &frame_count, &sweeps, &thread_count))
        return NULL;
    enum { POSES, OFFSETS, BONES, COORDINATES, TARGETS, ERRORS };
    array_view v[6];
    memset(v, 0, sizeof v);
    PyObject *result = NULL;
    sk_error error = {0};
    size_t vertex_count = 0, bone_count = 0;
    if (frame_count < 1) {
        PyErr_SetString(PyExc_ValueError, "frame_count must be at least 1");
        return NULL;
    }
    if (acquire(&v[POSES], objects[0], "poses", "d", 1) && acquire(&v[OFFSETS], objects[1], "offsets", "i", 0) &&
        acquire(&v[BONES], objects[2], "bones", "i", 0) && acquire(&v[COORDINATES], objects[3], "coordinates", "d", 0) &&
        acquire(&v[TARGETS], objects[4], "targets", "d", 0) && influence_counts(&v[OFFSETS], &vertex_count) &&
        expect_count(&v[COORDINATES], "coordinates", 4 * v[BONES].count) &&
        expect_count(&v[TARGETS], "targets", 3 * vertex_count * (size_t)frame_count) &&
        expect_multiple(&v[POSES], "poses", 16 * (size_t)frame_count, &bone_count) &&
        (objects[5] == Py_None ||
         (acquire(&v[ERRORS], objects[5], "frame_errors", "d", 1) &&
          expect_count(&v[ERRORS], "frame_errors", (size_t)frame_count)))) {
        sk_status status;
        Py_BEGIN_ALLOW_THREADS
        status = sk_solve_rigid_poses(v[POSES].buffer.buf, objects[5] == Py_None ? NULL : v[ERRORS].buffer.buf,
                                      &(sk_influences){v[OFFSETS].buffer.buf, v[BONES].buffer.buf, vertex_count,
                                                       v[BONES].count},
                                      v[COORDINATES].buffer.buf, v[TARGETS].buffer.buf, (size_t)frame_count,
                                      bone_count, sweeps, thread_count, &error);
        Py_END_ALLOW_THREADS
        result = outcome(status, &error);
    }
    release(v, 6);
    return result;
}

static PyObject *py_rank_bones(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objects[6];
    Py_ssize_t frame_count, candidate_count;
    int thread_count;
    if (!PyArg_ParseTuple(args, "OOOOOOnni", &objects[0], &objects[1], &objects[2], &objects[3], &objects[4],
                          &objects[5], &frame_count, &candidate_count, &thread_count))
        return NULL;
    enum { BEST, ERRORS, REST, FRAMES, MOTIONS, ALLOWED };
    array_view v[6];
    memset(v, 0, sizeof v);
    PyObject *result = NULL;
    sk_error error = {0};
    size_t vertex_count = 0, bone_count = 0;
    if (frame_count < 1 || candidate_count < 1) {
        PyErr_SetString(PyExc_ValueError, "frame_count and candidate_count must be at least 1");
        return NULL;
    }
    const int restricted = objects[5] != Py_None;
    if (acquire(&v[BEST], objects[0], "best_bones", "i", 1) && acquire(&v[ERRORS], objects[1], "best_errors", "d", 1) &&
        acquire(&v[REST], objects[2], "rest_positions", "d", 0) && acquire(&v[FRAMES], objects[3], "frames", "d", 0) &&
        acquire(&v[MOTIONS], objects[4], "motions", "d", 0) &&
        (!restricted || acquire(&v[ALLOWED], objects[5], "allowed", "B", 0)) &&
        expect_multiple(&v[REST], "rest_positions", 3, &vertex_count) &&
        expect_count(&v[FRAMES], "frames", 3 * vertex_count * (size_t)frame_count) &&
        expect_multiple(&v[MOTIONS], "motions", 16 * (size_t)frame_count, &bone_count) &&
        expect_count(&v[BEST], "best_bones", vertex_count * (size_t)candidate_count) &&
        expect_count(&v[ERRORS], "best_errors", vertex_count * (size_t)candidate_count) &&
        (!restricted || expect_count(&v[ALLOWED], "allowed", vertex_count * bone_count))) {
        sk_status status;
        Py_BEGIN_ALLOW_THREADS
        status = sk_rank_bones(v[BEST].buffer.buf, v[ERRORS].buffer.buf, v[REST].buffer.buf, v[FRAMES].buffer.buf,
                               v[MOTIONS].buffer.buf, restricted ? v[ALLOWED].buffer.buf : NULL, vertex_count,
                               (size_t)frame_count, bone_count, (size_t)candidate_count, thread_count, &error);
        Py_END_ALLOW_THREADS
        result = outcome(status, &error);
    }
    release(v, 6);
    return result;
}

static PyMethodDef methods[] = {
    {"validate_skeleton", py_validate_skeleton, METH_VARARGS,
     "validate_skeleton(parents int32[b], rest_frames float64[b*16] or None)"},
    {"validate_influences", py_validate_influences, METH_VARARGS,
     "validate_influences(offsets int32[V+1], bones int32[K], bone_count)"},
    {"validate_triangles", py_validate_triangles, METH_VARARGS,
     "validate_triangles(triangles int32[T*3], vertex_count)"},
    {"lbs_to_animation_space", py_lbs_to_animation_space, METH_VARARGS,
     "lbs_to_animation_space(dest f64[K*4], vectors f64[V*3], homogeneous, offsets, bones, weights f64[K], "
     "rest_frames f64[b*16])"},
    {"skinning_matrices", py_skinning_matrices, METH_VARARGS,
     "skinning_matrices(dest f64[b*16], poses f64[b*16], rest_frames f64[b*16])"},
    {"animation_space_evaluate", py_animation_space_evaluate, METH_VARARGS,
     "animation_space_evaluate(dest[V*3], offsets, bones, coordinates[K*4], poses[b*16], thread_count); "
     "all float64 or all float32"},
    {"lbs_evaluate", py_lbs_evaluate, METH_VARARGS,
     "lbs_evaluate(dest[V*3], vectors[V*3], homogeneous, offsets, bones, weights[K], skinning_matrices[b*16], "
     "thread_count); all float64 or all float32"},
    {"fit_per_vertex", py_fit_per_vertex, METH_VARARGS,
     "fit_per_vertex(coordinates f64[K*4], offsets, bones, poses f64[E*b*16], examples f64[E*V*3], E, lambda, "
     "prior f64[K*4] or None, thread_count)"},
    {"fit_global", py_fit_global, METH_VARARGS,
     "fit_global(coordinates (start, in/out), offsets, bones, poses, examples, E, edges int32[2M], "
     "edge_weights f64[M], (atol, btol, conlim, iteration_limit, precondition), thread_count, progress) -> report"},
    {"lsqr_dense", py_lsqr_dense, METH_VARARGS,
     "lsqr_dense(x f64[cols], matrix f64[rows*cols], b f64[rows], rows, cols, (atol, btol, conlim, "
     "iteration_limit)) -> report"},
    {"fit_lbs_weights", py_fit_lbs_weights, METH_VARARGS,
     "fit_lbs_weights(weights f64[K], offsets, bones, skinning_matrices f64[E*b*16], rest f64[V*3], "
     "examples f64[E*V*3], E, thread_count)"},
    {"joint_statistics", py_joint_statistics, METH_VARARGS,
     "joint_statistics(expected_local f64[b*16] out, expected_gram f64[b*16] out, local f64[S*b*16], parents)"},
    {"expectation_block", py_expectation_block, METH_VARARGS,
     "expectation_block(block f64[16] out, expected_local, expected_gram, parents, j, k)"},
    {"expectation_blocks", py_expectation_blocks, METH_VARARGS,
     "expectation_blocks(blocks f64[b*b*16] out, expected_local, expected_gram, parents)"},
    {"linear_norms", py_linear_norms, METH_VARARGS,
     "linear_norms(destination f64[n] out, matrices f64[n*16]): 2-norms of the 3x3 linear parts"},
    {"mean_distances", py_mean_distances, METH_VARARGS,
     "mean_distances(dest f64[n], offsets, bones, vectors f64[K*4], expected_local, expected_gram, parents, "
     "block_cache f64[b*b*16], cached u8[b*b], thread_count)"},
    {"max_distances", py_max_distances, METH_VARARGS,
     "max_distances(dest f64[n], offsets, bones, vectors f64[K*4], parents, linear_bound f64[b], "
     "translation_centre f64[b*3], translation_radius f64[b], thread_count)"},
    {"fit_core_motions", py_fit_core_motions, METH_VARARGS,
     "fit_core_motions(motions, core_offsets, core_vertices, rest_positions, frames, frame_count): section 4.1.4."},
    {"fit_rest_joints", py_fit_rest_joints, METH_VARARGS,
     "fit_rest_joints(joints, motions, parents, approximate_joints, lambda): eq. 4.6, top-down."},
    {"solve_rigid_poses", py_solve_rigid_poses, METH_VARARGS,
     "solve_rigid_poses(poses, offsets, bones, coordinates, targets, frame_errors|None, frame_count, sweeps, "
     "threads): poses in place."},
    {"rank_bones", py_rank_bones, METH_VARARGS,
     "rank_bones(best_bones, best_errors, rest, frames, motions, allowed|None, frame_count, candidates, threads)."},
    {"segment", py_segment, METH_VARARGS,
     "segment(charts i32[T] out, embedding f64[V*d], d, triangles i32[T*3], seams i32[2S], mode, chart_count, "
     "threshold, rho) -> (chart_count, mesh_metric, component_count)"},
    {"segment_corners", py_segment_corners, METH_VARARGS,
     "segment_corners(corners u8[V] out, triangles i32[T*3], charts i32[T], embedding f64[V*d] or None, d, V)"},
    {"segment_cut", py_segment_cut, METH_VARARGS,
     "segment_cut(cut_triangles i32[T*3] out, source_vertex i32[T*3] out, triangles i32[T*3], seams i32[2S], V) "
     "-> cut vertex count"},
    {"segment_straighten", py_segment_straighten, METH_VARARGS,
     "segment_straighten(charts i32[T] in/out, corners u8[V] out, embedding f64[V*d], d, triangles i32[T*3], ratio, "
     "rho) -> (paths, shortest, constrained, kept)"},
    {"flatten_charts", py_flatten_charts, METH_VARARGS,
     "flatten_charts(uv f64[T*6] out, charts_out i32[T] out, triangles i32[T*3], edge_lengths_sq f64[T*3], "
     "charts i32[T], corners u8[V], (straight, optimise, stretch_limit, sweep_limit, thread_count)) -> report"},
    {"stretch_triangles", py_stretch_triangles, METH_VARARGS,
     "stretch_triangles(dest f64[T] out, uv f64[T*6], edge_lengths_sq f64[T*3]): L2 stretch per triangle"},
    {"stretch_mesh", py_stretch_mesh, METH_VARARGS,
     "stretch_mesh(uv f64[T*6], edge_lengths_sq f64[T*3]) -> Sander's normalised L2 stretch"},
    {"pack_charts", py_pack_charts, METH_VARARGS,
     "pack_charts(dest f64[T*6] out, uv f64[T*6], charts i32[T], surface_area f64[T] or None, texture_size, "
     "margin) -> report"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "skinkit._core",
                                    "Native core of skinkit (stable ABI).", -1, methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__core(void)
{
    PyObject *m = PyModule_Create(&module);
    if (!m)
        return NULL;
    skinkit_error_type = PyErr_NewException("skinkit._core.Error", PyExc_ValueError, NULL);
    if (!skinkit_error_type || PyModule_AddObjectRef(m, "Error", skinkit_error_type) < 0 ||
        PyModule_AddStringConstant(m, "core_version", SK_VERSION_STRING) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
