"""The free-flying base in the augmented formulation, compiled (:mod:`robodyn_ros.systems.augmented`):
its own kinematics, joint-connection constraints, KKT solve and projection. Entry points in
:mod:`robodyn_ros.kernels.fixed_step`.
"""
from __future__ import annotations

import math

import numpy as np
from .jit import njit

from .linalg import NINFO, OK, cross, flag, kkt_solve, quat_to_R
from .tree import _JIT


# ----------------------------------------------------------------------------------------------
# free-flying base, augmented formulation (systems/augmented.py)
#   ip: [nb, nj, table, stabilisation, n_constraints, -, -, -, parent (nb), dof (nb)]
#   fp: [alpha, beta, table height, rcond, gravity (3), -, m (nb), com (3 nb), Ic (9 nb),
#        Etree (9 nb), r (3 nb), axis (3 nb), arm damping (nj)]
#   u:  [(B u_effort)[6:] (nj), base wrench (6)]
#   x = [quat (4), θ (nj), c (3 nb)], w = [ω (3), θ̇ (nj), ċ (3 nb)]
# ----------------------------------------------------------------------------------------------
AU_NB, AU_NJ, AU_TABLE, AU_STAB, AU_NC, AU_PARENT = 0, 1, 2, 3, 4, 8
AU_ALPHA, AU_BETA, AU_HEIGHT, AU_RCOND, AU_G, AU_M = 0, 1, 2, 3, 4, 8


@njit(**_JIT)
def au_offsets(nb):
    """fp offsets ``(com, Ic, Etree, r, axis, damping)`` of the augmented layout."""
    o_com = AU_M + nb
    o_ic = o_com + 3 * nb
    o_et = o_ic + 9 * nb
    o_r = o_et + 9 * nb
    o_ax = o_r + 3 * nb
    o_d = o_ax + 3 * nb
    return o_com, o_ic, o_et, o_r, o_ax, o_d


@njit(**_JIT)
def au_kinematics(ip, fp, x, w, R, E, om, J, beta):
    """Rotations R, E, angular velocities om, partial angular velocities J, β (``_kinematics``)."""
    nb, nj = ip[AU_NB], ip[AU_NJ]
    nr = 3 + nj
    o_com, o_ic, o_et, o_r, o_ax, o_d = au_offsets(nb)
    quat_to_R(x[0], x[1], x[2], x[3], R[0])
    for a in range(3):
        for b in range(3):
            E[0, a, b] = R[0, b, a]
        om[0, a] = w[a]
        beta[0, a] = 0.0
        for c in range(nr):
            J[0, a, c] = 1.0 if c == a else 0.0
    Rt = np.empty((3, 3))
    K0 = np.zeros((3, 3))
    t = np.empty(3)
    for i in range(1, nb):
        p = ip[AU_PARENT + i]
        k = ip[AU_PARENT + nb + i]
        ax0, ax1, ax2 = fp[o_ax + 3 * i], fp[o_ax + 3 * i + 1], fp[o_ax + 3 * i + 2]
        if k >= 0:
            # rot_axis(a, θ) = 1 + sin θ k× + (1 − cos θ) k× k×, then E = rot_axisᵀ Etree
            th = x[4 + k]
            s, c1 = math.sin(th), 1.0 - math.cos(th)
            K0[0, 1], K0[0, 2], K0[1, 0], K0[1, 2], K0[2, 0], K0[2, 1] = -ax2, ax1, ax2, -ax0, -ax1, ax0
            for a in range(3):
                for b in range(3):
                    kk = K0[a, 0] * K0[0, b] + K0[a, 1] * K0[1, b] + K0[a, 2] * K0[2, b]
                    Rt[b, a] = (1.0 if a == b else 0.0) + s * K0[a, b] + c1 * kk
            for a in range(3):
                for b in range(3):
                    E[i, a, b] = (Rt[a, 0] * fp[o_et + 9 * i + b] + Rt[a, 1] * fp[o_et + 9 * i + 3 + b]
                                  + Rt[a, 2] * fp[o_et + 9 * i + 6 + b])
        else:
            for a in range(3):
                for b in range(3):
                    E[i, a, b] = fp[o_et + 9 * i + 3 * a + b]
        for a in range(3):
            for b in range(3):
                R[i, a, b] = R[p, a, 0] * E[i, b, 0] + R[p, a, 1] * E[i, b, 1] + R[p, a, 2] * E[i, b, 2]
        for a in range(3):
            om[i, a] = E[i, a, 0] * om[p, 0] + E[i, a, 1] * om[p, 1] + E[i, a, 2] * om[p, 2]
            beta[i, a] = E[i, a, 0] * beta[p, 0] + E[i, a, 1] * beta[p, 1] + E[i, a, 2] * beta[p, 2]
            for c in range(nr):
                J[i, a, c] = E[i, a, 0] * J[p, 0, c] + E[i, a, 1] * J[p, 1, c] + E[i, a, 2] * J[p, 2, c]
        if k >= 0:
            thd = w[3 + k]
            at0, at1, at2 = ax0 * thd, ax1 * thd, ax2 * thd
            # β += (E ω_p) × (a θ̇) with E ω_p = om[i] before the joint rate is added
            t[0] = om[i, 1] * at2 - om[i, 2] * at1
            t[1] = om[i, 2] * at0 - om[i, 0] * at2
            t[2] = om[i, 0] * at1 - om[i, 1] * at0
            om[i, 0] += at0
            om[i, 1] += at1
            om[i, 2] += at2
            J[i, 0, 3 + k] += ax0
            J[i, 1, 3 + k] += ax1
            J[i, 2, 3 + k] += ax2
            for a in range(3):
                beta[i, a] += t[a]


@njit(**_JIT)
def _au_joint_end(R, om, J, beta, body, s, sign, nr, r0, Cq, Qd, Ms, acc, t1, t2):
    """One end (child: sign −1, parent: +1) of a joint's rows: ``sign R [s]× J`` into C_q and
    ``sign R (β × s + ω × (ω × s))`` into Q_d."""
    for a in range(3):
        Ms[a, 0] = R[body, a, 1] * s[2] - R[body, a, 2] * s[1]
        Ms[a, 1] = -R[body, a, 0] * s[2] + R[body, a, 2] * s[0]
        Ms[a, 2] = R[body, a, 0] * s[1] - R[body, a, 1] * s[0]
    for a in range(3):
        for c in range(nr):
            Cq[r0 + a, c] += sign * (Ms[a, 0] * J[body, 0, c] + Ms[a, 1] * J[body, 1, c] + Ms[a, 2] * J[body, 2, c])
    cross(beta[body], s, acc)
    cross(om[body], s, t1)
    cross(om[body], t1, t2)
    for a in range(3):
        acc[a] += t2[a]
    for a in range(3):
        Qd[r0 + a] += sign * (R[body, a, 0] * acc[0] + R[body, a, 1] * acc[1] + R[body, a, 2] * acc[2])


@njit(**_JIT)
def au_constraints(ip, fp, x, w, R, om, J, beta, C, Cq, Qd):
    """Joint-connection (and table) constraints ``C, C_q, Q_d`` (``AugmentedFreeFlyerSystem._constraints``)."""
    nb, nj = ip[AU_NB], ip[AU_NJ]
    nr = 3 + nj
    nv = nr + 3 * nb
    nc = ip[AU_NC]
    o_com, o_ic, o_et, o_r, o_ax, o_d = au_offsets(nb)
    co = 4 + nj  # c in x
    for i in range(nc):
        for j in range(nv):
            Cq[i, j] = 0.0
    sc = np.empty(3)
    sp = np.empty(3)
    Ms = np.empty((3, 3))
    t1 = np.empty(3)
    t2 = np.empty(3)
    acc = np.empty(3)
    for i in range(1, nb):
        p = ip[AU_PARENT + i]
        r0 = 3 * (i - 1)
        for a in range(3):
            sc[a] = -fp[o_com + 3 * i + a]
            sp[a] = fp[o_r + 3 * i + a] - fp[o_com + 3 * p + a]
        for a in range(3):
            C[r0 + a] = (x[co + 3 * i + a] + (R[i, a, 0] * sc[0] + R[i, a, 1] * sc[1] + R[i, a, 2] * sc[2])
                         - x[co + 3 * p + a] - (R[p, a, 0] * sp[0] + R[p, a, 1] * sp[1] + R[p, a, 2] * sp[2]))
            Cq[r0 + a, nr + 3 * i + a] = 1.0
            Cq[r0 + a, nr + 3 * p + a] = -1.0
        # C_q += −R_i [s_c]× J_i + R_p [s_p]× J_p;
        # Q_d = −(R_i (β_i × s_c + ω_i × (ω_i × s_c)) − R_p (β_p × s_p + ω_p × (ω_p × s_p)))
        for a in range(3):
            Qd[r0 + a] = 0.0
        _au_joint_end(R, om, J, beta, i, sc, -1.0, nr, r0, Cq, Qd, Ms, acc, t1, t2)
        _au_joint_end(R, om, J, beta, p, sp, 1.0, nr, r0, Cq, Qd, Ms, acc, t1, t2)
    if ip[AU_TABLE]:
        r0 = 3 * (nb - 1)
        for a in range(3):
            sc[a] = -fp[o_com + a]
        pb = np.empty(3)
        for a in range(3):
            pb[a] = x[co + a] + R[0, a, 0] * sc[0] + R[0, a, 1] * sc[1] + R[0, a, 2] * sc[2]
        n0, n1, n2 = R[0, 0, 2], R[0, 1, 2], R[0, 2, 2]
        C[r0] = pb[2] - fp[AU_HEIGHT]
        C[r0 + 1] = -n1
        C[r0 + 2] = n0
        # Kw[0] = −(R [s]×)[2], Kw[1:] = (−[e_z]× [n]× R)[:2], Kc[0, 2] = 1
        Cq[r0, 0] = -(R[0, 2, 1] * sc[2] - R[0, 2, 2] * sc[1])
        Cq[r0, 1] = -(-R[0, 2, 0] * sc[2] + R[0, 2, 2] * sc[0])
        Cq[r0, 2] = -(R[0, 2, 0] * sc[1] - R[0, 2, 1] * sc[0])
        for j in range(3):
            Cq[r0 + 1, j] = n2 * R[0, 0, j] - n0 * R[0, 2, j]
            Cq[r0 + 2, j] = n2 * R[0, 1, j] - n1 * R[0, 2, j]
        Cq[r0, nr + 2] = 1.0
        # k[0] = −(R (ω × (ω × s)))_z, k[1:] = −(e_z × (ω_w × (ω_w × n)))[:2]
        cross(om[0], sc, t1)
        cross(om[0], t1, t2)
        Qd[r0] = -(R[0, 2, 0] * t2[0] + R[0, 2, 1] * t2[1] + R[0, 2, 2] * t2[2])
        ww = np.empty(3)
        for a in range(3):
            ww[a] = R[0, a, 0] * om[0, 0] + R[0, a, 1] * om[0, 1] + R[0, a, 2] * om[0, 2]
        acc[0], acc[1], acc[2] = n0, n1, n2
        cross(ww, acc, t1)
        cross(ww, t1, t2)
        Qd[r0 + 1] = t2[1]
        Qd[r0 + 2] = -t2[0]


@njit(**_JIT)
def au_solve(ip, fp, u, y, exact_info, wd, lam, info, R, E, om, J, beta, C, Cq, M):
    """The augmented system at state y (``AugmentedFreeFlyerSystem.solve``): ẇ into wd, λ into lam,
    the kinematics into R, E, om, J, beta and C, C_q, M. Returns OK or SINGULAR."""
    nb, nj = ip[AU_NB], ip[AU_NJ]
    nr = 3 + nj
    nq = 4 + nj + 3 * nb
    nv = nr + 3 * nb
    nc = ip[AU_NC]
    x = y[:nq]
    w = y[nq:nq + nv]
    o_com, o_ic, o_et, o_r, o_ax, o_d = au_offsets(nb)
    au_kinematics(ip, fp, x, w, R, E, om, J, beta)
    for i in range(nv):
        for j in range(nv):
            M[i, j] = 0.0
    Q = np.zeros(nv)
    Ic = np.empty((3, 3))
    IJ = np.empty((3, nr))
    t = np.empty(3)
    Iw = np.empty(3)
    for i in range(nb):
        for a in range(3):
            for b in range(3):
                Ic[a, b] = fp[o_ic + 9 * i + 3 * a + b]
        for a in range(3):
            for c in range(nr):
                IJ[a, c] = Ic[a, 0] * J[i, 0, c] + Ic[a, 1] * J[i, 1, c] + Ic[a, 2] * J[i, 2, c]
        for r in range(nr):
            for c in range(nr):
                M[r, c] += J[i, 0, r] * IJ[0, c] + J[i, 1, r] * IJ[1, c] + J[i, 2, r] * IJ[2, c]
        for a in range(3):
            Iw[a] = Ic[a, 0] * om[i, 0] + Ic[a, 1] * om[i, 1] + Ic[a, 2] * om[i, 2]
        cross(om[i], Iw, t)
        for a in range(3):
            t[a] += Ic[a, 0] * beta[i, 0] + Ic[a, 1] * beta[i, 1] + Ic[a, 2] * beta[i, 2]
        for r in range(nr):
            Q[r] -= J[i, 0, r] * t[0] + J[i, 1, r] * t[1] + J[i, 2, r] * t[2]
        mi_ = fp[AU_M + i]
        for a in range(3):
            M[nr + 3 * i + a, nr + 3 * i + a] = mi_
            Q[nr + 3 * i + a] += mi_ * fp[AU_G + a]
    # thrusters: τ_c = τ_b − com_0 × f_b about the platform CoM, R_0 f_b on ċ_0
    fb = u[nj:nj + 3]
    c0 = np.empty(3)
    for a in range(3):
        c0[a] = fp[o_com + a]
    cross(c0, fb, t)
    for a in range(3):
        Q[a] += u[nj + 3 + a] - t[a]
    for a in range(3):
        Q[nr + a] += R[0, a, 0] * fb[0] + R[0, a, 1] * fb[1] + R[0, a, 2] * fb[2]
    for k in range(nj):
        Q[3 + k] += u[k] - fp[o_d + k] * w[3 + k]
    if nc == 0:
        return kkt_solve(M, nr, Q, Cq, np.zeros(0), fp[AU_RCOND], 0.0, exact_info, wd, lam, info)
    Qd = np.empty(nc)
    au_constraints(ip, fp, x, w, R, om, J, beta, C, Cq, Qd)
    two_alpha = 2.0 * fp[AU_ALPHA]
    b2 = fp[AU_BETA] * fp[AU_BETA]
    for i in range(nc):
        s = 0.0
        for j in range(nv):
            s += Cq[i, j] * w[j]
        Qd[i] = Qd[i] - two_alpha * s - b2 * C[i]
    return kkt_solve(M, nr, Q, Cq, Qd, fp[AU_RCOND], 0.0, exact_info, wd, lam, info)


@njit(**_JIT)
def au_config_rate(nq, nv, x, w, out):
    """``[½ quat ⊗ (ω, 0); θ̇; ċ]`` (``AugmentedFreeFlyerSystem.config_rate``)."""
    ax, ay, az, aw = x[0], x[1], x[2], x[3]
    bx, by, bz, bw = w[0], w[1], w[2], 0.0
    out[0] = 0.5 * (aw * bx + ax * bw + ay * bz - az * by)
    out[1] = 0.5 * (aw * by - ax * bz + ay * bw + az * bx)
    out[2] = 0.5 * (aw * bz + ax * by - ay * bx + az * bw)
    out[3] = 0.5 * (aw * bw - ax * bx - ay * by - az * bz)
    for j in range(4, nq):
        out[j] = w[j - 1]


@njit(**_JIT)
def au_evaluate(ip, fp, u, z, dz):
    """``dz = [ẋ; ẇ; power]`` (``AugmentedFreeFlyerSystem.rhs`` and ``.input_power``)."""
    nb, nj = ip[AU_NB], ip[AU_NJ]
    nr = 3 + nj
    nq = 4 + nj + 3 * nb
    nv = nr + 3 * nb
    nc = ip[AU_NC]
    x = z[:nq]
    w = z[nq:nq + nv]
    R = np.empty((nb, 3, 3))
    E = np.empty((nb, 3, 3))
    om = np.empty((nb, 3))
    J = np.empty((nb, 3, nr))
    beta = np.empty((nb, 3))
    C = np.empty(nc)
    Cq = np.empty((nc, nv))
    M = np.empty((nv, nv))
    lam = np.empty(nc)
    info = np.empty(NINFO)
    st = au_solve(ip, fp, u, z[:nq + nv], flag(0), dz[nq:nq + nv], lam, info, R, E, om, J, beta, C, Cq, M)
    au_config_rate(nq, nv, x, w, dz[:nq])
    # power: θ̇ · (τ_arm − D θ̇) + ω · τ_b + v_O · f_b, v_O = R_0ᵀ ċ_0 − ω × com_0
    o_com, o_ic, o_et, o_r, o_ax, o_d = au_offsets(nb)
    P = 0.0
    for k in range(nj):
        P += w[3 + k] * (u[k] - fp[o_d + k] * w[3 + k])
    P += w[0] * u[nj + 3] + w[1] * u[nj + 4] + w[2] * u[nj + 5]
    c0 = np.empty(3)
    t = np.empty(3)
    for a in range(3):
        c0[a] = fp[o_com + a]
    cross(w[0:3], c0, t)
    Rq = np.empty((3, 3))
    quat_to_R(x[0], x[1], x[2], x[3], Rq)
    for a in range(3):
        vo = Rq[0, a] * w[nr] + Rq[1, a] * w[nr + 1] + Rq[2, a] * w[nr + 2] - t[a]
        P += vo * u[nj + a]
    dz[nq + nv] = P
    return st


@njit(**_JIT)
def au_report(ip, fp, y, R, om, out):
    """Momentum and energies of the augmented state y (``AugmentedFreeFlyerSystem._momentum`` and
    ``._energies``) into out: ``[p (3), L about the CoM (3), CoM (3), kinetic, potential]``; R, om
    from :func:`au_kinematics`."""
    nb, nj = ip[AU_NB], ip[AU_NJ]
    nr = 3 + nj
    nq = 4 + nj + 3 * nb
    o_com, o_ic, o_et, o_r, o_ax, o_d = au_offsets(nb)
    co, cdo = 4 + nj, nq + nr
    mt = 0.0
    for i in range(nb):
        mt += fp[AU_M + i]
    for a in range(11):
        out[a] = 0.0
    Iw = np.empty(3)
    ke_t = 0.0
    ke_r = 0.0
    pe = 0.0
    for i in range(nb):
        m = fp[AU_M + i]
        for a in range(3):
            Iw[a] = (fp[o_ic + 9 * i + 3 * a] * om[i, 0] + fp[o_ic + 9 * i + 3 * a + 1] * om[i, 1]
                     + fp[o_ic + 9 * i + 3 * a + 2] * om[i, 2])
        for a in range(3):
            out[3 + a] += R[i, a, 0] * Iw[0] + R[i, a, 1] * Iw[1] + R[i, a, 2] * Iw[2]  # spin momenta
            out[a] += m * y[cdo + 3 * i + a]
            out[6 + a] += m * y[co + 3 * i + a]
        ke_t += m * (y[cdo + 3 * i] ** 2 + y[cdo + 3 * i + 1] ** 2 + y[cdo + 3 * i + 2] ** 2)
        ke_r += om[i, 0] * Iw[0] + om[i, 1] * Iw[1] + om[i, 2] * Iw[2]
        pe += m * (y[co + 3 * i] * fp[AU_G] + y[co + 3 * i + 1] * fp[AU_G + 1] + y[co + 3 * i + 2] * fp[AU_G + 2])
    for a in range(3):
        out[6 + a] /= mt
    for i in range(nb):  # + Σ m_i (c_i − c) × ċ_i
        m = fp[AU_M + i]
        r0 = y[co + 3 * i] - out[6]
        r1 = y[co + 3 * i + 1] - out[7]
        r2 = y[co + 3 * i + 2] - out[8]
        d0, d1, d2 = y[cdo + 3 * i], y[cdo + 3 * i + 1], y[cdo + 3 * i + 2]
        out[3] += m * (r1 * d2 - r2 * d1)
        out[4] += m * (r2 * d0 - r0 * d2)
        out[5] += m * (r0 * d1 - r1 * d0)
    out[9] = 0.5 * ke_t + 0.5 * ke_r
    out[10] = -pe


@njit(**_JIT)
def au_project(ip, y):
    """Renormalise the quaternion in place (the Baumgarte / unstabilised projection)."""
    n = math.sqrt(y[0] * y[0] + y[1] * y[1] + y[2] * y[2] + y[3] * y[3])
    for a in range(4):
        y[a] /= n
    return OK
