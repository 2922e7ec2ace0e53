"""Trees with linearly coupled joints (URDF ``<mimic>``): forward dynamics in the independent joints.

Coupling. A following joint j moves with an independent joint i: ``q_j = m q_i + o`` (chains of
mimics resolved, :func:`robodyn_ros.model.resolve_mimics`; table rows ``[q_j, v_j, q_i, v_i, m,
o]`` from :func:`robodyn_ros.model.mimic_table`). The velocities are ``v = G v_r`` with ``G``
(nv, nr): ``G[k, col[k]] = mul[k]`` — an independent DOF k has its own column and ``mul = 1``, a
follower its source's column and its multiplier (:func:`coupling`). The state keeps every joint
(joint_states, TF and recordings see each one); :func:`couple_into` sets the followers from
their sources after every step, so the coupling holds to the last bit.

Dynamics. The coupling's generalised force ``λ`` does no work on coupled motion (``Gᵀ λ = 0``),
so with ``M v̇ + h = τ + λ`` and ``v̇ = G v̇_r`` (Lagrange's equations in the independent
coordinates)::

    M_r v̇_r = Gᵀ (τ − h),   M_r = Gᵀ M G  (nr, nr),   v̇ = G v̇_r,

with ``M`` from CRBA (:func:`robodyn_ros.kernels.tree.crba_ws`), ``h = C v + g`` from RNEA at zero
acceleration (:func:`robodyn_ros.kernels.tree.rnea_ws`) and a Cholesky solve (``M_r`` is positive
definite when ``M`` is: G has full column rank). ``λ = M v̇ + h − τ`` is what the coupling (a
linkage, gear train or tendon) applies to each joint: at a following joint, the effort it
transmits (:func:`coupled_wrenches`). Cost per call: one CRBA, one RNEA, ``O(nv²)`` for the
reduction and ``O(nr³)`` for the factorisation, against ABA's ``O(nb)``: mimic robots pay for
their coupling, robots without one never enter this module.
"""
from __future__ import annotations

import numpy as np
from .jit import njit

from .linalg import chol_solve, cholesky
from .tree import _JIT, P_, crba_ws, rnea_ws, transforms, workspace


def coupling(table: np.ndarray, nv: int):
    """``(col (nv,) int64, mul (nv,) float64, nr)``: the velocity map ``v = G v_r`` of a mimic table
    (rows ``[q_j, v_j, q_i, v_i, m, o]``); independent DOFs numbered in v order."""
    follows = {int(r[1]): (int(r[3]), float(r[4])) for r in table}
    col = np.full(nv, -1, dtype=np.int64)
    mul = np.ones(nv)
    nr = 0
    for k in range(nv):
        if k not in follows:
            col[k] = nr
            nr += 1
    for k, (i, m) in follows.items():
        col[k], mul[k] = col[i], m
    return col, mul, nr


@njit(**_JIT)
def couple_into(table, q, v):
    """Set every following joint from its source: ``q_j = m q_i + o``, ``v_j = m v_i``."""
    for r in range(table.shape[0]):
        qj, vj, qi, vi = int(table[r, 0]), int(table[r, 1]), int(table[r, 2]), int(table[r, 3])
        m = table[r, 4]
        q[qj] = m * q[qi] + table[r, 5]
        v[vj] = m * v[vi]


@njit(**_JIT)
def reduce_into(A, f, col, mul, Ar, fr):
    """``Ar = Gᵀ A G`` (nr, nr) and ``fr = Gᵀ f`` (nr,) for a joint-space matrix A (nv, nv) and
    vector f (nv,) (G from :func:`coupling`): what any solve in the joint space of a coupled tree
    takes (the mass matrix here; ``M + γ h D + γ² h² K`` of an implicit step alike)."""
    nv = f.shape[0]
    nr = fr.shape[0]
    for a in range(nr):
        fr[a] = 0.0
        for c in range(nr):
            Ar[a, c] = 0.0
    for k in range(nv):
        ck = mul[k]
        if ck == 0.0:
            continue
        a = col[k]
        fr[a] += ck * f[k]
        for m in range(nv):
            if mul[m] != 0.0:
                Ar[a, col[m]] += ck * mul[m] * A[k, m]


@njit(**_JIT)
def coupled_fd_ws(mi, mf, col, mul, q, v, tau, qdd, W, H, h, Mr, L, b, x):
    """Coupled forward dynamics into qdd (nv,) (module docstring); ``transforms`` done by the caller.

    tau (nv,): every applied and passive generalised force; W: the tree work array; scratch H
    (nv, nv), h (nv,), Mr and L (nr, nr), b and x (nr,). A non-positive-definite ``M_r`` gives NaN
    accelerations (the caller's finiteness checks stop the run).
    """
    nv = qdd.shape[0]
    nr = Mr.shape[0]
    for k in range(nv):
        qdd[k] = 0.0
    rnea_ws(mi, mf, q, v, qdd, W, False, h, W)        # h = C v + g (zero acceleration)
    for k in range(nv):
        for m in range(nv):
            H[k, m] = 0.0
    crba_ws(mi, mf, H, W)
    for k in range(nv):
        h[k] = tau[k] - h[k]
    reduce_into(H, h, col, mul, Mr, b)                # M_r = Gᵀ M G, b = Gᵀ (τ − h)
    if cholesky(Mr, nr, L):
        chol_solve(L, nr, b, x)
    else:
        for a in range(nr):
            x[a] = np.nan
    for k in range(nv):                               # v̇ = G v̇_r
        qdd[k] = mul[k] * x[col[k]]


@njit(**_JIT)
def coupled_scratch(nb, nv, nr):
    """``(W, H, h, Mr, L, b, x)``: the work arrays of :func:`coupled_fd_ws`."""
    return (workspace(nb), np.zeros((nv, nv)), np.zeros(nv), np.zeros((nr, nr)), np.zeros((nr, nr)), np.zeros(nr),
            np.zeros(nr))


@njit(**_JIT)
def coupled_fd_into(mi, mf, col, mul, nr, q, v, tau, qdd):
    """Coupled forward dynamics into qdd (nv,) (one call from Python)."""
    W, H, h, Mr, L, b, x = coupled_scratch(mi.shape[0], qdd.shape[0], nr)
    transforms(mi, mf, q, W)
    coupled_fd_ws(mi, mf, col, mul, q, v, tau, qdd, W, H, h, Mr, L, b, x)


@njit(**_JIT)
def coupled_wrenches(mi, mf, col, mul, nr, q, v, tau):
    """``(qdd (nv,), f (nb, 6), λ (nv,))``: the coupled accelerations, the joint wrenches of RNEA at
    them (as :func:`robodyn_ros.kernels.tree.joint_wrenches`) and the coupling's generalised force
    ``λ = M v̇ + h − τ`` (``Gᵀ λ = 0``; at a following joint, the effort the coupling transmits)."""
    nv = tau.shape[0]
    W, H, h, Mr, L, b, x = coupled_scratch(mi.shape[0], nv, nr)
    transforms(mi, mf, q, W)
    qdd = np.empty(nv)
    coupled_fd_ws(mi, mf, col, mul, q, v, tau, qdd, W, H, h, Mr, L, b, x)
    lam = np.empty(nv)
    rnea_ws(mi, mf, q, v, qdd, W, False, lam, W)
    for k in range(nv):
        lam[k] -= tau[k]
    return qdd, W[:mi.shape[0], P_:P_ + 6].copy(), lam
