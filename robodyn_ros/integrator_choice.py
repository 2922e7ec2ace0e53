"""Which integrator a run uses, with which step, and why: the run's :class:`IntegratorPlan`.

This is the one room that decides. :func:`plan_integrator` makes the decision once per run, at the
run's initial state, and returns it as a plan: the method, its step or tolerances, the step budget,
the reason (when ``auto`` chose) and the step analysis behind it, with the warnings the run must
give. The :class:`~robodyn_ros.simulation.Simulator` asks for it when it is built, or is handed the
plan that ``robodyn run``, the node or a sweep made for the same state (:func:`robodyn_ros.runs.plan_run`,
which also writes the choice into the settings a recording keeps); it then builds its integrator from
the plan (:meth:`IntegratorPlan.build`) and spends the plan's step budget (:class:`StepBudget`). The
analysis itself (linearisation, eigenvalues, stability functions, the words of a refusal) is
:mod:`robodyn_ros.stability`, which this room calls.

The decision, in order:

1. **The name**: a registry name of :data:`robodyn_ros.integrators.INTEGRATORS`, or ``auto`` (also no
   name at all), the default wherever a scene, a command line or the node's parameters name none.
2. **Preflight** (:func:`robodyn_ros.stability.preflight`): a singular mass matrix or a non-finite
   derivative at the initial state is refused, its cause named, whatever the method.
3. **A named method** is checked, not replaced: a fixed explicit step beyond the system's declared
   fastest time constant (:data:`STABILITY_LIMIT`), or one that the step analysis refuses
   (:func:`robodyn_ros.stability.analyse_step`: a mode amplified by more than 1 % per step), raises
   ValueError naming the mode and the alternatives (rosenbrock2 first when it is stable there); a slow
   spurious growth becomes a warning of the plan. Error-controlled methods are not analysed (they
   adapt, or are stable): their step budget bounds them.
4. **auto** takes the cheapest method that is stable at the requested step dt and meets the tolerance,
   from the step analysis at the initial state (one finite-difference linearisation) and at the states
   the system names in ``analysis_states`` (a robot above a ground: resting on it, where the contact's
   stiffness and friction slope show; every rung must hold at each), on this ladder:

   1. ``rk4`` at dt, when no mode is too fast for it: nothing is stiff.
   2. ``rosenbrock2`` at dt, when rk4 is refused and the fast modes are passive forces (joint damping,
      Coulomb friction near rest, joint-limit stops, ground contact, motor electrics) that its linearly
      implicit stage holds, so that what it leaves explicit is stable. With a tolerance (``rtol`` given
      alongside dt) it must also meet it: its local error per step on the slow modes,
      ``|R(hλ) − e^{hλ}| ≈ |hλ|³/6`` (Heun's on what is explicit), must be at most rtol.
   3. ``radau`` at rtol (default :data:`AUTO_RTOL`, :data:`AUTO_ATOL`) otherwise: stiffness that is not
      passive (a mode the fixed step cannot resolve explicitly), or a tolerance the fixed step misses.

   Costs per step, for the order of the ladder: rk4 four evaluations of f (four ABA); rosenbrock2 about
   two (a CRBA, a Cholesky factorisation of the nv × nv iteration matrix, one RNEA, one ABA); radau a
   Newton iteration per step with error control (tens of evaluations, Jacobians by finite differences).
   What auto picks for each bundled scene, and why, is the table of docs/integrators.md (tested).
5. **The step budget** (:data:`STEP_BUDGET`, or the run's): accepted steps per simulated second an
   error-controlled method may take before the run stops, naming the stiff mode
   (:meth:`IntegratorPlan.over_budget`).

numpy and the analysis are imported when a plan is made, not with this module: ``robodyn --help``
prints the defaults below without them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ['AUTO', 'DEFAULT_DT', 'AUTO_RTOL', 'AUTO_ATOL', 'STEP_BUDGET', 'STEP_BURST', 'STABILITY_LIMIT',
           'IntegratorPlan', 'StepBudget', 'plan_integrator', 'is_auto', 'check_step_budget']

#: the integrator name that asks for the choice
AUTO = 'auto'
#: step (s) of a fixed-step method when the run and its scene give none
DEFAULT_DT = 1e-3
#: tolerances of an error-controlled method when the run and its scene give none (auto's last rung, and
#: an error-controlled method named by ``robodyn run``, the node or a sweep)
AUTO_RTOL, AUTO_ATOL = 1e-8, 1e-10
#: default step budget of the error-controlled integrators: accepted steps per simulated second.
#: The bundled scenes take at most 1.4e3 under rk45 or dop853 at the default tolerances
#: (huston_human17), the stiffest runs of the tests 1.7e4 (dop853 on a 1e-9 kg·m² link, rk45 on
#: 5.9 µs motor electrics: the numerical-extremes table): 12x below this
STEP_BUDGET = 2e5
#: simulated seconds of budget a run may spend at once (its bursts: a first step found by trial,
#: an impact): over any stretch of W seconds a run takes at most ``budget * (W + STEP_BURST)`` steps
STEP_BURST = 0.05
#: largest stable ``h/τ`` of the fixed-step explicit methods on a decaying mode ``ẏ = −y/τ`` (the
#: real-axis extent of their stability regions: Euler 2, classical RK4 2.785), checked against the
#: system's declared fastest time constant before the step analysis
STABILITY_LIMIT = {'euler': 2.0, 'semi_implicit_euler': 2.0, 'rk4': 2.785}


def is_auto(name) -> bool:
    """True for ``'auto'`` (any case) and for no name at all (None, '')."""
    return not name or str(name).strip().lower() == AUTO


def check_step_budget(value, what='step_budget') -> float | None:
    """A step budget as given (steps per simulated second, > 0; ``inf`` = none; None = the default)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0 or math.isnan(value):
        raise ValueError(f'{what} must be a number of steps per simulated second > 0 (inf: no budget), got {value!r}')
    return float(value)


@dataclass(frozen=True)
class IntegratorPlan:
    """How a run integrates, decided once by :func:`plan_integrator`.

    integrator: registry name (never ``'auto'``); dt: the fixed step (s; for an error-controlled method
    named by the run, the dt it was given, unused); rtol, atol: tolerances of an error-controlled method
    (None: the integrator's defaults; None for auto's fixed-step choices); step_budget: accepted steps
    per simulated second an error-controlled method may take (inf: none); auto: True when ``auto``
    chose; reason: auto's one sentence for the summary and the recording's metadata ('' when the run
    named its method); analysis: the :class:`~robodyn_ros.stability.StepAnalysis` of the fixed-step
    method at the initial state (None for error-controlled ones); warnings: texts of the
    ``StepWarning`` the run gives (a slow spurious growth), emitted by the Simulator that adopts the plan.
    """

    integrator: str
    dt: float | None
    rtol: float | None
    atol: float | None
    step_budget: float = STEP_BUDGET
    auto: bool = False
    reason: str = ''
    analysis: object = None
    warnings: tuple = ()

    @property
    def fixed_step(self) -> bool:
        """True for a fixed-step method (dt), False for an error-controlled one (rtol/atol)."""
        from .integrators import INTEGRATORS
        return INTEGRATORS[self.integrator].kind == 'fixed'

    def settings(self) -> dict:
        """``{integrator, dt, rtol, atol}`` and, when auto chose, ``auto``: the reason."""
        out = {'integrator': self.integrator, 'dt': self.dt, 'rtol': self.rtol, 'atol': self.atol}
        if self.auto:
            out['auto'] = self.reason
        return out

    def build(self, system):
        """A fresh :class:`robodyn_ros.integrators.Integrator` of this plan for ``system`` (its ``nq`` and
        ``config_rate`` for the symplectic Euler split); the settings that do not apply to the method's kind
        are left out. Raises ValueError for settings the integrator refuses (a tolerance below round-off)."""
        from .integrators import CONTROLLABLE, INTEGRATORS, make_integrator
        spec = INTEGRATORS[self.integrator]
        if spec.kind == 'fixed':
            kw = {'dt': self.dt}
            if spec.name == 'semi_implicit_euler':
                kw.update(nq=system.nq, qdot=system.config_rate)
            if spec.name in CONTROLLABLE and self.rtol is not None and not self.auto:
                kw.update(rtol=self.rtol, atol=self.atol)   # error control, dt the largest step
            return make_integrator(spec.name, **kw)
        return make_integrator(spec.name, rtol=self.rtol, atol=self.atol)

    def over_budget(self, system, y, u, t: float, steps: int, simulated: float) -> str:
        """The message of a run stopped by its step budget: the integrator, the ``steps`` it took over
        ``simulated`` seconds, the stiff mode at the last good state y (time t, inputs u held;
        :func:`robodyn_ros.stability.stiff_mode`) and what to do."""
        from .integrators import INTEGRATORS
        from .stability import stiff_mode
        name = self.integrator
        text = (f'{name} spent its step budget: {steps} steps for {simulated:.3g} s of simulated time '
                f'(budget {self.step_budget:.3g} steps per simulated second); ')
        mode = stiff_mode(system, y, u, t)
        text += (f'{mode}; ' if mode else '')
        if INTEGRATORS[name].implicit:
            text += (f'{name} is stable on it, so its error control needs these steps' if mode else
                     f'no mode is stiff there: its error control needs these steps for rtol={self.rtol:g}')
            text += ': loosen rtol/atol or raise the budget'
        else:
            stiff = ['radau', 'bdf'] + [n for n, s in INTEGRATORS.items() if s.kind == 'fixed' and s.implicit]
            text += (f'an explicit method ({name}) must take steps about as short as that time constant, for '
                     f'as long as the mode lasts: use an implicit integrator ({", ".join(stiff)}), '
                     'or raise the budget')
        return (text + ' (simulation: step_budget in the scene, robodyn run --step-budget, the node\'s '
                'step_budget parameter; inf = none). Last good state kept')


class StepBudget:
    """The plan's step budget as a token bucket that holds :data:`STEP_BURST` seconds' worth.

    rate: accepted steps per simulated second (inf: no budget). Before each call of an error-controlled
    integrator over ``span`` simulated seconds, :meth:`limit` gives the most steps it may take; after it,
    :meth:`spend` takes the steps it took. A run that spends the bucket stops (``StepBudgetError``)
    instead of creeping on at an explicit method's stability limit for hours.
    """

    def __init__(self, rate: float):
        self.rate = float(rate)
        self.reset()

    def reset(self):
        """A full bucket (a new run or episode)."""
        self.tokens = self.rate * STEP_BURST

    def limit(self, span: float) -> int | None:
        """The most accepted steps the next ``span`` seconds may take (None: no budget)."""
        if not math.isfinite(self.rate):
            return None
        return max(1, int(self.tokens + self.rate * span))

    def spend(self, limit: int, steps: int):
        """Take ``steps`` from a call that was allowed ``limit`` (:meth:`limit`)."""
        self.tokens = min(self.rate * STEP_BURST, limit - steps)


def plan_integrator(system, y, integrator=AUTO, dt=DEFAULT_DT, rtol=None, atol=None, step_budget=None,
                    t: float = 0.0, u=None) -> IntegratorPlan:
    """Decide how ``system`` is integrated from state y at time t (module docstring); the one place that does.

    system: the System; y: (ny,) initial state; integrator: registry name or ``'auto'`` (None, '' too);
    dt: the requested fixed step (s); rtol, atol: tolerances (optional; with auto, rtol also bounds the
    fixed step's estimated local error); step_budget: steps per simulated second of an error-controlled
    method (None: :data:`STEP_BUDGET`; inf: none); t: the start time (s); u: the inputs in force at the
    start (name -> values; None: the analysis' default, zeros). Raises ValueError, naming the cause, for an
    unknown name, a state that cannot be integrated, or a named fixed step the analysis refuses.
    """
    import numpy as np

    from .integrators import CONTROLLABLE, INTEGRATORS
    from .stability import preflight
    budget = check_step_budget(step_budget)
    budget = STEP_BUDGET if budget is None else budget
    auto = is_auto(integrator)
    name = AUTO if auto else str(integrator).strip().lower()
    if not auto and name not in INTEGRATORS:
        raise ValueError(f'unknown integrator {integrator!r}; valid names: {", ".join(INTEGRATORS)}')
    y = np.asarray(y, dtype=float)
    preflight(system, y, t)  # a singular mass matrix or non-finite dy/dt: refused, cause named
    if auto:
        name, dt, rtol, atol, reason, analysis = _auto(system, y, dt, rtol, atol, t, u)
    elif name in CONTROLLABLE and rtol is not None:
        # rosenbrock2 under error control: not analysed, as the error-controlled methods are not (its steps
        # adapt to what its largest, dt, cannot resolve; its step budget bounds it); atol defaults to rtol
        reason, analysis = '', None
        atol = rtol if atol is None else atol
    else:
        reason, analysis = '', _check_named(system, name, dt, y, t, u)
    warns = (analysis.message,) if analysis is not None and analysis.verdict == 'warn' else ()
    return IntegratorPlan(name, dt, rtol, atol, step_budget=budget, auto=auto, reason=reason, analysis=analysis,
                          warnings=warns)


def _check_named(system, name: str, dt, y, t: float, u=None):
    """The analysis of a fixed step the run named (None for error-controlled methods, or no dt), or
    ValueError when it is unstable: beyond the system's declared fastest time constant
    (:data:`STABILITY_LIMIT`), then on the modes of the linearisation at y
    (:func:`robodyn_ros.stability.analyse_step`; a free base's spin included)."""
    from .stability import FIXED_STEP, analyse_step, step_alternatives
    if dt is None or name not in FIXED_STEP:
        return None
    limit = STABILITY_LIMIT.get(name)   # explicit methods: the declared time constant first
    tau = float(system.fastest_time_constant(y)) if limit is not None else math.inf
    if limit is not None and dt > limit * tau:
        raise ValueError(f'{name} with dt={dt:g} s is unstable for this system: its fastest time constant is '
                         f'{tau:.3g} s ({type(system).__name__}'
                         f'{getattr(system, "time_constant_words", "") or "; e.g. motor electrics L/R"}), '
                         f'so a stable {name} step is at most {limit * tau:.3g} s. '
                         f'{step_alternatives(system, dt, y, u, t)}')
    if getattr(system, 'ny', 0) == 0:
        return None
    a = analyse_step(system, name, dt, y, u, t)
    if a.verdict == 'refuse':
        raise ValueError(a.message)
    return a


def _fastest(a) -> str:
    return f'fastest mode |λ| = {a.lam_max:.3g} 1/s, h·|λ| = {a.dt * a.lam_max:.3g}'


def _auto(system, y, dt, rtol, atol, t: float, u=None):
    """auto's ladder (module docstring, 4): ``(integrator, dt, rtol, atol, reason, analysis)``."""
    import numpy as np

    from .stability import analyse_step, linearisation
    h = float(dt)
    if not (math.isfinite(h) and h > 0.0):
        raise ValueError(f'integrator auto needs a step dt > 0 (s), got {dt!r}')
    if getattr(system, 'ny', y.size) == 0:
        return 'rk4', h, None, None, 'auto chose rk4: the system has no state to integrate', None
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
        return ('rk4', h, None, None, f'auto chose rk4 at dt={h:g} s: no mode is stiff{where} ({_fastest(a4)}; '
                f'rk4 is stable up to h·|λ| ≈ 2.8)', a4)
    why4 = (f'rk4 does not resolve a joint stop at dt={h:g} s (h/τ = {h / a4.system_tau:.3g})'
            if a4.extra.get('stop') else f'rk4 is unstable at dt={h:g} s{where} ({_fastest(a4)})')
    a2, all2, _ = worst('rosenbrock2')
    if a2.verdict != 'refuse':
        a2 = max(all2, key=_local_error)
    if a2.verdict != 'refuse':
        err = _local_error(a2)
        if rtol is None or err <= rtol:
            tol = '' if rtol is None else f', estimated local error {err:.2g} per step <= rtol {rtol:g}'
            return ('rosenbrock2', h, None, None,
                    f'auto chose rosenbrock2 at dt={h:g} s: {why4}, and the fast modes are passive forces, which '
                    f'rosenbrock2 integrates implicitly (fastest explicit mode '
                    f'|λ| = {a2.extra["explicit_lam_max"]:.3g} 1/s{tol})', a2)
        why2 = f'rosenbrock2 misses rtol {rtol:g} (estimated local error {err:.2g} per step)'
    else:
        why2 = (f'rosenbrock2 is unstable too (the stiffness is not passive: fastest explicit mode '
                f'|λ| = {a2.extra["explicit_lam_max"]:.3g} 1/s)')
    rt = AUTO_RTOL if rtol is None else float(rtol)
    at = AUTO_ATOL if atol is None else atol
    return 'radau', None, rt, at, f'auto chose radau rtol={rt:g} atol={at:g}: {why4}; {why2}', None


def _local_error(a) -> float:
    """rosenbrock2's estimated local relative error per step on the slow explicit modes (|hλ| <= 1):
    ``|R(z) − e^z|`` of Heun's method, about ``|z|³/6``; 0 when there are none."""
    import numpy as np
    h = a.dt
    errs = [abs(1 + z + z * z / 2 - np.exp(z)) for z in (h * complex(m) for m in a.eigenvalues) if abs(z) <= 1.0]
    return float(max(errs, default=0.0))
