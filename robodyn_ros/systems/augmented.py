"""The free-flying base + arm in the seed's augmented formulation (extended coordinates, multipliers).

Seed 003 (Unfried, da Fonseca & Goes, 2016) writes the platform-plus-arm dynamics on a
redundant set of coordinates — the platform pose, the joint angles and the position of every
link's centre of mass — tied together by the joint-connection constraints ``C(q) = 0``; the
multipliers are the joint reaction forces. This module is that formulation for any tree whose
root joint is FREE and whose other joints are revolute (or fixed), with the one change the
GUIDE asks for: the platform's attitude is a unit quaternion, never Euler/Bryan angles, and its
rate an angular velocity.

Coordinates (``nb`` bodies, body 0 = platform, ``nj`` revolute joints)::

    x = [quat (4) platform attitude (x, y, z, w) | θ (nj) joint angles | c (3 nb) CoMs in world]
    w = [ω (3) platform angular velocity, body axes | θ̇ (nj) | ċ (3 nb) CoM velocities, world]

For the seed's robot (platform + 5 links): w has 3 + 5 + 18 = 26 entries, the seed's 26
coordinates (6 platform, 5 angles, 15 link CoMs); x has 27 (the quaternion's 4 for 3 angles).

Derivation (Kane's / Jourdain's principle; it is Lagrange's equations of the seed, eq. (25),
written with the angular-velocity quasi-coordinates that a quaternion needs).

*Kinematics.* Body i's orientation follows from the platform attitude and the angles only:
``R_i = R_p E_iᵀ`` with ``E_i = (R_tree,i Rot(a_i, θ_i))ᵀ`` (parent → child coordinate
rotation). Its angular velocity in its own coordinates is linear in the rotational rates
``w_r = [ω; θ̇]``::

    ω_i = E_i ω_p + a_i θ̇_i = J_i w_r,     J_0 = [I₃ 0],  J_i = E_i J_p + a_i e_iᵀ
    ω̇_i = J_i ẇ_r + β_i,                   β_i = E_i β_p + (E_i ω_p) × (a_i θ̇_i)

(``Ė_i = −[a_i θ̇_i]× E_i``). The CoM velocities ċ_i are coordinates of their own.

*Kinetic energy* (seed eqs. (16)–(20), translational part about the CoMs, not rotated)::

    T = ½ Σ m_i ċ_iᵀ ċ_i + ½ Σ ω_iᵀ I_ci ω_i = ½ wᵀ M(x) w
    M = blockdiag( Σ J_iᵀ I_ci J_i ,  m_0 I₃, …, m_{nb−1} I₃ )

*Equations of motion.* The generalised inertia force of body i's rotation on the rates is
``J_iᵀ (I_ci ω̇_i + ω_i × I_ci ω_i)`` (Euler's equations projected by the partial angular
velocities J_i); of its translation on ċ_i, ``m_i c̈_i``. Hence, with the constraint forces
``C_qᵀ λ``::

    M ẇ = Q_e + Q_v + Q_p + Q_f + C_qᵀ λ
    Q_v = −Σ J_iᵀ (I_ci β_i + ω_i × I_ci ω_i)        (Coriolis, centrifugal, gyroscopic: seed (45))
    Q_p = [0; 0; m_i g]                               (gravity on every CoM: −∂V/∂c_i, seed (21), (46))
    Q_f = [0; −D θ̇; 0]                                (Rayleigh dissipation of the joints, seed (22), (47))
    Q_e = [τ_c; τ_arm; R_0 f_b on ċ_0]                (thrusters: force f_b at the base_link origin,
                                                         τ_c = τ_b − com_0 × f_b about the platform CoM)

(The seed writes ``+C_qᵀλ`` on the left with ``C = parent − child``; we put ``+C_qᵀλ`` on
the right with ``C = child − parent`` — the same λ, see below.)

*Constraints.* Joint i joins body i to its parent p at the joint origin, which is ``s_p,i =
r_i − com_p`` from the parent's CoM (parent axes) and ``s_c,i = −com_i`` from the child's::

    C_i(x) = (c_i + R_i s_c,i) − (c_p + R_p s_p,i) = 0                  (3 rows per joint)
    Ċ_i = ċ_i − ċ_p − R_i [s_c]× J_i w_r + R_p [s_p]× J_p w_r = C_q w
    C̈_i = C_q ẇ + R_i (β_i × s_c + ω_i × (ω_i × s_c)) − R_p (β_p × s_p + ω_p × (ω_p × s_p))

so ``C_q ẇ = Q_d`` with ``Q_d = −(the last two terms)`` (the seed's eq. (50), ``−(C_q q̇)_q q̇``).
On the air-bearing table the three platform rows of
:func:`robodyn_ros.systems.freeflyer.table_rows` are appended. Drift is held by Baumgarte
stabilisation ``Q_d − 2α Ċ − β² C`` (named gains ``alpha``, ``beta``), or removed after every
accepted step by projection (``stabilisation='projection'``): the CoMs move by the smallest
mass-weighted correction onto ``C = 0``
(:func:`robodyn_ros.constraints.project_positions`, which leaves the system's CoM where it is)
and the velocities by :func:`robodyn_ros.constraints.project_velocities`.

*The augmented system* (seed eq. (48))::

    [ M    C_qᵀ ] [ ẇ  ]   [ Q_e + Q_v + Q_p + Q_f ]
    [ C_q  0    ] [ −λ ] = [ Q_d                   ]

is solved by :func:`robodyn_ros.constraints.kkt_solve` (Cholesky of M, then the Schur
complement ``C_q M⁻¹ C_qᵀ`` by an eigen-decomposition that reports its rank; a rank loss is
reported in ``extra['constraint_rank']``).

*Multipliers = joint reaction forces.* ``C_qᵀ λ_i`` puts ``+λ_i`` on ċ_i and ``−λ_i`` on ċ_p,
and on the rotations the moments of those forces about the CoMs: λ_i is the force the parent
exerts on the child through joint i, in world coordinates — the force part of the transmitted
wrench of the minimal formulation (``R_i f_i[3:]``). The moment part is not a multiplier here
(the joint angle parametrises the rotation, so the two bending moments are workless and never
appear); for ``constraint_wrenches/<joint>`` it is recovered from the Euler equations of each
body, leaves first::

    n_i = I_ci ω̇_i + ω_i × I_ci ω_i − s_c,i × f_i + Σ_children j (E_jᵀ n_j + (r_j − com_i) × E_jᵀ f_j)

(moments about joint i's origin, f_i = R_iᵀ λ_i, child axes); its component on the axis is the
joint torque, a check the tests make.
"""
from __future__ import annotations

import numpy as np

from .. import constraints as con
from .. import dynamics as dyn
from .. import kernels
from ..model import FIXED, REVOLUTE, Model, ModelError
from ..spatial import inertia_parts, quat_mul, quat_to_R, rot_axis, skew
from .base import SystemOutputs
from .freeflyer import _cross, _FreeBaseCommon, level_quaternion, momentum_about_com, table_rows

__all__ = ['AugmentedFreeFlyerSystem']


_I3 = np.eye(3)


class AugmentedFreeFlyerSystem(_FreeBaseCommon):
    """Free-flying base + arm on extended coordinates with Lagrange multipliers.

    State ``y = [x (nq), w (nv)]`` with the layout of the module docstring (nq = 4 + nj + 3 nb,
    nv = 3 + nj + 3 nb). Constructor arguments as :class:`~robodyn_ros.systems.freeflyer.FreeFlyerSystem`;
    the model must have positive masses and a joint-space rotational inertia that is positive
    definite (no link whose rotational inertia about its own joint axis vanishes with its
    whole subtree). :meth:`from_minimal` / :meth:`minimal` convert states between the two
    formulations; :meth:`initial_state` takes minimal coordinates.
    """

    formulation = 'augmented'
    _COMPILED_METHODS = ('rhs', 'input_power', 'project', 'config_rate', 'solve', '_kinematics', '_constraints',
                         '_base_wrench', 'arm_torques', '_momentum', '_energies')

    def __init__(self, model: Model, **kw):
        super().__init__(model, **kw)
        nb = model.nb
        for i in range(1, nb):
            if model.jtype[i] not in (REVOLUTE, FIXED):
                raise ModelError(f'joint {model.joint_names[i]!r}: the augmented formulation handles revolute and '
                                 'fixed joints only (use formulation: minimal)')
        self.nb = nb
        self.nj = self.n_arm
        self.nr = 3 + self.nj
        self.nq = 4 + self.nj + 3 * nb
        self.nv = self.nr + 3 * nb
        self.ny = self.nq + self.nv
        self.initial_state_sizes = (model.nq, model.nv)  # initial_state() takes minimal coordinates
        self.m = np.empty(nb)
        self.com = np.empty((nb, 3))
        self.Ic = np.empty((nb, 3, 3))
        for i in range(nb):
            self.m[i], self.com[i], self.Ic[i] = inertia_parts(model.I[i])
            if not self.m[i] > 0.0:
                raise ModelError(f'link {model.link_names[i]!r}: the augmented formulation needs a positive mass '
                                 '(its CoM is a coordinate)')
        self.Etree = model.Xtree[:, :3, :3].copy()
        self.r = np.empty((nb, 3))  # joint origin in parent coordinates
        for i in range(nb):
            P = -self.Etree[i].T @ model.Xtree[i][3:, :3]
            self.r[i] = (P[2, 1], P[0, 2], P[1, 0])
        self.dof = np.full(nb, -1)  # column of θ
        for i in range(1, nb):
            if model.jtype[i] == REVOLUTE:
                self.dof[i] = model.q_idx[i] - 7
        self.children = [[j for j in range(nb) if model.parent[j] == i] for i in range(nb)]
        self.n_joint_rows = 3 * (nb - 1)
        self.n_constraints = self.n_joint_rows + (3 if self.table else 0)
        self.has_constraints = self.n_constraints > 0
        # slices of x and w
        self.sq, self.sth, self.sc = slice(0, 4), slice(4, 4 + self.nj), slice(4 + self.nj, self.nq)
        self.sw, self.sthd, self.scd = slice(0, 3), slice(3, self.nr), slice(self.nr, self.nv)
        self._compiled_class = AugmentedFreeFlyerSystem
        if self.backend != 'numpy':
            stab = {'baumgarte': 0, 'projection': 1, 'none': 2}[self.stabilisation]
            ip = [nb, self.nj, int(self.table), stab, self.n_constraints, 0, 0, 0] + list(model.parent) + list(self.dof)
            fp = [self.alpha, self.beta, 0.0 if self.table_height is None else self.table_height, con.KKT_RCOND,
                  *model.gravity, 0.0]
            for arr in (self.m, self.com, self.Ic, self.Etree, self.r, model.axis, model.damping[6:]):
                fp += list(np.asarray(arr, dtype=float).reshape(-1))
            self._cs = kernels.CompiledSystem(kernels.fixed_step.AUGMENTED, ip, fp, None, self.nq)

    def _u_vec(self, u):
        """``[(B u_effort)[6:] (nj), base wrench (6)]``."""
        uv = np.empty(self.nj + 6)
        uv[:self.nj] = (self.B @ u['effort'])[6:]
        uv[self.nj:] = u['base_wrench']
        return uv

    def _base_origin(self, y):
        """World position of the base_link origin (3,) of state y: ``c_0 − R_0 com_0``."""
        x = y[:self.nq]
        return x[self.sc][0:3] - quat_to_R(x[self.sq]) @ self.com[0]

    def _fused_supported(self) -> bool:
        # the position projection (Gauss–Newton on the CoMs) stays in numpy
        return self.stabilisation != 'projection'

    # -- conversions ---------------------------------------------------------------------
    def from_minimal(self, q, v):
        """Extended state (ny,) from minimal ``q (model.nq)``, ``v (model.nv)``."""
        m = self.model
        q = dyn.normalize_configuration(m, np.asarray(q, dtype=float))
        v = np.asarray(v, dtype=float)
        R, p = dyn.body_poses(m, q)
        vb = dyn.body_velocities(m, q, v)
        y = np.zeros(self.ny)
        x, w = y[:self.nq], y[self.nq:]
        x[self.sq] = q[3:7]
        x[self.sth] = q[7:]
        w[self.sw] = v[0:3]
        w[self.sthd] = v[6:]
        c = x[self.sc].reshape(self.nb, 3)
        cd = w[self.scd].reshape(self.nb, 3)
        for i in range(self.nb):
            c[i] = p[i] + R[i] @ self.com[i]
            cd[i] = R[i] @ (vb[i, 3:] + _cross(vb[i, :3], self.com[i]))
        return y

    def minimal(self, y):
        """Minimal ``(q (model.nq), v (model.nv))`` of the extended state y."""
        x, w = self.split(y)
        R0 = quat_to_R(x[self.sq])
        c0 = x[self.sc][0:3]
        cd0 = w[self.scd][0:3]
        om = w[self.sw]
        q = np.concatenate([c0 - R0 @ self.com[0], x[self.sq], x[self.sth]])
        v = np.concatenate([om, R0.T @ cd0 - _cross(om, self.com[0]), w[self.sthd]])
        return q, v

    def split(self, y):
        """Views ``(x, w)`` of the extended state (configuration, velocity)."""
        return y[:self.nq], y[self.nq:self.nq + self.nv]

    def initial_state(self, q0=None, v0=None):
        """Extended state from minimal q0 (model.nq,) and v0 (model.nv,) (neutral / zero by default)."""
        q0 = self.model.neutral() if q0 is None else np.asarray(q0, dtype=float)
        v0 = np.zeros(self.model.nv) if v0 is None else np.asarray(v0, dtype=float)
        if self.table:
            self._table_height(q0[:3])
        return self.from_minimal(q0, v0)

    def config_rate(self, x, w):
        """``dx/dt``: ``[½ quat ⊗ (ω, 0); θ̇; ċ]`` from the velocities at the start of ``w``."""
        out = np.empty(self.nq)
        out[self.sq] = 0.5 * quat_mul(x[self.sq], np.append(w[0:3], 0.0))
        out[4:] = w[3:self.nv]
        return out

    # -- kinematics ----------------------------------------------------------------------
    def _kinematics(self, x, w):
        """Rotations R (nb, 3, 3) world, E (nb, 3, 3) parent->child, ω (nb, 3), J (nb, 3, nr), β (nb, 3)."""
        nb, nr = self.nb, self.nr
        th, thd = x[self.sth], w[self.sthd]
        R = np.empty((nb, 3, 3))
        E = np.empty((nb, 3, 3))
        om = np.empty((nb, 3))
        J = np.zeros((nb, 3, nr))
        beta = np.zeros((nb, 3))
        R[0] = quat_to_R(x[self.sq])
        E[0] = R[0].T
        om[0] = w[self.sw]
        J[0, :, :3] = np.eye(3)
        for i in range(1, nb):
            p = self.model.parent[i]
            k = self.dof[i]
            a = self.model.axis[i]
            if k >= 0:
                E[i] = rot_axis(a, th[k]).T @ self.Etree[i]
            else:
                E[i] = self.Etree[i]
            R[i] = R[p] @ E[i].T
            Ewp = E[i] @ om[p]
            J[i] = E[i] @ J[p]
            beta[i] = E[i] @ beta[p]
            om[i] = Ewp
            if k >= 0:
                om[i] = om[i] + a * thd[k]
                J[i, :, 3 + k] += a
                beta[i] += _cross(Ewp, a * thd[k])
        return R, E, om, J, beta

    def _constraints(self, x, w, R, om, J, beta):
        """``(C (m,), C_q (m, nv), Q_d (m,))`` of the joint connections (+ table rows)."""
        nb, nr = self.nb, self.nr
        c = x[self.sc].reshape(nb, 3)
        C = np.empty(self.n_constraints)
        Cq = np.zeros((self.n_constraints, self.nv))
        Qd = np.empty(self.n_constraints)
        for i in range(1, nb):
            p = self.model.parent[i]
            rows = slice(3 * (i - 1), 3 * i)
            sc = -self.com[i]
            sp = self.r[i] - self.com[p]
            C[rows] = c[i] + R[i] @ sc - c[p] - R[p] @ sp
            Cq[rows, nr + 3 * i:nr + 3 * i + 3] = _I3
            Cq[rows, nr + 3 * p:nr + 3 * p + 3] = -_I3
            Cq[rows, :nr] = -R[i] @ skew(sc) @ J[i] + R[p] @ skew(sp) @ J[p]
            Qd[rows] = -(R[i] @ (_cross(beta[i], sc) + _cross(om[i], _cross(om[i], sc)))
                         - R[p] @ (_cross(beta[p], sp) + _cross(om[p], _cross(om[p], sp))))
        if self.table:
            rows = slice(self.n_joint_rows, self.n_joint_rows + 3)
            s = -self.com[0]
            pb = c[0] + R[0] @ s
            phi, Kw, Kc, k = table_rows(R[0], om[0], pb, self._table_height(pb), s=s)
            C[rows] = phi
            Cq[rows, 0:3] = Kw
            Cq[rows, nr:nr + 3] = Kc
            Qd[rows] = k
        return C, Cq, Qd

    def _base_wrench(self, u):
        """Thruster wrench: ``(τ_c (3) about the platform CoM in body axes, f_b (3) in body axes)``."""
        wr = u['base_wrench']
        f_b, t_b = wr[0:3], wr[3:6]
        return t_b - _cross(self.com[0], f_b), f_b

    def solve(self, y, u):
        """Solve the augmented system at state y with inputs u.

        Returns ``(ẇ (nv,), λ (m,), SolveInfo, kinematics tuple, C, C_q)``.
        """
        return self._solve(y, u, True)

    def _solve(self, y, u, exact_info):
        """:meth:`solve`; ``exact_info=False`` lets the compiled KKT solve skip the eigenvalues when
        it can certify full rank (SolveInfo then has the rank and NaN extreme eigenvalues)."""
        cs = self._compiled()
        if cs is not None:
            self._sync_height(cs, y)
            nb, nc, nr, nv = self.nb, self.n_constraints, self.nr, self.nv
            a, lam, info = np.empty(nv), np.empty(nc), np.empty(kernels.linalg.NINFO)
            R, E, om, J = np.empty((nb, 3, 3)), np.empty((nb, 3, 3)), np.empty((nb, 3)), np.empty((nb, 3, nr))
            beta, C, Cq, M = np.empty((nb, 3)), np.zeros(nc), np.zeros((nc, nv)), np.empty((nv, nv))
            if kernels.augmented.au_solve(cs.ip, cs.fp, self._u_vec(u), np.ascontiguousarray(y, dtype=float),
                                            exact_info, a, lam, info, R, E, om, J, beta, C, Cq, M):
                raise np.linalg.LinAlgError('mass matrix is not positive definite')
            info = con.SolveInfo(m=nc, rank=int(info[0]), sigma_min=float(info[1]), sigma_max=float(info[2]),
                                 residual=float(info[3]))
            return a, lam, info, (R, E, om, J, beta), C, Cq, M
        x, w = self.split(y)
        nb, nr = self.nb, self.nr
        R, E, om, J, beta = self._kinematics(x, w)
        M = np.zeros((self.nv, self.nv))
        Q = np.zeros(self.nv)
        for i in range(nb):
            Ic = self.Ic[i]
            M[:nr, :nr] += J[i].T @ Ic @ J[i]
            Q[:nr] -= J[i].T @ (Ic @ beta[i] + _cross(om[i], Ic @ om[i]))  # Q_v
            M[nr + 3 * i:nr + 3 * i + 3, nr + 3 * i:nr + 3 * i + 3] = self.m[i] * _I3
            Q[nr + 3 * i:nr + 3 * i + 3] += self.m[i] * self.model.gravity  # Q_p
        tau_c, f_b = self._base_wrench(u)
        Q[0:3] += tau_c  # Q_e, thrusters
        Q[nr:nr + 3] += R[0] @ f_b
        Q[self.sthd] += self.arm_torques(u, w[self.sthd])  # Q_e + Q_f (joint efforts, damping)
        if self.n_constraints:
            C, Cq, Qd = self._constraints(x, w, R, om, J, beta)
            k = con.baumgarte_rhs(Qd, C, Cq @ w, self.alpha, self.beta)
        else:
            C, Cq, k = np.zeros(0), np.zeros((0, self.nv)), np.zeros(0)
        a, lam, info = con.kkt_solve(M, Q, Cq, k)
        return a, lam, info, (R, E, om, J, beta), C, Cq, M

    def rhs(self, t, y, u):
        """``[ẋ; ẇ]``."""
        cs = self._compiled()
        if cs is not None:
            self._sync_height(cs, y)
            return cs.evaluate(t, y, self._u_vec(u))[:self.ny]
        x, w = self.split(y)
        a = self.solve(y, u)[0]
        return np.concatenate([self.config_rate(x, w), a])

    def project(self, y):
        """Renormalise the quaternion; with ``projection`` also project CoMs and velocities onto C = 0."""
        x, w = self.split(y)
        x[self.sq] /= np.linalg.norm(x[self.sq])
        if self.stabilisation == 'projection' and self.n_constraints:
            if self.table:
                x[self.sq] = level_quaternion(x[self.sq])
            u0 = self.zero_inputs()
            wz = np.zeros(self.nv)
            th_q = x[:4 + self.nj].copy()

            def kin(cvec):
                xx = np.concatenate([th_q, cvec])
                return xx, self._kinematics(xx, wz)

            def phi_fn(cvec):
                xx, (R, _, om, J, beta) = kin(cvec)
                return self._constraints(xx, wz, R, om, J, beta)[0]

            def K_fn(cvec):
                xx, (R, _, om, J, beta) = kin(cvec)
                return self._constraints(xx, wz, R, om, J, beta)[1][:, self.scd]

            Mc = np.kron(np.diag(self.m), np.eye(3))
            x[self.sc] = con.project_positions(Mc, phi_fn, K_fn, x[self.sc])[0]
            _, _, _, _, _, Cq, M = self.solve(y, u0)
            w[:] = con.project_velocities(M, Cq, w)
        return y

    # -- outputs -------------------------------------------------------------------------
    def joint_forces_world(self, lam):
        """The multipliers of the joint rows as (nb − 1, 3): force on each child from its parent, world."""
        return lam[:self.n_joint_rows].reshape(self.nb - 1, 3)

    def transmitted_wrenches(self, y, u, a, lam, kin):
        """Joint wrenches (nb, 6) [torque; force] on each child at its joint origin, child axes (row 0 unused)."""
        R, E, om, J, beta = kin
        nb = self.nb
        f = np.zeros((nb, 3))
        n = np.zeros((nb, 3))
        lamj = self.joint_forces_world(lam)
        for i in range(1, nb):
            f[i] = R[i].T @ lamj[i - 1]
        ar = a[:self.nr]
        for i in range(nb - 1, 0, -1):
            Ic = self.Ic[i]
            wd = J[i] @ ar + beta[i]
            ni = Ic @ wd + _cross(om[i], Ic @ om[i]) - _cross(-self.com[i], f[i])
            for j in self.children[i]:
                ni += E[j].T @ n[j] + _cross(self.r[j] - self.com[i], E[j].T @ f[j])
            n[i] = ni
        return np.hstack([n, f])

    def table_wrench_from(self, Cq, lam, R0):
        """The table's wrench [torque; force] on base_link at its origin, base_link axes (6,)."""
        if not self.table:
            return np.zeros(6)
        rows = slice(self.n_joint_rows, self.n_joint_rows + 3)
        G = Cq[rows].T @ lam[rows]
        tau_c = G[0:3]
        f_b = R0.T @ G[self.nr:self.nr + 3]
        return np.concatenate([tau_c + _cross(self.com[0], f_b), f_b])

    def _momentum(self, x, w, R, om):
        c = x[self.sc].reshape(self.nb, 3)
        cd = w[self.scd].reshape(self.nb, 3)
        Ls = (R @ (self.Ic @ om[:, :, None]))[:, :, 0]  # R_i I_ci ω_i
        return momentum_about_com(self.m, c, cd, Ls)

    def outputs(self, t, y, u, wrenches=True):
        """Joint states, odometry, joint and table wrenches, energies and momentum diagnostics."""
        x, w = self.split(y)
        # the rank is all that outputs report of the solve: the compiled one may skip the eigenvalues
        a, lam, info, kin, C, Cq, _ = self._solve(y, u, False) if self._compiled() is not None else self.solve(y, u)
        R, E, om, J, beta = kin
        q, v = self.minimal(y)
        wr = {}
        if wrenches:
            F = self.transmitted_wrenches(y, u, a, lam, kin)
            for i in range(1, self.nb):
                wr[self.model.joint_names[i]] = (self.model.link_names[i], F[i])
            if self.table:
                wr['base_plane'] = (self.base_link, self.table_wrench_from(Cq, lam, R[0]))
        cs = self._compiled()
        if cs is not None:
            rep = np.empty(11)
            kernels.augmented.au_report(cs.ip, cs.fp, np.ascontiguousarray(y, dtype=float), R, om, rep)
            p, L, com = rep[0:3], rep[3:6], rep[6:9]
            e = {'kinetic': float(rep[9]), 'potential': float(rep[10])}
        else:
            p, L, com = self._momentum(x, w, R, om)
            e = self._energies(x, w, om)
        res = float(np.abs(C).max()) if C.size else 0.0
        vres = float(np.abs(Cq @ w).max()) if C.size else 0.0
        odom = {'position': q[0:3], 'orientation': q[3:7], 'linear': v[3:6], 'angular': v[0:3]}
        return SystemOutputs(joint_names=list(self.joint_names), position=x[self.sth].copy(),
                             velocity=w[self.sthd].copy(), effort=(self.B @ u['effort'])[6:], wrenches=wr,
                             odom=odom, energy=e, extra=self._extra(p, L, com, res, vres, info))

    def _energies(self, x, w, om):
        c = x[self.sc].reshape(self.nb, 3)
        cd = w[self.scd].reshape(self.nb, 3)
        ke = 0.5 * float(np.sum(self.m * np.einsum('ij,ij->i', cd, cd)))
        ke += 0.5 * float(np.einsum('ni,nij,nj->', om, self.Ic, om))
        pe = -float(np.sum(self.m * (c @ self.model.gravity)))
        return {'kinetic': ke, 'potential': pe}

    def total_energy(self, y):
        """Kinetic plus gravitational potential energy (J)."""
        x, w = self.split(y)
        _, _, om, _, _ = self._kinematics(x, w)
        e = self._energies(x, w, om)
        return e['kinetic'] + e['potential']

    def input_power(self, t, y, u):
        """Power of the joint efforts and the base wrench minus joint damping (W)."""
        x, w = self.split(y)
        R0 = quat_to_R(x[self.sq])
        om = w[self.sw]
        vo = R0.T @ w[self.scd][0:3] - _cross(om, self.com[0])
        wr = u['base_wrench']
        return float(w[self.sthd] @ self.arm_torques(u, w[self.sthd]) + om @ wr[3:6] + vo @ wr[0:3])
