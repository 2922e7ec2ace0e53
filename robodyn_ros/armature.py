"""Joint armature: the rotor inertia that makes a mass matrix singular at the start regular.

A real joint is driven through a gear by a motor whose rotor spins ``N`` times faster than the
joint: its inertia ``J`` adds ``a = N² J`` to the joint's own diagonal entry of the mass matrix,
``M + diag(a)`` (MuJoCo's and Pinocchio's ``armature``; :attr:`robodyn_ros.model.LinkSpec.armature`,
computed by the compiled kernels). URDF has no element for it, so an imported robot has none, and a
robot whose joints meet no inertia at its start has a singular M there: example-robot-data's icub,
whose ``neck_yaw`` and ``neck_roll`` axes line up at q = 0 with a point mass between them, so a
motion of the two that cancels turns nothing. MuJoCo runs such a model anyway (its factorisation
clamps the pivots); here the importer offers the armature real joints have:
:func:`regularising_armature` finds the joints of M's near-null space at a configuration and the
smallest value of :data:`LADDER` that, added to those joints only, makes M regular (its smallest
eigenvalue at least :data:`REGULAR_RATIO` of its largest; the simulator's preflight calls M singular
below 1e-15). A scene that gives ``armature`` itself (0 for none) is not second-guessed.

Mimic joints: the dynamics is that of the independent joints, ``Gᵀ (M + diag(a)) G``
(:mod:`robodyn_ros.kernels.coupled`), so that is the matrix judged here.
"""
from __future__ import annotations

import numpy as np

from .model import PRISMATIC, REVOLUTE, SPHERICAL, Model, resolve_mimics

__all__ = ['LADDER', 'REGULAR_RATIO', 'mass_matrix', 'regularising_armature']

#: armature values tried, smallest first (kg·m² for a revolute or spherical joint, kg for a prismatic one)
LADDER = (1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1, 1.0)
#: smallest eigenvalue of a regular mass matrix relative to its largest (round-off in the accelerations
#: then stays below 1e-16 / 1e-9 = 1e-7 relative)
REGULAR_RATIO = 1e-9


def mass_matrix(model: Model, q) -> np.ndarray:
    """``M(q)`` (nv, nv) with the model's armature, by the compiled CRBA when the kernels are there (the
    only ones that compute spherical joints), else the numpy reference."""
    from . import kernels
    if kernels.AVAILABLE:
        return kernels.CompiledModel(model).crba(np.asarray(q, dtype=float))
    from . import dynamics
    return dynamics.crba(model, np.asarray(q, dtype=float))


def _coupling(model: Model) -> np.ndarray:
    """``G`` (nv, nv_r): ``v = G v_r`` with the mimic joints following their sources (identity without)."""
    mimics = resolve_mimics(model.specs)
    follow = {model.v_idx[model.joint_names.index(j)]: (model.v_idx[model.joint_names.index(src)], m)
              for j, (src, m, _) in mimics.items()}
    free = [k for k in range(model.nv) if k not in follow]
    G = np.zeros((model.nv, len(free)))
    col = {k: c for c, k in enumerate(free)}
    for k in free:
        G[k, col[k]] = 1.0
    for k, (src, m) in follow.items():
        G[k, col[src]] = m
    return G


def _regular(Mr) -> tuple:
    """``(regular?, eigenvalues, eigenvectors)`` of a (reduced) mass matrix."""
    if not np.all(np.isfinite(Mr)):
        return False, None, None
    w, V = np.linalg.eigh(0.5 * (Mr + Mr.T))
    return bool(w[0] >= REGULAR_RATIO * max(w[-1], 1e-300)), w, V


def regularising_armature(model: Model, q=None):
    """The smallest armature of :data:`LADDER` that makes ``M(q)`` regular, and the joints that need it.

    model: the tree (its own armature included); q: the configuration (default: the model's zero
    configuration). Returns None when M is regular already (or not finite: nothing to add), else
    ``(value, joints, (w_min, w_max))`` with joints the names of the joints given the value (those
    that move in M's near-null space, mimic joints through their sources) and the eigenvalue range
    of the matrix before; ``(None, joints, ...)`` when no value of the ladder is enough.
    """
    from . import kernels
    if model.has_spherical and not kernels.AVAILABLE:
        return None   # only the compiled kernels compute spherical joints; without them the backend refuses the model
    q = model.neutral() if q is None else np.asarray(q, dtype=float)
    M = mass_matrix(model, q)
    if M.size == 0:
        return None
    G = _coupling(model)
    ok, w, V = _regular(G.T @ M @ G)
    if ok or w is None:
        return None
    names = [model.joint_names[i] for i in range(model.nb) for _ in range(int(model.nv_j[i]))]
    takes = np.array([model.jtype[i] in (REVOLUTE, PRISMATIC, SPHERICAL) for i in range(model.nb)
                      for _ in range(int(model.nv_j[i]))], dtype=bool)
    mask = np.zeros(model.nv, dtype=bool)
    before = (float(w[0]), float(w[-1]))
    for _ in range(4):   # add the joints of each remaining near-null direction, then try the ladder
        null = w < REGULAR_RATIO * max(w[-1], 1e-300)
        for k in np.flatnonzero(null):
            x = np.abs(G @ V[:, k])
            mask |= (x >= 0.1 * x.max()) & takes
        for a in LADDER:
            ok, w, V = _regular(G.T @ (M + a * np.diag(mask.astype(float))) @ G)
            if ok:
                return a, sorted({names[k] for k in np.flatnonzero(mask)}, key=names.index), before
        if w is None:
            break
    return None, sorted({names[k] for k in np.flatnonzero(mask)}, key=names.index), before

