"""A scene's initial state, its stop condition and its run settings (``simulation`` section).

**A free root's velocity.** A tree on a free root (``mount: free``, a floating URDF, a free base)
has the root's twist as its first six velocities, in Featherstone's order: ``[ω (3), v_O (3)]``,
angular first, both in the root link's own (body) axes, v_O the velocity of its origin. ROS
``geometry_msgs/Twist``, the ``odom`` topic and Pinocchio put linear first, so a bare list is easy
to misread: ``initial_state.v`` may instead be a mapping that names each part and its frame::

    initial_state:
      v:
        root: {linear: [-1.0, 0.0, 0.0], angular: [0.0, 0.0, 0.0], frame: world}
        joints: [0.0, 0.0]        # the other velocities, in joint order (default zeros)

``frame: world`` gives both vectors in the world (odom) frame's axes, ``frame: body`` in the root
link's; they are turned into the body axes of the initial orientation (:func:`root_twist`). A bare
list whose root twist is not zero is still read in Featherstone's order, with a warning
(:class:`VelocityOrderWarning`) that says the order and shows the mapping.
"""
from __future__ import annotations

import warnings

import numpy as np

from ..model import FREE, PRISMATIC, REVOLUTE
from ..spatial import quat_to_R
from ..validation import SceneContext, typename
from ..validation import key_path as _key

#: the frames a free root's velocity may be given in (``initial_state.v.root.frame``)
ROOT_FRAMES = ('world', 'body')


class VelocityOrderWarning(UserWarning):
    """A free root's velocity given as a bare list: read angular first, in body axes (module docstring)."""


def free_root(system):
    """``(joint name, q index, v index)`` of the free root joint of ``system``'s tree, in the coordinates
    its initial state takes (``initial_state_sizes``), or None: the root's pose is ``q[i:i+7] = [p (3),
    quaternion (x, y, z, w)]`` (p in the world frame) and its twist ``v[j:j+6] = [ω, v_O]`` in body axes."""
    model = getattr(system, 'model', None)
    if model is None or not hasattr(model, 'jtype'):
        return None
    nq0, nv0 = getattr(system, 'initial_state_sizes', (system.nq, getattr(system, 'nv', None)))
    if (nq0, nv0) != (model.nq, model.nv):
        return None
    for i in range(model.nb):
        if int(model.jtype[i]) == FREE:
            return model.specs[i].joint, int(model.q_idx[i]), int(model.v_idx[i])
    return None


def root_twist(ctx: SceneContext, value, path: str, quaternion) -> np.ndarray:
    """The free root's twist ``[ω; v_O]`` (6,) in body axes from ``{linear, angular, frame}``.

    linear: velocity of the root link's origin (m/s); angular: its angular velocity (rad/s); frame:
    ``world`` (the world/odom axes) or ``body`` (the root link's axes); quaternion: the root's initial
    orientation ``(x, y, z, w)`` in the world, which turns world axes into body axes: ``x_b = Rᵀ x_w``."""
    ctx.mapping(value, path, required=('frame',), optional=('linear', 'angular'))
    frame = ctx.string(value['frame'], _key(path, 'frame'))
    if frame not in ROOT_FRAMES:
        ctx.fail(_key(path, 'frame'), f'expected one of {", ".join(ROOT_FRAMES)} (the axes linear and angular are '
                                      f'given in), got {frame!r}')
    lin = ctx.vector(value['linear'], _key(path, 'linear'), 3, 'values [x, y, z] (m/s)') if 'linear' in value \
        else np.zeros(3)
    ang = ctx.vector(value['angular'], _key(path, 'angular'), 3, 'values [x, y, z] (rad/s)') if 'angular' in value \
        else np.zeros(3)
    if frame == 'world':
        q = np.asarray(quaternion, dtype=float)
        R = quat_to_R(q / np.linalg.norm(q))
        lin, ang = R.T @ lin, R.T @ ang
    return np.concatenate([ang, lin])


def _velocities(ctx: SceneContext, value, path: str, system, q0, nv0, what) -> np.ndarray:
    """``initial_state.v`` (nv0,): a list in the system's order, or for a free root the mapping
    ``{root: {linear, angular, frame}, joints: [...]}`` (module docstring); q0: the initial q (None:
    neutral), whose root quaternion turns a world-frame twist into body axes."""
    root = free_root(system)
    if isinstance(value, dict):
        if root is None:
            ctx.fail(path, f'a mapping {{root, joints}} is for a tree with a free root; {type(system).__name__} has '
                           f'none: give a list of {nv0} {what}')
        name, qi, vi = root
        ctx.mapping(value, path, required=('root',), optional=('joints',))
        q = np.asarray(q0 if q0 is not None else system.model.neutral(), dtype=float)
        twist = root_twist(ctx, value['root'], _key(path, 'root'), q[qi + 3:qi + 7])
        rest = nv0 - 6
        joints = ctx.vector(value['joints'], _key(path, 'joints'), rest, f'values (the {rest} velocities after the '
                                                                         f'root\'s)') if 'joints' in value \
            else np.zeros(rest)
        return np.concatenate([joints[:vi], twist, joints[vi:]])
    v0 = ctx.vector(value, path, nv0, what)
    if root is not None:
        warn_bare_root_twist(v0[root[2]:root[2] + 6], root[0], f'{ctx.file}: {path}')
    return v0


def warn_bare_root_twist(twist, joint: str, where: str):
    """Warn (:class:`VelocityOrderWarning`) when a free root's twist ``[ω; v_O]`` (6,) given as bare
    numbers is not zero: say how they were read and how to say it unambiguously. ``where``: the file and
    key (or the parameter) it came from."""
    if not np.any(np.asarray(twist, dtype=float)):
        return
    w, v = [float(x) for x in twist[:3]], [float(x) for x in twist[3:6]]
    warnings.warn(VelocityOrderWarning(
        f'{where}: the free root {joint!r}\'s velocity is read angular first, in its body axes (Featherstone\'s '
        f'order, not ROS Twist\'s): angular {w} rad/s, linear {v} m/s; to say which, write '
        f'{{root: {{linear: [...], angular: [...], frame: world or body}}, joints: [...]}}'), stacklevel=3)

#: run settings a scene's ``simulation`` section may override (the CLI/node may override again)
DEFAULT_SETTINGS = {'integrator': 'auto', 'dt': 1e-3, 'publish_rate': 100.0, 'duration': 10.0}
_SETTING_KEYS = ('integrator', 'dt', 'rtol', 'atol', 'publish_rate', 'duration', 'step_budget')


def _initial_state(ctx: SceneContext, v, system) -> np.ndarray:
    """State vector y0 from ``initial_state: {q, v}`` (defaults: neutral q, zero v; a free root's
    velocity as in the module docstring)."""
    extra_keys = tuple(getattr(system, 'initial_state_keys', ()))  # e.g. a planar base: com, com_velocity
    ctx.mapping(v, 'initial_state', optional=('q', 'v') + extra_keys)
    model = getattr(system, 'model', None)
    names = getattr(system, 'coordinate_names', None) or getattr(system, 'joint_names', None)
    what_q = f'values (one per joint: {", ".join(names)})' if names else 'values'
    nq0, nv0 = getattr(system, 'initial_state_sizes', (system.nq, system.nv))  # augmented: minimal q, v
    q0 = ctx.vector(v['q'], 'initial_state.q', nq0, what_q) if 'q' in v else None
    v0 = _velocities(ctx, v['v'], 'initial_state.v', system, q0, nv0, what_q) if 'v' in v else None
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
    """Integrator names the package registers, and ``auto`` (None when the registry is unavailable)."""
    try:
        from ..integrators import INTEGRATORS
    except ImportError:
        return None
    return ('auto',) + tuple(INTEGRATORS)


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
    if 'step_budget' in v:   # steps per simulated second of an error-controlled integrator; .inf: none
        b = v['step_budget']
        if isinstance(b, bool) or not isinstance(b, (int, float)) or not b > 0:
            ctx.fail('simulation.step_budget', f'expected a number of steps per simulated second > 0 '
                                               f'(.inf: no budget), got {typename(b)} {b!r}')
        out['step_budget'] = float(b)
    return out

