"""The arm's compiled loops (:mod:`robodyn_ros.systems.arm`): its right-hand side with the work
quadrature (:func:`arm_rhs`), the fused fixed-step integration of one publication period
(:func:`integrate_arm`) and many periods in one call with the scripted commands and the outputs
(:func:`run_arm_periods`), on the tree algorithms of :mod:`robodyn_ros.kernels.tree`.

:mod:`robodyn_ros.kernels.codegen` compiles the source of the last two again against a scene's
generated ABA (the 'generated' backend).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .fixed_step import M_RK4, M_SEMI_IMPLICIT_EULER
from .profiles import CMD_GRAVITY_SINE, CMD_NONE, command_eval
from .coupled import couple_into, coupled_fd_ws
from .tree import (_JIT, aba_ws, joint_wrenches, limit_forces_add, normalize_into, qdot_into, rnea_into, transforms,
                   workspace)


# ----------------------------------------------------------------------------------------------
# fused fixed-step integration of an arm with its work quadrature
# ----------------------------------------------------------------------------------------------
@njit(**_JIT)
def arm_forces(damping, lim, tau_app, nq, nv, z, dz, tauv):
    """``tauv = B u − D v + τ_lim`` at ``z = [q, v, W(, W_lim)]``; returns the power ``vᵀ tauv``.
    With W_lim in z, ``dz[nq + nv + 1] = vᵀ τ_lim`` (the limit forces are formed alone in
    ``dz[nq:nq + nv]``, which the caller's ABA overwrites; one row per joint, so tauv gets the
    same sums as :func:`limit_forces_add` on it). Shared by :func:`arm_rhs` and the generated one."""
    q = z[:nq]
    v = z[nq:nq + nv]
    for k in range(nv):
        tauv[k] = tau_app[k] - damping[k] * v[k]
    if z.shape[0] > nq + nv + 1:
        tl = dz[nq:nq + nv]
        for k in range(nv):
            tl[k] = 0.0
        if lim.shape[0]:
            limit_forces_add(lim, q, v, tl)
        P = 0.0
        for k in range(nv):
            P += v[k] * tl[k]
            tauv[k] += tl[k]
        dz[nq + nv + 1] = P
    elif lim.shape[0]:
        limit_forces_add(lim, q, v, tauv)
    P = 0.0
    for k in range(nv):
        P += v[k] * tauv[k]
    return P


@njit(**_JIT)
def arm_rhs(mi, mf, damping, lim, tau_app, nq, nv, z, dz, tauv, W, cpl, cs):
    """``dz/dt`` for ``z = [q, v, W]``: ``[q̇; ABA(q, v, τ); vᵀ τ]`` with ``τ = B u − D v + τ_lim``;
    for ``z = [q, v, W, W_lim]`` also ``vᵀ τ_lim`` (the joint-limit work on its own).

    tau_app (nv,) = B u held over the call; damping (nv,) = D; lim: the joint-limit table
    (:func:`limit_forces_add`, 0 rows = none); tauv (nv,) scratch; cpl: None, or ``(mimic table,
    col, mul)`` of a tree with mimic joints (:mod:`.coupled`), whose v̇ is then the coupled
    dynamics (:func:`.coupled.coupled_fd_ws`, scratch cs) instead of ABA.
    (ArmSystem.rhs, .input_power and .limit_power of the reference path.)
    """
    q = z[:nq]
    v = z[nq:nq + nv]
    qdot_into(mi, q, v, dz[:nq])
    P = arm_forces(damping, lim, tau_app, nq, nv, z, dz, tauv)
    transforms(mi, mf, q, W)
    if cpl is not None:   # a None argument prunes this branch at compile time: no coupled code for other trees
        coupled_fd_ws(mi, mf, cpl[1], cpl[2], q, v, tauv, dz[nq:nq + nv], W, cs[0], cs[1], cs[2], cs[3], cs[4], cs[5])
    else:
        aba_ws(mi, mf, q, v, tauv, W, False, dz[nq:nq + nv], W)
    dz[nq + nv] = P


@njit(**_JIT)
def integrate_arm(mi, mf, damping, lim, tau_app, nq, method, z, dt, n_full, h_last, cpl):
    """Integrate ``z = [q, v, W]`` (or ``[q, v, W, W_lim]``, see :func:`arm_rhs`) in place over
    ``n_full`` steps of dt and one of h_last (if > 0).

    method: ``M_EULER``, ``M_SEMI_IMPLICIT_EULER`` or ``M_RK4``, with the arithmetic of
    :mod:`robodyn_ros.integrators` (RK4: ``acc = k1 + 2 k2 + 2 k3 + k4`` folded stage by
    stage, ``y += h/6 acc``; symplectic Euler: ``[v, W] += h f[nq:]``, then ``q += h q̇(q,
    v_new)``); free-joint quaternions are renormalised and mimic joints set from their sources
    (cpl: None, or see :func:`arm_rhs`) after every step, as the Simulator's projection does.
    Returns the index of the first step whose result is non-finite (z then holds that result), or -1.
    """
    if cpl is None:
        return arm_steps(mi, mf, damping, lim, tau_app, nq, method, z, dt, n_full, h_last, None, None)
    nv = damping.shape[0]
    nr = nv - cpl[0].shape[0]
    cs = (np.zeros((nv, nv)), np.zeros(nv), np.zeros((nr, nr)), np.zeros((nr, nr)), np.zeros(nr), np.zeros(nr))
    return arm_steps(mi, mf, damping, lim, tau_app, nq, method, z, dt, n_full, h_last, cpl, cs)


@njit(**_JIT)
def arm_steps(mi, mf, damping, lim, tau_app, nq, method, z, dt, n_full, h_last, cpl, cs):
    """The steps of :func:`integrate_arm` (cs: the coupled dynamics' scratch, None with cpl)."""
    nb = mi.shape[0]
    n = z.shape[0]
    nv = damping.shape[0]
    W = workspace(nb)
    buf = np.empty(3 * n + nv + nq)
    K = buf[:n]
    Y = buf[n:2 * n]
    acc = buf[2 * n:3 * n]
    tauv = buf[3 * n:3 * n + nv]
    qd = buf[3 * n + nv:]
    n_steps = n_full + (1 if h_last > 0.0 else 0)
    for k in range(n_steps):
        h = dt if k < n_full else h_last
        if method == M_RK4:
            half = 0.5 * h
            arm_rhs(mi, mf, damping, lim, tau_app, nq, nv, z, K, tauv, W, cpl, cs)
            for a in range(n):
                acc[a] = K[a]
                Y[a] = K[a] * half + z[a]
            arm_rhs(mi, mf, damping, lim, tau_app, nq, nv, Y, K, tauv, W, cpl, cs)
            for a in range(n):
                acc[a] = (acc[a] + K[a]) + K[a]
                Y[a] = K[a] * half + z[a]
            arm_rhs(mi, mf, damping, lim, tau_app, nq, nv, Y, K, tauv, W, cpl, cs)
            for a in range(n):
                acc[a] = (acc[a] + K[a]) + K[a]
                Y[a] = K[a] * h + z[a]
            arm_rhs(mi, mf, damping, lim, tau_app, nq, nv, Y, K, tauv, W, cpl, cs)
            h6 = h / 6.0
            for a in range(n):
                z[a] += (acc[a] + K[a]) * h6
        elif method == M_SEMI_IMPLICIT_EULER:
            arm_rhs(mi, mf, damping, lim, tau_app, nq, nv, z, K, tauv, W, cpl, cs)
            for a in range(nq, n):
                z[a] += K[a] * h
            qdot_into(mi, z[:nq], z[nq:nq + nv], qd)
            for a in range(nq):
                z[a] += qd[a] * h
        else:
            arm_rhs(mi, mf, damping, lim, tau_app, nq, nv, z, K, tauv, W, cpl, cs)
            for a in range(n):
                z[a] += K[a] * h
        normalize_into(mi, z[:nq])
        if cpl is not None:
            couple_into(cpl[0], z[:nq], z[nq:nq + nv])
        for a in range(n):
            if not math.isfinite(z[a]):
                return k
    return -1


@njit(**_JIT)
def run_arm_periods(mi, mf, mi_r, mf_r, damping, lim, B, nq, method, z, dt, t_start, n_full, h_last,
                    kind, P, times, values, BT, Bq, u, Zs, Us, TAUs, Fs, want_f):
    """K publication periods of an arm in one call: per period k the scripted command at its
    start ``t_start[k]`` (:func:`command_eval`, kind ``CMD_NONE``: u held as given), ``τ_app = B u``,
    :func:`integrate_arm` over its step grid ``(n_full[k], h_last[k])``, then the outputs at its end:
    ``Zs[k] = z``, ``Us[k] = u``, ``TAUs[k] = τ_app`` and, with want_f, the joint wrenches
    ``Fs[k]`` (:func:`joint_wrenches` under ``τ = B u − D v + τ_lim``, :func:`arm_forces`) -- the
    numbers the Simulator's per-period path computes with the same functions.

    z: ``[q, v, W(, W_lim)]`` in place; u (n,) the command held before period 0. Returns
    ``(k, code)``: code 0 after all K periods; 1: the command of period k is non-finite (not
    applied: u and z are those of the end of period k − 1); 2: the state became non-finite in
    period k (z as the failed integration left it; ``Zs[k − 1]`` is the end of period k − 1).
    The caller redoes period k on the per-period path, which raises with the diagnosis.
    """
    K = t_start.shape[0]
    nv = damping.shape[0]
    n = z.shape[0]
    nu = u.shape[0]
    g = np.zeros(nv)
    zeros = np.zeros(nv)
    un = np.empty(nu)
    tau_app = np.empty(nv)
    dz = np.empty(n)
    tauv = np.empty(nv)
    zf = np.zeros((mi.shape[0], 6))
    for k in range(K):
        if kind != CMD_NONE:
            if kind == CMD_GRAVITY_SINE:   # the gravity torques RNEA(q, 0, 0), as CompiledModel.rnea
                rnea_into(mi_r, mf_r, z[:nq], zeros, zeros, g)
            command_eval(kind, P, times, values, BT, Bq, z[:nq], g, t_start[k], un)
            for i in range(nu):
                if not math.isfinite(un[i]):
                    return k, 1
            for i in range(nu):
                u[i] = un[i]
        for r in range(nv):
            acc = 0.0
            for i in range(nu):
                acc += B[r, i] * u[i]
            tau_app[r] = acc
        # (the block path declines trees with mimic joints: ArmSystem.fused_periods)
        if integrate_arm(mi_r, mf_r, damping, lim, tau_app, nq, method, z, dt, n_full[k], h_last[k], None) >= 0:
            return k, 2
        for a in range(n):
            Zs[k, a] = z[a]
        for i in range(nu):
            Us[k, i] = u[i]
        for r in range(nv):
            TAUs[k, r] = tau_app[r]
        if want_f:
            arm_forces(damping, lim, tau_app, nq, nv, z, dz, tauv)
            _, f = joint_wrenches(mi, mf, z[:nq], z[nq:nq + nv], tauv, zf, False)
            for b in range(f.shape[0]):
                for c in range(6):
                    Fs[k, b, c] = f[b, c]
    return K, 0
