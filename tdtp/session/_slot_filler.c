/* SlotFiller: build an instance of a __slots__ class straight into its slots.
 *
 * tdtp builds one DataReceived (a frozen dataclass with slots) per sample received. Python can only
 * fill a frozen instance through each slot's descriptor (object.__new__, then one generic call per
 * field, each packing its arguments into a tuple): about 3,000 instructions per sample in the
 * compiled build, on the path from a datagram's arrival to the application's callback. This type
 * resolves the slots' offsets once, from the class's member descriptors, and then allocates the
 * instance with the class's own tp_alloc and stores each argument in its slot: the same object as
 * DataReceived(...) would give (equal, hashed, printed and pickled alike), without calling
 * __init__ (a frozen dataclass's __init__ stores the same values through object.__setattr__).
 *
 * Optional, like tdtp/aio/_datagram.c: tdtp/session/events.py falls back to the descriptors where
 * this was not built, and in the pure-Python build.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stddef.h>
#include <structmember.h>

#define MAX_FIELDS 16

typedef struct {
    PyObject_HEAD
    vectorcallfunc vectorcall;
    PyTypeObject *cls;
    Py_ssize_t count;
    Py_ssize_t offsets[MAX_FIELDS];
} SlotFiller;

static PyObject *
filler_vectorcall(PyObject *op, PyObject *const *args, size_t nargsf, PyObject *kwnames)
{
    SlotFiller *self = (SlotFiller *)op;
    Py_ssize_t n = PyVectorcall_NARGS(nargsf);
    if (kwnames != NULL && PyTuple_GET_SIZE(kwnames) > 0) {
        PyErr_SetString(PyExc_TypeError, "SlotFiller takes its values by position only");
        return NULL;
    }
    if (n != self->count) {
        PyErr_Format(PyExc_TypeError, "SlotFiller for %s takes %zd values, got %zd",
                     self->cls->tp_name, self->count, n);
        return NULL;
    }
    PyObject *obj = self->cls->tp_alloc(self->cls, 0);
    if (obj == NULL) {
        return NULL;
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject **slot = (PyObject **)((char *)obj + self->offsets[i]);
        Py_INCREF(args[i]);
        *slot = args[i]; /* freshly allocated: every slot is NULL */
    }
    return obj;
}

static PyObject *
filler_new(PyTypeObject *type, PyObject *args, PyObject *kwds)
{
    PyObject *cls_obj;
    PyObject *names;
    static char *keywords[] = {"cls", "names", NULL};
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "O!O:SlotFiller", keywords, &PyType_Type,
                                     &cls_obj, &names)) {
        return NULL;
    }
    PyTypeObject *cls = (PyTypeObject *)cls_obj;
    if (cls->tp_new != PyBaseObject_Type.tp_new) {
        PyErr_Format(PyExc_TypeError, "%s has its own __new__: SlotFiller would bypass it",
                     cls->tp_name);
        return NULL;
    }
    PyObject *seq = PySequence_Fast(names, "names must be a sequence of slot names");
    if (seq == NULL) {
        return NULL;
    }
    Py_ssize_t count = PySequence_Fast_GET_SIZE(seq);
    if (count > MAX_FIELDS) {
        PyErr_Format(PyExc_ValueError, "at most %d slots", MAX_FIELDS);
        Py_DECREF(seq);
        return NULL;
    }
    SlotFiller *self = (SlotFiller *)type->tp_alloc(type, 0);
    if (self == NULL) {
        Py_DECREF(seq);
        return NULL;
    }
    for (Py_ssize_t i = 0; i < count; i++) {
        PyObject *name = PySequence_Fast_GET_ITEM(seq, i);
        PyObject *descr = PyDict_GetItemWithError(cls->tp_dict, name); /* borrowed */
        if (descr == NULL || !PyObject_TypeCheck(descr, &PyMemberDescr_Type)) {
            if (!PyErr_Occurred()) {
                PyErr_Format(PyExc_TypeError, "%R is not a slot of %s", name, cls->tp_name);
            }
            Py_DECREF(seq);
            Py_DECREF(self);
            return NULL;
        }
        PyMemberDef *member = ((PyMemberDescrObject *)descr)->d_member;
        if (member->type != T_OBJECT_EX || (member->flags & READONLY)) {
            PyErr_Format(PyExc_TypeError, "%R of %s is not a plain object slot", name,
                         cls->tp_name);
            Py_DECREF(seq);
            Py_DECREF(self);
            return NULL;
        }
        self->offsets[i] = member->offset;
    }
    Py_DECREF(seq);
    Py_INCREF(cls);
    self->cls = cls;
    self->count = count;
    self->vectorcall = filler_vectorcall;
    return (PyObject *)self;
}

static void
filler_dealloc(PyObject *op)
{
    SlotFiller *self = (SlotFiller *)op;
    Py_XDECREF(self->cls);
    Py_TYPE(op)->tp_free(op);
}

static PyObject *
filler_repr(PyObject *op)
{
    SlotFiller *self = (SlotFiller *)op;
    return PyUnicode_FromFormat("<SlotFiller for %s, %zd slots>",
                                self->cls ? self->cls->tp_name : "?", self->count);
}

static PyTypeObject SlotFillerType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "tdtp.session._slot_filler.SlotFiller",
    .tp_doc = PyDoc_STR("SlotFiller(cls, names): a callable that builds an instance of the "
                        "__slots__ class cls from one value per name, stored straight into "
                        "its slots (no __init__)."),
    .tp_basicsize = sizeof(SlotFiller),
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_VECTORCALL,
    .tp_new = filler_new,
    .tp_dealloc = filler_dealloc,
    .tp_repr = filler_repr,
    .tp_call = PyVectorcall_Call,
    .tp_vectorcall_offset = offsetof(SlotFiller, vectorcall),
};

static struct PyModuleDef slot_filler_module = {
    PyModuleDef_HEAD_INIT,
    .m_name = "tdtp.session._slot_filler",
    .m_doc = PyDoc_STR("Instances of __slots__ classes built straight into their slots."),
    .m_size = -1,
};

PyMODINIT_FUNC
PyInit__slot_filler(void)
{
    if (PyType_Ready(&SlotFillerType) < 0) {
        return NULL;
    }
    PyObject *module = PyModule_Create(&slot_filler_module);
    if (module == NULL) {
        return NULL;
    }
    Py_INCREF(&SlotFillerType);
    if (PyModule_AddObject(module, "SlotFiller", (PyObject *)&SlotFillerType) < 0) {
        Py_DECREF(&SlotFillerType);
        Py_DECREF(module);
        return NULL;
    }
    return module;
}
