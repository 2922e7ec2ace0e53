"""Rigid-body dynamics on ``(model, q, v)``: RNEA, CRBA, ABA, joint wrenches, energy, momentum.

These are the reference kernels (for revolute, prismatic, fixed and free joints; a model with a
spherical joint is refused with ``model.SphericalJointError`` — the compiled kernels of
:mod:`robodyn_ros.kernels` are its only implementation): plain numpy on the model's arrays, book notation
(Featherstone 2008: ``Xup, S, vJ, c, IC, IA, pA, U, d, u``), one loop per pass and no per-body
Python objects, so that they can be compiled without a rewrite. Shapes:

* ``q`` (nq,), ``v`` (nv,), ``a``/``qdd`` (nv,), ``tau`` (nv,);
* ``f_ext`` (nb, 6): external spatial forces on each body, in that body's coordinates;
* returned body quantities are (nb, 6) in body coordinates unless the name says ``_world``.

Gravity enters as a fictitious base acceleration ``a0 = -[0; g]`` (book §5.3), so the joint
wrenches and torques include it. A joint's armature ``a`` (``Model.armature``, rotor inertia reflected
to the joint) enters the joint space only: ``M + diag(a)``, ``τ += a q̈``, ABA's ``D += a``, kinetic
energy ``+ ½ a q̇²``; never a body wrench.
"""
from __future__ import annotations

import numpy as np

from .model import FREE, Model, jcalc, refuse_spherical
from .spatial import crf, crm, inertia_parts, quat_exp, quat_mul, quat_to_R, xinv

__all__ = ['joint_transforms', 'rnea', 'rnea_wrenches', 'crba', 'bias_forces', 'aba', 'fd_crba',
           'forward_dynamics', 'joint_wrenches', 'forward_kinematics', 'body_poses', 'body_velocities',
           'kinetic_energy', 'potential_energy', 'spatial_momentum', 'center_of_mass', 'qdot',
           'integrate_configuration', 'passive_forces']


def joint_transforms(model: Model, q):
    """Per-body ``Xup`` (nb, 6, 6) parent->body and the stacked motion subspace.

    model: the tree; q: (nq,) configuration. Returns ``(Xup, S)`` where ``S`` (6, nv) holds
    every joint's subspace columns in its own body coordinates (column block ``v_idx[i]``).
    """
    refuse_spherical(model, 'joint_transforms')
    nb = model.nb
    Xup = np.empty((nb, 6, 6))
    S = np.zeros((6, model.nv))
    for i in range(nb):
        qi = model.q_idx[i]
        XJ, Si = jcalc(model.jtype[i], model.axis[i], q[qi:qi + model.nq_j[i]])
        Xup[i] = XJ @ model.Xtree[i]
        vi = model.v_idx[i]
        S[:, vi:vi + model.nv_j[i]] = Si
    return Xup, S


def _a0(model: Model):
    """Fictitious base acceleration that models uniform gravity: ``-[0; g]``."""
    a0 = np.zeros(6)
    a0[3:] = -model.gravity
    return a0


def rnea_wrenches(model: Model, q, v, a, f_ext=None):
    """Recursive Newton–Euler inverse dynamics (book Table 5.1), keeping the joint wrenches.

    model, q (nq,), v (nv,), a (nv,): state and generalised acceleration; f_ext: optional
    (nb, 6) external forces in body coordinates. Returns ``(tau (nv,), f (nb, 6))`` where
    ``f[i]`` is the spatial force the parent exerts on body i through joint i, at body i's
    origin (on the joint axis), in body i coordinates: ``tau_i = S_i^T f[i]``.
    """
    nb = model.nb
    Xup, S = joint_transforms(model, q)
    vb = np.empty((nb, 6))
    ab = np.empty((nb, 6))
    f = np.empty((nb, 6))
    a0 = _a0(model)
    for i in range(nb):
        s0, s1 = model.v_idx[i], model.v_idx[i] + model.nv_j[i]
        Si = S[:, s0:s1]
        vJ = Si @ v[s0:s1]
        p = model.parent[i]
        if p < 0:
            vb[i] = vJ
            ab[i] = Xup[i] @ a0 + Si @ a[s0:s1]
        else:
            vb[i] = Xup[i] @ vb[p] + vJ
            ab[i] = Xup[i] @ ab[p] + Si @ a[s0:s1] + crm(vb[i]) @ vJ
        Ii = model.I[i]
        f[i] = Ii @ ab[i] + crf(vb[i]) @ (Ii @ vb[i])
        if f_ext is not None:
            f[i] -= f_ext[i]
    tau = model.armature * a   # the rotors' share; f stays the wrench through the links
    for i in range(nb - 1, -1, -1):
        s0, s1 = model.v_idx[i], model.v_idx[i] + model.nv_j[i]
        tau[s0:s1] += S[:, s0:s1].T @ f[i]
        p = model.parent[i]
        if p >= 0:
            f[p] += Xup[i].T @ f[i]
    return tau, f


def rnea(model: Model, q, v, a, f_ext=None):
    """Inverse dynamics ``tau = M(q) a + h(q, v)`` (nv,); see :func:`rnea_wrenches`."""
    return rnea_wrenches(model, q, v, a, f_ext)[0]


def bias_forces(model: Model, q, v, f_ext=None):
    """Coriolis, centrifugal and gravity forces ``h(q, v)`` (nv,) = RNEA with zero acceleration."""
    return rnea(model, q, v, np.zeros(model.nv), f_ext)


def crba(model: Model, q):
    """Joint-space inertia matrix ``M(q)`` (nv, nv) by the composite-rigid-body algorithm (Table 6.2).

    model: the tree; q: (nq,) configuration.
    """
    nb = model.nb
    Xup, S = joint_transforms(model, q)
    IC = model.I.copy()
    for i in range(nb - 1, -1, -1):
        p = model.parent[i]
        if p >= 0:
            IC[p] += Xup[i].T @ IC[i] @ Xup[i]
    H = np.zeros((model.nv, model.nv))
    for i in range(nb):
        s0, s1 = model.v_idx[i], model.v_idx[i] + model.nv_j[i]
        if s1 == s0:
            continue
        F = IC[i] @ S[:, s0:s1]
        H[s0:s1, s0:s1] = S[:, s0:s1].T @ F
        j = i
        while model.parent[j] >= 0:
            F = Xup[j].T @ F
            j = model.parent[j]
            t0, t1 = model.v_idx[j], model.v_idx[j] + model.nv_j[j]
            H[s0:s1, t0:t1] = F.T @ S[:, t0:t1]
            H[t0:t1, s0:s1] = H[s0:s1, t0:t1].T
    return H + np.diag(model.armature)


def aba(model: Model, q, v, tau, f_ext=None):
    """Forward dynamics by the articulated-body algorithm (book Table 7.1), O(nb).

    model, q (nq,), v (nv,), tau (nv,) generalised forces; f_ext: optional (nb, 6) external
    forces in body coordinates. Returns ``qdd`` (nv,).
    """
    nb = model.nb
    Xup, S = joint_transforms(model, q)
    vb = np.empty((nb, 6))
    c = np.empty((nb, 6))
    IA = model.I.copy()
    pA = np.empty((nb, 6))
    for i in range(nb):
        s0, s1 = model.v_idx[i], model.v_idx[i] + model.nv_j[i]
        vJ = S[:, s0:s1] @ v[s0:s1]
        p = model.parent[i]
        if p < 0:
            vb[i] = vJ
            c[i] = 0.0
        else:
            vb[i] = Xup[i] @ vb[p] + vJ
            c[i] = crm(vb[i]) @ vJ
        pA[i] = crf(vb[i]) @ (model.I[i] @ vb[i])
        if f_ext is not None:
            pA[i] -= f_ext[i]
    U = [None] * nb
    Dinv = [None] * nb
    u = [None] * nb
    for i in range(nb - 1, -1, -1):
        s0, s1 = model.v_idx[i], model.v_idx[i] + model.nv_j[i]
        p = model.parent[i]
        if s1 > s0:
            Si = S[:, s0:s1]
            U[i] = IA[i] @ Si
            Dinv[i] = np.linalg.inv(Si.T @ U[i] + np.diag(model.armature[s0:s1]))
            u[i] = tau[s0:s1] - Si.T @ pA[i]
            Ia = IA[i] - U[i] @ Dinv[i] @ U[i].T
            pa = pA[i] + Ia @ c[i] + U[i] @ (Dinv[i] @ u[i])
        else:
            Ia = IA[i]
            pa = pA[i] + Ia @ c[i]
        if p >= 0:
            IA[p] += Xup[i].T @ Ia @ Xup[i]
            pA[p] += Xup[i].T @ pa
    qdd = np.empty(model.nv)
    ab = np.empty((nb, 6))
    a0 = _a0(model)
    for i in range(nb):
        s0, s1 = model.v_idx[i], model.v_idx[i] + model.nv_j[i]
        p = model.parent[i]
        ap = Xup[i] @ (a0 if p < 0 else ab[p]) + c[i]
        if s1 > s0:
            qdd[s0:s1] = Dinv[i] @ (u[i] - U[i].T @ ap)
            ab[i] = ap + S[:, s0:s1] @ qdd[s0:s1]
        else:
            ab[i] = ap
    return qdd


def fd_crba(model: Model, q, v, tau, f_ext=None):
    """Forward dynamics by CRBA + Cholesky: solve ``M qdd = tau - h`` (an independent route to ABA).

    Same arguments and result as :func:`aba`.
    """
    from scipy.linalg import cho_factor, cho_solve
    H = crba(model, q)
    h = bias_forces(model, q, v, f_ext)
    return cho_solve(cho_factor(H), tau - h)


forward_dynamics = aba


def passive_forces(model: Model, v):
    """Generalised forces of the passive joint elements: viscous damping ``-D v`` (nv,).

    These are the Rayleigh-dissipation forces of the free-flying-base seed, ``-dR/dv`` with
    ``R = ½ vᵀ D v``.
    """
    return -model.damping * v


def joint_wrenches(model: Model, q, v, tau, f_ext=None):
    """Accelerations and transmitted joint wrenches under applied forces ``tau``.

    Returns ``(qdd (nv,), f (nb, 6))``: forward dynamics, then the RNEA backward pass at that
    acceleration (see :func:`rnea_wrenches` for the wrench convention).
    """
    qdd = aba(model, q, v, tau, f_ext)
    return qdd, rnea_wrenches(model, q, v, qdd, f_ext)[1]


def forward_kinematics(model: Model, q):
    """Root-to-body transforms ``X0`` (nb, 6, 6): motion vectors from root to body coordinates."""
    Xup, _ = joint_transforms(model, q)
    X0 = np.empty_like(Xup)
    for i in range(model.nb):
        p = model.parent[i]
        X0[i] = Xup[i] if p < 0 else Xup[i] @ X0[p]
    return X0


def body_poses(model: Model, q):
    """World poses of the body frames: ``(R (nb, 3, 3), p (nb, 3))`` in the root frame."""
    X0 = forward_kinematics(model, q)
    R = np.transpose(X0[:, :3, :3], (0, 2, 1))
    p = np.empty((model.nb, 3))
    for i in range(model.nb):
        P = -R[i] @ X0[i][3:, :3]  # X[3:, :3] = -E r×  =>  r× = -E^T X[3:, :3]
        p[i] = (P[2, 1], P[0, 2], P[1, 0])
    return R, p


def body_velocities(model: Model, q, v):
    """Spatial velocities of all bodies (nb, 6) in body coordinates."""
    Xup, S = joint_transforms(model, q)
    vb = np.empty((model.nb, 6))
    for i in range(model.nb):
        s0, s1 = model.v_idx[i], model.v_idx[i] + model.nv_j[i]
        vJ = S[:, s0:s1] @ v[s0:s1]
        p = model.parent[i]
        vb[i] = vJ if p < 0 else Xup[i] @ vb[p] + vJ
    return vb


def kinetic_energy(model: Model, q, v):
    """Kinetic energy ``½ Σ v_iᵀ I_i v_i + ½ Σ a q̇²`` (J; the second sum: the rotors, armature a)."""
    vb = body_velocities(model, q, v)
    v = np.asarray(v, dtype=float)
    return 0.5 * float(np.einsum('ni,nij,nj->', vb, model.I, vb)) + 0.5 * float(model.armature @ (v * v))


def center_of_mass(model: Model, q):
    """Centre of mass of the whole tree (3,) in the root frame, and the total mass."""
    R, p = body_poses(model, q)
    mtot, acc = 0.0, np.zeros(3)
    for i in range(model.nb):
        m, c, _ = inertia_parts(model.I[i])
        acc += m * (p[i] + R[i] @ c)
        mtot += m
    return (acc / mtot if mtot > 0 else acc), mtot


def potential_energy(model: Model, q):
    """Gravitational potential energy ``-Σ m_i gᵀ c_i`` (J), zero at the root origin."""
    com, m = center_of_mass(model, q)
    return -m * float(model.gravity @ com)


def spatial_momentum(model: Model, q, v):
    """Total spatial momentum ``[angular about the root origin; linear]`` (6,) in root coordinates."""
    X0 = forward_kinematics(model, q)
    vb = body_velocities(model, q, v)
    h = np.zeros(6)
    for i in range(model.nb):
        h += X0[i].T @ (model.I[i] @ vb[i])  # force transform body->root is X0^T
    return h


def qdot(model: Model, q, v):
    """Configuration rate ``dq/dt`` (nq,) from the velocity ``v`` (nv,).

    For 1-DOF joints it is v itself. For a free joint, ``v = [w; v]`` in body coordinates gives
    ``ṗ = R v`` and the quaternion rate ``½ q ⊗ [w; 0]``.
    """
    if model.nq == model.nv:
        return np.array(v, dtype=float)
    refuse_spherical(model, 'qdot')
    qd = np.empty(model.nq)
    for i in range(model.nb):
        q0, v0 = model.q_idx[i], model.v_idx[i]
        if model.jtype[i] == FREE:
            quat = q[q0 + 3:q0 + 7]
            qd[q0:q0 + 3] = quat_to_R(quat) @ v[v0 + 3:v0 + 6]
            w = np.array([v[v0], v[v0 + 1], v[v0 + 2], 0.0])
            qd[q0 + 3:q0 + 7] = 0.5 * quat_mul(quat, w)
        else:
            qd[q0:q0 + model.nq_j[i]] = v[v0:v0 + model.nv_j[i]]
    return qd


def integrate_configuration(model: Model, q, v, dt):
    """``q ⊕ v dt`` on the configuration manifold (nq,): exact exponential map for quaternions.

    Free joints move by the body-frame twist held constant over ``dt`` (position with the
    rotation at the start of the step, first order), quaternions are multiplied by
    ``exp(w dt)`` and renormalised; other joints add ``v dt``.
    """
    refuse_spherical(model, 'integrate_configuration')
    qn = np.array(q, dtype=float)
    for i in range(model.nb):
        q0, v0 = model.q_idx[i], model.v_idx[i]
        if model.jtype[i] == FREE:
            quat = q[q0 + 3:q0 + 7]
            qn[q0:q0 + 3] += quat_to_R(quat) @ v[v0 + 3:v0 + 6] * dt
            nq = quat_mul(quat, quat_exp(v[v0:v0 + 3] * dt))
            qn[q0 + 3:q0 + 7] = nq / np.linalg.norm(nq)
        else:
            qn[q0:q0 + model.nq_j[i]] += v[v0:v0 + model.nv_j[i]] * dt
    return qn


def normalize_configuration(model: Model, q):
    """Renormalise the quaternions of free joints in ``q`` (nq,); a projection onto the manifold."""
    if model.nq == model.nv:
        return q
    refuse_spherical(model, 'normalize_configuration')
    q = np.array(q, dtype=float)
    for i in range(model.nb):
        if model.jtype[i] == FREE:
            s = model.q_idx[i] + 3
            q[s:s + 4] /= np.linalg.norm(q[s:s + 4])
    return q


def xinv_all(X):
    """Inverse transforms for a stack (n, 6, 6) (helper for callers that need body->root)."""
    return np.stack([xinv(x) for x in X])
