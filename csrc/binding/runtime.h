/*
 * The runtime of the generated binding (csrc/binding/pymodule.c, from scripts/gen_bindings.py): written by hand,
 * included once by the generated file, after its count_name enum (the counts an array size can name, NO_COUNT = 0
 * first, COUNT_NAMES last) and its result_storage union (what the C calls write besides arrays).
 *
 * Every entry point is one `entry`: its arguments in Python order, each array with the size rule that ties its
 * length to the counts, and a `run` function holding the C call. call_entry() parses and checks every argument
 * against the entry, releases the GIL around run(), and turns the status into None, a result dict or an exception.
 * Exceptions: TypeError or ValueError naming the argument for a bad argument, skinkit._core.Error (a ValueError)
 * for a failed status, MemoryError for SK_ERROR_MEMORY.
 */
#ifndef SKINKIT_BINDING_RUNTIME_H
#define SKINKIT_BINDING_RUNTIME_H

enum { MAX_ARGUMENTS = 40, MAX_FACTORS = 3 }; /* sk_simplify_chain_tuned takes 33 */

typedef enum argument_kind { ARRAY, SIZE, REAL, INTEGER, FLAG, PROGRESS } argument_kind;

/* An array's length is factor * counts[0] * counts[1] * counts[2] + bias. The rule either checks that (derives ==
 * NO_COUNT) or sets the one count it derives from the length, the others being known by then: the arrays' rules
 * run in the order of their steps, which the generator chose so. */
typedef struct size_rule {
    int step;
    count_name derives;
    size_t factor;
    size_t bias;
    count_name counts[MAX_FACTORS];
    char expression[64]; /* the size as the spec writes it, for messages */
} size_rule;

typedef struct argument {
    char name[40];
    argument_kind kind;
    char types[4];     /* ARRAY: the element types accepted: 'd' double, 'f' float, 'i' int32, 'H' uint16, 'B' uint8
                        * or bool */
    int writable;      /* ARRAY: a destination */
    int optional;      /* ARRAY: None passes NULL */
    size_rule size;    /* ARRAY */
    count_name count;  /* SIZE: the count it sets */
    long minimum;      /* SIZE, INTEGER */
    long maximum;      /* INTEGER; 0 with minimum 0: no bound but int's */
} argument;

typedef struct array_view {
    Py_buffer buffer;
    int held;
    char type;
    size_t count;
} array_view;

typedef struct frame {
    array_view view[MAX_ARGUMENTS];
    void *data[MAX_ARGUMENTS]; /* the arrays' memory, NULL for an optional array passed as None */
    double real[MAX_ARGUMENTS];
    int integer[MAX_ARGUMENTS];
    size_t count[COUNT_NAMES];
    PyObject *progress; /* borrowed from the arguments; NULL for None */
    int single_precision;
    result_storage result;
} frame;

/*
 * An entry's arguments come as a text table, one line per argument in Python order, read once when the module
 * loads (read_table), after a heading line that starts with '#':
 *   name  in|out|inout|optional_in|optional_out  types  size  step  [derived count]   an array
 *   name  size  minimum                                                                  a count given by the caller
 *   name  integer  minimum  maximum,   name  real,   name  flag,   name  progress        the other scalars
 * The C call is the entry's run(); DEFINE_ENTRY() writes both.
 */
typedef struct entry {
    const char *name;
    sk_status (*run)(frame *f, sk_error *error);
    PyObject *(*result)(const frame *f); /* NULL: the function returns None */
    const char *doc;
    const char *table;
    argument arguments[MAX_ARGUMENTS];
    size_t argument_count;
} entry;

#define LENGTH(array) (sizeof(array) / sizeof((array)[0]))
/* An entry, name_entry, and its run(): the C call (run with the GIL released), on the frame's arguments. */
#define DEFINE_ENTRY(name, result, doc_text, table_text, ...) \
    static sk_status run_##name(frame *f, sk_error *error) { return __VA_ARGS__; } \
    static entry name##_entry = {#name, run_##name, result, .doc = doc_text, .table = table_text};

static PyObject *skinkit_error_type; /* skinkit._core.Error, a ValueError */

/* ---- arrays ---- */

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
    if (*format == 'H' && buffer->itemsize == 2)
        return 'H';
    return '?';
}

/* Acquires a C-contiguous buffer of one of the wanted element types. */
static int acquire(array_view *view, PyObject *object, const argument *a)
{
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (a->writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(object, &view->buffer, flags) != 0) {
        PyErr_Format(PyExc_TypeError, "%s must be a C-contiguous%s array", a->name, a->writable ? " writable" : "");
        return 0;
    }
    view->held = 1;
    view->type = element_type(&view->buffer);
    if (view->type == '?' || !strchr(a->types, view->type)) {
        PyErr_Format(PyExc_TypeError, "%s has element type '%s', expected one of '%s'", a->name,
                     view->buffer.format ? view->buffer.format : "B", a->types);
        return 0;
    }
    view->count = (size_t)(view->buffer.len / view->buffer.itemsize);
    return 1;
}

static void release(frame *f, size_t count)
{
    for (size_t i = 0; i < count; ++i)
        if (f->view[i].held)
            PyBuffer_Release(&f->view[i].buffer);
}

/* Arrays accepting both precisions ("df") must all have the first one's; run() picks _f32 or _f64 by it. */
static int check_precision(frame *f, const entry *e)
{
    const char *first = NULL;
    char type = 0;
    for (size_t i = 0; i < e->argument_count; ++i) {
        const argument *a = &e->arguments[i];
        if (a->kind != ARRAY || strcmp(a->types, "df") != 0 || !f->view[i].held)
            continue;
        if (!first) {
            first = a->name;
            type = f->view[i].type;
        } else if (f->view[i].type != type) {
            PyErr_Format(PyExc_TypeError, "%s and %s must have the same precision", first, a->name);
            return 0;
        }
    }
    f->single_precision = type == 'f';
    return 1;
}

/* ---- sizes ---- */

static int checked_mul(size_t a, size_t b, size_t *product)
{
    if (b != 0 && a > SIZE_MAX / b)
        return 0;
    *product = a * b;
    return 1;
}

/* factor times the rule's known counts; a ValueError naming the array when that does not fit in a size_t. */
static int known_product(const frame *f, const char *name, const size_rule *rule, size_t *product)
{
    *product = rule->factor;
    for (int i = 0; i < MAX_FACTORS; ++i)
        if (rule->counts[i] != NO_COUNT && !checked_mul(*product, f->count[rule->counts[i]], product)) {
            PyErr_Format(PyExc_ValueError, "%s: its size %s overflows", name, rule->expression);
            return 0;
        }
    if (rule->derives == NO_COUNT && *product > SIZE_MAX - rule->bias) {
        PyErr_Format(PyExc_ValueError, "%s: its size %s overflows", name, rule->expression);
        return 0;
    }
    return 1;
}

static int apply_rule(frame *f, const array_view *view, const char *name, const size_rule *rule)
{
    size_t product;
    if (!view->held)
        return 1; /* an optional array passed as None */
    if (!known_product(f, name, rule, &product))
        return 0;
    if (rule->derives == NO_COUNT) {
        if (view->count == product + rule->bias)
            return 1;
        PyErr_Format(PyExc_ValueError, "%s has %zu elements, expected %zu (%s)", name, view->count,
                     product + rule->bias, rule->expression);
        return 0;
    }
    if (view->count < rule->bias) {
        PyErr_Format(PyExc_ValueError, "%s has %zu elements, expected at least %zu (%s)", name, view->count,
                     rule->bias, rule->expression);
        return 0;
    }
    const size_t rest = view->count - rule->bias;
    if (product == 0 ? rest != 0 : rest % product != 0) {
        PyErr_Format(PyExc_ValueError, "%s has %zu elements, not a multiple of %zu (%s)", name, view->count, product,
                     rule->expression);
        return 0;
    }
    f->count[rule->derives] = product == 0 ? 0 : rest / product;
    return 1;
}

/* ---- scalars ---- */

/* long long, not long: long is 32 bits on 64-bit Windows, where a size of 2**31 or more would be refused as out of
 * range instead of checked like everywhere else. */
static int parse_long(PyObject *object, const char *name, long long *value)
{
    PyObject *index = PyNumber_Index(object);
    if (!index) {
        PyErr_Format(PyExc_TypeError, "%s must be an integer", name);
        return 0;
    }
    int overflow = 0;
    *value = PyLong_AsLongLongAndOverflow(index, &overflow);
    Py_DECREF(index);
    if (overflow != 0 || (*value == -1 && PyErr_Occurred())) {
        PyErr_Clear();
        PyErr_Format(PyExc_ValueError, "%s is out of range", name);
        return 0;
    }
    return 1;
}

static int parse_size(frame *f, PyObject *object, const argument *a)
{
    long long value;
    if (!parse_long(object, a->name, &value))
        return 0;
    if (value < 0 && a->minimum >= 0) {
        PyErr_Format(PyExc_ValueError, "%s must not be negative", a->name);
        return 0;
    }
    if (value < a->minimum) {
        PyErr_Format(PyExc_ValueError, "%s must be at least %ld", a->name, a->minimum);
        return 0;
    }
    f->count[a->count] = (size_t)value;
    return 1;
}

static int parse_integer(frame *f, size_t i, PyObject *object, const argument *a)
{
    const int bounded = a->minimum != 0 || a->maximum != 0;
    const long long minimum = bounded ? a->minimum : INT_MIN, maximum = bounded ? a->maximum : INT_MAX;
    long long value;
    if (!parse_long(object, a->name, &value))
        return 0;
    if (value < minimum || value > maximum) {
        PyErr_Format(PyExc_ValueError, "%s must be between %lld and %lld, got %lld", a->name, minimum, maximum,
                     value);
        return 0;
    }
    f->integer[i] = (int)value;
    return 1;
}

static int parse_real(frame *f, size_t i, PyObject *object, const argument *a)
{
    f->real[i] = PyFloat_AsDouble(object);
    if (f->real[i] == -1.0 && PyErr_Occurred()) {
        PyErr_Format(PyExc_TypeError, "%s must be a number", a->name);
        return 0;
    }
    return 1;
}

static int parse_argument(frame *f, size_t i, PyObject *object, const argument *a)
{
    switch (a->kind) {
    case ARRAY:
        if (a->optional && object == Py_None)
            return 1;
        if (!acquire(&f->view[i], object, a))
            return 0;
        f->data[i] = f->view[i].buffer.buf;
        return 1;
    case SIZE:
        return parse_size(f, object, a);
    case REAL:
        return parse_real(f, i, object, a);
    case INTEGER:
        return parse_integer(f, i, object, a);
    case FLAG:
        f->integer[i] = PyObject_IsTrue(object);
        return f->integer[i] >= 0;
    case PROGRESS:
        if (object != Py_None && !PyCallable_Check(object)) {
            PyErr_Format(PyExc_TypeError, "%s must be callable or None", a->name);
            return 0;
        }
        f->progress = object == Py_None ? NULL : object;
        return 1;
    }
    return 0;
}

/* ---- calls ---- */

/* The arguments in the entry's order, positional or by keyword; a missing optional array or progress is None. */
static int collect(const entry *e, PyObject *args, PyObject *kwargs, PyObject **objects)
{
    const Py_ssize_t given = PyTuple_Size(args);
    Py_ssize_t by_keyword = 0;
    if (given > (Py_ssize_t)e->argument_count) {
        PyErr_Format(PyExc_TypeError, "%s() takes %zu arguments (%zd given)", e->name, e->argument_count, given);
        return 0;
    }
    for (size_t i = 0; i < e->argument_count; ++i) {
        const argument *a = &e->arguments[i];
        PyObject *keyword = kwargs ? PyDict_GetItemString(kwargs, a->name) : NULL;
        by_keyword += keyword != NULL;
        if (keyword && (Py_ssize_t)i < given) {
            PyErr_Format(PyExc_TypeError, "%s() got two values for '%s'", e->name, a->name);
            return 0;
        }
        objects[i] = (Py_ssize_t)i < given ? PyTuple_GetItem(args, (Py_ssize_t)i) : keyword;
        if (!objects[i] && (a->optional || a->kind == PROGRESS))
            objects[i] = Py_None;
        if (!objects[i]) {
            PyErr_Format(PyExc_TypeError, "%s() missing argument '%s'", e->name, a->name);
            return 0;
        }
    }
    if (kwargs && PyDict_Size(kwargs) != by_keyword) {
        PyErr_Format(PyExc_TypeError, "%s() got an unexpected keyword argument", e->name);
        return 0;
    }
    return 1;
}

static int prepare(frame *f, const entry *e, PyObject *args, PyObject *kwargs)
{
    PyObject *objects[MAX_ARGUMENTS];
    if (!collect(e, args, kwargs, objects))
        return 0;
    for (size_t i = 0; i < e->argument_count; ++i)
        if (!parse_argument(f, i, objects[i], &e->arguments[i]))
            return 0;
    if (!check_precision(f, e))
        return 0;
    for (int step = 0; step < (int)e->argument_count; ++step)
        for (size_t i = 0; i < e->argument_count; ++i) {
            const argument *a = &e->arguments[i];
            if (a->kind == ARRAY && a->size.step == step && !apply_rule(f, &f->view[i], a->name, &a->size))
                return 0;
        }
    return 1;
}

/* Raises the C message as it is (it names the element); the status travels as the exception's `status`
 * attribute ("index out of range", ...), for callers that branch on the kind of failure. */
static PyObject *raise_status(const sk_error *error)
{
    PyObject *type = error->status == SK_ERROR_MEMORY ? PyExc_MemoryError : skinkit_error_type;
    PyObject *exception = PyObject_CallFunction(type, "s", error->message);
    PyObject *status = PyUnicode_FromString(sk_status_name(error->status));
    if (exception && status && PyObject_SetAttrString(exception, "status", status) == 0)
        PyErr_SetObject(type, exception);
    Py_XDECREF(status);
    Py_XDECREF(exception);
    return NULL;
}

#define ENTRY_CAPSULE "skinkit._core.entry"

static PyObject *call_entry(PyObject *capsule, PyObject *args, PyObject *kwargs)
{
    const entry *e = PyCapsule_GetPointer(capsule, ENTRY_CAPSULE);
    if (!e)
        return NULL;
    frame f;
    memset(&f, 0, sizeof f);
    PyObject *result = NULL;
    if (prepare(&f, e, args, kwargs)) {
        sk_error error = {0};
        sk_status status;
        Py_BEGIN_ALLOW_THREADS
        status = e->run(&f, &error);
        Py_END_ALLOW_THREADS
        if (status != SK_OK)
            result = raise_status(&error);
        else
            result = e->result ? e->result(&f) : Py_NewRef(Py_None);
    }
    release(&f, e->argument_count);
    return result;
}

/* Calls a Python progress callable from a solver thread; a true result, an exception or Ctrl-C cancels. */
static int report_progress(void *user, double fraction)
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

/* ---- reading the argument tables ---- */

static count_name find_count(const char *name, size_t length)
{
    for (int i = NO_COUNT + 1; i < COUNT_NAMES; ++i)
        if (strlen(count_names[i]) == length && strncmp(count_names[i], name, length) == 0)
            return (count_name)i;
    return NO_COUNT;
}

/* "16*example_count*bone_count" or "vertex_count+1" into factor, bias and the counts other than the derived one. */
static int read_size(size_rule *rule, const char *text)
{
    int known = 0;
    rule->factor = 1;
    for (const char *term = text; *term && *term != '+';) {
        const size_t length = strcspn(term, "*+");
        if (isdigit((unsigned char)*term)) {
            rule->factor *= strtoul(term, NULL, 10);
        } else {
            const count_name count = find_count(term, length);
            if (count == NO_COUNT || (count != rule->derives && known == MAX_FACTORS))
                return 0;
            if (count != rule->derives)
                rule->counts[known++] = count;
        }
        term += length + (term[length] == '*');
    }
    const char *plus = strchr(text, '+');
    rule->bias = plus ? strtoul(plus + 1, NULL, 10) : 0;
    return strlen(text) < sizeof rule->expression && strcpy(rule->expression, text);
}

static int read_array(argument *a, const char *kind, const char *rest)
{
    static const char *const kinds[] = {"in", "out", "inout", "optional_in", "optional_out"};
    char size[64] = "", derives[40] = "";
    size_t k = 0;
    while (k < LENGTH(kinds) && strcmp(kind, kinds[k]) != 0)
        ++k;
    if (k == LENGTH(kinds) || sscanf(rest, "%3s %63s %d %39s", a->types, size, &a->size.step, derives) < 3)
        return 0;
    a->kind = ARRAY;
    a->writable = k != 0 && k != 3;
    a->optional = k >= 3;
    a->size.derives = derives[0] ? find_count(derives, strlen(derives)) : NO_COUNT;
    return (!derives[0] || a->size.derives != NO_COUNT) && read_size(&a->size, size);
}

static int read_argument(argument *a, const char *line)
{
    static const char *const scalars[] = {"size", "real", "integer", "flag", "progress"};
    char kind[16] = "";
    int consumed = 0;
    memset(a, 0, sizeof *a);
    a->size.step = -1;
    if (sscanf(line, "%39s %15s %n", a->name, kind, &consumed) < 2)
        return 0;
    for (size_t k = 0; k < LENGTH(scalars); ++k)
        if (strcmp(kind, scalars[k]) == 0) {
            a->kind = (argument_kind)(SIZE + k);
            a->count = a->kind == SIZE ? find_count(a->name, strlen(a->name)) : NO_COUNT;
            sscanf(line + consumed, "%ld %ld", &a->minimum, &a->maximum);
            return a->kind != SIZE || a->count != NO_COUNT;
        }
    return read_array(a, kind, line + consumed);
}

static int read_table(entry *e)
{
    e->argument_count = 0;
    for (const char *line = e->table; *line; e->argument_count++) {
        char text[160];
        const size_t length = strcspn(line, "\n");
        if (e->argument_count == MAX_ARGUMENTS || length >= sizeof text)
            return 0;
        memcpy(text, line, length);
        text[length] = '\0';
        line += length + (line[length] == '\n');
        if (text[0] == '#')
            --e->argument_count; /* a heading */
        else if (!read_argument(&e->arguments[e->argument_count], text))
            return 0;
    }
    return 1;
}

/* ---- the module ---- */

#define SK_STRINGIFY(x) #x
#define SK_VERSION_TEXT(a, b, c) SK_STRINGIFY(a) "." SK_STRINGIFY(b) "." SK_STRINGIFY(c)
#define SK_VERSION_STRING SK_VERSION_TEXT(SK_VERSION_MAJOR, SK_VERSION_MINOR, SK_VERSION_PATCH)

/* One builtin function per entry, bound to a capsule holding the entry (its `self`). */
static int add_function(PyObject *module, PyObject *module_name, entry *e, PyMethodDef *definition)
{
    if (!read_table(e)) {
        PyErr_Format(PyExc_RuntimeError, "skinkit._core: the argument table of %s does not read", e->name);
        return 0;
    }
    *definition = (PyMethodDef){e->name, (PyCFunction)(void (*)(void))call_entry, METH_VARARGS | METH_KEYWORDS, e->doc};
    PyObject *capsule = PyCapsule_New((void *)e, ENTRY_CAPSULE, NULL);
    PyObject *function = capsule ? PyCFunction_NewEx(definition, capsule, module_name) : NULL;
    const int added = function && PyModule_AddObjectRef(module, e->name, function) == 0;
    Py_XDECREF(function);
    Py_XDECREF(capsule);
    return added;
}

static struct PyModuleDef module_definition = {
    PyModuleDef_HEAD_INIT, "skinkit._core", "Native core of skinkit (stable ABI); generated by scripts/gen_bindings.py.",
    -1, NULL, NULL, NULL, NULL, NULL};

static PyObject *create_module(entry *const *entries, size_t count, PyMethodDef *definitions)
{
    PyObject *module = PyModule_Create(&module_definition);
    PyObject *name = module ? PyUnicode_FromString(module_definition.m_name) : NULL;
    int ok = name != NULL;
    for (size_t i = 0; ok && i < count; ++i)
        ok = add_function(module, name, entries[i], &definitions[i]);
    Py_XDECREF(name);
    skinkit_error_type = ok ? PyErr_NewException("skinkit._core.Error", PyExc_ValueError, NULL) : NULL;
    if (!skinkit_error_type || PyModule_AddObjectRef(module, "Error", skinkit_error_type) < 0 ||
        PyModule_AddStringConstant(module, "core_version", SK_VERSION_STRING) < 0) {
        Py_XDECREF(module);
        return NULL;
    }
    return module;
}

/* ---- test helpers ---- */

/* A dense row-major matrix as an sk_linear_operator, for testing LSQR against a direct solve (lsqr_dense_matrix). */
typedef struct dense_matrix {
    const double *values;
    size_t rows, cols;
} dense_matrix;

static void dense_apply(void *user, int transpose, const double *in, double *out)
{
    const dense_matrix *a = user;
    for (size_t i = 0; i < (transpose ? a->cols : a->rows); ++i)
        out[i] = 0.0;
    for (size_t r = 0; r < a->rows; ++r)
        for (size_t c = 0; c < a->cols; ++c) {
            if (transpose)
                out[c] += a->values[r * a->cols + c] * in[r];
            else
                out[r] += a->values[r * a->cols + c] * in[c];
        }
}

#endif /* SKINKIT_BINDING_RUNTIME_H */
