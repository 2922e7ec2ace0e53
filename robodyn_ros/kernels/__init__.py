"""Compiled (numba) rigid-body kernels: the fast path beside the numpy reference.

:mod:`robodyn_ros.dynamics` stays the reference; this package computes the same quantities
(tested equal to 1e-12 relative on random trees and every bundled scene) in numba-compiled
code on a packed copy of the model::

    from robodyn_ros import kernels
    if kernels.AVAILABLE:
        km = kernels.CompiledModel(model)
        qdd = km.aba(q, v, tau)              # (nv,)
        tau = km.rnea(q, v, a)               # (nv,)
        M = km.crba(q)                       # (nv, nv)
        qdd, f = km.joint_wrenches(q, v, tau)
        T, V = km.energies(q, v)

Arguments are float64 numpy arrays (1-D slices of a state vector are fine); results are new
arrays. ``AVAILABLE`` is False when numba cannot be imported, and callers (``ArmSystem``) then
use the reference. The fused integrators (:meth:`CompiledModel.integrate_arm`) run a whole
publication period of fixed steps in one compiled call.

Compilation cache. Every kernel is ``@njit(cache=True)``: the first start of a new install
compiles (a few seconds, see ``robodyn bench speed``) and writes the machine code next to the
source in ``robodyn_ros/kernels/__pycache__``; later starts load it. If that directory is not
writable (a system-wide install), the cache goes to ``$NUMBA_CACHE_DIR`` when set, else to
``$XDG_CACHE_HOME/robodyn_ros/numba`` (``~/.cache/robodyn_ros/numba``); :data:`CACHE_DIR`
says which one is in use. Set ``ROBODYN_BACKEND=numpy`` to switch the compiled path off.
"""
from __future__ import annotations

import os

import numpy as np

from ..model import Model


def _cache_dir() -> str:
    """Where numba's cache goes: in tree if writable, else NUMBA_CACHE_DIR or a user cache dir."""
    here = os.path.dirname(os.path.abspath(__file__))
    pycache = os.path.join(here, '__pycache__')
    if os.environ.get('NUMBA_CACHE_DIR'):
        return os.environ['NUMBA_CACHE_DIR']
    probe = pycache if os.path.isdir(pycache) else here
    if os.access(probe, os.W_OK):
        return pycache
    base = os.environ.get('XDG_CACHE_HOME') or os.path.join(os.path.expanduser('~'), '.cache')
    path = os.path.join(base, 'robodyn_ros', 'numba')
    os.environ['NUMBA_CACHE_DIR'] = path
    return path


#: directory holding the compiled kernels' cache (see the module docstring)
CACHE_DIR = _cache_dir()

try:
    if os.environ.get('ROBODYN_BACKEND', '').lower() == 'numpy':
        raise ImportError('ROBODYN_BACKEND=numpy')
    import numba  # noqa: F401
    if CACHE_DIR != os.path.join(os.path.dirname(os.path.abspath(__file__)), '__pycache__'):
        numba.config.CACHE_DIR = CACHE_DIR  # numba may have been imported before we set the env
    from . import core
    AVAILABLE = True
    UNAVAILABLE_REASON = ''
except ImportError as _e:  # numba missing: the numpy reference is used
    core = None
    AVAILABLE = False
    UNAVAILABLE_REASON = str(_e)

__all__ = ['AVAILABLE', 'CACHE_DIR', 'CompiledModel', 'pack_model', 'FUSED_METHODS', 'warmup']

#: integrator names the fused loop implements -> method code in :mod:`.core`
FUSED_METHODS = {'euler': 0, 'semi_implicit_euler': 1, 'rk4': 2}


def pack_model(model: Model):
    """The model as two arrays for the kernels: ``(mi (nb, 4) int64, mf (nb + 1, NF) float64)``.

    Column layout in :mod:`robodyn_ros.kernels.core`: per body parent, joint type, q and v
    index; axis, Xtree as (E, r), mass, m·com, rotational inertia about the body origin; the
    last row of mf holds gravity.
    """
    nb = model.nb
    mi = np.empty((nb, 4), dtype=np.int64)
    mi[:, 0] = model.parent
    mi[:, 1] = model.jtype
    mi[:, 2] = model.q_idx
    mi[:, 3] = model.v_idx
    NF = 28
    mf = np.zeros((nb + 1, NF))
    for i in range(nb):
        X = model.Xtree[i]
        E = X[:3, :3]
        rx = -(E.T @ X[3:, :3])  # X[3:, :3] = -E r×
        I = model.I[i]
        m = I[5, 5]
        hx = I[:3, 3:]  # = h× with h = m c
        mf[i, 0:3] = model.axis[i]
        mf[i, 3:12] = E.reshape(-1)
        mf[i, 12:15] = (rx[2, 1], rx[0, 2], rx[1, 0])
        mf[i, 15] = m
        mf[i, 16:19] = (hx[2, 1], hx[0, 2], hx[1, 0])
        mf[i, 19:28] = I[:3, :3].reshape(-1)
    mf[nb, 0:3] = model.gravity
    return np.ascontiguousarray(mi), np.ascontiguousarray(mf)


class CompiledModel:
    """A model packed for the compiled kernels, with the reference functions' signatures.

    model: the kinematic tree. All methods take float64 arrays of the reference shapes
    (q (nq,), v/a/tau (nv,), f_ext (nb, 6) in body coordinates) and return new arrays.
    """

    def __init__(self, model: Model):
        if not AVAILABLE:
            raise RuntimeError(f'compiled kernels unavailable: {UNAVAILABLE_REASON}')
        self.model = model
        self.mi, self.mf = pack_model(model)
        self.nb, self.nq, self.nv = model.nb, model.nq, model.nv
        self.damping = np.ascontiguousarray(model.damping, dtype=float).reshape(self.nv)
        self._zf = np.zeros((self.nb, 6))

    def aba(self, q, v, tau, f_ext=None):
        """Forward dynamics ``qdd`` (nv,) by the articulated-body algorithm."""
        if f_ext is None:
            return core.aba(self.mi, self.mf, q, v, tau)
        return core.aba_fext(self.mi, self.mf, q, v, tau, np.ascontiguousarray(f_ext, dtype=float))

    def rnea(self, q, v, a, f_ext=None):
        """Inverse dynamics ``tau = M a + h`` (nv,)."""
        if f_ext is None:
            return core.rnea_tau(self.mi, self.mf, q, v, a)
        return core.rnea(self.mi, self.mf, q, v, a, np.ascontiguousarray(f_ext, dtype=float), True)[0]

    def rnea_wrenches(self, q, v, a, f_ext=None):
        """``(tau (nv,), f (nb, 6))``: inverse dynamics and the joint wrenches (parent on child)."""
        fe, has = (self._zf, False) if f_ext is None else (np.ascontiguousarray(f_ext, dtype=float), True)
        return core.rnea(self.mi, self.mf, q, v, a, fe, has)

    def crba(self, q):
        """Joint-space inertia matrix ``M(q)`` (nv, nv)."""
        return core.crba(self.mi, self.mf, q, self.nv)

    def joint_wrenches(self, q, v, tau, f_ext=None):
        """``(qdd (nv,), f (nb, 6))`` under applied forces tau (see ``dynamics.joint_wrenches``)."""
        fe, has = (self._zf, False) if f_ext is None else (np.ascontiguousarray(f_ext, dtype=float), True)
        return core.joint_wrenches(self.mi, self.mf, q, v, tau, fe, has)

    def energies(self, q, v):
        """``(kinetic, potential)`` energy (J)."""
        return core.energies(self.mi, self.mf, q, v)

    def kinetic_energy(self, q, v):
        """Kinetic energy (J)."""
        return core.energies(self.mi, self.mf, q, v)[0]

    def potential_energy(self, q):
        """Gravitational potential energy (J), zero at the root origin."""
        return core.energies(self.mi, self.mf, q, np.zeros(self.nv))[1]

    def qdot(self, q, v):
        """Configuration rate ``dq/dt`` (nq,) (quaternion-aware)."""
        return core.qdot(self.mi, q, v)

    def normalize(self, q):
        """q with free-joint quaternions renormalised (a new array)."""
        q = np.array(q, dtype=float)
        core.normalize_into(self.mi, q)
        return q

    def integrate_arm(self, method: str, z, tau_app, dt, n_full, h_last) -> int:
        """Fused fixed-step integration of ``z = [q, v, W]`` in place (see ``core.integrate_arm``).

        method: a key of :data:`FUSED_METHODS`; z (nq + nv + 1,) float64, modified in place;
        tau_app (nv,) = B u held over the call; dt, n_full, h_last: the step grid. Returns the
        index of the first non-finite step or -1.
        """
        return core.integrate_arm(self.mi, self.mf, self.damping, tau_app, self.nq, FUSED_METHODS[method],
                                  z, float(dt), int(n_full), float(h_last))


def warmup(model: Model | None = None) -> float:
    """Load (or compile, on a cold cache) every kernel by calling it once; returns seconds taken."""
    import time
    from ..model import random_tree
    t0 = time.perf_counter()
    if not AVAILABLE:
        return 0.0
    if model is None:
        model = random_tree(3, np.random.default_rng(0))
    km = CompiledModel(model)
    q = model.neutral()
    v = np.zeros(model.nv)
    km.aba(q, v, v)
    km.aba(q, v, v, np.zeros((model.nb, 6)))
    km.rnea(q, v, v)
    km.rnea_wrenches(q, v, v)
    km.rnea(q, v, v, np.zeros((model.nb, 6)))
    km.crba(q)
    km.joint_wrenches(q, v, v)
    km.energies(q, v)
    km.qdot(q, v)
    km.normalize(q)
    for m in FUSED_METHODS:
        z = np.concatenate([q, v, [0.0]])
        km.integrate_arm(m, z, v, 1e-3, 2, 0.0)
    return time.perf_counter() - t0
