"""Scene files: YAML -> validated system, initial state, scripted commands and run settings.

A scene is one YAML mapping (unknown keys anywhere are errors, so typos never pass silently)::

    name: stanford_arm                    # required, str
    description: one paragraph            # optional, str ('robodyn scenes' lists it)
    source: where the parameters come from  # optional, str
    gravity: [0, 0, -9.81]                # optional, (3,) m/s² in the world frame (z up)
    parts:                                # required, non-empty list; each entry has a 'kind'
      - kind: arm                         # a key of PART_KINDS
        name: arm                         # unique part name
        mount: world                      # 'world' (later: the name of a platform / free-base part)
        origin: {xyz: [..], rpy: [..]}    # optional pose of the arm's base frame in the mount frame
        root: base_link                   # optional name of the arm's base frame (URDF root)
        dh:                               # either a DH table ...
          convention: standard            # 'standard' (Corke/Paul) or 'modified' (Craig)
          links: [{type, a, alpha, d, theta, mass, com, inertia, damping, limits}, ...]
        tool: true                        # standard DH only: add a fixed 'tool' link at DH frame n
        link_names: [...]                 # optional names for the DH links / joints
        joint_names: [...]
        links: [{name, joint, parent, type, origin: {xyz, rpy}, axis, mass, com, inertia,
                 damping, limits}, ...]   # ... or explicit links (URDF-like), not both
        actuated: [joint, ...]            # optional, default every 1-DOF joint; [] = passive
    initial_state: {q: [...], v: [...]}   # optional, defaults neutral / zero (a planar base also
                                          # takes com: [x, z], com_velocity: [vx, vz])
    commands:                             # optional scripted commands, per input port
      effort: {profile: <COMMAND_PROFILES key>, <profile parameters>}
    simulation: {integrator: rk4, dt: 0.001, rtol: .., atol: .., publish_rate: 100, duration: 10}
    stop_when: {com_z_below: -10.0}       # optional: end the run at the first publication where
                                          # it holds (STOP_CONDITIONS; planar bases have a CoM)

Link data: ``type`` revolute | prismatic (| fixed | planar | spherical | free for explicit links); ``mass`` kg (>= 0);
``com`` (3,) m; ``inertia`` about the centre of mass, either ``[[ixx, ixy, ixz], [..], [..]]``
or ``[ixx, iyy, izz, ixy, ixz, iyz]`` (kg·m²), symmetric positive semi-definite with principal
moments obeying the triangle inequality (a slender bar's zero axial moment is allowed).
For DH links com/inertia are expressed in DH frame i (Corke's toolbox convention, see
:func:`robodyn_ros.model.dh_links`); for explicit links in the link (joint) frame.
``damping`` is viscous (N·m·s/rad or N·s/m); ``limits`` ``[lo, hi]`` (rad or m) are recorded in
the URDF and checked against the initial state, but the dynamics does not enforce them;
``effort_limit`` (N·m or N, > 0) is the actuator's limit: effort commands are clamped to it, the
clamped components counted (diagnostics ``effort_clamped``) and joint_states shows the applied effort.

Planar root (a tree in free flight in a plane, e.g. the diver): an explicit link with ``type:
planar`` (no axis, limits or damping) and ``parent`` the arm's ``root`` becomes the joints
``<joint>_x``, ``<joint>_z`` (prismatic) and ``<joint>_pitch`` (revolute about y) through two
massless bodies, in the x–z plane of its ``origin`` (:func:`robodyn_ros.model.planar_links`).
The part is then a :class:`~robodyn_ros.systems.planar.PlanarBaseSystem`: ``odom`` is the
link's pose, ``joint_states`` the inner joints, q/v the three base coordinates then the inner
joints; ``actuated`` may name inner joints only. The ``pfl`` command profile (partial feedback
linearisation to a posture and back, :mod:`robodyn_ros.pfl`) drives such a tree.

Joint-limit moments: the mapping form ``limits: {lower, upper, stiffness, damping, return}``
adds the joint-limit moments of
Huston eq. (20.2.1) (:func:`robodyn_ros.kernels.core.limit_moment`): zero inside, beyond a limit
``-k (θ - θlim) - c θ̇`` while moving outward; moving back ``return: spring`` (default: the spring
without its damper) or ``none`` (the equation as printed: no moment at all — a joint that stops
beyond its range stays there, and error-controlled integrators crawl through the switching). stiffness k (N·m/rad or
N/m) and damping c (N·m·s/rad or N·s/m) default to 0; both 0 = reported only. They act on arms
on the world or on a free root; an arm carrying them on a free_base or diff_drive platform is refused.

Spherical joints (explicit links, ``type: spherical``, no axis): q is a unit quaternion
``[x, y, z, w]`` of the child frame in the joint frame, v its angular velocity in the child frame
(3); ``joint_states`` names ``<joint>_x/_y/_z`` (Bryan angles, see
:mod:`robodyn_ros.systems.arm`), which are also the names to list in ``actuated`` (torque
components about the child axes). Their ``limits`` mapping takes ``lower``/``upper`` as 3-vectors,
one per component of the joint's rotation vector φ (rad, joint frame; ``.inf`` for none).

Free root (``mount: free``): the tree floats; ``root`` defaults to ``odom`` and the one link whose
parent is the root frame has ``type: free`` (no origin, axis or limits); q starts with that
link's pose ``[x, y, z, qx, qy, qz, qw]`` in odom, v with its twist ``[ωx, ωy, ωz, vx, vy, vz]``
in its own frame; ``odom`` publishes it. Trees with spherical joints or limit moments need the
compiled kernels (backend numba; 'generated' falls back to them).

Errors: every defect raises :class:`SceneError` (a ValueError) with the message
``<file>: <key path>: <reason>``, e.g. ``arm.yaml: parts[0].dh.links[2].mass: missing key``;
YAML syntax errors use ``line L, column C`` as the key path.

Differential-drive platform (seed 001; :mod:`robodyn_ros.systems.diffdrive`)::

      - kind: diff_drive                  # planar chassis + two wheels rolling without slip
        name: platform                    # an arm mounts on it with 'mount: platform'
        mount: world                      # optional; a platform stands on the world only
        chassis: {mass: 3.3, yaw_inertia: 0.18965, com: [0, 0, 0.28]}   # kg, kg·m² about the com, m
        payload: {mass: 0.4, yaw_inertia: 0.975, com: [0, 0, 0.28]}     # optional rigid payload
        wheels: {radius: 0.28, half_track: 0.35, mass: 0.3, spin_inertia: 0.0037,
                 diametral_inertia: 0.00185}                           # optional, default spin/2
        motor: {kind: dc_motor, torque_constant: 0.061, resistance: 1.7,  # both wheels; or
                inductance: 0.0, gear_ratio: 1.0, rotor_inertia: 0.0,    # motors: {left: {..},
                viscous_friction: 0.0, coulomb_friction: 0.0,            #          right: {..}}
                coulomb_velocity: 0.05, supply_voltage: 24.0}
        baumgarte_alpha: 0.0              # optional, 1/s, velocity-level Baumgarte (projection always)

Its state is ``q = [x, y, yaw, left_wheel, right_wheel, arm joints...]``, ``v = q̇`` (the
initial velocity must roll without slip), then one current per motor with ``inductance > 0``;
its inputs are ``wheel_voltage`` ``[left, right]`` (V) and, with an arm mounted on it
(``mount: <platform name>``, ``origin`` in base_link), the arm's ``effort``.

Prescribed joint motion (seed 001's DH animation; :mod:`robodyn_ros.systems.kinematic`)::

      - kind: kinematic_arm               # the keys of an arm part, without 'actuated', plus
        name: arm
        links: [...]                      # (or dh: {...})
        motion: {joint1: pi*t, joint2: pi/3 + sin(t)}   # every 1-DOF joint: an expression of t

Expressions use the whitelist of :mod:`robodyn_ros.expressions` (numbers, ``t``, ``pi``, ``e``,
``+ - * / **``, sin, cos, exp, ...; never ``eval``), with exact q̇, q̈. The state is the clock
``[t]`` (``initial_state`` is refused) and the system has no inputs; its joint_states effort is the
inverse-dynamics effort that makes the arm follow the motion.
Imported robot (:func:`build_urdf_part`, :mod:`robodyn_ros.urdf`)::

      - kind: urdf
        name: panda
        file: panda.urdf                  # relative to the scene file; or urdf: <the URDF text>
        mount: world                      # or a diff_drive / free_base part (then origin places it)
        floating: false                   # true: a free 6-DOF base (environment free_fall, or orbit
                                          # with zero gravity); no mount, no origin
        locked: {panda_finger_joint1: 0.0}  # joints frozen as fixed (e.g. <mimic> joints)
        actuated: [...]                   # optional, default every 1-DOF joint
        position_limits: {stiffness: 500.0, damping: 5.0, return: spring}   # optional: <limit lower
                                          # upper> enforced by eq. 20.2.1 moments (absent: reported only)

A path ending in ``.urdf`` given to :func:`load_scene` is such a scene of one part
(:func:`urdf_scene_text`).

Extension: a new part kind registers ``PART_KINDS[kind] = builder`` with
``builder(spec, path, ctx) -> Part``; a new command profile registers
``COMMAND_PROFILES[name] = builder`` with ``builder(params, path, ctx, system, port) ->
f(t, y) -> (size,) array``. Both validate their own keys through the ``ctx`` helpers so their
errors carry the file and the key path. Scenes of several parts (an arm on a platform) are put
together in :func:`_assemble`.
"""
from __future__ import annotations

import math
import os
import re
import sys
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np
import yaml

from . import dynamics as dyn
from .model import JOINT_TYPES, PRISMATIC, REVOLUTE, LinkSpec, ModelError, build_model, dh_links, planar_root
from .spatial import R_to_rpy, rpy_to_R
from .systems.arm import ArmSystem

__all__ = ['SceneError', 'Scene', 'Part', 'SceneContext', 'PART_KINDS', 'COMMAND_PROFILES',
           'DEFAULT_SETTINGS', 'load_scene', 'parse_scene', 'list_scenes', 'scene_dirs', 'find_scene',
           'build_arm_part', 'build_urdf_part', 'urdf_scene_text']

#: run settings a scene's ``simulation`` section may override (the CLI/node may override again)
DEFAULT_SETTINGS = {'integrator': 'rk4', 'dt': 1e-3, 'publish_rate': 100.0, 'duration': 10.0}
_SETTING_KEYS = ('integrator', 'dt', 'rtol', 'atol', 'publish_rate', 'duration')
_TOP_KEYS_REQUIRED = ('name', 'parts')
_TOP_KEYS_OPTIONAL = ('description', 'source', 'gravity', 'initial_state', 'commands', 'simulation', 'stop_when')


class SceneError(ValueError):
    """A scene that cannot be loaded; the message is ``<file>: <key path>: <reason>``."""


@dataclass
class Part:
    """One built part of a scene.

    name: part name; kind: its PART_KINDS key; mount: 'world' or the part it sits on;
    system: the part's :class:`robodyn_ros.systems.System`; path: its key path in the file.
    """

    name: str
    kind: str
    mount: str
    system: object
    path: str


@dataclass
class Scene:
    """A loaded scene: what to simulate, from where, with which commands and settings.

    name: scene name; path: file it came from; text: the raw YAML (recorded in MCAP metadata);
    data: the parsed mapping; system: the System to integrate (an ArmSystem for now);
    y0: (ny,) initial state; script: ``script(t, y) -> {port: (size,) array}`` for the
    commanded ports, or None; settings: simulation defaults (integrator, dt, publish_rate,
    duration, and rtol/atol when given); parts: part names in file order; stop: ``stop(t, y) ->
    bool`` from ``stop_when`` (the run ends at the first publication where it is true), or None.
    """

    name: str
    path: str
    text: str
    data: dict
    system: object
    y0: np.ndarray
    script: Callable | None
    settings: dict
    parts: list = field(default_factory=list)
    stop: Callable | None = None


# --------------------------------------------------------------------------------------------
# YAML: YAML 1.2 floats (1e-3 is a number, not a string) and duplicate keys refused
# --------------------------------------------------------------------------------------------
class _Loader(yaml.SafeLoader):
    """SafeLoader that reads ``1e-3`` as a float and refuses duplicate mapping keys."""


_Loader.add_implicit_resolver(
    'tag:yaml.org,2002:float',
    re.compile(r'^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$'),
    list('-+0123456789'))


def _construct_mapping(loader, node, deep=False):
    """Mapping constructor that raises on a repeated key (PyYAML silently keeps the last)."""
    loader.flatten_mapping(node)
    seen = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=True)
        if key in seen:
            raise yaml.constructor.ConstructorError(None, None, f'duplicate key {key!r}', key_node.start_mark)
        seen.add(key)
    return yaml.SafeLoader.construct_mapping(loader, node, deep=deep)


_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


# --------------------------------------------------------------------------------------------
# validation helpers: every failure names the file and the key path
# --------------------------------------------------------------------------------------------
def _key(path: str, key) -> str:
    """Key path of ``key`` under ``path`` ('a.b', 'a[3]')."""
    if isinstance(key, int):
        return f'{path}[{key}]'
    return f'{path}.{key}' if path else str(key)


def _typename(v) -> str:
    return type(v).__name__ if v is not None else 'null'


class SceneContext:
    """Validation context: the file name, the gravity vector and the parts built so far.

    file: file name used in messages. Helpers raise :class:`SceneError` with the key path.
    """

    def __init__(self, file: str):
        self.file = file
        self.gravity = np.array([0.0, 0.0, -9.81])
        self.parts: list[Part] = []
        self.y0 = None  # the initial state, once known (command profiles are built after it)

    def fail(self, path: str, reason: str):
        """Raise ``SceneError('<file>: <path>: <reason>')``."""
        raise SceneError(f'{self.file}: {path or "(top level)"}: {reason}')

    def mapping(self, v, path: str, required=(), optional=()) -> dict:
        """Check that ``v`` is a mapping with all ``required`` keys and no keys outside both lists."""
        if not isinstance(v, dict):
            self.fail(path, f'expected a mapping, got {_typename(v)} {v!r}')
        allowed = tuple(required) + tuple(optional)
        for k in v:
            if k not in allowed:
                self.fail(_key(path, k), f'unknown key {k!r}; allowed keys here: {", ".join(allowed)}')
        for k in required:
            if k not in v:
                self.fail(_key(path, k), 'missing required key')
        return v

    def number(self, v, path: str, minimum=None, positive=False) -> float:
        """A finite real number (not a bool); ``minimum`` inclusive, ``positive`` strict."""
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.fail(path, f'expected a number, got {_typename(v)} {v!r}')
        x = float(v)
        if not math.isfinite(x):
            self.fail(path, f'expected a finite number, got {v!r}')
        if positive and x <= 0.0:
            self.fail(path, f'must be > 0, got {x!r}')
        if minimum is not None and x < minimum:
            self.fail(path, f'must be >= {minimum!r}, got {x!r}')
        return x

    def string(self, v, path: str) -> str:
        """A non-empty string."""
        if not isinstance(v, str) or not v:
            self.fail(path, f'expected a non-empty string, got {_typename(v)} {v!r}')
        return v

    def boolean(self, v, path: str) -> bool:
        """true or false."""
        if not isinstance(v, bool):
            self.fail(path, f'expected true or false, got {_typename(v)} {v!r}')
        return v

    def sequence(self, v, path: str, n: int | None = None, what: str = 'values') -> list:
        """A list, of length ``n`` when given."""
        if not isinstance(v, list):
            self.fail(path, f'expected a list, got {_typename(v)} {v!r}')
        if n is not None and len(v) != n:
            self.fail(path, f'expected {n} {what}, got {len(v)}')
        return v

    def vector(self, v, path: str, n: int | None = None, what: str = 'values', minimum=None) -> np.ndarray:
        """A list of ``n`` finite numbers as a float array."""
        self.sequence(v, path, n, what)
        return np.array([self.number(x, _key(path, i), minimum=minimum) for i, x in enumerate(v)], dtype=float)

    def names(self, v, path: str, n: int | None = None) -> list:
        """A list of distinct non-empty strings."""
        self.sequence(v, path, n, 'names')
        out = [self.string(x, _key(path, i)) for i, x in enumerate(v)]
        for i, x in enumerate(out):
            if x in out[:i]:
                self.fail(_key(path, i), f'duplicate name {x!r}')
        return out

    def inertia(self, v, path: str) -> np.ndarray:
        """Inertia (3, 3) from ``[[..],[..],[..]]`` or ``[ixx, iyy, izz, ixy, ixz, iyz]``.

        Only the form is checked here; symmetry, positive semi-definiteness and the triangle
        inequality are the model's checks (their errors are mapped back to this key path).
        """
        if isinstance(v, list) and len(v) == 6 and not any(isinstance(x, list) for x in v):
            ixx, iyy, izz, ixy, ixz, iyz = self.vector(v, path, 6)
            return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
        if isinstance(v, list) and len(v) == 3 and all(isinstance(r, list) for r in v):
            return np.array([self.vector(r, _key(path, i), 3) for i, r in enumerate(v)])
        self.fail(path, f'expected a 3x3 matrix or [ixx, iyy, izz, ixy, ixz, iyz], got {v!r}')

    def pose(self, v, path: str) -> np.ndarray:
        """Homogeneous transform (4, 4) from ``{xyz: (3,), rpy: (3,)}`` (URDF convention, both optional)."""
        self.mapping(v, path, optional=('xyz', 'rpy'))
        T = np.eye(4)
        T[:3, 3] = self.vector(v.get('xyz', [0.0, 0.0, 0.0]), _key(path, 'xyz'), 3)
        T[:3, :3] = rpy_to_R(self.vector(v.get('rpy', [0.0, 0.0, 0.0]), _key(path, 'rpy'), 3))
        return T

    def limits(self, v, path: str) -> tuple:
        """Joint limits ``[lo, hi]`` with lo < hi."""
        lo, hi = self.vector(v, path, 2, 'values [lower, upper]')
        if not lo < hi:
            self.fail(path, f'lower limit {lo!r} must be below upper limit {hi!r}')
        return (lo, hi)


# --------------------------------------------------------------------------------------------
# parts
# --------------------------------------------------------------------------------------------
_DH_ROW_REQUIRED = ('type', 'a', 'alpha', 'd', 'theta', 'mass')
_DH_ROW_OPTIONAL = ('com', 'inertia', 'damping', 'limits', 'effort_limit')
_LINK_REQUIRED = ('name', 'joint', 'parent', 'type')
_LINK_OPTIONAL = ('origin', 'axis', 'mass', 'com', 'inertia', 'damping', 'limits', 'effort_limit')
_LIMIT_KEYS = ('lower', 'upper', 'stiffness', 'damping', 'return')
_ARM_REQUIRED = ('kind', 'name')
_ARM_OPTIONAL = ('mount', 'origin', 'root', 'dh', 'tool', 'links', 'link_names', 'joint_names', 'actuated')
#: ModelError wording -> the link key it is about (for mapping model errors to key paths)
_MODEL_ERROR_KEYS = (('limit', 'limits'), ('parent', 'parent'), ('mass', 'mass'), ('inertia', 'inertia'),
                     ('principal moments', 'inertia'), ('axis', 'axis'), ('damping', 'damping'),
                     ('origin', 'origin'), ('joint type', 'type'), ('duplicate link name', 'name'))


def _joint_limits(ctx: SceneContext, v, path: str, spherical: bool = False) -> dict:
    """LinkSpec limit fields from ``[lo, hi]`` (reported only) or ``{lower, upper, stiffness, damping,
    return}`` (eq. 20.2.1 moments; a spherical joint's lower/upper are 3-vectors)."""
    if not isinstance(v, dict):
        if spherical:
            ctx.fail(path, 'a spherical joint takes limits: {lower: [3], upper: [3], stiffness, damping, return}')
        return {'limits': ctx.limits(v, path)}
    ctx.mapping(v, path, required=('lower', 'upper'), optional=_LIMIT_KEYS[2:])
    if spherical:
        def vec(k):
            if not isinstance(v[k], list) or len(v[k]) != 3:
                ctx.fail(_key(path, k), f'expected 3 values (one per rotation-vector component), got {v[k]!r}')
            out = []
            for i, x in enumerate(v[k]):
                if isinstance(x, float) and math.isinf(x):
                    out.append(x)
                else:
                    out.append(ctx.number(x, _key(_key(path, k), i)))
            return out
        lo, hi = vec('lower'), vec('upper')
        for i in range(3):
            if not lo[i] < hi[i]:
                ctx.fail(_key(_key(path, 'lower'), i), f'lower limit {lo[i]!r} must be below upper limit {hi[i]!r}')
        lim = tuple(zip(lo, hi))
    else:
        lim = ctx.limits([v['lower'], v['upper']], path)
    return {'limits': lim, **_limit_law(ctx, v, path)}


def _limit_law(ctx: SceneContext, v: dict, path: str) -> dict:
    """LinkSpec fields of the eq. 20.2.1 law from a limits mapping's ``stiffness``, ``damping``,
    ``return`` (a link's ``limits`` and a URDF part's ``position_limits``)."""
    from .model import LIMIT_RETURNS
    ret = ctx.string(v.get('return', 'spring'), _key(path, 'return'))
    if ret not in LIMIT_RETURNS:
        ctx.fail(_key(path, 'return'), f'unknown return mode {ret!r}; use {" or ".join(LIMIT_RETURNS)}')
    return {'limit_return': ret,
            'limit_stiffness': ctx.number(v.get('stiffness', 0.0), _key(path, 'stiffness'), minimum=0.0),
            'limit_damping': ctx.number(v.get('damping', 0.0), _key(path, 'damping'), minimum=0.0)}


def _inertial(ctx: SceneContext, row: dict, path: str, spherical: bool = False) -> dict:
    """Mass, com, inertia, damping, limits of a link mapping (shared by DH and explicit links)."""
    out = {}
    if 'mass' in row:
        m = ctx.number(row['mass'], _key(path, 'mass'))
        if m < 0.0:
            ctx.fail(_key(path, 'mass'), f'negative mass {m!r} kg; a mass must be >= 0')
        out['mass'] = m
    if 'com' in row:
        out['com'] = ctx.vector(row['com'], _key(path, 'com'), 3)
    if 'inertia' in row:
        out['inertia'] = ctx.inertia(row['inertia'], _key(path, 'inertia'))
    if 'damping' in row:
        out['damping'] = ctx.number(row['damping'], _key(path, 'damping'), minimum=0.0)
    if 'limits' in row:
        out.update(_joint_limits(ctx, row['limits'], _key(path, 'limits'), spherical))
    if 'effort_limit' in row:  # actuator limit: commands are clamped to ±effort_limit (and counted)
        out['effort_limit'] = ctx.number(row['effort_limit'], _key(path, 'effort_limit'), positive=True)
    return out


def _joint_type(ctx: SceneContext, v, path: str, allowed) -> str:
    jt = ctx.string(v, path)
    if jt not in allowed:
        known = f'; the model also knows {sorted(set(JOINT_TYPES) - set(allowed))} but not in an arm part' \
            if jt in JOINT_TYPES else ''
        ctx.fail(path, f'unknown joint type {jt!r}; valid types here: {", ".join(allowed)}{known}')
    return jt


def _dh_specs(ctx: SceneContext, spec: dict, path: str, root: str):
    """LinkSpecs and per-link key paths of an arm given by a DH table."""
    dh = ctx.mapping(spec['dh'], _key(path, 'dh'), required=('convention', 'links'))
    dpath = _key(path, 'dh')
    convention = ctx.string(dh['convention'], _key(dpath, 'convention'))
    if convention not in ('standard', 'modified'):
        ctx.fail(_key(dpath, 'convention'), f'unknown DH convention {convention!r}; use standard or modified')
    rows_in = ctx.sequence(dh['links'], _key(dpath, 'links'))
    if not rows_in:
        ctx.fail(_key(dpath, 'links'), 'a DH table needs at least one link')
    rows, paths = [], []
    for i, r in enumerate(rows_in):
        rp = _key(_key(dpath, 'links'), i)
        ctx.mapping(r, rp, required=_DH_ROW_REQUIRED, optional=_DH_ROW_OPTIONAL)
        row = {'type': _joint_type(ctx, r['type'], _key(rp, 'type'), ('revolute', 'prismatic'))}
        for k in ('a', 'alpha', 'd', 'theta'):
            row[k] = ctx.number(r[k], _key(rp, k))
        row.update(_inertial(ctx, r, rp))
        rows.append(row)
        paths.append(rp)
    n = len(rows)
    lnames = ctx.names(spec['link_names'], _key(path, 'link_names'), n) if 'link_names' in spec else \
        [f'link{i + 1}' for i in range(n)]
    jnames = ctx.names(spec['joint_names'], _key(path, 'joint_names'), n) if 'joint_names' in spec else \
        [f'joint{i + 1}' for i in range(n)]
    tool = ctx.boolean(spec['tool'], _key(path, 'tool')) if 'tool' in spec else convention == 'standard'
    if tool and convention != 'standard':
        ctx.fail(_key(path, 'tool'), 'the tool frame is only defined for standard DH (it is DH frame n)')
    specs = dh_links(rows, convention=convention, names=list(zip(lnames, jnames)), root=root, tool=tool)
    for sp, row in zip(specs, rows):   # eq. 20.2.1 limit moments of a limits mapping
        for k in ('limit_stiffness', 'limit_damping', 'limit_return'):
            if k in row:
                setattr(sp, k, row[k])
    if tool:
        if 'tool' in lnames or 'tool_joint' in jnames:
            ctx.fail(_key(path, 'link_names'), "'tool'/'tool_joint' are reserved for the standard-DH tool frame")
        paths.append(_key(path, 'tool'))
    return specs, paths


def _explicit_specs(ctx: SceneContext, spec: dict, path: str, root: str, free: bool = False):
    """LinkSpecs and per-link key paths of an arm given by explicit (URDF-like) links."""
    for k in ('link_names', 'joint_names', 'tool'):
        if k in spec:
            ctx.fail(_key(path, k), f"'{k}' applies to a 'dh' table only; explicit links carry their names")
    lpath = _key(path, 'links')
    items = ctx.sequence(spec['links'], lpath)
    if not items:
        ctx.fail(lpath, 'an arm needs at least one link')
    specs, paths = [], []
    for i, r in enumerate(items):
        rp = _key(lpath, i)
        ctx.mapping(r, rp, required=_LINK_REQUIRED, optional=_LINK_OPTIONAL)
        jt = _joint_type(ctx, r['type'], _key(rp, 'type'), ('revolute', 'prismatic', 'fixed', 'planar', 'spherical',
                                                             'free'))
        T = ctx.pose(r['origin'], _key(rp, 'origin')) if 'origin' in r else np.eye(4)
        axis = ctx.vector(r['axis'], _key(rp, 'axis'), 3) if 'axis' in r else np.array([0.0, 0.0, 1.0])
        if jt in ('fixed', 'planar') and any(k in r for k in ('axis', 'limits', 'damping', 'effort_limit')):
            ctx.fail(rp, f'a {jt} joint takes no axis, limits, damping or effort_limit')
        if jt == 'spherical' and 'axis' in r:
            ctx.fail(_key(rp, 'axis'), 'a spherical joint has no axis')
        parent = ctx.string(r['parent'], _key(rp, 'parent'))
        if jt == 'free' and (not free or parent != root):
            ctx.fail(_key(rp, 'type'), f"a free joint joins the tree's root link to the root frame {root!r} of an arm "
                                       "with mount: free")
        if jt == 'free' and any(k in r for k in ('origin', 'axis', 'limits', 'damping')):
            ctx.fail(rp, 'a free joint takes no origin, axis, limits or damping (its pose is in q)')
        inert = _inertial(ctx, r, rp, spherical=jt == 'spherical')
        specs.append(LinkSpec(name=ctx.string(r['name'], _key(rp, 'name')),
                              joint=ctx.string(r['joint'], _key(rp, 'joint')), parent=parent,
                              joint_type=jt, origin_xyz=tuple(T[:3, 3]), origin_R=T[:3, :3],
                              origin_rpy=tuple(R_to_rpy(T[:3, :3])), axis=tuple(axis),
                              mass=inert.get('mass', 0.0), com=tuple(inert.get('com', np.zeros(3))),
                              inertia=inert.get('inertia', np.zeros((3, 3))),
                              damping=inert.get('damping', 0.0), limits=inert.get('limits'),
                              effort_limit=inert.get('effort_limit'),
                              **{k: inert[k] for k in ('limit_stiffness', 'limit_damping', 'limit_return')
                                 if k in inert}))
        paths.append(rp)
    if free and sum(s.joint_type == 'free' for s in specs) != 1:
        ctx.fail(lpath, f"mount: free needs exactly one link with type: free and parent: {root}")
    return specs, paths


def _model_error_path(err: ModelError, specs, paths, fallback: str) -> str:
    """Key path a ModelError is about: the link it names plus the key its wording points to."""
    m = re.match(r"link '([^']+)'", str(err))
    if not m:
        return fallback
    index = {s.name: k for k, s in enumerate(specs)}
    k = index.get(m.group(1))
    if k is None:
        return fallback
    text = str(err)[m.end():]
    for word, key in _MODEL_ERROR_KEYS:
        if word in text:
            return _key(paths[k], key)
    return paths[k]


def build_arm_part(spec: dict, path: str, ctx: SceneContext, specs=None) -> Part:
    """Build an ``arm`` part: a kinematic tree from a DH table or explicit links -> ArmSystem.

    spec: the part mapping (see the module docstring for its keys); path: its key path
    ('parts[0]'); ctx: validation context (file name, gravity). Model errors are re-raised as
    :class:`SceneError` with the key path of the offending link.
    """
    ctx.mapping(spec, path, required=_ARM_REQUIRED, optional=_ARM_OPTIONAL)
    name = ctx.string(spec['name'], _key(path, 'name'))
    mount = ctx.string(spec.get('mount', 'world'), _key(path, 'mount'))
    free = mount == 'free'
    root = ctx.string(spec.get('root', 'odom' if free else 'base_link'), _key(path, 'root'))
    if specs is not None:  # built elsewhere (an imported URDF): (LinkSpecs, key paths)
        specs, paths = specs
    elif ('dh' in spec) == ('links' in spec):
        ctx.fail(path, "give exactly one of 'dh' (a DH table) or 'links' (explicit links)")
    elif 'dh' in spec:
        if free:
            ctx.fail(_key(path, 'mount'), "mount: free needs explicit 'links' (one of them with type: free)")
        specs, paths = _dh_specs(ctx, spec, path, root)
    else:
        specs, paths = _explicit_specs(ctx, spec, path, root, free)
    if 'origin' in spec:  # the mount pose: compose it into the joints that hang from the root
        T0 = ctx.pose(spec['origin'], _key(path, 'origin'))
        for s in specs:
            if s.parent in (None, root):
                T = np.eye(4)
                T[:3, :3] = s.origin_R if s.origin_R is not None else rpy_to_R(s.origin_rpy)
                T[:3, 3] = s.origin_xyz
                T = T0 @ T
                s.origin_R, s.origin_xyz, s.origin_rpy = T[:3, :3], tuple(T[:3, 3]), tuple(R_to_rpy(T[:3, :3]))
    try:
        model = build_model(specs, gravity=ctx.gravity, name=name, root=root)
    except ModelError as e:
        ctx.fail(_model_error_path(e, specs, paths, path), str(e))
    planar = planar_root(model) is not None
    actuated = _actuated(ctx, spec, path, model, planar=planar)
    try:
        if planar:  # a tree in free flight in the x-z plane (systems.planar)
            from .systems.planar import PlanarBaseSystem
            system = PlanarBaseSystem(model, actuated=actuated)
        else:
            system = ArmSystem(model, actuated=actuated)
    except ValueError as e:   # e.g. spherical joints on the numpy backend
        ctx.fail(path, str(e))
    return Part(name=name, kind='arm', mount=mount, system=system, path=path)


def _actuated(ctx: SceneContext, spec: dict, path: str, model, planar: bool = False):
    """The part's ``actuated`` joint names, each a 1-DOF joint or a spherical joint component of
    ``model`` (not a planar root joint when ``planar``); None when not given."""
    if 'actuated' not in spec:
        return None
    dof = list(model.state_joint_names)[3:] if planar else list(model.state_joint_names)
    apath = _key(path, 'actuated')
    actuated = ctx.names(spec['actuated'], apath)
    for i, j in enumerate(actuated):
        if j not in dof:
            ctx.fail(_key(apath, i), f'{j!r} is not a 1-DOF joint (or a spherical joint component) of this arm; '
                                     f'joints are {dof}' + (' (the planar root joints are never actuated)' if planar else ''))
    return actuated


_PRESCRIBED_KEYS = ('end_effector', 'end_effector_path', 'formulation', 'baumgarte')


def build_prescribed_arm_part(spec: dict, path: str, ctx: SceneContext) -> Part:
    """Build a ``prescribed_arm`` part: an arm whose end point E is driven along a planar path.

    Huston §19.16–19.18 (see :mod:`robodyn_ros.systems.prescribed`). The keys of an ``arm``
    part plus: ``end_effector`` (link whose frame origin is E; default the last link),
    ``end_effector_path: {kind: circle | line, plane: xy | xz | yz, <kind parameters>}``,
    ``formulation: complement | kkt`` (default complement) and ``baumgarte: {alpha, beta}``
    (1/s). ``actuated`` defaults to none here (free pins, problem P19.16.1).
    """
    from .systems import prescribed as pr
    ctx.mapping(spec, path, required=_ARM_REQUIRED + ('end_effector_path',),
                optional=_ARM_OPTIONAL + _PRESCRIBED_KEYS)
    arm = build_arm_part({**{k: v for k, v in spec.items() if k not in _PRESCRIBED_KEYS},
                          'kind': 'arm', 'actuated': spec.get('actuated', [])}, path, ctx)
    model = arm.system.model
    eff = ctx.string(spec.get('end_effector', model.link_names[-1]), _key(path, 'end_effector'))
    if eff not in model.link_names:
        ctx.fail(_key(path, 'end_effector'), f'no link {eff!r}; links are {list(model.link_names)}')
    ppath = _key(path, 'end_effector_path')
    ps = spec['end_effector_path']
    if not isinstance(ps, dict) or 'kind' not in ps:
        ctx.fail(_key(ppath, 'kind'), f'missing required key; kinds: {", ".join(pr.PATH_KINDS)}')
    kind = ctx.string(ps['kind'], _key(ppath, 'kind'))
    if kind not in pr.PATH_KINDS:
        ctx.fail(_key(ppath, 'kind'), f'unknown path kind {kind!r}; kinds: {", ".join(pr.PATH_KINDS)}')
    cls, req, opt = pr.PATH_KINDS[kind]
    ctx.mapping(ps, ppath, required=('kind',) + tuple(req), optional=('plane',) + tuple(opt))
    params = {k: (ctx.vector(ps[k], _key(ppath, k), n) if n else ctx.number(ps[k], _key(ppath, k)))
              for k, n in {**req, **opt}.items() if k in ps}
    plane = ctx.string(ps.get('plane', 'xy'), _key(ppath, 'plane'))
    if plane not in pr.PLANES:
        ctx.fail(_key(ppath, 'plane'), f'unknown plane {plane!r}; planes: {", ".join(pr.PLANES)}')
    try:
        curve = cls(**params)
    except pr.PathError as e:
        ctx.fail(_key(ppath, e.param), e.reason)
    form = ctx.string(spec.get('formulation', 'complement'), _key(path, 'formulation'))
    if form not in pr.FORMULATIONS:
        ctx.fail(_key(path, 'formulation'), f'unknown formulation {form!r}; use {" or ".join(pr.FORMULATIONS)}')
    bpath = _key(path, 'baumgarte')
    gains = ctx.mapping(spec.get('baumgarte', {}), bpath, optional=('alpha', 'beta'))
    gains = {k: ctx.number(x, _key(bpath, k), minimum=0.0) for k, x in gains.items()}
    system = pr.PrescribedPathSystem(model, eff, curve, plane=plane, formulation=form,
                                     actuated=arm.system.actuated, **gains)
    return Part(name=arm.name, kind='prescribed_arm', mount=arm.mount, system=system, path=path)


_FREE_BASE_REQUIRED = ('kind', 'name', 'environment', 'mass', 'inertia')
_FREE_BASE_OPTIONAL = ('link', 'joint', 'com', 'formulation', 'table_height', 'stabilisation')


def build_free_base_part(spec: dict, path: str, ctx: SceneContext) -> Part:
    """Build a ``free_base`` part: a 6-DOF platform (seed 003), alone or carrying arms mounted on it.

    Keys: ``environment: orbit | air_bearing_table | free_fall`` (orbit needs ``gravity: [0, 0,
    0]``, the table gravity along -z; free_fall: any gravity, no contact); ``mass`` (kg), ``com`` (3,) m and ``inertia`` about the com
    (base_link axes); ``link`` (default base_link), ``joint`` (the free joint, default
    base_joint); ``formulation: minimal | augmented`` (default minimal); ``table_height`` (m,
    default the initial height); ``stabilisation: {method: baumgarte | projection | none,
    alpha, beta}`` (1/s). An arm part with ``mount: <this part's name>`` hangs from ``link``.
    """
    from .systems import freeflyer as ff
    from .systems.augmented import AugmentedFreeFlyerSystem
    ctx.mapping(spec, path, required=_FREE_BASE_REQUIRED, optional=_FREE_BASE_OPTIONAL)
    name = ctx.string(spec['name'], _key(path, 'name'))
    env = ctx.string(spec['environment'], _key(path, 'environment'))
    if env not in ff.ENVIRONMENTS:
        ctx.fail(_key(path, 'environment'), f'unknown environment {env!r}; use {" or ".join(ff.ENVIRONMENTS)}')
    if env == 'orbit' and np.any(ctx.gravity != 0.0):
        ctx.fail('gravity', f'environment orbit needs gravity: [0, 0, 0], got {ctx.gravity.tolist()}')
    if env == 'air_bearing_table' and not (ctx.gravity[2] < 0.0 and np.allclose(ctx.gravity[:2], 0.0)):
        ctx.fail('gravity', f'the air-bearing table is horizontal: gravity must point along -z, got {ctx.gravity.tolist()}')
    form = ctx.string(spec.get('formulation', 'minimal'), _key(path, 'formulation'))
    if form not in ff.FORMULATIONS:
        ctx.fail(_key(path, 'formulation'), f'unknown formulation {form!r}; use {" or ".join(ff.FORMULATIONS)}')
    inert = _inertial(ctx, {k: spec[k] for k in ('mass', 'com', 'inertia') if k in spec}, path)
    spath = _key(path, 'stabilisation')
    st = ctx.mapping(spec.get('stabilisation', {}), spath, optional=('method', 'alpha', 'beta'))
    method = ctx.string(st.get('method', 'baumgarte'), _key(spath, 'method'))
    if method not in ff.STABILISATIONS:
        ctx.fail(_key(spath, 'method'), f'unknown method {method!r}; use {", ".join(ff.STABILISATIONS)}')
    opts = {k: ctx.number(st[k], _key(spath, k), minimum=0.0) for k in ('alpha', 'beta') if k in st}
    if 'table_height' in spec:
        if env != 'air_bearing_table':
            ctx.fail(_key(path, 'table_height'), 'only an air_bearing_table environment has a table height')
        opts['table_height'] = ctx.number(spec['table_height'], _key(path, 'table_height'))
    base = LinkSpec(name=ctx.string(spec.get('link', 'base_link'), _key(path, 'link')),
                    joint=ctx.string(spec.get('joint', 'base_joint'), _key(path, 'joint')), parent=None,
                    joint_type='free', mass=inert['mass'], com=tuple(inert.get('com', np.zeros(3))),
                    inertia=inert['inertia'])
    cls = AugmentedFreeFlyerSystem if form == 'augmented' else ff.FreeFlyerSystem
    try:
        model = ff.free_flyer_model(base, [], gravity=ctx.gravity, name=name)
        system = cls(model, environment=env, stabilisation=method, **opts)
    except (ModelError, ValueError) as e:
        ctx.fail(path, str(e))
    return Part(name=name, kind='free_base', mount='world', system=system, path=path)


def _refuse_limit_moments(ctx: SceneContext, part, host: str):
    """Joint-limit moments act in :class:`ArmSystem` only (fixed or free root): refuse them on an
    arm that rides on a ``free_base`` or ``diff_drive`` platform rather than drop them silently."""
    bad = [s.joint for s in part.system.model.specs if s.limit_stiffness or s.limit_damping]
    if bad:
        ctx.fail(part.path, f'joint {bad[0]!r}: joint-limit moments (limits with stiffness/damping, URDF '
                            f'position_limits) are not computed for an arm on a {host} platform; give limits: '
                            '[lower, upper] (reported only), or mount the arm on the world (or mount: free)')


def _assemble_free_base(ctx: SceneContext, parts: list):
    """A free base and the arm parts mounted on it -> one free-flyer system."""
    bases = [p for p in parts if p.kind == 'free_base']
    if len(bases) != 1:
        ctx.fail(_key(bases[1].path, 'kind'), 'a scene can have one free_base part')
    fb = bases[0]
    arms = [p for p in parts if p is not fb]
    link = fb.system.base_link
    specs, actuated = [], []
    for p in arms:
        if p.kind != 'arm' or p.mount != fb.name:
            ctx.fail(_key(p.path, 'mount'), f"with a free_base part every other part must be an 'arm' with "
                                             f"mount: {fb.name}")
        if p.system.model.root != link:
            ctx.fail(_key(p.path, 'root'), f'the arm must hang from the free base link {link!r}, '
                                            f'its root is {p.system.model.root!r}')
        _refuse_limit_moments(ctx, p, 'free_base')
        specs += list(p.system.model.specs)
        actuated += list(p.system.actuated)
    try:
        return fb.system.with_arm(specs, actuated=actuated) if arms else fb.system
    except (ModelError, ValueError) as e:
        ctx.fail(fb.path, str(e))


#: part kind -> builder(spec, path, ctx) -> Part
PART_KINDS: dict[str, Callable] = {'arm': build_arm_part, 'prescribed_arm': build_prescribed_arm_part,
                                   'free_base': build_free_base_part}


_URDF_KEYS = ('kind', 'name', 'file', 'urdf', 'mount', 'origin', 'floating', 'locked', 'actuated', 'position_limits')


def _urdf_position_limits(ctx: SceneContext, v, path: str, specs) -> list:
    """``position_limits: {stiffness, damping, return}``: the eq. 20.2.1 joint-limit moments on every
    joint with URDF ``<limit lower upper>`` (revolute, prismatic; continuous and locked joints have none)."""
    ctx.mapping(v, path, optional=_LIMIT_KEYS[2:])
    law = _limit_law(ctx, v, path)
    return [replace(s, **law) if s.limits is not None and s.joint_type in ('revolute', 'prismatic') else s
            for s in specs]


def build_urdf_part(spec: dict, path: str, ctx: SceneContext) -> Part:
    """Build a ``urdf`` part: a robot description imported by :func:`robodyn_ros.urdf.read_urdf`.

    Keys: ``file`` (path, relative to the scene file) or ``urdf`` (inline URDF text), exactly
    one; ``mount: world | <diff_drive part> | <free_base part>`` (default world; the URDF's root
    link is then the frame it hangs from, placed by ``origin``); ``floating`` (default false:
    the root link is welded to the mount; true: it is a free 6-DOF base in the scene's gravity,
    environment ``free_fall`` — no ground contact — or ``orbit`` with zero gravity);
    ``locked: {joint: position}`` freezes joints (gripper fingers, ``<mimic>`` joints);
    ``actuated`` as for an arm (default every 1-DOF joint); ``position_limits: {stiffness,
    damping, return}`` (optional; absent = URDF position limits reported only) enforces every
    joint's ``<limit lower upper>`` with the joint-limit moments of Huston eq. (20.2.1), as a
    ``limits`` mapping does for an arm link (world-mounted, non-floating robots). The part is an
    arm (its kind is ``arm`` once built) so it mounts wherever an arm does.
    """
    from .urdf import UrdfError, read_urdf
    ctx.mapping(spec, path, required=('kind', 'name'), optional=_URDF_KEYS)
    name = ctx.string(spec['name'], _key(path, 'name'))
    mount = ctx.string(spec.get('mount', 'world'), _key(path, 'mount'))
    floating = ctx.boolean(spec.get('floating', False), _key(path, 'floating'))
    if ('file' in spec) == ('urdf' in spec):
        ctx.fail(path, "give exactly one of 'file' (a URDF file) or 'urdf' (the URDF text)")
    if 'file' in spec:
        src = Path(ctx.string(spec['file'], _key(path, 'file')))
        if not src.is_absolute():
            base = Path(ctx.file).parent if Path(ctx.file).is_file() else Path.cwd()
            src = base / src
        if not src.is_file():
            ctx.fail(_key(path, 'file'), f'no such URDF file {str(src)!r} (relative paths start at the scene file)')
        where = _key(path, 'file')
    else:
        src = ctx.string(spec['urdf'], _key(path, 'urdf'))
        where = _key(path, 'urdf')
    lpath = _key(path, 'locked')
    given = spec.get('locked', {})
    if not isinstance(given, dict):
        ctx.fail(lpath, f'expected a mapping joint: position, got {_typename(given)} {given!r}')
    locked = {k: ctx.number(v, _key(lpath, k)) for k, v in given.items()}
    try:
        robot = read_urdf(src, floating=floating, locked=locked)
    except UrdfError as e:
        m = re.match(r"locked joint '([^']+)'", str(e))
        ctx.fail(_key(lpath, m.group(1)) if m else where, str(e))
    specs = robot.specs
    if floating and (mount != 'world' or 'origin' in spec):
        ctx.fail(_key(path, 'floating'), 'a floating URDF base stands on its own: no mount or origin')
    if any(s.friction > 0.0 for s in specs) and (floating or mount != 'world'):
        j = next(s.joint for s in specs if s.friction > 0.0)
        ctx.fail(where, f"joint {j!r}: Coulomb <dynamics friction> is supported for a URDF mounted on the world "
                        "only (set friction=\"0\" or mount: world)")
    if 'position_limits' in spec:
        ppath = _key(path, 'position_limits')
        if floating or mount != 'world':
            ctx.fail(ppath, 'joint-limit moments are supported for a URDF mounted on the world only '
                            '(not floating, not on a platform); remove position_limits or use mount: world')
        specs = _urdf_position_limits(ctx, spec['position_limits'], ppath, specs)
    if floating:
        from .systems import freeflyer as ff
        env = 'orbit' if not np.any(ctx.gravity) else 'free_fall'
        try:
            model = ff.free_flyer_model(specs[0], specs[1:], gravity=ctx.gravity, name=name)
        except ModelError as e:
            ctx.fail(where, str(e))
        system = ff.FreeFlyerSystem(model, actuated=_actuated(ctx, spec, path, model), environment=env)
        return Part(name=name, kind='free_base', mount='world', system=system, path=path)
    root = robot.root
    host = next((p for p in ctx.parts if p.name == mount and p.kind == 'free_base'), None)
    if host is not None:  # hang from the free base's link
        specs = [replace(s, parent=host.system.base_link) if s.parent == root else s for s in specs]
        root = host.system.base_link
    arm_spec = {'kind': 'arm', 'name': name, 'mount': mount, 'root': root,
                **{k: spec[k] for k in ('origin', 'actuated') if k in spec}}
    return build_arm_part(arm_spec, path, ctx, specs=(specs, [where] * len(specs)))


_MOTOR_KEYS = ('kind', 'torque_constant', 'resistance', 'inductance', 'gear_ratio', 'rotor_inertia',
               'viscous_friction', 'coulomb_friction', 'coulomb_velocity', 'supply_voltage')
_WHEEL_KEYS = {'radius': 'wheel_radius', 'half_track': 'half_track', 'mass': 'wheel_mass',
               'spin_inertia': 'wheel_spin_inertia', 'diametral_inertia': 'wheel_diametral_inertia'}


def _dc_motor(ctx: SceneContext, spec, path: str):
    """A :class:`~robodyn_ros.systems.motor.DCMotor` from a ``dc_motor`` mapping."""
    from .systems.motor import DCMotor
    ctx.mapping(spec, path, required=('torque_constant', 'resistance'), optional=_MOTOR_KEYS)
    if ctx.string(spec.get('kind', 'dc_motor'), _key(path, 'kind')) != 'dc_motor':
        ctx.fail(_key(path, 'kind'), f"unknown motor kind {spec['kind']!r}; known kinds: dc_motor")
    kw = {}
    for k in _MOTOR_KEYS[1:]:
        if k in spec:
            strict = k in ('torque_constant', 'resistance', 'gear_ratio', 'coulomb_velocity', 'supply_voltage')
            kw[k] = ctx.number(spec[k], _key(path, k), positive=strict, minimum=None if strict else 0.0)
    return DCMotor(**kw)


def build_diff_drive_part(spec: dict, path: str, ctx: SceneContext) -> Part:
    """Build a ``diff_drive`` part: chassis, two wheels, two DC motors (module docstring schema).

    Physically inconsistent values (a wheel spin inertia above m r², a diametral inertia that
    breaks the triangle inequality, ...) are refused with the key path of the offending value.
    """
    from .systems import diffdrive as dd
    ctx.mapping(spec, path, required=('kind', 'name', 'chassis', 'wheels'),
                optional=('mount', 'payload', 'motor', 'motors', 'baumgarte_alpha'))
    name = ctx.string(spec['name'], _key(path, 'name'))
    mount = ctx.string(spec.get('mount', 'world'), _key(path, 'mount'))
    if mount != 'world':
        ctx.fail(_key(path, 'mount'), f"a diff_drive platform stands on the ground: mount must be 'world', "
                                      f"got {mount!r}")

    def body(key):
        bp = _key(path, key)
        b = ctx.mapping(spec[key], bp, required=('mass', 'yaw_inertia'), optional=('com',))
        com = ctx.vector(b['com'], _key(bp, 'com'), 3) if 'com' in b else np.zeros(3)
        return dd.Body(ctx.number(b['mass'], _key(bp, 'mass'), minimum=0.0),
                       ctx.number(b['yaw_inertia'], _key(bp, 'yaw_inertia'), minimum=0.0), tuple(com))
    wpath = _key(path, 'wheels')
    wh = ctx.mapping(spec['wheels'], wpath, required=('radius', 'half_track', 'mass', 'spin_inertia'),
                     optional=('diametral_inertia',))
    kw = {field_: ctx.number(wh[k], _key(wpath, k), positive=k in ('radius', 'half_track'), minimum=0.0)
          for k, field_ in _WHEEL_KEYS.items() if k in wh}
    if ('motor' in spec) == ('motors' in spec):
        ctx.fail(path, "give exactly one of 'motor' (the same DC motor on both wheels) or "
                       "'motors: {left: .., right: ..}'")
    if 'motor' in spec:
        motors = (_dc_motor(ctx, spec['motor'], _key(path, 'motor')),) * 2
    else:
        mp = _key(path, 'motors')
        ms = ctx.mapping(spec['motors'], mp, required=('left', 'right'))
        motors = tuple(_dc_motor(ctx, ms[s], _key(mp, s)) for s in ('left', 'right'))
    if 'baumgarte_alpha' in spec:
        kw['baumgarte_alpha'] = ctx.number(spec['baumgarte_alpha'], _key(path, 'baumgarte_alpha'), minimum=0.0)
    chassis = body('chassis')
    if chassis.mass <= 0.0 or chassis.yaw_inertia <= 0.0:
        ctx.fail(_key(path, 'chassis'), 'the chassis needs a mass and a yaw inertia > 0')
    try:
        params = dd.PlatformParams(chassis=chassis, payload=body('payload') if 'payload' in spec else None,
                                   motors=motors, **kw)
    except ValueError as e:
        field_ = str(e).split(':', 1)[0]
        keys = {v: _key(wpath, k) for k, v in _WHEEL_KEYS.items()}
        ctx.fail(keys.get(field_, path), str(e))
    system = dd.DiffDriveSystem(params, gravity=ctx.gravity, name=name)
    return Part(name=name, kind='diff_drive', mount=mount, system=system, path=path)


def _assemble_diff_drive(ctx: SceneContext, parts: list):
    """A platform alone, or the mobile manipulator: one arm mounted on the platform."""
    from .systems.diffdrive import DiffDriveSystem
    drives = [p for p in parts if p.kind == 'diff_drive']
    if len(drives) > 1:
        ctx.fail(_key(drives[1].path, 'kind'), 'a scene holds one diff_drive platform')
    drive = drives[0]
    others = [p for p in parts if p is not drive]
    for p in others:
        if p.mount != drive.name:
            ctx.fail(_key(p.path, 'mount'), f"{p.kind} part {p.name!r} must be mounted on the platform: "
                                            f"mount: {drive.name} (got {p.mount!r}; independent systems in one "
                                            "scene are not supported)")
        if p.kind != 'arm':
            ctx.fail(_key(p.path, 'kind'), f"a {p.kind!r} part cannot ride on a diff_drive platform; use 'arm'")
    if len(others) > 1:
        ctx.fail(_key(others[1].path, 'mount'), 'one arm per platform')
    if not others:
        return drive.system
    arm = others[0]
    _refuse_limit_moments(ctx, arm, 'diff_drive')
    am = arm.system.model
    try:
        return DiffDriveSystem(drive.system.params, arm_specs=list(am.specs), arm_root=am.root,
                               arm_actuated=arm.system.actuated, gravity=ctx.gravity, name=drive.name)
    except (ModelError, ValueError) as e:
        ctx.fail(arm.path, f'cannot mount it on {drive.name!r}: {e}')


PART_KINDS['diff_drive'] = build_diff_drive_part
PART_KINDS['urdf'] = build_urdf_part


def build_kinematic_arm_part(spec: dict, path: str, ctx: SceneContext) -> Part:
    """Build a ``kinematic_arm`` part: an arm whose 1-DOF joints follow functions of time.

    The keys of an ``arm`` part (``dh`` or ``links``; no ``actuated``: every joint is driven)
    plus ``motion: {<joint>: <expression of t>, ...}`` for every 1-DOF joint, written with the
    whitelist of :mod:`robodyn_ros.expressions` (e.g. ``pi/3 + t``). The system
    (:mod:`robodyn_ros.systems.kinematic`) publishes the inverse-dynamics efforts that make the
    arm follow the motion. A parameter that varies in time but is not a joint variable (Betancur's
    DH twist alpha_2(t)) is written as an extra driven joint with a massless child frame.
    """
    from .expressions import ExpressionError, parse_time_function
    from .systems.kinematic import KinematicArmSystem
    ctx.mapping(spec, path, required=_ARM_REQUIRED + ('motion',),
                optional=tuple(k for k in _ARM_OPTIONAL if k != 'actuated'))
    from .systems.base import backend_scope, default_backend
    backend = default_backend()
    with backend_scope('numpy'):  # only the validated model is kept: no compiled arm kernels for it
        arm = build_arm_part({**{k: v for k, v in spec.items() if k != 'motion'}, 'kind': 'arm'}, path, ctx)
    model = arm.system.model
    mpath = _key(path, 'motion')
    mot = ctx.mapping(spec['motion'], mpath, optional=tuple(model.dof_joint_names))
    motion = {}
    for j in model.dof_joint_names:
        if j not in mot:
            ctx.fail(_key(mpath, j), f'missing: every 1-DOF joint needs its motion; joints are {model.dof_joint_names}')
        try:
            f = parse_time_function(mot[j])
        except ExpressionError as e:
            ctx.fail(_key(mpath, j), str(e))
        with np.errstate(all='ignore'):
            if not np.all(np.isfinite(f.jet(0.0))):
                ctx.fail(_key(mpath, j), f'{f.text!r} or its derivatives are not finite at t = 0')
        motion[j] = f
    try:
        system = KinematicArmSystem(model, motion, backend=backend)
    except ValueError as e:
        ctx.fail(path, str(e))
    return Part(name=arm.name, kind='kinematic_arm', mount=arm.mount, system=system, path=path)


PART_KINDS['kinematic_arm'] = build_kinematic_arm_part


def _assemble(ctx: SceneContext, parts: list) -> object:
    """The scene's System from its parts.

    For now a scene is one part mounted on the world; composing parts (an arm on a
    differential-drive platform or on a free-flying base) is added here by later work.
    """
    if any(p.kind == 'free_base' for p in parts):
        return _assemble_free_base(ctx, parts)
    if any(p.kind == 'diff_drive' for p in parts):  # the platform, or the mobile manipulator
        return _assemble_diff_drive(ctx, parts)
    if len(parts) != 1:
        ctx.fail('parts', f'a scene of {len(parts)} parts needs a composition of '
                          f'{[p.kind for p in parts]} that is not available yet; use one part')
    p = parts[0]
    if p.mount not in ('world', 'free'):
        ctx.fail(_key(p.path, 'mount'), f"mount {p.mount!r} is not available to part kind '{p.kind}' "
                                        "in a one-part scene; use 'world'")
    return p.system


# --------------------------------------------------------------------------------------------
# command profiles: builder(params, path, ctx, system, port) -> f(t, y) -> (size,) array
# --------------------------------------------------------------------------------------------
def _compiled(f, kind: str, P=None, times=None, values=None, BT=None, Bq=None):
    """f with ``f.program``: the profile as :func:`robodyn_ros.kernels.core.command_eval` evaluates
    it (``(kind code, P, times, values, BT, Bq)``, C-contiguous float64), which the Simulator's
    block path runs inside its compiled loop with the same arithmetic (the recordings test
    compares both paths byte for byte). Without the compiled kernels f is returned as it is."""
    from . import kernels
    if kernels.AVAILABLE:
        e2 = np.zeros((0, 0))
        c = np.ascontiguousarray
        f.program = (int(getattr(kernels.core, kind)), e2 if P is None else c(P, dtype=float),
                     np.zeros(0) if times is None else c(times, dtype=float),
                     e2 if values is None else c(values, dtype=float),
                     e2 if BT is None else c(BT, dtype=float), e2 if Bq is None else c(Bq, dtype=float))
    return f


def _zero_profile(params, path, ctx, system, port):
    """``zero``: no parameters; u = 0."""
    ctx.mapping(params, path, required=('profile',))
    u = np.zeros(system.inputs[port].size)
    return _compiled(lambda t, y: u.copy(), 'CMD_ZERO')


def _constant_profile(params, path, ctx, system, port):
    """``constant``: ``value`` (size,); u = value."""
    ctx.mapping(params, path, required=('profile', 'value'))
    n = system.inputs[port].size
    u = ctx.vector(params['value'], _key(path, 'value'), n, f'values (one per {port} input)')
    return _compiled(lambda t, y: u.copy(), 'CMD_CONSTANT', P=u[None, :])


def _piecewise_constant_profile(params, path, ctx, system, port):
    """``piecewise_constant``: ``times`` (k,) increasing from >= 0, ``values`` (k, size).

    u(t) = values[j] for times[j] <= t < times[j+1], the last value after times[-1], zero
    before times[0].
    """
    ctx.mapping(params, path, required=('profile', 'times', 'values'))
    n = system.inputs[port].size
    times = ctx.vector(params['times'], _key(path, 'times'), minimum=0.0)
    if times.size == 0:
        ctx.fail(_key(path, 'times'), 'needs at least one switching time')
    if np.any(np.diff(times) <= 0.0):
        ctx.fail(_key(path, 'times'), f'times must be strictly increasing, got {times.tolist()}')
    vpath = _key(path, 'values')
    rows = ctx.sequence(params['values'], vpath, times.size, 'rows (one per switching time)')
    values = np.array([ctx.vector(r, _key(vpath, i), n, f'values (one per {port} input)')
                       for i, r in enumerate(rows)])
    zero = np.zeros(n)

    def f(t, y):
        j = int(np.searchsorted(times, t, side='right')) - 1
        return (zero if j < 0 else values[j]).copy()
    return _compiled(f, 'CMD_PIECEWISE', times=times, values=values)


def _sine_parts(params, path, ctx, n, port):
    what = f'values (one per {port} input)'
    A = ctx.vector(params['amplitude'], _key(path, 'amplitude'), n, what)
    fhz = ctx.vector(params['frequency_hz'], _key(path, 'frequency_hz'), n, what, minimum=0.0)
    phase = ctx.vector(params['phase'], _key(path, 'phase'), n, what) if 'phase' in params else np.zeros(n)
    return A, 2.0 * np.pi * fhz, phase


def _sine_profile(params, path, ctx, system, port):
    """``sine``: u = offset + amplitude sin(2π frequency_hz t + phase), elementwise (size,)."""
    ctx.mapping(params, path, required=('profile', 'amplitude', 'frequency_hz'), optional=('phase', 'offset'))
    n = system.inputs[port].size
    A, w, phase = _sine_parts(params, path, ctx, n, port)
    offset = ctx.vector(params['offset'], _key(path, 'offset'), n) if 'offset' in params else np.zeros(n)
    return _compiled(lambda t, y: offset + A * np.sin(w * t + phase), 'CMD_SINE', P=np.array([offset, A, w, phase]))


def _gravity_compensation_sine_profile(params, path, ctx, system, port):
    """``gravity_compensation_sine``: u = Bᵀ g(q) + K (center - Bᵀ q) + amplitude sin(2π f t + phase).

    g(q) = RNEA(q, 0, 0) are the gravity torques of the current state, so the arm moves as if
    weightless under the sine excitation. Optional ``stiffness`` K (per actuated joint, N·m/rad
    or N/m, >= 0) with its required ``center`` posture adds soft joint springs: without them a
    weightless chain under zero-mean torques still drifts (centrifugal forces push a prismatic
    joint outwards, velocity offsets left by the start-up transient integrate). Needs an
    arm's ``effort`` port (1-DOF joints, so q and v share indices).
    """
    ctx.mapping(params, path, required=('profile', 'amplitude', 'frequency_hz'),
                optional=('phase', 'stiffness', 'center'))
    model = getattr(system, 'model', None)
    if port != 'effort' or model is None or not hasattr(system, 'B') or \
            (model.nq != model.nv and not hasattr(system, 'minimal')):
        ctx.fail(_key(path, 'profile'), "gravity_compensation_sine needs the 'effort' port of a fixed-base arm "
                                        "or of a free-flyer (which maps its state to minimal coordinates)")
    n = system.inputs[port].size
    what = f'values (one per {port} input)'
    A, w, phase = _sine_parts(params, path, ctx, n, port)
    K = ctx.vector(params['stiffness'], _key(path, 'stiffness'), n, what, minimum=0.0) \
        if 'stiffness' in params else np.zeros(n)
    if 'center' in params:
        center = ctx.vector(params['center'], _key(path, 'center'), n, what)
    elif 'stiffness' in params:
        ctx.fail(_key(path, 'center'), "missing required key (the posture the 'stiffness' springs pull to)")
    else:
        center = np.zeros(n)
    zeros = np.zeros(model.nv)
    BT = system.B.T
    Bq = getattr(system, 'Bq', BT)  # actuated joint positions = Bq q (= Bᵀ q when q and v share indices)
    minimal = getattr(system, 'minimal', None)
    # the arm's own backend (compiled kernels when available, == reference to 1e-12); a free base
    # on a compiled backend gets the compiled RNEA of its tree as well
    if minimal is None and hasattr(system, 'inverse_dynamics'):
        rnea = system.inverse_dynamics
    elif getattr(system, 'backend', 'numpy') != 'numpy':
        from . import kernels
        km = kernels.CompiledModel(model)

        def rnea(q, v, a):
            return km.rnea(np.ascontiguousarray(q, dtype=float), v, a)
    else:
        def rnea(q, v, a):
            return dyn.rnea(model, q, v, a)

    def f(t, y):
        q = minimal(y)[0] if minimal is not None else system.split(y)[0]
        return BT @ rnea(q, zeros, zeros) + K * (center - Bq @ q) + A * np.sin(w * t + phase)
    # compiled form: an arm's own compiled RNEA (CompiledModel.rnea) with 0/1 selection matrices
    if minimal is None and getattr(system, '_km', None) is not None and rnea == system.inverse_dynamics \
            and getattr(system, '_B_is_selection', False) and Bq is BT:
        return _compiled(f, 'CMD_GRAVITY_SINE', P=np.array([A, w, phase, K, center]), BT=BT, Bq=BT)
    return f


#: command profile name -> builder(params, path, ctx, system, port) -> f(t, y)
COMMAND_PROFILES: dict[str, Callable] = {
    'zero': _zero_profile,
    'constant': _constant_profile,
    'piecewise_constant': _piecewise_constant_profile,
    'sine': _sine_profile,
    'gravity_compensation_sine': _gravity_compensation_sine_profile,
}


def _pfl_profile(params, path, ctx, system, port):
    """``pfl``: partial feedback linearisation of a planar-base tree (:mod:`robodyn_ros.pfl`)."""
    from .pfl import pfl_profile
    return pfl_profile(params, path, ctx, system, port)


COMMAND_PROFILES['pfl'] = _pfl_profile


def _registered(ctx: SceneContext, spec, path: str, key: str, registry: dict, what: str, plural: str,
                mapping_hint: str = ''):
    """The builder that ``spec[key]`` names in ``registry`` (part kinds, command profiles).

    Fails with the file and key path when spec is not a mapping, lacks ``key``, or names
    nothing registered (the message lists the known ``plural``).
    """
    if not isinstance(spec, dict):
        ctx.fail(path, f'expected a mapping{mapping_hint}, got {_typename(spec)} {spec!r}')
    if key not in spec:
        ctx.fail(_key(path, key), 'missing required key')
    name = ctx.string(spec[key], _key(path, key))
    builder = registry.get(name)
    if builder is None:
        ctx.fail(_key(path, key), f'unknown {what} {name!r}; known {plural}: {", ".join(registry)}')
    return builder


def _script(ctx: SceneContext, commands, system):
    """``script(t, y) -> {port: array}`` from the ``commands`` section, or None if it is empty."""
    if not isinstance(commands, dict):
        ctx.fail('commands', f'expected a mapping of input ports, got {_typename(commands)} {commands!r}')
    for port in commands:
        if port not in system.inputs:
            ctx.fail(_key('commands', port), f'unknown input port {port!r}; this scene\'s system has '
                                             f'{", ".join(system.inputs) or "no inputs"}')
    fns = {}
    for port, params in commands.items():
        path = _key('commands', port)
        builder = _registered(ctx, params, path, 'profile', COMMAND_PROFILES, 'command profile', 'profiles',
                              ' with a profile')
        fns[port] = builder(params, path, ctx, system, port)
    if not fns:
        return None

    def script(t, y):
        """Scripted commands at time t (s) and state y: {port: (size,) array}."""
        return {port: f(t, y) for port, f in fns.items()}
    script.profiles = fns  # port -> f(t, y), e.g. to reach a controller profile's object
    script.programs = {port: getattr(f, 'program', None) for port, f in fns.items()}  # compiled forms (block path)
    return script


# --------------------------------------------------------------------------------------------
# initial state and settings
# --------------------------------------------------------------------------------------------
def _initial_state(ctx: SceneContext, v, system) -> np.ndarray:
    """State vector y0 from ``initial_state: {q, v}`` (defaults: neutral q, zero v)."""
    extra_keys = tuple(getattr(system, 'initial_state_keys', ()))  # e.g. a planar base: com, com_velocity
    ctx.mapping(v, 'initial_state', optional=('q', 'v') + extra_keys)
    model = getattr(system, 'model', None)
    names = getattr(system, 'coordinate_names', None) or getattr(system, 'joint_names', None)
    what_q = f'values (one per joint: {", ".join(names)})' if names else 'values'
    nq0, nv0 = getattr(system, 'initial_state_sizes', (system.nq, system.nv))  # augmented: minimal q, v
    q0 = ctx.vector(v['q'], 'initial_state.q', nq0, what_q) if 'q' in v else None
    v0 = ctx.vector(v['v'], 'initial_state.v', nv0, what_q) if 'v' in v else None
    if q0 is not None and model is not None:
        for i in range(model.nb):
            s = model.specs[i]
            if model.jtype[i] in (REVOLUTE, PRISMATIC) and s.limits is not None:
                k = int(model.q_idx[i])
                lo, hi = s.limits
                if not lo <= q0[k] <= hi:
                    ctx.fail(_key('initial_state.q', k), f'{float(q0[k])!r} is outside the limits [{lo}, {hi}] '
                                                         f'of joint {s.joint!r}')
    extra = {k: ctx.vector(v[k], _key('initial_state', k), 2, 'values [x, z]') for k in extra_keys if k in v}
    try:
        return system.initial_state(q0, v0, **extra)
    except ValueError as e:  # e.g. a prescribed end point that the initial configuration cannot reach
        ctx.fail('initial_state', str(e))


#: stop_when conditions: key -> (what the system must have, builder(value, system) -> stop(t, y) -> bool)
STOP_CONDITIONS = {
    'com_z_below': ('com', lambda z, system: lambda t, y: bool(system.com(*system.split(y))[0][2] < z)),
}


def _stop_condition(ctx: SceneContext, v, system):
    """``stop(t, y) -> bool`` from ``stop_when: {<condition>: <value>}`` (one condition).

    ``com_z_below: z`` (m): the centre of mass is below height z in the world frame (systems
    with a ``com(q, v)`` method: the planar base). Evaluated after every publication period by
    ``robodyn run`` and the sim node: the run ends at the first period end where it holds (or at
    ``duration``, whichever comes first), so its resolution is one period.
    """
    ctx.mapping(v, 'stop_when', optional=tuple(STOP_CONDITIONS))
    if len(v) != 1:
        ctx.fail('stop_when', f'give one condition of {", ".join(STOP_CONDITIONS)}')
    (key, value), = v.items()
    needs, build = STOP_CONDITIONS[key]
    if not hasattr(system, needs):
        ctx.fail(_key('stop_when', key), f'{type(system).__name__} has no {needs}(); {key} needs a planar base')
    return build(ctx.number(value, _key('stop_when', key)), system)


def _known_integrators():
    """Integrator names the package registers (None when the registry is unavailable)."""
    try:
        from .integrators import INTEGRATORS
    except ImportError:
        return None
    return tuple(INTEGRATORS)


def _settings(ctx: SceneContext, v) -> dict:
    """Simulation defaults from the ``simulation`` section, over :data:`DEFAULT_SETTINGS`."""
    ctx.mapping(v, 'simulation', optional=_SETTING_KEYS)
    out = dict(DEFAULT_SETTINGS)
    if 'integrator' in v:
        name = ctx.string(v['integrator'], 'simulation.integrator')
        known = _known_integrators()
        if known is not None and name not in known:
            ctx.fail('simulation.integrator', f'unknown integrator {name!r}; known: {", ".join(known)}')
        out['integrator'] = name
    for k in ('dt', 'rtol', 'atol', 'publish_rate', 'duration'):
        if k in v:
            out[k] = ctx.number(v[k], _key('simulation', k), positive=True)
    return out


# --------------------------------------------------------------------------------------------
# loading
# --------------------------------------------------------------------------------------------
def parse_scene(text: str, file: str = '<string>', path: str | None = None) -> Scene:
    """Validate scene YAML text and build its :class:`Scene`.

    text: the YAML; file: name used in error messages; path: file path stored in the Scene
    (default ``file``). Raises :class:`SceneError` ``<file>: <key path>: <reason>``.
    """
    ctx = SceneContext(file)
    try:
        data = yaml.load(text, Loader=_Loader)
    except yaml.YAMLError as e:
        mark = getattr(e, 'problem_mark', None)
        where = f'line {mark.line + 1}, column {mark.column + 1}' if mark is not None else 'YAML'
        ctx.fail(where, f'YAML syntax error: {getattr(e, "problem", None) or e}')
    ctx.mapping(data, '', required=_TOP_KEYS_REQUIRED, optional=_TOP_KEYS_OPTIONAL)
    name = ctx.string(data['name'], 'name')
    for k in ('description', 'source'):
        if k in data:
            ctx.string(data[k], k)
    if 'gravity' in data:
        ctx.gravity = ctx.vector(data['gravity'], 'gravity', 3)
    items = ctx.sequence(data['parts'], 'parts')
    if not items:
        ctx.fail('parts', 'a scene needs at least one part')
    for i, spec in enumerate(items):
        ppath = _key('parts', i)
        builder = _registered(ctx, spec, ppath, 'kind', PART_KINDS, 'part kind', 'kinds')
        part = builder(spec, ppath, ctx)
        if any(p.name == part.name for p in ctx.parts):
            ctx.fail(_key(ppath, 'name'), f'duplicate part name {part.name!r}')
        ctx.parts.append(part)
    system = _assemble(ctx, ctx.parts)
    y0 = _initial_state(ctx, data.get('initial_state', {}), system)
    ctx.y0 = y0  # command profiles may start from the initial state (e.g. a posture path)
    script = _script(ctx, data.get('commands', {}), system)
    settings = _settings(ctx, data.get('simulation', {}))
    stop = _stop_condition(ctx, data['stop_when'], system) if 'stop_when' in data else None
    return Scene(name=name, path=path or file, text=text, data=data, system=system, y0=y0, script=script,
                 settings=settings, parts=[p.name for p in ctx.parts], stop=stop)


def scene_dirs() -> list:
    """Directories searched for bundled scenes, in order (existing ones only).

    ``<package dir>/../config/scenes`` (source tree), the ament index share directory
    ``robodyn_ros/config/scenes``, then ``<sys.prefix>/share/robodyn_ros/config/scenes``.
    """
    cands = [Path(__file__).resolve().parent.parent / 'config' / 'scenes']
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
    except ImportError:  # no ROS installation: the other two places remain
        pass
    else:
        try:
            cands.append(Path(get_package_share_directory('robodyn_ros')) / 'config' / 'scenes')
        except (PackageNotFoundError, OSError):  # not installed, or AMENT_PREFIX_PATH unset
            pass
    cands.append(Path(sys.prefix) / 'share' / 'robodyn_ros' / 'config' / 'scenes')
    out = []
    for c in cands:
        if c.is_dir() and all(c.resolve() != o.resolve() for o in out):
            out.append(c)
    return out


def _bundled() -> dict:
    """name -> path of every bundled scene (the first directory that has a name wins)."""
    found = {}
    for d in scene_dirs():
        for p in sorted(d.glob('*.yaml')):
            found.setdefault(p.stem, p)
    return found


def find_scene(name_or_path) -> Path:
    """Path of a scene given a bundled name or a file path.

    name_or_path: an existing file path, a path ending in .yaml/.yml, or a bundled name.
    Raises :class:`SceneError` when nothing matches.
    """
    s = os.fspath(name_or_path)
    p = Path(s)
    if p.is_file():
        return p
    if p.suffix in ('.yaml', '.yml') or os.sep in s:
        raise SceneError(f'{s}: (file): no such scene file')
    bundled = _bundled()
    if s in bundled:
        return bundled[s]
    raise SceneError(f'{s}: (name): no bundled scene of that name; bundled scenes: {", ".join(sorted(bundled))} '
                     f'(searched {", ".join(str(d) for d in scene_dirs())})')


def load_scene(name_or_path, position_limits: dict | None = None) -> Scene:
    """Load a bundled scene by name (``stanford_arm``), a scene file by path, or a URDF file.

    name_or_path: name or path (str or PathLike); a path ending in ``.urdf`` is imported as a
    one-part scene (:func:`urdf_scene_text`), with ``position_limits`` (``{stiffness, damping,
    return}``, optional) as its part's key; a scene file gives that key itself (refused here).
    Returns the validated :class:`Scene`; raises :class:`SceneError` whose message is
    ``<file>: <key path>: <reason>``.
    """
    s = os.fspath(name_or_path)
    if s.lower().endswith('.urdf'):  # a robot description alone: a one-part scene around it
        return parse_scene(urdf_scene_text(s, position_limits=position_limits), file=s, path=s)
    if position_limits is not None:
        raise SceneError(f'{s}: (position_limits): applies to a URDF file only; in a scene file give '
                         'position_limits on its kind: urdf part')
    p = find_scene(name_or_path)
    try:
        text = p.read_text(encoding='utf-8')
    except (OSError, UnicodeDecodeError) as e:
        raise SceneError(f'{p}: (file): cannot read: {e}') from None
    return parse_scene(text, file=str(p), path=str(p))


def urdf_scene_text(urdf_file=None, floating: bool = False, text: str | None = None,
                    position_limits: dict | None = None) -> str:
    """Scene YAML of one URDF: ``kind: urdf`` mounted on the world (or ``floating``), no scripted
    commands, default settings. urdf_file: its path (``load_scene('robot.urdf')``, ``robodyn run
    robot.urdf``, the node's ``robot_description_file``), or text: the URDF itself (the node
    reading ``robot_description``). A URDF whose root is a massless ``world`` link with a
    floating joint is floating anyway. position_limits: the part's ``position_limits`` mapping
    (``{stiffness, damping, return}``; None = URDF position limits reported only)."""
    part = {'kind': 'urdf'}
    if text is None:
        p = Path(urdf_file)
        if not p.is_file():
            raise SceneError(f'{urdf_file}: (file): no such URDF file')
        name, origin, part['file'] = p.stem, str(p.resolve()), str(p.resolve())
    else:
        m = re.search(r'<robot[^>]*\sname="([^"]*)"', text)
        name, origin, part['urdf'] = (m.group(1) if m else 'robot'), 'robot_description', text
    part['name'] = name = re.sub(r'[^A-Za-z0-9_]', '_', name) or 'robot'
    if floating:
        part['floating'] = True
    if position_limits is not None:
        part['position_limits'] = dict(position_limits)
    return yaml.safe_dump({'name': name, 'description': f'imported from {origin}', 'parts': [part]}, sort_keys=False)


def list_scenes() -> list:
    """``[(name, description), ...]`` of the bundled scenes, sorted by name.

    Only the ``description`` is read (quickly, without building the systems); an unreadable
    file is listed with the parse error as its description.
    """
    out = []
    for name, p in sorted(_bundled().items()):
        try:
            data = yaml.load(p.read_text(encoding='utf-8'), Loader=_Loader)
            desc = data.get('description', '') if isinstance(data, dict) else ''
        except (OSError, UnicodeDecodeError, yaml.YAMLError) as e:
            desc = f'(unreadable: {e.__class__.__name__})'
        out.append((name, ' '.join(str(desc).split())))
    return out
