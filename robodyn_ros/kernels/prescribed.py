"""The prescribed end-point path, compiled (:mod:`robodyn_ros.systems.prescribed`): the path, the
end point's kinematics, the orthogonal-complement and KKT solves. Entry points in
:mod:`robodyn_ros.kernels.fixed_step`.
"""
from __future__ import annotations

import math

import numpy as np
from .jit import njit

from ..model import PRISMATIC, REVOLUTE
from .frames import body_frames, joint_motion_vector, xmot_vector
from .linalg import (EPS, NINFO, OK, SINGULAR, all_finite, chol_solve, cholesky, cross, flag, kkt_solve, lu_solve,
                     pinv_solve, singular_values_2, sym_eig)
from .tree import AX, JTYPE, PARENT, VIDX, _JIT, crba_ws, rnea_ws, transforms, workspace


# ----------------------------------------------------------------------------------------------
# prescribed end-point path (systems/prescribed.py)
#   ip: [body, formulation (0 complement, 1 kkt), path kind (0 circle, 1 line), has_effort]
#   fp: [alpha, beta, singular_ratio, dls_damping, rcond (KKT), nullspace tol, P (6, row major),
#        path (6): circle [cx, cy, radius, omega, phase, -] | line [x0, y0, x1, y1, duration, delay],
#        damping (nv)]
#   u:  [B u_effort (nv)]
# Solve record (PR_*): ratio, rank, damping, method (0 complement, 1 kkt, 2 kkt_damped), info (4)
# ----------------------------------------------------------------------------------------------
PR_BODY, PR_FORM, PR_PATH, PR_HAS_EFFORT = 0, 1, 2, 3
PF_ALPHA, PF_BETA, PF_SR, PF_DLS, PF_RCOND, PF_TOL, PF_P, PF_PATH, PF_DAMPING = 0, 1, 2, 3, 4, 5, 6, 12, 18
PATH_CIRCLE, PATH_LINE = 0, 1
METHOD_COMPLEMENT, METHOD_KKT, METHOD_KKT_DAMPED = 0, 1, 2
PS_RATIO, PS_RANK, PS_DAMPING, PS_METHOD, PS_INFO, NPS = 0, 1, 2, 3, 4, 8


@njit(**_JIT)
def path_eval(ip, fp, t, pd, vd, ad):
    """Position, velocity, acceleration (2,) of the prescribed path at t (``CirclePath``/``LinePath``)."""
    o = PF_PATH
    if ip[PR_PATH] == PATH_CIRCLE:
        r, w = fp[o + 2], fp[o + 3]
        th = fp[o + 4] + w * t
        c, s = math.cos(th), math.sin(th)
        rw = r * w
        rww = -r * w * w
        pd[0], pd[1] = fp[o] + r * c, fp[o + 1] + r * s
        vd[0], vd[1] = rw * -s, rw * c
        ad[0], ad[1] = rww * c, rww * s
    else:
        dur, delay = fp[o + 4], fp[o + 5]
        tau = min(max((t - delay) / dur, 0.0), 1.0)
        s = math.pow(tau, 3.0) * (10.0 - 15.0 * tau + 6.0 * tau * tau)
        ds = 30.0 * tau * tau * math.pow(1.0 - tau, 2.0) / dur
        dds = 60.0 * tau * (1.0 - tau) * (1.0 - 2.0 * tau) / math.pow(dur, 2.0)
        for a in range(2):
            d = fp[o + 2 + a] - fp[o + a]
            pd[a] = fp[o + a] + s * d
            vd[a] = ds * d
            ad[a] = dds * d


@njit(**_JIT)
def end_point_kinematics(mi, mf, q, v, body, E, J, Jdv, R):
    """World position E (3,), Jacobian J (3, nv), ``J̇ v`` (3,) and orientation R (3, 3) of a body's
    origin (:func:`robodyn_ros.systems.prescribed.end_point_kinematics`; 1-DOF joints)."""
    W = workspace(mi.shape[0])
    transforms(mi, mf, q, W)
    end_point_kinematics_ws(mi, mf, q, v, body, W, E, J, Jdv, R)


@njit(**_JIT)
def end_point_kinematics_ws(mi, mf, q, v, body, W, E, J, Jdv, R):
    """:func:`end_point_kinematics` with the transforms already in W (only their columns are read)."""
    nb = mi.shape[0]
    Rb = np.empty((nb, 3, 3))
    pb = np.empty((nb, 3))
    body_frames(mi, mf, q, W, Rb, pb)
    vb = np.empty((nb, 6))
    ab = np.empty((nb, 6))
    vJ = np.empty(6)
    for i in range(nb):
        par = mi[i, PARENT]
        joint_motion_vector(mi, mf, v, i, vJ)
        if par < 0:
            for a in range(6):
                vb[i, a] = vJ[a]
                ab[i, a] = 0.0
        else:
            xmot_vector(W, i, vb[par], vb[i])
            xmot_vector(W, i, ab[par], ab[i])
            for a in range(6):
                vb[i, a] += vJ[a]
            # + crm(v_i) vJ = [ω × vJ_ω; ω × vJ_v + v_v × vJ_ω]
            w0, w1, w2 = vb[i, 0], vb[i, 1], vb[i, 2]
            u0, u1, u2 = vb[i, 3], vb[i, 4], vb[i, 5]
            a0, a1, a2 = vJ[0], vJ[1], vJ[2]
            b0, b1, b2 = vJ[3], vJ[4], vJ[5]
            ab[i, 0] += w1 * a2 - w2 * a1
            ab[i, 1] += w2 * a0 - w0 * a2
            ab[i, 2] += w0 * a1 - w1 * a0
            ab[i, 3] += (w1 * b2 - w2 * b1) + (u1 * a2 - u2 * a1)
            ab[i, 4] += (w2 * b0 - w0 * b2) + (u2 * a0 - u0 * a2)
            ab[i, 5] += (w0 * b1 - w1 * b0) + (u0 * a1 - u1 * a0)
    for a in range(3):
        E[a] = pb[body, a]
        for b in range(3):
            R[a, b] = Rb[body, a, b]
    for a in range(3):
        for c in range(J.shape[1]):
            J[a, c] = 0.0
    d = np.empty(3)
    ra = np.empty(3)
    t = np.empty(3)
    i = body
    while i >= 0:
        jt = mi[i, JTYPE]
        if jt == REVOLUTE or jt == PRISMATIC:
            s0 = mi[i, VIDX]
            for a in range(3):
                ra[a] = Rb[i, a, 0] * mf[i, AX] + Rb[i, a, 1] * mf[i, AX + 1] + Rb[i, a, 2] * mf[i, AX + 2]
            if jt == PRISMATIC:
                for a in range(3):
                    J[a, s0] = ra[a]
            else:
                for a in range(3):
                    d[a] = E[a] - pb[i, a]
                cross(ra, d, t)
                for a in range(3):
                    J[a, s0] = t[a]
        i = mi[i, PARENT]
    for a in range(3):
        t[a] = ab[body, 3 + a]
    t[0] += vb[body, 1] * vb[body, 5] - vb[body, 2] * vb[body, 4]
    t[1] += vb[body, 2] * vb[body, 3] - vb[body, 0] * vb[body, 5]
    t[2] += vb[body, 0] * vb[body, 4] - vb[body, 1] * vb[body, 3]
    for a in range(3):
        Jdv[a] = R[a, 0] * t[0] + R[a, 1] * t[1] + R[a, 2] * t[2]


@njit(**_JIT)
def complement_solve(A, f, B, k, tol, a, lam, info):
    """Huston's orthogonal-complement route (:func:`robodyn_ros.constraints.complement_solve`).

    C = eigenvectors of the (relatively) zero eigenvalues of ``BᵀB``; ``[CᵀA; B] a = [Cᵀf; k]``
    (LU with partial pivoting when square, else the minimum-norm least-squares solution through
    the normal equations — the rank-deficient case, which the prescribed-path system never
    reaches: it switches to damped least squares first); ``λ = (BBᵀ)⁺ B (A a − f)`` with the
    ``tol`` cut-off; singular values of B (two rows) for the info.
    """
    n = A.shape[0]
    m = B.shape[0]
    BtB = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            s = 0.0
            for r in range(m):
                s += B[r, i] * B[r, j]
            BtB[i, j] = s
    w = np.empty(n)
    V = np.empty((n, n))
    sym_eig(BtB, w, V)
    wmax = 0.0
    for j in range(n):
        wmax = max(wmax, w[j])
    nz = 0
    for j in range(n):
        if not (wmax > 0.0) or w[j] <= tol * wmax:
            nz += 1
    rank = n - nz
    Qr = np.empty((nz + m, n))
    h = np.empty(nz + m)
    r = 0
    for j in range(n):
        if not (wmax > 0.0) or w[j] <= tol * wmax:
            for c in range(n):
                s = 0.0
                for e in range(n):
                    s += V[e, j] * A[e, c]
                Qr[r, c] = s
            s = 0.0
            for e in range(n):
                s += V[e, j] * f[e]
            h[r] = s
            r += 1
    for i in range(m):
        for c in range(n):
            Qr[nz + i, c] = B[i, c]
        h[nz + i] = k[i]
    if rank == m:
        lu_solve(Qr, h, a)
    else:
        N = np.empty((n, n))
        g = np.empty(n)
        for i in range(n):
            s = 0.0
            for e in range(nz + m):
                s += Qr[e, i] * h[e]
            g[i] = s
            for j in range(n):
                s = 0.0
                for e in range(nz + m):
                    s += Qr[e, i] * Qr[e, j]
                N[i, j] = s
        pinv_solve(N, g, EPS * max(nz + m, n), a)
    BBt = np.empty((m, m))
    rhs = np.empty(m)
    res = np.empty(n)
    for c in range(n):
        s = 0.0
        for e in range(n):
            s += A[c, e] * a[e]
        res[c] = s - f[c]
    for i in range(m):
        s = 0.0
        for c in range(n):
            s += B[i, c] * res[c]
        rhs[i] = s
        for j in range(m):
            s = 0.0
            for c in range(n):
                s += B[i, c] * B[j, c]
            BBt[i, j] = s
    pinv_solve(BBt, rhs, tol, lam)
    sv = np.empty(2)
    singular_values_2(B, sv)
    info[0] = rank
    info[1] = sv[1]
    info[2] = sv[0]
    r2 = 0.0
    for i in range(m):
        s = 0.0
        for c in range(n):
            s += B[i, c] * a[c]
        r2 = max(r2, abs(s - k[i]))
    info[3] = r2


@njit(**_JIT)
def pr_solve(ip, fp, mi, mf, mi_r, mf_r, u, t, y, a, lam, Bm, phi, phidot, E, R, tau, rec):
    """The constrained accelerations and driving force at (t, y) (``PrescribedPathSystem.solve``).

    Fills a (n,), lam (2,), Bm (2, n), phi, phidot (2,), E (3,), R (3, 3), tau (n,) and the
    record rec (NPS,) (module layout). Returns OK or SINGULAR.
    """
    n = a.shape[0]
    q = y[:n]
    v = y[n:2 * n]
    for j in range(n):
        tau[j] = -fp[PF_DAMPING + j] * v[j]
    if ip[PR_HAS_EFFORT]:
        for j in range(n):
            tau[j] = tau[j] + u[j]
    W = workspace(mi.shape[0])  # one set of transforms (full tree) for RNEA, CRBA and the end point
    transforms(mi, mf, q, W)
    hb = np.empty(n)
    rnea_ws(mi, mf, q, v, np.zeros(n), W, flag(0), hb, W)
    A = np.zeros((n, n))
    crba_ws(mi, mf, A, W)
    f = np.empty(n)
    for j in range(n):
        f[j] = tau[j] - hb[j]
    J = np.empty((3, n))
    Jdv = np.empty(3)
    end_point_kinematics_ws(mi, mf, q, v, ip[PR_BODY], W, E, J, Jdv, R)
    pd = np.empty(2)
    vd = np.empty(2)
    ad = np.empty(2)
    path_eval(ip, fp, t, pd, vd, ad)
    k = np.empty(2)
    two_alpha = 2.0 * fp[PF_ALPHA]
    b2 = fp[PF_BETA] * fp[PF_BETA]
    for r in range(2):
        p0, p1, p2 = fp[PF_P + 3 * r], fp[PF_P + 3 * r + 1], fp[PF_P + 3 * r + 2]
        for c in range(n):
            Bm[r, c] = p0 * J[0, c] + p1 * J[1, c] + p2 * J[2, c]
        phi[r] = (p0 * E[0] + p1 * E[1] + p2 * E[2]) - pd[r]
        s = 0.0
        for c in range(n):
            s += Bm[r, c] * v[c]
        phidot[r] = s - vd[r]
        k[r] = ad[r] - (p0 * Jdv[0] + p1 * Jdv[1] + p2 * Jdv[2])
        k[r] = k[r] - two_alpha * phidot[r] - b2 * phi[r]
    sv = np.empty(2)
    singular_values_2(Bm, sv)
    sr = fp[PF_SR]
    ratio = sv[1] / sv[0] if sv[0] > 0.0 else 0.0
    rank = 0
    if sv[0] > 0.0:
        for s in sv:
            if s > sr * sv[0]:
                rank += 1
    damping = 0.0
    info = rec[PS_INFO:PS_INFO + NINFO]
    if ratio < sr:
        L = np.empty((n, n))
        if not cholesky(A, n, L):
            return SINGULAR if all_finite(A) else OK
        X = np.empty((2, n))
        for r in range(2):
            chol_solve(L, n, Bm[r], X[r])
        S = np.empty((2, 2))
        for r in range(2):
            for c in range(2):
                acc = 0.0
                for e in range(n):
                    acc += Bm[r, e] * X[c, e]
                S[r, c] = acc
        # eigvalsh reads the lower triangle
        S[0, 1] = S[1, 0]
        ws = np.empty(2)
        Vs = np.empty((2, 2))
        sym_eig(S, ws, Vs)
        wmax = max(ws[0], ws[1])
        damping = fp[PF_DLS] * wmax * (1.0 - math.pow(ratio / sr, 2.0))
        st = kkt_solve(A, n, f, Bm, k, fp[PF_RCOND], damping, flag(1), a, lam, info)
        method = METHOD_KKT_DAMPED
    elif ip[PR_FORM] == METHOD_COMPLEMENT:
        complement_solve(A, f, Bm, k, fp[PF_TOL], a, lam, info)
        st = OK
        method = METHOD_COMPLEMENT
    else:
        st = kkt_solve(A, n, f, Bm, k, fp[PF_RCOND], 0.0, flag(1), a, lam, info)
        method = METHOD_KKT
    rec[PS_RATIO] = ratio
    rec[PS_RANK] = rank
    rec[PS_DAMPING] = damping
    rec[PS_METHOD] = method
    return st


@njit(**_JIT)
def pr_evaluate(ip, fp, mi, mf, mi_r, mf_r, u, t, z, dz, stat):
    """``dz = [q̇; q̈; power]`` (``PrescribedPathSystem.rhs`` and ``.input_power``); counts
    singular evaluations in stat ``[count, t of the first, its ratio, its damping]``."""
    n = (z.shape[0] - 1) // 2
    y = z[:2 * n]
    for x in y:
        if not math.isfinite(x):
            dz[:] = np.nan
            return OK
    lam = np.empty(2)
    Bm = np.empty((2, n))
    phi = np.empty(2)
    phidot = np.empty(2)
    E = np.empty(3)
    R = np.empty((3, 3))
    tau = np.empty(n)
    rec = np.empty(NPS)
    st = pr_solve(ip, fp, mi, mf, mi_r, mf_r, u, t, y, dz[n:2 * n], lam, Bm, phi, phidot, E, R, tau, rec)
    if rec[PS_RANK] < 2:
        if stat[0] == 0:
            stat[1] = t
            stat[2] = rec[PS_RATIO]
            stat[3] = rec[PS_DAMPING]
        stat[0] += 1
    P = 0.0
    for j in range(n):
        dz[j] = z[n + j]
        P += z[n + j] * tau[j]
    for r in range(2):
        s = 0.0
        for c in range(n):
            s += Bm[r, c] * z[n + c]
        P += lam[r] * s
    dz[2 * n] = P
    return st
