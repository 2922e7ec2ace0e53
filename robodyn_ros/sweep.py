"""``robodyn sweep``: many runs of one scene on Dask — Monte Carlo, grids, tolerance studies.

A sweep spec is one YAML mapping (unknown keys are errors, as in scene files)::

    scene: stanford_arm            # required: bundled scene name or scene file (relative to the spec)
    seed: 2026                     # int >= 0; required when 'random' is given
    samples: 64                    # random draws per grid point (int >= 1, default 1)
    duration: 1.0                  # simulated seconds per run (default: the scene's)
    backend: numba                 # kernels of every run (default numba: the 'generated' backend
                                   # would compile a new kernel for every drawn mass)
    grid:                          # optional: every combination of these values
      integrator: [rk4, dop853]    # run settings: integrator, dt, rtol, atol
      parts.0.dh.links.2.mass: [4.0, 4.5]          # or scene keys (dotted path, list index = number)
    random:                        # optional: one independent draw per run, in this order
      initial_state.q: {normal: [0.0, 0.05], add: true}   # added to the scene's value (each element)
      parts.0.dh.links.2.mass: {uniform: [3.5, 5.0]}      # replaces it
      parts.0.dh.links.1.mass: {normal: [1.0, 0.05], scale: true}   # multiplies it
      integrator: {choice: [rk4, dop853]}
    reference: {integrator: dop853, rtol: 1.0e-10, atol: 1.0e-10}   # for final_error (default)
    figures: [final_error, energy_drift, momentum_drift, constraint_residual, max_joint_wrench]
    record: false                  # true: one MCAP per run in DIR/mcap/ (what `robodyn run` records)

A parameter path addresses a key of the scene file (``parts.0.dh.links.2.mass``,
``initial_state.q``, ``initial_state.q.1``, ``commands.effort.amplitude.0``, ``gravity.2``) or
one of the run settings ``integrator``, ``dt``, ``rtol``, ``atol``. Distributions: ``uniform:
[lo, hi]``, ``normal: [mean, std]`` (lo, hi, mean, std scalars or lists as long as the target),
``choice: [v, ...]``; ``add: true`` / ``scale: true`` add the draw to / multiply the scene's value.

**Runs.** ``n = (product of the grid lengths) x samples``; run ``i`` is grid point ``i // samples``
and draw ``i % samples``. Its random draws come from
``numpy.random.default_rng(SeedSequence(seed, spawn_key=(i,)))`` — what ``SeedSequence(seed)
.spawn(n)[i]`` gives — drawn on the client in spec order, so a run's parameters depend on the
spec and ``i`` only, never on the worker or the order in which runs finish. Each run is the
product's own loop (:func:`robodyn_ros.simulation.run_headless` with the scene's scripted
commands, as ``robodyn run``) and, for ``final_error``, a reference run of the same parameters
with the ``reference`` settings.

**Figures** (columns of the table; ``TIMING_COLUMNS`` depend on the machine, all others are equal
bit for bit whatever the number of workers):

* ``final_error`` — ``max_i |y_i − y_ref,i| / (1 + |y_ref,i|)`` of the final state against the
  reference run (the measure of ``robodyn bench precision``; 0 when the run is the reference);
* ``energy_drift`` — largest ``|E − E0 − W|`` over the publication periods divided by the largest
  of ``|E0|, |E|, |W|`` (W: work of inputs and dissipation);
* ``momentum_drift`` — largest change of linear (N·s) and angular (N·m·s) momentum of a free base
  (meaningful without external forces: a free flyer in orbit without base thrust);
* ``constraint_residual`` — largest constraint residual the system reports (m, or m/s);
* ``max_joint_wrench`` — ``max_joint_force`` (N) and ``max_joint_torque`` (N·m): largest norms
  of the constraint wrenches (``constraint_wrenches/<joint>``) over the periods;
* ``status`` ``ok`` | ``failed`` (the simulation stopped: non-finite state, solver failure) |
  ``refused`` (the simulator refused the settings: unstable step) | ``invalid`` (the drawn
  parameters make no valid scene) | ``error`` (anything else), with ``message``;
* ``steps``, ``rhs_evals``, ``y_final`` (the final state), and ``cpu_time``, ``wall_time`` (s,
  of the run without its reference), ``worker``.

**Fault tolerance.** Tasks are pure functions of their arguments (idempotent): a task Dask runs
twice (a worker died under it) returns the same row. The client writes each finished row to
``DIR/runs/<index>.json`` (atomically) as soon as it arrives, and ``DIR/sweep.json`` records the
spec; a second ``robodyn sweep`` with the same spec and DIR skips the runs that have a row, a
different spec is refused. At the end the rows become ``DIR/results.parquet`` (one row per run,
in index order) and ``DIR/summary.png``.

**Cluster.** ``dask.distributed.LocalCluster`` (one process per worker, one thread each) unless a
scheduler address is given; remote workers need the same robodyn_ros version (checked). The
engine (:class:`robodyn_ros.pool.Pool`) also runs the ladder of ``robodyn bench precision``.

Layout: the spec, its validation and the runs it expands to are :mod:`robodyn_ros.sweep_spec`; the
engine is :mod:`robodyn_ros.pool`; this module runs a run (:func:`execute_run`) and the sweep
(resume, rows on disk, the table).
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import tempfile
import time
from dataclasses import dataclass

import numpy as np

from .measures import Progress, state_error  # noqa: F401  (Progress: part of this module's API)
from .pool import ClusterError, CtrlC, Pool, chunk_size
from .sweep_spec import (FIGURES, FORMAT, SETTINGS, Spec, SweepError, build_scene, expand,  # noqa: F401
                         files_digest, load_spec, parse_spec)
from .version import __version__

__all__ = ['SweepError', 'ClusterError', 'Spec', 'parse_spec', 'load_spec', 'expand', 'execute_run', 'Pool', 'Progress',
           'run_sweep', 'read_table', 'TIMING_COLUMNS', 'FIGURES']

#: columns that depend on the machine and the schedule (not compared between worker counts)
TIMING_COLUMNS = ('cpu_time', 'wall_time', 'worker')
#: env var naming a directory where every task execution leaves a file (tests count executions)
TRACE_ENV = 'ROBODYN_SWEEP_TRACE'
#: env var naming a directory that gates every run (tests): run i leaves ``started-<i>-<pid>`` there,
#: then waits until ``go-<i>`` or ``go`` exists, so a test knows which runs are under way in which
#: process and sends its signals while the sweep is provably mid-way
GATE_ENV = 'ROBODYN_SWEEP_GATE'
#: env var ``N:PATH`` (tests): after writing N rows the client waits until PATH exists, so a test
#: interrupts a sweep that has provably written N rows and no more (its workers run on meanwhile)
PAUSE_ENV = 'ROBODYN_SWEEP_PAUSE'


# ---------------------------------------------------------------------------------------------
# runs
# ---------------------------------------------------------------------------------------------
def requested_settings(scene, overrides: dict, duration: float) -> dict:
    """The settings one run asks for: ``overrides`` over the scene's (:func:`robodyn_ros.runs.resolve_settings`;
    the integrator may be ``auto``; tolerances on a row of a fixed-step method other than rosenbrock2 are
    dropped, as its settings' columns then say)."""
    from .runs import resolve_settings
    return resolve_settings(scene, **{k: overrides[k] for k in SETTINGS if k in overrides}, duration=duration,
                            strict=False)


def run_settings(scene, overrides: dict, duration: float):
    """How one run integrates: ``(plan, st)``, its integrator plan and its settings, resolved as ``robodyn run``
    does (:func:`robodyn_ros.runs.plan_run`: ``auto`` replaced by the method it picks at the scene's initial
    state). Raises ValueError when the run cannot be planned."""
    from .runs import plan_run
    return plan_run(requested_settings(scene, overrides, duration), scene.system, scene.y0)


def _settings_columns(st) -> dict:
    """The row's integrator columns from settings ``st`` (dt for a fixed-step method, else rtol/atol; both for
    rosenbrock2 under error control)."""
    from .integrators import CONTROLLABLE, INTEGRATORS
    fixed = INTEGRATORS[st['integrator']].kind == 'fixed'
    tol = not fixed or (st['integrator'] in CONTROLLABLE and st.get('rtol') is not None)
    return dict(integrator=st['integrator'], dt=st['dt'] if fixed else None, rtol=st['rtol'] if tol else None,
                atol=st['atol'] if tol else None, duration=st['duration'])


class _Figures:
    """Run sink collecting the figures of one run over its publication periods."""

    def __init__(self, wrenches: bool):
        self.wants_wrenches = wrenches
        self.energy_drift, self.energy_scale = 0.0, 1e-12
        self.p0, self.momentum = None, 0.0
        self.residual, self.has_residual = 0.0, False
        self.force, self.torque = 0.0, 0.0

    def on_start(self, sim):
        pass

    def on_command(self, t, port, values):
        pass

    #: run_headless may hand this sink many periods at once (:meth:`on_block`)
    takes_blocks = True

    def _energy(self, e):
        self.energy_drift = max(self.energy_drift, abs(e['drift']))
        self.energy_scale = max(self.energy_scale, abs(e['energy0']), abs(e['energy']), abs(e['work']))

    def _wrench(self, w):
        w = np.asarray(w, dtype=float)
        self.torque = max(self.torque, float(np.linalg.norm(w[:3])))
        self.force = max(self.force, float(np.linalg.norm(w[3:])))

    def block_periods(self, t_out, template, cmd_kind) -> int:
        """Any number of periods, unless the system reports extra values (constraint residuals,
        momenta), which a block does not carry per period."""
        return 0 if template.extra else len(t_out)

    def on_block(self, blk, sim):
        """The figures of each period of a block (:class:`robodyn_ros.blocks.PeriodBlock`):
        the numbers :meth:`on_output` takes from each, the energy report's from its state and work."""
        ny = sim.system.ny
        for z in blk.z:
            self._energy(sim.energy_report(z[:ny], float(z[ny])))
        if self.wants_wrenches and blk.wrenches is not None:
            for F in blk.wrenches:
                for w in F:
                    self._wrench(w)

    def on_output(self, t, out, sim):
        self._energy(sim.energy_report())
        ex = out.extra
        if 'constraint_residual' in ex:
            self.has_residual = True
            self.residual = max(self.residual, abs(float(ex['constraint_residual'])))
        keys = ('momentum_linear_x', 'momentum_linear_y', 'momentum_linear_z',
                'momentum_angular_com_x', 'momentum_angular_com_y', 'momentum_angular_com_z')
        if all(k in ex for k in keys):
            p = np.array([float(ex[k]) for k in keys])
            self.p0 = p if self.p0 is None else self.p0
            self.momentum = max(self.momentum, float(np.max(np.abs(p - self.p0))))
        for _, w in out.wrenches.values():
            self._wrench(w)

    def close(self):
        pass


def _simulate(scene, st, plan, sinks=()):
    """Run ``scene`` with settings ``st`` and integrator plan ``plan`` (:func:`run_settings`): ``(sim, status,
    message)``; never raises for the run's own failures (the plan's warnings go into the message)."""
    import warnings

    from .simulation import SimulationError, Simulator, run_headless
    notes = []
    sim, status, msg = None, 'ok', ''
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        try:
            sim = Simulator(scene.system, scene.y0, plan=plan)
        except ValueError as e:
            return None, 'refused', str(e)
        try:
            # as robodyn run, on one thread: the pool's runs fill the cores already
            run_headless(sim, st['duration'], st['rate'], scene.script, sinks, stop=scene.stop, pipeline=False)
        except SimulationError as e:
            status, msg = 'failed', str(e)
        for w in caught:
            if issubclass(w.category, UserWarning) and str(w.message) not in notes:
                notes.append(str(w.message))
    return sim, status, '; '.join(([msg] if msg else []) + notes)


#: final states of reference runs in this process: the same parameters under another grid
#: setting (an integrator study with common draws) need the reference once per process
_REFERENCES: dict = {}


def clear_reference_cache():
    """Forget the reference runs kept in this process (benchmarks time sweeps from scratch)."""
    _REFERENCES.clear()


def _reference_state(task, scene, st_run):
    """Final state of the reference run of this task's parameters, or ``(None, reason)``."""
    ref = dict(task['reference'])
    try:
        plan, st = run_settings(scene, ref, task['duration'])
    except ValueError as e:
        return None, f'reference run refused: {e}'
    if all(st.get(k) == st_run.get(k) for k in SETTINGS):
        return None, 'same'
    key = hashlib.sha256(json.dumps([task['scene_text'], {k: v for k, v in task['params'].items()
                                                           if k not in SETTINGS}, st, task['backend'],
                                     files_digest(task.get('files') or {})], sort_keys=True).encode()).hexdigest()
    if key not in _REFERENCES:
        sim, status, msg = _simulate(scene, st, plan)
        _REFERENCES[key] = (sim.y.copy(), '') if status == 'ok' else (None, f'reference run {status}: {msg}')
        if len(_REFERENCES) > 64:
            _REFERENCES.pop(next(iter(_REFERENCES)))
    return _REFERENCES[key]


def _wait_at_gate(gate: str, index: int):
    """The test hook of :data:`GATE_ENV`: say that run ``index`` started here, wait for its go (or
    for the Dask worker to close: an interrupted sweep shuts its workers down)."""
    with open(os.path.join(gate, f'started-{index}-{os.getpid()}'), 'w'):
        pass
    try:
        from distributed import get_worker
        from distributed.core import Status
        worker, running = get_worker(), (Status.running, Status.paused)
    except (ImportError, ValueError):   # not on a Dask worker
        worker = None
    while not (os.path.exists(os.path.join(gate, f'go-{index}')) or os.path.exists(os.path.join(gate, 'go'))):
        if worker is not None and worker.status not in running:
            return
        time.sleep(0.005)


def _row_head(task) -> dict:
    """The first columns of a run's row: its index, grid point, sample and ``param.<path>`` values."""
    row = {'run': task['index'], 'grid_point': task['grid_point'], 'sample': task['sample']}
    row.update({f'param.{k}': v for k, v in task['params'].items()})
    return row


def execute_run(task: dict) -> dict:
    """Run one task of :func:`expand` and return its row (a dict of plain values; pure: the same
    task gives the same row apart from ``TIMING_COLUMNS``, so a task Dask reruns is harmless).

    Never raises for a run that goes wrong: the row's status and message say what happened.
    """
    if task.get('version', __version__) != __version__:  # a worker that joined after the client's check
        raise ClusterError(f'this worker runs robodyn_ros {__version__}, the client {task["version"]}; install the '
                           'same version on every worker')
    trace = os.environ.get(TRACE_ENV)
    if trace:  # tests count executions
        os.makedirs(trace, exist_ok=True)
        with open(os.path.join(trace, f'{task["index"]:06d}-{os.getpid()}-{time.time_ns()}'), 'w'):
            pass
    gate = os.environ.get(GATE_ENV)
    if gate:
        _wait_at_gate(gate, task['index'])
    row = _row_head(task)
    row.update({'integrator': None, 'dt': None, 'rtol': None, 'atol': None, 'duration': None,
                'status': 'ok', 'message': '', 'steps': 0, 'rhs_evals': 0})
    for f in FIGURES:
        if f == 'max_joint_wrench':
            row['max_joint_force'] = row['max_joint_torque'] = math.nan
        else:
            row[f] = math.nan
    row.update(y_final=None, cpu_time=math.nan, wall_time=math.nan, worker='')
    mcap = None
    w0 = time.perf_counter()
    from .integrators import INTEGRATORS
    from .runs import plan_run
    from .scene import SceneError
    st = requested = None
    try:
        scene = build_scene(task['scene_text'], task['scene_file'], task['params'], task['backend'],
                            task.get('files') or {})
        requested = requested_settings(scene, task['params'], task['duration'])
        plan, st = plan_run(requested, scene.system, scene.y0)
    except SceneError as e:
        row.update(status='invalid', message=str(e))
    except ValueError as e:   # the run cannot be planned: auto cannot analyse its state, a named step is refused
        row.update(status='refused', message=str(e))
        if requested is not None and requested['integrator'] in INTEGRATORS:   # (auto is not)
            row.update(_settings_columns(requested))   # the method and step that were refused
    if st is not None:
        row.update(_settings_columns(st))
        fig = _Figures(wrenches='max_joint_wrench' in task['figures'])
        sinks = [fig]
        tmp = None
        if task['record']:
            from .recording.run_sink import HEADLESS_BATCH, McapRunSink
            fd, tmp = tempfile.mkstemp(suffix='.mcap')
            os.close(fd)
            from .runs import DIAGNOSTICS_PERIOD
            # robodyn run's vectorised path: the same bytes, but for the meshes, which the many recordings of
            # a sweep reference instead of carrying (an A1's are 9 MB a file; robodyn run records them)
            from .systems.base import recorded_backend
            sinks.append(McapRunSink(tmp, scene, {**st, 'backend': recorded_backend(task['backend']),
                                                  'mode': 'headless'},
                                     diagnostics_period=DIAGNOSTICS_PERIOD, batch=HEADLESS_BATCH,
                                     embed_meshes=False))
        try:
            c0 = time.process_time()
            sim, status, msg = _simulate(scene, st, plan, sinks)
            cpu = time.process_time() - c0
        finally:
            for s in sinks[1:]:
                s.close()
            if tmp:  # the recording goes back to the client, which writes DIR (workers need no shared disk)
                with open(tmp, 'rb') as f:
                    mcap = f.read()
                os.unlink(tmp)
        row.update(status=status, message=msg, cpu_time=cpu)
        if sim is not None:
            d = sim.diag
            row.update(steps=int(d.steps), rhs_evals=int(d.rhs_evals), y_final=[float(x) for x in sim.y])
            fl = task['figures']
            if 'energy_drift' in fl:
                row['energy_drift'] = fig.energy_drift / fig.energy_scale
            if 'momentum_drift' in fl and fig.p0 is not None:
                row['momentum_drift'] = fig.momentum
            if 'constraint_residual' in fl and fig.has_residual:
                row['constraint_residual'] = fig.residual
            if 'max_joint_wrench' in fl and fig.wants_wrenches:
                row['max_joint_force'], row['max_joint_torque'] = fig.force, fig.torque
            if 'final_error' in fl and status == 'ok':
                y_ref, why = _reference_state(task, scene, st)
                if why == 'same':
                    row['final_error'] = 0.0
                elif y_ref is None:
                    row['message'] = '; '.join(x for x in (row['message'], why) if x)
                else:
                    row['final_error'] = state_error(sim.y, y_ref)
    row['wall_time'] = time.perf_counter() - w0
    row['worker'] = f'{os.uname().nodename}:{os.getpid()}'
    return {'row': row, 'mcap': mcap}


# ---------------------------------------------------------------------------------------------
# the sweep: resume, rows on disk, the table
# ---------------------------------------------------------------------------------------------
def _write_atomic(path: str, data: bytes):
    """Write ``path`` whole or not at all (a temporary file renamed over it): a process killed
    while writing leaves no half row. No fsync: the rows must survive the death of a process,
    and the page cache outlives it (an operating-system crash may cost the last rows)."""
    tmp = f'{path}.tmp-{os.getpid()}'
    with open(tmp, 'wb') as f:
        f.write(data)
    os.replace(tmp, path)


def _row_path(out: str, index: int) -> str:
    return os.path.join(out, 'runs', f'{index:06d}.json')


def _prepare(spec: Spec, out: str) -> set:
    """Create ``out`` (or check that it holds this spec's sweep) and return the finished run indices
    (rows of status 'error' — a task that raised, a lost or misconfigured worker — are removed so
    that the runs are tried again; ok, failed, refused and invalid rows are results)."""
    os.makedirs(os.path.join(out, 'runs'), exist_ok=True)
    meta_path = os.path.join(out, 'sweep.json')
    meta = {'format': FORMAT, 'digest': spec.digest, 'runs': spec.n_runs, 'spec_file': os.path.abspath(spec.file),
            'scene': spec.scene_name, 'version': __version__, 'spec': spec.text}
    if os.path.exists(meta_path):
        with open(meta_path, encoding='utf-8') as f:
            old = json.load(f)
        if old.get('digest') != spec.digest:
            raise SweepError(f'{spec.file}: (spec): {out} holds the results of another sweep '
                             f'({old.get("spec_file")}, {old.get("runs")} runs, or an edited spec/scene); '
                             'give another --out, or delete that directory to start again')
    else:
        _write_atomic(meta_path, json.dumps(meta, indent=1).encode())
    done = set()
    for name in os.listdir(os.path.join(out, 'runs')):
        if name.endswith('.json') and name[:-5].isdigit():
            i = int(name[:-5])
            if not 0 <= i < spec.n_runs:
                continue
            with open(os.path.join(out, 'runs', name), encoding='utf-8') as f:
                if json.load(f).get('status') == 'error':
                    os.unlink(os.path.join(out, 'runs', name))  # an unexpected failure is tried again
                    continue
            done.add(i)
    return done


def _error_row(task, message) -> dict:
    """The row of a run whose task raised (status 'error')."""
    return dict(_row_head(task), status='error', message=message)


@dataclass
class SweepResult:
    """What :func:`run_sweep` did: ``runs`` (total), ``skipped`` (found done in DIR), ``executed``
    (finished now), ``interrupted``, ``table`` (path of results.parquet, None if interrupted),
    ``plot`` (summary PNG or None), ``wall`` (s)."""

    runs: int
    skipped: int
    executed: int
    interrupted: bool
    table: str | None
    plot: str | None
    wall: float


def run_sweep(spec: Spec, out: str, workers: int | None = None, scheduler: str | None = None,
              progress: Progress | None = None, plot: bool = True, pool: Pool | None = None) -> SweepResult:
    """Run the missing runs of ``spec`` into ``out`` and write the table (module docstring).

    workers: LocalCluster processes (default one per core; 0 = in this process); scheduler: a
    Dask scheduler address instead; pool: an entered :class:`Pool` to use instead of both (it stays
    open). On KeyboardInterrupt the finished rows stay in ``out`` and the result says ``interrupted``.
    """
    w0 = time.perf_counter()
    done = _prepare(spec, out)
    todo = [i for i in range(spec.n_runs) if i not in done]
    if progress is not None:
        progress.total, progress.done, progress.start_done = spec.n_runs, len(done), len(done)
    executed, interrupted = 0, False
    if todo:
        tasks = {t['index']: t for t in expand(spec, todo)}
        import contextlib
        here = contextlib.nullcontext(pool) if pool is not None else Pool(workers, scheduler)
        try:
            with CtrlC() as ctrl_c, here as p:
                chunk = chunk_size(len(tasks), p.threads())
                for i, res in p.run(execute_run, tasks.items(), name='run', chunk=chunk):
                    ctrl_c.check()
                    if os.path.exists(_row_path(out, i)):
                        continue  # a rerun of a task already written
                    if 'error' in res:
                        row, mcap = _error_row(tasks[i], res['error']), None
                    else:
                        row, mcap = res['row'], res['mcap']
                    if mcap is not None:
                        os.makedirs(os.path.join(out, 'mcap'), exist_ok=True)
                        _write_atomic(os.path.join(out, 'mcap', f'run-{i:06d}.mcap'), mcap)
                    _write_atomic(_row_path(out, i), json.dumps(row).encode())
                    executed += 1
                    _pause_after(executed, ctrl_c)
                    if progress is not None:
                        progress.step(f'run {i}: {row["status"]}')
                ctrl_c.check()
        except KeyboardInterrupt:
            interrupted = True
    table = fig = None
    if not interrupted:
        table = consolidate(spec, out)
        if plot:
            fig = summary_plot(table, os.path.join(out, 'summary.png'))
    return SweepResult(runs=spec.n_runs, skipped=len(done), executed=executed, interrupted=interrupted,
                       table=table, plot=fig, wall=time.perf_counter() - w0)


def _pause_after(written: int, ctrl_c: CtrlC):
    """The test hook of :data:`PAUSE_ENV`: after the N-th row written, wait for its file (a Ctrl-C ends
    the wait: ``ctrl_c.check``)."""
    hook = os.environ.get(PAUSE_ENV)
    if hook:
        n, path = hook.split(':', 1)
        while written == int(n) and not os.path.exists(path):
            ctrl_c.check()
            time.sleep(0.01)


def read_rows(out: str, n: int) -> list:
    """The rows of runs 0..n-1 from ``out/runs`` (missing ones raise FileNotFoundError)."""
    rows = []
    for i in range(n):
        with open(_row_path(out, i), encoding='utf-8') as f:
            rows.append(json.load(f))
    return rows


def consolidate(spec: Spec, out: str) -> str:
    """Write ``out/results.parquet`` from the row files (index order); returns its path."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    rows = read_rows(out, spec.n_runs)
    columns = []
    for r in rows:
        for k in r:
            if k not in columns:
                columns.append(k)
    data = {}
    for k in columns:
        vals = [r.get(k) for r in rows]
        if all(v is None or isinstance(v, (int, float)) and not isinstance(v, bool) for v in vals) and \
                any(isinstance(v, float) for v in vals):
            vals = [math.nan if v is None else float(v) for v in vals]
        data[k] = vals
    table = pa.table(data)
    table = table.replace_schema_metadata({'robodyn_sweep': json.dumps({'spec': spec.text, 'scene': spec.scene_name,
                                                                        'format': FORMAT})})
    path = os.path.join(out, 'results.parquet')
    buf = pa.BufferOutputStream()
    pq.write_table(table, buf)
    _write_atomic(path, buf.getvalue().to_pybytes())
    return path


def read_table(path: str) -> list:
    """The rows of a results.parquet as dicts (``pyarrow``), in run order."""
    import pyarrow.parquet as pq
    return pq.read_table(path).to_pylist()


def summary_plot(table_path: str, png: str) -> str | None:
    """Histograms of the figures over the successful runs (log10 where positive) and the run
    status counts; None when matplotlib is not installed (the table is the result)."""
    try:
        import matplotlib
    except ImportError:
        return None
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    rows = read_table(table_path)
    cols = [c for c in ('final_error', 'energy_drift', 'momentum_drift', 'constraint_residual', 'max_joint_force',
                        'max_joint_torque', 'cpu_time')
            if any(r.get(c) is not None and math.isfinite(r[c]) for r in rows if r.get('status') == 'ok')]
    n = len(cols) + 1
    ncol = min(n, 3)
    fig, axes = plt.subplots((n + ncol - 1) // ncol, ncol, figsize=(4.5 * ncol, 3.2 * ((n + ncol - 1) // ncol)),
                             squeeze=False)
    axes = axes.ravel()
    for ax, c in zip(axes, cols):
        v = np.array([r[c] for r in rows if r.get('status') == 'ok' and r.get(c) is not None and math.isfinite(r[c])])
        if np.all(v > 0) and v.size:
            ax.hist(np.log10(v), bins=min(30, max(5, v.size // 2)))
            ax.set_xlabel(f'log10 {c}')
        else:
            ax.hist(v, bins=min(30, max(5, v.size // 2)))
            ax.set_xlabel(c)
        ax.set_ylabel('runs')
    ax = axes[len(cols)]
    status = {}
    for r in rows:
        status[r.get('status')] = status.get(r.get('status'), 0) + 1
    ax.bar(list(map(str, status)), list(status.values()))
    ax.set_title(f'{len(rows)} runs')
    for ax in axes[len(cols) + 1:]:
        ax.set_visible(False)
    fig.tight_layout()
    fig.savefig(png, dpi=80)
    plt.close(fig)
    return png
