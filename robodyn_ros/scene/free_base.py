"""The ``free_base`` part: a 6-DOF platform, alone or carrying arms mounted on it.
"""
from __future__ import annotations

import numpy as np

from ..model import LinkSpec, ModelError
from ..validation import SceneContext
from ..validation import key_path as _key
from .arm import _inertial, _refuse_limit_moments
from .part import Part


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
    from ..systems import freeflyer as ff
    from ..systems.augmented import AugmentedFreeFlyerSystem
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


def _assemble_free_base(ctx: SceneContext, parts: list):
    """A free base and the arm parts mounted on it -> one free-flyer system."""
    bases = [p for p in parts if p.kind == 'free_base']
    if len(bases) != 1:
        ctx.fail(_key(bases[1].path, 'kind'), 'a scene can have one free_base part')
    fb = bases[0]
    arms = [p for p in parts if p is not fb]
    link = fb.system.base_link
    specs, actuated, mounted = [], [], []
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
        if p.system.model.root_visuals:   # an imported arm's root link, drawn on the base's
            mounted.append((link, p.system.model.root_visuals))
    try:
        return fb.system.with_arm(specs, actuated=actuated, mounted_visuals=mounted) if arms else fb.system
    except (ModelError, ValueError) as e:
        ctx.fail(fb.path, str(e))
