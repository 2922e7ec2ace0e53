"""URDF text -> plain values: the document read leniently, each element parsed with the link or joint it
belongs to named in every failure (the first half of :func:`robodyn_ros.urdf.read_urdf`, which turns
these values into checked LinkSpecs).

What is lenient here (a BOM and blank lines before ``<?xml``, bytes after ``</robot>``, elements the
format does not define, collision shapes that cannot be read, numbers with one trailing dot) and what
is refused (XML that is not well-formed, a missing or non-finite number, two ``<inertial>`` in one
link, ...) is listed in :mod:`robodyn_ros.urdf`'s docstring.
"""
from __future__ import annotations

import contextvars
import os
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .model import Collision
from .spatial import rpy_to_R

__all__ = ['UrdfError', 'UrdfWarning', 'UrdfText']

#: a number with one trailing dot (``-1.57.``): C's strtod reads the number and stops at the dot
_TRAILING_DOT = re.compile(r'[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?\.')
#: the numbers read so in the document being read: ``[(where, '<tag attr="text">')]`` (one note for all)
_TRAILING_READ: contextvars.ContextVar = contextvars.ContextVar('urdf_trailing_dot')
#: the URDF format's elements (children of robot, link, joint, inertial); others are noted and ignored
_KNOWN = {'robot': {'link', 'joint', 'material', 'transmission', 'gazebo'},
          'link': {'inertial', 'visual', 'collision'},
          'joint': {'origin', 'parent', 'child', 'axis', 'calibration', 'dynamics', 'limit', 'mimic',
                    'safety_controller'},
          'inertial': {'origin', 'mass', 'inertia'}}
_XACRO = '{http://www.ros.org/wiki/xacro}'


class UrdfError(ValueError):
    """A URDF that cannot be simulated: one line ``<file>: <where>: <reason>``.

    where: the link or joint (``joint 'elbow'``, ``link 'b' (joint 'j1')``), or ``line L, column
    C`` of an XML error; file: the file read, or None for URDF text given without a name (the
    message is then ``<where>: <reason>``). Attributes ``file``, ``where``, ``reason``.
    """

    def __init__(self, where: str, reason: str, file: str | None = None):
        self.where, self.reason, self.file = where, ' '.join(str(reason).split()), file
        super().__init__(': '.join(x for x in (file, where, self.reason) if x))


class UrdfWarning(UserWarning):
    """Something in a URDF that was read leniently (ignored, or adapted); the message names it."""


# ------------------------------------------------------------------------------------------------
# the document: bytes or text -> the <robot> element
# ------------------------------------------------------------------------------------------------
class UrdfText(str):
    """A str that is URDF text, never a file path (:func:`read_urdf` guesses for a plain str)."""


def _load(source, file):
    """``(data, base_dir, file label)`` of a URDF path, its bytes, or text (a :class:`UrdfText`, or
    a str that is blank or starts with '<' after a BOM or whitespace); data is bytes for a file (its
    XML declaration names the encoding), else str."""
    if isinstance(source, (bytes, UrdfText)):
        return (source if isinstance(source, bytes) else str(source)), None, file
    if isinstance(source, os.PathLike) or (isinstance(source, str) and source.strip('\ufeff \t\r\n')
                                           and not source.lstrip('\ufeff \t\r\n').startswith('<')):
        p = Path(source)
        try:
            return p.read_bytes(), p.resolve().parent, file or str(source)
        except OSError as e:
            raise UrdfError('(file)', f'cannot read the URDF file: {e.strerror or e}', file or str(source)) from None
    return str(source), None, file


def _strip_head(data):
    """Data without the byte-order mark and blank space in front of the first '<'."""
    if isinstance(data, bytes):
        if data.startswith((b'\xff\xfe', b'\xfe\xff')):  # UTF-16 with its BOM: decode, parse as text
            return _strip_head(data.decode('utf-16', errors='replace'))
        if data.startswith(b'\xef\xbb\xbf'):
            data = data[3:]
        return data.lstrip(b' \t\r\n')
    return data.lstrip('\ufeff \t\r\n')


def _parse_document(data, notes) -> ET.Element:
    """The root element; bytes after its end are ignored with a note. Raises UrdfError with the
    line and column of the first XML error inside the document."""
    data = _strip_head(data)
    if isinstance(data, str):  # text: its declared encoding no longer applies
        data = re.sub(r'^<\?xml[^>]*\?>', '', data, count=1)
    parser = ET.XMLPullParser(events=('start', 'end'))
    try:
        parser.feed(data)
        parser.close()
    except ET.ParseError:
        pass  # the parser queues the error after the events read before it
    depth, root, events = 0, None, parser.read_events()
    try:
        for ev, el in events:
            if ev == 'start':
                root = el if root is None else root
                depth += 1
            else:
                depth -= 1
                if depth == 0:
                    break
    except ET.ParseError as e:
        line, col = e.position
        raise UrdfError(f'line {line}, column {col + 1}', f'not well-formed XML: {str(e).split(":")[0]}') from None
    if root is None or depth != 0:
        raise UrdfError('(document)', 'not well-formed XML: ' + ('no element found' if root is None else
                                                                 f'<{root.tag}> is never closed'))
    if root.tag != 'robot':
        raise UrdfError('(document)', f'the root element must be <robot>, got <{root.tag}>')
    try:
        for _ in events:
            pass
    except ET.ParseError as e:  # something after </robot>: ignored
        line, col = e.position
        notes.append(f'(document): ignored what follows </robot> from line {line}, column {col + 1} '
                     f'({str(e).split(":")[0]})')
    return root


# ------------------------------------------------------------------------------------------------
# elements -> plain values (each failure names the link or joint)
# ------------------------------------------------------------------------------------------------
def _floats(el, attr, n, where, default=None):
    """The attribute as ``n`` finite floats (an array), or ``default`` when absent."""
    s = el.get(attr) if el is not None else None
    if s is None:
        if default is None:
            raise UrdfError(where, f'<{el.tag}> needs the attribute {attr}=')
        return np.array(default, dtype=float)
    parts = s.split()
    try:
        x = np.array([_number(p) for p in parts], dtype=float)
    except ValueError:
        raise UrdfError(where, f'<{el.tag} {attr}="{s[:40]}">: expected {n} number{"s" if n > 1 else ""}') from None
    if any(_strtod_only(p) for p in parts):
        read = _TRAILING_READ.get(None)
        if read is not None:
            read.append((where, f'<{el.tag} {attr}="{s[:40]}">'))
    if len(x) != n:
        raise UrdfError(where, f'<{el.tag} {attr}="{s[:40]}">: expected {n} numbers, got {len(x)}')
    if not np.all(np.isfinite(x)):
        raise UrdfError(where, f'<{el.tag} {attr}="{s[:40]}">: expected finite numbers')
    return x


def _number(text: str) -> float:
    """One number of an attribute: Python's float, or a number with one trailing dot (``-1.57.``) read
    as C's ``strtod`` reads it (the dot ignored; :func:`_read` says so in one note)."""
    try:
        return float(text)
    except ValueError:
        if _TRAILING_DOT.fullmatch(text):
            return float(text[:-1])
        raise


def _strtod_only(text: str) -> bool:
    """Whether ``text`` is a number only for strtod (a trailing dot), not for Python's float."""
    try:
        float(text)
        return False
    except ValueError:
        return True


def _float(el, attr, where, default=None):
    """The attribute as one finite float, or ``default`` (may be None) when absent."""
    if el is None or el.get(attr) is None:
        return default
    return float(_floats(el, attr, 1, where)[0])


def _one(el, tag, where):
    """The child element ``tag`` (None when absent); two of them are refused (which would count?)."""
    found = el.findall(tag)
    if len(found) > 1:
        raise UrdfError(where, f'{len(found)} <{tag}> elements (one expected)')
    return found[0] if found else None


def _origin(el, where) -> np.ndarray:
    """Homogeneous transform (4, 4) of an ``<origin xyz rpy>`` element (identity when absent)."""
    T = np.eye(4)
    if el is not None:
        T[:3, :3] = rpy_to_R(_floats(el, 'rpy', 3, where, (0.0, 0.0, 0.0)))
        T[:3, 3] = _floats(el, 'xyz', 3, where, (0.0, 0.0, 0.0))
    return T


@dataclass
class _Link:
    """A parsed ``<link>``: mass (kg), com (3,) and inertia (3, 3) about the com in link axes
    (None: no ``<inertial>``), its ``<visual>`` elements as XML text, its ``<collision>`` shapes and
    its ``<visual>`` shapes (:class:`robodyn_ros.model.Collision`; the latter only to infer a mass)."""

    name: str
    inertial: tuple | None
    visuals: tuple
    collisions: tuple = ()
    visual_shapes: tuple = ()


@dataclass
class _Joint:
    """A parsed ``<joint>``: origin T (4, 4), axis (3,), limit values (None when absent), dynamics,
    mimic ``(joint, multiplier, offset)`` or None."""

    name: str
    type: str
    parent: str
    child: str
    T: np.ndarray
    axis: np.ndarray
    effort: float | None = None
    velocity: float | None = None
    lower: float | None = None
    upper: float | None = None
    damping: float = 0.0
    friction: float = 0.0
    mimic: tuple | None = None


def _inertial(el, where):
    """``(mass, com (3,), inertia (3, 3) about the com in link axes)`` of an ``<inertial>``."""
    T = _origin(_one(el, 'origin', where), where)
    m_el = _one(el, 'mass', where)
    mass = _float(m_el, 'value', where) if m_el is not None else None
    if mass is None:
        raise UrdfError(where, '<inertial> needs <mass value="..."/>')
    i_el = _one(el, 'inertia', where)
    if i_el is None:
        raise UrdfError(where, '<inertial> needs <inertia ixx=".." iyy=".." izz=".." (ixy ixz iyz)/>')
    d = [_float(i_el, k, where) for k in ('ixx', 'iyy', 'izz')]
    if None in d:
        raise UrdfError(where, '<inertia> needs ixx, iyy and izz')
    ixy, ixz, iyz = (_float(i_el, k, where, 0.0) for k in ('ixy', 'ixz', 'iyz'))
    I0 = np.array([[d[0], ixy, ixz], [ixy, d[1], iyz], [ixz, iyz, d[2]]])
    R = T[:3, :3]
    Ic = R @ I0 @ R.T
    return mass, T[:3, 3].copy(), 0.5 * (Ic + Ic.T)


def _visuals(elem, base_dir, materials, link) -> tuple:
    """The ``<visual>`` elements of a link as XML text, each standing alone: relative mesh paths
    made absolute file:// URIs, a material naming a top-level ``<material>`` given its colour, a
    nameless material given a name (urdfdom, hence robot_state_publisher and RViz, needs one), a
    material that is defined nowhere dropped."""
    out = []
    for k, v in enumerate(elem.findall('visual')):
        v = ET.fromstring(ET.tostring(v))
        for mesh in v.iter('mesh'):
            fn = mesh.get('filename', '')
            if base_dir is not None and fn and '://' not in fn:
                mesh.set('filename', 'file://' + str((base_dir / fn).resolve()))
        for mat in v.findall('material'):
            own = mat.find('color') is not None or mat.find('texture') is not None
            if not own and mat.get('name') in materials:
                mat.extend(ET.fromstring(ET.tostring(c)) for c in materials[mat.get('name')])
            elif not own:
                v.remove(mat)
                continue
            if not mat.get('name'):
                mat.set('name', f'{link}_visual{k}')
        out.append(ET.tostring(v, encoding='unicode').strip())
    return tuple(out)


#: collision geometry -> its size attributes, in Collision.size order
_SHAPES = {'sphere': ('radius',), 'box': ('size',), 'cylinder': ('radius', 'length'), 'capsule': ('radius', 'length'),
           'mesh': ()}


def _collisions(elem, base_dir, where, notes, tag: str = 'collision') -> tuple:
    """The ``<collision>`` shapes of a link (:class:`robodyn_ros.model.Collision`); one that cannot be
    read is left out with a note (collision shapes enter a ground part's contact, and the mass of a link
    without ``<inertial>``). tag: 'visual' reads the ``<visual>`` shapes the same way."""
    out = []
    for k, c in enumerate(elem.findall(tag)):
        what = f'{where} <{tag}> number {k + 1}'
        geom = c.find('geometry')
        shapes = [g for g in (geom if geom is not None else []) if isinstance(g.tag, str)]
        if len(shapes) != 1 or shapes[0].tag not in _SHAPES:
            found = ', '.join(f'<{g.tag}>' for g in shapes) or 'nothing'
            notes.append(f'{what}: left out: its <geometry> holds {found} (one of '
                         f'{", ".join(f"<{t}>" for t in _SHAPES)} expected)')
            continue
        g = shapes[0]
        try:
            T = _origin(_one(c, 'origin', what), what)
            if g.tag == 'box':
                size = tuple(float(x) for x in _floats(g, 'size', 3, what))
            else:
                size = tuple(float(_floats(g, a, 1, what)[0]) for a in _SHAPES[g.tag])
            scale = tuple(float(x) for x in _floats(g, 'scale', 3, what, (1.0, 1.0, 1.0))) if g.tag == 'mesh' \
                else (1.0, 1.0, 1.0)
        except UrdfError as e:
            notes.append(f'{what}: left out: {e.reason}')
            continue
        if any(x <= 0.0 for x in size) or any(x == 0.0 for x in scale):
            notes.append(f'{what}: left out: <{g.tag}> sizes must be positive, got {list(size or scale)}')
            continue
        mesh = ''
        if g.tag == 'mesh':
            mesh = g.get('filename', '')
            if not mesh:
                notes.append(f'{what}: left out: <mesh> without a filename')
                continue
            if base_dir is not None and '://' not in mesh:
                mesh = str((base_dir / mesh).resolve())
        out.append(Collision(kind=g.tag, origin=T, size=size, mesh=mesh, scale=scale))
    return tuple(out)


def _joint(e, where) -> _Joint:
    """A parsed ``<joint>`` (its name, type, parent and child already checked)."""
    lim, dyn, mim = _one(e, 'limit', where), _one(e, 'dynamics', where), _one(e, 'mimic', where)
    j = _Joint(name=e.get('name'), type=e.get('type'), parent=e.find('parent').get('link'),
               child=e.find('child').get('link'), T=_origin(_one(e, 'origin', where), where),
               axis=_floats(_one(e, 'axis', where), 'xyz', 3, where, (1.0, 0.0, 0.0)))
    if lim is not None:
        j.effort, j.velocity = _float(lim, 'effort', where), _float(lim, 'velocity', where)
        j.lower, j.upper = _float(lim, 'lower', where), _float(lim, 'upper', where)
    if dyn is not None:
        j.damping, j.friction = _float(dyn, 'damping', where, 0.0), _float(dyn, 'friction', where, 0.0)
    if mim is not None:
        if not mim.get('joint'):
            raise UrdfError(where, '<mimic> needs joint="..."')
        j.mimic = (mim.get('joint'), _float(mim, 'multiplier', where, 1.0), _float(mim, 'offset', where, 0.0))
    return j


def _parse_robot(root, base_dir, notes, default_name):
    """``(name, links {name: _Link} in file order, joints [_Joint])`` of the ``<robot>`` element."""
    unknown = {}

    def note_unknown(el, level, path):
        for c in el:
            if not isinstance(c.tag, str):
                continue  # comments, processing instructions
            if c.tag.startswith(_XACRO):
                raise UrdfError(f'{path}<xacro:{c.tag[len(_XACRO):]}>',
                                'an unexpanded xacro macro: run xacro on the file first (xacro robot.urdf.xacro > '
                                'robot.urdf)')
            if c.tag not in _KNOWN[level]:
                unknown[f'{path}<{c.tag}>'] = unknown.get(f'{path}<{c.tag}>', 0) + 1
    note_unknown(root, 'robot', '')
    materials = {m.get('name'): list(m) for m in root.findall('material') if m.get('name')}
    links = {}
    for k, e in enumerate(root.findall('link')):
        name = e.get('name')
        if not name:
            raise UrdfError(f'<link> number {k + 1}', 'needs a name attribute')
        where = f'link {name!r}'
        if name in links:
            raise UrdfError(where, 'duplicate link name')
        note_unknown(e, 'link', '<link>/')
        in_el = _one(e, 'inertial', where)
        if in_el is not None:
            note_unknown(in_el, 'inertial', '<inertial>/')
        links[name] = _Link(name, _inertial(in_el, where) if in_el is not None else None,
                            _visuals(e, base_dir, materials, name), _collisions(e, base_dir, where, notes),
                            _collisions(e, base_dir, where, [], 'visual') if in_el is None else ())
    joints = []
    for k, e in enumerate(root.findall('joint')):
        name = e.get('name')
        if not name:
            raise UrdfError(f'<joint> number {k + 1}', 'needs a name attribute')
        where = f'joint {name!r}'
        if not e.get('type'):
            raise UrdfError(where, 'needs a type attribute')
        for end in ('parent', 'child'):
            el = _one(e, end, where)
            if el is None or not el.get('link'):
                raise UrdfError(where, f'missing <{end} link="..."/>')
        note_unknown(e, 'joint', '<joint>/')
        joints.append(_joint(e, where))
    if unknown:
        notes.append('(document): ignored elements that are not URDF: ' +
                     ', '.join(f'{t}' + (f' x{n}' if n > 1 else '') for t, n in unknown.items()))
    return root.get('name') or default_name, links, joints
