"""Sweep specs: the YAML that says which runs of a scene ``robodyn sweep`` makes (schema in
:mod:`robodyn_ros.sweep`), validated with ``<file>: <key path>: <reason>`` errors; the runs it
expands to (:func:`expand`: grid points and seeded draws, plain values the same on any machine)
and the scene of one run's parameters (:func:`build_scene`).
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import itertools
from dataclasses import dataclass, field

import numpy as np
import yaml

from .version import __version__

__all__ = ['SweepError', 'Spec', 'parse_spec', 'load_spec', 'expand', 'run_seed', 'build_scene', 'lookup', 'assign', 'FIGURES', 'SETTINGS',
           'DISTRIBUTIONS', 'DEFAULT_REFERENCE', 'FORMAT']

#: figures a spec may ask for (status, message, steps, rhs_evals, y_final and timings always come)
FIGURES = ('final_error', 'energy_drift', 'momentum_drift', 'constraint_residual', 'max_joint_wrench')
#: run settings a parameter path may name (everything else is a scene key)
SETTINGS = ('integrator', 'dt', 'rtol', 'atol')
DISTRIBUTIONS = ('uniform', 'normal', 'choice')
DEFAULT_REFERENCE = {'integrator': 'dop853', 'rtol': 1e-10, 'atol': 1e-10}
_SPEC_REQUIRED = ('scene',)
_SPEC_OPTIONAL = ('seed', 'samples', 'duration', 'backend', 'grid', 'random', 'reference', 'figures', 'record',
                  'description')
#: the table layout; bump when the meaning of a column changes (a DIR of another format is refused)
FORMAT = 1

class SweepError(ValueError):
    """A sweep spec that cannot be run; the message is ``<file>: <key path>: <reason>``."""


@dataclass
class Spec:
    """A validated sweep spec (see the module docstring).

    file: where it came from; text: its YAML; scene_file: the scene's path; scene_text: the
    scene's YAML; grid: ``[(path, values)]``; random: ``[(path, distribution mapping)]``;
    settings: the scene's run settings with ``duration`` resolved; reference: settings of the
    reference run (None without final_error); files: the contents of the files the scene refers to
    (URDF files, as written in the scene -> bytes), read once on the client: they travel with every
    task, so that no run reads a disk (workers need no shared file system).
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
    files: dict = field(default_factory=dict)

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
        """sha256 of everything that decides the rows (the spec, the scene's text and the files it
        refers to)."""
        what = [FORMAT, self.text, self.scene_text] + ([files_digest(self.files)] if self.files else [])
        return hashlib.sha256(json.dumps(what).encode()).hexdigest()


def _fail(file, path, reason):
    raise SweepError(f'{file}: {path or "(top level)"}: {reason}')


def _split(path: str) -> list:
    """``'parts.0.dh.links.2.mass'`` -> ``['parts', 0, 'dh', 'links', 2, 'mass']``."""
    return [int(p) if p.isdigit() else p for p in path.split('.')]


def lookup(data, path: str):
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


def assign(data, path: str, value):
    """Set a dotted path in the nested scene mapping (the path exists: checked by :func:`lookup`)."""
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
    """A value for a run setting: a known integrator name (or auto) or a positive number."""
    if key == 'integrator':
        from .integrator_choice import AUTO
        from .integrators import INTEGRATORS
        if not isinstance(value, str) or (value not in INTEGRATORS and value != AUTO):
            _fail(file, path, f'unknown integrator {value!r}; known: {AUTO}, {", ".join(INTEGRATORS)}')
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
                ok, current, why = lookup(scene_data, key)
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
    absent = {k for k, _ in random if k not in SETTINGS and lookup(scene_data, k)[1] is None}
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
        spec.files.update(scene.files)   # read here, on the client, and only here
        if g == 0:
            spec.settings = dict(scene.settings)
            _warn_bare_root_velocity(file, grid, random, scene)
    spec.duration = float(duration) if duration is not None else float(spec.settings.get('duration', 10.0))
    return spec


def _warn_bare_root_velocity(file, grid, random, scene):
    """Warn once per spec (``scene.state.VelocityOrderWarning``) where a parameter sets a free root's
    velocities as bare numbers (``initial_state.v`` a list, or its elements 0..5 from the root's first):
    they are read angular first, in the root's body axes; the mapping form
    (``initial_state.v.root.linear``, ``...angular``, with its ``frame``) says which."""
    import warnings

    from .scene.state import VelocityOrderWarning, free_root
    root = free_root(scene.system)
    v = (scene.data.get('initial_state') or {}).get('v')
    if root is None or isinstance(v, dict):
        return
    for section, items in (('grid', grid), ('random', random)):
        for key, _ in items:
            keys = _split(key)
            if keys[:2] != ['initial_state', 'v'] or (len(keys) > 2 and not root[2] <= keys[2] < root[2] + 6):
                continue
            warnings.warn(VelocityOrderWarning(
                f'{file}: {section}.{key}: the free root {root[0]!r}\'s velocities are read angular first, in its '
                f'body axes (Featherstone\'s order, not ROS Twist\'s); to say which, give the scene initial_state.v: '
                f'{{root: {{linear: [...], angular: [...], frame: world or body}}, joints: [...]}} and vary '
                f'initial_state.v.root.linear or .angular'), stacklevel=3)
            return


def files_digest(files: dict) -> str:
    """sha256 of a scene's referenced files (reference -> bytes or text), in reference order."""
    h = hashlib.sha256()
    for ref in sorted(files):
        data = files[ref]
        for part in (ref.encode(), data if isinstance(data, bytes) else data.encode()):
            h.update(len(part).to_bytes(8, 'little') + part)
    return h.hexdigest()


def build_scene(scene_text: str, scene_file: str, params: dict, backend: str, files: dict | None = None):
    """The scene with the parameters' scene keys set (run settings are left to the caller).

    files: the contents of the files the scene refers to (:attr:`Spec.files`); None: read them from
    the disk (the client, checking a spec)."""
    from .scene import SceneLoader, parse_scene
    from .systems.base import backend_scope
    keys = {k: v for k, v in params.items() if k not in SETTINGS}
    text = scene_text
    if keys:
        data = yaml.load(scene_text, Loader=SceneLoader)
        for k, v in keys.items():
            assign(data, k, v)
        text = yaml.safe_dump(data, sort_keys=False)
    import warnings
    with warnings.catch_warnings(), backend_scope(backend):
        warnings.simplefilter('ignore')  # a stretched-arm warning belongs to the run's message
        return parse_scene(text, file=scene_file, path=scene_file, files=files)


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
    draws) and what :func:`execute_run` needs (scene text, the contents of the files it refers to,
    settings, figures, reference): a task reads nothing from a disk.
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
                current = None if path in SETTINGS else lookup(scene_data, path)[1]
                params[path] = _draw(rng, dist, current)
        out.append({'index': int(i), 'grid_point': g, 'sample': s, 'params': params, 'version': __version__,
                    'scene_text': spec.scene_text, 'scene_file': spec.scene_file,
                    'files': _task_files(spec, params), 'backend': spec.backend,
                    'duration': spec.duration, 'figures': spec.figures, 'reference': spec.reference,
                    'record': spec.record})
    return out


def _task_files(spec: Spec, params: dict) -> dict:
    """The referenced files a run needs: the spec's, and a file a drawn parameter names (a
    ``choice`` of URDF files for a part's ``file``), read here on the client."""
    files = spec.files
    for k, v in params.items():
        if k.rsplit('.', 1)[-1] == 'file' and isinstance(v, str) and v not in files:
            from .scene import SceneError
            try:
                scene = build_scene(spec.scene_text, spec.scene_file, {k: v}, spec.backend)
            except SceneError:
                continue   # the run reports it (an 'invalid' row)
            files = {**files, **scene.files}
            spec.files.update(scene.files)
    return files
