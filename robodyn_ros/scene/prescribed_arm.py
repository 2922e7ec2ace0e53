"""The ``prescribed_arm`` part: an arm whose end point is driven along a planar path.
"""
from __future__ import annotations

from ..validation import SceneContext
from ..validation import key_path as _key
from .arm import _ARM_OPTIONAL, _ARM_REQUIRED, build_arm_part
from .part import Part


_PRESCRIBED_KEYS = ('end_effector', 'end_effector_path', 'formulation', 'baumgarte')


def build_prescribed_arm_part(spec: dict, path: str, ctx: SceneContext) -> Part:
    """Build a ``prescribed_arm`` part: an arm whose end point E is driven along a planar path.

    Huston §19.16–19.18 (see :mod:`robodyn_ros.systems.prescribed`). The keys of an ``arm``
    part plus: ``end_effector`` (link whose frame origin is E; default the last link),
    ``end_effector_path: {kind: circle | line, plane: xy | xz | yz, <kind parameters>}``,
    ``formulation: complement | kkt`` (default complement) and ``baumgarte: {alpha, beta}``
    (1/s). ``actuated`` defaults to none here (free pins, problem P19.16.1).
    """
    from ..systems import prescribed as pr
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
