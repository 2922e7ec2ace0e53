"""The kinematic tree as plain arrays, built from link specs, DH tables or explicit origins.

A :class:`Model` is immutable data (Featherstone's model structure, spatial_v2 style): a parent
array with ``-1`` for the fixed root frame, joint-type codes, joint axes, tree transforms
``Xtree`` and spatial inertias. State ``(q, v)`` lives outside the model.

Frames. Every body ``i`` has one frame, the *joint frame after the joint's motion*: its origin is
on the joint axis. ``Xtree[i]`` transforms from the parent body's frame (or the root frame) to
body ``i``'s frame at ``q_i = 0``; the joint then moves it by ``XJ(q_i)`` (see :func:`jcalc`), so
``Xup[i] = XJ(q_i) @ Xtree[i]``. URDF export uses exactly these frames, so link names, joint
names and frames agree between the simulator, ``joint_states`` and ``robot_description``.

Joint codes: ``FIXED`` (no DOF), ``REVOLUTE`` and ``PRISMATIC`` (1 DOF about/along ``axis`` in
the joint frame), ``FREE`` (a 6-DOF floating joint: ``q = [p (3, parent coords), quat (x, y, z,
w)]``, ``v = body twist [w; v] in body coordinates``), ``SPHERICAL`` (a 3-DOF ball joint
anywhere in the tree: ``q = quat (x, y, z, w)`` of the child frame in the joint frame, ``v =`` the
child's angular velocity relative to the parent, in child coordinates; ``S = [1; 0]``). The
spherical joint is computed by the compiled kernels only (:mod:`robodyn_ros.kernels`); the numpy
reference (:mod:`robodyn_ros.dynamics`) refuses it with :class:`SphericalJointError`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from .spatial import (R_to_rpy, mcI, plux, quat_to_R, rot_axis, rotx, rotz, rpy_to_R, skew)

FIXED, REVOLUTE, PRISMATIC, FREE, SPHERICAL = 0, 1, 2, 3, 4
JOINT_TYPES = {'fixed': FIXED, 'revolute': REVOLUTE, 'prismatic': PRISMATIC, 'free': FREE, 'spherical': SPHERICAL}
JOINT_NAMES = {v: k for k, v in JOINT_TYPES.items()}
_NQ = {FIXED: 0, REVOLUTE: 1, PRISMATIC: 1, FREE: 7, SPHERICAL: 4}
_NV = {FIXED: 0, REVOLUTE: 1, PRISMATIC: 1, FREE: 6, SPHERICAL: 3}
#: suffixes of the three published components of a spherical joint (joint_states, URDF export)
SPHERICAL_AXES = ('_x', '_y', '_z')


#: joint-name suffixes of the three joints of a planar composite, in q order
PLANAR_SUFFIXES = ('_x', '_z', '_pitch')
#: regularisation speed (rad/s or m/s) of Coulomb friction ``-f tanh(q̇ / v_s)``: the DC motor's
#: default (at the motor shaft) and the URDF joints' (``LinkSpec.friction``)
COULOMB_VELOCITY = 0.05


class ModelError(ValueError):
    """A kinematic tree that cannot be built; the message names the link/joint and the reason."""


class SphericalJointError(NotImplementedError):
    """The numpy reference was asked to compute a model with spherical joints (kernels only)."""


def refuse_spherical(model, what: str):
    """Raise :class:`SphericalJointError` when ``model`` has a spherical joint (numpy reference paths)."""
    if model.has_spherical:
        j = [model.joint_names[i] for i in range(model.nb) if model.jtype[i] == SPHERICAL]
        raise SphericalJointError(
            f'{model.name}: {what} of the numpy reference does not implement spherical joints ({j[:3]}...); '
            "they are computed by the compiled kernels only: use backend 'numba' "
            '(robodyn_ros.kernels.CompiledModel)')


@dataclass(frozen=True)
class Collision:
    """One ``<collision>`` shape of a link (URDF), for ground contact (:mod:`robodyn_ros.systems.contact`).

    kind: ``'sphere'``, ``'box'``, ``'cylinder'``, ``'capsule'`` or ``'mesh'``; origin (4, 4): the
    shape's frame in the link frame; size: sphere ``(radius,)``, box ``(x, y, z)`` (full edge
    lengths), cylinder and capsule ``(radius, length)`` along the shape's z axis (a capsule's length
    is that of its cylinder part, between the centres of its end spheres), mesh ``()``; mesh: the
    mesh file as written (a relative path made absolute), scale (3,) its scale.
    """

    kind: str
    origin: np.ndarray
    size: tuple = ()
    mesh: str = ''
    scale: tuple = (1.0, 1.0, 1.0)


@dataclass
class LinkSpec:
    """One body and the joint that connects it to its parent.

    name: link name; joint: joint name; parent: parent link name (``None`` = the fixed root
    frame); joint_type: 'revolute' | 'prismatic' | 'fixed' | 'free'; origin_xyz, origin_rpy:
    joint frame in the parent link frame at q = 0 (URDF convention); axis: (3,) joint axis in
    the joint frame; mass (kg), com (3,) in the link frame, inertia (3, 3) about the com in link
    axes; damping: viscous joint damping (N·m·s/rad or N·s/m); limits: optional (lower, upper)
    (rad or m; a spherical joint: three ``(lower, upper)`` pairs, one per component of its
    rotation vector, ±inf allowed). limit_stiffness k, limit_damping c: the joint-limit moments of
    Huston eq. (20.2.1) (:func:`limit_table`; both 0 = limits reported only); limit_return: the
    moment while the joint moves back toward its range, ``'spring'`` (default: ``-k (θ - θlim)``
    without damping, the law as the issue states it) or ``'none'`` (eq. 20.2.1 as printed: M = 0;
    a joint that stops beyond its range then stays there, and the right-hand side is
    discontinuous in θ̇ at rest, which error-controlled integrators resolve only with tiny steps).
    friction: Coulomb joint friction (N·m or N; regularised, see :mod:`robodyn_ros.urdf`);
    effort_limit: optional largest |effort| (N·m or N) an actuator may apply (commands are
    clamped); velocity_limit: optional largest |q̇| (rad/s or m/s, URDF ``<limit velocity>``),
    reported only: publications above it are counted (:class:`robodyn_ros.simulation.Simulator`,
    diagnostics ``velocity_limit_exceeded``); visuals: URDF ``<visual>`` elements (XML text)
    exported as given (an imported URDF's, none for a link the file draws nothing on), or None:
    :func:`to_urdf` draws shapes (:func:`link_visuals`);
    inertia_as_given: the importer accepted a positive-definite inertia that breaks the triangle
    inequality (and warned, :mod:`robodyn_ros.urdf`): :func:`build_model` then does not refuse it;
    mimic: ``(joint, multiplier, offset)``: this 1-DOF joint follows another 1-DOF joint,
    ``q = multiplier · q_joint + offset`` (URDF ``<mimic>``, :func:`mimic_table`); collisions: the
    link's URDF ``<collision>`` shapes (:class:`Collision`), the geometry a ground part may use;
    armature: the joint's rotor inertia reflected to the joint (kg·m² or kg; a spherical joint: on
    each of its three coordinates), added to the mass matrix's diagonal, ``M + diag(a)`` (MuJoCo's and
    Pinocchio's ``armature``; the compiled kernels and the numpy reference add it to CRBA, ABA's
    ``D``, RNEA's ``τ`` and the kinetic energy).
    """

    name: str
    joint: str
    parent: str | None
    joint_type: str = 'revolute'  # or 'planar' (expanded by planar_links, see the module docstring)
    origin_xyz: Sequence[float] = (0.0, 0.0, 0.0)
    origin_rpy: Sequence[float] = (0.0, 0.0, 0.0)
    axis: Sequence[float] = (0.0, 0.0, 1.0)
    mass: float = 0.0
    com: Sequence[float] = (0.0, 0.0, 0.0)
    inertia: Sequence[Sequence[float]] = field(default_factory=lambda: np.zeros((3, 3)))
    damping: float = 0.0
    limits: tuple | None = None
    origin_R: np.ndarray | None = None  # exact rotation, overrides origin_rpy when given
    friction: float = 0.0
    effort_limit: float | None = None
    visuals: tuple | None = None
    limit_stiffness: float = 0.0
    limit_damping: float = 0.0
    limit_return: str = 'spring'
    velocity_limit: float | None = None
    inertia_as_given: bool = False
    mimic: tuple | None = None
    collisions: tuple = ()
    armature: float = 0.0


@dataclass(frozen=True)
class Model:
    """A kinematic tree in plain arrays (bodies in topological order: parent[i] < i).

    name: robot name; root: name of the fixed root frame; link_names, joint_names: (nb,)
    tuples; parent: (nb,) int, -1 = root; jtype: (nb,) int joint codes; axis: (nb, 3) unit axes
    in joint frames; Xtree: (nb, 6, 6) parent->joint transforms at q = 0; I: (nb, 6, 6) spatial
    inertias in body frames; q_idx, v_idx: (nb,) first index of each joint in q and v; nq_j,
    nv_j: (nb,) sizes; damping: (nv,) viscous damping; gravity: (3,) in the root frame (m/s²);
    q_lower, q_upper: (nq,) joint limits (inf when none); specs: the LinkSpecs it was built from;
    root_visuals: ``<visual>`` elements (XML text) of the root frame's link (an imported fixed base's root
    link), or None: :func:`to_urdf` draws shapes; mounted_visuals: ``((link, visuals), ...)``, the root link's
    visuals of an imported robot mounted on that link (a platform's, a free base's; in its frame), drawn there
    besides the link's own.
    """

    name: str
    root: str
    link_names: tuple
    joint_names: tuple
    parent: np.ndarray
    jtype: np.ndarray
    axis: np.ndarray
    Xtree: np.ndarray
    I: np.ndarray
    q_idx: np.ndarray
    v_idx: np.ndarray
    nq_j: np.ndarray
    nv_j: np.ndarray
    damping: np.ndarray
    gravity: np.ndarray
    specs: tuple
    root_visuals: tuple | None = None
    mounted_visuals: tuple = ()

    @property
    def nb(self) -> int:
        """Number of bodies."""
        return len(self.parent)

    @property
    def nq(self) -> int:
        """Size of the configuration vector q."""
        return int(self.nq_j.sum())

    @property
    def nv(self) -> int:
        """Size of the velocity vector v (= number of degrees of freedom)."""
        return int(self.nv_j.sum())

    @property
    def dof_joint_names(self) -> list:
        """Names of the joints that carry a DOF, in q/v order (1-DOF joints only)."""
        return [self.joint_names[i] for i in range(self.nb) if self.jtype[i] in (REVOLUTE, PRISMATIC)]

    @property
    def armature(self) -> np.ndarray:
        """Joint armature (nv,): each joint's ``LinkSpec.armature`` on every one of its velocity
        coordinates (0 for FREE joints and specs without one)."""
        cached = self.__dict__.get('_armature')
        if cached is None:
            cached = np.zeros(self.nv)
            for i, s in enumerate(self.specs):
                if self.jtype[i] in (REVOLUTE, PRISMATIC, SPHERICAL):
                    cached[self.v_idx[i]:self.v_idx[i] + self.nv_j[i]] = float(getattr(s, 'armature', 0.0))
            cached.setflags(write=False)
            self.__dict__['_armature'] = cached
        return cached

    @property
    def friction(self) -> np.ndarray:
        """Coulomb friction (nv,) of the 1-DOF joints from their specs (0 elsewhere)."""
        out = np.zeros(self.nv)
        for i, s in enumerate(self.specs):
            if self.jtype[i] in (REVOLUTE, PRISMATIC):
                out[self.v_idx[i]] = s.friction
        return out

    def body(self, link_name: str) -> int:
        """Index of the body called ``link_name``."""
        try:
            return self.link_names.index(link_name)
        except ValueError:
            raise ModelError(f'no link named {link_name!r}; links are {list(self.link_names)}') from None

    def neutral(self) -> np.ndarray:
        """The zero configuration (identity quaternions for free joints), shape (nq,)."""
        q = np.zeros(self.nq)
        for i in range(self.nb):
            if self.jtype[i] == FREE:
                q[self.q_idx[i] + 6] = 1.0
            elif self.jtype[i] == SPHERICAL:
                q[self.q_idx[i] + 3] = 1.0
        return q

    def state_index(self, name: str) -> tuple:
        """``(body, v index)`` of a ``joint_states`` entry (:attr:`state_joint_names`); ValueError if unknown."""
        if name in self.joint_names:
            i = self.joint_names.index(name)
            if self.jtype[i] in (REVOLUTE, PRISMATIC):
                return i, int(self.v_idx[i])
        for k, suf in enumerate(SPHERICAL_AXES):
            if name.endswith(suf) and name[:-2] in self.joint_names:
                i = self.joint_names.index(name[:-2])
                if self.jtype[i] == SPHERICAL:
                    return i, int(self.v_idx[i]) + k
        raise ValueError(f'{name!r} is not a joint_states entry of {self.name}; entries are {self.state_joint_names}')

    @property
    def has_mimic(self) -> bool:
        """True when a joint follows another (URDF ``<mimic>``, :func:`mimic_table`)."""
        return any(s.mimic is not None for s in self.specs)

    @property
    def mimic_joint_names(self) -> list:
        """Names of the joints that follow another (they take no effort command), in model order."""
        return [s.joint for s in self.specs if s.mimic is not None]

    @property
    def has_spherical(self) -> bool:
        """True when a joint is SPHERICAL (then only the compiled kernels compute the model)."""
        return bool(np.any(self.jtype == SPHERICAL))

    @property
    def state_joint_names(self) -> list:
        """Names of the ``joint_states`` entries, in v order: a 1-DOF joint's own name, and
        ``<joint>_x``, ``<joint>_y``, ``<joint>_z`` for a spherical joint (its Bryan angles, the
        three revolute joints of the URDF export). A FREE joint is not listed (odom publishes it)."""
        out = []
        for i in range(self.nb):
            if self.jtype[i] in (REVOLUTE, PRISMATIC):
                out.append(self.joint_names[i])
            elif self.jtype[i] == SPHERICAL:
                out += [self.joint_names[i] + a for a in SPHERICAL_AXES]
        return out

    def with_gravity(self, gravity) -> 'Model':
        """A copy of the model with another gravity vector (3,) in the root frame."""
        from dataclasses import replace
        return replace(self, gravity=np.asarray(gravity, dtype=float))

    def total_mass(self) -> float:
        """Sum of link masses (kg)."""
        return float(self.I[:, 5, 5].sum())


def jcalc(jtype, axis, qj):
    """Joint transform and motion subspace (spatial_v2 ``jcalc``).

    jtype: joint code; axis: (3,) unit axis in the joint frame; qj: the joint's slice of q.
    Returns ``(XJ (6, 6), S (6, nv_j))`` with S in body coordinates.
    """
    if jtype == REVOLUTE:
        XJ = plux(rot_axis(axis, qj[0]).T, np.zeros(3))
        S = np.zeros((6, 1))
        S[:3, 0] = axis
        return XJ, S
    if jtype == PRISMATIC:
        XJ = plux(np.eye(3), axis * qj[0])
        S = np.zeros((6, 1))
        S[3:, 0] = axis
        return XJ, S
    if jtype == FREE:
        R = quat_to_R(qj[3:7])
        return plux(R.T, qj[:3]), np.eye(6)
    if jtype == SPHERICAL:
        raise SphericalJointError('jcalc: the spherical joint is computed by the compiled kernels only '
                                  "(robodyn_ros.kernels); use backend 'numba'")
    return np.eye(6), np.zeros((6, 0))


def _check_inertia(spec: LinkSpec, where: str):
    """Refuse negative masses, inertias that are not symmetric positive semi-definite and (unless
    ``spec.inertia_as_given``) principal moments breaking the triangle inequality."""
    if not np.isfinite(spec.mass) or spec.mass < 0.0:
        raise ModelError(f'{where}: mass must be a finite number >= 0, got {spec.mass!r}')
    Ic = np.asarray(spec.inertia, dtype=float)
    if Ic.shape != (3, 3) or not np.all(np.isfinite(Ic)):
        raise ModelError(f'{where}: inertia must be a finite 3x3 matrix, got shape {Ic.shape}')
    if not np.allclose(Ic, Ic.T, atol=1e-12 * max(1.0, np.abs(Ic).max())):
        raise ModelError(f'{where}: inertia must be symmetric, got {Ic.tolist()}')
    ev = np.linalg.eigvalsh(Ic)
    tol = 1e-12 * max(1.0, ev.max())
    # the eigenvalues to six significant digits: LAPACK's last bits differ between CPUs (OpenBLAS picks its
    # kernels per CPU), and a message, like the table of example-robot-data that quotes it, must not
    def shown():
        return '[' + ', '.join(f'{e:.6g}' for e in ev) + ']'
    if ev.min() < -tol:
        raise ModelError(f'{where}: inertia is not positive semi-definite (eigenvalues {shown()})')
    # principal moments must satisfy the triangle inequality of a real body
    if ev.sum() > tol and (ev[0] + ev[1] < ev[2] - 1e-9 * ev.sum()) and not spec.inertia_as_given:
        raise ModelError(f'{where}: principal moments {shown()} violate the triangle inequality '
                         '(no physical body has them)')


#: ``limit_return`` values -> mode codes of :func:`limit_table` (kernels.tree.limit_moment)
LIMIT_RETURNS = {'none': 1, 'spring': 2}


def _check_limits(s: LinkSpec, jt: int, where: str):
    """Refuse limit data that do not fit the joint (shape, order, signs, unknown return mode)."""
    if s.limit_return not in LIMIT_RETURNS:
        raise ModelError(f'{where}: limit_return must be one of {sorted(LIMIT_RETURNS)}, got {s.limit_return!r}')
    for name in ('limit_stiffness', 'limit_damping'):
        x = getattr(s, name)
        if not np.isfinite(x) or x < 0.0:
            raise ModelError(f'{where}: {name} must be finite and >= 0, got {x!r}')
    if s.limits is None:
        if s.limit_stiffness or s.limit_damping:
            raise ModelError(f'{where}: limit stiffness/damping given without limits')
        return
    if jt not in (REVOLUTE, PRISMATIC, SPHERICAL):
        raise ModelError(f'{where}: only revolute, prismatic and spherical joints take limits')
    pairs = np.asarray(s.limits, dtype=float).reshape(-1, 2) if np.size(s.limits) in (2, 6) else None
    if pairs is None or len(pairs) != (3 if jt == SPHERICAL else 1):
        raise ModelError(f'{where}: limits must be (lower, upper)' +
                         (' per rotation-vector component, 3 pairs' if jt == SPHERICAL else '') + f', got {s.limits!r}')
    for lo, hi in pairs:
        if np.isnan(lo) or np.isnan(hi) or not lo < hi:
            raise ModelError(f'{where}: limits need lower < upper, got {s.limits!r}')


def limit_table(model) -> np.ndarray:
    """The joints with limit moments as rows ``[jtype, q index, v index, mode, lo0, hi0, lo1, hi1, lo2, hi2,
    k, c]`` (float (nl, 12)) for :func:`robodyn_ros.kernels.tree.limit_forces_add`; a 1-DOF joint uses
    pair 0, a spherical joint its three rotation-vector components. Joints whose limits have neither
    stiffness nor damping are left out (reported only)."""
    rows = []
    for i, s in enumerate(model.specs):
        if s.limits is None or not (s.limit_stiffness or s.limit_damping):
            continue
        pairs = np.full((3, 2), np.inf)
        pairs[:, 0] = -np.inf
        lim = np.asarray(s.limits, dtype=float).reshape(-1, 2)
        pairs[:len(lim)] = lim
        rows.append([float(model.jtype[i]), float(model.q_idx[i]), float(model.v_idx[i]),
                     float(LIMIT_RETURNS[s.limit_return]), *pairs.reshape(-1), float(s.limit_stiffness),
                     float(s.limit_damping)])
    return np.ascontiguousarray(np.array(rows, dtype=float).reshape(-1, 12))


def resolve_mimics(specs) -> dict:
    """Each following joint's independent joint: ``{joint: (source, multiplier, offset)}`` with
    ``q_joint = multiplier · q_source + offset`` and ``source`` itself not following another (a
    mimic of a mimic composes: ``m = m₁ m₂``, ``o = m₁ o₂ + o₁``). specs: the LinkSpecs of one tree.
    Raises :class:`ModelError` naming the joint for a source that is not a 1-DOF joint of the tree,
    a following joint that is not 1-DOF, a non-finite multiplier or offset, or a cycle.
    """
    by_joint = {s.joint: s for s in specs}
    one_dof = ('revolute', 'prismatic')
    direct = {}
    for s in specs:
        if s.mimic is None:
            continue
        where = f'link {s.name!r} (joint {s.joint!r})'
        src, m, o = s.mimic
        if s.joint_type not in one_dof:
            raise ModelError(f'{where}: only a revolute or prismatic joint can follow another (mimic), not a '
                             f'{s.joint_type} joint')
        if src not in by_joint or by_joint[src].joint_type not in one_dof:
            what = 'is not a joint of the tree' if src not in by_joint else f'is a {by_joint[src].joint_type} joint'
            raise ModelError(f'{where}: mimics joint {src!r}, which {what} (a mimic follows a revolute or prismatic '
                             'joint)')
        if not (math.isfinite(m) and math.isfinite(o)):
            raise ModelError(f'{where}: mimic multiplier and offset must be finite, got {m!r}, {o!r}')
        direct[s.joint] = (src, float(m), float(o))
    out = {}
    for j in direct:
        chain, (src, m, o) = [j], direct[j]
        while src in direct:
            if src in chain:
                raise ModelError(f'joint {j!r}: the mimic joints form a cycle {" -> ".join(chain + [src])}')
            chain.append(src)
            s2, m2, o2 = direct[src]
            src, m, o = s2, m * m2, m * o2 + o
        out[j] = (src, m, o)
    return out


def mimic_table(model) -> np.ndarray:
    """The joints that follow another as rows ``[q_j, v_j, q_i, v_i, multiplier, offset]`` (float
    (nm, 6)) with ``q_j = multiplier · q_i + offset`` and i independent (:func:`resolve_mimics`),
    for the compiled kernels' coupled dynamics (:mod:`robodyn_ros.kernels`): the velocity map
    ``v = G v_r`` has ``G[v_j, r(v_i)] = multiplier``."""
    rows = []
    index = {n: i for i, n in enumerate(model.joint_names)}
    for j, (src, m, o) in resolve_mimics(model.specs).items():
        a, b = index[j], index[src]
        rows.append([float(model.q_idx[a]), float(model.v_idx[a]), float(model.q_idx[b]), float(model.v_idx[b]), m, o])
    return np.ascontiguousarray(np.array(rows, dtype=float).reshape(-1, 6))


def build_model(links: Sequence[LinkSpec], gravity=(0.0, 0.0, -9.81), name='robot',
                root='base_link', root_visuals=None, mounted_visuals=()) -> Model:
    """Build a :class:`Model` from link specs, sorting them so that parents come first.

    links: the bodies; a parent of ``None`` or ``root`` attaches to the fixed root frame.
    gravity: (3,) in the root frame (zero allowed). name: robot name; root: root frame name;
    root_visuals: the root link's ``<visual>`` elements (XML text; :func:`to_urdf` writes them), None to have
    shapes drawn; mounted_visuals: ``((link, visuals), ...)`` drawn besides a link's own (:class:`Model`).
    Raises :class:`ModelError` naming the offending link for unknown parents, cycles, duplicate
    names, bad joint types, non-unit axes and non-physical inertias.
    """
    links = [x for s in links for x in (planar_links(s) if s.joint_type == 'planar' else (s,))]
    by_name = {}
    for s in links:
        if s.name in by_name or s.name == root:
            raise ModelError(f'link {s.name!r}: duplicate link name')
        by_name[s.name] = s
    jnames = [s.joint for s in links]
    dup = {j for j in jnames if jnames.count(j) > 1}
    if dup:
        raise ModelError(f'duplicate joint names {sorted(dup)}')
    # topological order with cycle detection
    order, state = [], {}

    def visit(n, path):
        if state.get(n) == 2:
            return
        if state.get(n) == 1:
            raise ModelError(f'link {n!r}: parent cycle {" -> ".join(path + [n])}')
        state[n] = 1
        p = by_name[n].parent
        if p is not None and p != root:
            if p not in by_name:
                raise ModelError(f'link {n!r}: unknown parent {p!r}')
            visit(p, path + [n])
        state[n] = 2
        order.append(n)

    for s in links:
        visit(s.name, [])
    index = {n: i for i, n in enumerate(order)}
    nb = len(order)
    parent = np.full(nb, -1, dtype=np.int64)
    jtype = np.zeros(nb, dtype=np.int64)
    axis = np.zeros((nb, 3))
    Xtree = np.zeros((nb, 6, 6))
    I = np.zeros((nb, 6, 6))
    nq_j = np.zeros(nb, dtype=np.int64)
    nv_j = np.zeros(nb, dtype=np.int64)
    damping = []
    specs = []
    for i, n in enumerate(order):
        s = by_name[n]
        where = f'link {n!r} (joint {s.joint!r})'
        if s.joint_type not in JOINT_TYPES:
            raise ModelError(f'{where}: unknown joint type {s.joint_type!r}; '
                             f'valid types are {sorted(JOINT_TYPES)}')
        jt = JOINT_TYPES[s.joint_type]
        if jt == FREE and s.parent not in (None, root):
            raise ModelError(f'{where}: a free joint must attach to the root frame {root!r}')
        parent[i] = -1 if s.parent in (None, root) else index[s.parent]
        jtype[i] = jt
        a = np.asarray(s.axis, dtype=float)
        if jt in (REVOLUTE, PRISMATIC):
            na = np.linalg.norm(a)
            if a.shape != (3,) or not np.isfinite(na) or na < 1e-9:
                raise ModelError(f'{where}: axis must be a non-zero 3-vector, got {s.axis!r}')
            a = a / na
        axis[i] = a if a.shape == (3,) else (0.0, 0.0, 1.0)
        Rj = np.asarray(s.origin_R, dtype=float) if s.origin_R is not None else rpy_to_R(s.origin_rpy)
        xyz = np.asarray(s.origin_xyz, dtype=float)
        if xyz.shape != (3,) or not np.all(np.isfinite(xyz)) or not np.all(np.isfinite(Rj)):
            raise ModelError(f'{where}: origin must be finite xyz (3,) and rpy (3,)')
        Xtree[i] = plux(Rj.T, xyz)
        _check_inertia(s, where)
        I[i] = mcI(float(s.mass), np.asarray(s.com, dtype=float), np.asarray(s.inertia, dtype=float))
        nq_j[i], nv_j[i] = _NQ[jt], _NV[jt]
        if s.damping < 0 or not np.isfinite(s.damping):
            raise ModelError(f'{where}: damping must be finite and >= 0, got {s.damping!r}')
        damping += [float(s.damping)] * int(nv_j[i])
        if not (np.isfinite(s.friction) and s.friction >= 0.0):
            raise ModelError(f'{where}: friction must be finite and >= 0, got {s.friction!r}')
        if not (np.isfinite(s.armature) and s.armature >= 0.0):
            raise ModelError(f'{where}: armature must be finite and >= 0, got {s.armature!r}')
        if s.armature and jt not in (REVOLUTE, PRISMATIC, SPHERICAL):
            raise ModelError(f'{where}: armature applies to revolute, prismatic and spherical joints, not to a '
                             f'{s.joint_type} joint')
        if s.effort_limit is not None and not (np.isfinite(s.effort_limit) and s.effort_limit > 0.0):
            raise ModelError(f'{where}: effort limit must be a finite number > 0, got {s.effort_limit!r}')
        if s.velocity_limit is not None and not (np.isfinite(s.velocity_limit) and s.velocity_limit > 0.0):
            raise ModelError(f'{where}: velocity limit must be a finite number > 0, got {s.velocity_limit!r}')
        _check_limits(s, jt, where)
        specs.append(s)
    resolve_mimics(specs)  # refuses a mimic of an unknown or non-1-DOF joint, or a cycle
    q_idx = np.concatenate([[0], np.cumsum(nq_j)[:-1]]).astype(np.int64) if nb else np.zeros(0, np.int64)
    v_idx = np.concatenate([[0], np.cumsum(nv_j)[:-1]]).astype(np.int64) if nb else np.zeros(0, np.int64)
    g = np.asarray(gravity, dtype=float)
    if g.shape != (3,) or not np.all(np.isfinite(g)):
        raise ModelError(f'gravity must be a finite 3-vector, got {gravity!r}')
    for link, _ in mounted_visuals:
        if link != root and link not in by_name:
            raise ModelError(f'visuals mounted on {link!r}: no such link')
    return Model(name=name, root=root, link_names=tuple(order), joint_names=tuple(by_name[n].joint for n in order),
                 parent=parent, jtype=jtype, axis=axis, Xtree=Xtree, I=I, q_idx=q_idx, v_idx=v_idx,
                 nq_j=nq_j, nv_j=nv_j, damping=np.asarray(damping), gravity=g, specs=tuple(specs),
                 root_visuals=None if root_visuals is None else tuple(root_visuals),
                 mounted_visuals=tuple((str(k), tuple(v)) for k, v in mounted_visuals))


def planar_links(spec: LinkSpec) -> list:
    """The three LinkSpecs of a planar joint (x–z plane of the joint frame, pitch about its y).

    spec: a LinkSpec with ``joint_type='planar'`` (its axis, limits and damping must be left at
    their defaults). Returns ``[J_x_link (prismatic x), J_z_link (prismatic z), L (revolute y)]``
    with joints ``J_x, J_z, J_pitch``; the first two bodies are massless (see the module docstring).
    """
    from dataclasses import replace
    where = f'link {spec.name!r} (joint {spec.joint!r})'
    if spec.limits is not None or spec.damping:
        raise ModelError(f'{where}: a planar joint takes no limits or damping')
    if tuple(float(a) for a in spec.axis) != (0.0, 0.0, 1.0):
        raise ModelError(f'{where}: a planar joint takes no axis (its plane is the x-z plane of its '
                         'joint frame; rotate the plane with the origin rpy)')
    jx, jz, jp = (spec.joint + s for s in PLANAR_SUFFIXES)
    return [LinkSpec(name=f'{jx}_link', joint=jx, parent=spec.parent, joint_type='prismatic',
                     origin_xyz=spec.origin_xyz, origin_rpy=spec.origin_rpy, origin_R=spec.origin_R,
                     axis=(1.0, 0.0, 0.0)),
            LinkSpec(name=f'{jz}_link', joint=jz, parent=f'{jx}_link', joint_type='prismatic', axis=(0.0, 0.0, 1.0)),
            replace(spec, joint=jp, parent=f'{jz}_link', joint_type='revolute', origin_xyz=(0.0, 0.0, 0.0),
                    origin_rpy=(0.0, 0.0, 0.0), origin_R=None, axis=(0.0, 1.0, 0.0))]


def planar_root(model: Model):
    """``(joint name J, index of body L)`` when bodies 0-2 of ``model`` are a planar composite
    attached to the root frame (as :func:`planar_links` builds it), else None."""
    if model.nb < 3 or model.parent[0] != -1 or list(model.parent[1:3]) != [0, 1]:
        return None
    j = model.joint_names[0][:-len(PLANAR_SUFFIXES[0])]
    want = [(PRISMATIC, (1.0, 0.0, 0.0)), (PRISMATIC, (0.0, 0.0, 1.0)), (REVOLUTE, (0.0, 1.0, 0.0))]
    for i, (jt, ax) in enumerate(want):
        if model.joint_names[i] != j + PLANAR_SUFFIXES[i] or model.jtype[i] != jt or tuple(model.axis[i]) != ax:
            return None
    if np.any(model.I[:2]) or not (np.allclose(model.Xtree[1], np.eye(6)) and np.allclose(model.Xtree[2], np.eye(6))):
        return None
    return j, 2


def _homog(R, p):
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = p
    return T


def dh_links(rows, convention='standard', names=None, root='base_link', tool=True):
    """Link specs for a serial chain from a Denavit–Hartenberg table.

    rows: sequence of dicts with keys ``type`` ('revolute'|'prismatic'), ``a``, ``alpha``, ``d``,
    ``theta`` (the constant part; the joint variable adds to theta or d), ``mass``, ``com`` (3,)
    and ``inertia`` (3x3 about the com) expressed in the DH frame of that link (frame i for
    standard DH, as in Corke's toolbox; frame i for modified DH, Craig), optional ``damping``,
    ``limits``, ``effort_limit``. convention: 'standard' (Rz(θ) Tz(d) Tx(a) Rx(α)) or 'modified'
    (Rx(α_{i-1}) Tx(a_{i-1}) Rz(θ_i) Tz(d_i)). names: optional list of (link, joint) names.
    tool: for standard DH, append a massless fixed ``tool`` link at DH frame n.

    Standard DH puts link i's frame at its distal end, but our body frames sit on the joint
    axis; so body i's frame is DH frame i-1 moved by the joint (Rz(θ)Tz(d), which commute), the
    link's remaining Tx(a_i)Rx(α_i) goes into the next joint's origin, and the inertial data is
    transformed from DH frame i into body frame i here.
    """
    if convention not in ('standard', 'modified'):
        raise ModelError(f'DH convention must be standard or modified, got {convention!r}')
    specs = []
    n = len(rows)
    names = names or [(f'link{i + 1}', f'joint{i + 1}') for i in range(n)]
    prev = root
    tail = np.eye(4)  # standard DH: Tx(a_{i-1}) Rx(α_{i-1}) left over from the previous link
    for i, r in enumerate(rows):
        jt = r.get('type', 'revolute')
        a, alpha, d, theta = (float(r.get(k, 0.0)) for k in ('a', 'alpha', 'd', 'theta'))
        com = np.asarray(r.get('com', (0.0, 0.0, 0.0)), dtype=float)
        Ic = np.asarray(r.get('inertia', np.zeros((3, 3))), dtype=float)
        if convention == 'modified':
            # Rz(θ) and Tz(d) commute, so both joint kinds are Tz(d) Rz(θ) followed by the motion
            T = _homog(rotx(alpha), np.zeros(3)) @ _homog(np.eye(3), (a, 0, 0)) @ _homog(rotz(theta), (0, 0, d))
            com_b, Ic_b = com, Ic
        else:
            T = tail @ _homog(rotz(theta), (0, 0, d))
            # DH frame i = body frame i * Tx(a) Rx(α): move com and inertia into body frame i
            Rb = rotx(alpha)
            com_b = np.array([a, 0.0, 0.0]) + Rb @ com
            Ic_b = Rb @ Ic @ Rb.T
            tail = _homog(np.eye(3), (a, 0, 0)) @ _homog(rotx(alpha), np.zeros(3))
        ln, jn = names[i]
        specs.append(LinkSpec(name=ln, joint=jn, parent=prev, joint_type=jt, origin_xyz=tuple(T[:3, 3]),
                              origin_R=T[:3, :3], origin_rpy=tuple(R_to_rpy(T[:3, :3])), axis=(0.0, 0.0, 1.0),
                              mass=float(r.get('mass', 0.0)), com=tuple(com_b), inertia=Ic_b,
                              damping=float(r.get('damping', 0.0)), limits=r.get('limits'),
                              effort_limit=r.get('effort_limit')))
        prev = ln
    if convention == 'standard' and tool and n:
        specs.append(LinkSpec(name='tool', joint='tool_joint', parent=prev, joint_type='fixed',
                              origin_xyz=tuple(tail[:3, 3]), origin_R=tail[:3, :3],
                              origin_rpy=tuple(R_to_rpy(tail[:3, :3]))))
    return specs


#: smallest dimension (m) of a drawn visual, so that a slender bar or a thin disk stays visible
VISUAL_MIN_SIZE = 0.01
#: radius (m) of the sphere drawn at a massless frame with nothing to join (a tool or contact point)
VISUAL_FRAME_RADIUS = 0.02
#: fit test of a link's solid: along each direction its key points span, it may pass them by
#: max(VISUAL_FIT_MARGIN, VISUAL_FIT_FRACTION x their extent) (m) at either end
VISUAL_FIT_MARGIN, VISUAL_FIT_FRACTION = 0.06, 0.3
#: density (kg/m³, water) that sets the radius of a joint-to-joint cylinder from the link's mass
VISUAL_DENSITY = 1000.0
_MATERIAL = '<material name="robodyn_body"><color rgba="0.6 0.65 0.7 1"/></material>'


def _visual(xyz, R, geom: str) -> str:
    """One ``<visual>`` element: ``geom`` placed at ``xyz`` (3,) with rotation ``R`` (3, 3), link frame."""
    return (f'<visual><origin xyz="{" ".join(repr(float(x)) for x in xyz)}" '
            f'rpy="{" ".join(repr(float(x)) for x in R_to_rpy(R))}"/><geometry>{geom}</geometry>{_MATERIAL}</visual>')


def _inertia_solid(mass, com, Ic):
    """The uniform solid of a link's inertia: ``(geometry XML, R (3, 3), points (k, 3))`` or None.

    The points are the solid's extreme points in the link frame (box corners, cylinder rims,
    sphere poles), for the fit test of :func:`link_visuals`. See :func:`inertia_visual`.
    """
    m = float(mass)
    if not m > 0.0:
        return None
    ev, Q = np.linalg.eigh(0.5 * (np.asarray(Ic, dtype=float) + np.asarray(Ic, dtype=float).T))
    ev = np.maximum(ev, 0.0)
    if np.linalg.det(Q) < 0:
        Q[:, 0] = -Q[:, 0]
    tol = 1e-6 * max(ev.max(), 1e-300)

    def ln(x):
        return max(float(np.sqrt(max(x, 0.0))), VISUAL_MIN_SIZE)
    if ev[2] - ev[0] <= tol:
        r = ln(2.5 * ev[0] / m)
        geom, local = f'<sphere radius="{r!r}"/>', np.vstack([np.eye(3), -np.eye(3)]) * r
    elif ev[1] - ev[0] <= tol or ev[2] - ev[1] <= tol:
        k = 2 if ev[1] - ev[0] <= tol else 0  # the odd principal axis
        Ia, Ip = ev[k], ev[1]
        Q = np.roll(Q, 2 - k, axis=1)  # odd axis -> local z of the cylinder (a cyclic shift keeps det = +1)
        r, h = ln(2.0 * Ia / m), ln(12.0 * Ip / m - 6.0 * Ia / m)
        geom = f'<cylinder radius="{r!r}" length="{h!r}"/>'
        a = np.linspace(0.0, 2.0 * np.pi, 16, endpoint=False)
        local = np.array([(r * np.cos(t), r * np.sin(t), z) for t in a for z in (-h / 2, h / 2)])
    else:
        d = [ln(6.0 * (ev[(a + 1) % 3] + ev[(a + 2) % 3] - ev[a]) / m) for a in range(3)]
        geom = f'<box size="{d[0]!r} {d[1]!r} {d[2]!r}"/>'
        local = np.array([(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * np.array(d) / 2
    return geom, Q, np.asarray(com, dtype=float) + local @ Q.T


def inertia_visual(mass, com, Ic) -> str:
    """A ``<visual>`` (URDF XML) of the uniform solid with the link's mass and inertia, or ''.

    mass (kg), com (3,) in the link frame, Ic (3, 3) about the com. Principal moments
    ``I1 <= I2 <= I3`` (principal axes give the orientation): three equal -> a sphere
    (``I = 2/5 m r²``); two equal -> a cylinder along the odd axis (``I_axis = m r²/2``,
    ``I_perp = m (3 r² + h²)/12``): slender bars, wheels, de Leva's segments; else the box with
    ``I_x = m (y² + z²)/12`` etc. URDF has no ellipsoid. Each dimension is at least
    :data:`VISUAL_MIN_SIZE`. Massless links get none.
    """
    solid = _inertia_solid(mass, com, Ic)
    return '' if solid is None else _visual(com, solid[1], solid[0])


def solid_fits(points, key_points) -> bool:
    """Whether a solid (its extreme points (k, 3)) stays within a link's key points (n, 3).

    Along each principal direction u of the key points (SVD of the centred points) in which they
    extend by e > :data:`VISUAL_MIN_SIZE`, the solid may pass them by at most
    ``max(VISUAL_FIT_MARGIN, VISUAL_FIT_FRACTION e)`` at either end; across the link (directions
    the key points do not span: a torso's width, a bar's thickness) it is free.
    """
    K = np.asarray(key_points, dtype=float)
    _, _, Vt = np.linalg.svd(K - K.mean(axis=0))
    for u in Vt:
        k, p = K @ u, np.asarray(points) @ u
        e = k.max() - k.min()
        pad = max(VISUAL_FIT_MARGIN, VISUAL_FIT_FRACTION * e)
        if e > VISUAL_MIN_SIZE and (p.min() < k.min() - pad or p.max() > k.max() + pad):
            return False
    return True


def _cylinders(ends, radius) -> list:
    """``<visual>`` cylinders from the link frame origin to each point of ``ends`` (link frame)."""
    out, radius = [], float(radius)
    for t in ends:
        L = float(np.linalg.norm(t))
        z = np.asarray(t, dtype=float) / L
        x = np.cross(z, (1.0, 0.0, 0.0) if abs(z[0]) < 0.9 else (0.0, 1.0, 0.0))
        x /= np.linalg.norm(x)
        out.append(_visual(np.asarray(t, dtype=float) / 2, np.column_stack([x, np.cross(z, x), z]),
                           f'<cylinder radius="{radius!r}" length="{L!r}"/>'))
    return out


def link_visuals(spec, jtype: int, children, root: bool = False) -> list:
    """The ``<visual>`` elements drawn for a link without visuals of its own (see docs/urdf.md).

    spec: the link's LinkSpec; jtype: its joint code; children: [(xyz (3,) of a child joint's
    origin in this link's frame, mass of the child's subtree)]; root: the model's root frame. Its *key points* are the frame
    origin, the child joint origins and, with mass, the centre of mass c and 2c (a body hung from
    its joint through its CoM reaches about that far).

    * A link with mass gets the uniform solid of its inertia (:func:`inertia_visual`) when it has
      no child joint (a hand, a wheel: nothing bounds it), when it floats (free root) or when the
      solid fits its key points (:func:`solid_fits`). Otherwise (the Stanford arm's boom, whose
      inertia is that of a 2.7 m rod) it gets cylinders from the origin to each child joint and to
      2c, of the radius of a water cylinder of its mass (:data:`VISUAL_DENSITY`) and at most a
      quarter of the longest.
    * A massless link gets cylinders (radius a tenth of the length, 1 to 5 cm) to the child
      joints that carry mass (a fixed base's pedestal, an axle), or else a sphere of
      :data:`VISUAL_FRAME_RADIUS` (a tool or contact point, a fixed base at the first joint). An
      intermediate frame other than the root whose children all sit at its origin and carry mass
      (a planar root's massless bodies, a time-varying DH twist's frame) gets nothing.
    """
    far = [(np.asarray(p, dtype=float), m) for p, m in children if np.linalg.norm(p) > VISUAL_MIN_SIZE]
    if not spec.mass > 0.0:
        ends = [p for p, m in far if m > 0.0]
        if ends:
            return _cylinders(ends, min(max(0.1 * min(np.linalg.norm(ends, axis=1)), 0.01), 0.05))
        if not root and any(m > 0.0 for _, m in children):
            return []
        return [_visual(np.zeros(3), np.eye(3), f'<sphere radius="{VISUAL_FRAME_RADIUS!r}"/>')]
    c = np.asarray(spec.com, dtype=float)
    geom, R, pts = _inertia_solid(spec.mass, c, spec.inertia)
    key = np.vstack([np.zeros(3), c, 2.0 * c] + [np.asarray(p, dtype=float) for p, _ in children])
    if not children or jtype == FREE or solid_fits(pts, key):
        return [_visual(c, R, geom)]
    ends = [p for p, _ in far] + ([2.0 * c] if np.linalg.norm(2.0 * c) > VISUAL_MIN_SIZE else [])
    Ls = np.linalg.norm(ends, axis=1)
    r = float(np.sqrt(spec.mass / (VISUAL_DENSITY * np.pi * Ls.sum())))
    return _cylinders(ends, min(max(r, VISUAL_MIN_SIZE), 0.25 * Ls.max()))


def _origin(model: Model, i: int):
    """Joint i's origin in its parent's frame: ``(xyz (3,), R (3, 3))`` from ``Xtree[i]``."""
    E = model.Xtree[i][:3, :3]
    p = -(E.T @ model.Xtree[i][3:, :3])  # skew(r) = -E^T X[3:, :3]
    return np.array([p[2, 1], p[0, 2], p[1, 0]]), E.T


def _xa(name) -> str:
    """A name as the text of an XML attribute (``&``, ``<``, ``>`` and ``"`` escaped)."""
    return str(name).replace('&', '&amp;').replace('<', '&lt;').replace('>', '&gt;').replace('"', '&quot;')


def to_urdf(model: Model) -> str:
    """URDF text of the model; link/joint names and frames equal the simulator's.

    Revolute joints without limits are exported as ``revolute`` with wide limits (not
    ``continuous``, which some parsers turn into a 2-coordinate joint). A free root joint is
    written as ``floating``. Effort and velocity limits, damping, friction and mimics are written. The
    links of a URDF imported with ``<visual>`` elements keep exactly those (meshes passed through; none
    where the file has none); every other link (a link of a scene's part, of a platform, of a URDF
    without any ``<visual>``) gets shapes drawn from its inertia and joints (:func:`link_visuals`) so
    that a 3D viewer shows bodies, and a link a URDF robot is mounted on gets that robot's root-link
    visuals as well (``Model.mounted_visuals``). Every number is written as Python's ``repr`` of the
    double (the shortest text that parses back to the same bits), so a tool that rebuilds the model from
    this text gets the simulator's numbers exactly.
    """
    def f(x):
        return ' '.join(repr(float(v)) for v in x)

    nb = model.nb
    sub = np.array([float(s.mass) for s in model.specs])  # mass of each subtree
    for i in range(nb - 1, -1, -1):
        if model.parent[i] >= 0:
            sub[model.parent[i]] += sub[i]
    origins = [_origin(model, i) for i in range(nb)]
    kids = {j: [] for j in range(-1, nb)}
    for i in range(nb):
        if model.jtype[i] != FREE:
            kids[int(model.parent[i])].append((origins[i][0], sub[i]))
    mounted = {}
    for link, vis in model.mounted_visuals:
        mounted[link] = mounted.get(link, ()) + tuple(vis)
    root = LinkSpec(name=model.root, joint='', parent=None)
    out = [f'<?xml version="1.0"?>', f'<robot name="{_xa(model.name)}">']
    root_vis = list(model.root_visuals) if model.root_visuals is not None else \
        link_visuals(root, FIXED, kids[-1], root=True) if kids[-1] else []
    root_vis += mounted.get(model.root, ())
    out += [f'  <link name="{_xa(model.root)}">', *(f'    {v}' for v in root_vis), '  </link>'] if root_vis \
        else [f'  <link name="{_xa(model.root)}"/>']
    for i, s in enumerate(model.specs):
        Ic = np.asarray(s.inertia, dtype=float)
        out.append(f'  <link name="{_xa(s.name)}">')
        if s.mass > 0.0:
            out.append('    <inertial>')
            out.append(f'      <origin xyz="{f(s.com)}" rpy="0 0 0"/>')
            out.append(f'      <mass value="{float(s.mass)!r}"/>')
            out.append('      <inertia ixx="{!r}" ixy="{!r}" ixz="{!r}" iyy="{!r}" iyz="{!r}" izz="{!r}"/>'.format(
                *(float(Ic[j, k]) for j, k in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)))))
            out.append('    </inertial>')
        own = s.visuals if s.visuals is not None else link_visuals(s, int(model.jtype[i]), kids[i])
        for v in (*own, *mounted.get(s.name, ())):
            out.append(f'    {v}')
        out.append('  </link>')
        jt = int(model.jtype[i])
        parent = model.root if model.parent[i] < 0 else model.link_names[model.parent[i]]
        r, R = origins[i]
        if jt == SPHERICAL:
            out += _spherical_urdf(s, parent, f(r), f(R_to_rpy(R)))
            continue
        kind = {FIXED: 'fixed', REVOLUTE: 'revolute', PRISMATIC: 'prismatic', FREE: 'floating'}[jt]
        out.append(f'  <joint name="{_xa(s.joint)}" type="{kind}">')
        out.append(f'    <parent link="{_xa(parent)}"/>')
        out.append(f'    <child link="{_xa(s.name)}"/>')
        out.append(f'    <origin xyz="{f(r)}" rpy="{f(R_to_rpy(R))}"/>')
        if jt in (REVOLUTE, PRISMATIC):
            out.append(f'    <axis xyz="{f(model.axis[i])}"/>')
            lo, hi = np.ravel(s.limits) if s.limits is not None else (-1e4, 1e4)
            eff = float(s.effort_limit) if s.effort_limit is not None else 1e6
            vel = float(s.velocity_limit) if s.velocity_limit is not None else 1e6
            out.append(f'    <limit lower="{float(lo)!r}" upper="{float(hi)!r}" effort="{eff!r}" velocity="{vel!r}"/>')
            if s.damping or s.friction:
                out.append(f'    <dynamics damping="{float(s.damping)!r}" friction="{float(s.friction)!r}"/>')
            if s.mimic is not None:
                out.append(f'    <mimic joint="{_xa(s.mimic[0])}" multiplier="{float(s.mimic[1])!r}" '
                           f'offset="{float(s.mimic[2])!r}"/>')
        out.append('  </joint>')
    out.append('</robot>')
    return '\n'.join(out) + '\n'


def spherical_link_names(spec) -> tuple:
    """The two massless intermediate links of a spherical joint's URDF export (after _x, after _y)."""
    return (f'{spec.joint}_x_link', f'{spec.joint}_y_link')


def _spherical_urdf(s, parent, xyz, rpy) -> list:
    """URDF lines of a spherical joint: three revolute joints ``<joint>_x``, ``_y``, ``_z`` about the
    joint frame's x, then the new y, then the new z axis, joined by two massless links
    (:func:`spherical_link_names`). Their angles are the Bryan angles of Huston eq. (20.3.2),
    ``R = Rx(α) Ry(β) Rz(γ)``, which ``joint_states`` publishes (:func:`bryan_angles`)."""
    lx, ly = spherical_link_names(s)
    out = [f'  <link name="{_xa(lx)}"/>', f'  <link name="{_xa(ly)}"/>']
    chain = ((parent, lx, xyz, rpy, '1 0 0'), (lx, ly, '0 0 0', '0 0 0', '0 1 0'),
             (ly, s.name, '0 0 0', '0 0 0', '0 0 1'))
    for (pa, ch, o_xyz, o_rpy, ax), suf in zip(chain, SPHERICAL_AXES):
        out += [f'  <joint name="{_xa(s.joint + suf)}" type="revolute">', f'    <parent link="{_xa(pa)}"/>',
                f'    <child link="{_xa(ch)}"/>', f'    <origin xyz="{o_xyz}" rpy="{o_rpy}"/>', f'    <axis xyz="{ax}"/>',
                '    <limit lower="-10000.0" upper="10000.0" effort="1e6" velocity="1e6"/>', '  </joint>']
    return out


def bryan_angles(quat) -> tuple:
    """Bryan angles ``(α, β, γ)`` with ``R(quat) = Rx(α) Ry(β) Rz(γ)`` (Huston eq. 20.3.2), quat (x, y, z, w).

    β in [-π/2, π/2] from the first row; α from the third column; γ from the rotation left after
    ``Rx(α) Ry(β)``, so the three angles rebuild R to rounding even at the gimbal lock β = ±π/2
    (where α and γ are not unique). Plain floats: runs at every publication.
    """
    x, y, z, w = quat.tolist() if isinstance(quat, np.ndarray) else (float(c) for c in quat)
    n = math.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    r00, r01, r02 = 1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)
    r10, r20 = 2 * (x * y + z * w), 2 * (x * z - y * w)
    r12, r22 = 2 * (y * z - x * w), 1 - 2 * (x * x + y * y)
    b = math.atan2(r02, math.hypot(r00, r01))   # first row [cβ cγ, -cβ sγ, sβ]; asin(r02) loses digits at ±π/2
    a = math.atan2(-r12, r22)
    # residual Rz(γ) = (Rx(α) Ry(β))ᵀ R: γ from its first column
    ca, sa, cb, sb = math.cos(a), math.sin(a), math.cos(b), math.sin(b)
    # rows of (Rx(α) Ry(β))ᵀ: [cb, sa sb, -ca sb], [0, ca, sa]
    c00 = cb * r00 + sa * sb * r10 - ca * sb * r20
    c10 = ca * r10 + sa * r20
    return a, b, math.atan2(c10, c00)


def random_tree(nb, rng, prismatic_fraction=0.3, chain=False, gravity=(0.0, 0.0, -9.81), spherical_fraction=0.0,
                free_root=False):
    """A random tree of ``nb`` bodies with physical inertias, for tests and benchmarks.

    nb: number of bodies; rng: ``numpy.random.Generator`` (seeded by the caller);
    prismatic_fraction: share of prismatic joints; chain: a serial chain instead of a tree;
    spherical_fraction: share of spherical joints (drawn first; default none, so the random
    stream of 1-DOF trees is unchanged); free_root: body 0 on a FREE joint.
    """
    specs = []
    for i in range(nb):
        p = None if i == 0 else (f'l{i - 1}' if chain else f'l{rng.integers(0, i)}')
        ax = rng.normal(size=3)
        ev = np.sort(rng.uniform(0.01, 0.2, size=3))
        ev[2] = min(ev[2], ev[0] + ev[1] - 1e-3)  # triangle inequality of principal moments
        Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        if free_root and i == 0:
            jt = 'free'
        elif spherical_fraction and rng.random() < spherical_fraction:
            jt = 'spherical'
        else:
            jt = 'prismatic' if rng.random() < prismatic_fraction else 'revolute'
        specs.append(LinkSpec(
            name=f'l{i}', joint=f'j{i}', parent=p, joint_type=jt,
            origin_xyz=tuple(rng.uniform(-0.5, 0.5, size=3)), origin_rpy=tuple(rng.uniform(-np.pi, np.pi, size=3)),
            axis=tuple(ax / np.linalg.norm(ax)), mass=float(rng.uniform(0.5, 3.0)),
            com=tuple(rng.uniform(-0.2, 0.2, size=3)), inertia=Q @ np.diag(ev) @ Q.T))
    return build_model(specs, gravity=gravity, name=f'random{nb}')


__all__ = ['FIXED', 'REVOLUTE', 'PRISMATIC', 'FREE', 'SPHERICAL', 'SPHERICAL_AXES', 'SphericalJointError',
           'refuse_spherical', 'LIMIT_RETURNS', 'limit_table', 'JOINT_TYPES', 'ModelError', 'LinkSpec', 'Model',
           'jcalc', 'build_model', 'bryan_angles', 'spherical_link_names', 'dh_links', 'to_urdf', 'inertia_visual',
           'link_visuals', 'solid_fits',
           'random_tree', 'skew', 'PLANAR_SUFFIXES', 'planar_links', 'planar_root']
