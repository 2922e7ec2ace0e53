"""The ``diff_drive`` part: a differential-drive platform (chassis, two wheels, two DC motors).
"""
from __future__ import annotations

import numpy as np

from ..model import ModelError
from ..validation import SceneContext
from ..validation import key_path as _key
from .arm import _refuse_limit_moments
from .part import Part


_MOTOR_KEYS = ('kind', 'torque_constant', 'resistance', 'inductance', 'gear_ratio', 'rotor_inertia',
               'viscous_friction', 'coulomb_friction', 'coulomb_velocity', 'supply_voltage')
_WHEEL_KEYS = {'radius': 'wheel_radius', 'half_track': 'half_track', 'mass': 'wheel_mass',
               'spin_inertia': 'wheel_spin_inertia', 'diametral_inertia': 'wheel_diametral_inertia'}


def _dc_motor(ctx: SceneContext, spec, path: str):
    """A :class:`~robodyn_ros.systems.motor.DCMotor` from a ``dc_motor`` mapping."""
    from ..systems.motor import DCMotor
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
    from ..systems import diffdrive as dd
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
    from ..systems.diffdrive import DiffDriveSystem
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
                               arm_actuated=arm.system.actuated, gravity=ctx.gravity, name=drive.name,
                               arm_root_visuals=am.root_visuals or ())
    except (ModelError, ValueError) as e:
        ctx.fail(arm.path, f'cannot mount it on {drive.name!r}: {e}')
