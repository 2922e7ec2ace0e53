"""ROS 2 ``.msg`` definitions: locate, parse, and assemble rosbag2 ``ros2msg`` schema text.

A definition is read from ``<share>/<pkg>/msg/<Type>.msg`` where ``<share>`` comes from (in this
order) ``ament_index_python``, the ``AMENT_PREFIX_PATH`` entries, ``sys.prefix`` (the venv,
where the PyPI ROS wheels install their share directories) and, last, the definitions bundled
in this package (:data:`BUNDLED_DIR`). No ROS import is needed.

Type names are accepted as ``pkg/Type`` or ``pkg/msg/Type``; the canonical form used everywhere in
this package (and by rosbag2 for MCAP schema names) is ``pkg/msg/Type``.

The full schema text follows rosbag2's ``LocalMessageDefinitionSource::get_full_text``: the main
definition verbatim, then for each not-yet-seen dependency (sorted by name, depth first) a newline,
80 ``=``, ``MSG: pkg/Type``, and that dependency's own text (with its own dependencies after it).
"""
import functools
import os
import re
import sys
from dataclasses import dataclass
from typing import Optional, Tuple

#: Primitive .msg types -> (struct format character, size in bytes). ``char`` is uint8 and
#: ``byte`` is an octet in the ROS 2 IDL mapping; both are one unsigned byte on the wire.
PRIMITIVES = {
    'bool': ('?', 1),
    'byte': ('B', 1),
    'char': ('B', 1),
    'int8': ('b', 1),
    'uint8': ('B', 1),
    'int16': ('h', 2),
    'uint16': ('H', 2),
    'int32': ('i', 4),
    'uint32': ('I', 4),
    'int64': ('q', 8),
    'uint64': ('Q', 8),
    'float32': ('f', 4),
    'float64': ('d', 8),
}
STRING_TYPES = ('string', 'wstring')

_NAME = r'[A-Za-z][A-Za-z0-9_]*'
# "pkg/Type", "pkg/msg/Type" or "Type", an optional string bound "<=N", an optional array suffix.
_TYPE_RE = re.compile(
    r'^(?P<base>(?:' + _NAME + r'/)?(?:msg/)?' + _NAME + r')'
    r'(?:<=(?P<strbound>\d+))?'
    r'(?P<array>\[(?P<bounded><=)?(?P<size>\d*)\])?$')
_CONSTANT_RE = re.compile(r'^(' + _NAME + r')\s*=')
#: ``<pkg>/msg/<Type>.msg`` (and the ``.json`` type description rosidl generates next to it) for
#: message packages that may be missing where we run: ``tf2_msgs/msg/TFMessage`` (Jazzy's text,
#: and the description and RIHS01 hash rosidl_generator_type_description produces from it).
BUNDLED_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'msg')


@dataclass(frozen=True)
class Field:
    """One field of a message definition.

    Attributes:
        name: field name.
        type: primitive name (``float64``), ``string``/``wstring``, or a canonical nested type
            name ``pkg/msg/Type``.
        array: None for a scalar, else ``'fixed'``, ``'bounded'`` or ``'unbounded'``.
        length: element count of a fixed array, upper bound of a bounded one, else None.
        string_bound: the ``N`` of ``string<=N``, else None.
        default: the default value written in the definition (already parsed), else None.
    """

    name: str
    type: str
    array: Optional[str] = None
    length: Optional[int] = None
    string_bound: Optional[int] = None
    default: object = None

    @property
    def is_primitive(self) -> bool:
        """True for numeric/bool/byte/char types (not strings, not nested messages)."""
        return self.type in PRIMITIVES

    @property
    def is_nested(self) -> bool:
        """True when the element type is another message."""
        return self.type not in PRIMITIVES and self.type not in STRING_TYPES


@dataclass(frozen=True)
class MsgDef:
    """A parsed message definition.

    Attributes:
        name: canonical type name ``pkg/msg/Type``.
        fields: the fields in wire order (constants are not fields).
        constants: ``(type, name, raw value text)`` of each constant, for reference only.
        text: the ``.msg`` file text, verbatim.
        dependencies: ``pkg/Type`` names of the nested types referenced directly (sorted).
    """

    name: str
    fields: Tuple[Field, ...]
    constants: Tuple[Tuple[str, str, str], ...]
    text: str
    dependencies: Tuple[str, ...]


@functools.lru_cache(maxsize=None)
def canonical_name(type_name: str) -> str:
    """Return ``pkg/msg/Type`` for a type written ``pkg/Type`` or ``pkg/msg/Type``.

    Args:
        type_name: the type name as written by a user, a .msg file or a schema record.
    """
    parts = type_name.strip().split('/')
    if len(parts) == 2:
        return f'{parts[0]}/msg/{parts[1]}'
    if len(parts) == 3 and parts[1] == 'msg':
        return type_name.strip()
    raise ValueError(f'not a message type name (want pkg/Type or pkg/msg/Type): {type_name!r}')


def short_name(type_name: str) -> str:
    """Return ``pkg/Type`` (the form rosbag2 puts after ``MSG:``) for any accepted type name.

    Args:
        type_name: ``pkg/Type`` or ``pkg/msg/Type``.
    """
    pkg, _, typ = canonical_name(type_name).split('/')
    return f'{pkg}/{typ}'


def _share_dirs(package: str):
    """Yield candidate ``share/<package>`` directories, most authoritative first.

    Args:
        package: ROS package name, e.g. ``sensor_msgs``.
    """
    try:
        from ament_index_python.packages import get_package_share_directory
        yield get_package_share_directory(package)
    except (ImportError, LookupError, OSError, ValueError):
        # Not installed, AMENT_PREFIX_PATH unset, or package not registered in the index.
        pass
    for prefix in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep):
        if prefix:
            yield os.path.join(prefix, 'share', package)
    yield os.path.join(sys.prefix, 'share', package)
    # last resort: the definitions bundled with this package (tf2_msgs, which has no PyPI wheel)
    yield os.path.join(BUNDLED_DIR, package)


def find_msg_file(type_name: str) -> str:
    """Return the path of the ``.msg`` file defining a type.

    Args:
        type_name: ``pkg/Type`` or ``pkg/msg/Type``.

    Raises:
        FileNotFoundError: no search location holds the file; the message lists where it looked.
    """
    pkg, _, typ = canonical_name(type_name).split('/')
    tried = []
    for share in _share_dirs(pkg):
        path = os.path.join(share, 'msg', typ + '.msg')
        if os.path.isfile(path):
            return path
        tried.append(path)
    raise FileNotFoundError(f'no .msg definition for {type_name}; looked at: {tried}')


def _strip_comment(line: str) -> str:
    """Remove a ``#`` comment that is not inside a quoted string.

    Args:
        line: one line of a .msg file.
    """
    quote = None
    for i, ch in enumerate(line):
        if quote:
            if ch == quote:
                quote = None
        elif ch in '"\'':
            quote = ch
        elif ch == '#':
            return line[:i]
    return line


def _parse_scalar(text: str, type_: str):
    """Parse the default value of a scalar field.

    Args:
        text: the literal as written after the field name.
        type_: the field's element type.
    """
    text = text.strip()
    if type_ in STRING_TYPES:
        if len(text) >= 2 and text[0] == text[-1] and text[0] in '"\'':
            return text[1:-1]
        return text
    if type_ == 'bool':
        if text.lower() in ('true', '1'):
            return True
        if text.lower() in ('false', '0'):
            return False
        raise ValueError(f'bad bool default {text!r}')
    if type_ in ('float32', 'float64'):
        return float(text)
    return int(text, 0)


def _parse_default(text: str, field_type: str, array: Optional[str]):
    """Parse a field default, scalar or ``[a, b, ...]`` array.

    Args:
        text: the literal as written after the field name.
        field_type: the field's element type.
        array: the field's array kind, or None.
    """
    if array is None:
        return _parse_scalar(text, field_type)
    inner = text.strip()
    if not (inner.startswith('[') and inner.endswith(']')):
        raise ValueError(f'array default must be [..], got {text!r}')
    inner = inner[1:-1].strip()
    if not inner:
        return ()
    return tuple(_parse_scalar(item, field_type) for item in inner.split(','))


def parse_msg(type_name: str, text: str) -> MsgDef:
    """Parse ``.msg`` text into a :class:`MsgDef`.

    Args:
        type_name: the type being defined (``pkg/Type`` or ``pkg/msg/Type``); its package resolves
            relative field types such as ``Header`` inside std_msgs.
        text: the definition text.
    """
    name = canonical_name(type_name)
    package = name.split('/')[0]
    fields, constants, deps = [], [], set()
    for lineno, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith('#'):
            continue
        parts = line.split(None, 1)
        if len(parts) != 2:
            raise ValueError(f'{name}:{lineno}: cannot parse {raw!r}')
        type_text, rest = parts
        m = _TYPE_RE.match(type_text)
        if not m:
            raise ValueError(f'{name}:{lineno}: bad type {type_text!r}')
        if _CONSTANT_RE.match(rest):
            const_name, value = rest.split('=', 1)
            constants.append((type_text, const_name.strip(), value.strip()))
            continue
        rest = _strip_comment(rest).strip()
        field_parts = rest.split(None, 1)
        field_name = field_parts[0]
        base = m.group('base')
        if base in PRIMITIVES or base in STRING_TYPES:
            ftype = base
        else:
            ftype = canonical_name(base if '/' in base else f'{package}/{base}')
            deps.add(short_name(ftype))
        if m.group('array') is None:
            array, length = None, None
        elif m.group('bounded'):
            array, length = 'bounded', int(m.group('size'))
        elif m.group('size'):
            array, length = 'fixed', int(m.group('size'))
        else:
            array, length = 'unbounded', None
        default = None
        if len(field_parts) == 2:
            if ftype not in PRIMITIVES and ftype not in STRING_TYPES:
                raise ValueError(f'{name}:{lineno}: nested fields cannot have defaults')
            default = _parse_default(field_parts[1], ftype, array)
        strbound = m.group('strbound')
        fields.append(Field(field_name, ftype, array, length,
                            int(strbound) if strbound else None, default))
    return MsgDef(name, tuple(fields), tuple(constants), text, tuple(sorted(deps)))


@functools.lru_cache(maxsize=None)
def get_msgdef(type_name: str) -> MsgDef:
    """Return the parsed definition of a type, reading and caching its ``.msg`` file.

    Args:
        type_name: ``pkg/Type`` or ``pkg/msg/Type``.
    """
    name = canonical_name(type_name)
    if name != type_name:
        return get_msgdef(name)
    with open(find_msg_file(name), encoding='utf-8', newline='') as f:
        return parse_msg(name, f.read())


@functools.lru_cache(maxsize=None)
def full_text(type_name: str) -> str:
    """Return the ``ros2msg`` schema text of a type with all its dependencies (rosbag2 layout).

    Args:
        type_name: ``pkg/Type`` or ``pkg/msg/Type``.
    """
    seen = set()

    def append(name: str) -> str:
        msgdef = get_msgdef(name)
        out = msgdef.text
        for dep in msgdef.dependencies:
            if dep not in seen:
                seen.add(dep)
                out += '\n' + '=' * 80 + '\nMSG: ' + dep + '\n' + append(dep)
        return out

    return append(canonical_name(type_name))


@functools.lru_cache(maxsize=None)
def type_hash(type_name: str) -> str:
    """Return the RIHS01 type hash rosidl generated for a type, or '' when unavailable.

    rosbag2 (Jazzy) stores it as the ``topic_type_hash`` channel metadata; it is read from the
    ``.json`` type description installed next to the ``.msg`` file.

    Args:
        type_name: ``pkg/Type`` or ``pkg/msg/Type``.
    """
    import json
    name = canonical_name(type_name)
    try:
        path = find_msg_file(name)[:-len('.msg')] + '.json'
        with open(path, encoding='utf-8') as f:
            hashes = json.load(f).get('type_hashes', [])
    except (FileNotFoundError, ValueError):
        return ''
    for entry in hashes:
        if entry.get('type_name') == name:
            return entry.get('hash_string', '')
    return ''
