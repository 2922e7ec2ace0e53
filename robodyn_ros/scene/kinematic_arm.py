"""The ``kinematic_arm`` part: an arm whose 1-DOF joints follow functions of time.
"""
from __future__ import annotations

import numpy as np

from ..validation import SceneContext
from ..validation import key_path as _key
from .arm import _ARM_OPTIONAL, _ARM_REQUIRED, build_arm_part
from .part import Part


def build_kinematic_arm_part(spec: dict, path: str, ctx: SceneContext) -> Part:
    """Build a ``kinematic_arm`` part: an arm whose 1-DOF joints follow functions of time.

    The keys of an ``arm`` part (``dh`` or ``links``; no ``actuated``: every joint is driven)
    plus ``motion: {<joint>: <expression of t>, ...}`` for every 1-DOF joint, written with the
    whitelist of :mod:`robodyn_ros.expressions` (e.g. ``pi/3 + t``). The system
    (:mod:`robodyn_ros.systems.kinematic`) publishes the inverse-dynamics efforts that make the
    arm follow the motion. A parameter that varies in time but is not a joint variable (Betancur's
    DH twist alpha_2(t)) is written as an extra driven joint with a massless child frame.
    """
    from ..expressions import ExpressionError, parse_time_function
    from ..systems.kinematic import KinematicArmSystem
    ctx.mapping(spec, path, required=_ARM_REQUIRED + ('motion',),
                optional=tuple(k for k in _ARM_OPTIONAL if k != 'actuated'))
    from ..systems.base import backend_scope, default_backend
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
