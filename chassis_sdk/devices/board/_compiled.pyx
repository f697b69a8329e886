# cython: language_level=3, binding=True, boundscheck=False, wraparound=False
# cython: initializedcheck=False, cdivision=True, infer_types=False
"""The compiled twin of protocol B's decoding hot path (see chassis_sdk/core/compiled.py).

`feed` does what ``FrameDecoder.feed`` does with ``_ProtocolBDecoder._try_frame`` and
``_swallows_a_head``, step for step, for `BoardDecoder` and `BoardCommandDecoder` exactly
(not their subclasses): the scanning loop, the type and length tests, the checksum and
the alignment rule are done in C; the 0x11 IMU sample (100 Hz) is unpacked in C and
built as its pure parser builds it (``object.__new__`` and each slot's descriptor, as
``frozen_builder`` does, and ``tuple.__new__`` for the vectors and the counts); every
other frame goes to the Python parser in the decoder's ``_table``, so the tables stay
the single source. The head, the table and ``check_alignment`` are read from the
decoder at each call, so a class or an instance that changes them is honoured.

Whatever this code is not sure to mirror exactly, it hands to the pure code: a class or
an instance whose ``_try_frame`` or ``_swallows_a_head`` was changed, a head, buffer or
table of another type (the whole call goes to ``FrameDecoder.feed``). No bound is
trusted: every read is checked against the end of the buffer, whose size cannot change
during the call (a buffer export is held on it).

protocol.py calls `bind` once with the objects of the pure code this mirrors.
"""

from cpython.buffer cimport PyBUF_SIMPLE, PyBuffer_Release, PyObject_GetBuffer
from cpython.dict cimport PyDict_GetItemWithError
from cpython.list cimport PyList_Append
from cpython.long cimport PyLong_AsLongAndOverflow, PyLong_FromLong
from cpython.object cimport PyObject
from libc.string cimport memchr

cdef extern from *:
    """
    /* object.__new__(cls): what frozen_builder's ``_new(_cls)`` does. */
    static PyObject *board_b_new_object(PyObject *cls, PyObject *no_args) {
        return PyBaseObject_Type.tp_new((PyTypeObject *)cls, no_args, NULL);
    }
    /* The tuples a sample holds are left untracked by the collector. A tuple subclass
       without a __dict__ (bind checks it) whose items are all floats or ints can be in
       no reference cycle but one through its class (the class an attribute of which
       holds it, a leak no code here makes): CPython itself untracks exact tuples of
       such items when it first meets them, never a subclass. Untracked, the three
       vectors and the counts of every sample cost the collector nothing; the dealloc
       is the same (subtype_dealloc untracks only what is tracked, and re-tracks before
       the base's dealloc). */
    static PyObject *board_b_untracked(PyObject *t) {
        if (t != NULL)
            PyObject_GC_UnTrack(t);
        return t;
    }
    /* tuple.__new__(cls, (a, b, c)): the pure parser's ``_tuple_new(Vector3, (...))``.
       Before 3.14 that is tuple_subtype_new: cls->tp_alloc(cls, 3), then the items (here
       without its two temporary tuples); from 3.14, whose tuples cache their hash, the
       call itself. The items are new references, stolen. */
    static PyObject *board_b_tuple3(PyObject *cls, PyObject *a, PyObject *b, PyObject *c) {
        PyObject *t;
    #if PY_VERSION_HEX < 0x030E0000
        t = ((PyTypeObject *)cls)->tp_alloc((PyTypeObject *)cls, 3);
        if (t != NULL) {
            PyTuple_SET_ITEM(t, 0, a);
            PyTuple_SET_ITEM(t, 1, b);
            PyTuple_SET_ITEM(t, 2, c);
            return board_b_untracked(t);
        }
    #else
        PyObject *items = PyTuple_New(3);
        if (items != NULL) {
            PyTuple_SET_ITEM(items, 0, a);
            PyTuple_SET_ITEM(items, 1, b);
            PyTuple_SET_ITEM(items, 2, c);
            PyObject *args = PyTuple_Pack(1, items);
            Py_DECREF(items);
            if (args == NULL)
                return NULL;
            t = PyTuple_Type.tp_new((PyTypeObject *)cls, args, NULL);
            Py_DECREF(args);
            return board_b_untracked(t);
        }
    #endif
        Py_DECREF(a);
        Py_DECREF(b);
        Py_DECREF(c);
        return NULL;
    }
    /* The same for ImuCounts: tuple.__new__(cls, (c[0], ..., c[8])), nine int16. */
    static PyObject *board_b_counts(PyObject *cls, const int *c) {
        PyObject *t;
        Py_ssize_t i;
    #if PY_VERSION_HEX < 0x030E0000
        t = ((PyTypeObject *)cls)->tp_alloc((PyTypeObject *)cls, 9);
        if (t == NULL)
            return NULL;
        for (i = 0; i < 9; i++) {
            PyObject *item = PyLong_FromLong(c[i]);
            if (item == NULL) {
                Py_DECREF(t);  /* its unset items are NULL, which dealloc skips */
                return NULL;
            }
            PyTuple_SET_ITEM(t, i, item);
        }
        return board_b_untracked(t);
    #else
        PyObject *items = PyTuple_New(9);
        if (items == NULL)
            return NULL;
        for (i = 0; i < 9; i++) {
            PyObject *item = PyLong_FromLong(c[i]);
            if (item == NULL) {
                Py_DECREF(items);
                return NULL;
            }
            PyTuple_SET_ITEM(items, i, item);
        }
        PyObject *args = PyTuple_Pack(1, items);
        Py_DECREF(items);
        if (args == NULL)
            return NULL;
        t = PyTuple_Type.tp_new((PyTypeObject *)cls, args, NULL);
        Py_DECREF(args);
        return board_b_untracked(t);
    #endif
    }
    /* A float for each of a, b, c (NULL on failure, with nothing leaked). */
    static PyObject *board_b_vector(PyObject *cls, double a, double b, double c) {
        PyObject *x = PyFloat_FromDouble(a), *y = PyFloat_FromDouble(b), *z = PyFloat_FromDouble(c);
        if (x == NULL || y == NULL || z == NULL) {
            Py_XDECREF(x);
            Py_XDECREF(y);
            Py_XDECREF(z);
            return NULL;
        }
        return board_b_tuple3(cls, x, y, z);
    }
    /* descriptor.__set__(obj, value): what frozen_builder's ``_setN(self, value)`` does. */
    static int board_b_descr_set(PyObject *descr, PyObject *obj, PyObject *value) {
        descrsetfunc set = Py_TYPE(descr)->tp_descr_set;
        if (set == NULL) {
            PyErr_SetString(PyExc_TypeError, "not a data descriptor");
            return -1;
        }
        return set(descr, obj, value);
    }
    /* What a class defines (or inherits) under ``name``, before any descriptor or
       instance is looked at: a borrowed reference, or NULL (no error set). */
    static PyObject *board_b_class_attr(PyObject *cls, PyObject *name) {
        return _PyType_Lookup((PyTypeObject *)cls, name);
    }
    /* descriptor.__get__(obj, type(obj)): a slot's value (AttributeError if unset). */
    static PyObject *board_b_descr_get(PyObject *descr, PyObject *obj) {
        descrgetfunc get = Py_TYPE(descr)->tp_descr_get;
        if (get == NULL) {
            PyErr_SetString(PyExc_TypeError, "not a descriptor");
            return NULL;
        }
        return get(descr, obj, (PyObject *)Py_TYPE(obj));
    }
    /* Whether a type's attributes are looked up plainly (no __getattribute__/__getattr__),
       and set plainly (no __setattr__/__delattr__). */
    static int board_b_plain_getattr(PyObject *type) {
        return ((PyTypeObject *)type)->tp_getattro == PyObject_GenericGetAttr;
    }
    static int board_b_plain_setattr(PyObject *type) {
        return ((PyTypeObject *)type)->tp_setattro == PyObject_GenericSetAttr;
    }
    /* The type's version tag: CPython resets it to 0 (invalid) whenever the type or one
       of its bases is changed, and gives it a new, unused one at its next lookup; what
       was read from a type holds while the tag is the same. */
    static unsigned int board_b_type_tag(PyObject *type) {
    #if PY_VERSION_HEX < 0x030C0000
        if (!PyType_HasFeature((PyTypeObject *)type, Py_TPFLAGS_VALID_VERSION_TAG)) return 0;
    #endif
        return ((PyTypeObject *)type)->tp_version_tag;
    }
    """
    object board_b_new_object(object cls, object no_args)
    object board_b_vector(object cls, double a, double b, double c)
    object board_b_counts(object cls, const int *counts)
    int board_b_descr_set(object descr, object obj, object value) except -1
    PyObject *board_b_class_attr(object cls, object name)
    unsigned int board_b_type_tag(object type) noexcept
    bint board_b_plain_getattr(object type) noexcept
    bint board_b_plain_setattr(object type) noexcept
    object board_b_descr_get(object descr, object obj)
    object PyObject_GenericGetDict(object obj, void *context)

# _try_frame's results (core.framing's NEED_DATA and INVALID), and the frame's layout:
# head, type, length, data (length - 1 bytes), check; the IMU frame's length byte.
cdef enum:
    NEED_DATA = 0
    INVALID = -1
    HEADER = 4
    IMU_LENGTH = 0x13
    # _swallows_a_head's results: None, False, True.
    UNDECIDED = -1
    NO_HEAD = 0
    A_HEAD = 1

# The pure code's objects, set by bind().
cdef object _decoder_cls = None  # BoardDecoder
cdef object _command_cls = None  # BoardCommandDecoder
cdef object _pure_feed = None  # FrameDecoder.feed
cdef object _try_frame = None  # _ProtocolBDecoder._try_frame
cdef object _swallows = None  # _ProtocolBDecoder._swallows_a_head
cdef object _parse_imu = None
cdef object _imu_cls = None  # ImuSample
cdef object _vector_cls = None  # Vector3
cdef object _counts_cls = None  # ImuCounts
cdef double _accel = 1.0  # ACCEL_SCALE
cdef double _gyro = 1.0  # GYRO_SCALE
cdef tuple _slots = ()  # ImuSample's slot descriptors, in field order
cdef object _stats_cls = None  # DecoderStats, and its counters' slot descriptors
cdef object _received_slot = None
cdef object _frames_slot = None
cdef object _dropped_slot = None
cdef unsigned int _stats_tag = 0
cdef tuple _no_args = ()
cdef bint _bound = False

# What feed read from each decoder class (0: BoardDecoder, 1: BoardCommandDecoder) for an
# instance with nothing of its own, and the class's version tag then (0: nothing kept):
# while the tag is the same, the class is as it was read, and feed skips the lookups.
cdef unsigned int _class_tag[2]
cdef list _class_head = [None, None]
cdef list _class_table = [None, None]
cdef int _class_align[2]
_class_tag[0] = _class_tag[1] = 0


def bind(
    *,
    decoder_cls,
    command_cls,
    pure_feed,
    try_frame,
    swallows_a_head,
    parse_imu,
    imu_cls,
    vector_cls,
    counts_cls,
    stats_cls,
    accel_scale,
    gyro_scale,
):
    """Give this module the pure code's objects it mirrors (protocol.py calls it once).

    The two scales are read here, once: they are the module's constants, which the pure
    ``_parse_imu`` divides by.

    Raises:
        TypeError: ``imu_cls`` is not a slotted dataclass of five fields held in slot
            descriptors, ``vector_cls`` or ``counts_cls`` is not a tuple subclass
            without a ``__dict__`` (its instances are left untracked by the collector),
            ``stats_cls`` does not hold its counters in slot descriptors, or a scale is
            not a float.
    """
    global _decoder_cls, _command_cls, _pure_feed, _try_frame, _swallows, _parse_imu
    global _imu_cls, _vector_cls, _counts_cls, _accel, _gyro, _slots, _bound
    global _stats_cls, _received_slot, _frames_slot, _dropped_slot
    import dataclasses
    import types

    names = [f.name for f in dataclasses.fields(imu_cls)]
    slots = tuple(imu_cls.__dict__.get(name) for name in names)
    if len(slots) != 5 or not all(type(s) is types.MemberDescriptorType for s in slots):
        raise TypeError(f"{imu_cls!r} is not a slotted dataclass of 5 fields")
    stats_slots = tuple(
        stats_cls.__dict__.get(name) for name in ("bytes_received", "frames", "bytes_dropped")
    )
    if not all(type(s) is types.MemberDescriptorType for s in stats_slots):
        raise TypeError(f"not slot descriptors: {stats_slots!r}")
    for cls in (vector_cls, counts_cls):
        if not (issubclass(cls, tuple) and cls.__dictoffset__ == 0):
            raise TypeError(f"{cls!r} is not a tuple subclass without a __dict__")
    if type(accel_scale) is not float or type(gyro_scale) is not float:
        raise TypeError("the IMU scales must be floats")
    _decoder_cls = decoder_cls
    _command_cls = command_cls
    _pure_feed = pure_feed
    _try_frame = try_frame
    _swallows = swallows_a_head
    _parse_imu = parse_imu
    _imu_cls = imu_cls
    _vector_cls = vector_cls
    _counts_cls = counts_cls
    _accel = accel_scale
    _gyro = gyro_scale
    _slots = slots
    _stats_cls = stats_cls
    _received_slot, _frames_slot, _dropped_slot = stats_slots
    _bound = True


cdef inline int _i16(const unsigned char *p, Py_ssize_t i) noexcept:
    cdef unsigned int u = p[i] | (<unsigned int>p[i + 1] << 8)
    return <int>u - 0x10000 if u >= 0x8000 else <int>u


cdef object _imu(const unsigned char *p, Py_ssize_t o, object ts):
    """_parse_imu in C: the frame's data, nine int16, at ``p[o:o + 18]``."""
    cdef int c[9]
    cdef int i
    for i in range(9):
        c[i] = _i16(p, o + 2 * i)
    # Python's int / float converts the (exact) int to a double and divides: the same.
    accel = board_b_vector(_vector_cls, c[0] / _accel, c[1] / _accel, c[2] / _accel)
    gyro = board_b_vector(_vector_cls, c[3] / _gyro, c[4] / _gyro, c[5] / _gyro)
    mag = board_b_vector(_vector_cls, <double>c[6], <double>c[7], <double>c[8])
    counts = board_b_counts(_counts_cls, c)
    # frozen_builder(ImuSample): object.__new__, then each field through its slot.
    msg = board_b_new_object(_imu_cls, _no_args)
    cdef tuple s = _slots
    board_b_descr_set(s[0], msg, accel)
    board_b_descr_set(s[1], msg, gyro)
    board_b_descr_set(s[2], msg, mag)
    board_b_descr_set(s[3], msg, ts)
    board_b_descr_set(s[4], msg, counts)
    return msg


cdef Py_ssize_t _find(const unsigned char *p, Py_ssize_t pos, Py_ssize_t n,
                      unsigned char h0, unsigned char h1) noexcept:
    """buf.find(head, pos, n) for a two-byte head (``n`` at most the buffer's size), or -1."""
    cdef const unsigned char *hit
    while n - pos >= 2:
        hit = <const unsigned char *>memchr(p + pos, h0, <size_t>(n - 1 - pos))
        if hit == NULL:
            return -1
        pos = hit - p
        if p[pos + 1] == h1:
            return pos
        pos += 1
    return -1


cdef int _refused(object expected, unsigned int length) except -1:
    """_try_frame's ``length != expected if expected else length == 0``."""
    cdef int overflow = 0
    cdef long value
    if type(expected) is int:
        value = PyLong_AsLongAndOverflow(expected, &overflow)
        if overflow:
            return 1  # not 0, and no byte holds it
        return length != value if value else length == 0
    # Another type in a changed table: Python decides, as in the pure code.
    if (length != expected) if expected else (length == 0):
        return 1
    return 0


cdef int _plausible(object expected, unsigned int length) except -1:
    """_swallows_a_head's ``length == expected if expected else length != 0``."""
    cdef int overflow = 0
    cdef long value
    if type(expected) is int:
        value = PyLong_AsLongAndOverflow(expected, &overflow)
        if overflow:
            return 0
        return length == value if value else length != 0
    if (length == expected) if expected else (length != 0):
        return 1
    return 0


cdef int _swallows_a_head(const unsigned char *p, Py_ssize_t start, Py_ssize_t stop,
                          Py_ssize_t end, dict table, unsigned char h0,
                          unsigned char h1) except -2:
    """_ProtocolBDecoder._swallows_a_head: A_HEAD, NO_HEAD or UNDECIDED (its None)."""
    cdef Py_ssize_t limit = stop + 1 if stop + 1 < end else end  # find() clips to the end
    cdef Py_ssize_t i = _find(p, start + 1, limit, h0, h1)
    cdef PyObject *found
    while i >= 0:
        if i + 2 >= end:
            return UNDECIDED
        found = PyDict_GetItemWithError(table, PyLong_FromLong(p[i + 2]))
        if found != NULL and <object>found is not None:
            if i + 3 >= end:
                return UNDECIDED
            if _plausible((<object>found)[0], p[i + 3]):
                return A_HEAD
        i = _find(p, i + 1, limit, h0, h1)
    if stop >= end and p[stop - 1] == h0:
        return UNDECIDED
    return NO_HEAD


cdef Py_ssize_t _try(object buf, const unsigned char *p, Py_ssize_t start, Py_ssize_t end,
                     list out, object ts, dict table, unsigned char h0, unsigned char h1,
                     object stats, int *align, object self) except -2:
    """_ProtocolBDecoder._try_frame at ``p[start]``. ``align[0]`` is check_alignment's
    truth, -1 until it is first needed (then read from ``self``, once per call)."""
    cdef Py_ssize_t stop, i, limit
    cdef unsigned int msg_type, length, total
    cdef PyObject *found
    cdef bint imu
    cdef int swallowed
    if end - start < HEADER:
        return NEED_DATA
    msg_type = p[start + 2]
    found = PyDict_GetItemWithError(table, PyLong_FromLong(msg_type))
    if found == NULL or <object>found is None:
        return INVALID
    expected, parser = <object>found
    length = p[start + 3]
    if _refused(expected, length):
        return INVALID
    stop = start + HEADER + length
    if stop > end:
        return NEED_DATA
    total = msg_type + length
    for i in range(start + HEADER, stop - 1):
        total += p[i]
    if (total & 0xFF) != p[stop - 1]:
        stats.checksum_errors += 1
        return INVALID
    # The IMU sample cannot be malformed: it is built once the alignment rule took it.
    imu = parser is _parse_imu and length == IMU_LENGTH
    if imu:
        msg = None
    else:
        msg = parser(buf, start + HEADER, length - 1, ts)
        if msg is None:
            stats.malformed_frames += 1
            return INVALID
    if align[0] < 0:
        align[0] = 1 if self.check_alignment else 0
    if align[0]:
        limit = stop + 1 if stop + 1 < end else end
        if _find(p, start + 1, limit, h0, h1) >= 0 or (stop >= end and p[stop - 1] == h0):
            swallowed = _swallows_a_head(p, start, stop, end, table, h0, h1)
            if swallowed == UNDECIDED:
                return NEED_DATA
            if swallowed == A_HEAD:
                stats.misaligned_frames += 1
                return INVALID
    if imu:
        msg = _imu(p, start + HEADER, ts)
    PyList_Append(out, msg)
    return stop - start


cdef bint _stats_plain():
    """Whether DecoderStats is as bind found it (its counters in the slots recorded, read
    and written plainly); checked again only when its version tag changes."""
    global _stats_tag
    cdef unsigned int tag = board_b_type_tag(_stats_cls)
    if tag != 0 and tag == _stats_tag:
        return True
    _stats_tag = 0
    names = _stats_cls.__dict__
    if not (
        board_b_plain_getattr(_stats_cls)
        and board_b_plain_setattr(_stats_cls)
        and names.get("bytes_received") is _received_slot
        and names.get("frames") is _frames_slot
        and names.get("bytes_dropped") is _dropped_slot
    ):
        return False
    _stats_tag = board_b_type_tag(_stats_cls)
    return True


cdef object _class_value(object cls, object name, type kind):
    """What ``instance.name`` is for an instance with nothing of its own under ``name``,
    if the class holds a ``kind`` (which is no descriptor) there; else None."""
    cdef PyObject *found = board_b_class_attr(cls, name)
    if found != NULL and type(<object>found) is kind:
        return <object>found
    return None


def feed(self, data, timestamp=0.0):
    """Consume ``data`` and return every message completed by it, in wire order.

    Args:
        data: The bytes as they arrived; any chunking, garbage included.
        timestamp: Time of receipt, stored on timestamped messages. The decoder never
            reads a clock itself; the link passes ``time.monotonic()``.

    Returns:
        The decoded messages (possibly none). Never raises for any input.
    """
    cdef Py_ssize_t n, pos, start, consumed, keep, dropped
    cdef unsigned char h0, h1
    cdef const unsigned char *p
    cdef int align = -1
    cdef Py_buffer view
    cdef PyObject *found
    cdef int which
    cdef unsigned int tag
    cls = type(self)
    if not _bound:
        return _pure_feed(self, data, timestamp)
    if cls is _decoder_cls:
        which = 0
    elif cls is _command_cls:
        which = 1
    else:
        return _pure_feed(self, data, timestamp)
    # The instance (almost always with nothing of its own: its attributes are then the
    # class's, read without the instance).
    attrs = PyObject_GenericGetDict(self, NULL)
    head = table = alignment = None
    tag = board_b_type_tag(cls)
    if not attrs and tag != 0 and tag == _class_tag[which]:
        # The class is as it was read last time: the same methods and values.
        head = _class_head[which]
        table = _class_table[which]
        align = _class_align[which]
    else:
        _class_tag[which] = 0
        # The methods the pure loop would call, as the class has them...
        found = board_b_class_attr(cls, "_try_frame")
        if found == NULL or <object>found is not _try_frame:
            return _pure_feed(self, data, timestamp)
        found = board_b_class_attr(cls, "_swallows_a_head")
        if found == NULL or <object>found is not _swallows:
            return _pure_feed(self, data, timestamp)
        if not attrs:
            head = _class_value(cls, "_head", bytes)
            table = _class_value(cls, "_table", dict)
            alignment = _class_value(cls, "check_alignment", bool)
            if (
                head is not None
                and len(<bytes>head) == 2
                and table is not None
                and alignment is not None
            ):
                _class_head[which] = head
                _class_table[which] = table
                _class_align[which] = alignment is True
                _class_tag[which] = board_b_type_tag(cls)  # (the lookups gave it one)
        elif "_try_frame" in attrs or "_swallows_a_head" in attrs:
            return _pure_feed(self, data, timestamp)
    if head is None:
        head = self._head
    if table is None:
        table = self._table
    if alignment is not None:
        align = alignment is True
    stored = self._buf
    if (
        type(head) is not bytes
        or len(<bytes>head) != 2
        or type(table) is not dict
        or type(stored) is not bytearray
    ):
        return _pure_feed(self, data, timestamp)
    h0 = (<bytes>head)[0]
    h1 = (<bytes>head)[1]
    # From here on, FrameDecoder.feed line for line.
    if stored:
        stored += data
        buf = stored
    else:
        buf = data if type(data) is bytes else bytes(data)
    stats = self.stats
    n = len(buf)
    fast_stats = type(stats) is _stats_cls and _stats_plain()
    if fast_stats:  # stats.bytes_received += len(data)
        count = board_b_descr_get(_received_slot, stats)
        count += len(data)
        board_b_descr_set(_received_slot, stats, count)
    else:
        stats.bytes_received += len(data)
    out = []
    pos = 0
    dropped = 0
    # The export keeps a bytearray's size (and so p) fixed while Python code runs.
    PyObject_GetBuffer(buf, &view, PyBUF_SIMPLE)
    try:
        if view.len != n:
            raise BufferError("the buffer changed size")  # cannot happen: bytes or bytearray
        p = <const unsigned char *>view.buf
        while pos < n:
            start = _find(p, pos, n, h0, h1)
            if start < 0:
                # Keep a trailing first head byte: its partner may be in the next chunk.
                keep = n - 1 if p[n - 1] == h0 else n
                dropped += keep - pos
                pos = keep
                break
            dropped += start - pos
            consumed = _try(buf, p, start, n, out, timestamp, table, h0, h1, stats, &align,
                            self)
            if consumed > 0:
                pos = start + consumed
            elif consumed == NEED_DATA:
                pos = start
                break
            else:
                dropped += 1
                pos = start + 1
    finally:
        PyBuffer_Release(&view)
    if buf is stored:
        if pos:
            del stored[:pos]
    elif pos < n:
        stored += buf[pos:]
    if fast_stats:
        if dropped:  # stats.bytes_dropped += dropped
            count = board_b_descr_get(_dropped_slot, stats)
            count += dropped
            board_b_descr_set(_dropped_slot, stats, count)
        count = board_b_descr_get(_frames_slot, stats)  # stats.frames += len(out)
        count += len(out)
        board_b_descr_set(_frames_slot, stats, count)
        return out
    if dropped:
        stats.bytes_dropped += dropped
    stats.frames += len(out)
    return out
