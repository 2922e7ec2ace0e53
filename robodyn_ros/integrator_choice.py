"""``integrator: auto``: the cheapest integrator that is stable at the requested step and meets the tolerance.

The default wherever a scene, a command line or the node's parameters name no integrator. The choice is
made once, at the initial state, from the step preflight's eigen-analysis
(:func:`robodyn_ros.stability.analyse_step` on one finite-difference linearisation), and also at the states
the system names in ``analysis_states`` (a robot above a ground: resting on it, where the contact's
stiffness and friction slope show; every rung must hold at each), on this ladder:

1. ``rk4`` at dt, when no mode is too fast for it: nothing is stiff. The scenes that run today keep
   their method and their bytes.
2. ``rosenbrock2`` at dt, when rk4 is refused and the fast modes are passive forces (joint damping,
   Coulomb friction near rest, joint-limit stops, motor electrics) that its linearly implicit stage
   holds, so that what it leaves explicit is stable. With a tolerance (``rtol`` given alongside dt) it
   must also meet it: its local error per step on the slow modes, ``|R(hλ) − e^{hλ}| ≈ |hλ|³/6``
   (Heun's on what is explicit), must be at most rtol.
3. ``radau`` at rtol (default :data:`AUTO_RTOL`, :data:`AUTO_ATOL`) otherwise: stiffness that is not
   passive (a mode the fixed step cannot resolve explicitly), or a tolerance the fixed step misses.

Costs per step, for the order of the ladder: rk4 four evaluations of f (four ABA); rosenbrock2 about two
(a CRBA, a Cholesky factorisation of the nv × nv iteration matrix, one RNEA, one ABA); radau a Newton
iteration per step with error control (tens of evaluations, and Jacobians by finite differences).
The choice and its reason go to the run summary and the recording's metadata.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .stability import StepAnalysis, analyse_step, linearisation

__all__ = ['AUTO', 'AUTO_RTOL', 'AUTO_ATOL', 'IntegratorChoice', 'choose_integrator', 'is_auto']

#: the integrator name that asks for the choice
AUTO = 'auto'
#: tolerances of the error-controlled last rung when the settings give none (the CLI's adaptive defaults)
AUTO_RTOL, AUTO_ATOL = 1e-8, 1e-10


def is_auto(name) -> bool:
    """True for ``'auto'`` (any case) and for no name at all (None, '')."""
    return not name or str(name).strip().lower() == AUTO


@dataclass(frozen=True)
class IntegratorChoice:
    """What ``auto`` chose: integrator (registry name), dt (s, fixed-step) or rtol/atol (error-controlled),
    reason (one sentence, for the summary and the recording's metadata), analysis: the step analysis of the
    chosen fixed-step method (None for radau)."""

    integrator: str
    dt: float | None
    rtol: float | None
    atol: float | None
    reason: str
    analysis: StepAnalysis | None = None


def _fastest(a: StepAnalysis) -> str:
    return f'fastest mode |λ| = {a.lam_max:.3g} 1/s, h·|λ| = {a.dt * a.lam_max:.3g}'


def choose_integrator(system, y, dt, rtol=None, atol=None, t: float = 0.0, u=None) -> IntegratorChoice:
    """Pick rk4, rosenbrock2 or radau for ``system`` from state y (module docstring).

    dt: the requested fixed step (s); rtol, atol: the tolerance (optional; rtol also bounds the fixed
    step's estimated local error); t, u: time and inputs of the linearisation (default 0, zeros).
    """
    h = float(dt)
    if not (math.isfinite(h) and h > 0.0):
        raise ValueError(f'integrator auto needs a step dt > 0 (s), got {dt!r}')
    y = np.asarray(y, dtype=float)
    if getattr(system, 'ny', y.size) == 0:
        return IntegratorChoice('rk4', h, None, None, 'auto chose rk4: the system has no state to integrate')
    states = [y] + [np.asarray(s, dtype=float) for s in system.analysis_states(y)] \
        if hasattr(system, 'analysis_states') else [y]
    Js = [linearisation(system, s, u, t) for s in states]

    def worst(name):   # the analysis at the state where the method fares worst (a refusal first), its words
        out = [analyse_step(system, name, h, s, u, t, J=J) for s, J in zip(states, Js)]
        k = next((i for i, a in enumerate(out) if a.verdict == 'refuse'), 0)
        return out[k], out, ('' if len(out) == 1 else ' resting on the ground (the state a landing meets)' if k
                             else ' at the initial state and resting on the ground')
    a4, _, where = worst('rk4')
    if a4.verdict != 'refuse':
        return IntegratorChoice('rk4', h, None, None,
                                f'auto chose rk4 at dt={h:g} s: no mode is stiff{where} ({_fastest(a4)}; rk4 is '
                                f'stable up to h·|λ| ≈ 2.8)', a4)
    why4 = f'rk4 is unstable at dt={h:g} s{where} ({_fastest(a4)})'
    a2, all2, _ = worst('rosenbrock2')
    if a2.verdict != 'refuse':
        a2 = max(all2, key=_local_error)
    if a2.verdict != 'refuse':
        err = _local_error(a2)
        if rtol is None or err <= rtol:
            tol = '' if rtol is None else f', estimated local error {err:.2g} per step <= rtol {rtol:g}'
            return IntegratorChoice('rosenbrock2', h, None, None,
                                    f'auto chose rosenbrock2 at dt={h:g} s: {why4}, and the fast modes are passive '
                                    f'forces, which rosenbrock2 integrates implicitly (fastest explicit mode '
                                    f'|λ| = {a2.extra["explicit_lam_max"]:.3g} 1/s{tol})', a2)
        why2 = f'rosenbrock2 misses rtol {rtol:g} (estimated local error {err:.2g} per step)'
    else:
        why2 = (f'rosenbrock2 is unstable too (the stiffness is not passive: fastest explicit mode '
                f'|λ| = {a2.extra["explicit_lam_max"]:.3g} 1/s)')
    rt = AUTO_RTOL if rtol is None else float(rtol)
    at = AUTO_ATOL if atol is None else atol
    return IntegratorChoice('radau', None, rt, at, f'auto chose radau rtol={rt:g} atol={at:g}: {why4}; {why2}')


def _local_error(a: StepAnalysis) -> float:
    """rosenbrock2's estimated local relative error per step on the slow explicit modes (|hλ| <= 1):
    ``|R(z) − e^z|`` of Heun's method, about ``|z|³/6``; 0 when there are none."""
    h = a.dt
    errs = [abs(1 + z + z * z / 2 - np.exp(z)) for z in (h * complex(m) for m in a.eigenvalues) if abs(z) <= 1.0]
    return float(max(errs, default=0.0))
