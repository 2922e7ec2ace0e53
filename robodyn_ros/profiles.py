"""Command profiles: the scripted commands of a scene, one builder per profile.

A scene's ``commands: {<port>: {profile: <name>, <parameters>}}`` section names a profile per
input port; :data:`COMMAND_PROFILES` maps each name to its builder
``builder(params, path, ctx, system, port) -> f(t, y) -> (size,) array``, which validates its own
parameters through ``ctx`` (:class:`robodyn_ros.validation.SceneContext`, so errors carry the file
and key path) and returns the command as a function of time t (s) and state y. A new profile
registers ``COMMAND_PROFILES[name] = builder``. :func:`build_script` puts the ports' profiles
together into the scene's ``script(t, y) -> {port: array}``.

Every profile but ``pfl`` is evaluated by :func:`robodyn_ros.kernels.profiles.command_eval` (its
one implementation); those the compiled block path can run carry their program ``f.program``; the
``trajectory`` profile, whose commands are messages at given times, says when its next is due
(``f.next_send``: the block path runs the periods between them).
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np

from . import dynamics as dyn
from .messages import to_ns
from .pfl import PFLController, PosturePath, stamp_seconds
from .validation import SceneContext, registered, typename
from .validation import key_path as _key

__all__ = ['COMMAND_PROFILES', 'build_script']


def _profile(kind: str, n: int, P=None, times=None, values=None, BT=None, Bq=None, state=None, gravity=None,
             block: bool = True, velocity=None):
    """The profile ``f(t, y) -> u (n,)``: :func:`robodyn_ros.kernels.profiles.command_eval` of its
    program ``(kind code, P, times, values, BT, Bq)`` (C-contiguous float64), the profiles' one
    implementation. For ``CMD_GRAVITY_SINE`` and ``CMD_PD_HOLD``, ``state(y)`` gives q (nq,),
    ``velocity(y)`` v (nv,) and ``gravity(q)`` the gravity torques (nv,) by the system's own RNEA
    (each None where the profile reads none of it).

    With the compiled kernels and ``block``, f also carries ``f.program``, which the Simulator's
    block path runs inside the arm's compiled loop (it computes the gravity torques there with the
    arm's compiled RNEA, the numbers of ``CompiledModel.rnea``).
    """
    from . import kernels
    from .kernels import profiles as kp
    e2 = np.zeros((0, 0))
    c = np.ascontiguousarray
    program = (int(getattr(kp, kind)), e2 if P is None else c(P, dtype=float),
               np.zeros(0) if times is None else c(times, dtype=float), e2 if values is None else c(values, dtype=float),
               e2 if BT is None else c(BT, dtype=float), e2 if Bq is None else c(Bq, dtype=float))
    run, none = kp.command_eval, np.zeros(0)

    def f(t, y):
        u = np.empty(n)
        if state is None:
            run(*program, none, none, none, float(t), u)
        else:
            q = c(state(y), dtype=float)
            run(*program, q, none if velocity is None else c(velocity(y), dtype=float),
                none if gravity is None else c(gravity(q), dtype=float), float(t), u)
        return u
    if kernels.AVAILABLE and block:
        f.program = program
    return f


def _zero_profile(params, path, ctx, system, port):
    """``zero``: no parameters; u = 0."""
    ctx.mapping(params, path, required=('profile',))
    return _profile('CMD_ZERO', system.inputs[port].size)


def _constant_profile(params, path, ctx, system, port):
    """``constant``: ``value`` (size,); u = value."""
    ctx.mapping(params, path, required=('profile', 'value'))
    n = system.inputs[port].size
    u = ctx.vector(params['value'], _key(path, 'value'), n, f'values (one per {port} input)')
    return _profile('CMD_CONSTANT', n, P=u[None, :])


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
    return _profile('CMD_PIECEWISE', n, times=times, values=values)


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
    return _profile('CMD_SINE', n, P=np.array([offset, A, w, phase]))


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
    if BT.shape != (n, model.nv) or Bq.shape != (n, model.nq):
        ctx.fail(_key(path, 'profile'), f'gravity_compensation_sine: the port maps {BT.shape[1]} velocities and '
                                        f'{Bq.shape[1]} positions, the tree has {model.nv} and {model.nq}')
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

    def state(y):
        return minimal(y)[0] if minimal is not None else system.split(y)[0]

    def gravity(q):
        return rnea(q, zeros, zeros)
    # the block path: an arm's own compiled RNEA (CompiledModel.rnea) with 0/1 selection matrices
    block = minimal is None and getattr(system, '_km', None) is not None and rnea == system.inverse_dynamics \
        and getattr(system, '_B_is_selection', False) and Bq is BT
    return _profile('CMD_GRAVITY_SINE', n, P=np.array([A, w, phase, K, center]), BT=BT, Bq=Bq, state=state,
                    gravity=gravity, block=block)


def _pd_hold_profile(params, path, ctx, system, port):
    """``pd_hold``: u = K_p (q* − q) − K_d q̇ (+ g(q) with ``gravity_compensation: true``), per actuated joint.

    Keys: ``posture`` q* (a mapping joint -> position, the others at their initial position; or one
    value per actuated joint; default: the initial state's), ``kp`` (N·m/rad or N/m) and ``kd``
    (N·m·s/rad or N·s/m): one value for every joint or one per actuated joint (>= 0), and
    ``gravity_compensation`` (default false): add the gravity torques ``g(q) = RNEA(q, 0, 0)`` of the
    tree (for a floating tree, those that would hold it still with its root held: a swing leg's, not
    a stance leg's). Sampled at the start of each period and held, as a controller node's command
    (the ``pd_hold_controller`` node, :mod:`robodyn_ros.nodes.pd_hold_controller`, runs the same law
    over ROS topics). Needs an arm's ``effort`` port whose actuated joints are 1-DOF (revolute,
    prismatic), on a fixed or free root.
    """
    from .model import PRISMATIC, REVOLUTE
    ctx.mapping(params, path, required=('profile', 'kp', 'kd'), optional=('posture', 'gravity_compensation'))
    model = getattr(system, 'model', None)
    if port != 'effort' or model is None or not hasattr(system, 'B') or not hasattr(system, 'actuated') \
            or hasattr(system, 'minimal') or not hasattr(system, 'inverse_dynamics'):
        ctx.fail(_key(path, 'profile'), "pd_hold needs the 'effort' port of an arm or urdf part (fixed base, "
                                        "mount: free or floating: true)")
    names = list(system.actuated)
    n = len(names)
    Bq = np.zeros((n, model.nq))
    for k, name in enumerate(names):
        i, _ = model.state_index(name)
        if model.jtype[i] not in (REVOLUTE, PRISMATIC):
            ctx.fail(_key(path, 'profile'), f'pd_hold holds 1-DOF joints; {name!r} is a component of a spherical '
                                            'joint (leave it out of actuated, or use another profile)')
        Bq[k, int(model.q_idx[i])] = 1.0
    q0 = Bq @ system.split(ctx.y0)[0]
    what = f'values (one per actuated joint: {", ".join(names)})'

    def gains(key):
        v = params[key]
        if isinstance(v, list):
            return ctx.vector(v, _key(path, key), n, what, minimum=0.0)
        return np.full(n, ctx.number(v, _key(path, key), minimum=0.0))
    kp, kd = gains('kp'), gains('kd')
    posture = q0.copy()
    if 'posture' in params:
        ppath = _key(path, 'posture')
        if isinstance(params['posture'], dict):
            for name, val in ctx.mapping(params['posture'], ppath, optional=names).items():
                posture[names.index(name)] = ctx.number(val, _key(ppath, name))
        else:
            posture = ctx.vector(params['posture'], ppath, n, what)
    gc = ctx.boolean(params.get('gravity_compensation', False), _key(path, 'gravity_compensation'))
    zeros = np.zeros(model.nv)

    def state(y):
        return system.split(y)[0]

    def velocity(y):
        return system.split(y)[1]

    def gravity(q):
        return system.inverse_dynamics(q, zeros, zeros)
    block = getattr(system, '_km', None) is not None and getattr(system, '_B_is_selection', False)
    return _profile('CMD_PD_HOLD', n, P=np.array([posture, kp, kd, np.full(n, 1.0 if gc else 0.0)]), BT=system.B.T,
                    Bq=Bq, state=state, velocity=velocity, gravity=gravity if gc else None, block=block)


#: command profile name -> builder(params, path, ctx, system, port) -> f(t, y)
COMMAND_PROFILES: dict[str, Callable] = {
    'zero': _zero_profile,
    'constant': _constant_profile,
    'piecewise_constant': _piecewise_constant_profile,
    'sine': _sine_profile,
    'gravity_compensation_sine': _gravity_compensation_sine_profile,
    'pd_hold': _pd_hold_profile,
}


def _pfl_params(ctx, params, path, system, start):
    """Validated ``(PosturePath, kp, kd)`` from the profile's keys (see :mod:`robodyn_ros.pfl`)."""
    ctx.mapping(params, path, required=('profile', 'target', 'schedule'), optional=('kp', 'kd'))
    inner = list(system.inner_joint_names)
    m = len(inner)

    def gains(k, default):
        v = params.get(k, default)
        if isinstance(v, list):
            return ctx.vector(v, _key(path, k), m, f'values (one per inner joint: {", ".join(inner)})', minimum=0.0)
        return np.full(m, ctx.number(v, _key(path, k), positive=True))
    kp, kd = gains('kp', 100.0), gains('kd', 20.0)
    tpath = _key(path, 'target')
    target = np.array(start, dtype=float)
    for name, val in ctx.mapping(params['target'], tpath, optional=inner).items():
        target[inner.index(name)] = ctx.number(val, _key(tpath, name))
    sched = ctx.vector(params['schedule'], _key(path, 'schedule'), 4, 'times [t0, t1, t2, t3]', minimum=0.0)
    if not np.all(np.diff(sched) > 0.0):
        ctx.fail(_key(path, 'schedule'), f'times must increase strictly, got {sched.tolist()}')
    return PosturePath(start, target, sched), kp, kd


def _pfl_profile(params, path, ctx, system, port):
    """``pfl``: partial feedback linearisation of a planar-base tree (:mod:`robodyn_ros.pfl`):
    ``f(t, y) -> effort`` of :class:`~robodyn_ros.pfl.PFLController`, from the outputs the
    system publishes at (t, y) (the values a node would receive)."""
    if port != 'effort' or not hasattr(system, 'inner_joint_names'):
        ctx.fail(_key(path, 'profile'), "pfl needs the 'effort' port of a tree on a planar root joint "
                                        "(an arm part whose root link has type: planar)")
    start = np.asarray(system.split(ctx.y0)[0][3:], dtype=float)
    pathf, kp, kd = _pfl_params(ctx, params, path, system, start)
    try:
        ctl = PFLController(system, pathf, kp, kd)
    except ValueError as e:
        ctx.fail(path, str(e))

    def f(t, y):
        q, v = system.published_state(y)   # = state_from_outputs of system.outputs(t, y, ...)
        return ctl.torques(stamp_seconds(to_ns(t)), q, v)
    f.controller = ctl
    return f


COMMAND_PROFILES['pfl'] = _pfl_profile


_TRAJECTORY_KEYS = ('joint_names', 'points', 'stamp', 'send_at')
_POINT_KEYS = ('time_from_start', 'positions', 'velocities', 'accelerations', 'effort')


def _trajectory_message(params, path, ctx, system):
    """``(send_at, message dict)`` of one scripted trajectory (keys of :func:`_trajectory_profile`)."""
    from .setpoints import TrajectoryError, parse_trajectory, trajectory_message
    joints = list(system.inputs['trajectory'].labels)
    names = ctx.names(params['joint_names'], _key(path, 'joint_names')) if 'joint_names' in params else joints
    ppath = _key(path, 'points')
    points = []
    for i, p in enumerate(ctx.sequence(params['points'], ppath)):
        ip = _key(ppath, i)
        ctx.mapping(p, ip, required=('time_from_start', 'positions'), optional=_POINT_KEYS[2:])
        pt = {'time_from_start': ctx.number(p['time_from_start'], _key(ip, 'time_from_start'), minimum=0.0)}
        for k in _POINT_KEYS[1:]:
            if k in p:
                pt[k] = ctx.vector(p[k], _key(ip, k), len(names), f'values (one per joint: {", ".join(names)})')
        points.append(pt)
    stamp = ctx.number(params.get('stamp', 0.0), _key(path, 'stamp'), minimum=0.0)
    send_at = ctx.number(params.get('send_at', 0.0), _key(path, 'send_at'), minimum=0.0)
    msg = trajectory_message(names, points, stamp)
    try:
        parse_trajectory(msg, joints)
    except TrajectoryError as e:
        ctx.fail(path, str(e))
    return send_at, msg


def _trajectory_profile(params, path, ctx, system, port):
    """``trajectory``: trajectory_msgs/JointTrajectory messages on the ``trajectory`` port, each sent at the
    first period that starts at or after its ``send_at`` (s, default 0; several due in one period: the
    last), as a controller would publish them on ``joint_trajectory``.

    Keys: ``joint_names`` (default: every position-commanded joint), ``points`` (a list of
    ``{time_from_start (s), positions, velocities?, accelerations?, effort?}``, one value per joint),
    ``stamp`` (s of simulation time; 0 = when it is sent: "now"), ``send_at``; or ``messages``: a list
    of such mappings. The messages are validated here as the Simulator validates them
    (:func:`robodyn_ros.setpoints.parse_trajectory`); one whose last point is past when it is sent is
    refused then, and counted, like a controller's.
    """
    if port != 'trajectory' or 'trajectory' not in system.inputs:
        ctx.fail(_key(path, 'profile'), "trajectory needs the 'trajectory' port of an arm with position-commanded "
                                        'joints (command_interfaces)')
    if 'messages' in params:
        ctx.mapping(params, path, required=('profile', 'messages'))
        items = ctx.sequence(params['messages'], _key(path, 'messages'))
        if not items:
            ctx.fail(_key(path, 'messages'), 'needs at least one message')
        sent = []
        for i, m in enumerate(items):
            mp = _key(_key(path, 'messages'), i)
            ctx.mapping(m, mp, required=('points',), optional=_TRAJECTORY_KEYS)
            sent.append(_trajectory_message(m, mp, ctx, system))
    else:
        ctx.mapping(params, path, required=('profile', 'points'), optional=_TRAJECTORY_KEYS)
        sent = [_trajectory_message(params, path, ctx, system)]
    order = sorted(range(len(sent)), key=lambda k: sent[k][0])
    times = [sent[k][0] for k in order]
    msgs = [sent[k][1] for k in order]
    state = {'next': 0, 'last': -np.inf}

    def f(t, y):
        if t <= state['last']:   # a new run or episode (a reset): send them again
            state['next'] = 0
        state['last'] = t
        due = None
        while state['next'] < len(times) and times[state['next']] <= t + 1e-12:
            due = msgs[state['next']]
            state['next'] += 1
        return due

    def next_send():
        """When the next message is due (s; inf when all are sent): the block path ends its blocks before it."""
        return times[state['next']] if state['next'] < len(times) else math.inf
    f.next_send = next_send
    return f


COMMAND_PROFILES['trajectory'] = _trajectory_profile


def build_script(ctx: SceneContext, commands, system):
    """``script(t, y) -> {port: array}`` from the ``commands`` section, or None if it is empty."""
    if not isinstance(commands, dict):
        ctx.fail('commands', f'expected a mapping of input ports, got {typename(commands)} {commands!r}')
    for port in commands:
        if port not in system.inputs:
            ctx.fail(_key('commands', port), f'unknown input port {port!r}; this scene\'s system has '
                                             f'{", ".join(system.inputs) or "no inputs"}')
    fns = {}
    for port, params in commands.items():
        path = _key('commands', port)
        builder = registered(ctx, params, path, 'profile', COMMAND_PROFILES, 'command profile', 'profiles',
                             ' with a profile')
        fns[port] = builder(params, path, ctx, system, port)
    if not fns:
        return None

    def script(t, y):
        """Scripted commands at time t (s) and state y: {port: (size,) array} (a message port: its message,
        only at the periods that send one)."""
        out = {}
        for port, f in fns.items():
            value = f(t, y)
            if value is not None:
                out[port] = value
        return out
    script.profiles = fns  # port -> f(t, y), e.g. to reach a controller profile's object
    script.programs = {port: getattr(f, 'program', None) for port, f in fns.items()}  # compiled forms (block path)
    # ports whose commands are messages at given times: when the next is due (the block path)
    script.next_send = {port: f.next_send for port, f in fns.items() if hasattr(f, 'next_send')}
    return script
