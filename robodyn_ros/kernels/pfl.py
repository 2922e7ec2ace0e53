"""The partial feedback linearisation law of :mod:`robodyn_ros.pfl`: its one implementation.

One call per controller update (:func:`torques_into`): the joint-space inertia and bias of the
tree (:func:`robodyn_ros.kernels.tree.crba_ws`, :func:`~robodyn_ros.kernels.tree.rnea_ws` on one
workspace), the desired inner accelerations and the torques, with no array built in Python.
Compiled by numba; without numba the same source runs as plain Python (:mod:`.jit`).
``M_ba α``, ``M_ab q̈_b`` and ``M_aa α`` are BLAS matrix–vector products (``np.dot``) and
``M_bb⁻¹`` is LAPACK ``gesv`` (``np.linalg.solve``): numba's call scipy's OpenBLAS (0.3.30 with
scipy 1.17.1), plain Python numpy's (0.3.31 with numpy 2.4.6; both pinned in constraints.txt), so
the torques' last bits follow the BLAS kernels the machine's OpenBLAS picks.
"""
from __future__ import annotations

import numpy as np

from . import tree
from .jit import njit
from .tree import _JIT


@njit(**_JIT)
def mass_and_bias_into(mi, mf, damping, q, v, M, h):
    """``M (nv, nv)`` (zeroed by the caller) and ``h = C v + g + D v`` (nv,) at (q, v);
    mi, mf: the tree packed with fixed bodies welded (``CompiledModel.mi_r, mf_r``)."""
    W = tree.workspace(mi.shape[0])    # the joint transforms once, for both (crba_into, rnea_into)
    tree.transforms(mi, mf, q, W)
    tree.crba_ws(mi, mf, M, W)
    tree.rnea_ws(mi, mf, q, v, np.zeros(v.shape[0]), W, False, h, W)
    for k in range(h.shape[0]):
        h[k] = h[k] + damping[k] * v[k]


@njit(**_JIT)
def path_into(start, delta, s, d, a, qd, vd, ad):
    """Desired inner angles, rates, accelerations (m,) of a posture path at time scalars
    ``(s, ṡ, s̈)`` (``PosturePath.coefficients``): ``start + s δ``, ``ṡ δ``, ``s̈ δ``."""
    for k in range(start.shape[0]):
        qd[k] = start[k] + s * delta[k]
        vd[k] = d * delta[k]
        ad[k] = a * delta[k]


@njit(**_JIT)
def accelerations_into(start, delta, s, d, a, kp, kd, q, v, alpha):
    """``α = q̈_d + K_d (q̇_d − q̇_a) + K_p (q_d − q_a)`` (m,) of the inner joints (q, v: (n,))."""
    m = start.shape[0]
    qd, vd, ad = np.empty(m), np.empty(m), np.empty(m)
    path_into(start, delta, s, d, a, qd, vd, ad)
    for k in range(m):
        alpha[k] = ad[k] + kd[k] * (vd[k] - v[3 + k]) + kp[k] * (qd[k] - q[3 + k])


@njit(**_JIT)
def torques_into(mi, mf, damping, start, delta, s, d, a, kp, kd, q, v, tau):
    """Inner joint torques ``τ = M_ab q̈_b + M_aa α + h_a`` (m,) with
    ``q̈_b = −M_bb⁻¹ (M_ba α + h_b)``, at (q, v) (n,) and path time scalars (s, ṡ, s̈)."""
    n = v.shape[0]
    m = n - 3
    M = np.zeros((n, n))
    h = np.empty(n)
    mass_and_bias_into(mi, mf, damping, q, v, M, h)
    alpha = np.empty(m)
    accelerations_into(start, delta, s, d, a, kp, kd, q, v, alpha)
    rhs = np.dot(np.ascontiguousarray(M[:3, 3:]), alpha)
    for i in range(3):
        rhs[i] = rhs[i] + h[i]
    M_bb = np.ascontiguousarray(M[:3, :3])
    if not (np.isfinite(M_bb).all() and np.isfinite(rhs).all()):
        tau[:] = np.nan   # a non-finite state: NaN torques (as numpy's solve gives; numba's raises), refused as a command
        return
    qdd_b = -np.linalg.solve(M_bb, rhs)
    t_b = np.dot(np.ascontiguousarray(M[3:, :3]), qdd_b)
    t_a = np.dot(np.ascontiguousarray(M[3:, 3:]), alpha)
    for k in range(m):
        tau[k] = t_b[k] + t_a[k] + h[3 + k]
