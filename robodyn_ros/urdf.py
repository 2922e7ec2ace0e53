"""URDF import: a robot description (file or text) -> LinkSpecs for :func:`robodyn_ros.model.build_model`.

Reading. The XML is read here with the standard library's parser (meshes are neither loaded nor
resolved), leniently where the robot is unambiguous and never with a traceback:

* a byte-order mark, blank lines or spaces before ``<?xml`` are skipped; bytes after the root
  element's end (a trailing NUL, an editor's junk) are ignored, with a note;
* elements the URDF format does not define (``<ros2_control>``, ``<mujoco>``, ``<contact>``
  under a link, ...) are ignored, with one note listing them; ``<transmission>``, ``<gazebo>``,
  ``<calibration>`` and ``<safety_controller>`` are URDF, not dynamics, and are ignored silently;
  a top-level ``<material>`` needs no name (its colour is copied into the visuals that use it, so
  the exported description stands alone); a robot without a name takes the file's;
* ``<collision>`` shapes (``sphere``, ``box``, ``cylinder``, ``capsule``, ``mesh``, with their
  origin) are read into ``LinkSpec.collisions`` (:class:`robodyn_ros.model.Collision`) for a scene's
  ground contact; they enter no dynamics, so a shape that cannot be read (no geometry, an unknown
  one, a size that is not a positive number) is left out with a note instead of refusing the robot;
* everything the dynamics reads must be there and be a finite number: a missing mass value or
  diagonal moment, two ``<inertial>`` in one link, ``nan`` in an origin... is refused; a number with
  one trailing dot (``-1.57.``) is read as C's ``strtod`` reads it, with one note;
* a moving rigid body (a link on a moving joint, or the floating root, with the links welded to it)
  none of whose links has an ``<inertial>`` gets the mass properties of its links' ``<collision>``
  (else ``<visual>``) shapes as solids of ``density`` (default 1000 kg/m³, MuJoCo's
  ``inertiafromgeom``; :mod:`robodyn_ros.mass_properties`), with one note naming the links;
* a mass matrix singular at q = 0 gets the smallest stated joint armature that makes it regular on
  the joints of its near-null space (:mod:`robodyn_ros.armature`), with one note; ``armature`` may
  instead be given (0: none).

Notes and warnings are :class:`UrdfWarning` (``warnings.warn``, and :attr:`UrdfRobot.notes`);
``robodyn run`` and the ``sim`` node print each once.

Mapping onto our tree:

* joint types: ``revolute`` and ``continuous`` -> REVOLUTE (continuous has no position limits),
  ``prismatic`` -> PRISMATIC, ``fixed`` -> FIXED (kept as a body, so every URDF link has a TF
  frame; the compiled kernels weld it into its parent, as Pinocchio does), ``floating`` -> FREE,
  allowed only from the root link (a ``world`` link with a floating joint is the same as
  ``floating=True``); ``spherical`` (a URDF extension) -> SPHERICAL, the scene format's ball joint
  (no axis; its damping acts on each rate; limits, friction and mimic are ignored with a note).
  ``planar`` (3 DOF in a plane) is refused: the model has no such joint; write it as two prismatic
  joints and a revolute one.
* frames: our body frame of a link is the URDF link frame (the joint frame after its motion), so
  joint origins, axes and ``<visual>`` origins carry over unchanged; ``<inertial>`` with an origin
  rpy is rotated into the link frame (``I_link = R I R^T`` about the centre of mass).
* ``<dynamics damping>`` is the viscous damping ``-d q̇``; ``<dynamics friction>`` is a Coulomb
  friction ``-f tanh(q̇ / COULOMB_VELOCITY)`` regularised as the DC motor's
  (:mod:`robodyn_ros.systems.motor`): a smooth right-hand side, no stick-slip events; below
  ``|q̇| ~ COULOMB_VELOCITY`` it acts as a stiff damper of slope ``f / COULOMB_VELOCITY``.
* ``<limit effort>`` becomes the joint's effort limit (commands are clamped to ±effort and the
  clamps counted, see :mod:`robodyn_ros.simulation`); ``effort="0"`` means "no limit given" (the
  ROS convention: many vendor exports write it on every joint) and is read so, with one warning
  naming the joints, and so does ``velocity="0"`` (or below); ``lower``/``upper`` become ``LinkSpec.limits`` (reported, exported, checked
  against the initial state; enforced by the joint-limit moments of Huston eq. 20.2.1 only when a
  scene's ``kind: urdf`` part gives ``position_limits``, :func:`robodyn_ros.scene.build_urdf_part`);
  ``lower == upper`` means none given; ``velocity`` (> 0) becomes ``LinkSpec.velocity_limit``: not
  enforced, but publications of a joint velocity above it are counted (diagnostics
  ``velocity_limit_exceeded``, :class:`robodyn_ros.simulation.Simulator`).
* ``<mimic joint multiplier offset>`` (defaults 1 and 0) makes the joint follow another,
  ``q = multiplier · q_joint + offset`` (``LinkSpec.mimic``; chains of mimics compose): the
  dynamics is reduced to the independent joints in the compiled kernels
  (:mod:`robodyn_ros.kernels.coupled`), the joint stays in joint_states and TF and takes no
  effort command (:mod:`robodyn_ros.systems.arm`). A mimic of a joint that does not exist or does
  not move is ignored with a note (urdfdom and Pinocchio read such a joint as independent); a
  cycle of mimics is refused. ``locked={joint: position}`` freezes a joint as FIXED at that
  position (as Pinocchio's ``buildReducedModel`` does); the joints that mimic a locked joint are
  locked with it, at their coupled position.

Inertias (:func:`_settle_inertia`). A link welded by fixed joints whose own inertia is not
physical (sensor frames with made-up values) is lumped with its welded group into the group's
moving link first (:func:`_lump_welded`); only that composite is then judged. Principal moments
``I1 <= I2 <= I3`` of a real body obey the triangle inequality ``I1 + I2 >= I3`` (each moment is a
sum of two of the three second moments of the mass distribution, which are >= 0). CAD exports
often break it by a little. Such an inertia is accepted with a warning naming the link and the
violation:

* positive definite (``I1 > 0``): kept as given. The kinetic energy ``½ vᵀ I v`` is still positive
  for every motion, so the mass matrix is positive definite and the dynamics well posed
  (Pinocchio accepts it too); but no mass distribution has these moments: it is the inertia of a
  body with some negative density, ``Σ = ½ tr(I) 1 − I`` having a negative eigenvalue;
* positive semi-definite with a zero moment (``I1 = 0 < I2 < I3``, not a slender bar): balanced
  the way MuJoCo's compiler option ``balanceinertia`` does: the three principal moments are
  replaced by their mean (the trace, and with it ``Σ m r²``, kept; the principal axes then no
  longer matter), since a singular inertia that is not a bar's can make the mass matrix singular;
* not positive semi-definite (a negative moment), or a negative mass: refused.

A URDF that cannot be simulated is refused with :class:`UrdfError`, one line ``<file>: <where>:
<reason>`` naming the link or joint (or the line and column of an XML error): a link with two
parents, a loop, several roots, an unknown joint type, a moving link whose subtree has no mass
(a zero-mass or missing ``<inertial>`` leaf), a non-physical inertia
(:func:`robodyn_ros.model.build_model`'s checks).
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .mass_properties import DENSITY, combine, shape_properties
from .meshes import example_robot_data_dir
from .model import COULOMB_VELOCITY, LinkSpec, ModelError, _check_inertia, build_model, resolve_mimics
from .spatial import R_to_rpy, inertia_parts, mcI, plux, rot_axis
from .urdf_xml import _TRAILING_READ, UrdfError, UrdfText, UrdfWarning, _Joint, _Link, _load, _parse_document, _parse_robot

__all__ = ['UrdfError', 'UrdfWarning', 'UrdfRobot', 'UrdfText', 'read_urdf', 'COULOMB_VELOCITY', 'example_robot_data_dir']

_MOVING = {'revolute': 'revolute', 'continuous': 'revolute', 'prismatic': 'prismatic', 'spherical': 'spherical'}
_JOINT_TYPES = ('revolute', 'continuous', 'prismatic', 'fixed', 'floating', 'planar', 'spherical')
#: relative tolerance of the inertia checks (of the largest principal moment)
INERTIA_TOL = 1e-9


@dataclass
class UrdfRobot:
    """What :func:`read_urdf` found.

    name: robot name; root: name of the root link (the fixed frame, or the floating base);
    specs: LinkSpecs (one per non-root link; with ``floating`` the root link's spec comes first
    with joint type 'free'); floating: whether the root moves freely; velocity_limits: joint ->
    URDF ``<limit velocity>`` (reported only); text: the URDF text read; notes: the
    :class:`UrdfWarning` messages issued while reading (one line each); root_visuals: the ``<visual>``
    elements (XML text) of a fixed base's root link, which is no body of the model but is drawn (a
    floating root's are its spec's); None, and every spec's ``visuals`` None, when the file has no
    ``<visual>`` at all (:func:`robodyn_ros.model.to_urdf` then draws shapes).
    """

    name: str
    root: str
    specs: list
    floating: bool
    velocity_limits: dict = field(default_factory=dict)
    text: str = ''
    notes: list = field(default_factory=list)
    root_visuals: tuple | None = ()


# ------------------------------------------------------------------------------------------------
# the robot: parsed links and joints -> checked LinkSpecs
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Options:
    """What :func:`read_urdf` was asked beyond the file: density (kg/m³) of the solids inferred for
    moving links without ``<inertial>`` (0: none inferred); armature: 'auto', a number for every
    moving joint, or ``{joint: value}``."""

    density: float = DENSITY
    armature: object = 'auto'


def read_urdf(source, floating: bool = False, locked: dict | None = None, file: str | None = None,
              base_dir=None, density: float = DENSITY, armature='auto') -> UrdfRobot:
    """Read a URDF and check that it can be simulated.

    source: a file path, the file's bytes, or the URDF text; floating: give the root link a FREE
    (6-DOF) joint; locked: joint name -> position (rad or m) of joints to freeze as FIXED (e.g.
    gripper fingers, or ``<mimic>`` joints); file: the name messages give the source (default:
    the path, or none for text); base_dir: where relative mesh paths start for bytes or text (a
    path's own directory otherwise); density: kg/m³ of the solids a moving link without
    ``<inertial>`` is inferred to be (its collision, else visual, shapes; 0: none inferred, the link
    is massless); armature: ``'auto'`` (the smallest :data:`robodyn_ros.armature.LADDER` value on the
    joints of a mass matrix singular at q = 0, with a note; none where M is regular), a number >= 0
    (every moving joint; 0: none) or ``{joint: value}``. Returns a :class:`UrdfRobot`; raises
    :class:`UrdfError` (one line); issues a :class:`UrdfWarning` per note (also in ``UrdfRobot.notes``).
    """
    data, own_dir, label = _load(source, file)
    base_dir = own_dir if base_dir is None else Path(base_dir)
    notes, trailing = [], []
    token = _TRAILING_READ.set(trailing)
    try:
        robot = _read(data, base_dir, label, floating, dict(locked or {}), notes, _Options(float(density), armature))
    except UrdfError as e:
        raise UrdfError(e.where, e.reason, label) from None
    finally:
        _TRAILING_READ.reset(token)
    if trailing:
        seen = list(dict.fromkeys(f'{w} {t}' for w, t in trailing))
        notes.insert(0, f'{len(seen)} number{"s" if len(seen) > 1 else ""} with a trailing dot read as C\'s strtod '
                        f'reads {"them" if len(seen) > 1 else "it"} (the dot ignored): ' + ', '.join(seen[:6]) +
                     (f' and {len(seen) - 6} more' if len(seen) > 6 else ''))
    for n in notes:
        warnings.warn(UrdfWarning(f'{label}: {n}' if label else n), stacklevel=2)
    robot.notes = [f'{label}: {n}' if label else n for n in notes]
    return robot


def _read(data, base_dir, label, floating, locked, notes, opts: _Options) -> UrdfRobot:
    """:func:`read_urdf` without the file name in its errors and notes."""
    xml_root = _parse_document(data, notes)
    default_name = Path(label).stem if label else 'robot'
    name, links, joint_list = _parse_robot(xml_root, base_dir, notes, default_name)
    text = data.decode('utf-8', errors='replace') if isinstance(data, bytes) else data
    if not links:
        raise UrdfError(f'robot {name!r}', 'no <link> element: nothing to simulate')
    joints, parent_of = {}, {}
    for j in joint_list:
        if j.name in joints:
            raise UrdfError(f'joint {j.name!r}', 'duplicate joint name')
        joints[j.name] = j
        for end, what in ((j.parent, 'parent'), (j.child, 'child')):
            if end not in links:
                raise UrdfError(f'joint {j.name!r}', f'{what} link {end!r} is not a <link> of the robot')
        if j.child in parent_of:
            raise UrdfError(f'link {j.child!r}', f'has two parents (joints {parent_of[j.child].name!r} and '
                                                 f'{j.name!r}); a URDF must be a tree (closed loops are not supported)')
        parent_of[j.child] = j
    for jn in locked:
        if jn not in joints:
            raise UrdfError(f'locked joint {jn!r}', f'no such joint; joints are {sorted(joints)}')
    roots = [n for n in links if n not in parent_of]
    if len(roots) != 1:
        if not roots:
            raise UrdfError(f'robot {name!r}', 'every link has a parent, so the joints form a loop')
        shown = roots if len(roots) <= 6 else roots[:6] + ['...']
        raise UrdfError(f'robot {name!r}', f'{len(roots)} root links {shown}; the links must form one tree')
    root = roots[0]
    for n in links:  # a loop among non-root links leaves them unreachable from the root
        seen, k = [n], n
        while k in parent_of:
            k = parent_of[k].parent
            if k in seen:
                raise UrdfError(f'link {n!r}', f'the joints form a loop {" <- ".join(seen + [k])}')
            seen.append(k)
    children = {n: [] for n in links}
    for j in joint_list:
        children[j.parent].append(j.child)
    # a 'world' link with one floating joint to the base: floating base written in the URDF
    free_joint = 'root_joint'  # Pinocchio's name for the free-flyer joint it adds
    if len(children[root]) == 1 and parent_of[children[root][0]].type == 'floating' and \
            (links[root].inertial is None or links[root].inertial[0] == 0.0):
        floating, root = True, children[root][0]
        free_joint = parent_of.pop(root).name
    _infer_inertials(links, _inferable(links, parent_of, root, floating), base_dir, opts.density, notes)
    specs, no_inertial, no_effort, no_velocity = [], {n for n, lk in links.items() if lk.inertial is None}, [], []
    for lname in _depth_first(root, children):
        lk = links[lname]
        if lname == root:
            if floating:
                specs.append(_spec(lk, None, 'free', free_joint, no_effort))
            continue
        j = parent_of[lname]
        where = f'joint {j.name!r}'
        if j.type == 'floating':
            raise UrdfError(where, 'a floating joint is only supported from the root link '
                                   f'(here it attaches link {lname!r} to {j.parent!r})')
        if j.type == 'planar':
            raise UrdfError(where, 'planar joints are not supported (no 3-DOF planar joint in the model); '
                                   'write it as two prismatic joints and one revolute joint')
        if j.type not in _JOINT_TYPES:
            raise UrdfError(where, f'unknown joint type {j.type!r}; supported: revolute, continuous, prismatic, '
                                   'fixed, spherical, floating (root only)')
        if j.type == 'spherical':
            unused = [w for w, given in (('<limit effort>', j.effort), ('<limit velocity>', j.velocity),
                                         ('<limit lower>', j.lower), ('<limit upper>', j.upper),
                                         ('<dynamics friction>', j.friction or None), ('<mimic>', j.mimic))
                      if given is not None]
            if unused:
                notes.append(f'{where}: a spherical joint (3 DOF, no axis): {", ".join(unused)} ignored; its '
                             '<dynamics damping> acts on each of its three rates')
        s = _spec(lk, j, 'fixed' if j.type == 'fixed' else _MOVING[j.type], j.name, no_effort, no_velocity)
        if j.name in locked and j.type != 'fixed':
            s = _lock(s, j.name, locked[j.name])
        elif j.mimic is not None and j.type != 'fixed':
            src = joints.get(j.mimic[0])
            if src is not None and src.type in _MOVING:
                s = replace(s, mimic=j.mimic)
            else:  # urdfdom and Pinocchio read such a joint as an independent one; so do we, with a note
                what = 'is not a joint of the robot' if src is None else f'is a {src.type} joint'
                notes.append(f'joint {j.name!r}: <mimic joint="{j.mimic[0]}"> ignored: {j.mimic[0]!r} {what}; '
                             'the joint moves on its own')
        specs.append(s)
    specs = _lock_followers(specs, locked, notes)
    if no_effort:
        notes.append(f'<limit effort="0"> read as "no effort limit given" (the ROS convention) on '
                     f'{len(no_effort)} joint{"s" if len(no_effort) > 1 else ""}: {", ".join(no_effort)}')
    if no_velocity:
        notes.append(f'<limit velocity="0"> (or below) read as "no velocity limit given", as effort="0" is, on '
                     f'{len(no_velocity)} joint{"s" if len(no_velocity) > 1 else ""}: {", ".join(no_velocity)}')
    for s in specs:  # before lumping: a negative mass is refused wherever it is
        if s.mass < 0.0:
            raise UrdfError(f'link {s.name!r} (joint {s.joint!r})', f'mass must be >= 0, got {s.mass!r}')
    specs = _lump_welded(specs)
    specs = [_settle_inertia(s, notes) for s in specs]
    try:  # the model's own checks (axes, origins, ...) with the link and joint named
        build_model(specs, root='__urdf_world__' if floating else root, name=name)
    except ModelError as e:
        where, _, reason = str(e).partition(': ')
        raise UrdfError(where, reason) if reason else UrdfError(f'robot {name!r}', str(e)) from None
    bare = _massless(specs, no_inertial, resolve_mimics(specs))
    if bare:
        return _lock_massless(data, base_dir, label, floating, locked, notes, specs, bare, opts)
    specs = _with_armature(specs, opts.armature, floating, root, name, notes)
    vel = {s.joint: s.velocity_limit for s in specs if s.velocity_limit is not None}
    if not any(lk.visuals for lk in links.values()):   # a file that draws nothing: shapes are drawn for it
        specs = [replace(s, visuals=None) for s in specs]
        root_visuals = None
    else:
        root_visuals = () if floating else tuple(links[root].visuals)
    return UrdfRobot(name=name, root=root, specs=specs, floating=floating, velocity_limits=vel, text=text,
                     root_visuals=root_visuals)


def _inferable(links: dict, parent_of: dict, root: str, floating: bool) -> list:
    """The links whose mass :func:`_infer_inertials` infers: those of a moving rigid body (a link on a
    moving joint, or the floating root, with the links welded to it by fixed joints) none of whose links
    has an ``<inertial>`` (a body whose mass the file puts on a welded link, as ANYmal's ``base_inertia``
    for its ``base``, keeps the file's mass)."""
    def head(n):
        while n in parent_of and parent_of[n].type == 'fixed':
            n = parent_of[n].parent
        return n
    group = {}
    for n in links:
        group.setdefault(head(n), []).append(n)
    out = []
    for h, members in group.items():
        moving = (h == root and floating) or (h in parent_of and parent_of[h].type in _MOVING)
        if moving and all(links[n].inertial is None for n in members):
            out += members
    return out


def _infer_inertials(links: dict, moving: list, base_dir, density: float, notes) -> None:
    """Give each link of ``moving`` (:func:`_inferable`; links: name -> :class:`_Link`, modified in place)
    the mass properties of its ``<collision>`` shapes (else its ``<visual>`` shapes) as solids of
    ``density`` kg/m³ (:mod:`robodyn_ros.mass_properties`), as MuJoCo's ``inertiafromgeom`` does; one
    note names them. A link with no shape stays massless (:func:`_massless` then judges its joint);
    a mesh that cannot be read is refused, naming the link (its mass would be a guess)."""
    if not density > 0.0:
        return
    done = []
    for n in moving:
        lk = links[n]
        if lk.inertial is not None:
            continue
        shapes, source = (lk.collisions, 'collision') if lk.collisions else (lk.visual_shapes, 'visual')
        if not shapes:
            continue
        parts = []
        for c in shapes:
            verts = None
            if c.kind == 'mesh':
                from .meshes import MeshError, mesh_vertices, resolve_uri
                try:
                    verts = mesh_vertices(resolve_uri(c.mesh, base_dir)) * np.asarray(c.scale, dtype=float)
                except MeshError as e:
                    raise UrdfError(f'link {n!r}', f'has no <inertial>, and its <{source}> mesh cannot be read to '
                                                   f'infer one ({e}); give the link an <inertial>') from None
            try:
                m, com, Ic = shape_properties(c.kind, c.size, density, verts)
            except ValueError as e:
                raise UrdfError(f'link {n!r}', f'has no <inertial>, and its <{source}> {c.kind} gives no volume to '
                                               f'infer one from ({e}); give the link an <inertial>') from None
            parts.append((m, com, Ic, np.asarray(c.origin)[:3, :3], np.asarray(c.origin)[:3, 3]))
        m, com, Ic = combine(parts)
        lk.inertial = (m, com, Ic)
        done.append(f'{n} {_g(m)} kg ({len(parts)} {source} shape{"s" if len(parts) > 1 else ""})')
    if done:
        notes.append(f'{len(done)} moving link{"s" if len(done) > 1 else ""} without <inertial>: mass and inertia '
                     f'inferred from {"their" if len(done) > 1 else "its"} geometry as solids of density '
                     f'{_g(density)} kg/m³ (as MuJoCo\'s inertiafromgeom; meshes by their convex hull): '
                     + ', '.join(done) + '; give the links an <inertial> for their real values')


def _with_armature(specs, armature, floating: bool, root: str, name: str, notes) -> list:
    """The specs with joint armature (:mod:`robodyn_ros.armature`): ``'auto'`` adds the smallest
    :data:`~robodyn_ros.armature.LADDER` value to the joints of a mass matrix singular at q = 0, with a
    note (none where M is regular, or where no value is enough: the preflight then refuses the robot,
    naming the joints); a number goes on every moving joint, a mapping on the joints it names."""
    from . import armature as arm
    takes = [s.joint for s in specs if s.joint_type in ('revolute', 'prismatic', 'spherical')]
    if isinstance(armature, str) and armature == 'auto':
        if not takes:
            return specs
        model = build_model(specs, root='__urdf_world__' if floating else root, name=name)
        found = arm.regularising_armature(model)
        if found is None or found[0] is None:
            return specs
        a, joints, (w0, w1) = found
        js = f'joint{"s" if len(joints) > 1 else ""} {", ".join(joints)}'
        notes.append(f'the mass matrix is singular at q = 0 (eigenvalues {w0:.3g} .. {w1:.3g}: a motion of {js} '
                     f'meets no inertia there): armature {a:g} kg·m² (kg for a prismatic joint) '
                     f'added to {"them" if len(joints) > 1 else "it"}, the smallest of {", ".join(f"{x:g}" for x in arm.LADDER)} '
                     f'that makes M regular (rotor inertia, as real joints have; none in the URDF); give the part '
                     f'armature: to choose it (0: none)')
        given = {j: a for j in joints}
    elif isinstance(armature, dict):
        given = {}
        for j, a in armature.items():
            if j not in takes:
                raise UrdfError(f'armature joint {j!r}', f'not a moving (revolute, prismatic or spherical) joint; '
                                                          f'those are {takes}')
            given[j] = a
    else:
        given = {j: armature for j in takes}
    out = []
    for s in specs:
        a = given.get(s.joint, 0.0)
        try:
            a = float(a)
        except (TypeError, ValueError):
            raise UrdfError(f'armature joint {s.joint!r}', f'expected a number >= 0, got {a!r}') from None
        if not (math.isfinite(a) and a >= 0.0):
            raise UrdfError(f'armature joint {s.joint!r}', f'expected a finite number >= 0, got {a!r}')
        out.append(replace(s, armature=a) if a else s)
    return out


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
            continue  # a lone body: judged by _settle_inertia
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


def _settle_inertia(s: LinkSpec, notes) -> LinkSpec:
    """The spec with an inertia breaking the triangle inequality accepted (positive definite: as
    given) or balanced (singular: MuJoCo's ``balanceinertia``, every principal moment set to their
    mean), with a note naming the link and the violation; other inertias unchanged (a negative
    moment or mass is left to build_model's refusal)."""
    Ic = np.asarray(s.inertia, dtype=float)
    if s.mass < 0.0 or not np.all(np.isfinite(Ic)) or _physical(s):
        return s
    ev = np.linalg.eigvalsh(0.5 * (Ic + Ic.T))
    tol = INERTIA_TOL * max(ev[2], 1e-300)
    if ev[0] < -tol or ev[0] + ev[1] >= ev[2] - tol:
        return s  # not positive semi-definite, or not a triangle defect: build_model says why
    where = f'link {s.name!r} (joint {s.joint!r})'
    what = (f'principal moments {_g(ev[0])}, {_g(ev[1])}, {_g(ev[2])} kg·m² break the triangle inequality '
            f'(I1 + I2 = {_g(ev[0] + ev[1])} < I3; {100 * (ev[2] - ev[0] - ev[1]) / ev[2]:.2g} % of I3)')
    if ev[0] > tol:
        notes.append(f'{where}: {what}: accepted as given (positive definite, so the dynamics is well posed, '
                     'but no mass distribution has these moments)')
        return replace(s, inertia_as_given=True)
    mean = ev.sum() / 3.0
    notes.append(f'{where}: {what} and the smallest is zero: balanced as MuJoCo\'s balanceinertia does '
                 f'(all three moments set to their mean {_g(mean)} kg·m²)')
    return replace(s, inertia=np.eye(3) * mean)


def _g(x) -> str:
    return f'{float(x):.4g}'


def _depth_first(root, children):
    out, stack = [], [root]
    while stack:
        n = stack.pop()
        out.append(n)
        stack.extend(reversed(children[n]))
    return out


def _spec(lk: _Link, j: _Joint | None, jtype, jname, no_effort, no_velocity=None) -> LinkSpec:
    """LinkSpec of link ``lk`` hanging from joint ``j`` (None for the root); joints whose
    ``<limit effort="0">`` (``velocity="0"``) is read as no limit are appended to no_effort
    (no_velocity). A spherical joint keeps its damping only (:func:`_read` notes the rest)."""
    mass, com, Ic = lk.inertial if lk.inertial is not None else (0.0, np.zeros(3), np.zeros((3, 3)))
    kw = dict(name=lk.name, joint=jname, parent=None, joint_type=jtype, mass=mass, com=tuple(com), inertia=Ic,
              visuals=lk.visuals, collisions=lk.collisions)
    if j is None:
        return LinkSpec(**kw)
    jw = f'joint {j.name!r}'
    kw.update(parent=j.parent, origin_xyz=tuple(j.T[:3, 3]), origin_R=j.T[:3, :3].copy(),
              origin_rpy=tuple(R_to_rpy(j.T[:3, :3])))
    if jtype == 'fixed':
        return LinkSpec(**kw)
    if jtype == 'spherical':
        if j.damping < 0.0:
            raise UrdfError(jw, f'<dynamics damping> must be >= 0, got {j.damping!r}')
        return LinkSpec(**kw, damping=j.damping)
    kw.update(axis=tuple(float(x) for x in j.axis), damping=j.damping, friction=j.friction)
    for k in ('damping', 'friction'):
        if kw[k] < 0.0:
            raise UrdfError(jw, f'<dynamics {k}> must be >= 0, got {kw[k]!r}')
    if j.effort is not None:
        if j.effort < 0.0:
            raise UrdfError(jw, f'<limit effort> must be >= 0 (0: no limit given), got {j.effort!r}')
        if j.effort == 0.0:
            no_effort.append(j.name)
        else:
            kw['effort_limit'] = j.effort
    if j.velocity is not None and j.velocity > 0.0:  # reported only
        kw['velocity_limit'] = j.velocity
    elif j.velocity is not None and no_velocity is not None:   # <= 0 (written by some exporters): none given
        no_velocity.append(j.name)
    if j.type != 'continuous' and (j.lower is not None or j.upper is not None):
        lo, hi = j.lower or 0.0, j.upper or 0.0
        if lo < hi:  # URDF: lower == upper means "no limits given" for some exporters
            kw['limits'] = (lo, hi)
        elif lo > hi:
            raise UrdfError(jw, f'<limit lower="{lo}"> is above upper="{hi}"')
    return LinkSpec(**kw)


def _lock_followers(specs, locked, notes):
    """Specs with every joint that mimics a locked joint (directly or through other mimics) locked
    too, at ``multiplier · q_locked + offset``, with a note."""
    at = {k: float(v) for k, v in locked.items()}
    specs, changed = list(specs), True
    while changed:
        changed = False
        for k, s in enumerate(specs):
            if s.mimic is not None and s.mimic[0] in at:
                src, m, o = s.mimic
                at[s.joint] = m * at[src] + o
                specs[k] = _lock(replace(s, mimic=None), s.joint, at[s.joint])
                notes.append(f'joint {s.joint!r}: mimics locked joint {src!r}, so it is locked too, at '
                             f'{at[s.joint]:.6g}')
                changed = True
    return specs


def _lock(s: LinkSpec, name: str, q) -> LinkSpec:
    """The joint frozen as FIXED at position q: its motion folded into the origin."""
    where = f'locked joint {name!r}'
    try:
        q = float(q)
    except (TypeError, ValueError):
        raise UrdfError(where, f'expected a number, got {q!r}') from None
    if not np.isfinite(q):
        raise UrdfError(where, f'expected a finite number, got {q!r}')
    if s.limits is not None and not s.limits[0] <= q <= s.limits[1]:
        raise UrdfError(where, f'position {q!r} is outside its limits {list(s.limits)}')
    R0 = np.asarray(s.origin_R, dtype=float)
    if s.joint_type == 'spherical':   # locked at its identity orientation only (a position is one number)
        if q != 0.0:
            raise UrdfError(where, f'a spherical joint locks at its zero (identity) orientation only, got {q!r}')
        return replace(s, joint_type='fixed', damping=0.0)
    a = np.asarray(s.axis, dtype=float)
    na = np.linalg.norm(a)
    if not na > 1e-9:
        raise UrdfError(f'joint {name!r}', f'axis must be a non-zero 3-vector, got {list(a)}')
    a = a / na
    if s.joint_type == 'revolute':
        R, p = R0 @ rot_axis(a, q), np.asarray(s.origin_xyz)
    else:
        R, p = R0, np.asarray(s.origin_xyz) + R0 @ (a * q)
    return replace(s, joint_type='fixed', origin_R=R, origin_xyz=tuple(p), origin_rpy=tuple(R_to_rpy(R)),
                   damping=0.0, friction=0.0, effort_limit=None, limits=None, velocity_limit=None)


def _massless(specs, no_inertial, mimics) -> list:
    """``[(spec, where, reason)]`` of the moving joints whose subtree (the link and everything below
    it) has no mass, nor the subtree of any joint that mimics them (mimics:
    :func:`robodyn_ros.model.resolve_mimics`; a mimic joint moves with its source, which is the one
    that needs something to accelerate). Such a joint has no dynamics: its row of the mass matrix is
    zero."""
    sub = {s.name: s.mass for s in specs}
    by_parent = {}
    for s in specs:
        by_parent.setdefault(s.parent, []).append(s)
    for s in reversed(specs):  # depth-first order: children after their parent
        for c in by_parent.get(s.name, []):
            sub[s.name] += sub[c.name]
    followers = {}
    for s in specs:
        if s.joint in mimics:
            followers.setdefault(mimics[s.joint][0], []).append(s.name)
    out = []
    for s in specs:
        if s.joint_type in ('fixed', 'free') or s.joint in mimics or sub[s.name] > 0.0 or \
                any(sub[f] > 0.0 for f in followers.get(s.joint, [])):
            continue
        leaf = not by_parent.get(s.name)
        where = f'link {s.name!r} (joint {s.joint!r})'
        rest = f'{" at a leaf" if leaf else " whose subtree has no mass either"}' + \
            (' (nor have those of the joints that mimic it)' if s.joint in followers else '') + \
            '; its joint would have no inertia to accelerate'
        if s.name in no_inertial:
            out.append((s, where, f'missing <inertial> on a moving link, and no <collision> or <visual> geometry to '
                                  f'infer one from{rest} (give it an <inertial> or make the joint fixed)'))
        else:
            out.append((s, where, f'zero-mass moving link{rest} (give it a mass or make the joint fixed)'))
    return out


def _lock_massless(data, base_dir, label, floating, locked, notes, specs, bare, opts) -> UrdfRobot:
    """The robot read again with the massless moving joints of ``bare`` (:func:`_massless`) locked as
    fixed joints at 0 (or the limit nearest 0), and the joints that mimic them with them, with one
    note naming them (vendor URDFs carry such joints: a hand's massless finger links, a sensor on a
    continuous joint). A joint with nothing to accelerate has no dynamics (Pinocchio's ABA divides
    by its zero articulated inertia; MuJoCo refuses a moving body without mass; Gazebo's URDF import
    drops such links). Refused with the first joint's reason when nothing would be left to move."""
    s0, where, reason = bare[0]
    independent = {s.joint for s in specs if s.joint_type not in ('fixed', 'free') and s.mimic is None}
    at = {}
    for s, _, _ in bare:
        lo, hi = s.limits if s.limits is not None else (-math.inf, math.inf)
        at[s.joint] = min(max(0.0, lo), hi)
    if not floating and independent <= set(at):
        raise UrdfError(where, reason)
    fresh = []
    try:
        robot = _read(data, base_dir, label, floating, {**locked, **at}, fresh, opts)
    except UrdfError:
        raise UrdfError(where, reason) from None
    names = ', '.join(f'{j} at {q:.6g}' for j, q in at.items())
    follows = [n for n in fresh if any(f"mimics locked joint '{j}'" in n for j in at)]   # said once, below
    them = 'them' if len(at) > 1 else 'it'
    notes[:] = [n for n in fresh if n not in follows] + [
        f'{len(at)} moving joint{"s" if len(at) > 1 else ""} with no mass below {them} (nor below the joints '
        f'that mimic {them}) locked as fixed: {names}' +
        (f', with the {len(follows)} joints that mimic {them}' if len(follows) > 1 else
         f', with the joint that mimics {them}' if follows else '') +
        f' ({len(at) + len(follows)} joint{"s" if len(at) + len(follows) > 1 else ""} in all)' +
        ' (a joint with nothing to accelerate has no dynamics); give the links an <inertial> to move them']
    return robot
