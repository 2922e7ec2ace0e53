"""``robodyn bench precision``: what every integrator costs and achieves, per scene.

For each scene, every integrator runs over a ladder of fixed steps (euler,
semi_implicit_euler, rk4, rosenbrock2) or tolerances (rk45, dop853, radau, bdf, lsoda; ``atol = rtol``; and
rosenbrock2 under error control, ``rosenbrock2+rtol``, one publication period its largest step), and, where the scene has more than one formulation (a free base: minimal / augmented; a
prescribed end point: complement / kkt), once per formulation. A run is the product's own loop:
a :class:`~robodyn_ros.simulation.Simulator` advanced in publication periods of the scene
(``publish_rate``) with the scene's scripted commands held over each period, exactly as
``robodyn run`` does. Error-controlled integrators restart at every period (the commands may
jump there), so at loose tolerances their cost has a floor of one step per period.

Per run it records:

* ``wall_per_sim_s`` — wall seconds spent in ``Simulator.advance`` per simulated second, and
  ``cpu_per_sim_s`` — the process CPU seconds of the same calls (the scripted commands and the
  diagnostics are not counted). Both depend on the machine; CPU time does not count the time
  other processes take the CPU from this one, so it is the cost used for choosing (the cheapest
  run below, ``robodyn advise``) and plotted;
* ``rhs_evals`` — evaluations of the right-hand side (finite-difference Jacobians included),
  and accepted / rejected steps (rejected unknown for radau, bdf, lsoda);
* ``error`` — the final-state error ``max_i |y_i − y_ref,i| / (1 + |y_ref,i|)`` in minimal
  coordinates ``[q; v]`` (so formulations compare against one reference; quaternion signs
  aligned), against a closed form where the scene has one (``closed_form``), otherwise against
  DOP853 at rtol = atol = 1e-13 with its step bounded to a quarter of a publication period
  (:data:`REFERENCE_STEPS_PER_PERIOD`), checked against the same with an eighth: their difference
  (at least :data:`ROUNDOFF_FLOOR`) is the reference's error estimate, its floor. The bound keeps
  the reference from taking the very steps of a measured run: held commands make every period a
  fresh start, and a smooth scene is met by one DOP853 step per period at any rtol, so an
  unbounded reference would agree with the run it measures to the last bit. An error at or below
  the floor is printed as "≤ floor", never as 0; an error-controlled run that took one step per
  period is marked so (a tighter or looser rtol gives the same run);
* ``energy_drift`` — the largest ``|E − E0 − W|`` over the periods divided by the largest of
  ``|E0|, |E|, |W|`` over the run (W = work done by inputs and dissipation),
  ``momentum_drift`` — the largest change of linear
  (N·s) and angular (N·m·s) momentum of a free-floating system in orbit without base thrust,
  ``constraint_residual`` — the largest constraint residual reported by the system (m, or m/s
  for the rolling constraints), sampled at up to ``SAMPLES`` instants;
* ``status`` — ``ok``, ``refused`` (the simulator refused the step before starting: the
  message names the unstable mode), ``failed`` (stopped with the cause: non-finite state,
  solver failure) or ``budget`` (stopped after ``--budget`` wall seconds); a warning the
  simulator issued (e.g. explicit Euler amplifying an oscillation) is kept in ``note``.

Outputs, in ``--out`` (default ``docs/precision``): ``<scene>.csv`` (one row per run),
``<scene>.md`` (the table, the reference, and the cheapest run for each of 1e-3, 1e-6, 1e-9),
``<scene>.png`` (work-precision diagram: error against rhs evaluations and against CPU time,
log–log, one line per method and formulation) and ``summary.md`` (the cheapest runs of every
scene). The measurements are also stored for ``robodyn advise`` (:mod:`robodyn_ros.measurements`).

``--quick`` uses the short ladder ``robodyn advise`` runs when it has no measurements.
``--workers N`` / ``--scheduler ADDRESS`` run every scene's reference and each method's ladder as
tasks on Dask (:class:`robodyn_ros.pool.Pool`, the machinery of ``robodyn sweep``), side by side;
the tables are the same apart from the timing columns. The default (0) runs them one after the
other in this process, so that no timed run shares the CPU with another.
"""
from __future__ import annotations

import csv
import math
import os
import sys
import time
import warnings
from dataclasses import dataclass

import numpy as np

from ..measurements import CSV_FIELDS, Run, cost_key, store
from ..measurements import load_scene_quietly as _load
from ..measures import Progress as _Progress
from ..measures import state_error  # noqa: F401  (used here and by bench.extremes)

HELP = 'work-precision: error vs cost of every integrator and formulation per scene (CSV, markdown, PNG)'

#: scenes measured when none are named (those that exist in this install)
DEFAULT_SCENES = ('betancur_pendulum', 'huston_p19_2_3', 'stanford_arm', 'betancur_platform',
                  'huston_prescribed_planar3', 'unfried_free_flyer')
#: fixed steps (s) per method; steps longer than the publication period are left out
FIXED_LADDERS = {
    'full': {'euler': (1e-2, 3e-3, 1e-3, 3e-4, 1e-4),
             'semi_implicit_euler': (1e-2, 3e-3, 1e-3, 3e-4, 1e-4),
             'rk4': (2e-2, 1e-2, 5e-3, 2e-3, 1e-3, 5e-4),
             'rosenbrock2': (1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 2e-4)},
    'quick': {'euler': (1e-2, 1e-3), 'semi_implicit_euler': (1e-2, 1e-3), 'rk4': (1e-2, 3e-3, 1e-3),
              'rosenbrock2': (1e-2, 3e-3, 1e-3)},
}
#: relative tolerances of the error-controlled methods (atol = ATOL_FACTOR * rtol)
ADAPTIVE_LADDERS = {'full': (1e-3, 1e-5, 1e-7, 1e-9, 1e-11), 'quick': (1e-4, 1e-6, 1e-8, 1e-10)}
ATOL_FACTOR = 1.0
#: simulated seconds per run
HORIZONS = {'full': 2.0, 'quick': 0.5}
#: wall seconds after which a run is stopped (status 'budget') and longer runs of that method skipped
BUDGETS = {'full': 120.0, 'quick': 20.0}
#: the reference's tolerance (DOP853, rtol = atol), and its step bound: at least this many steps per
#: publication period (its check takes twice as many), so that it never takes a measured run's steps
REFERENCE_RTOL, REFERENCE_STEPS_PER_PERIOD = 1e-13, 4
#: the smallest error estimate a reference is given (round-off of the final state's comparison)
ROUNDOFF_FLOOR = 1e-15
#: the closed forms' check (DOP853, unbounded)
CHECK_RTOL = 1e-12
#: accuracies for which the markdown names the cheapest run
TARGETS = (1e-3, 1e-6, 1e-9)
#: instants (evenly spread) at which outputs (momentum, constraint residual) are sampled
SAMPLES = 20
#: formulations a scene part may select: (part kind, key, values, preferred for the reference)
FORMULATION_KEYS = {'free_base': ('minimal', 'augmented'), 'prescribed_arm': ('complement', 'kkt')}
#: error-controlled methods
ADAPTIVE = ('rk45', 'dop853', 'radau', 'bdf', 'lsoda')
FIXED = ('euler', 'semi_implicit_euler', 'rk4', 'rosenbrock2')

@dataclass
class Reference:
    """The reference final state of a scene: ``kind`` 'closed form' or 'dop853 rtol=1e-13 ...';
    ``y`` (comparable coordinates); ``error_estimate``: its estimated error, the floor of the errors
    measured against it (difference to the convergence check run); ``check``: words on how it was
    checked; ``formulation`` it used; ``steps``: the steps it took (0 for a closed form)."""

    kind: str
    y: np.ndarray
    error_estimate: float
    check: str
    formulation: str = ''
    steps: int = 0


# ---------------------------------------------------------------------------------------------
# scenes, formulations, closed forms
# ---------------------------------------------------------------------------------------------
def formulations(scene) -> list:
    """``[(formulation, Scene)]``: the scene in each formulation its parts offer.

    The first entry is the preferred one for the reference (minimal, complement); a scene with
    one formulation gives ``[('', scene)]``. Variants are re-parsed from the scene's YAML with
    the part's ``formulation`` key changed.
    """
    import yaml
    from ..scene import parse_scene
    parts = scene.data.get('parts', [])
    for i, p in enumerate(parts):
        if isinstance(p, dict) and p.get('kind') in FORMULATION_KEYS:
            values = FORMULATION_KEYS[p['kind']]
            out = []
            for f in values:
                data = dict(scene.data)
                data['parts'] = [dict(q) for q in parts]
                data['parts'][i]['formulation'] = f
                text = yaml.safe_dump(data, sort_keys=False)
                with warnings.catch_warnings():
                    warnings.simplefilter('ignore')
                    out.append((f, parse_scene(text, file=scene.path, path=scene.path)))
            return out
    return [('', scene)]


def scene_formulation(scene) -> str:
    """The formulation the scene file itself selects ('' when it has no choice)."""
    for p in scene.data.get('parts', []):
        if isinstance(p, dict) and p.get('kind') in FORMULATION_KEYS:
            return p.get('formulation', FORMULATION_KEYS[p['kind']][0] if p['kind'] == 'free_base' else 'complement')
    return ''


def comparable(system, y) -> np.ndarray:
    """The state in minimal coordinates ``[q; v]`` (plus extra states such as motor currents),
    with a free base's quaternion sign fixed (w >= 0), so formulations can be compared."""
    y = np.asarray(y, dtype=float)
    minimal = getattr(system, 'minimal', None)
    if minimal is None:
        return y.copy()
    q, v = minimal(y)
    q = np.array(q, dtype=float)
    model = getattr(system, 'model', None)
    from ..model import FREE
    if model is not None and model.nb and model.jtype[0] == FREE and q[6] < 0:
        q[3:7] = -q[3:7]
    return np.concatenate([q, np.asarray(v, dtype=float)])


def closed_form(scene):
    """``f(t) -> comparable state`` of the exact solution, for scenes that have one, else None.

    Differential-drive platform without an arm, identical motors with ``L = 0``, no friction,
    driven from rest at yaw 0 with one constant voltage V on both motors (within the supply):
    it runs straight along x with ``v(t) = v_ss (1 − exp(−t/τ))``, ``v_ss = r V / (N K)``,
    ``τ = m_eff R r² / (2 N² K²)``, ``m_eff = m + (I_s,l + I_s,r) / r²`` (the module docstring
    of :mod:`robodyn_ros.systems.diffdrive`), so ``x = v_ss (t − τ (1 − exp(−t/τ)))`` and
    both wheels turn by ``x / r``.
    """
    from ..systems.diffdrive import DiffDriveSystem
    s = scene.system
    if not isinstance(s, DiffDriveSystem) or s.has_arm or s.n_current:
        return None
    m_l, m_r = s.motors
    if m_l != m_r or m_l.viscous_friction or m_l.coulomb_friction:
        return None
    cmd = (scene.data.get('commands') or {}).get('wheel_voltage')
    if set((scene.data.get('commands') or {})) - {'wheel_voltage'}:
        return None
    if not cmd or cmd.get('profile') != 'constant' or len(set(cmd['value'])) != 1:
        return None
    V = float(cmd['value'][0])
    if abs(V) > m_l.supply_voltage:
        return None
    if np.any(scene.y0 != 0.0):
        return None
    r, K, N, R = s.params.wheel_radius, m_l.torque_constant, m_l.gear_ratio, m_l.resistance
    m_eff = s._m + float(np.sum(s._Is)) / r ** 2
    v_ss = r * V / (N * K)
    tau = m_eff * R * r ** 2 / (2.0 * N ** 2 * K ** 2)
    nv = s.nv

    def exact(t):
        e = math.exp(-t / tau)
        x = v_ss * (t - tau * (1.0 - e))
        xd = v_ss * (1.0 - e)
        y = np.zeros(s.ny)
        y[0], y[3], y[4] = x, x / r, x / r
        y[nv + 0], y[nv + 3], y[nv + 4] = xd, xd / r, xd / r
        return y
    exact.description = (f'closed form: straight run, v_ss = {v_ss:.4g} m/s, tau = {tau:.4g} s '
                         f'(r V / (N K), m_eff R r² / (2 N² K²))')
    return exact


# ---------------------------------------------------------------------------------------------
# one run
# ---------------------------------------------------------------------------------------------
class _Budget(Exception):
    """A run exceeded its wall-time budget."""


def _momentum(extra) -> np.ndarray | None:
    keys = ('momentum_linear_x', 'momentum_linear_y', 'momentum_linear_z',
            'momentum_angular_com_x', 'momentum_angular_com_y', 'momentum_angular_com_z')
    if not all(k in extra for k in keys):
        return None
    return np.array([float(extra[k]) for k in keys])


def simulate(scene, integrator: str, dt=None, rtol=None, atol=None, horizon=1.0, budget=math.inf,
             formulation: str = '', sample: bool = True, max_step: float | None = None) -> Run:
    """Run ``scene`` for ``horizon`` s with one integrator setting and measure it (a :class:`Run`).

    scene: a loaded Scene; integrator: registry name; dt (fixed) or rtol/atol (adaptive), or both (rosenbrock2
    under error control, dt its largest step);
    horizon: simulated seconds (rounded to whole publication periods); budget: wall seconds
    before the run is stopped with status 'budget'; formulation: label recorded; sample: also
    sample outputs for momentum and constraint drift; max_step: the longest step (s) an
    error-controlled integrator may take (the reference's bound; None: unbounded, as ``robodyn run``).
    Never raises for a refused or failed run.
    """
    from ..simulation import SimulationError, Simulator
    kind = run_kind(integrator, dt, rtol)
    rate = float(scene.settings.get('publish_rate', 100.0))
    n = max(1, int(round(horizon * rate)))
    run = Run(scene=scene.name, formulation=formulation, integrator=integrator, kind=kind,
              dt=dt if kind != 'adaptive' else None, rtol=rtol if kind != 'fixed' else None,
              atol=atol if kind != 'fixed' else None, horizon=n / rate)
    system = scene.system
    if hasattr(system, 'reset_episode'):
        system.reset_episode()
    notes = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        try:
            sim = Simulator(system, scene.y0, integrator=integrator, dt=dt, rtol=rtol, atol=atol)
        except ValueError as e:
            run.status, run.note = 'refused', str(e)
            return run
        if max_step is not None:
            sim.integrator.max_step = float(max_step)
        momentum_ok = getattr(system, 'environment', '') == 'orbit' and not \
            (scene.data.get('commands') or {}).get('base_wrench')
        sample_at = set(np.linspace(0, n, min(SAMPLES, n) + 1).round().astype(int).tolist()) if sample else set()
        p0, mom, res, has_res = None, 0.0, 0.0, False
        e_max, e_scale, cpu = 0.0, 1e-12, 0.0
        t_start = sim.t
        w0 = time.perf_counter()
        try:
            for k in range(n + 1):
                if k in sample_at:
                    out = sim.outputs(wrenches=False)
                    ex = out.extra
                    if 'constraint_residual' in ex:
                        has_res = True
                        res = max(res, abs(float(ex['constraint_residual'])))
                    p = _momentum(ex) if momentum_ok else None
                    if p is not None:
                        p0 = p if p0 is None else p0
                        mom = max(mom, float(np.max(np.abs(p - p0))))
                if k == n:
                    break
                if scene.script is not None:
                    for port, values in scene.script(sim.t, sim.y).items():
                        sim.set_command(port, values)
                c0 = time.process_time()
                sim.advance(t_start + (k + 1) / rate)
                cpu += time.process_time() - c0
                e = sim.energy_report()
                e_max = max(e_max, abs(e['drift']))
                e_scale = max(e_scale, abs(e['energy0']), abs(e['energy']), abs(e['work']))
                if time.perf_counter() - w0 > budget:
                    raise _Budget()
        except SimulationError as e:
            run.status, run.note = 'failed', str(e)
        except _Budget:
            run.status = 'budget'
            run.note = f'stopped after {budget:g} s wall at t = {sim.t:.4g} s'
        for w in caught:
            if issubclass(w.category, UserWarning):
                text = str(w.message)
                if text not in notes:
                    notes.append(text)
    d = sim.diag
    sim_time = max(sim.t - t_start, 1e-300)
    run.wall_per_sim_s = d.wall / sim_time
    run.cpu_per_sim_s = cpu / sim_time
    run.rhs_evals = int(d.rhs_evals)
    run.rhs_per_sim_s = d.rhs_evals / sim_time
    run.steps = int(d.steps)
    run.rejected_steps = d.rejected_steps
    run.energy_drift = e_max / e_scale
    run.momentum_drift = mom if p0 is not None else math.nan
    run.constraint_residual = res if has_res else math.nan
    if run.status == 'ok':
        run.y = comparable(system, sim.y)
    if notes:
        run.note = '; '.join(([run.note] if run.note else []) + notes)
    return run


# ---------------------------------------------------------------------------------------------
# a scene
# ---------------------------------------------------------------------------------------------
def reference(scene, horizon: float, variants=None) -> Reference:
    """The reference final state of ``scene`` after ``horizon`` s (closed form, or DOP853 at rtol = atol
    = :data:`REFERENCE_RTOL` with at least :data:`REFERENCE_STEPS_PER_PERIOD` steps per publication
    period).

    variants: ``formulations(scene)`` if already built. The closed form is checked against DOP853 at
    :data:`CHECK_RTOL`; the DOP853 reference against the same with its step bound halved: their
    difference (at least :data:`ROUNDOFF_FLOOR`) is its error estimate. Bounded so, the reference
    cannot take the steps of a measured run (module docstring).
    """
    variants = variants or formulations(scene)
    form, sc = variants[0]
    rate = float(sc.settings.get('publish_rate', 100.0))
    T = max(1, int(round(horizon * rate))) / rate
    exact = closed_form(sc)
    if exact is not None:
        check = simulate(sc, 'dop853', rtol=CHECK_RTOL, atol=CHECK_RTOL, horizon=horizon, formulation=form,
                         sample=False)
        y = exact(T)
        diff = state_error(check.y, y) if check.y is not None else math.nan
        return Reference('closed form', y, 0.0, f'{exact.description}; DOP853 rtol={CHECK_RTOL:g} agrees to {diff:.2g}',
                         form)
    bound = 1.0 / (rate * REFERENCE_STEPS_PER_PERIOD)
    ref = simulate(sc, 'dop853', rtol=REFERENCE_RTOL, atol=REFERENCE_RTOL, horizon=horizon, formulation=form,
                   sample=False, max_step=bound)
    check = simulate(sc, 'dop853', rtol=REFERENCE_RTOL, atol=REFERENCE_RTOL, horizon=horizon, formulation=form,
                     sample=False, max_step=bound / 2)
    if ref.y is None or check.y is None:
        raise RuntimeError(f'{scene.name}: the DOP853 reference run failed: {ref.note or check.note}')
    diff = state_error(check.y, ref.y)
    est = max(diff, ROUNDOFF_FLOOR)
    return Reference(f'DOP853 rtol=atol={REFERENCE_RTOL:g}, steps <= {bound:g} s', ref.y, est,
                     f'{ref.steps} steps; differs from the same with steps <= {bound / 2:g} s ({check.steps} steps) '
                     f'by {diff:.2g}; error estimate (floor) {est:.2g}', form, steps=ref.steps)


def run_kind(integrator: str, dt, rtol) -> str:
    """``'fixed'``, ``'adaptive'`` or ``'controlled'`` (a fixed-step method given a tolerance: rosenbrock2 under
    error control, dt its largest step)."""
    from ..integrators import INTEGRATORS
    kind = INTEGRATORS[integrator].kind
    return 'controlled' if kind == 'fixed' and dt is not None and rtol is not None else kind


def ladder(scene, mode: str = 'full', integrators=None) -> list:
    """``[(integrator, dt, rtol, atol)]`` of a scene: fixed steps up to one publication period, tolerances, and
    for rosenbrock2 also the tolerances under error control with one publication period its largest step
    (atol = rtol, its default)."""
    from ..integrators import CONTROLLABLE, INTEGRATORS
    period = 1.0 / float(scene.settings.get('publish_rate', 100.0))
    names = list(integrators) if integrators else [n for n in (FIXED + ADAPTIVE) if n in INTEGRATORS]
    out = []
    for name in names:
        spec = INTEGRATORS[name]
        if spec.kind == 'fixed':
            steps = FIXED_LADDERS[mode].get(name, FIXED_LADDERS[mode]['rk4'])
            out += [(name, h, None, None) for h in steps if h <= period * (1 + 1e-12)]
            if name in CONTROLLABLE:
                out += [(name, period, r, r) for r in ADAPTIVE_LADDERS[mode]]
        else:
            out += [(name, None, r, ATOL_FACTOR * r) for r in ADAPTIVE_LADDERS[mode]]
    return out


def method_of(setting) -> tuple:
    """The method of a ladder entry ``(integrator, dt, rtol, atol)``: its integrator and kind (the unit of a
    :func:`_method_task`: a run out of budget skips the rest of its own method's ladder only)."""
    integ, dt, rtol, _ = setting
    return integ, run_kind(integ, dt, rtol)


class Progress(_Progress):
    """The shared progress bar (:class:`robodyn_ros.measures.Progress`) labelled ``precision``,
    a line per run off a terminal."""

    def __init__(self, total: int, stream=None, quiet=False, width=30):
        super().__init__(total, stream=stream, quiet=quiet, width=width, interval=0.0, label='precision')


@dataclass
class SceneResult:
    """Everything measured on one scene."""

    scene: str
    horizon: float
    rate: float
    mode: str
    reference: Reference
    runs: list
    own_formulation: str = ''
    machine: str = ''


def run_scene(name, mode='full', horizon=None, budget=None, integrators=None, formulations_only=None,
              progress=None, pool=None) -> SceneResult:
    """Measure one scene over its ladder (see the module docstring).

    name: bundled scene name or path; mode: 'full' | 'quick'; horizon: simulated seconds
    (default ``HORIZONS[mode]``); budget: wall seconds per run (default ``BUDGETS[mode]``);
    integrators: restrict to these names; formulations_only: restrict to these formulations;
    progress: a :class:`Progress` (counted once per run and once for the reference); pool: a
    :class:`robodyn_ros.pool.Pool` to run on (default: this process).
    """
    return next(measure_scenes([name], mode, horizon, budget, integrators, formulations_only, progress, pool))


def _reference_task(args):
    """Task: the reference of a scene (:func:`reference`) from ``(name, horizon)``."""
    name, horizon = args
    return reference(_load(name), horizon)


def _method_task(args):
    """Task: the ladder of one method in one formulation of a scene, in order, from ``(name,
    formulation, [(integrator, dt, rtol, atol)], horizon, budget)``. One task per method, because
    a setting that runs out of budget skips the longer ones after it; its first use (imports,
    compiled kernels, caches) is a warm-up run of one period, not measured."""
    name, form, settings, horizon, budget = args
    sc = dict(formulations(_load(name)))[form]
    period = 1.0 / float(sc.settings.get('publish_rate', 100.0))
    integ, dt, rtol, atol = settings[0]
    simulate(sc, integ, dt=dt, rtol=rtol, atol=atol, horizon=period, sample=False)
    runs, over_budget = [], False
    for integ, dt, rtol, atol in settings:
        if over_budget:
            r = Run(scene=sc.name, formulation=form, integrator=integ,
                    kind=run_kind(integ, dt, rtol), dt=dt, rtol=rtol, atol=atol,
                    horizon=horizon, status='skipped', note='a cheaper setting of this method ran out of budget')
        else:
            r = simulate(sc, integ, dt=dt, rtol=rtol, atol=atol, horizon=horizon, budget=budget, formulation=form)
            over_budget = r.status == 'budget'
        runs.append(r)
    return runs


def measure_scenes(names, mode='full', horizon=None, budget=None, integrators=None, formulations_only=None,
                   progress=None, pool=None):
    """Measure several scenes (arguments of :func:`run_scene`); yields their :class:`SceneResult`
    in the order of ``names``. Every scene's reference and methods are tasks of one ``pool``
    (default: this process), so on a Dask pool they run side by side; each result is put
    together as :func:`run_scene` always did (errors against the reference, runs in ladder order).
    """
    from ..pool import Pool
    horizon = HORIZONS[mode] if horizon is None else float(horizon)
    budget = BUDGETS[mode] if budget is None else float(budget)
    keep = None if not formulations_only else set(formulations_only) | {''}
    plans, items = [], []
    for k, name in enumerate(names):
        where = os.path.abspath(name) if os.path.isfile(str(name)) else name  # workers may run elsewhere
        scene = _load(where)
        groups = []
        for form, sc in formulations(scene):
            if keep is not None and form not in keep:
                continue
            steps = ladder(sc, mode, integrators)
            for method in dict.fromkeys(method_of(s) for s in steps):
                groups.append([s for s in steps if method_of(s) == method])
                items.append(((k, len(groups)), (where, form, groups[-1], horizon, budget)))
        items.insert(len(items) - len(groups), ((k, 0), (where, horizon)))
        plans.append((scene, len(groups)))
    done, emitted = {}, 0
    with (pool if pool is not None else Pool(workers=0)) as p:
        tasks = [(key, (_reference_task if key[1] == 0 else _method_task, arg)) for key, arg in items]
        for key, res in p.run(_precision_task, tasks, name='precision'):
            if isinstance(res, dict) and 'error' in res:
                raise RuntimeError(f'{names[key[0]]}: {res["error"]}')
            done[key] = res
            if progress:
                scene = plans[key[0]][0]
                if key[1] == 0:
                    progress.step(f'{scene.name}: reference ({res.kind})')
                else:
                    ref = done.get((key[0], 0))
                    for r in res:
                        err = f' err {state_error(r.y, ref.y):.1e}' if ref is not None and r.status == 'ok' else ''
                        progress.step(f'{r.scene} {r.label} {r.setting}: {r.status}{err}')
            while emitted < len(plans) and all((emitted, g) in done for g in range(plans[emitted][1] + 1)):
                yield _assemble(plans[emitted][0], mode, horizon, [done.pop((emitted, g))
                                                                   for g in range(plans[emitted][1] + 1)])
                emitted += 1


def _precision_task(fn_arg):
    """One task of :func:`measure_scenes`: ``(_reference_task or _method_task, its argument)``."""
    fn, arg = fn_arg
    return fn(arg)


def _assemble(scene, mode, horizon, results) -> SceneResult:
    """A scene's :class:`SceneResult` from its reference and method tasks' results (in plan order)."""
    ref, runs = results[0], [r for group in results[1:] for r in group]
    for r in runs:
        if r.y is not None:
            r.error = state_error(r.y, ref.y)
            r.error_floor = r.error <= max(ref.error_estimate, 0.0)
    from .timing import machine_line
    return SceneResult(scene=scene.name, horizon=runs[0].horizon if runs else horizon,
                       rate=float(scene.settings.get('publish_rate', 100.0)), mode=mode, reference=ref, runs=runs,
                       own_formulation=scene_formulation(scene), machine=machine_line())


def count_runs(name, mode='full', integrators=None, formulations_only=None) -> int:
    """Number of progress units :func:`run_scene` will report for a scene (runs + reference)."""
    scene = _load(name)
    variants = [v for v in formulations(scene) if not formulations_only or not v[0] or v[0] in formulations_only]
    return 1 + sum(len(ladder(sc, mode, integrators)) for _, sc in variants)


# ---------------------------------------------------------------------------------------------
# choosing
# ---------------------------------------------------------------------------------------------
def cheapest(runs, tol: float, formulation=None):
    """The cheapest successful run whose error is at most ``tol`` (None if none is).

    runs: :class:`Run` objects; tol: accuracy (the final-state error measure); formulation:
    only runs of this formulation (None = any). Cost is :func:`cost_key`.
    """
    ok = [r for r in runs if r.status == 'ok' and math.isfinite(r.error) and r.error <= tol
          and (formulation is None or r.formulation == formulation)]
    return min(ok, key=cost_key) if ok else None


# ---------------------------------------------------------------------------------------------
# writing
# ---------------------------------------------------------------------------------------------
def _g(x, fmt='.2e'):
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return '—'
    return format(x, fmt)


def write_csv(res: SceneResult, path: str) -> None:
    """One row per run (CSV_FIELDS)."""
    with open(path, 'w', newline='') as f:
        w = csv.DictWriter(f, fieldnames=CSV_FIELDS)
        w.writeheader()
        for r in res.runs:
            w.writerow(r.row())


def read_csv(path: str) -> list:
    """The runs of a CSV written by :func:`write_csv`."""
    with open(path, newline='') as f:
        return [Run.from_row(d) for d in csv.DictReader(f)]


def error_words(r, floor: float) -> str:
    """A run's error as printed (:meth:`Run.error_text`: "≤ floor" at or below the reference's floor)."""
    return r.error_text(floor)


def cheapest_line(res: SceneResult, tol: float) -> str:
    """``rk4 dt=0.002`` with its error and cost, or why none qualifies."""
    r = cheapest(res.runs, tol)
    if r is None:
        best = min((x.error for x in res.runs if x.status == 'ok'), default=math.nan)
        return f'none measured (best error {best:.1e})'
    return (f'{r.label} {r.setting} — error {error_words(r, res.reference.error_estimate)}, '
            f'{r.cpu_per_sim_s:.3g} CPU s per simulated s, '
            f'{r.rhs_per_sim_s:.0f} rhs/s')


def markdown(res: SceneResult, png: str | None = None) -> str:
    """The scene's markdown: heading, reference, cheapest runs, the table and the diagram."""
    from .timing import table
    ref = res.reference
    lines = [f'## {res.scene}', '',
             f'Horizon {res.horizon:g} s in {res.rate:g} Hz publication periods; {res.mode} ladder; reference: '
             f'{ref.kind} ({ref.check}). Error = max_i |y_i − y_ref,i| / (1 + |y_ref,i|) over [q; v] in minimal '
             'coordinates ("≤ floor" where it is at or below the reference\'s own error estimate; "~1 step/period": '
             'an error-controlled run that took about one step per publication period: the period, not rtol, set '
             'its steps); CPU and wall = '
             'seconds per simulated second on the machine below (single runs: CPU time is the steadier figure '
             'on a shared machine); rhs evals = right-hand-side evaluations (finite-difference Jacobians '
             'included); energy drift = largest |E − E0 − W| over the largest energy scale of the run.', '']
    if res.own_formulation:
        lines += [f'The scene file selects the **{res.own_formulation}** formulation; the reference uses '
                  f'{ref.formulation}.', '']
    lines += ['Cheapest run (least CPU time per simulated second) reaching each accuracy:', '']
    for tol in TARGETS:
        lines.append(f'* **{tol:g}**: {cheapest_line(res, tol)}')
    lines.append('')
    if png:
        lines += [f'![work-precision diagram of {res.scene}]({png})', '']
    rows = []
    for r in res.runs:
        err = error_words(r, ref.error_estimate) if r.status == 'ok' else _g(r.error, '.1e')
        setting = r.setting + (' (~1 step/period)' if r.one_step_per_period(res.rate) else '')
        rows.append([r.integrator, r.formulation or '—', setting, r.status, err, _g(r.cpu_per_sim_s, '.3g'),
                     _g(r.wall_per_sim_s, '.3g'), r.rhs_evals, r.steps,
                     '?' if r.rejected_steps is None else r.rejected_steps,
                     _g(r.energy_drift, '.1e'), _g(r.momentum_drift, '.1e'), _g(r.constraint_residual, '.1e')])
    lines.append(table(['integrator', 'formulation', 'setting', 'status', 'error', 'CPU s/s', 'wall s/s', 'rhs evals',
                        'steps',
                        'rejected', 'energy drift', 'momentum drift', 'constraint residual'], rows))
    notes = [(r, r.note) for r in res.runs if r.note and r.status != 'ok']
    if notes:
        lines += ['', 'Runs that did not finish:', '']
        for r, n in notes:
            lines.append(f'* {r.label} {r.setting} — {r.status}: {n}')
    lines += ['', f'Machine: {res.machine}', '']
    return '\n'.join(lines)


def plot(res: SceneResult, path: str) -> None:
    """Work-precision diagram: error vs rhs evaluations and vs CPU time, log–log, one line per method
    and formulation (colour and marker per integrator, and for rosenbrock2 under error control; dashed for the
    formulation the reference did not use; horizontal lines at the target accuracies, dotted at the
    reference's error)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(13, 5), sharey=True)
    groups = {}
    for r in res.runs:
        if r.status == 'ok' and math.isfinite(r.error):
            groups.setdefault(r.label, []).append(r)
    order = list(FIXED + ADAPTIVE)
    colors = plt.get_cmap('tab10').colors
    markers = 'osD^v<>pXh*'
    floor = max(res.reference.error_estimate, 1e-16)
    def place(r):   # the integrators in order, rosenbrock2 under error control after its fixed steps, in the 10th colour
        if r.kind == 'controlled':
            return order.index(r.integrator) + 0.5, len(order)
        k = order.index(r.integrator) if r.integrator in order else len(order) + 1
        return k, k
    for label, rs in sorted(groups.items(), key=lambda kv: (place(kv[1][0])[0], kv[0])):
        rs = sorted(rs, key=lambda r: r.rhs_per_sim_s)
        err = [max(r.error, 1e-16) for r in rs]
        k = place(rs[0])[1]
        other = rs[0].formulation and rs[0].formulation != res.reference.formulation
        # one colour and marker per integrator; dashed for the formulation the reference did not use
        style = dict(color=colors[k % len(colors)], marker=markers[k % len(markers)],
                     linestyle='--' if other else '-', markerfacecolor='none' if other else None, label=label)
        axes[0].loglog([r.rhs_per_sim_s for r in rs], err, **style)
        axes[1].loglog([max(cost_key(r)[0], 1e-6) for r in rs], err, **style)
    for ax, xl in zip(axes, ('rhs evaluations per simulated second', 'CPU seconds per simulated second')):
        ax.set_xlabel(xl)
        ax.grid(True, which='both', alpha=0.3)
        if res.reference.error_estimate > 0:
            ax.axhline(floor, color='grey', linestyle=':', linewidth=1)
        for tol in TARGETS:
            ax.axhline(tol, color='k', linewidth=0.5, alpha=0.4)
    axes[0].set_ylabel('final-state error')
    axes[0].set_title(f'{res.scene}: error vs rhs evaluations')
    axes[1].set_title(f'error vs CPU time ({res.horizon:g} s horizon)')
    axes[1].legend(fontsize=8, loc='center left', bbox_to_anchor=(1.02, 0.5))
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def summary_markdown(results) -> str:
    """The cheapest run for each target accuracy of every scene, as one table.

    results: ``[(scene name, runs)]``.
    """
    from .timing import table
    rows = []
    for scene, runs in results:
        cells = [scene]
        for tol in TARGETS:
            r = cheapest(runs, tol)
            cells.append('—' if r is None else f'{r.label} {r.setting} ({r.cpu_per_sim_s:.2g} CPU s/s)')
        rows.append(cells)
    return table(['scene'] + [f'≤ {t:g}' for t in TARGETS], rows)


def write_summary(out: str, results=()) -> str:
    """Write ``summary.md`` in ``out`` for every scene measured into it (``results`` of this run,
    the others read back from their CSV files), in DEFAULT_SCENES order; returns the table."""
    done = {res.scene: res.runs for res in results}
    for f in os.listdir(out):
        if f.endswith('.csv') and f[:-4] not in done:
            done[f[:-4]] = read_csv(os.path.join(out, f))
    rank = {n: k for k, n in enumerate(DEFAULT_SCENES)}
    summary = summary_markdown(sorted(done.items(), key=lambda kv: (rank.get(kv[0], len(rank)), kv[0])))
    with open(os.path.join(out, 'summary.md'), 'w') as f:
        f.write('# Cheapest integrator per accuracy\n\nLeast CPU time per simulated second among the measured '
                'runs whose final-state error is at most the accuracy (see each scene\'s page for the runs).\n\n'
                + summary + '\n')
    return summary


#: printed once when the diagram cannot be drawn (the measurements are written all the same)
MATPLOTLIB_HINT = ('matplotlib is not installed, so no work-precision diagram (PNG) was drawn; the CSV and '
                   'markdown tables are written. For the diagram: pip install matplotlib '
                   '(or: sudo apt install python3-matplotlib), then run the benchmark again')


def write_scene(res: SceneResult, out: str) -> dict:
    """Write ``<scene>.csv`` and ``<scene>.md`` in ``out``, then draw ``<scene>.png``; returns their
    paths (``png`` is None when matplotlib is not installed: the tables are written first, and the
    markdown links the diagram only once it exists)."""
    os.makedirs(out, exist_ok=True)
    paths = {ext: os.path.join(out, f'{res.scene}.{ext}') for ext in ('csv', 'md', 'png')}
    write_csv(res, paths['csv'])
    with open(paths['md'], 'w') as f:
        f.write(markdown(res))
    try:
        plot(res, paths['png'])
    except ModuleNotFoundError as e:
        if not (e.name or '').startswith('matplotlib'):
            raise
        paths['png'] = None
        return paths
    with open(paths['md'], 'w') as f:
        f.write(markdown(res, png=f'{res.scene}.png'))
    return paths


# ---------------------------------------------------------------------------------------------
# command line
# ---------------------------------------------------------------------------------------------
def add_arguments(p):
    """Options of the precision benchmark."""
    p.add_argument('scenes', nargs='*', help=f'bundled scene names or files (default: {", ".join(DEFAULT_SCENES)})')
    p.add_argument('--out', default=os.path.join('docs', 'precision'), help='output directory (default docs/precision)')
    p.add_argument('--horizon', type=float, default=None,
                   help=f'simulated seconds per run (default {HORIZONS["full"]:g}; --quick {HORIZONS["quick"]:g})')
    p.add_argument('--quick', action='store_true', help='short ladder and horizon (what robodyn advise runs)')
    p.add_argument('--budget', type=float, default=None,
                   help=f'wall seconds per run before it is stopped (default {BUDGETS["full"]:g}; --quick '
                        f'{BUDGETS["quick"]:g})')
    p.add_argument('--integrators', nargs='*', default=None, help='only these integrators')
    p.add_argument('--formulations', nargs='*', default=None, help='only these formulations (e.g. minimal kkt)')
    p.add_argument('--no-cache', action='store_true', help='do not store the measurements for robodyn advise')
    p.add_argument('--quiet', action='store_true', help='no progress bar')
    p.add_argument('--workers', type=int, default=0,
                   help='Dask worker processes running the references and methods side by side (robodyn sweep\'s '
                        'machinery; default 0: one after the other in this process, so that no run shares the CPU '
                        'with another while it is timed)')
    p.add_argument('--scheduler', default=None, help='address of a Dask scheduler (tcp://host:8786) to run on')
    return p


def main(args) -> int:
    """Measure the scenes, write CSV/markdown/PNG per scene and a summary; 0 on success."""
    from ..integrators import INTEGRATORS
    from ..scene import SceneError, list_scenes
    mode = 'quick' if args.quick else 'full'
    bundled = [n for n, _ in list_scenes()]
    names = list(args.scenes) or [n for n in DEFAULT_SCENES if n in bundled]
    bad = [i for i in (args.integrators or []) if i not in INTEGRATORS]
    if bad:
        print(f'robodyn bench precision: unknown integrator(s) {bad}; valid: {", ".join(INTEGRATORS)}', file=sys.stderr)
        return 2
    try:
        total = sum(count_runs(n, mode, args.integrators, args.formulations) for n in names)
    except SceneError as e:
        print(f'robodyn bench precision: {e}', file=sys.stderr)
        return 2
    progress = Progress(total, quiet=args.quiet)
    results, unplotted = [], []
    from ..pool import Pool
    pool = Pool(args.workers, args.scheduler)
    for res in measure_scenes(names, mode, args.horizon, args.budget, args.integrators, args.formulations, progress,
                              pool):
        name = names[len(results)]
        paths = write_scene(res, args.out)
        results.append(res)
        if not args.no_cache:
            store(name, res)
        if paths['png'] is None:
            unplotted.append(res.scene)
        if not args.quiet:
            wrote = [paths[k] for k in ('csv', 'md', 'png') if paths[k]]
            print(f'{res.scene}: wrote {", ".join(wrote)}', file=sys.stderr)
    summary = write_summary(args.out, results)
    print(summary)
    if unplotted:
        print(f'robodyn bench precision: {MATPLOTLIB_HINT}', file=sys.stderr)
    return 0


if __name__ == '__main__':  # pragma: no cover
    import argparse
    _p = argparse.ArgumentParser(prog='python -m robodyn_ros.bench.precision', description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sys.exit(main(add_arguments(_p).parse_args()))
