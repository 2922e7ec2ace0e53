"""A scene's initial state, its stop condition and its run settings (``simulation`` section).
"""
from __future__ import annotations

import numpy as np

from ..model import PRISMATIC, REVOLUTE
from ..validation import SceneContext, typename
from ..validation import key_path as _key

#: run settings a scene's ``simulation`` section may override (the CLI/node may override again)
DEFAULT_SETTINGS = {'integrator': 'auto', 'dt': 1e-3, 'publish_rate': 100.0, 'duration': 10.0}
_SETTING_KEYS = ('integrator', 'dt', 'rtol', 'atol', 'publish_rate', 'duration', 'step_budget')


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

