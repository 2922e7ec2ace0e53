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
engine (:class:`Pool`) also runs the ladder of ``robodyn bench precision``.
"""
from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
import tempfile
import time
from dataclasses import dataclass, field

import numpy as np
import yaml

from .measures import Progress, state_error  # noqa: F401  (Progress: part of this module's API)

__all__ = ['SweepError', 'ClusterError', 'Spec', 'parse_spec', 'load_spec', 'expand', 'execute_run', 'Pool', 'Progress',
           'run_sweep', 'read_table', 'TIMING_COLUMNS', 'FIGURES']

#: figures a spec may ask for (status, message, steps, rhs_evals, y_final and timings always come)
FIGURES = ('final_error', 'energy_drift', 'momentum_drift', 'constraint_residual', 'max_joint_wrench')
#: columns that depend on the machine and the schedule (not compared between worker counts)
TIMING_COLUMNS = ('cpu_time', 'wall_time', 'worker')
#: run settings a parameter path may name (everything else is a scene key)
SETTINGS = ('integrator', 'dt', 'rtol', 'atol')
DISTRIBUTIONS = ('uniform', 'normal', 'choice')
DEFAULT_REFERENCE = {'integrator': 'dop853', 'rtol': 1e-10, 'atol': 1e-10}
_SPEC_REQUIRED = ('scene',)
_SPEC_OPTIONAL = ('seed', 'samples', 'duration', 'backend', 'grid', 'random', 'reference', 'figures', 'record',
                  'description')
#: the table layout; bump when the meaning of a column changes (a DIR of another format is refused)
FORMAT = 1
#: Dask tasks per worker thread a sweep aims at, and the most runs one task carries (a task costs
#: the scheduler, the worker and the client a few ms, more than a tenth of a short run on a busy
#: machine: ``robodyn bench sweep``)
TASKS_PER_THREAD, MAX_CHUNK = 4, 8
#: seconds a sweep on a remote scheduler waits for its first worker
WORKER_WAIT = 60.0
#: env var naming a directory where every task execution leaves a file (tests count executions)
TRACE_ENV = 'ROBODYN_SWEEP_TRACE'


class SweepError(ValueError):
    """A sweep spec that cannot be run; the message is ``<file>: <key path>: <reason>``."""


class ClusterError(RuntimeError):
    """The Dask cluster cannot run the sweep (unreachable scheduler, no worker, another version)."""


# ---------------------------------------------------------------------------------------------
# the spec
# ---------------------------------------------------------------------------------------------
@dataclass
class Spec:
    """A validated sweep spec (see the module docstring).

    file: where it came from; text: its YAML; scene_file: the scene's path; scene_text: the
    scene's YAML; grid: ``[(path, values)]``; random: ``[(path, distribution mapping)]``;
    settings: the scene's run settings with ``duration`` resolved; reference: settings of the
    reference run (None without final_error).
    """

    file: str
    text: str
    scene_name: str
    scene_file: str
    scene_text: str
    seed: int | None
    samples: int
    duration: float
    backend: str
    grid: list
    random: list
    reference: dict | None
    figures: tuple
    record: bool
    settings: dict = field(default_factory=dict)

    @property
    def n_grid(self) -> int:
        """Number of grid points (1 without a grid)."""
        return math.prod(len(v) for _, v in self.grid)

    @property
    def n_runs(self) -> int:
        """Number of runs."""
        return self.n_grid * self.samples

    @property
    def digest(self) -> str:
        """sha256 of everything that decides the rows (the spec and the scene's text)."""
        return hashlib.sha256(json.dumps([FORMAT, self.text, self.scene_text]).encode()).hexdigest()


def _fail(file, path, reason):
    raise SweepError(f'{file}: {path or "(top level)"}: {reason}')


def _split(path: str) -> list:
    """``'parts.0.dh.links.2.mass'`` -> ``['parts', 0, 'dh', 'links', 2, 'mass']``."""
    return [int(p) if p.isdigit() else p for p in path.split('.')]


def _lookup(data, path: str):
    """``(exists, value, reason)`` of a dotted path in the scene mapping (the last mapping key may
    be absent: the scene loader then decides whether it is allowed there)."""
    node = data
    keys = _split(path)
    for k, key in enumerate(keys):
        last = k == len(keys) - 1
        where = '.'.join(str(x) for x in keys[:k]) or 'the scene'
        if isinstance(node, list):
            if not isinstance(key, int):
                return False, None, f'{where} is a list: expected an index 0..{len(node) - 1}, got {key!r}'
            if not 0 <= key < len(node):
                return False, None, f'{where} has {len(node)} entries, no index {key}'
            node = node[key]
        elif isinstance(node, dict):
            if key not in node:
                if last:
                    return True, None, ''
                import difflib
                keys_here = ', '.join(str(x) for x in node)
                near = difflib.get_close_matches(str(key), [str(x) for x in node], n=1)
                hint = f'; did you mean {near[0]!r}?' if near else ''
                return False, None, f'{where} has no key {key!r} (keys: {keys_here}){hint}'
            node = node[key]
        else:
            return False, None, f'{where} is a value ({node!r}), it has no key {key!r}'
    return True, node, ''


def _assign(data, path: str, value):
    """Set a dotted path in the nested scene mapping (the path exists: checked by :func:`_lookup`)."""
    keys = _split(path)
    node = data
    for key in keys[:-1]:
        node = node[key]
    node[keys[-1]] = value


def _number_or_list(file, path, v, what='a number or a list of numbers'):
    if isinstance(v, bool) or not (isinstance(v, (int, float)) or
                                   (isinstance(v, list) and v and all(isinstance(x, (int, float)) and
                                                                      not isinstance(x, bool) for x in v))):
        _fail(file, path, f'expected {what}, got {v!r}')
    arr = np.asarray(v, dtype=float)
    if not np.all(np.isfinite(arr)):
        _fail(file, path, f'expected finite numbers, got {v!r}')
    return arr


def _check_setting(file, path, key, value):
    """A value for a run setting: a known integrator name or a positive number."""
    if key == 'integrator':
        from .integrators import INTEGRATORS
        if not isinstance(value, str) or value not in INTEGRATORS:
            _fail(file, path, f'unknown integrator {value!r}; known: {", ".join(INTEGRATORS)}')
    elif isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0 or not math.isfinite(value):
        _fail(file, path, f'expected a positive number of {"seconds" if key == "dt" else "relative units"}, '
                          f'got {value!r}')


def _check_distribution(file, path, dist, key, current):
    """Validate one ``random`` entry (its distribution and the shape of what it draws)."""
    if not isinstance(dist, dict):
        _fail(file, path, f'expected a mapping with one of {", ".join(DISTRIBUTIONS)}, got {dist!r}')
    kinds = [k for k in dist if k in DISTRIBUTIONS]
    for k in dist:
        if k not in DISTRIBUTIONS + ('add', 'scale'):
            _fail(file, f'{path}.{k}', f'unknown key {k!r}; allowed keys here: {", ".join(DISTRIBUTIONS)}, add, scale')
    if len(kinds) != 1:
        _fail(file, path, f'expected exactly one of {", ".join(DISTRIBUTIONS)}, got {sorted(dist) or "none"}')
    kind = kinds[0]
    for flag in ('add', 'scale'):
        if flag in dist and not isinstance(dist[flag], bool):
            _fail(file, f'{path}.{flag}', f'expected true or false, got {dist[flag]!r}')
    relative = dist.get('add') or dist.get('scale')
    if dist.get('add') and dist.get('scale'):
        _fail(file, path, 'add and scale exclude each other')
    v = dist[kind]
    if kind == 'choice':
        if not isinstance(v, list) or not v:
            _fail(file, f'{path}.choice', f'expected a non-empty list of values, got {v!r}')
        if relative:
            _fail(file, path, 'add/scale apply to uniform and normal draws, not to choice')
        if key in SETTINGS:
            for j, x in enumerate(v):
                _check_setting(file, f'{path}.choice.{j}', key, x)
        return
    if not isinstance(v, list) or len(v) != 2:
        _fail(file, f'{path}.{kind}', f'expected [{"lo, hi" if kind == "uniform" else "mean, std"}], got {v!r}')
    a = _number_or_list(file, f'{path}.{kind}.0', v[0])
    b = _number_or_list(file, f'{path}.{kind}.1', v[1])
    if key == 'integrator':
        _fail(file, path, 'the integrator is drawn with choice: [...]')
    if kind == 'uniform' and np.any(b < a):
        _fail(file, f'{path}.uniform', f'lower bound {v[0]!r} is above the upper bound {v[1]!r}')
    if kind == 'normal' and np.any(b < 0):
        _fail(file, f'{path}.normal.1', f'standard deviation must be >= 0, got {v[1]!r}')
    n = None if current is None or not isinstance(current, list) else len(current)
    for j, arr in enumerate((a, b)):
        if arr.ndim == 1 and arr.size != (n or 0) and not (n is None and arr.size == 1):
            _fail(file, f'{path}.{kind}.{j}', f'expected a number or {n} numbers (the length of the scene value), '
                                              f'got {arr.size}' if n else
                  'expected a number: the scene value here is a single number')
    if relative and current is None:
        _fail(file, path, 'add/scale need a value in the scene to start from; this key is not set there')


def parse_spec(text: str, file: str = '<string>', base_dir: str | None = None) -> Spec:
    """Validate sweep-spec YAML and resolve its scene.

    text: the YAML; file: name in error messages; base_dir: directory a relative scene path is
    taken from (default: the spec's). Raises :class:`SweepError` ``<file>: <key path>: <reason>``;
    also builds the scene for every grid point with its first draw, so a parameter the scene
    refuses is reported here (with the scene's own reason) and not by every run.
    """
    from .scene import SceneError, SceneLoader, find_scene
    try:
        data = yaml.load(text, Loader=SceneLoader)
    except yaml.YAMLError as e:
        mark = getattr(e, 'problem_mark', None)
        where = f'line {mark.line + 1}, column {mark.column + 1}' if mark is not None else 'YAML'
        _fail(file, where, f'YAML syntax error: {getattr(e, "problem", None) or e}')
    if not isinstance(data, dict):
        _fail(file, '', f'expected a mapping, got {type(data).__name__}')
    for k in data:
        if k not in _SPEC_REQUIRED + _SPEC_OPTIONAL:
            _fail(file, k, f'unknown key {k!r}; allowed keys here: {", ".join(_SPEC_REQUIRED + _SPEC_OPTIONAL)}')
    for k in _SPEC_REQUIRED:
        if k not in data:
            _fail(file, k, 'missing required key')
    scene_ref = data['scene']
    if not isinstance(scene_ref, str) or not scene_ref:
        _fail(file, 'scene', f'expected a scene name or file, got {scene_ref!r}')
    base = base_dir if base_dir is not None else os.path.dirname(os.path.abspath(file))
    cand = scene_ref if os.path.isabs(scene_ref) else os.path.join(base, scene_ref)
    try:
        scene_path = find_scene(cand if os.path.isfile(cand) else scene_ref)
        scene_text = scene_path.read_text(encoding='utf-8')
    except (SceneError, OSError) as e:
        _fail(file, 'scene', f'unknown scene {scene_ref!r}: {e}')
    scene_data = yaml.load(scene_text, Loader=SceneLoader)

    def count(key, default, minimum):
        v = data.get(key, default)
        if isinstance(v, bool) or not isinstance(v, int):
            _fail(file, key, f'expected a whole number, got {v!r}')
        if v < minimum:
            _fail(file, key, f'must be >= {minimum}, got {v}')
        return v

    samples = count('samples', 1, 1)
    seed = count('seed', 0, 0) if 'seed' in data else None
    grid, random = [], []
    for section in ('grid', 'random'):
        sec = data.get(section, {}) or {}
        if not isinstance(sec, dict):
            _fail(file, section, f'expected a mapping of parameter paths, got {sec!r}')
        for key, v in sec.items():
            path = f'{section}.{key}'
            key = str(key)
            if key in SETTINGS:
                current = None
            else:
                ok, current, why = _lookup(scene_data, key)
                if not ok:
                    _fail(file, path, f'no such parameter in scene {scene_ref!r}: {why}')
            if section == 'grid':
                if not isinstance(v, list) or not v:
                    _fail(file, path, f'expected a non-empty list of values, got {v!r}')
                for j, x in enumerate(v):
                    if key in SETTINGS:
                        _check_setting(file, f'{path}.{j}', key, x)
                grid.append((key, list(v)))
            else:
                _check_distribution(file, path, v, key, current)
                random.append((key, v))
    both = {k for k, _ in grid} & {k for k, _ in random}
    if both:
        _fail(file, f'random.{sorted(both)[0]}', 'this parameter is also in grid; vary it in one of them')
    if random and seed is None:
        _fail(file, 'seed', 'missing required key: random draws need a seed (a whole number >= 0)')
    figures = data.get('figures', list(FIGURES))
    if not isinstance(figures, list):
        _fail(file, 'figures', f'expected a list of {", ".join(FIGURES)}, got {figures!r}')
    for j, f in enumerate(figures):
        if f not in FIGURES:
            _fail(file, f'figures.{j}', f'unknown figure {f!r}; known: {", ".join(FIGURES)}')
    reference = None
    if 'final_error' in figures:
        reference = dict(DEFAULT_REFERENCE)
        ref = data.get('reference', {})
        if not isinstance(ref, dict):
            _fail(file, 'reference', f'expected a mapping of run settings, got {ref!r}')
        for k, v in ref.items():
            if k not in SETTINGS:
                _fail(file, f'reference.{k}', f'unknown key {k!r}; allowed keys here: {", ".join(SETTINGS)}')
            _check_setting(file, f'reference.{k}', k, v)
            reference[k] = v
    elif 'reference' in data:
        _fail(file, 'reference', 'a reference run is used by final_error only, which figures does not list')
    record = data.get('record', False)
    if not isinstance(record, bool):
        _fail(file, 'record', f'expected true or false, got {record!r}')
    from .systems.base import BACKENDS
    backend = data.get('backend', 'numba')
    if backend not in BACKENDS:
        _fail(file, 'backend', f'unknown backend {backend!r}; valid: {", ".join(BACKENDS)}')
    if 'description' in data and not isinstance(data['description'], str):
        _fail(file, 'description', f'expected a string, got {data["description"]!r}')
    duration = data.get('duration')
    if duration is not None and (isinstance(duration, bool) or not isinstance(duration, (int, float))
                                 or not duration > 0 or not math.isfinite(duration)):
        _fail(file, 'duration', f'must be a positive number of seconds, got {duration!r}')
    spec = Spec(file=file, text=text, scene_name=str(scene_data.get('name', scene_ref)) if isinstance(scene_data, dict)
                else scene_ref, scene_file=str(scene_path), scene_text=scene_text, seed=seed, samples=samples,
                duration=0.0, backend=backend, grid=grid, random=random, reference=reference,
                figures=tuple(f for f in FIGURES if f in figures), record=record)
    # every grid point must make a valid scene (the scene loader's own reasons); random draws of
    # keys the scene has are checked per run (an unlucky draw is an 'invalid' row, not a bad
    # spec), those of keys it lacks here with the first draw (the scene may not allow that key)
    absent = {k for k, _ in random if k not in SETTINGS and _lookup(scene_data, k)[1] is None}
    seen = set()
    for g, task in enumerate(expand(spec, [j * spec.samples for j in range(spec.n_grid)])):
        params = {k: v for k, v in task['params'].items() if k not in SETTINGS and (k in absent or
                                                                                    k not in dict(random))}
        if json.dumps(params) in seen:
            continue
        seen.add(json.dumps(params))
        try:
            scene = build_scene(spec.scene_text, spec.scene_file, params, spec.backend)
        except SceneError as e:
            _blame(spec, params, e)
        if g == 0:
            spec.settings = dict(scene.settings)
    spec.duration = float(duration) if duration is not None else float(spec.settings.get('duration', 10.0))
    return spec


def _blame(spec: Spec, params: dict, err):
    """Raise SweepError for a scene that refused ``params``: at the one parameter that the scene
    refuses on its own (``grid.<path>`` or ``random.<path>``), else at the section."""
    from .scene import SceneError
    section = {k: 'grid' for k, _ in spec.grid} | {k: 'random' for k, _ in spec.random}
    for k, v in params.items():
        if k in SETTINGS:
            continue
        try:
            build_scene(spec.scene_text, spec.scene_file, {k: v}, spec.backend)
        except SceneError as e1:
            _fail(spec.file, f'{section[k]}.{k}', f'the scene refuses {k} = {_short(v)}: {e1}')
    where = 'grid' if spec.grid else 'random'
    shown = ', '.join(f'{k}={_short(v)}' for k, v in params.items() if k not in SETTINGS)
    _fail(spec.file, where, f'the scene refuses these parameters together ({shown}): {err}')


def _short(v) -> str:
    if isinstance(v, list):
        return '[' + ', '.join(f'{x:.4g}' if isinstance(x, float) else str(x) for x in v) + ']'
    return f'{v:.6g}' if isinstance(v, float) else str(v)


def load_spec(path) -> Spec:
    """Read and validate a sweep spec file (:func:`parse_spec`)."""
    try:
        with open(path, encoding='utf-8') as f:
            text = f.read()
    except (OSError, UnicodeDecodeError) as e:
        raise SweepError(f'{path}: (file): cannot read: {e}') from None
    return parse_spec(text, file=str(path))


# ---------------------------------------------------------------------------------------------
# runs
# ---------------------------------------------------------------------------------------------
def _draw(rng, dist, current):
    """One draw of a ``random`` entry (the scene's ``current`` value for add/scale and shape)."""
    if 'choice' in dist:
        values = dist['choice']
        return values[int(rng.integers(len(values)))]
    kind = 'uniform' if 'uniform' in dist else 'normal'
    a, b = (np.asarray(x, dtype=float) for x in dist[kind])
    shape = (len(current),) if isinstance(current, list) else ()
    x = rng.uniform(a, b, size=shape) if kind == 'uniform' else rng.normal(a, b, size=shape)
    if dist.get('add'):
        x = np.asarray(current, dtype=float) + x
    elif dist.get('scale'):
        x = np.asarray(current, dtype=float) * x
    return x.tolist() if shape else float(x)


def run_seed(seed: int, index: int) -> np.random.SeedSequence:
    """The seed sequence of run ``index``: ``SeedSequence(seed).spawn(n)[index]`` for any n > index."""
    return np.random.SeedSequence(seed, spawn_key=(index,))


def expand(spec: Spec, indices=None) -> list:
    """The tasks of runs ``indices`` (default all): dicts of plain values, the same on any machine.

    Each has ``index``, ``grid_point``, ``sample``, ``params`` (path -> value, grid values then
    draws) and what :func:`execute_run` needs (scene text, settings, figures, reference).
    """
    from .scene import SceneLoader
    scene_data = yaml.load(spec.scene_text, Loader=SceneLoader)
    sizes = [len(v) for _, v in spec.grid]
    points = list(itertools.product(*[range(n) for n in sizes])) if spec.grid else [()]
    out = []
    for i in (range(spec.n_runs) if indices is None else indices):
        g, s = divmod(int(i), spec.samples)
        params = {path: values[k] for (path, values), k in zip(spec.grid, points[g])}
        if spec.random:
            rng = np.random.default_rng(run_seed(spec.seed, int(i)))
            for path, dist in spec.random:
                current = None if path in SETTINGS else _lookup(scene_data, path)[1]
                params[path] = _draw(rng, dist, current)
        out.append({'index': int(i), 'grid_point': g, 'sample': s, 'params': params, 'version': _version(),
                    'scene_text': spec.scene_text, 'scene_file': spec.scene_file, 'backend': spec.backend,
                    'duration': spec.duration, 'figures': spec.figures, 'reference': spec.reference,
                    'record': spec.record})
    return out


def _version() -> str:
    from .version import __version__
    return __version__


def build_scene(scene_text: str, scene_file: str, params: dict, backend: str):
    """The scene with the parameters' scene keys set (run settings are left to the caller)."""
    from .scene import SceneLoader, parse_scene
    from .systems.base import backend_scope
    keys = {k: v for k, v in params.items() if k not in SETTINGS}
    text = scene_text
    if keys:
        data = yaml.load(scene_text, Loader=SceneLoader)
        for k, v in keys.items():
            _assign(data, k, v)
        text = yaml.safe_dump(data, sort_keys=False)
    import warnings
    with warnings.catch_warnings(), backend_scope(backend):
        warnings.simplefilter('ignore')  # a stretched-arm warning belongs to the run's message
        return parse_scene(text, file=scene_file, path=scene_file)


def run_settings(scene, overrides: dict, duration: float) -> dict:
    """Integrator settings of one run: ``overrides`` over the scene's, resolved as ``robodyn run`` does."""
    from .runs import resolve_settings
    return resolve_settings(scene, **{k: overrides[k] for k in SETTINGS if k in overrides}, duration=duration)


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
        """The figures of each period of a block (:class:`robodyn_ros.simulation.PeriodBlock`):
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


def _simulate(scene, st, sinks=()):
    """Run ``scene`` with settings ``st``: ``(sim, status, message)``; never raises for the run's own failures."""
    import warnings

    from .simulation import SimulationError, Simulator, run_headless
    notes = []
    sim, status, msg = None, 'ok', ''
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        try:
            sim = Simulator(scene.system, scene.y0, integrator=st['integrator'], dt=st['dt'], rtol=st['rtol'],
                            atol=st['atol'])
        except ValueError as e:
            return None, 'refused', str(e)
        try:
            run_headless(sim, st['duration'], st['rate'], scene.script, sinks, stop=scene.stop)  # as robodyn run
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
    st = run_settings(scene, ref, task['duration'])
    if all(st.get(k) == st_run.get(k) for k in SETTINGS):
        return None, 'same'
    key = hashlib.sha256(json.dumps([task['scene_text'], {k: v for k, v in task['params'].items()
                                                           if k not in SETTINGS}, st, task['backend']],
                                    sort_keys=True).encode()).hexdigest()
    if key not in _REFERENCES:
        sim, status, msg = _simulate(scene, st)
        _REFERENCES[key] = (sim.y.copy(), '') if status == 'ok' else (None, f'reference run {status}: {msg}')
        if len(_REFERENCES) > 64:
            _REFERENCES.pop(next(iter(_REFERENCES)))
    return _REFERENCES[key]


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
    if task.get('version', _version()) != _version():  # a worker that joined after the client's check
        raise ClusterError(f'this worker runs robodyn_ros {_version()}, the client {task["version"]}; install the '
                           'same version on every worker')
    trace = os.environ.get(TRACE_ENV)
    if trace:  # tests count executions
        os.makedirs(trace, exist_ok=True)
        with open(os.path.join(trace, f'{task["index"]:06d}-{os.getpid()}-{time.time_ns()}'), 'w'):
            pass
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
    from .scene import SceneError
    try:
        scene = build_scene(task['scene_text'], task['scene_file'], task['params'], task['backend'])
        st = run_settings(scene, task['params'], task['duration'])
    except SceneError as e:
        row.update(status='invalid', message=str(e))
        st = None
    if st is not None:
        from .integrators import INTEGRATORS
        fixed = INTEGRATORS[st['integrator']].kind == 'fixed'
        row.update(integrator=st['integrator'], dt=st['dt'] if fixed else None, rtol=None if fixed else st['rtol'],
                   atol=None if fixed else st['atol'], duration=st['duration'])
        fig = _Figures(wrenches='max_joint_wrench' in task['figures'])
        sinks = [fig]
        tmp = None
        if task['record']:
            from .recording.run_sink import HEADLESS_BATCH, McapRunSink
            fd, tmp = tempfile.mkstemp(suffix='.mcap')
            os.close(fd)
            from .runs import DIAGNOSTICS_PERIOD
            sinks.append(McapRunSink(tmp, scene, {**st, 'backend': task['backend'], 'mode': 'headless'},
                                     diagnostics_period=DIAGNOSTICS_PERIOD,
                                     batch=HEADLESS_BATCH))  # robodyn run's vectorised path: the same bytes
        try:
            c0 = time.process_time()
            sim, status, msg = _simulate(scene, st, sinks)
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


def _run_guarded(fn, task):
    """``fn(task)``; an exception becomes ``{'error': 'Type: message'}`` so one broken run does not
    stop a sweep (the caller turns it into a row with status 'error')."""
    try:
        return fn(task)
    except Exception as e:  # noqa: BLE001 — recorded in the row, with its type; the sweep goes on
        import traceback
        where = traceback.extract_tb(e.__traceback__)[-1]
        return {'error': f'{type(e).__name__}: {e} (at {os.path.basename(where.filename)}:{where.lineno})'}


# ---------------------------------------------------------------------------------------------
# the engine: Dask or in-process
# ---------------------------------------------------------------------------------------------
class Pool:
    """Where tasks run: a Dask ``LocalCluster`` of ``workers`` processes (one thread each), a
    remote scheduler (``scheduler='tcp://host:8786'``), or this process (``workers=0``).

    Use as a context manager; :meth:`run` yields ``(key, result)`` as tasks finish.
    """

    def __init__(self, workers: int | None = None, scheduler: str | None = None, check_version: bool = True):
        self.workers = (os.cpu_count() or 1) if workers is None else int(workers)
        if self.workers < 0:
            raise ValueError(f'workers must be >= 0, got {workers}')
        self.scheduler = scheduler
        self.check_version = check_version
        self.client = self.cluster = None

    @property
    def inline(self) -> bool:
        """True when tasks run in this process (no Dask)."""
        return self.scheduler is None and self.workers == 0

    def __enter__(self):
        if self.inline:
            return self
        import logging

        from dask.distributed import Client, LocalCluster
        if self.scheduler:
            try:
                self.client = Client(self.scheduler, timeout='30s')
            except OSError as e:
                raise ClusterError(f'cannot reach the Dask scheduler {self.scheduler}: {e}') from None
            try:
                self.client.wait_for_workers(1, timeout=WORKER_WAIT)
            except TimeoutError:
                self.client.close()
                raise ClusterError(f'no Dask worker has joined the scheduler {self.scheduler} within {WORKER_WAIT:g} s '
                                   f'(start some: dask worker {self.scheduler} --nthreads 1)') from None
        else:
            # preload: dask_setup below runs in every worker process (restarted ones too)
            self.cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True,
                                        dashboard_address=None, silence_logs=logging.ERROR,
                                        preload=[__name__])
            self.client = Client(self.cluster)
        if self.check_version:
            self._check_versions()
        return self

    def _check_versions(self):
        seen = self.client.run(_version)
        bad = {w: v for w, v in seen.items() if v != _version()}
        if bad:
            self.__exit__(None, None, None)
            raise ClusterError(f'Dask workers run another robodyn_ros version than this client ({_version()}): '
                               + ', '.join(f'{w}: {v}' for w, v in sorted(bad.items()))
                               + '; install the same version on every worker')

    def __exit__(self, *exc):
        if self.client is not None:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()
        self.client = self.cluster = None
        return False

    def threads(self) -> int:
        """Worker threads that run tasks now (1 in process)."""
        if self.inline:
            return 1
        return max(1, sum(w.get('nthreads', 1) for w in self.client.scheduler_info()['workers'].values()))

    def run(self, fn, items, name='task', chunk: int = 1):
        """Run ``fn(arg)`` for every ``(key, arg)`` of ``items``; yield ``(key, result)`` as each
        finishes (an exception inside fn is returned as ``{'error': ...}``, see :func:`_run_guarded`).

        chunk: items per Dask task (consecutive items; their results arrive together), so that
        the scheduling cost of a task is shared by several short runs. Dask reruns the task of a
        worker that died (fn must be idempotent); the caller keeps the first result of each key.
        """
        items = list(items)
        if self.inline:
            for key, arg in items:
                yield key, _run_guarded(fn, arg)
            return
        from dask.distributed import as_completed
        token = os.urandom(4).hex()
        chunk = max(1, int(chunk))
        futures = {}
        for k in range(0, len(items), chunk):
            batch = items[k:k + chunk]
            fut = self.client.submit(_run_batch, fn, [arg for _, arg in batch], key=f'{name}-{batch[0][0]}-{token}',
                                     pure=False)
            futures[fut] = [key for key, _ in batch]
        try:
            for fut in as_completed(futures):
                keys = futures[fut]
                try:
                    results = fut.result()
                except Exception as e:  # noqa: BLE001 — a task lost beyond Dask's retries (KilledWorker): rows say so
                    results = [{'error': f'{type(e).__name__}: {e}'}] * len(keys)
                yield from zip(keys, results)
                fut.release()
        finally:
            for fut in futures:
                if not fut.done():
                    fut.cancel()


def dask_setup(worker):
    """Worker preload of the local cluster: Ctrl-C in a terminal reaches every process of the
    group; the workers ignore it and the client, which keeps the finished rows, shuts them down
    (instead of a KeyboardInterrupt traceback from each worker)."""
    import signal
    import threading
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def _run_batch(fn, args) -> list:
    """One Dask task: ``fn`` over several arguments, guarded one by one."""
    return [_run_guarded(fn, a) for a in args]


def chunk_size(runs: int, threads: int) -> int:
    """Runs per Dask task: about ``TASKS_PER_THREAD`` tasks per worker thread (load balance), at
    most ``MAX_CHUNK`` runs each (a lost task is rerun whole, and rows arrive a task at a time)."""
    return max(1, min(MAX_CHUNK, runs // (TASKS_PER_THREAD * max(1, threads))))


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
            'scene': spec.scene_name, 'version': _version(), 'spec': spec.text}
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
        try:
            with (contextlib.nullcontext(pool) if pool is not None else Pool(workers, scheduler)) as p:
                chunk = chunk_size(len(tasks), p.threads())
                for i, res in p.run(execute_run, tasks.items(), name='run', chunk=chunk):
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
                    if progress is not None:
                        progress.step(f'run {i}: {row["status"]}')
        except KeyboardInterrupt:
            interrupted = True
    table = fig = None
    if not interrupted:
        table = consolidate(spec, out)
        if plot:
            fig = summary_plot(table, os.path.join(out, 'summary.png'))
    return SweepResult(runs=spec.n_runs, skipped=len(done), executed=executed, interrupted=interrupted,
                       table=table, plot=fig, wall=time.perf_counter() - w0)


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
