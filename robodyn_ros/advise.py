"""``robodyn advise``: the integrator and step or tolerance that meet an accuracy at least cost.

The answer comes from measurements, not from a formula: the work-precision runs of
:mod:`robodyn_ros.bench.precision` (final-state error against a reference, CPU and wall time per
simulated second, rhs evaluations) for that scene on this machine, kept in the measurement store
(:mod:`robodyn_ros.measurements`, one JSON file per scene and machine). ``robodyn bench
precision`` stores its measurements there too; with no entry, :func:`advise` runs the quick
ladder (``bench precision --quick``, about a minute per scene) and stores it.

The choice (:func:`choose`): among successful runs whose error is at most the tolerance, the one
with the least CPU time per simulated second (``measurements.cost_key``; ties: fewer rhs
evaluations per simulated second).
Only measured settings are offered (no interpolation between ladder points), and the error is
the measure the benchmark uses (``bench.precision.state_error`` over its horizon), against a
reference that cannot take a measured run's steps (``bench.precision.reference``). An error at
or below that reference's floor is printed as "≤ floor", never as 0, and an error-controlled run
that took about one step per publication period says so: there rtol did not set its steps.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from .measurements import cost_key, load, runs, scene_of, store

__all__ = ['choose', 'Advice', 'advise', 'format_advice', 'run_command']

def choose(runs, tolerance: float):
    """``(best, others)``: the cheapest run with error <= tolerance, and the other qualifying runs
    cheapest first (one per method (an integrator, and for rosenbrock2 fixed or under error control) and
    formulation). ``best`` is None when none qualifies."""
    ok = [r for r in runs if r.status == 'ok' and math.isfinite(r.error) and r.error <= tolerance]
    ok.sort(key=cost_key)
    if not ok:
        return None, []
    seen = {(ok[0].integrator, ok[0].kind, ok[0].formulation)}
    others = []
    for r in ok[1:]:
        if (r.integrator, r.kind, r.formulation) not in seen:
            seen.add((r.integrator, r.kind, r.formulation))
            others.append(r)
    return ok[0], others


@dataclass
class Advice:
    """What :func:`advise` found: the scene, the tolerance, the chosen run (or None), the next
    cheapest alternatives, the most accurate run measured, and where the figures came from."""

    scene: str
    tolerance: float
    best: object
    others: list
    most_accurate: object
    source: str
    meta: dict = field(default_factory=dict)


def advise(scene_name, tolerance: float, refresh: bool = False, directory: Path | None = None,
           measure=None, progress=None) -> Advice:
    """Advice for ``scene_name`` at final-state error ``tolerance`` (see the module docstring).

    refresh: measure again even if cached; directory: cache directory (default :func:`robodyn_ros.measurements.cache_dir`);
    measure: ``measure(scene_name) -> SceneResult`` (default the quick ladder of
    :func:`robodyn_ros.bench.precision.run_scene`); progress: a bench Progress for that run.
    """
    if not (isinstance(tolerance, (int, float)) and math.isfinite(tolerance) and tolerance > 0):
        raise ValueError(f'tolerance must be a finite number > 0, got {tolerance!r}')
    scene = scene_of(scene_name)
    data = None if refresh else load(scene, directory)
    source = 'cache'
    if data is None:
        if measure is None:
            from .bench.precision import run_scene

            def measure(name):
                return run_scene(name, 'quick', progress=progress)
        result = measure(scene_name)
        store(scene, result, directory)
        data = load(scene, directory)
        source = 'measured now'
        if data is None:  # a full entry that a quick one must not replace is impossible here; be safe
            raise RuntimeError(f'could not cache the measurements of {scene.name}')
    measured = runs(data)
    best, others = choose(measured, tolerance)
    ok = [r for r in measured if r.status == 'ok' and math.isfinite(r.error)]
    most = min(ok, key=lambda r: r.error) if ok else None
    return Advice(scene=scene.name, tolerance=float(tolerance), best=best, others=others, most_accurate=most,
                  source=source, meta={k: v for k, v in data.items() if k != 'runs'})


def run_command(scene: str, run) -> str:
    """The ``robodyn run`` command line that uses a run's integrator setting."""
    if run.kind == 'fixed':
        return f'robodyn run {scene} --integrator {run.integrator} --dt {run.dt:g}'
    if run.kind == 'controlled':   # rosenbrock2 under error control, dt its largest step
        return (f'robodyn run {scene} --integrator {run.integrator} --dt {run.dt:g} --rtol {run.rtol:g} '
                f'--atol {run.atol:g}')
    return f'robodyn run {scene} --integrator {run.integrator} --rtol {run.rtol:g} --atol {run.atol:g}'


def _describe(r, meta: dict) -> str:
    """One run as advise prints it: setting, error (``≤ floor`` at or below the reference's floor, never
    0), whether rtol mattered (one step per period: it did not), cost."""
    floor = (meta.get('reference') or {}).get('error_estimate', 0.0) or 0.0
    once = r.one_step_per_period(float(meta.get('rate', 100.0)))
    return (f'{r.integrator} {r.setting}' + (f' [{r.formulation}]' if r.formulation else '') +
            f': error {r.error_text(floor)}'
            + (' (about one step per period: the period, not rtol, sets its steps; a tighter rtol may give '
               'this same run)' if once else '') +
            f', {r.cpu_per_sim_s:.3g} CPU s per simulated s, {r.rhs_per_sim_s:.0f} rhs/s')


def format_advice(adv: Advice, scene_arg: str | None = None) -> str:
    """Human-readable advice (several lines)."""
    m = adv.meta
    scene_arg = scene_arg or adv.scene
    head = (f'{adv.scene}: final-state error <= {adv.tolerance:g} over {m.get("horizon", float("nan")):g} s '
            f'({m.get("mode", "?")} ladder, reference {m.get("reference", {}).get("kind", "?")})')
    lines = [head]
    if adv.best is None:
        most = adv.most_accurate
        lines.append(f'  no measured setting reaches it; the most accurate was '
                     f'{_describe(most, m) if most else "none (every run failed)"}')
        lines.append('  try a tighter setting (robodyn bench precision --integrators dop853 radau) '
                     'or a looser tolerance')
    else:
        b = adv.best
        lines.append(f'  cheapest: {_describe(b, m)}')
        own = m.get('own_formulation') or ''
        if b.formulation and own and b.formulation != own:
            lines.append(f'  (in the {b.formulation} formulation: set "formulation: {b.formulation}" in the scene; '
                         f'the scene uses {own})')
        lines.append(f'  run it:   {run_command(scene_arg, b)}')
        for r in adv.others[:3]:
            lines.append(f'  next:     {_describe(r, m)}')
    floor = m.get('reference', {}).get('error_estimate', 0.0) or 0.0
    if floor and adv.tolerance < 10 * floor:
        lines.append(f'  note: the reference itself is only good to about {floor:.1g}')
    ref = m.get('reference', {})
    if ref.get('kind'):
        lines.append(f'  reference: {ref["kind"]} ({ref.get("check", "")})')
    lines.append(f'  measurements: {m.get("path", "?")} ({adv.source}, {m.get("created", "?")}, machine '
                 f'{m.get("machine", "?")}; --refresh measures again)')
    return '\n'.join(lines)
