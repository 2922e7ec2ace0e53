"""Command interfaces and sensors of a scene: an arm or urdf part's ``command_interfaces`` and ``servo``
keys, and the scene's ``sensors`` list (docs/control.md).

``command_interfaces`` says which joints take ``effort`` (the default: every actuated joint, as
without the key), ``position`` or ``velocity`` commands: a string gives every actuated joint that
interface (``command_interfaces: position``), a mapping lists joints per interface
(``{position: [j1, j2], velocity: [j3]}``; joints it does not list keep effort). ``servo`` sets the
joint servo of the position and velocity joints (:mod:`robodyn_ros.kernels.servo`): ``kp``, ``kd``
(one number for every joint, or a mapping joint -> number; default from the mass matrix:
:mod:`robodyn_ros.systems.servo`), ``frequency_hz`` and ``damping_ratio`` of the default gains,
``feedforward`` (default true on a fixed base, false on a floating one).

``sensors`` lists ``{kind: imu, link, name?, noise?, bias?, seed?}`` and ``{kind: force_torque, joint,
frame?, name?, noise?, bias?, seed?}`` (:mod:`robodyn_ros.systems.sensors`).
"""
from __future__ import annotations

import numpy as np

from ..validation import SceneContext
from ..validation import key_path as _key

#: keys of an arm or urdf part read here
PART_KEYS = ('command_interfaces', 'servo')
_SERVO_KEYS = ('kp', 'kd', 'feedforward', 'frequency_hz', 'damping_ratio')


def part_control(ctx: SceneContext, spec: dict, path: str):
    """The part's ``command_interfaces`` and ``servo`` keys, checked for form (the joints are checked
    against the assembled system by :func:`apply_control`), as ``(interfaces, servo, path)`` or None."""
    if 'command_interfaces' not in spec:
        if 'servo' in spec:
            ctx.fail(_key(path, 'servo'), "servo gains need command_interfaces with position or velocity joints")
        return None
    from ..systems.servo import INTERFACES
    ipath = _key(path, 'command_interfaces')
    ci = spec['command_interfaces']
    if isinstance(ci, str):
        if ci not in INTERFACES:
            ctx.fail(ipath, f'unknown command interface {ci!r}; use one of {", ".join(INTERFACES)} '
                            '(or a mapping interface -> joints)')
        interfaces = ci
    else:
        ctx.mapping(ci, ipath, optional=INTERFACES)
        interfaces = {k: ctx.names(v, _key(ipath, k)) for k, v in ci.items()}
        seen = {}
        for k, names in interfaces.items():
            for i, n in enumerate(names):
                if n in seen:
                    ctx.fail(_key(_key(ipath, k), i), f'joint {n!r} is already given the {seen[n]} interface')
                seen[n] = k
    servo = spec.get('servo', {})
    spath = _key(path, 'servo')
    ctx.mapping(servo, spath, optional=_SERVO_KEYS)
    return interfaces, servo, path


def _gain(ctx, v, path, names):
    """A gain as (ns,) over names from one number or a mapping joint -> number (None: not given)."""
    if v is None:
        return None
    if isinstance(v, dict):
        ctx.mapping(v, path, required=tuple(names))
        return np.array([ctx.number(v[n], _key(path, n), minimum=0.0) for n in names])
    return np.full(len(names), ctx.number(v, path, minimum=0.0))


def apply_control(ctx: SceneContext, system, parts, y0, settings) -> None:
    """Give ``system`` the joint servo its parts' ``command_interfaces`` ask for (default gains from its
    mass matrix at y0 and the scene's step ``settings['dt']``)."""
    from ..model import PRISMATIC, REVOLUTE
    from ..systems.arm import ArmSystem
    from ..systems.servo import JointServo, default_gains
    asked = [p.control for p in parts if getattr(p, 'control', None) is not None]
    if not asked:
        return
    if len(asked) > 1:
        ctx.fail(asked[1][2], 'command_interfaces on one part of a scene only')
    interfaces, servo, path = asked[0]
    ipath = _key(path, 'command_interfaces')
    if isinstance(interfaces, str) and interfaces == 'effort':
        if servo:
            ctx.fail(_key(path, 'servo'), 'servo gains need position or velocity joints')
        return
    if not isinstance(system, ArmSystem):
        ctx.fail(ipath, f'position and velocity commands are tracked on an arm ({type(system).__name__} here): an '
                        'arm or urdf part on the world, mount: free, or a floating URDF on a ground part')
    model = system.model
    actuated = list(system.actuated)
    followers = set(model.mimic_joint_names)

    def check(names, where):
        for i, n in enumerate(names):
            if n not in actuated:
                ctx.fail(_key(where, i) if where != ipath else where,
                         f'joint {n!r} is not an actuated joint of {model.name}; actuated joints are {actuated}')
            body, _ = model.state_index(n)
            if model.jtype[body] not in (REVOLUTE, PRISMATIC) or n in followers:
                ctx.fail(_key(where, i) if where != ipath else where,
                         f'joint {n!r}: position and velocity commands drive revolute and prismatic joints '
                         '(not a spherical joint component or a mimic joint)')
    if isinstance(interfaces, str):
        pos = actuated if interfaces == 'position' else []
        vel = actuated if interfaces == 'velocity' else []
        check(actuated, ipath)
    else:
        pos, vel = interfaces.get('position', []), interfaces.get('velocity', [])
        for k, names in interfaces.items():
            check(names, _key(ipath, k))
    pos, vel = list(pos), list(vel)
    if not pos and not vel:
        if servo:
            ctx.fail(_key(path, 'servo'), 'servo gains need position or velocity joints')
        return
    spath = _key(path, 'servo')
    names = pos + vel
    kp = _gain(ctx, servo.get('kp'), _key(spath, 'kp'), names)
    kd = _gain(ctx, servo.get('kd'), _key(spath, 'kd'), names)
    if kp is None or kd is None:
        fhz = ctx.number(servo.get('frequency_hz', 10.0), _key(spath, 'frequency_hz'), positive=True)
        zeta = ctx.number(servo.get('damping_ratio', 1.0), _key(spath, 'damping_ratio'), positive=True)
        q0 = np.ascontiguousarray(system.split(np.asarray(y0, dtype=float))[0])
        M = system._km.crba(q0)
        vidx = [model.state_index(n)[1] for n in names]
        kp0, kd0, _ = default_gains(M, vidx[:len(pos)], vidx[len(pos):], settings.get('dt'), fhz, zeta)
        kp = kp0 if kp is None else kp
        kd = kd0 if kd is None else kd
    kp[len(pos):] = 0.0
    ff = ctx.boolean(servo.get('feedforward', system.free_body is None), _key(spath, 'feedforward'))
    try:
        system.use_servo(JointServo(model, pos, vel, kp, kd, ff))
    except ValueError as e:
        ctx.fail(ipath, str(e))


def build_sensors(ctx: SceneContext, items, system) -> None:
    """Attach the scene's ``sensors`` list to ``system`` (an arm; refused elsewhere)."""
    from ..systems.arm import ArmSystem
    from ..systems.sensors import BIAS_KEYS, NOISE_KEYS, Sensor, SensorSet
    path = 'sensors'
    items = ctx.sequence(items, path)
    if not items:
        return
    if not isinstance(system, ArmSystem):
        ctx.fail(path, f'sensors are read on an arm ({type(system).__name__} here): an arm or urdf part on the world, '
                       'mount: free, or a floating URDF on a ground part')
    model = system.model
    links = list(model.link_names[:model.nb])
    joints = list(model.joint_names)
    out, names = [], set()
    for i, it in enumerate(items):
        ip = _key(path, i)
        if not isinstance(it, dict) or it.get('kind') not in ('imu', 'force_torque'):
            ctx.fail(_key(ip, 'kind'), f"expected kind: imu or kind: force_torque, got {it!r}")
        kind = it['kind']
        opt = ('name', 'noise', 'bias', 'seed') + (('link',) if kind == 'imu' else ('frame',))
        ctx.mapping(it, ip, required=('kind', 'link' if kind == 'imu' else 'joint'), optional=opt)

        def link_of(key, default=None):
            v = ctx.string(it[key], _key(ip, key)) if key in it else default
            if v not in links:
                ctx.fail(_key(ip, key), f'no link {v!r} in {model.name}; links are {links}')
            return v
        if kind == 'imu':
            frame = link_of('link')
            body, joint = links.index(frame), ''
            name = ctx.string(it.get('name', frame), _key(ip, 'name'))
        else:
            joint = ctx.string(it['joint'], _key(ip, 'joint'))
            if joint not in joints:
                ctx.fail(_key(ip, 'joint'), f'no joint {joint!r} in {model.name}; joints are {joints}')
            body = joints.index(joint)
            frame = link_of('frame', links[body])
            name = ctx.string(it.get('name', joint), _key(ip, 'name'))
        if (kind, name) in names:
            ctx.fail(_key(ip, 'name'), f'duplicate {kind} sensor name {name!r}')
        names.add((kind, name))
        noise, bias = {}, {}
        if 'noise' in it:
            npath = _key(ip, 'noise')
            ctx.mapping(it['noise'], npath, optional=tuple(NOISE_KEYS[kind]))
            noise = {k: ctx.number(v, _key(npath, k), minimum=0.0) for k, v in it['noise'].items()}
        if 'bias' in it:
            bpath = _key(ip, 'bias')
            ctx.mapping(it['bias'], bpath, optional=BIAS_KEYS[kind])
            bias = {k: ctx.vector(v, _key(bpath, k), 3) for k, v in it['bias'].items()}
        seed = int(ctx.number(it.get('seed', 0), _key(ip, 'seed'), minimum=0.0))
        out.append(Sensor(kind=kind, name=name, frame=frame, body=body, frame_body=links.index(frame), joint=joint,
                          noise=noise, bias=bias, seed=seed))
    try:
        system.attach_sensors(SensorSet(out))
    except ValueError as e:
        ctx.fail(path, str(e))

