"""Outputs of many publication periods in one compiled call (the recorder's batches).

``joint_wrenches_many`` is :func:`robodyn_ros.kernels.core.joint_wrenches` (ABA, then the RNEA
wrenches at that acceleration) for K states at once: the same compiled function per state, so
the same numbers bit for bit (the recordings test compares them byte for byte), without K
Python calls.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from . import core


@njit(cache=True, nogil=True, error_model='numpy')
def _joint_wrenches_many(mi, mf, Q, V, TAU, fext, has_fext):
    # has_fext is an argument (a plain bool), not the constant False: numba then calls the
    # joint_wrenches it already compiled (and cached) for CompiledModel.joint_wrenches instead of
    # compiling the whole ABA/RNEA chain again for a literal flag (5 s on a cold cache)
    K = Q.shape[0]
    nb = mi.shape[0]
    out = np.empty((K, nb, 6))
    for k in range(K):
        _, f = core.joint_wrenches(mi, mf, Q[k], V[k], TAU[k], fext, has_fext)
        out[k] = f
    return out


def joint_wrenches_many(km, Q, V, TAU) -> np.ndarray:
    """``(K, nb, 6)``: the joint wrenches ``km.joint_wrenches(Q[k], V[k], TAU[k])[1]`` of K states.

    km: a :class:`robodyn_ros.kernels.CompiledModel`; Q, V, TAU: (K, nq), (K, nv), (K, nv).
    """
    return _joint_wrenches_many(km.mi, km.mf, np.ascontiguousarray(Q, dtype=np.float64),
                                np.ascontiguousarray(V, dtype=np.float64),
                                np.ascontiguousarray(TAU, dtype=np.float64), km._zf, False)


@njit(cache=True, nogil=True, error_model='numpy')
def tf_values_many(revolute, src, axis, p_tree, q_tree, R_tree, positions, out, first):
    """``/tf`` of K publications: ``out[k, first + j] = (x, y, z, qx, qy, qz, qw)`` of moving joint j
    at ``theta = positions[k, src[j]]``, by the float operations of ``TfTree.transforms`` in its
    order: a revolute joint ``q_tree ⊗ (a sin θ/2, cos θ/2)`` at ``p_tree``, a prismatic one
    ``p_tree + R_tree a d`` with ``q_tree`` (the recordings test compares the bytes with that path).
    """
    K = positions.shape[0]
    for k in range(K):
        for j in range(src.shape[0]):
            th = positions[k, src[j]]
            o = out[k, first + j]
            if revolute[j]:
                half = 0.5 * th
                s = math.sin(half)
                c = math.cos(half)
                bx, by, bz = axis[j, 0] * s, axis[j, 1] * s, axis[j, 2] * s
                qx, qy, qz, qw = q_tree[j, 0], q_tree[j, 1], q_tree[j, 2], q_tree[j, 3]
                o[0], o[1], o[2] = p_tree[j, 0], p_tree[j, 1], p_tree[j, 2]
                o[3] = qw * bx + c * qx + qy * bz - qz * by
                o[4] = qw * by + c * qy + qz * bx - qx * bz
                o[5] = qw * bz + c * qz + qx * by - qy * bx
                o[6] = qw * c - qx * bx - qy * by - qz * bz
            else:
                dx, dy, dz = axis[j, 0] * th, axis[j, 1] * th, axis[j, 2] * th
                for r in range(3):
                    o[r] = p_tree[j, r] + R_tree[j, r, 0] * dx + R_tree[j, r, 1] * dy + R_tree[j, r, 2] * dz
                for r in range(4):
                    o[3 + r] = q_tree[j, r]
