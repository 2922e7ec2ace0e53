"""The command profiles of :mod:`robodyn_ros.profiles`: :func:`command_eval`, their one
implementation, evaluates a profile from its program ``(kind code, P, times, values, BT, Bq)``.
A profile's Python form ``f(t, y)`` calls it, and the arm's many-period loop
(:func:`robodyn_ros.kernels.arm.run_arm_periods`) runs it inside its compiled loop. Compiled by
numba; without numba the same source runs as plain Python (:mod:`.jit`).
"""
from __future__ import annotations

import math

from .jit import njit
from .tree import _JIT

#: command profile kind codes (profiles.py ``COMMAND_PROFILES`` -> ``f.program``)
CMD_NONE, CMD_ZERO, CMD_CONSTANT, CMD_PIECEWISE, CMD_SINE, CMD_GRAVITY_SINE, CMD_PD_HOLD = -1, 0, 1, 2, 3, 4, 5


@njit(**_JIT)
def command_eval(kind, P, times, values, BT, Bq, q, v, g, t, u):
    """u (n,) = a scene's command profile at time t (s) and state (q (nq,), v (nv,)):

    - ``CMD_ZERO``: 0; ``CMD_CONSTANT``: ``P[0]``;
    - ``CMD_PIECEWISE``: ``values[j]`` with ``j = searchsorted(times, t, 'right') - 1`` (0 before
      ``times[0]``);
    - ``CMD_SINE`` (P rows offset, A, ω, φ): ``offset + A sin(ω t + φ)``;
    - ``CMD_GRAVITY_SINE`` (P rows A, ω, φ, K, center): ``Bᵀ g + K (center − B_q q) + A sin(ω t + φ)``
      with g (nv,) the gravity torques ``RNEA(q, 0, 0)`` the caller computed (the system's own
      RNEA; :func:`robodyn_ros.kernels.tree.rnea_into` on the merged tree in the arm's loop).
    - ``CMD_PD_HOLD`` (P rows posture q*, K_p, K_d, gravity flag): ``K_p (q* − B_q q) − K_d Bᵀ v``, plus
      ``Bᵀ g`` when the flag (any entry of its row) is nonzero (g as for ``CMD_GRAVITY_SINE``).

    ``Bᵀ g``, ``Bᵀ v`` and ``B_q q`` are sums from +0.0 in index order; over the 0/1 selection
    matrices of the bundled scenes every summation order gives the same bits. q, v and g are read
    by ``CMD_GRAVITY_SINE`` and ``CMD_PD_HOLD`` only.
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
    elif kind == CMD_PD_HOLD:
        nv = v.shape[0]
        nq = q.shape[0]
        for i in range(n):
            bq = 0.0
            for j in range(nq):
                bq += Bq[i, j] * q[j]
            bv = 0.0
            for j in range(nv):
                bv += BT[i, j] * v[j]
            ui = P[1, i] * (P[0, i] - bq) - P[2, i] * bv
            if P[3, 0] != 0.0:
                gi = 0.0
                for j in range(g.shape[0]):
                    gi += BT[i, j] * g[j]
                ui += gi
            u[i] = ui
    else:
        nv = g.shape[0]
        nq = q.shape[0]
        for i in range(n):
            gi = 0.0
            for j in range(nv):
                gi += BT[i, j] * g[j]
            bq = 0.0
            for j in range(nq):
                bq += Bq[i, j] * q[j]
            u[i] = (gi + P[3, i] * (P[4, i] - bq)) + P[0, i] * math.sin(P[1, i] * t + P[2, i])
