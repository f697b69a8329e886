# cython: language_level=3, binding=True, boundscheck=False, wraparound=False
# cython: initializedcheck=False, cdivision=True, infer_types=False
"""The compiled twin of protocol A's decoding hot path (see chassis_sdk/core/compiled.py).

`feed` does what ``FrameDecoder.feed`` does with ``_ProtocolADecoder._try_frame``, step for
step, for `ChassisDecoder` and `ChassisCommandDecoder` exactly (not their subclasses):
the scanning loop, the header, the checksum and the tail are read in C; the 0x81
telemetry frame (50 Hz per chassis) is unpacked in C and built as its pure parser
builds it (``object.__new__`` and each slot's descriptor, the same enum caches, the same
``tuple.__new__`` for the wheels); every other frame goes to the Python parser in the
decoder's ``_table``, so the tables stay the single source. The sequence tracker's
usual frame (both numbering schemes agree) is checked in C and leaves the tracker's
state exactly as ``SequenceTracker.update`` would; every other frame calls it.

Whatever this code is not sure to mirror exactly, it hands to the pure code: a class
whose ``_try_frame`` or ``_head`` was changed, a buffer, table or tracker of another type
(the whole call goes to ``FrameDecoder.feed``), a table entry it does not expect (that
candidate goes to the Python ``_try_frame``, which is what the pure loop would call
there). No bound is trusted: every read is checked against the end of the buffer, whose
size cannot change during the call (a buffer export is held on it).

protocol.py calls `bind` once with the objects of the pure code this mirrors.
"""

from cpython.buffer cimport PyBUF_SIMPLE, PyBuffer_Release, PyObject_GetBuffer
from cpython.dict cimport PyDict_GetItemWithError, PyDict_SetItem
from cpython.float cimport PyFloat_FromDouble
from cpython.list cimport PyList_Append
from cpython.long cimport PyLong_FromLong
from cpython.object cimport PyObject
from cpython.tuple cimport PyTuple_Pack
from libc.string cimport memchr

cdef extern from *:
    """
    /* object.__new__(cls): what frozen_builder's ``_new(_cls)`` does. */
    static PyObject *chassis_a_new_object(PyObject *cls, PyObject *no_args) {
        return PyBaseObject_Type.tp_new((PyTypeObject *)cls, no_args, NULL);
    }
    /* tuple.__new__(cls, (a, b, c, d)): the pure parser's ``_tuple_new(WheelSpeeds, ...)``
       for a tuple subclass is tuple_subtype_new: cls->tp_alloc(cls, 4), the items set;
       done here without its two temporary tuples. Python 3.14 gives tuples a hash cache
       to set up: there, tuple.__new__ itself is called. A tuple subclass without a
       __dict__ (bind checks it) whose items are floats can be in no reference cycle
       but one through its class (an attribute of WheelSpeeds holding it: a leak no code
       here makes), so the collector need not track it (CPython untracks exact tuples
       of such items when it first meets them, never a subclass): untracked, the wheels
       of every frame cost the collector nothing; their dealloc is the same. */
    static PyObject *chassis_a_new_tuple4(PyObject *cls, double a, double b, double c, double d) {
    #if PY_VERSION_HEX >= 0x030E0000
        PyObject *items = Py_BuildValue("((dddd))", a, b, c, d);
        if (items == NULL) return NULL;
        PyObject *made = PyTuple_Type.tp_new((PyTypeObject *)cls, items, NULL);
        Py_DECREF(items);
        if (made != NULL) PyObject_GC_UnTrack(made);
        return made;
    #else
        PyTypeObject *type = (PyTypeObject *)cls;
        PyObject *made, *item;
        double values[4] = {a, b, c, d};
        made = type->tp_alloc(type, 4);
        if (made == NULL) return NULL;
        for (int i = 0; i < 4; i++) {
            item = PyFloat_FromDouble(values[i]);
            if (item == NULL) {
                Py_DECREF(made);
                return NULL;
            }
            PyTuple_SET_ITEM(made, i, item);
        }
        PyObject_GC_UnTrack(made);
        return made;
    #endif
    }
    /* descriptor.__set__(obj, value): what frozen_builder's ``_setN(self, value)`` does. */
    static int chassis_a_descr_set(PyObject *descr, PyObject *obj, PyObject *value) {
        descrsetfunc set = Py_TYPE(descr)->tp_descr_set;
        if (set == NULL) {
            PyErr_SetString(PyExc_TypeError, "not a data descriptor");
            return -1;
        }
        return set(descr, obj, value);
    }
    /* descriptor.__get__(obj, type(obj)): a slot's value (AttributeError if unset). */
    static PyObject *chassis_a_descr_get(PyObject *descr, PyObject *obj) {
        descrgetfunc get = Py_TYPE(descr)->tp_descr_get;
        if (get == NULL) {
            PyErr_SetString(PyExc_TypeError, "not a descriptor");
            return NULL;
        }
        return get(descr, obj, (PyObject *)Py_TYPE(obj));
    }
    /* The type's version tag: CPython resets it to 0 (invalid) whenever the type or one
       of its bases is changed, and gives it a new, unused one at its next lookup; what
       was read from a type holds while the tag is the same. */
    static unsigned int chassis_a_type_tag(PyObject *type) {
    #if PY_VERSION_HEX < 0x030C0000
        if (!PyType_HasFeature((PyTypeObject *)type, Py_TPFLAGS_VALID_VERSION_TAG)) return 0;
    #endif
        return ((PyTypeObject *)type)->tp_version_tag;
    }
    /* Whether a type's attributes are looked up plainly (no __getattribute__/__getattr__),
       and set plainly (no __setattr__/__delattr__). */
    static int chassis_a_plain_getattr(PyObject *type) {
        return ((PyTypeObject *)type)->tp_getattro == PyObject_GenericGetAttr;
    }
    static int chassis_a_plain_setattr(PyObject *type) {
        return ((PyTypeObject *)type)->tp_setattro == PyObject_GenericSetAttr;
    }
    """
    unsigned int chassis_a_type_tag(object type) noexcept
    bint chassis_a_plain_getattr(object type) noexcept
    bint chassis_a_plain_setattr(object type) noexcept
    object chassis_a_new_object(object cls, object no_args)
    object chassis_a_new_tuple4(object cls, double a, double b, double c, double d)
    object chassis_a_descr_get(object descr, object obj)
    int chassis_a_descr_set(object descr, object obj, object value) except -1

cdef extern from "Python.h":
    long PyLong_AsLongAndOverflow(object value, int *overflow) except? -1

# _try_frame's results (core.framing's NEED_DATA and INVALID), and the layout of a frame.
cdef enum:
    NEED_DATA = 0
    INVALID = -1
    OVERHEAD = 10
    DATA = 6
    TELEMETRY_SIZE = 28
    # Sizes beyond this are not the protocol's (its length byte stops at 255): such an
    # entry in a changed table goes to the Python _try_frame.
    MAX_SIZE = 1 << 20

# The pure code's objects, set by bind().
cdef object _decoder_cls = None  # ChassisDecoder
cdef object _command_cls = None  # ChassisCommandDecoder
cdef object _pure_feed = None  # FrameDecoder.feed
cdef object _pure_try_frame = None  # _ProtocolADecoder._try_frame
cdef object _tracker_cls = None  # SequenceTracker
cdef object _update = None  # SequenceTracker.update
cdef object _parse_telemetry = None
cdef object _telemetry_cls = None
cdef object _wheels_cls = None
cdef object _status = None  # MemberCache(ChassisStatus)
cdef object _docking = None  # MemberCache(DockingState)
cdef tuple _slots = ()  # Telemetry's slot descriptors, in field order
cdef object _last_slot = None  # SequenceTracker's _last and _by_id slot descriptors
cdef object _by_id_slot = None
cdef object _buf_slot = None  # the decoders' _buf, stats and sequence slot descriptors
cdef object _stats_slot = None
cdef object _sequence_slot = None
cdef object _stats_cls = None  # DecoderStats, and its counters' slot descriptors
cdef object _received_slot = None
cdef object _frames_slot = None
cdef object _dropped_slot = None
cdef unsigned int _stats_tag = 0
cdef tuple _no_args = ()
cdef bint _bound = False

# What feed last checked on each decoder class (0: ChassisDecoder, 1: the command one) and
# on the tracker's class, valid while the class's version tag is the one recorded.
cdef unsigned int _class_tag[2]
cdef list _class_table = [None, None]
cdef unsigned char _class_head[2][2]
cdef unsigned int _tracker_tag = 0
_class_tag[0] = _class_tag[1] = 0


def bind(
    *,
    decoder_cls,
    command_cls,
    pure_feed,
    try_frame,
    tracker_cls,
    stats_cls,
    parse_telemetry,
    telemetry_cls,
    wheels_cls,
    status,
    docking,
):
    """Give this module the pure code's objects it mirrors (protocol.py calls it once).

    Raises:
        TypeError: ``telemetry_cls`` is not a slotted dataclass of eight fields held in
            slot descriptors, ``wheels_cls`` is not a tuple subclass without a
            ``__dict__`` (its instances are left untracked by the collector), or the
            caches are not dicts.
    """
    global _decoder_cls, _command_cls, _pure_feed, _pure_try_frame, _tracker_cls, _update
    global _parse_telemetry, _telemetry_cls, _wheels_cls, _status, _docking, _slots, _bound
    global _last_slot, _by_id_slot, _buf_slot, _stats_slot, _sequence_slot, _stats_cls
    global _received_slot, _frames_slot, _dropped_slot
    import dataclasses
    import types

    names = [f.name for f in dataclasses.fields(telemetry_cls)]
    slots = tuple(telemetry_cls.__dict__.get(name) for name in names)
    if len(slots) != 8 or not all(type(s) is types.MemberDescriptorType for s in slots):
        raise TypeError(f"{telemetry_cls!r} is not a slotted dataclass of 8 fields")
    tracker_slots = (tracker_cls.__dict__.get("_last"), tracker_cls.__dict__.get("_by_id"))
    decoder_slots = (decoder_cls._buf, decoder_cls.stats, decoder_cls.sequence)
    stats_slots = tuple(
        stats_cls.__dict__.get(name) for name in ("bytes_received", "frames", "bytes_dropped")
    )
    for held in (tracker_slots, decoder_slots, stats_slots):
        if not all(type(s) is types.MemberDescriptorType for s in held):
            raise TypeError(f"not slot descriptors: {held!r}")
    if not (issubclass(wheels_cls, tuple) and wheels_cls.__dictoffset__ == 0):
        raise TypeError(f"{wheels_cls!r} is not a tuple subclass without a __dict__")
    if not isinstance(status, dict) or not isinstance(docking, dict):
        raise TypeError("the enum caches must be dicts (core.construct.MemberCache)")
    _decoder_cls = decoder_cls
    _command_cls = command_cls
    _pure_feed = pure_feed
    _pure_try_frame = try_frame
    _tracker_cls = tracker_cls
    _update = tracker_cls.update
    _parse_telemetry = parse_telemetry
    _telemetry_cls = telemetry_cls
    _wheels_cls = wheels_cls
    _status = status
    _docking = docking
    _slots = slots
    _last_slot, _by_id_slot = tracker_slots
    _buf_slot, _stats_slot, _sequence_slot = decoder_slots
    _stats_cls = stats_cls
    _received_slot, _frames_slot, _dropped_slot = stats_slots
    _bound = True


cdef inline unsigned int _u16(const unsigned char *p, Py_ssize_t i) noexcept:
    return p[i] | (<unsigned int>p[i + 1] << 8)


cdef inline int _i16(const unsigned char *p, Py_ssize_t i) noexcept:
    cdef unsigned int u = p[i] | (<unsigned int>p[i + 1] << 8)
    return <int>u - 0x10000 if u >= 0x8000 else <int>u


cdef inline object _member(object cache, unsigned int value):
    # cache[value] as the pure parser does it: a dict hit, else MemberCache.__missing__.
    cdef PyObject *hit
    key = PyLong_FromLong(value)
    hit = PyDict_GetItemWithError(cache, key)
    if hit != NULL:
        return <object>hit
    return cache[key]


cdef object _telemetry(const unsigned char *p, Py_ssize_t o, object ts):
    """_parse_telemetry in C: the frame's data at ``p[o:o + 18]``, its number at ``o - 4``."""
    cdef double fl = _i16(p, o + 10) / 1000.0, fr = _i16(p, o + 12) / 1000.0
    cdef double rl = _i16(p, o + 14) / 1000.0, rr = _i16(p, o + 16) / 1000.0
    wheels = chassis_a_new_tuple4(_wheels_cls, fl, fr, rl, rr)
    return _build(
        PyFloat_FromDouble(_u16(p, o) / 10.0),
        _member(_status, _u16(p, o + 2)),
        _member(_docking, _u16(p, o + 4)),
        PyFloat_FromDouble(_i16(p, o + 6) / 1000.0),
        PyFloat_FromDouble(_i16(p, o + 8) / 1000.0),
        wheels,
        PyLong_FromLong(_u16(p, o - 4)),
        ts,
    )


cdef object _build(object v, object st, object dk, object vx, object wz, object w, object seq, object ts):
    # frozen_builder(Telemetry): object.__new__, then each field through its slot.
    msg = chassis_a_new_object(_telemetry_cls, _no_args)
    cdef tuple s = _slots
    chassis_a_descr_set(s[0], msg, v)
    chassis_a_descr_set(s[1], msg, st)
    chassis_a_descr_set(s[2], msg, dk)
    chassis_a_descr_set(s[3], msg, vx)
    chassis_a_descr_set(s[4], msg, wz)
    chassis_a_descr_set(s[5], msg, w)
    chassis_a_descr_set(s[6], msg, seq)
    chassis_a_descr_set(s[7], msg, ts)
    return msg


cdef int _track(object tracker, bint inline_ok, int frame_id, unsigned int seq) except -1:
    """SequenceTracker.update(frame_id, seq); its usual case done here, to the same state."""
    cdef PyObject *previous
    cdef long last_value, previous_value
    cdef int overflow = 0
    fid = PyLong_FromLong(frame_id)
    number = PyLong_FromLong(seq)
    if inline_ok:
        last = chassis_a_descr_get(_last_slot, tracker)  # tracker._last
        by_id = chassis_a_descr_get(_by_id_slot, tracker)
        if type(last) is int and type(by_id) is dict:
            last_value = PyLong_AsLongAndOverflow(last, &overflow)
            # (last + 1) & 0xFFFF as Python computes it: unsigned arithmetic wraps modulo
            # a multiple of 65536, so the low 16 bits are the same, for negatives too.
            if not overflow and ((<unsigned long>last_value + 1) & 0xFFFF) == seq:
                # The shared scheme agrees; and the per-id one?
                previous = PyDict_GetItemWithError(by_id, fid)
                if previous != NULL and type(<object>previous) is int:
                    previous_value = PyLong_AsLongAndOverflow(<object>previous, &overflow)
                    if overflow or ((<unsigned long>previous_value + 1) & 0xFFFF) != seq:
                        overflow = 1
                elif previous != NULL:
                    overflow = 1
                if not overflow:  # both agree: update() would set these and return
                    chassis_a_descr_set(_last_slot, tracker, number)  # tracker._last = number
                    PyDict_SetItem(by_id, fid, number)
                    return 0
    tracker.update(fid, number)
    return 0


cdef Py_ssize_t _find(const unsigned char *p, Py_ssize_t pos, Py_ssize_t n,
                      unsigned char h0, unsigned char h1) noexcept:
    """buf.find(head, pos) for a two-byte head, or -1."""
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


cdef Py_ssize_t _try(object self, object buf, const unsigned char *p, Py_ssize_t start,
                     Py_ssize_t end, list out, object ts, dict table, object stats,
                     object tracker, bint inline_track) except -2:
    """_ProtocolADecoder._try_frame at ``p[start]``, the frames right behind it too."""
    cdef Py_ssize_t first = start, size, stop, i
    cdef unsigned int seq, frame_id, claimed, total
    cdef int overflow = 0
    cdef PyObject *found
    while True:
        if end - start < 6:
            return NEED_DATA if start == first else start - first
        seq = _u16(p, start + 2)
        frame_id = p[start + 4]
        claimed = p[start + 5]
        found = PyDict_GetItemWithError(table, PyLong_FromLong(frame_id))
        if found == NULL or <object>found is None:
            return INVALID if start == first else start - first
        entry = <object>found
        if not (type(entry) is tuple and len(<tuple>entry) == 2 and type((<tuple>entry)[0]) is int):
            break  # an entry the pure code may read otherwise: it decides
        size = PyLong_AsLongAndOverflow((<tuple>entry)[0], &overflow)
        if overflow or not (size == 0 or OVERHEAD <= size <= MAX_SIZE):
            break
        parser = (<tuple>entry)[1]
        if size == 0:
            if claimed < OVERHEAD:
                return INVALID if start == first else start - first
            size = claimed
        stop = start + size
        if stop > end:
            return NEED_DATA if start == first else start - first
        if _u16(p, stop - 2) != 0xBCBD:
            return INVALID if start == first else start - first
        # byte_sum (Adler-32's low half, the byte sum modulo 65521) of all before the check.
        total = 0
        for i in range(start, stop - 4):
            total += p[i]
        if (total % 65521) & 0xFFFF != _u16(p, stop - 4):
            if start != first:
                return start - first
            stats.checksum_errors += 1
            return INVALID
        if parser is _parse_telemetry and size == TELEMETRY_SIZE:
            msg = _telemetry(p, start + DATA, ts)
        else:
            msg = parser(buf, start + DATA, size - OVERHEAD, ts)
            if msg is None:
                if start != first:
                    return start - first
                stats.malformed_frames += 1
                return INVALID
        if claimed != size:
            stats.length_mismatches += 1
        _track(tracker, inline_track, frame_id, seq)
        PyList_Append(out, msg)
        start = stop
        if end - start < 2 or p[start] != 0xED or p[start + 1] != 0xDE:
            return start - first
    # Past the first frame, stop before the entry: the loop comes back to it as a first.
    if start != first:
        return start - first
    return self._try_frame(buf, start, end, out, ts)


cdef bint _stats_plain():
    """Whether DecoderStats is as bind found it (its counters in the slots recorded, read
    and written plainly); checked again only when its version tag changes."""
    global _stats_tag
    cdef unsigned int tag = chassis_a_type_tag(_stats_cls)
    if tag != 0 and tag == _stats_tag:
        return True
    _stats_tag = 0
    names = _stats_cls.__dict__
    if not (
        chassis_a_plain_getattr(_stats_cls)
        and chassis_a_plain_setattr(_stats_cls)
        and names.get("bytes_received") is _received_slot
        and names.get("frames") is _frames_slot
        and names.get("bytes_dropped") is _dropped_slot
    ):
        return False
    _stats_tag = chassis_a_type_tag(_stats_cls)
    return True


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
    cdef Py_buffer view
    cdef int which
    cdef unsigned int tag
    global _tracker_tag
    cls = type(self)
    if not _bound:
        return _pure_feed(self, data, timestamp)
    if cls is _decoder_cls:
        which = 0
    elif cls is _command_cls:
        which = 1
    else:
        return _pure_feed(self, data, timestamp)
    if not chassis_a_plain_getattr(cls):  # a __getattribute__ or __getattr__: pure
        return _pure_feed(self, data, timestamp)
    tag = chassis_a_type_tag(cls)
    if tag != 0 and tag == _class_tag[which]:
        # The class is as it was checked: its attributes and slots are the ones recorded.
        stored = chassis_a_descr_get(_buf_slot, self)  # self._buf
        tracker = chassis_a_descr_get(_sequence_slot, self)  # self.sequence
        table = _class_table[which]
        h0 = _class_head[which][0]
        h1 = _class_head[which][1]
    else:
        _class_tag[which] = 0
        stored = self._buf
        tracker = self.sequence
        head = self._head
        table = self._table
        if (
            cls._try_frame is not _pure_try_frame
            or type(head) is not bytes
            or len(<bytes>head) != 2
            or type(table) is not dict
        ):
            return _pure_feed(self, data, timestamp)
        h0 = (<bytes>head)[0]
        h1 = (<bytes>head)[1]
        if cls._buf is _buf_slot and cls.stats is _stats_slot and cls.sequence is _sequence_slot:
            _class_table[which] = table
            _class_head[which][0] = h0
            _class_head[which][1] = h1
            _class_tag[which] = chassis_a_type_tag(cls)
    if type(stored) is not bytearray:
        return _pure_feed(self, data, timestamp)
    if type(tracker) is not _tracker_cls:
        inline_track = False
    else:
        tag = chassis_a_type_tag(_tracker_cls)
        inline_track = tag != 0 and tag == _tracker_tag
        if not inline_track:
            _tracker_tag = 0
            names = _tracker_cls.__dict__
            inline_track = (
                _tracker_cls.update is _update
                and names.get("_last") is _last_slot
                and names.get("_by_id") is _by_id_slot
                and chassis_a_plain_getattr(_tracker_cls)
            )
            if inline_track:
                _tracker_tag = chassis_a_type_tag(_tracker_cls)
    # From here on, FrameDecoder.feed line for line.
    if stored:
        stored += data
        buf = stored
    else:
        buf = data if type(data) is bytes else bytes(data)
    if _class_tag[which] != 0:
        stats = chassis_a_descr_get(_stats_slot, self)  # self.stats
    else:
        stats = self.stats
    n = len(buf)
    fast_stats = type(stats) is _stats_cls and _stats_plain()
    if fast_stats:  # stats.bytes_received += len(data)
        count = chassis_a_descr_get(_received_slot, stats)
        count += len(data)
        chassis_a_descr_set(_received_slot, stats, count)
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
            consumed = _try(self, buf, p, start, n, out, timestamp, table, stats, tracker,
                            inline_track)
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
            count = chassis_a_descr_get(_dropped_slot, stats)
            count += dropped
            chassis_a_descr_set(_dropped_slot, stats, count)
        count = chassis_a_descr_get(_frames_slot, stats)  # stats.frames += len(out)
        count += len(out)
        chassis_a_descr_set(_frames_slot, stats, count)
        return out
    if dropped:
        stats.bytes_dropped += dropped
    stats.frames += len(out)
    return out
