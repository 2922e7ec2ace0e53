"""What every run needs, wherever it starts (``robodyn run``, the sim node, ``robodyn sweep``):
its settings, its integrator plan, and its human-readable summary.

Settings resolve the same way for all three: the value given for the run (command-line option,
node parameter, sweep parameter) over the scene's ``simulation`` defaults over the package
defaults, so a node run and a headless run of the same scene integrate alike. The package's default
integrator is ``auto``. :func:`plan_run` asks :func:`robodyn_ros.integrator_choice.plan_integrator`,
once, how the run integrates (the Simulator is then handed that plan) and writes the method auto
picked, and why, into the settings (under ``auto``: the summary prints it and the recording's
metadata keeps it; a run that names its integrator has no ``auto`` key, so its recording keeps its
bytes).
"""
from __future__ import annotations

import math
import os
import signal

from .integrator_choice import AUTO, AUTO_ATOL, AUTO_RTOL, DEFAULT_DT

#: simulated seconds between diagnostics messages in a recording (robodyn run, robodyn sweep)
DIAGNOSTICS_PERIOD = 0.1
#: publication (and scripted-command) rate (Hz) when the run and its scene give none
DEFAULT_RATE = 100.0
#: simulated seconds of a run when the run and its scene give none
DEFAULT_DURATION = 10.0


def resolve_settings(scene, integrator=None, dt=None, rtol=None, atol=None, rate=None, duration=None,
                     step_budget=None, strict=True) -> dict:
    """Integrator settings of a run: the given values over the scene's ``simulation`` defaults.

    scene: a loaded :class:`robodyn_ros.scene.Scene` (its ``settings``); integrator, dt (s),
    rtol, atol, rate (publication rate, Hz), duration (simulated s), step_budget (steps per
    simulated second of an error-controlled integrator, inf = none): None takes the scene's
    value, else the package default (``AUTO``, ``DEFAULT_DT``, ``DEFAULT_RATE``, ``DEFAULT_DURATION``;
    ``AUTO_RTOL`` and ``AUTO_ATOL`` for an adaptive integrator; ``integrator_choice.STEP_BUDGET``).
    Returns a dict with the first six keys (integrator may be ``'auto'``: see :func:`plan_run`), and
    ``step_budget`` when the run or the scene gives one (recordings of other runs keep their
    settings' bytes). A fixed-step integrator other than rosenbrock2 takes no tolerances: the scene's are
    dropped, and given ones are refused (ValueError naming the methods that take them), or with ``strict``
    False dropped too (a sweep's grid of integrators and tolerances).
    """
    s = dict(scene.settings)
    out = {'integrator': (integrator or s.get('integrator', AUTO)).lower(),
           'dt': dt if dt is not None else s.get('dt', DEFAULT_DT),
           'rtol': rtol if rtol is not None else s.get('rtol'),
           'atol': atol if atol is not None else s.get('atol'),
           'rate': rate if rate is not None else s.get('publish_rate', DEFAULT_RATE),
           'duration': duration if duration is not None else s.get('duration', DEFAULT_DURATION)}
    budget = step_budget if step_budget is not None else s.get('step_budget')
    if budget is not None:
        out['step_budget'] = budget
    from .integrators import CONTROLLABLE, INTEGRATORS, tolerance_refused
    spec = INTEGRATORS.get(out['integrator'])
    if spec is not None and spec.kind == 'fixed' and spec.name not in CONTROLLABLE:
        given = [k for k, x in (('rtol', rtol), ('atol', atol)) if x is not None]
        if given and strict:   # a tolerance the run would not use: refused, not ignored
            raise tolerance_refused(spec.name, '/'.join(given), auto=True)
        out['rtol'] = out['atol'] = None   # the scene's tolerances are for its own method
    if spec is not None and spec.kind == 'adaptive':
        out['rtol'] = out['rtol'] if out['rtol'] is not None else AUTO_RTOL
        out['atol'] = out['atol'] if out['atol'] is not None else AUTO_ATOL
    return out


def plan_run(st: dict, system, y0, t0: float = 0.0):
    """How a run with settings ``st`` (from :func:`resolve_settings`) integrates from state y0 at t0:
    ``(plan, st)``, the :class:`~robodyn_ros.integrator_choice.IntegratorPlan` made once by
    :func:`~robodyn_ros.integrator_choice.plan_integrator` (hand it to the Simulator: ``Simulator(...,
    plan=plan)``), and the settings with the plan written in: an ``'auto'`` integrator replaced by the
    method it chose (its dt, or rtol/atol for radau) and the reason under ``'auto'``, a new dict; ``st``
    itself when it names its integrator (with the atol rosenbrock2 under error control defaults to: rtol).
    Raises ValueError naming the cause (plan_integrator)."""
    from .integrator_choice import plan_integrator
    dt = st.get('dt')
    plan = plan_integrator(system, y0, st.get('integrator'), DEFAULT_DT if dt is None else dt, st.get('rtol'),
                           st.get('atol'), st.get('step_budget'), t0)
    if not plan.auto:
        return plan, (st if plan.atol == st.get('atol') else {**st, 'atol': plan.atol})   # rosenbrock2: atol = rtol
    return plan, {**st, 'integrator': plan.integrator, 'dt': plan.dt if plan.dt is not None else dt,
                  'rtol': plan.rtol, 'atol': plan.atol, 'auto': plan.reason}


def summary(scene, sim, st, wall, record, sinks, cpu=None) -> str:
    """Human-readable summary of a finished run (cpu: process CPU seconds of the run, if known)."""
    import numpy as np
    e = sim.energy_report()
    d = sim.diag
    ran = sim.integrator.settings()   # what ran: the method and its dt, or its rtol and atol
    method = ran['integrator'] + (f' dt={ran["dt"]:g} s' + (f' (the largest step) rtol={ran["rtol"]:g} atol={ran["atol"]:g}'
                                                         if 'rtol' in ran else '') if 'dt' in ran else
                                  f' rtol={ran["rtol"]:g} atol=' + (f'{ran["atol"]:g}' if np.ndim(ran['atol']) == 0
                                                                    else 'per component'))
    lines = [
        f'scene        {scene.name} ({scene.system.__class__.__name__}, {scene.system.ny} states)',
        f'integrator   {method}; {d.steps} steps, {d.rhs_evals} rhs evaluations, '
        + (f'{d.rejected_steps} rejected' if d.rejected_steps is not None
           else 'rejected steps not counted by this method'),
        *([f'             ({st["auto"]})'] if st.get('auto') else []),
        f'time         simulated {sim.t:.3f} s in {wall:.3f} s wall '
        f'(real-time factor {sim.t / wall if wall > 0 else math.inf:.1f}, {d.wall:.3f} s integrating'
        + (f', {cpu:.3f} s CPU' if cpu is not None else '') + ')',
        f'energy       E0 {e["energy0"]:.6g} J, E {e["energy"]:.6g} J, work in {e["work"]:.6g} J, '
        f'drift {e["drift"]:.3g} J ({e["relative_drift"]:.2e} relative)',
    ]
    if 'limit_work' in e:   # joint-limit moments (Huston eq. 20.2.1): their part of the work
        lines[-1] += f'; joint-limit work {e["limit_work"]:.6g} J'
    contact = getattr(scene.system, 'contact', None)
    if contact is not None:   # the ground: its law, its part of the work, the contacts at the end
        x = sim.outputs(wrenches=False).extra
        lines.append(f'contact      {contact.n_points} points on {len(contact.links)} links ({contact.law_words()}); '
                     f'contact work {e.get("contact_work", 0.0):.6g} J; at the end {x["contact_active"]} touching, '
                     f'penetration {x["contact_max_penetration"]:.3g} m, slip {x["contact_max_slip_speed"]:.3g} m/s')
    if d.velocity_limit_exceeded:   # URDF <limit velocity>: reported, not enforced
        lines.append(f'limits       {d.velocity_limit_exceeded} published joint velocities above the velocity limits')
    clamped = {k: p.clamped for k, p in sim.ports.items() if p.clamped}
    if clamped:  # actuator effort limits (URDF <limit effort>, effort_limit)
        lines.append('limits       ' + ', '.join(f'{n} {k} command components clamped to the effort limits'
                                                 for k, n in clamped.items()))
    if record:
        n = sum(getattr(s, 'count', 0) for s in sinks)
        lines.append(f'recording    {os.path.abspath(record)} ({n} messages; check with: robodyn check {record})')
    report = getattr(scene.system, 'run_report', None)  # e.g. a planar base: rotations at the end
    if report is not None:
        lines.append(report(sim.y))
    if sim.failed:
        lines.append(f'FAILED       {sim.failed}')
    return '\n'.join(lines)


class StopSignals:
    """SIGINT (Ctrl-C) and SIGTERM as a request to stop where the run is whole: the first sets
    :attr:`requested` (its name, ``'Ctrl-C'`` or ``'SIGTERM'``) for the loop to ask at its next period
    boundary (``run_headless(halt=...)``, the node's loop) and calls ``on_request()`` (a live run's steering,
    which also ends a pause); a second raises KeyboardInterrupt at once.
    A context manager: the handlers before it are restored on leaving (main thread only)."""

    NAMES = {signal.SIGINT: 'Ctrl-C', signal.SIGTERM: 'SIGTERM'}
    #: exit status of a run stopped by each signal (128 + its number, as a shell reports it)
    STATUS = {'Ctrl-C': 128 + signal.SIGINT, 'SIGTERM': 128 + signal.SIGTERM}

    def __init__(self, on_request=None):
        self.requested = None
        self.on_request = on_request
        self._previous = {}

    def __call__(self, signum, frame=None):
        if self.requested is not None:
            raise KeyboardInterrupt
        self.requested = self.NAMES.get(signum, f'signal {signum}')
        if self.on_request is not None:
            self.on_request()

    def asked(self) -> bool:
        """Whether a stop was requested (``run_headless``'s ``halt``)."""
        return self.requested is not None

    def __enter__(self):
        for s in self.NAMES:
            self._previous[s] = signal.signal(s, self)
        return self

    def __exit__(self, *exc):
        for s, h in self._previous.items():
            signal.signal(s, h)
        self._previous.clear()
        return False
