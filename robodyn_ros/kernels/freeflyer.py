"""The free-flying base in minimal coordinates, compiled (:mod:`robodyn_ros.systems.freeflyer`):
its table constraint, solve, forces and projection. Entry points in :mod:`robodyn_ros.kernels.fixed_step`.
"""
from __future__ import annotations

import math

import numpy as np
from .jit import njit

from .linalg import NINFO, OK, cross, flag, kkt_solve, project_velocities, quat_to_R
from .tree import _JIT, aba_fext_into, crba_into, crba_ws, normalize_into, qdot_into, rnea_ws, transforms, workspace


# ----------------------------------------------------------------------------------------------
# free-flying base, minimal coordinates (systems/freeflyer.py)
#   ip: [table, stabilisation (0 baumgarte, 1 projection, 2 none)]
#   fp: [alpha, beta, table height, rcond, damping (nv)]
#   u:  [B u_effort (nv), base wrench (6) = fx fy fz tx ty tz in base_link]
# ----------------------------------------------------------------------------------------------
FF_TABLE, FF_STAB = 0, 1
FF_ALPHA, FF_BETA, FF_HEIGHT, FF_RCOND, FF_DAMPING = 0, 1, 2, 3, 4
STAB_BAUMGARTE, STAB_PROJECTION, STAB_NONE = 0, 1, 2


@njit(**_JIT)
def ff_table(fp, nv, q, v, phi, K, k):
    """Table constraints in minimal coordinates: φ (3,), K (3, nv), k (3,) (``FreeFlyerSystem._table``
    with :func:`robodyn_ros.systems.freeflyer.table_rows` for s = 0)."""
    R = np.empty((3, 3))
    quat_to_R(q[3], q[4], q[5], q[6], R)
    n0, n1, n2 = R[0, 2], R[1, 2], R[2, 2]
    phi[0] = q[2] - fp[FF_HEIGHT]
    phi[1] = -n1
    phi[2] = n0
    for i in range(3):
        for j in range(nv):
            K[i, j] = 0.0
    for j in range(3):
        K[1, j] = n2 * R[0, j] - n0 * R[2, j]
        K[2, j] = n2 * R[1, j] - n1 * R[2, j]
        K[0, 3 + j] = R[2, j]
    w = v[0:3]
    wv = np.empty(3)
    cross(w, v[3:6], wv)
    k[0] = -(R[2, 0] * wv[0] + R[2, 1] * wv[1] + R[2, 2] * wv[2])
    ww = np.empty(3)
    for a in range(3):
        ww[a] = R[a, 0] * w[0] + R[a, 1] * w[1] + R[a, 2] * w[2]
    nn = np.empty(3)
    nn[0], nn[1], nn[2] = n0, n1, n2
    t1 = np.empty(3)
    t2 = np.empty(3)
    cross(ww, nn, t1)
    cross(ww, t1, t2)
    k[1] = t2[1]
    k[2] = -t2[0]


@njit(**_JIT)
def ff_solve(ip, fp, mi, mf, mi_r, mf_r, q, v, tau, fext, exact_info, a, lam, info):
    """Accelerations and table multipliers (``FreeFlyerSystem.solve``); lam has 3 or 0 entries."""
    nv = v.shape[0]
    if ip[FF_TABLE] == 0:
        aba_fext_into(mi, mf, q, v, tau, fext, a)
        info[0] = 0.0
        info[1] = np.inf
        info[2] = np.inf
        info[3] = 0.0
        return OK
    M = np.zeros((nv, nv))
    h = np.empty(nv)
    W = workspace(mi.shape[0])
    transforms(mi, mf, q, W)
    rnea_ws(mi, mf, q, v, np.zeros(nv), fext, flag(1), h, W)
    crba_ws(mi, mf, M, W)  # the transforms are still in W
    phi = np.empty(3)
    K = np.empty((3, nv))
    k = np.empty(3)
    ff_table(fp, nv, q, v, phi, K, k)
    two_alpha = 2.0 * fp[FF_ALPHA]
    b2 = fp[FF_BETA] * fp[FF_BETA]
    for i in range(3):
        s = 0.0
        for j in range(nv):
            s += K[i, j] * v[j]
        k[i] = k[i] - two_alpha * s - b2 * phi[i]
    rhs = np.empty(nv)
    for j in range(nv):
        rhs[j] = tau[j] - h[j]
    return kkt_solve(M, nv, rhs, K, k, fp[FF_RCOND], 0.0, exact_info, a, lam, info)


@njit(**_JIT)
def ff_forces(fp, u, v, tau, fext):
    """Joint-space forces ``B u − D v`` into tau and the base wrench as f_ext on body 0."""
    nv = v.shape[0]
    for j in range(nv):
        tau[j] = u[j] + (-fp[FF_DAMPING + j] * v[j])
    for i in range(fext.shape[0]):
        for a in range(6):
            fext[i, a] = 0.0
    for a in range(3):
        fext[0, a] = u[nv + 3 + a]
        fext[0, 3 + a] = u[nv + a]


@njit(**_JIT)
def ff_evaluate(ip, fp, mi, mf, mi_r, mf_r, u, nq, z, dz):
    """``dz = [q̇; v̇; power]`` (``FreeFlyerSystem.rhs`` and ``.input_power``)."""
    nv = z.shape[0] - 1 - nq
    q = z[:nq]
    v = z[nq:nq + nv]
    qdot_into(mi, q, v, dz[:nq])
    tau = np.empty(nv)
    fext = np.empty((mi.shape[0], 6))
    ff_forces(fp, u, v, tau, fext)
    lam = np.empty(3)
    info = np.empty(NINFO)
    st = ff_solve(ip, fp, mi, mf, mi_r, mf_r, q, v, tau, fext, flag(0), dz[nq:nq + nv], lam, info)
    P = 0.0
    for j in range(nv):
        P += v[j] * tau[j]
    P += v[0] * u[nv + 3] + v[1] * u[nv + 4] + v[2] * u[nv + 5]
    P += v[3] * u[nv] + v[4] * u[nv + 1] + v[5] * u[nv + 2]
    dz[nq + nv] = P
    return st


@njit(**_JIT)
def ff_project(ip, fp, mi, mf, mi_r, mf_r, nq, y):
    """Renormalise the quaternion; with projection on the table also q, v (``FreeFlyerSystem.project``)."""
    q = y[:nq]
    normalize_into(mi, q)
    if ip[FF_TABLE] == 0 or ip[FF_STAB] != STAB_PROJECTION:
        return OK
    nv = y.shape[0] - nq
    v = y[nq:]
    z, w = q[5], q[6]
    n = math.hypot(z, w)
    if n < 1e-12:
        q[3], q[4], q[5], q[6] = 0.0, 0.0, 0.0, 1.0
    else:
        q[3], q[4], q[5], q[6] = 0.0, 0.0, z / n, w / n
    q[2] = fp[FF_HEIGHT]
    M = np.zeros((nv, nv))
    crba_into(mi_r, mf_r, q, M)
    phi = np.empty(3)
    K = np.empty((3, nv))
    k = np.empty(3)
    ff_table(fp, nv, q, v, phi, K, k)
    return project_velocities(M, nv, K, v, np.zeros(3), fp[FF_RCOND])
