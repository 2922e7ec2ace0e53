"""The measurement store: work-precision runs of a scene on this machine, cached for later advice.

A measured run is a :class:`Run` (one row of ``robodyn bench precision``'s CSV: the setting, its
final-state error against a reference, its CPU and wall time per simulated second, rhs
evaluations, drifts). ``robodyn bench precision`` stores the runs of each scene here and
``robodyn advise`` reads them back, one JSON file per scene and machine::

    $XDG_CACHE_HOME/robodyn_ros/precision/<scene>-<key>.json    (~/.cache/robodyn_ros/... by default)
    key = sha256(scene name, sha256 of the scene's YAML text, machine id, package version)[:20]
    machine id = platform.node() + '-' + cpu count

so an edited scene, another machine or another release of the package never reuses old figures
(the old file simply stops being found). A full-ladder entry is never replaced by a quick one.
The cost of a run, for choosing among runs, is :func:`cost_key`.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import platform
import re
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ['CSV_FIELDS', 'Run', 'cost_key', 'load_scene_quietly', 'CACHE_FORMAT', 'cache_dir', 'machine_id',
           'scene_hash', 'cache_key', 'cache_path', 'scene_of', 'store', 'load', 'runs']

CSV_FIELDS = ('scene', 'formulation', 'integrator', 'kind', 'dt', 'rtol', 'atol', 'horizon', 'status', 'error',
              'error_floor', 'wall_per_sim_s', 'cpu_per_sim_s', 'rhs_evals', 'rhs_per_sim_s', 'steps', 'rejected_steps',
              'energy_drift', 'momentum_drift', 'constraint_residual', 'note')


#: "about one step per period": at most this many steps per publication period (:meth:`Run.one_step_per_period`)
ONE_STEP_SLACK = 1.25


@dataclass
class Run:
    """One measured run (a row of the CSV; see the module docstring for the fields)."""

    scene: str
    formulation: str
    integrator: str
    kind: str
    dt: float | None
    rtol: float | None
    atol: float | None
    horizon: float
    status: str = 'ok'
    error: float = math.nan
    error_floor: bool = False
    wall_per_sim_s: float = math.nan
    cpu_per_sim_s: float = math.nan
    rhs_evals: int = 0
    rhs_per_sim_s: float = math.nan
    steps: int = 0
    rejected_steps: int | None = 0
    energy_drift: float = math.nan
    momentum_drift: float = math.nan
    constraint_residual: float = math.nan
    note: str = ''
    y: np.ndarray | None = field(default=None, repr=False)

    @property
    def setting(self) -> str:
        """``dt=0.001``, ``rtol=1e-06`` or (rosenbrock2 under error control) ``rtol=1e-06 dt<=0.01``."""
        if self.kind == 'controlled':
            return f'rtol={self.rtol:g} dt<={self.dt:g}'
        return f'dt={self.dt:g}' if self.kind == 'fixed' else f'rtol={self.rtol:g}'

    @property
    def label(self) -> str:
        """Method (``rosenbrock2+rtol`` under error control) and formulation, for plot legends."""
        return self.integrator + ('+rtol' if self.kind == 'controlled' else '') + \
            (f' ({self.formulation})' if self.formulation else '')

    def one_step_per_period(self, rate: float) -> bool:
        """An error-controlled run that took about one step per publication period (``rate`` Hz; at most
        :data:`ONE_STEP_SLACK` times as many steps as periods: the first periods may take two while
        the controller finds its step): each period starts afresh (held commands) and one step met
        the tolerance, so a looser or tighter rtol, down to where that stops, takes the same steps and
        gives the same run: the period, not rtol, sets the step."""
        periods = int(round(self.horizon * rate))
        return self.kind in ('adaptive', 'controlled') and self.status == 'ok' and \
            0 < self.steps <= ONE_STEP_SLACK * periods

    def error_text(self, floor: float) -> str:
        """The error as printed: ``3.2e-07``, or ``≤ 2e-15 (the reference's floor)`` when it is at or below
        the reference's error estimate ``floor``: a smaller figure, 0 included, says nothing of the run."""
        if not math.isfinite(self.error):
            return '—'
        if self.error_floor:
            return f'≤ {max(floor, 0.0):.1g} (the reference\'s floor)'
        return f'{self.error:.1e}'

    def row(self) -> dict:
        """The CSV row."""
        d = {k: getattr(self, k) for k in CSV_FIELDS}
        d['rejected_steps'] = '' if self.rejected_steps is None else self.rejected_steps
        for k in ('dt', 'rtol', 'atol'):
            d[k] = '' if d[k] is None else d[k]
        return d

    @classmethod
    def from_row(cls, d: dict) -> 'Run':
        """Inverse of :meth:`row` (CSV or JSON)."""
        def num(x, conv=float):
            return None if x in ('', None) else conv(x)
        kw = {}
        for f in dataclasses.fields(cls):
            if f.name == 'y' or f.name not in d:
                continue
            x = d[f.name]
            if f.name in ('dt', 'rtol', 'atol'):
                kw[f.name] = num(x)
            elif f.name in ('rhs_evals', 'steps'):
                kw[f.name] = int(float(x))
            elif f.name == 'rejected_steps':
                kw[f.name] = num(x, lambda s: int(float(s)))
            elif f.name == 'error_floor':
                kw[f.name] = x in (True, 'True', 'true', '1', 1)
            elif f.name in ('horizon', 'error', 'wall_per_sim_s', 'cpu_per_sim_s', 'rhs_per_sim_s', 'energy_drift',
                            'momentum_drift', 'constraint_residual'):
                kw[f.name] = math.nan if x in ('', None) else float(x)
            else:
                kw[f.name] = x
        return cls(**kw)


def cost_key(r):
    """Sort key of a run's cost: CPU seconds per simulated second (wall seconds when CPU time was
    not measured), then rhs evaluations per simulated second."""
    c = r.cpu_per_sim_s if math.isfinite(r.cpu_per_sim_s) else r.wall_per_sim_s
    n = r.rhs_per_sim_s
    return (c if math.isfinite(c) else math.inf, n if math.isfinite(n) else math.inf)


def load_scene_quietly(name_or_path):
    """Load a scene with warnings silenced (a stretched-arm warning belongs to the run)."""
    from .scene import load_scene
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        return load_scene(name_or_path)


#: bump when the cached JSON layout or the meaning of its figures changes
CACHE_FORMAT = 4   # 3: rosenbrock2 in the precision ladder; 4: the reference's steps bounded (its floor)


def cache_dir() -> Path:
    """``$XDG_CACHE_HOME/robodyn_ros/precision`` (``~/.cache/robodyn_ros/precision`` when unset)."""
    base = os.environ.get('XDG_CACHE_HOME') or os.path.join(os.path.expanduser('~'), '.cache')
    return Path(base) / 'robodyn_ros' / 'precision'


def machine_id() -> str:
    """This machine for cache purposes: host name and CPU count."""
    return f'{platform.node() or "unknown"}-{os.cpu_count() or 0}'


def scene_hash(text: str) -> str:
    """sha256 (hex) of a scene's YAML text."""
    return hashlib.sha256(text.encode('utf-8')).hexdigest()


def _version() -> str:
    from .version import __version__
    return __version__


def cache_key(name: str, text: str, machine: str | None = None, version: str | None = None) -> str:
    """The cache key of a scene's measurements (module docstring)."""
    parts = [CACHE_FORMAT, name, scene_hash(text), machine or machine_id(), version or _version()]
    return hashlib.sha256(json.dumps(parts).encode('utf-8')).hexdigest()[:20]


def cache_path(name: str, text: str, directory: Path | None = None) -> Path:
    """File holding the measurements of scene ``name`` with YAML ``text`` on this machine."""
    safe = re.sub(r'[^A-Za-z0-9_.-]', '_', name)
    return Path(directory or cache_dir()) / f'{safe}-{cache_key(name, text)}.json'


def scene_of(name_or_scene):
    """A loaded scene as it is, or the scene of that name or path (loaded quietly)."""
    if hasattr(name_or_scene, 'text'):
        return name_or_scene
    return load_scene_quietly(name_or_scene)


def store(name_or_scene, result, directory: Path | None = None) -> Path:
    """Cache a :class:`~robodyn_ros.bench.precision.SceneResult` (or any object with its fields) for
    its scene; returns the file.

    A full-ladder entry is kept when a quick one arrives. The write is atomic (temp + rename).
    """
    scene = scene_of(name_or_scene)
    path = cache_path(scene.name, scene.text, directory)
    old = load(scene, directory)
    if old is not None and old.get('mode') == 'full' and result.mode != 'full':
        return path
    data = {'format': CACHE_FORMAT, 'scene': scene.name, 'scene_sha256': scene_hash(scene.text),
            'machine': machine_id(), 'version': _version(), 'created': time.strftime('%Y-%m-%d %H:%M:%S'),
            'mode': result.mode, 'horizon': result.horizon, 'rate': result.rate,
            'own_formulation': result.own_formulation,
            'reference': {'kind': result.reference.kind, 'error_estimate': result.reference.error_estimate,
                          'check': result.reference.check},
            'runs': [_jsonable(r.row()) for r in result.runs]}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f'.tmp{os.getpid()}')
    tmp.write_text(json.dumps(data, indent=1, allow_nan=True))
    os.replace(tmp, path)
    return path


def _jsonable(row: dict) -> dict:
    out = {}
    for k, v in row.items():
        if hasattr(v, 'item'):
            v = v.item()
        out[k] = v
    return out


def load(name_or_scene, directory: Path | None = None) -> dict | None:
    """The cached measurements of a scene on this machine (None when absent or unreadable)."""
    scene = scene_of(name_or_scene)
    path = cache_path(scene.name, scene.text, directory)
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if data.get('format') != CACHE_FORMAT or data.get('scene_sha256') != scene_hash(scene.text):
        return None
    data['path'] = str(path)
    return data


def runs(data: dict) -> list:
    """The :class:`Run` records of a cache entry (:func:`load`)."""
    return [Run.from_row(d) for d in data['runs']]
