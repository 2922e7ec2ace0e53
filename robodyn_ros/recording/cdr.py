"""Canonical little-endian CDR (XCDR1 plain) encoding of ROS 2 messages, driven by .msg files.

Why not ``rclpy.serialization``: Fast DDS pads the buffer with uninitialised bytes and appends
trailing bytes, so the output is neither accepted by rosbags nor byte-identical between runs. This
encoder writes exactly what rosbags' ``serialize_cdr`` and mcap-ros2-support's serializer write:

- a 4-byte encapsulation header ``00 01 00 00`` (CDR_LE, options 0);
- every primitive aligned to its own size (1, 2, 4, 8), alignment counted from the first byte
  after the header; padding bytes are zero;
- strings as uint32 length (including the terminating NUL), the UTF-8 bytes, then NUL;
- sequences (unbounded or bounded) as a uint32 count, then the elements; the elements of an empty
  sequence are not aligned (nothing is written after the count);
- fixed arrays as their elements only;
- nothing after the last field (no trailing padding to a multiple of 4);
- an empty message as one zero byte (``structure_needs_at_least_one_member``).

A message may be a dict (missing keys take the field's default, else zero/empty), or any object
with attributes named like the fields (rclpy message instances, dataclasses, ...). Nested values
may themselves be dicts or objects; arrays may be lists, tuples, ``array.array`` or numpy arrays.
"""
import struct

import numpy as np

from .msgdefs import PRIMITIVES, STRING_TYPES, Field, get_msgdef

ENCAPSULATION_HEADER = b'\x00\x01\x00\x00'
_MISSING = object()
_PACKERS = {t: struct.Struct('<' + fmt) for t, (fmt, _) in PRIMITIVES.items()}
_NUMPY_FLOATS = {'float32': '<f4', 'float64': '<f8'}


def _get(msg, name: str):
    """Return field ``name`` of a dict or attribute object, or ``_MISSING``.

    Args:
        msg: a dict, an object with attributes, or None (all fields missing).
        name: the field name.
    """
    if msg is None:
        return _MISSING
    if isinstance(msg, dict):
        return msg.get(name, _MISSING)
    return getattr(msg, name, _MISSING)


def _zero(type_: str):
    """Return the zero value of an element type (a nested type's zero is an empty message).

    Args:
        type_: primitive name, string type, or nested type name.
    """
    if type_ in STRING_TYPES:
        return ''
    if type_ == 'bool':
        return False
    if type_ in ('float32', 'float64'):
        return 0.0
    if type_ in PRIMITIVES:
        return 0
    return None


def _default(field: Field):
    """Return the value encoded for a missing field: its declared default, else zero/empty.

    Args:
        field: the field definition.
    """
    if field.default is not None:
        return field.default
    if field.array == 'fixed':
        return [_zero(field.type)] * field.length
    if field.array is not None:
        return ()
    return _zero(field.type)


def _primitive_value(type_: str, value):
    """Convert one primitive value as rclpy/numpy/Python may hold it to what struct expects.

    Args:
        type_: primitive type name.
        value: bool, int, float, numpy scalar, 1-byte ``bytes`` (rclpy ``byte``) or 1-char
            ``str`` (rclpy ``char``).
    """
    if isinstance(value, (bytes, bytearray)):
        if len(value) != 1:
            raise ValueError(f'{type_} value must be one byte, got {value!r}')
        return value[0]
    if isinstance(value, str):
        if len(value) != 1:
            raise ValueError(f'{type_} value must be one character, got {value!r}')
        return ord(value)
    if type_ == 'bool':
        return bool(value)
    if type_ in ('float32', 'float64'):
        return float(value)
    return int(value)


class _Encoder:
    """Append CDR bytes for one message to a bytearray (the header is written by the caller)."""

    __slots__ = ('buf',)

    def __init__(self):
        self.buf = bytearray(ENCAPSULATION_HEADER)

    def align(self, size: int):
        """Pad with zeros so the next byte's offset (after the header) is a multiple of size.

        Args:
            size: alignment in bytes (1, 2, 4 or 8).
        """
        pad = -(len(self.buf) - 4) % size
        if pad:
            self.buf += bytes(pad)

    def string(self, value, bound):
        """Write a length-prefixed NUL-terminated UTF-8 string.

        Args:
            value: str (or bytes, written as is).
            bound: maximum length in characters (bytes) from ``string<=N``, or None.
        """
        data = value if isinstance(value, (bytes, bytearray)) else str(value).encode('utf-8')
        if bound is not None and len(data) > bound:
            raise ValueError(f'string of {len(data)} bytes exceeds bound {bound}')
        self.align(4)
        self.buf += struct.pack('<I', len(data) + 1)
        self.buf += data
        self.buf += b'\x00'

    def primitive_array(self, type_: str, values, count: int):
        """Write ``count`` primitive elements, aligned if there is at least one.

        Args:
            type_: primitive type name.
            values: the elements (list, tuple, array.array, numpy array, or bytes for 8-bit types).
            count: number of elements (already validated).
        """
        if count == 0:
            return
        fmt, size = PRIMITIVES[type_]
        self.align(size)
        if type_ in _NUMPY_FLOATS:
            # Fast path: one conversion and one copy (float64[] dominates our traffic).
            self.buf += np.asarray(values, dtype=_NUMPY_FLOATS[type_]).tobytes()
        elif size == 1 and isinstance(values, (bytes, bytearray)):
            self.buf += values
        else:
            self.buf += struct.pack(f'<{count}{fmt}',
                                    *[_primitive_value(type_, v) for v in values])

    def field(self, field: Field, value):
        """Write one field (scalar, string, nested, or any array of them).

        Args:
            field: the field definition.
            value: the field's value; ``_MISSING`` or None selects the default.
        """
        if value is _MISSING or value is None:
            value = _default(field)
        if field.array is None:
            self.element(field, value)
            return
        count = len(value)
        if field.array == 'fixed':
            if count != field.length:
                raise ValueError(
                    f'field {field.name!r} needs exactly {field.length} elements, got {count}')
        else:
            if field.array == 'bounded' and count > field.length:
                raise ValueError(
                    f'field {field.name!r} allows at most {field.length} elements, got {count}')
            self.align(4)
            self.buf += struct.pack('<I', count)
        if field.is_primitive:
            self.primitive_array(field.type, value, count)
        else:
            for item in value:
                self.element(field, item)

    def element(self, field: Field, value):
        """Write one element of a field's type.

        Args:
            field: the field definition (its element type is used).
            value: the element value.
        """
        type_ = field.type
        if type_ in _PACKERS:
            fmt, size = PRIMITIVES[type_]
            self.align(size)
            self.buf += _PACKERS[type_].pack(_primitive_value(type_, value))
        elif type_ == 'string':
            self.string(value, field.string_bound)
        elif type_ == 'wstring':
            raise NotImplementedError('wstring fields are not supported')
        else:
            self.message(type_, value)

    def message(self, type_name: str, msg):
        """Write all fields of a (nested) message.

        Args:
            type_name: canonical or short type name.
            msg: dict, attribute object, or None for an all-default message.
        """
        fields = get_msgdef(type_name).fields
        if not fields:
            # An empty .msg becomes an IDL struct with `uint8 structure_needs_at_least_one_member`
            # (ROS 2 legacy interface mapping): one zero byte on the wire.
            self.buf += b'\x00'
        for f in fields:
            self.field(f, _get(msg, f.name))


# ------------------------------------------------------------------------------------------
# Fast path for the fixed-layout messages written at every publication (joint_states, /clock,
# effort commands, /tf): the same bytes as the generic encoder (tested), written by straight-line
# code instead of the per-field dispatch, which dominated the recording cost of a headless run.
# Only plain dicts with every field present and values of the expected Python/numpy types take
# it; anything else (missing keys, attribute objects, odd values) goes the generic way.
# ------------------------------------------------------------------------------------------
_U32 = struct.Struct('<I')
_TIME = struct.Struct('<iI')
_INTS = (int, np.integer)
_NAMES_CACHE: dict = {}
_NAMES_CACHE_MAX = 64


def _fast_time(t):
    """``(sec, nanosec)`` of a builtin_interfaces/Time dict, or None if it is not a plain one."""
    if type(t) is not dict or len(t) != 2:
        return None
    sec, nsec = t.get('sec'), t.get('nanosec')
    if isinstance(sec, _INTS) and isinstance(nsec, _INTS):
        return int(sec), int(nsec)
    return None


def _fast_floats(values):
    """Little-endian float64 bytes and count of a 1-D float64 sequence, or None."""
    if isinstance(values, np.ndarray):
        if values.ndim != 1 or values.dtype.kind != 'f':
            return None
        return values.astype('<f8', copy=False).tobytes(), values.shape[0]
    if isinstance(values, (list, tuple)) and all(type(x) is float for x in values):
        return np.asarray(values, dtype='<f8').tobytes(), len(values)
    return None


def _fast_string(buf: bytearray, value: str):
    """Append an aligned CDR string (as :meth:`_Encoder.string`, unbounded)."""
    pad = -(len(buf) - 4) % 4
    if pad:
        buf += bytes(pad)
    data = value.encode('utf-8')
    buf += _U32.pack(len(data) + 1)
    buf += data
    buf += b'\x00'


def _fast_count(buf: bytearray, n: int):
    """Append a sequence's element count (uint32, 4-aligned)."""
    buf += bytes(-(len(buf) - 4) % 4)
    buf += _U32.pack(n)


def _fast_float_seq(buf: bytearray, packed):
    """Append a float64 sequence: aligned count, then (if any) 8-aligned elements."""
    data, count = packed
    pad = -(len(buf) - 4) % 4
    if pad:
        buf += bytes(pad)
    buf += _U32.pack(count)
    if count:
        pad = -(len(buf) - 4) % 8
        if pad:
            buf += bytes(pad)
        buf += data


def _fast_joint_state(msg):
    if type(msg) is not dict or len(msg) != 5:
        return None
    header, names = msg.get('header'), msg.get('name')
    if type(header) is not dict or len(header) != 2 or not isinstance(names, (list, tuple)):
        return None
    stamp, frame = _fast_time(header.get('stamp')), header.get('frame_id')
    arrays = [_fast_floats(msg.get(k)) for k in ('position', 'velocity', 'effort')]
    if stamp is None or type(frame) is not str or any(a is None for a in arrays):
        return None
    key = (frame, tuple(names))
    middle = _NAMES_CACHE.get(key)
    if middle is None:  # frame_id and names: the same bytes at every publication
        if not all(type(n) is str for n in names):
            return None
        middle = joint_state_names(frame, key[1])
    return _joint_state_bytes(stamp, middle, arrays)


def joint_state_names(frame: str, names: tuple) -> bytes:
    """The constant middle of a JointState's CDR (frame_id and names), cached: pass it to
    :func:`joint_state_bytes`. frame: ``header.frame_id``; names: tuple of joint names (str)."""
    key = (frame, names)
    middle = _NAMES_CACHE.get(key)
    if middle is None:
        b = bytearray(ENCAPSULATION_HEADER + bytes(8))
        _fast_string(b, frame)
        b += bytes(-(len(b) - 4) % 4)
        b += _U32.pack(len(names))
        for n in names:
            _fast_string(b, n)
        if len(_NAMES_CACHE) >= _NAMES_CACHE_MAX:
            _NAMES_CACHE.clear()
        middle = _NAMES_CACHE[key] = bytes(b[12:])
    return middle


def _joint_state_bytes(stamp, middle: bytes, arrays) -> bytes:
    buf = bytearray(ENCAPSULATION_HEADER)
    buf += _TIME.pack(*stamp)
    buf += middle
    for a in arrays:
        _fast_float_seq(buf, a)
    return bytes(buf)


def joint_state_bytes(sec: int, nanosec: int, middle: bytes, position, velocity, effort):
    """CDR of a JointState straight from its parts (what :func:`encode` writes for the dict of
    :func:`robodyn_ros.messages.joint_state`), or None when an array is not a 1-D float array.

    sec, nanosec: the stamp; middle: :func:`joint_state_names`; position, velocity, effort:
    1-D float numpy arrays (or lists of Python floats).
    """
    arrays = (_fast_floats(position), _fast_floats(velocity), _fast_floats(effort))
    if arrays[0] is None or arrays[1] is None or arrays[2] is None:
        return None
    return _joint_state_bytes((sec, nanosec), middle, arrays)


def clock_bytes(sec: int, nanosec: int) -> bytes:
    """CDR of a ``rosgraph_msgs/Clock`` (as :func:`encode` writes it)."""
    return ENCAPSULATION_HEADER + _TIME.pack(sec, nanosec)


def _fast_clock(msg):
    if type(msg) is not dict or len(msg) != 1:
        return None
    stamp = _fast_time(msg.get('clock'))
    return None if stamp is None else ENCAPSULATION_HEADER + _TIME.pack(*stamp)


def _fast_float64_multi_array(msg):
    if type(msg) is not dict or len(msg) != 2:
        return None
    layout, data = msg.get('layout'), _fast_floats(msg.get('data'))
    if type(layout) is not dict or len(layout) != 2 or data is None:
        return None
    dims, offset = layout.get('dim'), layout.get('data_offset')
    if not isinstance(dims, (list, tuple)) or not isinstance(offset, _INTS):
        return None
    buf = bytearray(ENCAPSULATION_HEADER)
    buf += _U32.pack(len(dims))
    for d in dims:
        if type(d) is not dict or len(d) != 3 or type(d.get('label')) is not str or \
                not isinstance(d.get('size'), _INTS) or not isinstance(d.get('stride'), _INTS):
            return None
        _fast_string(buf, d['label'])
        buf += bytes(-(len(buf) - 4) % 4)
        buf += _U32.pack(int(d['size']))
        buf += _U32.pack(int(d['stride']))
    buf += bytes(-(len(buf) - 4) % 4)
    buf += _U32.pack(int(offset))
    _fast_float_seq(buf, data)
    return bytes(buf)


_TF_VALUES = struct.Struct('<7d')
_TF_CACHE: dict = {}


def _tf_layout(frames):
    """``(template bytes, stamp offsets, value offsets)`` of a TFMessage with these
    ``(frame_id, child_frame_id)`` pairs: the strings and padding are fixed, so only the stamps
    and the seven float64 of each transform change between publications."""
    buf = bytearray(ENCAPSULATION_HEADER)
    buf += _U32.pack(len(frames))
    stamps, values = [], []
    for frame, child in frames:
        stamps.append(len(buf))       # 4-aligned: after the count or the previous float64s
        buf += bytes(8)
        _fast_string(buf, frame)
        _fast_string(buf, child)
        buf += bytes(-(len(buf) - 4) % 8)
        values.append(len(buf))
        buf += bytes(56)
    return bytes(buf), stamps, values


def _fast_tf_message(msg):
    if type(msg) is not dict or len(msg) != 1:
        return None
    transforms = msg.get('transforms')
    if type(transforms) is not list:
        return None
    frames, stamps, values = [], [], []
    for tr in transforms:
        if type(tr) is not dict or len(tr) != 3:
            return None
        header, child, tf = tr.get('header'), tr.get('child_frame_id'), tr.get('transform')
        if type(header) is not dict or len(header) != 2 or type(child) is not str or \
                type(tf) is not dict or len(tf) != 2:
            return None
        stamp, frame = _fast_time(header.get('stamp')), header.get('frame_id')
        t, r = tf.get('translation'), tf.get('rotation')
        if stamp is None or type(frame) is not str or type(t) is not dict or len(t) != 3 or \
                type(r) is not dict or len(r) != 4:
            return None
        v = (t.get('x'), t.get('y'), t.get('z'), r.get('x'), r.get('y'), r.get('z'), r.get('w'))
        if not all(type(x) is float for x in v):
            return None
        frames.append((frame, child))
        stamps.append(stamp)
        values.append(v)
    return tf_message_bytes(tf_layout(tuple(frames)), stamps, values)


def tf_layout(frames: tuple):
    """The cached layout (:func:`_tf_layout`) of a TFMessage with these ``(frame_id, child)`` pairs."""
    layout = _TF_CACHE.get(frames)
    if layout is None:
        if len(_TF_CACHE) >= _NAMES_CACHE_MAX:
            _TF_CACHE.clear()
        layout = _TF_CACHE[frames] = _tf_layout(frames)
    return layout


def tf_message_bytes(layout, stamps, values) -> bytes:
    """CDR of a TFMessage from its layout (:func:`tf_layout`), one ``(sec, nanosec)`` stamp and
    seven floats ``(tx, ty, tz, qx, qy, qz, qw)`` per transform (what :func:`encode` writes)."""
    template, stamp_at, values_at = layout
    buf = bytearray(template)
    for k in range(len(stamp_at)):
        _TIME.pack_into(buf, stamp_at[k], *stamps[k])
        _TF_VALUES.pack_into(buf, values_at[k], *values[k])
    return bytes(buf)


_F64MA_EMPTY_LAYOUT = ENCAPSULATION_HEADER + _U32.pack(0) + _U32.pack(0)  # no dims, data_offset 0
_D6 = struct.Struct('<6d')
_D7 = struct.Struct('<7d')
_STAMP_AT = 4  # header.stamp is the first field of a stamped message: right after the encapsulation
_TEMPLATES: dict = {}


def _template(type_name: str, msg, n_tail: int):
    """Generic encoding of ``msg`` (zeros in its numbers) and the offset of its trailing n_tail
    float64: the constant bytes of a message whose strings do not change."""
    enc = _Encoder()
    enc.message(type_name, msg)
    data = bytes(enc.buf)
    return data, len(data) - 8 * n_tail


def wrench_stamped_layout(frame: str):
    """``(template, offset)`` of a ``geometry_msgs/WrenchStamped`` with this frame_id: its CDR
    with zero stamp and numbers, and where its six float64 (force x y z, torque x y z) start;
    the stamp is at :data:`STAMP_AT`. Cached."""
    key = ('WrenchStamped', frame)
    t = _TEMPLATES.get(key)
    if t is None:
        if len(_TEMPLATES) >= 4 * _NAMES_CACHE_MAX:
            _TEMPLATES.clear()
        zero = {'x': 0.0, 'y': 0.0, 'z': 0.0}
        t = _TEMPLATES[key] = _template('geometry_msgs/msg/WrenchStamped',
                                        {'header': {'stamp': {'sec': 0, 'nanosec': 0}, 'frame_id': frame},
                                         'wrench': {'force': zero, 'torque': zero}}, 6)
    return t


def odometry_layout(frame: str = 'odom', child: str = 'base_link'):
    """``(template, offset)`` of a ``nav_msgs/Odometry`` (zero covariances): position and
    orientation (x, y, z, w) are the 7 float64 from offset, linear and angular twist the 6 from
    ``offset + 8 * 43``; the stamp is at :data:`STAMP_AT`. Cached."""
    key = ('Odometry', frame, child)
    t = _TEMPLATES.get(key)
    if t is None:
        if len(_TEMPLATES) >= 4 * _NAMES_CACHE_MAX:
            _TEMPLATES.clear()
        zero = {'x': 0.0, 'y': 0.0, 'z': 0.0}
        t = _TEMPLATES[key] = _template('nav_msgs/msg/Odometry', {
            'header': {'stamp': {'sec': 0, 'nanosec': 0}, 'frame_id': frame}, 'child_frame_id': child,
            'pose': {'pose': {'position': zero, 'orientation': dict(zero, w=0.0)}, 'covariance': np.zeros(36)},
            'twist': {'twist': {'linear': zero, 'angular': zero}, 'covariance': np.zeros(36)}}, 85)
    return t


def imu_layout(frame: str):
    """``(template, offset)`` of a ``sensor_msgs/Imu`` with this frame_id: its CDR with zero stamp and numbers,
    and where its 37 float64 start (orientation x y z w, its covariance (9), angular velocity x y z, its
    covariance, linear acceleration x y z, its covariance: contiguous after the header); the stamp is at
    :data:`STAMP_AT`. Cached."""
    key = ('Imu', frame)
    t = _TEMPLATES.get(key)
    if t is None:
        if len(_TEMPLATES) >= 4 * _NAMES_CACHE_MAX:
            _TEMPLATES.clear()
        zero, z9 = {'x': 0.0, 'y': 0.0, 'z': 0.0}, [0.0] * 9
        t = _TEMPLATES[key] = _template('sensor_msgs/msg/Imu',
                                        {'header': {'stamp': {'sec': 0, 'nanosec': 0}, 'frame_id': frame},
                                         'orientation': {**zero, 'w': 0.0}, 'orientation_covariance': z9,
                                         'angular_velocity': zero, 'angular_velocity_covariance': z9,
                                         'linear_acceleration': zero, 'linear_acceleration_covariance': z9}, 37)
    return t


def joint_state_layout(middle: bytes, counts) -> tuple:
    """``(template, offsets)`` of a JointState with the names of ``middle``
    (:func:`joint_state_names`) and position, velocity, effort of ``counts`` elements: the CDR
    :func:`joint_state_bytes` writes with zero stamp and numbers, and where each array's float64
    start (the stamp is at :data:`STAMP_AT`)."""
    buf = bytearray(ENCAPSULATION_HEADER)
    buf += bytes(8)
    buf += middle
    offsets = []
    for n in counts:   # the sequences as _joint_state_bytes appends them
        _fast_float_seq(buf, (bytes(8 * n), n))
        offsets.append(len(buf) - 8 * n)
    return bytes(buf), offsets


def float64_array_layout(n: int) -> tuple:
    """``(template, offset)`` of a Float64MultiArray with an empty layout and n values
    (:func:`float64_array_bytes`): its CDR with zero values, and where they start."""
    data = float64_array_bytes(np.zeros(n))
    return data, len(data) - 8 * n


#: offset of ``header.stamp`` (int32 sec, uint32 nanosec) in a stamped message's CDR
STAMP_AT = _STAMP_AT


def wrench_stamped_bytes(sec: int, nanosec: int, frame: str, w) -> bytes:
    """CDR of ``geometry_msgs/WrenchStamped`` from a spatial force ``w = [torque; force]`` (6,),
    as :func:`encode` writes :func:`robodyn_ros.messages.wrench_stamped` (frame_id ``frame``)."""
    t = wrench_stamped_layout(frame)
    buf = bytearray(t[0])
    _TIME.pack_into(buf, _STAMP_AT, sec, nanosec)
    _D6.pack_into(buf, t[1], float(w[3]), float(w[4]), float(w[5]), float(w[0]), float(w[1]), float(w[2]))
    return bytes(buf)


def odometry_bytes(sec: int, nanosec: int, odom: dict, frame: str = 'odom', child: str = 'base_link') -> bytes:
    """CDR of ``nav_msgs/Odometry`` as :func:`encode` writes :func:`robodyn_ros.messages.odometry`
    (zero covariances): position, orientation (x, y, z, w), linear and angular twist of ``odom``."""
    t = odometry_layout(frame, child)
    buf = bytearray(t[0])
    _TIME.pack_into(buf, _STAMP_AT, sec, nanosec)
    p, q, lin, ang = odom['position'], odom['orientation'], odom['linear'], odom['angular']
    _D7.pack_into(buf, t[1], float(p[0]), float(p[1]), float(p[2]), float(q[0]), float(q[1]), float(q[2]),
                  float(q[3]))
    _D6.pack_into(buf, t[1] + 8 * 43, float(lin[0]), float(lin[1]), float(lin[2]), float(ang[0]), float(ang[1]),
                  float(ang[2]))
    return bytes(buf)


def float64_array_bytes(values):
    """CDR of a ``std_msgs/Float64MultiArray`` with an empty layout (no dims, offset 0), as
    :func:`encode` writes :func:`robodyn_ros.messages.float64_array` without a label; None when
    values is not a 1-D float array."""
    packed = _fast_floats(values)
    if packed is None:
        return None
    buf = bytearray(_F64MA_EMPTY_LAYOUT)
    _fast_float_seq(buf, packed)
    return bytes(buf)


def _fast_string_message(msg):
    """``std_msgs/String`` of a dict ``{'data': str}`` in one join (a robot_description with its meshes
    embedded is tens of MB: the generic encoder copies it three times); None for anything else."""
    if type(msg) is not dict or msg.keys() != {'data'} or type(msg['data']) is not str:
        return None
    return string_message_bytes((msg['data'].encode('utf-8'),))


def string_message_bytes(parts) -> bytes:
    """``std_msgs/String`` CDR of the text whose UTF-8 bytes are the pieces ``parts`` (bytes-like) one after the
    other, in one join (the recorder's robot_description: :func:`robodyn_ros.assets.embed_meshes_parts`)."""
    n = sum(len(p) for p in parts)
    return b''.join((ENCAPSULATION_HEADER, _U32.pack(n + 1), *parts, b'\x00'))


def _fast_diagnostic_array(msg):
    """DiagnosticArray of plain dicts (header, statuses with 1-byte level, strings, key/value
    strings), as :meth:`_Encoder.message` writes it; None for anything else."""
    if type(msg) is not dict or len(msg) != 2:
        return None
    header, status = msg.get('header'), msg.get('status')
    if type(header) is not dict or len(header) != 2 or type(status) is not list:
        return None
    stamp, frame = _fast_time(header.get('stamp')), header.get('frame_id')
    if stamp is None or type(frame) is not str:
        return None
    statuses = []
    for st in status:
        if type(st) is not dict or len(st) != 5:
            return None
        level, values = st.get('level'), st.get('values')
        strings = (st.get('name'), st.get('message'), st.get('hardware_id'))
        if type(level) is not bytes or len(level) != 1 or type(values) is not list or \
                not all(type(x) is str for x in strings):
            return None
        pairs = []
        for kv in values:
            if type(kv) is not dict or len(kv) != 2:
                return None
            k, v = kv.get('key'), kv.get('value')
            if type(k) is not str or type(v) is not str:
                return None
            pairs.append((k, v))
        statuses.append((level[0], *strings, pairs))
    return diagnostic_array_bytes(*stamp, frame, statuses)


_PADS = (b'', b'\x00', b'\x00\x00', b'\x00\x00\x00')
_KEY_BYTES: dict = {}   # (key string, position mod 4) -> its padding, CDR string and the padding after it
_LENGTHS = tuple(_U32.pack(n) for n in range(64))   # the CDR length of short strings, packed once
_HEADS: dict = {}       # (frame_id, number of statuses) -> (their CDR after the stamp, position mod 4 after it)


def diagnostic_array_bytes(sec: int, nsec: int, frame_id: str, statuses) -> bytes:
    """``diagnostic_msgs/DiagnosticArray`` as canonical CDR, from plain values: statuses
    ``[(level int, name, message, hardware_id, [(key, value string), ...])]`` (what
    :meth:`_Encoder.message` writes for the message dict; the header after the stamp and the keys,
    which repeat from message to message, are encoded once, each key with its alignment).

    CDR aligns a string's uint32 length to 4 bytes from the encapsulation header's end; only the
    position mod 4 matters, and after a key (aligned) it is 0, after a string of n bytes (n + 1 with
    its NUL) it is ``(n + 1) mod 4``."""
    head = _HEADS.get((frame_id, len(statuses)))
    if head is None:
        data = frame_id.encode('utf-8')
        h = _U32.pack(len(data) + 1) + data + b'\x00'
        pos = 8 + len(h)
        h += _PADS[-pos % 4] + _U32.pack(len(statuses))
        head = _HEADS[(frame_id, len(statuses))] = (h, 0)
    out = bytearray(ENCAPSULATION_HEADER)
    out += _TIME.pack(sec, nsec)
    out += head[0]
    r = head[1]
    keys = _KEY_BYTES
    for level, name, message, hw, pairs in statuses:
        out.append(level)
        r = (r + 1) & 3
        for x in (name, message, hw):
            data = x.encode('utf-8')
            out += _PADS[-r % 4]
            out += _U32.pack(len(data) + 1)
            out += data
            out.append(0)
            r = (len(data) + 1) & 3
        out += _PADS[-r % 4]
        out += _U32.pack(len(pairs))
        r = 0
        for k, v in pairs:
            kb = keys.get((k, r))
            out += kb if kb is not None else _key_bytes(k, r)
            r = _put_value(out, v.encode('utf-8'))
    return bytes(out)


def _key_bytes(k: str, r: int) -> bytes:
    """A diagnostics key at position r (mod 4): its padding, CDR string and the padding up to its value's
    length (cached in ``_KEY_BYTES``)."""
    data = k.encode('utf-8')
    kb = _PADS[-r % 4] + _U32.pack(len(data) + 1) + data + b'\x00'
    kb = _KEY_BYTES[(k, r)] = kb + _PADS[-(r + len(kb)) % 4]
    return kb


def _put_value(out: bytearray, data: bytes) -> int:
    """Append a value string's CDR (length, bytes, NUL; aligned by its key) to out; its end's position mod 4."""
    n = len(data) + 1
    out += _LENGTHS[n] if n < 64 else _U32.pack(n)
    out += data
    out.append(0)
    return n & 3


_DIAG_LAYOUTS: dict = {}   # (frame_id, level, name, message, hardware_id, keys) -> (prefix, key bytes by position)


def diagnostic_values_bytes(sec: int, nsec: int, frame_id: str, level: int, name: str, message: str,
                            hardware_id: str, values: dict, fmt) -> bytes:
    """:func:`diagnostic_array_bytes` of one status whose pairs are ``(key, fmt(value))`` of ``values``
    (a dict, in its order): the same bytes, the status's fields up to its values and each key with its
    padding at each position mod 4 laid out once per set of keys (the recorder's diagnostics, 10 per
    simulated second)."""
    keys = tuple(values)
    lay = _DIAG_LAYOUTS.get((frame_id, level, name, message, hardware_id, keys))
    if lay is None:
        empty = diagnostic_array_bytes(0, 0, frame_id, [(level, name, message, hardware_id, [])])
        kbs = tuple(tuple(_key_bytes(k, r) for r in range(4)) for k in keys)
        lay = (empty[12:-4] + _U32.pack(len(keys)), kbs)
        if len(_DIAG_LAYOUTS) < 256:
            _DIAG_LAYOUTS[(frame_id, level, name, message, hardware_id, keys)] = lay
    out = bytearray(ENCAPSULATION_HEADER)
    out += _TIME.pack(sec, nsec)
    out += lay[0]
    r = 0
    for kb, v in zip(lay[1], values.values()):
        out += kb[r]
        r = _put_value(out, fmt(v).encode('utf-8'))
    return bytes(out)


#: canonical type name -> fast encoder returning bytes, or None to decline
_FAST_ENCODERS = {
    'sensor_msgs/msg/JointState': _fast_joint_state,
    'rosgraph_msgs/msg/Clock': _fast_clock,
    'std_msgs/msg/Float64MultiArray': _fast_float64_multi_array,
    'tf2_msgs/msg/TFMessage': _fast_tf_message,
    'diagnostic_msgs/msg/DiagnosticArray': _fast_diagnostic_array,
    'std_msgs/msg/String': _fast_string_message,
}


def encode(type_name: str, msg) -> bytes:
    """Serialize a message to canonical CDR bytes (with the 4-byte encapsulation header).

    Args:
        type_name: ``pkg/msg/Type`` or ``pkg/Type``, e.g. ``sensor_msgs/msg/JointState``.
        msg: a dict (nested dicts/lists/numpy arrays; missing keys take defaults) or any object
            with attributes named like the fields (e.g. an rclpy message instance).

    Raises:
        ValueError: a fixed array has the wrong length, a bounded one is too long, or a value
            does not fit its type. struct.error: an integer is out of range for its type.
    """
    fast = _FAST_ENCODERS.get(type_name)
    if fast is not None:
        data = fast(msg)
        if data is not None:
            return data
    enc = _Encoder()
    enc.message(type_name, msg)
    return bytes(enc.buf)


class _Decoder:
    """Read CDR bytes back into plain dicts (the inverse of :class:`_Encoder`)."""

    __slots__ = ('data', 'pos')

    def __init__(self, data: bytes):
        if bytes(data[:2]) != ENCAPSULATION_HEADER[:2]:
            raise ValueError(f'not little-endian plain CDR: header {bytes(data[:4]).hex()}')
        self.data = memoryview(data)
        self.pos = 4

    def align(self, size: int):
        """Skip padding up to the next multiple of size (counted after the header).

        Args:
            size: alignment in bytes.
        """
        self.pos += -(self.pos - 4) % size

    def take(self, n: int) -> memoryview:
        """Return the next n bytes and advance.

        Args:
            n: byte count.
        """
        if self.pos + n > len(self.data):
            raise ValueError(
                f'CDR data too short: need {self.pos + n} bytes, have {len(self.data)}')
        out = self.data[self.pos:self.pos + n]
        self.pos += n
        return out

    def count(self) -> int:
        """Read a uint32 sequence length or string length."""
        self.align(4)
        return struct.unpack('<I', self.take(4))[0]

    def field(self, field: Field):
        """Read one field.

        Args:
            field: the field definition.
        """
        if field.array is None:
            return self.element(field)
        n = field.length if field.array == 'fixed' else self.count()
        if field.is_primitive:
            if n == 0:
                return np.zeros(0) if field.type in _NUMPY_FLOATS else []
            fmt, size = PRIMITIVES[field.type]
            self.align(size)
            raw = self.take(n * size)
            if field.type in _NUMPY_FLOATS:
                return np.frombuffer(raw, dtype=_NUMPY_FLOATS[field.type]).copy()
            return list(struct.unpack(f'<{n}{fmt}', raw))
        return [self.element(field) for _ in range(n)]

    def element(self, field: Field):
        """Read one element of a field's type.

        Args:
            field: the field definition.
        """
        type_ = field.type
        if type_ in _PACKERS:
            size = PRIMITIVES[type_][1]
            self.align(size)
            return _PACKERS[type_].unpack(self.take(size))[0]
        if type_ == 'string':
            n = self.count()
            return bytes(self.take(n)[:max(n - 1, 0)]).decode('utf-8')
        if type_ == 'wstring':
            raise NotImplementedError('wstring fields are not supported')
        return self.message(type_)

    def message(self, type_name: str) -> dict:
        """Read all fields of a (nested) message into a dict.

        Args:
            type_name: canonical or short type name.
        """
        fields = get_msgdef(type_name).fields
        if not fields:
            self.take(1)  # structure_needs_at_least_one_member
        return {f.name: self.field(f) for f in fields}


def decode(type_name: str, data: bytes) -> dict:
    """Deserialize canonical little-endian CDR bytes into nested dicts (float arrays as numpy).

    Args:
        type_name: ``pkg/msg/Type`` or ``pkg/Type``.
        data: CDR bytes including the encapsulation header.

    Raises:
        ValueError: wrong header, data too short, or bytes left over after the last field beyond
            the at most 3 bytes of trailing padding other serializers may add.
    """
    dec = _Decoder(data)
    out = dec.message(type_name)
    if len(dec.data) - dec.pos > 3:
        raise ValueError(f'{len(dec.data) - dec.pos} bytes left after decoding {type_name}')
    return out
