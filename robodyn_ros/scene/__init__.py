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
Huston eq. (20.2.1) (:func:`robodyn_ros.kernels.tree.limit_moment`): zero inside, beyond a limit
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

Layout: one module per part kind (:mod:`.arm`, :mod:`.prescribed_arm`, :mod:`.kinematic_arm`,
:mod:`.urdf`, :mod:`.diff_drive`, :mod:`.free_base`), :mod:`.state` (initial state, stop
condition, settings) and :mod:`.loading` (parsing, composition, bundled scenes); the
validation context is :mod:`robodyn_ros.validation`, the command profiles
:mod:`robodyn_ros.profiles`.

Extension: a new part kind registers ``PART_KINDS[kind] = builder`` with
``builder(spec, path, ctx) -> Part``; a new command profile registers
``COMMAND_PROFILES[name] = builder`` with ``builder(params, path, ctx, system, port) ->
f(t, y) -> (size,) array``. Both validate their own keys through the ``ctx`` helpers so their
errors carry the file and the key path. Scenes of several parts (an arm on a platform) are put
together in :func:`robodyn_ros.scene.loading._assemble`.
"""
from __future__ import annotations

from ..profiles import COMMAND_PROFILES
from ..validation import SceneContext, SceneError
from .arm import build_arm_part
from .loading import (PART_KINDS, Scene, SceneLoader, find_scene, list_scenes, load_scene, parse_scene,
                      scene_dirs, urdf_scene_text)
from .part import Part
from .state import DEFAULT_SETTINGS, STOP_CONDITIONS
from .urdf import build_urdf_part

__all__ = ['SceneError', 'Scene', 'Part', 'SceneContext', 'SceneLoader', 'PART_KINDS', 'COMMAND_PROFILES',
           'DEFAULT_SETTINGS', 'STOP_CONDITIONS', 'load_scene', 'parse_scene', 'list_scenes', 'scene_dirs',
           'find_scene', 'build_arm_part', 'build_urdf_part', 'urdf_scene_text']
