"""Validation of input files: every failure names the file and the key path.

A scene file (and the command profiles in it) is checked through one :class:`SceneContext`,
whose helpers raise :class:`SceneError` ``<file>: <key path>: <reason>`` (e.g. ``arm.yaml:
parts[0].dh.links[2].mass: missing key``). This module sits low in the house so that the parts'
parsers (:mod:`robodyn_ros.scene`) and the command profiles (:mod:`robodyn_ros.profiles`) share
it without importing each other.
"""
from __future__ import annotations

import math

import numpy as np

from .spatial import rpy_to_R

__all__ = ['SceneError', 'SceneContext', 'key_path', 'typename', 'registered']


class SceneError(ValueError):
    """A scene that cannot be loaded; the message is ``<file>: <key path>: <reason>``."""


def key_path(path: str, key) -> str:
    """Key path of ``key`` under ``path`` ('a.b', 'a[3]')."""
    if isinstance(key, int):
        return f'{path}[{key}]'
    return f'{path}.{key}' if path else str(key)


def typename(v) -> str:
    """The type name of a YAML value for messages ('null' for None)."""
    return type(v).__name__ if v is not None else 'null'


class SceneContext:
    """Validation context: the file name, the gravity vector and the parts built so far.

    file: file name used in messages, and the file relative references start from; files: the
    referenced files' contents given with the scene text (reference as written -> bytes; None: read
    them from disk). Helpers raise :class:`SceneError` with the key path.
    """

    def __init__(self, file: str, files: dict | None = None):
        self.file = file
        self.given_files = files
        self.files = {}   # what the scene read: reference -> bytes (Scene.files)
        self.gravity = np.array([0.0, 0.0, -9.81])
        self.parts: list = []   # robodyn_ros.scene.Part
        self.y0 = None  # the initial state, once known (command profiles are built after it)

    def fail(self, path: str, reason: str):
        """Raise ``SceneError('<file>: <path>: <reason>')``."""
        raise SceneError(f'{self.file}: {path or "(top level)"}: {reason}')

    def mapping(self, v, path: str, required=(), optional=()) -> dict:
        """Check that ``v`` is a mapping with all ``required`` keys and no keys outside both lists."""
        if not isinstance(v, dict):
            self.fail(path, f'expected a mapping, got {typename(v)} {v!r}')
        allowed = tuple(required) + tuple(optional)
        for k in v:
            if k not in allowed:
                self.fail(key_path(path, k), f'unknown key {k!r}; allowed keys here: {", ".join(allowed)}')
        for k in required:
            if k not in v:
                self.fail(key_path(path, k), 'missing required key')
        return v

    def number(self, v, path: str, minimum=None, positive=False) -> float:
        """A finite real number (not a bool); ``minimum`` inclusive, ``positive`` strict."""
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.fail(path, f'expected a number, got {typename(v)} {v!r}')
        x = float(v)
        if not math.isfinite(x):
            self.fail(path, f'expected a finite number, got {v!r}')
        if positive and x <= 0.0:
            self.fail(path, f'must be > 0, got {x!r}')
        if minimum is not None and x < minimum:
            self.fail(path, f'must be >= {minimum!r}, got {x!r}')
        return x

    def string(self, v, path: str) -> str:
        """A non-empty string."""
        if not isinstance(v, str) or not v:
            self.fail(path, f'expected a non-empty string, got {typename(v)} {v!r}')
        return v

    def boolean(self, v, path: str) -> bool:
        """true or false."""
        if not isinstance(v, bool):
            self.fail(path, f'expected true or false, got {typename(v)} {v!r}')
        return v

    def sequence(self, v, path: str, n: int | None = None, what: str = 'values') -> list:
        """A list, of length ``n`` when given."""
        if not isinstance(v, list):
            self.fail(path, f'expected a list, got {typename(v)} {v!r}')
        if n is not None and len(v) != n:
            self.fail(path, f'expected {n} {what}, got {len(v)}')
        return v

    def vector(self, v, path: str, n: int | None = None, what: str = 'values', minimum=None) -> np.ndarray:
        """A list of ``n`` finite numbers as a float array."""
        self.sequence(v, path, n, what)
        return np.array([self.number(x, key_path(path, i), minimum=minimum) for i, x in enumerate(v)], dtype=float)

    def names(self, v, path: str, n: int | None = None) -> list:
        """A list of distinct non-empty strings."""
        self.sequence(v, path, n, 'names')
        out = [self.string(x, key_path(path, i)) for i, x in enumerate(v)]
        for i, x in enumerate(out):
            if x in out[:i]:
                self.fail(key_path(path, i), f'duplicate name {x!r}')
        return out

    def inertia(self, v, path: str) -> np.ndarray:
        """Inertia (3, 3) from ``[[..],[..],[..]]`` or ``[ixx, iyy, izz, ixy, ixz, iyz]``.

        Only the form is checked here; symmetry, positive semi-definiteness and the triangle
        inequality are the model's checks (their errors are mapped back to this key path).
        """
        if isinstance(v, list) and len(v) == 6 and not any(isinstance(x, list) for x in v):
            ixx, iyy, izz, ixy, ixz, iyz = self.vector(v, path, 6)
            return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
        if isinstance(v, list) and len(v) == 3 and all(isinstance(r, list) for r in v):
            return np.array([self.vector(r, key_path(path, i), 3) for i, r in enumerate(v)])
        self.fail(path, f'expected a 3x3 matrix or [ixx, iyy, izz, ixy, ixz, iyz], got {v!r}')

    def pose(self, v, path: str) -> np.ndarray:
        """Homogeneous transform (4, 4) from ``{xyz: (3,), rpy: (3,)}`` (URDF convention, both optional)."""
        self.mapping(v, path, optional=('xyz', 'rpy'))
        T = np.eye(4)
        T[:3, 3] = self.vector(v.get('xyz', [0.0, 0.0, 0.0]), key_path(path, 'xyz'), 3)
        T[:3, :3] = rpy_to_R(self.vector(v.get('rpy', [0.0, 0.0, 0.0]), key_path(path, 'rpy'), 3))
        return T

    def limits(self, v, path: str) -> tuple:
        """Joint limits ``[lo, hi]`` with lo < hi."""
        lo, hi = self.vector(v, path, 2, 'values [lower, upper]')
        if not lo < hi:
            self.fail(path, f'lower limit {lo!r} must be below upper limit {hi!r}')
        return (lo, hi)


def registered(ctx: SceneContext, spec, path: str, key: str, registry: dict, what: str, plural: str,
               mapping_hint: str = ''):
    """The builder that ``spec[key]`` names in ``registry`` (part kinds, command profiles).

    Fails with the file and key path when spec is not a mapping, lacks ``key``, or names
    nothing registered (the message lists the known ``plural``).
    """
    if not isinstance(spec, dict):
        ctx.fail(path, f'expected a mapping{mapping_hint}, got {typename(spec)} {spec!r}')
    if key not in spec:
        ctx.fail(key_path(path, key), 'missing required key')
    name = ctx.string(spec[key], key_path(path, key))
    builder = registry.get(name)
    if builder is None:
        ctx.fail(key_path(path, key), f'unknown {what} {name!r}; known {plural}: {", ".join(registry)}')
    return builder
