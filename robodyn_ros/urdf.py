"""URDF import: a robot description (file or text) -> LinkSpecs for :func:`robodyn_ros.model.build_model`.

Parsing is done by `yourdfpy <https://github.com/clemense/yourdfpy>`_ (a maintained URDF parser
from PyPI, pinned in constraints.txt; meshes are neither loaded nor resolved, so its mesh stack is
never exercised); this module only checks what it read and maps it onto our tree:

* joint types: ``revolute`` and ``continuous`` -> REVOLUTE (continuous has no position limits),
  ``prismatic`` -> PRISMATIC, ``fixed`` -> FIXED (kept as a body, so every URDF link has a TF
  frame; the compiled kernels weld it into its parent, as Pinocchio does), ``floating`` -> FREE,
  allowed only from the root link (a ``world`` link with a floating joint is the same as
  ``floating=True``). ``planar`` (3 DOF in a plane) is refused: the model has no such joint;
  write it as two prismatic joints and a revolute one.
* frames: our body frame of a link is the URDF link frame (the joint frame after its motion), so
  joint origins, axes and ``<visual>`` origins carry over unchanged; ``<inertial>`` with an origin
  rpy is rotated into the link frame (``I_link = R I R^T`` about the centre of mass).
* ``<dynamics damping>`` is the viscous damping ``-d q̇``; ``<dynamics friction>`` is a Coulomb
  friction ``-f tanh(q̇ / COULOMB_VELOCITY)`` regularised as the DC motor's
  (:mod:`robodyn_ros.systems.motor`): a smooth right-hand side, no stick-slip events; below
  ``|q̇| ~ COULOMB_VELOCITY`` it acts as a stiff damper of slope ``f / COULOMB_VELOCITY``.
* ``<limit effort>`` becomes the joint's effort limit (commands are clamped to ±effort and the
  clamps counted, see :mod:`robodyn_ros.simulation`); ``lower``/``upper`` become
  ``LinkSpec.limits`` (reported, exported, checked against the initial state; enforced by the
  joint-limit moments of Huston eq. 20.2.1 only when a scene's ``kind: urdf`` part gives
  ``position_limits``, :func:`robodyn_ros.scene.build_urdf_part`); ``velocity`` (> 0) becomes
  ``LinkSpec.velocity_limit``: not enforced, but publications of a joint velocity above it are
  counted (diagnostics ``velocity_limit_exceeded``, :class:`robodyn_ros.simulation.Simulator`).
* ``<mimic>`` is refused (a coupled DOF the kernels do not have), unless the mimic joint is
  locked (``locked={joint: position}``: the joint becomes FIXED at that position, as
  Pinocchio's ``buildReducedModel`` does).

A URDF that cannot be simulated is refused with :class:`UrdfError` naming the link or joint and the
reason: XML errors, a link with two parents, a loop, several roots, an unknown joint type, a
moving link whose subtree has no mass (a zero-mass or missing ``<inertial>`` leaf), a
non-physical inertia (:func:`robodyn_ros.model.build_model`'s checks). A link welded by fixed
joints whose own inertia is not physical (sensor frames with made-up values) is lumped with its
welded group into the group's moving link first (:func:`_lump_welded`); only that composite must
be physical.
"""
from __future__ import annotations

import io
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .model import COULOMB_VELOCITY, LinkSpec, ModelError, _check_inertia, build_model
from .spatial import R_to_rpy, inertia_parts, mcI, plux, rot_axis

__all__ = ['UrdfError', 'UrdfRobot', 'read_urdf', 'COULOMB_VELOCITY', 'example_robot_data_dir']

_MOVING = {'revolute': 'revolute', 'continuous': 'revolute', 'prismatic': 'prismatic'}


class UrdfError(ValueError):
    """A URDF that cannot be simulated; the message names the link or joint and the reason."""


@dataclass
class UrdfRobot:
    """What :func:`read_urdf` found.

    name: robot name; root: name of the root link (the fixed frame, or the floating base);
    specs: LinkSpecs (one per non-root link; with ``floating`` the root link's spec comes first
    with joint type 'free'); floating: whether the root moves freely; velocity_limits: joint ->
    URDF ``<limit velocity>`` (reported only); text: the URDF text read.
    """

    name: str
    root: str
    specs: list
    floating: bool
    velocity_limits: dict = field(default_factory=dict)
    text: str = ''


def example_robot_data_dir() -> Path | None:
    """Directory of the URDFs shipped by the ``example-robot-data`` wheel (test extras), or None."""
    try:
        from importlib.metadata import PackageNotFoundError, distribution
        d = distribution('example-robot-data')
    except (ImportError, PackageNotFoundError):
        return None
    p = Path(d.locate_file('cmeel.prefix/share/example-robot-data/robots'))
    return p if p.is_dir() else None


def _load(source):
    """``(text, base_dir)`` of a URDF path or text (text starts with '<' after whitespace)."""
    if isinstance(source, (str, os.PathLike)) and not str(source).lstrip().startswith('<'):
        p = Path(source)
        try:
            return p.read_text(encoding='utf-8'), p.resolve().parent
        except (OSError, UnicodeDecodeError) as e:
            raise UrdfError(f'{p}: cannot read the URDF file: {e}') from None
    return str(source), None


def _visuals(elem, base_dir) -> tuple:
    """The ``<visual>`` elements of a link as XML text; relative mesh paths made absolute file:// URIs."""
    out = []
    for v in elem.findall('visual'):
        v = ET.fromstring(ET.tostring(v))
        for mesh in v.iter('mesh'):
            fn = mesh.get('filename', '')
            if base_dir is not None and fn and '://' not in fn:
                mesh.set('filename', 'file://' + str((base_dir / fn).resolve()))
        out.append(ET.tostring(v, encoding='unicode').strip())
    return tuple(out)


def _float(x, what, default=0.0) -> float:
    if x is None:
        return default
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise UrdfError(f'{what}: expected a number, got {x!r}') from None
    if not np.isfinite(v):
        raise UrdfError(f'{what}: expected a finite number, got {x!r}')
    return v


def read_urdf(source, floating: bool = False, locked: dict | None = None) -> UrdfRobot:
    """Read a URDF and check that it can be simulated.

    source: a file path or the URDF text; floating: give the root link a FREE (6-DOF) joint;
    locked: joint name -> position (rad or m) of joints to freeze as FIXED (e.g. gripper fingers,
    or ``<mimic>`` joints). Returns a :class:`UrdfRobot`; raises :class:`UrdfError`.
    """
    import yourdfpy
    text, base_dir = _load(source)
    try:  # strict XML first: yourdfpy's lxml parser silently recovers from broken files
        xml_root = ET.fromstring(text)
    except ET.ParseError as e:
        raise UrdfError(f'URDF is not well-formed XML: {e}') from None
    if xml_root.tag != 'robot':
        raise UrdfError(f"URDF root element must be <robot>, got <{xml_root.tag}>")
    for k, e in enumerate(xml_root.findall('joint')):  # what the parser would trip over without naming it
        jn = e.get('name')
        if not jn or not e.get('type'):
            raise UrdfError(f'<joint> number {k + 1} ({jn!r}): needs a name and a type attribute')
        for end in ('parent', 'child'):
            el = e.find(end)
            if el is None or not el.get('link'):
                raise UrdfError(f'joint {jn!r}: missing <{end} link="..."/>')
    for e in xml_root.findall('link'):
        if not e.get('name'):
            raise UrdfError('<link> without a name attribute')
    try:
        urdf = yourdfpy.URDF.load(io.BytesIO(text.encode('utf-8')), build_scene_graph=False, load_meshes=False,
                                  build_collision_scene_graph=False, load_collision_meshes=False)
    except Exception as e:  # noqa: BLE001 - the parser raises assorted types; report its words
        raise UrdfError(f'URDF parser (yourdfpy): {type(e).__name__}: {e}') from None
    robot = urdf.robot
    locked = dict(locked or {})
    links = {lk.name: lk for lk in robot.links}
    xml_links = {e.get('name'): e for e in xml_root.findall('link')}
    if not links:
        raise UrdfError(f'robot {robot.name!r}: no <link>')
    if len(xml_links) != len(xml_root.findall('link')):
        raise UrdfError(f'robot {robot.name!r}: duplicate link names')
    joints = {}
    parent_of = {}
    for j in robot.joints:
        if j.name in joints:
            raise UrdfError(f'joint {j.name!r}: duplicate joint name')
        joints[j.name] = j
        for end, what in ((j.parent, 'parent'), (j.child, 'child')):
            if end not in links:
                raise UrdfError(f'joint {j.name!r}: {what} link {end!r} is not a <link> of the robot')
        if j.child in parent_of:
            raise UrdfError(f'link {j.child!r}: has two parents (joints {parent_of[j.child].name!r} and {j.name!r}); '
                            'a URDF must be a tree (closed loops are not supported)')
        parent_of[j.child] = j
    for name in locked:
        if name not in joints:
            raise UrdfError(f'locked joint {name!r}: no such joint; joints are {sorted(joints)}')
    roots = [n for n in links if n not in parent_of]
    if len(roots) != 1:
        if not roots:
            raise UrdfError(f'robot {robot.name!r}: every link has a parent, so the joints form a loop')
        raise UrdfError(f'robot {robot.name!r}: {len(roots)} root links {roots}; the links must form one tree')
    root = roots[0]
    for n in links:  # a loop among non-root links leaves them unreachable from the root
        seen, k = [n], n
        while k in parent_of:
            k = parent_of[k].parent
            if k in seen:
                raise UrdfError(f'link {n!r}: the joints form a loop {" <- ".join(seen + [k])}')
            seen.append(k)
    children = {n: [] for n in links}
    for j in robot.joints:
        children[j.parent].append(j.child)
    # a 'world' link with one floating joint to the base: floating base written in the URDF
    free_joint = 'root_joint'  # Pinocchio's name for the free-flyer joint it adds
    if len(children[root]) == 1 and parent_of[children[root][0]].type == 'floating' and \
            _float(getattr(links[root].inertial, 'mass', 0.0), f'link {root!r}: <mass>') == 0.0:
        floating, root = True, children[root][0]
        free_joint = parent_of.pop(root).name
    specs = []
    no_inertial = {n for n, lk in links.items() if lk.inertial is None}
    for name in _depth_first(root, children):
        lk = links[name]
        if name == root:
            if floating:
                specs.append(_spec(lk, None, 'free', free_joint, xml_links, base_dir))
            continue
        j = parent_of[name]
        jt = j.type
        where = f'joint {j.name!r}'
        if jt == 'floating':
            raise UrdfError(f'{where}: a floating joint is only supported from the root link '
                            f'(here it attaches link {name!r} to {j.parent!r})')
        if jt == 'planar':
            raise UrdfError(f'{where}: planar joints are not supported (no 3-DOF planar joint in the model); '
                            'write it as two prismatic joints and one revolute joint')
        if jt not in _MOVING and jt != 'fixed':
            raise UrdfError(f'{where}: unknown joint type {jt!r}; supported: revolute, continuous, prismatic, '
                            'fixed, floating (root only)')
        if j.mimic is not None and j.name not in locked:
            raise UrdfError(f'{where}: <mimic joint="{j.mimic.joint}"> is not supported (a coupled DOF); '
                            f'lock the joint instead (locked: {{{j.name}: 0.0}}) or remove the <mimic>')
        s = _spec(lk, j, 'fixed' if jt == 'fixed' else _MOVING[jt], j.name, xml_links, base_dir)
        if j.name in locked and jt != 'fixed':
            s = _lock(s, j, _float(locked[j.name], f'locked joint {j.name!r}'))
        specs.append(s)
    specs = _lump_welded(specs)
    try:  # the model's own checks (inertia, axes, ...) with the link and joint named
        build_model(specs, root='__urdf_world__' if floating else root, name=robot.name)
    except ModelError as e:
        raise UrdfError(str(e)) from None
    _check_masses(specs, no_inertial)
    vel = {j.name: _float(j.limit.velocity, f'joint {j.name!r}: <limit velocity>')
           for j in robot.joints if j.limit is not None and j.limit.velocity is not None and j.type in _MOVING}
    return UrdfRobot(name=robot.name, root=root, specs=specs, floating=floating, velocity_limits=vel, text=text)


def _physical(s: LinkSpec) -> bool:
    try:
        _check_inertia(s, s.name)
        return True
    except ModelError:
        return False


def _lump_welded(specs):
    """Lump the inertias of links welded together by fixed joints into their moving head link
    when one of them alone is not physical (real URDFs carry sensor frames with made-up
    inertias): the dynamics sees only the welded composite, as in Pinocchio, and that composite
    is what :func:`build_model` then checks. Links welded to a fixed base's root enter no
    dynamics: a non-physical one just loses its inertia. specs: depth-first order (parents first).
    """
    index = {s.name: k for k, s in enumerate(specs)}
    head, X = {}, {}  # head link of each link's welded group (None: welded to the world); head -> link
    for s in specs:
        if s.joint_type != 'fixed':
            head[s.name], X[s.name] = s.name, np.eye(6)
        else:
            head[s.name] = head.get(s.parent)
            R = np.asarray(s.origin_R, dtype=float)
            X[s.name] = plux(R.T, np.asarray(s.origin_xyz, dtype=float)) @ X.get(s.parent, np.eye(6))
    bad = {head[s.name] for s in specs if not _physical(s)}
    out = list(specs)
    for h in bad:
        members = [s for s in specs if head[s.name] == h]
        if h is not None and len(members) < 2:
            continue  # a lone body: build_model refuses it with its own words
        zero = dict(mass=0.0, com=(0.0, 0.0, 0.0), inertia=np.zeros((3, 3)))
        for s in members:
            if h is not None or not _physical(s):
                out[index[s.name]] = replace(out[index[s.name]], **zero)
        if h is None:
            continue
        I = sum(X[s.name].T @ mcI(float(s.mass), np.asarray(s.com, dtype=float), np.asarray(s.inertia, dtype=float))
                @ X[s.name] for s in members)
        m, c, Ic = inertia_parts(I)
        out[index[h]] = replace(out[index[h]], mass=float(m), com=tuple(c), inertia=0.5 * (Ic + Ic.T))
    return out


def _depth_first(root, children):
    out, stack = [], [root]
    while stack:
        n = stack.pop()
        out.append(n)
        stack.extend(reversed(children[n]))
    return out


def _spec(lk, j, jtype, jname, xml_links, base_dir) -> LinkSpec:
    """LinkSpec of URDF link ``lk`` hanging from joint ``j`` (None for the root)."""
    where = f'link {lk.name!r}'
    mass, com, Ic = 0.0, np.zeros(3), np.zeros((3, 3))
    if lk.inertial is not None:
        mass = _float(lk.inertial.mass, f'{where}: <mass>')
        T = lk.inertial.origin if lk.inertial.origin is not None else np.eye(4)
        Ic0 = np.asarray(lk.inertial.inertia if lk.inertial.inertia is not None else np.zeros((3, 3)), dtype=float)
        if not np.all(np.isfinite(Ic0)) or not np.all(np.isfinite(T)):
            raise UrdfError(f'{where}: <inertial> has non-finite values')
        R = np.asarray(T[:3, :3], dtype=float)
        com, Ic = np.asarray(T[:3, 3], dtype=float), R @ Ic0 @ R.T
        Ic = 0.5 * (Ic + Ic.T)
    kw = dict(name=lk.name, joint=jname, parent=None, joint_type=jtype, mass=mass, com=tuple(com), inertia=Ic,
              visuals=_visuals(xml_links[lk.name], base_dir))
    if j is not None:
        jw = f'joint {j.name!r}'
        T = np.asarray(j.origin, dtype=float) if j.origin is not None else np.eye(4)
        kw.update(parent=j.parent, origin_xyz=tuple(T[:3, 3]), origin_R=T[:3, :3].copy(),
                  origin_rpy=tuple(R_to_rpy(T[:3, :3])))
        if jtype != 'fixed':
            kw['axis'] = tuple(np.asarray(j.axis if j.axis is not None else (1.0, 0.0, 0.0), dtype=float))
            if j.dynamics is not None:
                kw['damping'] = _float(j.dynamics.damping, f'{jw}: <dynamics damping>')
                kw['friction'] = _float(j.dynamics.friction, f'{jw}: <dynamics friction>')
                for k in ('damping', 'friction'):
                    if kw[k] < 0.0:
                        raise UrdfError(f'{jw}: <dynamics {k}> must be >= 0, got {kw[k]!r}')
            lim = j.limit
            if lim is not None:
                if lim.effort is not None:
                    eff = _float(lim.effort, f'{jw}: <limit effort>')
                    if eff <= 0.0:
                        raise UrdfError(f'{jw}: <limit effort> must be > 0, got {eff!r} '
                                        '(a joint that can exert no effort: make it passive instead)')
                    kw['effort_limit'] = eff
                if lim.velocity is not None:  # reported only; <= 0 (written by some exporters) = none
                    vel = _float(lim.velocity, f'{jw}: <limit velocity>')
                    if vel > 0.0:
                        kw['velocity_limit'] = vel
                if j.type != 'continuous' and (lim.lower is not None or lim.upper is not None):
                    lo = _float(lim.lower, f'{jw}: <limit lower>')
                    hi = _float(lim.upper, f'{jw}: <limit upper>')
                    if lo < hi:  # URDF: lower == upper means "no limits given" for some exporters
                        kw['limits'] = (lo, hi)
                    elif lo > hi:
                        raise UrdfError(f'{jw}: <limit lower="{lo}"> is above upper="{hi}"')
    return LinkSpec(**kw)


def _lock(s: LinkSpec, j, q: float) -> LinkSpec:
    """The joint frozen as FIXED at position q: its motion folded into the origin."""
    if s.limits is not None and not s.limits[0] <= q <= s.limits[1]:
        raise UrdfError(f'locked joint {j.name!r}: position {q!r} is outside its limits {list(s.limits)}')
    R0 = np.asarray(s.origin_R, dtype=float)
    a = np.asarray(s.axis, dtype=float)
    a = a / np.linalg.norm(a)
    if s.joint_type == 'revolute':
        R, p = R0 @ rot_axis(a, q), np.asarray(s.origin_xyz)
    else:
        R, p = R0, np.asarray(s.origin_xyz) + R0 @ (a * q)
    return replace(s, joint_type='fixed', origin_R=R, origin_xyz=tuple(p), origin_rpy=tuple(R_to_rpy(R)),
                   damping=0.0, friction=0.0, effort_limit=None, limits=None, velocity_limit=None)


def _check_masses(specs, no_inertial):
    """Refuse a moving joint whose subtree (the link and everything below it) has no mass."""
    sub = {s.name: s.mass for s in specs}
    by_parent = {}
    for s in specs:
        by_parent.setdefault(s.parent, []).append(s)
    for s in reversed(specs):  # depth-first order: children after their parent
        for c in by_parent.get(s.name, []):
            sub[s.name] += sub[c.name]
    for s in specs:
        if s.joint_type == 'fixed' or sub[s.name] > 0.0:
            continue
        leaf = not by_parent.get(s.name)
        if s.name in no_inertial:
            raise UrdfError(f'link {s.name!r} (joint {s.joint!r}): missing <inertial> on a moving link'
                            f'{" at a leaf" if leaf else " whose subtree has no mass either"}; its joint would have '
                            'no inertia to accelerate (give it an <inertial> or make the joint fixed)')
        raise UrdfError(f'link {s.name!r} (joint {s.joint!r}): zero-mass moving link'
                        f'{" at a leaf" if leaf else " whose subtree has no mass either"}; its joint would have '
                        'no inertia to accelerate (give it a mass or make the joint fixed)')
