"""Outputs of many publication periods in one compiled call (the recorder's batches).

``joint_wrenches_many`` is :func:`robodyn_ros.kernels.tree.joint_wrenches` (ABA, then the RNEA
wrenches at that acceleration) for K states at once: the same compiled function per state, so
the same numbers bit for bit (the recordings test compares them byte for byte), without K
Python calls.
"""
from __future__ import annotations

import numpy as np
from .jit import njit

from . import tree


@njit(cache=True, nogil=True, error_model='numpy', _nrt=True)
def _joint_wrenches_many(mi, mf, Q, V, TAU, fext, has_fext):
    # has_fext is an argument (a plain bool), not the constant False: numba then calls the
    # joint_wrenches it already compiled (and cached) for CompiledModel.joint_wrenches instead of
    # compiling the whole ABA/RNEA chain again for a literal flag (5 s on a cold cache)
    K = Q.shape[0]
    nb = mi.shape[0]
    out = np.empty((K, nb, 6))
    for k in range(K):
        _, f = tree.joint_wrenches(mi, mf, Q[k], V[k], TAU[k], fext, has_fext)
        out[k] = f
    return out


def joint_wrenches_many(km, Q, V, TAU) -> np.ndarray:
    """``(K, nb, 6)``: the joint wrenches ``km.joint_wrenches(Q[k], V[k], TAU[k])[1]`` of K states.

    km: a :class:`robodyn_ros.kernels.CompiledModel`; Q, V, TAU: (K, nq), (K, nv), (K, nv).
    """
    return _joint_wrenches_many(km.mi, km.mf, np.ascontiguousarray(Q, dtype=np.float64),
                                np.ascontiguousarray(V, dtype=np.float64),
                                np.ascontiguousarray(TAU, dtype=np.float64), km._zf, False)

