"""The command profiles of :mod:`robodyn_ros.profiles`, compiled: :func:`command_eval` evaluates a
profile from its program ``(kind code, P, times, values, BT, Bq)`` (``f.program`` of a profile),
inside the arm's many-period loop (:func:`robodyn_ros.kernels.arm.run_arm_periods`).
"""
from __future__ import annotations

import math

from .jit import njit
from .tree import _JIT, rnea_into


# ----------------------------------------------------------------------------------------------
# many publication periods in one call: scripted commands, integration, outputs (issue 15)
# ----------------------------------------------------------------------------------------------
#: compiled command profiles (profiles.py ``COMMAND_PROFILES`` -> ``f.program``): kind codes
CMD_NONE, CMD_ZERO, CMD_CONSTANT, CMD_PIECEWISE, CMD_SINE, CMD_GRAVITY_SINE = -1, 0, 1, 2, 3, 4


@njit(**_JIT)
def command_eval(kind, P, times, values, BT, Bq, mi_r, mf_r, nq, t, z, g, zeros, u):
    """u (n,) = a scene's command profile at time t and state z (``[q, v, ...]``), with the
    arithmetic of its Python form in :mod:`robodyn_ros.profiles`, operation by operation:

    - ``CMD_ZERO``: 0; ``CMD_CONSTANT``: ``P[0]``;
    - ``CMD_PIECEWISE``: ``values[j]`` with ``j = searchsorted(times, t, 'right') - 1`` (0 before
      ``times[0]``);
    - ``CMD_SINE`` (P rows offset, A, ω, φ): ``offset + A sin(ω t + φ)``;
    - ``CMD_GRAVITY_SINE`` (P rows A, ω, φ, K, center): ``Bᵀ g(q) + K (center − B_q q) + A sin(ω t + φ)``
      with ``g = RNEA(q, 0, 0)`` (:func:`rnea_into` on the merged tree, as ``CompiledModel.rnea``).

    The products ``Bᵀ g`` and ``B_q q`` are sums from +0.0 (numpy's matmul) over 0/1 selection
    matrices, whose every summation order gives the same bits; the caller only compiles
    profiles whose matrices are such selections. g (nv,) and zeros (nv,) are scratch.
    """
    n = u.shape[0]
    if kind == CMD_ZERO:
        for i in range(n):
            u[i] = 0.0
    elif kind == CMD_CONSTANT:
        for i in range(n):
            u[i] = P[0, i]
    elif kind == CMD_PIECEWISE:
        j = -1
        for m in range(times.shape[0]):
            if times[m] <= t:
                j = m
            else:
                break
        for i in range(n):
            u[i] = 0.0 if j < 0 else values[j, i]
    elif kind == CMD_SINE:
        for i in range(n):
            u[i] = P[0, i] + P[1, i] * math.sin(P[2, i] * t + P[3, i])
    else:
        q = z[:nq]
        rnea_into(mi_r, mf_r, q, zeros, zeros, g)
        nv = g.shape[0]
        for i in range(n):
            gi = 0.0
            for j in range(nv):
                gi += BT[i, j] * g[j]
            bq = 0.0
            for j in range(nq):
                bq += Bq[i, j] * q[j]
            u[i] = (gi + P[3, i] * (P[4, i] - bq)) + P[0, i] * math.sin(P[1, i] * t + P[2, i])
