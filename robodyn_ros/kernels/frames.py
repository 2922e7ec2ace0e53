"""Body frames, body velocities and the momentum of a tree, compiled (numba): the world poses of
``dynamics.body_poses``, the body velocities of ``dynamics.body_velocities`` and the momentum about
the centre of mass of ``systems.freeflyer.momentum_about_com``, on the packed tree of
:mod:`robodyn_ros.kernels.tree`.
"""
from __future__ import annotations

import numpy as np
from .jit import njit

from ..model import FREE, PRISMATIC, REVOLUTE, SPHERICAL
from .linalg import cross
from .tree import AX, E_, HV, IB, JTYPE, MASS, PARENT, R_, VIDX, _JIT, transforms, workspace


@njit(**_JIT)
def body_frames(mi, mf, q, W, R, p):
    """World orientation R (nb, 3, 3) and origin p (nb, 3) of every body (``dynamics.body_poses``);
    W must hold the transforms (:func:`robodyn_ros.kernels.tree.transforms`)."""
    nb = mi.shape[0]
    E0 = np.empty((nb, 9))
    for i in range(nb):
        par = mi[i, PARENT]
        if par < 0:
            for a in range(9):
                E0[i, a] = W[i, E_ + a]
            for a in range(3):
                p[i, a] = W[i, R_ + a]
        else:
            r0, r1, r2 = W[i, R_], W[i, R_ + 1], W[i, R_ + 2]
            for a in range(3):
                p[i, a] = p[par, a] + E0[par, a] * r0 + E0[par, 3 + a] * r1 + E0[par, 6 + a] * r2
                for b in range(3):
                    E0[i, 3 * a + b] = (W[i, E_ + 3 * a] * E0[par, b] + W[i, E_ + 3 * a + 1] * E0[par, 3 + b]
                                        + W[i, E_ + 3 * a + 2] * E0[par, 6 + b])
        for a in range(3):
            for b in range(3):
                R[i, a, b] = E0[i, 3 * b + a]


@njit(**_JIT)
def xmot_vector(W, i, src, dst):
    """``dst = X_i src`` for a motion vector (Xup_i in W): ``[E w; E (u − r × w)]``."""
    w0, w1, w2 = src[0], src[1], src[2]
    r0, r1, r2 = W[i, R_], W[i, R_ + 1], W[i, R_ + 2]
    u0 = src[3] - (r1 * w2 - r2 * w1)
    u1 = src[4] - (r2 * w0 - r0 * w2)
    u2 = src[5] - (r0 * w1 - r1 * w0)
    for a in range(3):
        e0, e1, e2 = W[i, E_ + 3 * a], W[i, E_ + 3 * a + 1], W[i, E_ + 3 * a + 2]
        dst[a] = e0 * w0 + e1 * w1 + e2 * w2
        dst[3 + a] = e0 * u0 + e1 * u1 + e2 * u2


@njit(**_JIT)
def joint_motion_vector(mi, mf, x, i, out):
    """``out = S_i x_i`` (6,) in body i coordinates."""
    jt = mi[i, JTYPE]
    s = mi[i, VIDX]
    for a in range(6):
        out[a] = 0.0
    if jt == REVOLUTE:
        for a in range(3):
            out[a] = mf[i, AX + a] * x[s]
    elif jt == PRISMATIC:
        for a in range(3):
            out[3 + a] = mf[i, AX + a] * x[s]
    elif jt == FREE:
        for a in range(6):
            out[a] = x[s + a]
    elif jt == SPHERICAL:
        for a in range(3):
            out[a] = x[s + a]


@njit(**_JIT)
def body_velocities(mi, mf, q, v, W, vb):
    """Body spatial velocities vb (nb, 6) ``[ω; v_O]`` in body coordinates (``dynamics.body_velocities``)."""
    vJ = np.empty(6)
    for i in range(mi.shape[0]):
        par = mi[i, PARENT]
        joint_motion_vector(mi, mf, v, i, vJ)
        if par < 0:
            for a in range(6):
                vb[i, a] = vJ[a]
        else:
            xmot_vector(W, i, vb[par], vb[i])
            for a in range(6):
                vb[i, a] += vJ[a]


@njit(**_JIT)
def momentum(mi, mf, q, v):
    """``(p (3,), L (3,), c (3,))``: linear momentum, angular momentum about the CoM and the CoM,
    world coordinates (``freeflyer.momentum_about_com`` of ``FreeFlyerSystem.body_coms``)."""
    nb = mi.shape[0]
    W, R, p = frames_ws(mi, mf, q)
    vb = np.empty((nb, 6))
    body_velocities(mi, mf, q, v, W, vb)
    ms = np.empty(nb)
    c = np.empty((nb, 3))
    cd = np.empty((nb, 3))
    Ls = np.empty((nb, 3))
    ci = np.empty(3)
    t = np.empty(3)
    Ic = np.empty((3, 3))
    for i in range(nb):
        m = mf[i, MASS]
        for a in range(3):
            for b in range(3):
                Ic[a, b] = mf[i, IB + 3 * a + b]
        if m <= 0.0:
            m = 0.0
            ci[:] = 0.0
        else:
            for a in range(3):
                ci[a] = mf[i, HV + a] / m
            # Ic = I_O − m c× c×ᵀ = I_O − m (|c|² 1 − c cᵀ)
            cc = ci[0] * ci[0] + ci[1] * ci[1] + ci[2] * ci[2]
            for a in range(3):
                for b in range(3):
                    Ic[a, b] -= m * ((cc if a == b else 0.0) - ci[a] * ci[b])
        ms[i] = m
        cross(vb[i, :3], ci, t)
        for a in range(3):
            t[a] += vb[i, 3 + a]
        for a in range(3):
            c[i, a] = p[i, a] + R[i, a, 0] * ci[0] + R[i, a, 1] * ci[1] + R[i, a, 2] * ci[2]
            cd[i, a] = R[i, a, 0] * t[0] + R[i, a, 1] * t[1] + R[i, a, 2] * t[2]
        for a in range(3):
            ci[a] = Ic[a, 0] * vb[i, 0] + Ic[a, 1] * vb[i, 1] + Ic[a, 2] * vb[i, 2]
        for a in range(3):
            Ls[i, a] = R[i, a, 0] * ci[0] + R[i, a, 1] * ci[1] + R[i, a, 2] * ci[2]
    mt = 0.0
    for i in range(nb):
        mt += ms[i]
    com = np.zeros(3)
    lin = np.zeros(3)
    ang = np.zeros(3)
    for i in range(nb):
        for a in range(3):
            com[a] += ms[i] * c[i, a]
            lin[a] += ms[i] * cd[i, a]
            ang[a] += Ls[i, a]
    for a in range(3):
        com[a] /= mt
    for i in range(nb):
        for a in range(3):
            ci[a] = c[i, a] - com[a]
        cross(ci, cd[i], t)
        for a in range(3):
            ang[a] += ms[i] * t[a]
    return lin, ang, com


@njit(**_JIT)
def frames_ws(mi, mf, q):
    """``(W, R (nb, 3, 3), p (nb, 3))``: a workspace holding the transforms at q, and the world
    poses of the body frames."""
    nb = mi.shape[0]
    W = workspace(nb)
    transforms(mi, mf, q, W)
    R = np.empty((nb, 3, 3))
    p = np.empty((nb, 3))
    body_frames(mi, mf, q, W, R, p)
    return W, R, p


@njit(**_JIT)
def poses(mi, mf, q):
    """``(R (nb, 3, 3), p (nb, 3))`` world poses of the body frames."""
    _, R, p = frames_ws(mi, mf, q)
    return R, p
