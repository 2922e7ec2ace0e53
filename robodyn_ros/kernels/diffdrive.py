"""The differential drive, compiled (:mod:`robodyn_ros.systems.diffdrive`, alone or with an arm):
its electrical model, rolling constraints, mass matrix, KKT solve, outputs and contact wrenches.
Entry points for the Simulator are in :mod:`robodyn_ros.kernels.fixed_step`.
"""
from __future__ import annotations

import math

import numpy as np
from .jit import njit

from .frames import frames_ws
from .linalg import NINFO, OK, flag, kkt_solve, project_velocities
from .rosenbrock import B1, B2, C21, GAMMA
from .tree import P_, _JIT, crba_ws, energies, rnea_ws, transforms, workspace


# ----------------------------------------------------------------------------------------------
# differential drive (systems/diffdrive.py), alone or with an arm
#   ip: [nv, has_arm, cur_left, cur_right, has_effort]  (cur_*: index of the current state or -1)
#   fp: [r_w, r_c, alpha, m, S0, S1, J, Is_l, Is_r, rcond, motor left (8), motor right (8),
#        armature (nv), damping (nv)]; motor: [K, R, L, N, b, tau_c, omega_s, V_s]
#   u:  [V_left, V_right, B u_effort (nv)]
#   y = [q (nv), v (nv), currents]; q = [x, y, yaw, phi_l, phi_r, arm...]
# ----------------------------------------------------------------------------------------------
DD_NV, DD_HAS_ARM, DD_CUR, DD_HAS_EFFORT = 0, 1, 2, 4
DD_RW, DD_RC, DD_ALPHA, DD_M, DD_S, DD_J, DD_IS, DD_RCOND, DD_MOTOR = 0, 1, 2, 3, 4, 6, 7, 9, 10
MOT_K, MOT_R, MOT_L, MOT_N, MOT_B, MOT_TC, MOT_WS, MOT_VS, MOT_SIZE = 0, 1, 2, 3, 4, 5, 6, 7, 8
DD_ARMATURE = DD_MOTOR + 2 * MOT_SIZE
_IX, _IY, _ITH, _IL, _IR = 0, 1, 2, 3, 4


@njit(**_JIT)
def dd_electrical(ip, fp, u, y, el):
    """``el = [volts (2), currents (2), wheel torques (2)]`` (``DiffDriveSystem.electrical``)."""
    nv = ip[DD_NV]
    for k in range(2):
        o = DD_MOTOR + MOT_SIZE * k
        Vs = fp[o + MOT_VS]
        volts = min(max(u[k], -Vs), Vs)
        w = y[nv + _IL + k]
        Kt, Nn = fp[o + MOT_K], fp[o + MOT_N]
        cur = ip[DD_CUR + k]
        if cur >= 0:
            i = y[2 * nv + cur]
        else:
            i = (volts - Kt * Nn * w) / fp[o + MOT_R]
        wm = Nn * w
        fr = fp[o + MOT_B] * wm + fp[o + MOT_TC] * math.tanh(wm / fp[o + MOT_WS])
        el[k] = volts
        el[2 + k] = i
        el[4 + k] = Nn * (Kt * i - fr)


@njit(**_JIT)
def dd_constraints(fp, nv, q, v, K, kdv):
    """``K (4, nv)`` and ``K̇ v (4,)`` of the rolling constraints (D4)."""
    rw, rc = fp[DD_RW], fp[DD_RC]
    c, s = math.cos(q[_ITH]), math.sin(q[_ITH])
    for i in range(4):
        for j in range(nv):
            K[i, j] = 0.0
    K[0, _IX], K[0, _IY], K[0, _ITH], K[0, _IL] = c, s, -rc, -rw
    K[1, _IX], K[1, _IY] = -s, c
    K[2, _IX], K[2, _IY], K[2, _ITH], K[2, _IR] = c, s, rc, -rw
    K[3, _IX], K[3, _IY] = -s, c
    vf = c * v[_IX] + s * v[_IY]
    vy = -s * v[_IX] + c * v[_IY]
    w = v[_ITH]
    kdv[0] = w * vy
    kdv[1] = -w * vf
    kdv[2] = w * vy
    kdv[3] = -w * vf


@njit(**_JIT)
def dd_mass(ip, fp, mi_r, mf_r, q, v, M, h, bias):
    """``M`` (+ rotor inertia) and, if bias, ``h`` (``DiffDriveSystem.mass_and_bias``)."""
    nv = ip[DD_NV]
    if ip[DD_HAS_ARM] == 0:
        c, s = math.cos(q[_ITH]), math.sin(q[_ITH])
        S0, S1 = fp[DD_S], fp[DD_S + 1]
        for i in range(5):
            for j in range(5):
                M[i, j] = 0.0
        M[0, 0] = fp[DD_M]
        M[1, 1] = fp[DD_M]
        M[0, 2] = M[2, 0] = c * -S1 - s * S0
        M[1, 2] = M[2, 1] = s * -S1 + c * S0
        M[2, 2] = fp[DD_J]
        M[3, 3] = fp[DD_IS]
        M[4, 4] = fp[DD_IS + 1]
        if bias:
            w2 = -v[_ITH] ** 2
            h[0] = w2 * (c * S0 - s * S1)
            h[1] = w2 * (s * S0 + c * S1)
            for j in range(2, 5):
                h[j] = 0.0
        return
    for i in range(nv):
        for j in range(nv):
            M[i, j] = 0.0
    W = workspace(mi_r.shape[0])
    transforms(mi_r, mf_r, q, W)
    if bias:  # RNEA leaves the transforms in W for the CRBA
        rnea_ws(mi_r, mf_r, q, v, np.zeros(nv), W, flag(0), h, W)
    crba_ws(mi_r, mf_r, M, W)
    for i in range(nv):
        M[i, i] += fp[DD_ARMATURE + i]


@njit(**_JIT)
def dd_solve(ip, fp, mi_r, mf_r, u, y, exact_info, a, lam, info, el):
    """Constrained accelerations a and ground forces lam (4,) (``DiffDriveSystem.solve``); el
    receives the electrical quantities of :func:`dd_electrical`. Returns OK or SINGULAR."""
    nv = ip[DD_NV]
    q = y[:nv]
    v = y[nv:2 * nv]
    dd_electrical(ip, fp, u, y, el)
    M = np.empty((nv, nv))
    h = np.empty(nv)
    dd_mass(ip, fp, mi_r, mf_r, q, v, M, h, flag(1))
    K = np.empty((4, nv))
    kdv = np.empty(4)
    dd_constraints(fp, nv, q, v, K, kdv)
    alpha = fp[DD_ALPHA]
    k = np.empty(4)
    for i in range(4):
        s = 0.0
        for j in range(nv):
            s += K[i, j] * v[j]
        k[i] = -kdv[i] - alpha * s
    Q = np.empty(nv)
    for j in range(nv):
        Q[j] = -fp[DD_ARMATURE + nv + j] * v[j]
    Q[_IL] += el[4]
    Q[_IR] += el[5]
    if ip[DD_HAS_EFFORT]:
        for j in range(nv):
            Q[j] += u[2 + j]
    for j in range(nv):
        Q[j] -= h[j]
    return kkt_solve(M, nv, Q, K, k, fp[DD_RCOND], 0.0, exact_info, a, lam, info)


@njit(**_JIT)
def dd_evaluate(ip, fp, mi_r, mf_r, u, y, dz):
    """``dz = [q̇; v̇; di/dt; power]`` (``DiffDriveSystem.rhs`` and ``.input_power``)."""
    nv = ip[DD_NV]
    ny = y.shape[0]
    for x in y:
        if not math.isfinite(x):
            dz[:] = np.nan
            return OK
    el = np.empty(6)
    lam = np.empty(4)
    info = np.empty(NINFO)
    st = dd_solve(ip, fp, mi_r, mf_r, u, y, flag(0), dz[nv:2 * nv], lam, info, el)
    if st != OK:
        return st
    for j in range(nv):
        dz[j] = y[nv + j]
    P = 0.0
    for k in range(2):
        o = DD_MOTOR + MOT_SIZE * k
        volts, i, w = el[k], el[2 + k], y[nv + _IL + k]
        cur = ip[DD_CUR + k]
        Kt, Nn, Rr = fp[o + MOT_K], fp[o + MOT_N], fp[o + MOT_R]
        if cur >= 0:
            dz[2 * nv + cur] = (volts - Rr * i - Kt * Nn * w) / fp[o + MOT_L]
        wm = Nn * w
        fr = fp[o + MOT_B] * wm + fp[o + MOT_TC] * math.tanh(wm / fp[o + MOT_WS])
        P += volts * i - Rr * i * i - fr * (Nn * w)
    s = 0.0
    for j in range(nv):
        s += y[nv + j] * (-fp[DD_ARMATURE + nv + j] * y[nv + j])
    P += s
    if ip[DD_HAS_EFFORT]:
        s = 0.0
        for j in range(nv):
            s += y[nv + j] * u[2 + j]
        P += s
    dz[ny] = P
    return OK


@njit(**_JIT)
def dd_passive(ip, fp, y, gh, Dm, ce):
    """The passive part of the differential drive's Jacobian at y for γh = gh (the linearly implicit
    step, :mod:`robodyn_ros.kernels.rosenbrock`), as named contributions: Dm (nv, nv, overwritten) =
    joint damping ``diag(d)`` + each motor's friction slope at its wheel ``N² (b + τ_c sech²(N ω/ω_s)/ω_s)``
    + for a motor without a current state (L = 0) its back-EMF damping ``N² K² / R``; a motor with a
    current state (L > 0, ``L di/dt = V − R i − K N ω``, torque ``N K i``) writes ``ce[k] = [N K, L, R]``
    (else ``[0, 0, 0]``): :func:`dd_rosenbrock_step` eliminates its current from the stage equations."""
    nv = ip[DD_NV]
    for i in range(nv):
        for j in range(nv):
            Dm[i, j] = 0.0
        Dm[i, i] = fp[DD_ARMATURE + nv + i]
    for k in range(2):
        o = DD_MOTOR + MOT_SIZE * k
        Kt, Nn, Rr, Ll = fp[o + MOT_K], fp[o + MOT_N], fp[o + MOT_R], fp[o + MOT_L]
        th = math.tanh(Nn * y[nv + _IL + k] / fp[o + MOT_WS])
        j = _IL + k
        Dm[j, j] += Nn * Nn * (fp[o + MOT_B] + fp[o + MOT_TC] * (1.0 - th * th) / fp[o + MOT_WS])
        if ip[DD_CUR + k] >= 0:
            ce[k, 0], ce[k, 1], ce[k, 2] = Nn * Kt, Ll, Rr
        else:
            Dm[j, j] += (Nn * Kt) ** 2 / Rr
            ce[k, 0], ce[k, 1], ce[k, 2] = 0.0, 0.0, 0.0


@njit(**_JIT)
def dd_rosenbrock_step(ip, fp, mi_r, mf_r, u, z, h, dz, Y, k1):
    """One linearly implicit step (:mod:`robodyn_ros.kernels.rosenbrock`, (R1)-(R3)) of the differential
    drive, ``z = [q, v, currents, W]`` in place; returns OK, or SINGULAR (z untouched).

    J at zₙ holds the passive forces (:func:`dd_passive`: damping, friction slopes, back-EMF) and the
    motor electrics with their back-EMF coupling; the rolling constraints enter through the
    constrained mobility ``Y`` (``J_vv = −Y D``, ``J_vi = Y N K``, ``J_iv = −N K / L``, ``J_ii = −R/L``). Each
    stage ``(I − γhJ) k = b`` is then, with the current eliminated
    (``k_i = (L b_i − γh N K k_ω)/(L + γh R)``), one KKT solve with the mass matrix and constraint rows at qₙ::

        [M + γh D + Σ γ²h² (N K)²/(L + γh R) e_ω e_ωᵀ,  Kᵀ] [kv]   [M bv + Σ γh N K L b_i/(L + γh R) e_ω]
        [K,                                             0] [·ᵀ] = [K bv]

    (``M kv + γh (D kv − N K k_i) = M bv + Kᵀ μ``, ``K kv = K bv`` is ``kv = bv − γh Y (D kv − N K k_i)``).
    bv = the constrained acceleration at the stage point (:func:`dd_evaluate`; stage 2 less 2 kv1);
    the work entry takes the power. dz, Y, k1 (ny + 1,): scratch."""
    nv = ip[DD_NV]
    n = z.shape[0]
    ny = n - 1
    nc = ny - 2 * nv
    gh = GAMMA * h
    M = np.empty((nv, nv))
    hb = np.empty(nv)
    dd_mass(ip, fp, mi_r, mf_r, z[:nv], z[nv:2 * nv], M, hb, flag(0))
    Kc = np.empty((4, nv))
    kdv = np.empty(4)
    dd_constraints(fp, nv, z[:nv], z[nv:2 * nv], Kc, kdv)
    Dm = np.empty((nv, nv))
    ce = np.empty((2, 3))
    dd_passive(ip, fp, z, gh, Dm, ce)
    A = np.empty((nv, nv))
    for i in range(nv):
        for j in range(nv):
            A[i, j] = M[i, j] + gh * Dm[i, j]
    for m in range(2):
        if ce[m, 1] > 0.0:
            A[_IL + m, _IL + m] += gh * gh * ce[m, 0] ** 2 / (ce[m, 1] + gh * ce[m, 2])
    bv = np.empty(nv)
    rhs = np.empty(nv)
    crhs = np.empty(4)
    kv = np.empty(nv)
    lam = np.empty(4)
    info = np.empty(NINFO)
    k2 = np.empty(n)
    for s in range(2):
        st = dd_evaluate(ip, fp, mi_r, mf_r, u, z[:ny] if s == 0 else Y[:ny], dz)
        if st != OK:
            return st
        kk = k1 if s == 0 else k2
        for a in range(nv):   # b of this stage (stage 2: f(Y) − 2 k1)
            kk[a] = dz[a] if s == 0 else dz[a] + C21 * k1[a]
            bv[a] = dz[nv + a] if s == 0 else dz[nv + a] + C21 * k1[nv + a]
        for a in range(2 * nv, n):
            kk[a] = dz[a] if s == 0 else dz[a] + C21 * k1[a]
        for i in range(nv):
            acc = 0.0
            for j in range(nv):
                acc += M[i, j] * bv[j]
            rhs[i] = acc
        for m in range(2):
            cur = ip[DD_CUR + m]
            if cur >= 0:
                L_, R_ = ce[m, 1], ce[m, 2]
                rhs[_IL + m] += gh * ce[m, 0] * L_ * kk[2 * nv + cur] / (L_ + gh * R_)
        for i in range(4):
            acc = 0.0
            for j in range(nv):
                acc += Kc[i, j] * bv[j]
            crhs[i] = acc
        st = kkt_solve(A, nv, rhs, Kc, crhs, fp[DD_RCOND], 0.0, flag(0), kv, lam, info)
        if st != OK:
            return st
        for a in range(nv):
            kk[nv + a] = kv[a]
            kk[a] += gh * kv[a]             # kq = bq + γh kv
        for m in range(2):
            cur = ip[DD_CUR + m]
            if cur >= 0:
                L_, R_ = ce[m, 1], ce[m, 2]
                kk[2 * nv + cur] = (L_ * kk[2 * nv + cur] - gh * ce[m, 0] * kv[_IL + m]) / (L_ + gh * R_)
        if s == 0:
            for a in range(n):
                Y[a] = z[a] + h * k1[a]
    for a in range(n):
        z[a] += h * (B1 * k1[a] + B2 * k2[a])
    return OK


#: entries of :func:`dd_report`'s output
DR_EL, DR_FRICTION, DR_RESIDUAL, DR_KINETIC, DR_POTENTIAL, DR_MAGNETIC, NDR = 0, 6, 8, 9, 10, 11, 12


@njit(**_JIT)
def dd_report(ip, fp, mi_r, mf_r, u, y, out):
    """What ``DiffDriveSystem.outputs`` reports besides the wrenches, into out (NDR,):
    electrical quantities (6, :func:`dd_electrical`), friction loss per motor (2), ``max |K v|``,
    kinetic (with rotor inertia), potential (arm) and magnetic energy."""
    nv = ip[DD_NV]
    q = y[:nv]
    v = y[nv:2 * nv]
    dd_electrical(ip, fp, u, y, out[DR_EL:DR_EL + 6])
    for k in range(2):
        o = DD_MOTOR + MOT_SIZE * k
        w = v[_IL + k]
        Nn = fp[o + MOT_N]
        wm = Nn * w
        fr = fp[o + MOT_B] * wm + fp[o + MOT_TC] * math.tanh(wm / fp[o + MOT_WS])
        out[DR_FRICTION + k] = fr * (Nn * w)
    K = np.empty((4, nv))
    kdv = np.empty(4)
    dd_constraints(fp, nv, q, v, K, kdv)
    r = 0.0
    for i in range(4):
        s = 0.0
        for j in range(nv):
            s += K[i, j] * v[j]
        r = max(r, abs(s))
    out[DR_RESIDUAL] = r
    M = np.empty((nv, nv))
    h = np.empty(nv)
    dd_mass(ip, fp, mi_r, mf_r, q, v, M, h, flag(0))
    kin = 0.0
    for i in range(nv):
        s = 0.0
        for j in range(nv):
            s += M[i, j] * v[j]
        kin += v[i] * s
    out[DR_KINETIC] = 0.5 * kin
    out[DR_POTENTIAL] = energies(mi_r, mf_r, q, v)[1] if ip[DD_HAS_ARM] else 0.0
    mag = 0.0
    for k in range(2):
        cur = ip[DD_CUR + k]
        if cur >= 0:
            mag += 0.5 * fp[DD_MOTOR + MOT_SIZE * k + MOT_L] * y[2 * nv + cur] ** 2
    out[DR_MAGNETIC] = mag


@njit(**_JIT)
def dd_project(ip, fp, mi_r, mf_r, y):
    """Mass-orthogonal projection of v onto ``K v = 0`` in place (``DiffDriveSystem.project``)."""
    nv = ip[DD_NV]
    q = y[:nv]
    v = y[nv:2 * nv]
    K = np.empty((4, nv))
    kdv = np.empty(4)
    dd_constraints(fp, nv, q, v, K, kdv)
    e = 0.0
    for i in range(4):
        s = 0.0
        for j in range(nv):
            s += K[i, j] * v[j]
        e = max(e, abs(s))
    if not e > 0.0:
        return OK
    M = np.empty((nv, nv))
    h = np.empty(nv)
    dd_mass(ip, fp, mi_r, mf_r, q, v, M, h, flag(0))
    return project_velocities(M, nv, K, v, np.zeros(4), fp[DD_RCOND])


#: blocks of :func:`dd_outputs`'s output after the joint states (3 n_pub: positions, velocities,
#: efforts): odometry (13: position, orientation x y z w, linear, angular), the report (NDR, as
#: :func:`dd_report`), then DO_NEXTRA diagnostics values in ``DiffDriveSystem.outputs``' order
#: [per motor: voltage, current, power, torque, friction loss; electrical power, copper loss,
#: voltage saturated (0/1), constraint residual, constraint rank], then, with wrenches, the
#: (2 + n_bodies, 6) wrenches (contacts, then the bodies given)
DO_ODOM, DO_NEXTRA = 13, 15


@njit(**_JIT)
def dd_contact_wrenches(fp, mi, mf, q, v, a, lam, bodies, wheels, f):
    """Contact and joint wrenches (``DiffDriveSystem.contact_wrenches``) into f (2 + len(bodies), 6):
    rows 0, 1 the left and right contacts ``[0, 0, 0, F_long, F_lat, 0]``, then the RNEA joint
    wrench (parent on child, child coordinates) of each body in ``bodies``, with the contact
    forces acting on the wheel bodies ``wheels`` (2,) as external forces.

    The force at a contact, ``F = F_long heading + F_lat left``, and ``r × F`` (r = contact point
    minus wheel centre) are taken to the wheel frame with ``Rᵀ x`` (three products summed in
    order, no BLAS). The numbers equal the numpy method's (``dynamics`` poses and RNEA, not these
    kernels) to round-off (tested to 1e-11), not to the bit.
    """
    nb = mi.shape[0]
    W, R, p = frames_ws(mi, mf, q)
    th = q[_ITH]
    c, s = math.cos(th), math.sin(th)
    fext = np.zeros((nb, 6))
    F = np.empty(3)
    rxF = np.empty(3)
    r0, r1, r2 = 0.0, 0.0, -fp[DD_RW]
    for k in range(2):
        F_long, F_lat = lam[2 * k], lam[2 * k + 1]
        F[0] = F_long * c + F_lat * -s
        F[1] = F_long * s + F_lat * c
        F[2] = F_long * 0.0 + F_lat * 0.0
        rxF[0] = r1 * F[2] - r2 * F[1]
        rxF[1] = r2 * F[0] - r0 * F[2]
        rxF[2] = r0 * F[1] - r1 * F[0]
        b = wheels[k]
        for j in range(3):
            fext[b, j] = R[b, 0, j] * rxF[0] + R[b, 1, j] * rxF[1] + R[b, 2, j] * rxF[2]
            fext[b, 3 + j] = R[b, 0, j] * F[0] + R[b, 1, j] * F[1] + R[b, 2, j] * F[2]
        for j in range(6):
            f[k, j] = 0.0
        f[k, 3] = F_long
        f[k, 4] = F_lat
    tau = np.empty(v.shape[0])
    rnea_ws(mi, mf, q, v, a, fext, True, tau, W)
    for n in range(bodies.shape[0]):
        for j in range(6):
            f[2 + n, j] = W[bodies[n], P_ + j]


@njit(**_JIT)
def dd_outputs(ip, fp, mi, mf, mi_r, mf_r, u, y, pub, wrenches, bodies, wheels, out):
    """Everything ``DiffDriveSystem.outputs`` publishes, in one call, into out (layout at
    :data:`DO_ODOM`): pub the published coordinates (wheels, then the arm joints); wrenches:
    also solve for the ground forces (:func:`dd_solve` with the exact rank) and compute the
    wrenches of :func:`dd_contact_wrenches` for ``bodies``. Returns OK or SINGULAR.

    The values are the kernels' report, then the numpy method's operations in its order (its
    two-term ``volts @ i`` as two products summed): equal to the numpy method's to round-off.
    """
    nv = ip[DD_NV]
    npub = pub.shape[0]
    o = 3 * npub
    rep = out[o + DO_ODOM:o + DO_ODOM + NDR]
    dd_report(ip, fp, mi_r, mf_r, u, y, rep)
    for n in range(npub):
        out[n] = y[pub[n]]
        out[npub + n] = y[nv + pub[n]]
        out[2 * npub + n] = u[2 + pub[n]]
    out[2 * npub] = rep[DR_EL + 4]
    out[2 * npub + 1] = rep[DR_EL + 5]
    th = y[_ITH]
    c, s = math.cos(th), math.sin(th)
    vx, vy = y[nv + _IX], y[nv + _IY]
    od = out[o:o + DO_ODOM]
    od[0], od[1], od[2] = y[_IX], y[_IY], 0.0
    od[3], od[4], od[5], od[6] = 0.0, 0.0, math.sin(0.5 * th), math.cos(0.5 * th)
    od[7], od[8], od[9] = c * vx + s * vy, -s * vx + c * vy, 0.0
    od[10], od[11], od[12] = 0.0, 0.0, y[nv + _ITH]
    ex = out[o + DO_ODOM + NDR:o + DO_ODOM + NDR + DO_NEXTRA]
    volts, cur = rep[DR_EL:DR_EL + 2], rep[DR_EL + 2:DR_EL + 4]
    for k in range(2):
        ex[5 * k] = volts[k]
        ex[5 * k + 1] = cur[k]
        ex[5 * k + 2] = volts[k] * cur[k]
        ex[5 * k + 3] = rep[DR_EL + 4 + k]
        ex[5 * k + 4] = rep[DR_FRICTION + k]
    ex[10] = volts[0] * cur[0] + volts[1] * cur[1]
    R0, R1 = fp[DD_MOTOR + MOT_R], fp[DD_MOTOR + MOT_SIZE + MOT_R]
    ex[11] = R0 * cur[0] * cur[0] + R1 * cur[1] * cur[1]
    ex[12] = 1.0 if volts[0] != u[0] or volts[1] != u[1] else 0.0
    ex[13] = rep[DR_RESIDUAL]
    ex[14] = 0.0
    if not wrenches:
        return OK
    a = np.empty(nv)
    lam = np.empty(4)
    info = np.empty(NINFO)
    el = np.empty(6)
    st = dd_solve(ip, fp, mi_r, mf_r, u, y, flag(1), a, lam, info, el)
    if st != OK:
        return st
    ex[14] = info[0]
    w0 = o + DO_ODOM + NDR + DO_NEXTRA
    f = out[w0:w0 + 6 * (2 + bodies.shape[0])].reshape((2 + bodies.shape[0], 6))
    dd_contact_wrenches(fp, mi, mf, y[:nv], y[nv:2 * nv], a, lam, bodies, wheels, f)
    return OK
