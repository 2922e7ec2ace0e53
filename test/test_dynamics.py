"""Dynamics kernels checked against each other, against closed forms and against physics.

Every check collects its errors over all cases and asserts once on the worst one (and on the
number of cases), so that a check can never pass by running zero times. All randomness is
seeded. Expected values come from algebra written out here, never from the code under test.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from conftest import N_TREES
from robodyn_ros import dynamics as dyn
from robodyn_ros.model import FIXED, PRISMATIC, REVOLUTE, LinkSpec, build_model, random_tree
from robodyn_ros.spatial import (R_to_quat, R_to_rpy, crf, crm, inertia_parts, mcI, plux, pose_of,
                                 quat_exp, quat_mul, quat_to_R, rot_axis, rotx, roty, rotz,
                                 rpy_to_R, skew, xinv)


def rel(x, y, floor=1.0):
    """Max-norm error of x against y, relative to max(|y|, floor)."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    return float(np.max(np.abs(x - y), initial=0.0) / max(float(np.max(np.abs(y), initial=0.0)), floor))


def worst(errors):
    """``(max error, label)`` of a list of ``(error, label)``."""
    return max(errors, key=lambda e: e[0])


def random_rotation(rng):
    """A uniformly random proper rotation matrix."""
    Q, Rr = np.linalg.qr(rng.normal(size=(3, 3)))
    Q = Q @ np.diag(np.sign(np.diag(Rr)))
    return Q if np.linalg.det(Q) > 0 else -Q


def dM_dq(model, q, h=1e-5):
    """Central finite differences of CRBA: ``D[k] = dM/dq_k`` (nv, nv, nv)."""
    D = np.empty((model.nv, model.nv, model.nv))
    for k in range(model.nv):
        e = np.zeros(model.nq)
        e[k] = h
        D[k] = (dyn.crba(model, q + e) - dyn.crba(model, q - e)) / (2.0 * h)
    return D


def christoffel_C(D, v):
    """Christoffel-symbol Coriolis matrix ``C_ij = Σ_k ½(∂_k M_ij + ∂_j M_ik - ∂_i M_jk) v_k``."""
    return 0.5 * (np.einsum('kij,k->ij', D, v) + np.einsum('jik,k->ij', D, v) - np.einsum('ijk,k->ij', D, v))


def rnea_C(model, q, v):
    """Christoffel C from RNEA alone: the velocity part ``Γ(v, v) = h(q, v) - g(q)`` is a symmetric
    quadratic form and ``C(q, v) w = Γ(v, w)``, recovered exactly by polarisation."""
    z = np.zeros(model.nv)
    g = dyn.rnea(model, q, z, z)

    def gam(x):
        return dyn.rnea(model, q, x, z) - g

    gv = gam(v)
    C = np.empty((model.nv, model.nv))
    for j in range(model.nv):
        e = np.zeros(model.nv)
        e[j] = 1.0
        C[:, j] = 0.5 * (gam(v + e) - gv - gam(e))
    return C


def total_energy(model, q, v):
    return dyn.kinetic_energy(model, q, v) + dyn.potential_energy(model, q)


# ----------------------------------------------------------------------------------------------
# 1. algorithms against each other on random trees
# ----------------------------------------------------------------------------------------------

def test_trees_fixture_covers_the_promised_mix(trees):
    nbs = [m.nb for _, m in trees]
    jt = np.concatenate([m.jtype for _, m in trees])
    assert len(trees) == N_TREES
    assert min(nbs) == 1 and max(nbs) == 12
    assert {REVOLUTE, PRISMATIC, FIXED} <= set(jt.tolist())
    # some trees branch (a parent with two children), some are chains
    branched = [np.bincount(m.parent[m.parent >= 0], minlength=m.nb).max(initial=0) > 1 for _, m in trees]
    assert 3 <= sum(branched) <= N_TREES - 3
    # the FIXED joints sit mid-tree: a welded body that has a moving parent chain above it
    fixed_mid = [m for _, m in trees if any(m.jtype[i] == FIXED and m.parent[i] >= 0 for i in range(m.nb))]
    assert len(fixed_mid) == 3


def test_forward_inverse_roundtrip(trees, state_of):
    """FD(ID(qdd)) = qdd and ID(FD(tau)) = tau, for ABA and for CRBA + Cholesky, with and
    without external forces."""
    rng = np.random.default_rng(11)
    errs = []
    for label, m in trees:
        for trial in range(3):
            q, v, a = state_of(m, rng)
            fext = rng.normal(size=(m.nb, 6)) if trial == 2 else None
            tau = dyn.rnea(m, q, v, a, fext)
            errs.append((rel(dyn.aba(m, q, v, tau, fext), a), f'{label} ABA(RNEA)'))
            errs.append((rel(dyn.fd_crba(m, q, v, tau, fext), a), f'{label} CRBA-FD(RNEA)'))
            tau = rng.normal(size=m.nv) * 5.0
            errs.append((rel(dyn.rnea(m, q, v, dyn.aba(m, q, v, tau, fext), fext), tau), f'{label} RNEA(ABA)'))
            errs.append((rel(dyn.rnea(m, q, v, dyn.fd_crba(m, q, v, tau, fext), fext), tau), f'{label} RNEA(CRBA-FD)'))
    assert len(errs) == 4 * 3 * N_TREES
    e, where = worst(errs)
    assert e < 2e-11, where   # measured 2.1e-13


def test_rnea_is_M_qdd_plus_h(trees, state_of):
    """tau = M(q) qdd + h(q, v): CRBA and RNEA agree, and RNEA is affine in qdd."""
    rng = np.random.default_rng(12)
    errs = []
    for label, m in trees:
        q, v, a = state_of(m, rng)
        h = dyn.bias_forces(m, q, v)
        errs.append((rel(dyn.crba(m, q) @ a + h, dyn.rnea(m, q, v, a)), label))
    assert len(errs) == N_TREES
    e, where = worst(errs)
    assert e < 1e-13, where   # measured 1.1e-15


def test_mass_matrix_symmetric_positive_definite(trees, state_of):
    rng = np.random.default_rng(13)
    asym, mineig = [], []
    for label, m in trees:
        for _ in range(3):
            q, _, _ = state_of(m, rng)
            M = dyn.crba(m, q)
            asym.append((rel(M, M.T), label))
            mineig.append((np.linalg.eigvalsh(0.5 * (M + M.T)).min(), label))
    assert len(asym) == len(mineig) == 3 * N_TREES
    assert worst(asym)[0] < 1e-14, worst(asym)[1]
    lo = min(mineig, key=lambda e: e[0])
    assert lo[0] > 1e-6, lo[1]


def test_kinetic_energy_is_half_vMv(trees, state_of):
    rng = np.random.default_rng(14)
    errs = []
    for label, m in trees:
        q, v, _ = state_of(m, rng)
        ke = dyn.kinetic_energy(m, q, v)
        errs.append((rel(ke, 0.5 * v @ dyn.crba(m, q) @ v), label))
    assert len(errs) == N_TREES
    e, where = worst(errs)
    assert e < 1e-13, where   # measured 6.7e-16


def test_coriolis_matrix_christoffel_and_skew_symmetry(trees, state_of):
    """The Christoffel C from finite differences of CRBA equals the C that RNEA implies, and
    ``Mdot - 2C`` is skew-symmetric with RNEA's C and finite-difference Mdot.

    (With C built from the same finite-difference dM/dq the skew property is an algebraic
    identity for any symmetric M, so it is checked here with RNEA's C: that ties the velocity
    terms of RNEA to the configuration dependence of CRBA.)"""
    rng = np.random.default_rng(15)
    c_err, skew_err, quad_err = [], [], []
    for label, m in trees:
        q, v, _ = state_of(m, rng)
        D = dM_dq(m, q)
        Mdot = np.einsum('kij,k->ij', D, v)
        C_chr = christoffel_C(D, v)
        C_rn = rnea_C(m, q, v)
        scale = max(np.abs(Mdot).max(), np.abs(C_rn).max(), 1.0)
        c_err.append((np.abs(C_chr - C_rn).max() / scale, label))
        N = Mdot - 2.0 * C_rn
        skew_err.append((np.abs(N + N.T).max() / scale, label))
        # the weaker identity for the RNEA velocity term h(q,v) - g(q) = C(q,v) v
        cv = dyn.bias_forces(m, q, v) - dyn.bias_forces(m, q, np.zeros(m.nv))
        quad_err.append((abs(v @ Mdot @ v - 2.0 * v @ cv) / (scale * (v @ v)), label))
    assert len(c_err) == len(skew_err) == len(quad_err) == N_TREES
    for errs in (c_err, skew_err, quad_err):   # finite-difference dM/dq: measured ≤ 2.5e-10
        e, where = worst(errs)
        assert e < 3e-8, where


def test_power_balance(trees, state_of):
    """Without damping dE/dt = vᵀ tau; dE/dt by a central difference of E = KE + PE along the
    trajectory through (q, v) with qdd = ABA(tau)."""
    rng = np.random.default_rng(16)
    errs = []
    hstep = 1e-5
    for label, m in trees:
        q, v, _ = state_of(m, rng)
        tau = rng.normal(size=m.nv) * 3.0
        a = dyn.aba(m, q, v, tau)
        Ep = total_energy(m, q + hstep * v + 0.5 * hstep ** 2 * a, v + hstep * a)
        Em = total_energy(m, q - hstep * v + 0.5 * hstep ** 2 * a, v - hstep * a)
        dE = (Ep - Em) / (2.0 * hstep)
        scale = np.abs(v) @ (np.abs(tau) + np.abs(dyn.bias_forces(m, q, v))) + 1.0
        errs.append((abs(dE - v @ tau) / scale, label))
    assert len(errs) == N_TREES
    e, where = worst(errs)
    assert e < 5e-8, where   # central difference of E: measured 7.2e-10


def test_whole_tree_newton_euler(trees, state_of):
    """The wrenches of the joints attached to the root are the whole tree's rate of change of
    spatial momentum minus gravity and external forces (all about the root origin, root axes):
    ties joint_wrenches, spatial_momentum and center_of_mass together."""
    rng = np.random.default_rng(17)
    errs = []
    hstep = 1e-5
    for label, m in trees:
        q, v, _ = state_of(m, rng)
        tau = rng.normal(size=m.nv)
        a, f = dyn.joint_wrenches(m, q, v, tau)
        X0 = dyn.forward_kinematics(m, q)
        root_wrench = sum(X0[i].T @ f[i] for i in range(m.nb) if m.parent[i] < 0)
        hp = dyn.spatial_momentum(m, q + hstep * v + 0.5 * hstep ** 2 * a, v + hstep * a)
        hm = dyn.spatial_momentum(m, q - hstep * v + 0.5 * hstep ** 2 * a, v - hstep * a)
        hdot = (hp - hm) / (2.0 * hstep)
        com, mass = dyn.center_of_mass(m, q)
        W = mass * m.gravity
        gravity_wrench = np.concatenate([np.cross(com, W), W])
        errs.append((rel(root_wrench + gravity_wrench, hdot, floor=10.0), label))
    assert len(errs) == N_TREES
    e, where = worst(errs)
    assert e < 1e-6, where


# ----------------------------------------------------------------------------------------------
# 4. joint wrench semantics
# ----------------------------------------------------------------------------------------------

def test_joint_wrench_projection_is_joint_effort(trees, state_of):
    """S_iᵀ f[i] = tau_i for the wrenches returned by joint_wrenches (ABA, then RNEA's backward
    pass) under applied tau and external forces."""
    rng = np.random.default_rng(18)
    errs = []
    for label, m in trees:
        q, v, _ = state_of(m, rng)
        tau = rng.normal(size=m.nv) * 2.0
        fext = rng.normal(size=(m.nb, 6))
        _, f = dyn.joint_wrenches(m, q, v, tau, fext)
        for i in range(m.nb):
            if m.jtype[i] in (REVOLUTE, PRISMATIC):
                ax = m.axis[i]
                s = np.concatenate([ax, np.zeros(3)]) if m.jtype[i] == REVOLUTE else np.concatenate([np.zeros(3), ax])
                errs.append((abs(s @ f[i] - tau[m.v_idx[i]]) / max(1.0, abs(tau[m.v_idx[i]])), f'{label} body {i}'))
    assert len(errs) == sum(m.nv for _, m in trees)
    e, where = worst(errs)
    assert e < 2e-12, where   # measured 2.4e-14


def _hanging_pendulum(mass, l, Ic=np.zeros((3, 3)), g=9.81, damping=0.0):
    """Revolute about y at the root origin; com at (0, 0, -l) in the body frame; gravity -z."""
    return build_model([LinkSpec(name='bob', joint='pivot', parent=None, joint_type='revolute', axis=(0, 1, 0),
                                 mass=mass, com=(0.0, 0.0, -l), inertia=Ic, damping=damping)],
                       gravity=(0.0, 0.0, -g))


def test_static_pendulum_wrench_is_weight_and_lever_torque():
    """Holding a pendulum still at angle th: the pivot pushes with the weight, m g up, and
    with the torque m g l sin(th) about y (the moment of the weight about the pivot)."""
    rng = np.random.default_rng(19)
    errs = []
    for _ in range(10):
        mass, l, g, th = rng.uniform(0.2, 5.0), rng.uniform(0.1, 2.0), rng.uniform(1.0, 20.0), rng.uniform(-3, 3)
        a1, a2 = rng.uniform(0.01, 0.1, size=2)
        m = _hanging_pendulum(mass, l, np.diag([a1, a2, a1 + a2]), g)
        q, z = np.array([th]), np.zeros(1)
        tau, f = dyn.rnea_wrenches(m, q, z, z)
        # body axes are the root axes turned by th about y: the world force (0, 0, m g) in body axes
        f_expected = np.array([-mass * g * np.sin(th), 0.0, mass * g * np.cos(th)])
        n_expected = np.array([0.0, mass * g * l * np.sin(th), 0.0])
        errs.append(rel(f[0], np.concatenate([n_expected, f_expected])))
        errs.append(rel(tau, [mass * g * l * np.sin(th)]))
    assert len(errs) == 20
    assert max(errs) < 1e-12


def test_prismatic_mass_slides_at_g_cos_axis_angle():
    """A body on a prismatic joint whose axis makes angle phi with the downward vertical slides
    with qdd = g cos(phi); the joint pushes with m (qdd e - g) and the moment of that force about
    the com offset."""
    rng = np.random.default_rng(20)
    errs = []
    for _ in range(12):
        g = rng.uniform(1.0, 20.0)
        phi, psi = rng.uniform(0.0, np.pi), rng.uniform(-np.pi, np.pi)  # polar angle from -z, azimuth
        e_world = np.array([np.sin(phi) * np.cos(psi), np.sin(phi) * np.sin(psi), -np.cos(phi)])
        Rj = random_rotation(rng)  # joint frame orientation; the axis is given in joint axes
        mass = rng.uniform(0.1, 10.0)
        com = rng.uniform(-0.3, 0.3, size=3)
        a1, a2 = rng.uniform(0.01, 0.1, size=2)
        m = build_model([LinkSpec(name='slider', joint='rail', parent=None, joint_type='prismatic',
                                  origin_xyz=tuple(rng.uniform(-1, 1, size=3)), origin_R=Rj,
                                  axis=tuple(Rj.T @ e_world), mass=mass, com=tuple(com),
                                  inertia=np.diag([a1, a2, a1 + a2]))], gravity=(0.0, 0.0, -g))
        q, v = rng.normal(size=1), rng.normal(size=1)
        qdd, f = dyn.joint_wrenches(m, q, v, np.zeros(1))
        errs.append(rel(qdd, [g * np.cos(phi)], floor=g))
        F_world = mass * (g * np.cos(phi) * e_world - np.array([0.0, 0.0, -g]))
        F_body = Rj.T @ F_world
        errs.append(rel(f[0], np.concatenate([np.cross(com, F_body), F_body]), floor=mass * g))
        errs.append(abs(e_world @ F_world) / (mass * g))  # no force along the free axis
    assert len(errs) == 36
    assert max(errs) < 1e-12


# ----------------------------------------------------------------------------------------------
# 2. closed forms
# ----------------------------------------------------------------------------------------------

def _period_by_zero_crossings(m, th0, n_periods=6):
    """Integrate from rest at th0 (DOP853) and return the mean period between upward zero crossings."""
    def rhs(t, y):
        return np.concatenate([y[1:], dyn.aba(m, y[:1], y[1:], np.zeros(1))])

    def crossing(t, y):
        return y[0]
    crossing.direction = 1.0
    T_guess = 2 * np.pi * np.sqrt(1.0 / 9.81)
    sol = solve_ivp(rhs, (0.0, (n_periods + 1) * 4 * T_guess), [th0, 0.0], method='DOP853', rtol=1e-12,
                    atol=1e-14, events=crossing)
    tc = sol.t_events[0]
    assert len(tc) >= n_periods
    return (tc[-1] - tc[0]) / (len(tc) - 1)


@pytest.mark.parametrize('kind', ['point_mass', 'uniform_bar'])
def test_small_angle_pendulum_period(kind):
    """T = 2π sqrt(I_pivot / (m g l_c)) at small amplitude (the first amplitude correction
    θ0²/16 is below 1e-7 for θ0 = 1e-3)."""
    mass, g = 1.7, 9.81
    if kind == 'point_mass':
        l = 0.8
        m = _hanging_pendulum(mass, l, g=g)
        I_pivot, lc = mass * l ** 2, l
    else:
        L = 1.3  # bar along body -z from the pivot: Ic = m L²/12 about x and y, 0 about z
        m = _hanging_pendulum(mass, L / 2, np.diag([mass * L ** 2 / 12, mass * L ** 2 / 12, 0.0]), g=g)
        I_pivot, lc = mass * L ** 2 / 3, L / 2
    T_expected = 2 * np.pi * np.sqrt(I_pivot / (mass * g * lc))
    T = _period_by_zero_crossings(m, 1e-3)
    assert abs(T - T_expected) / T_expected < 1e-6


def _two_link(p, g):
    """Planar two-link arm: joints about z, links along body x, gravity -y (Spong's set-up)."""
    return build_model([
        LinkSpec(name='link1', joint='q1', parent=None, axis=(0, 0, 1), mass=p['m1'], com=(p['lc1'], 0, 0),
                 inertia=np.diag([0.1 * p['I1'], p['I1'], p['I1']])),
        LinkSpec(name='link2', joint='q2', parent='link1', origin_xyz=(p['l1'], 0, 0), axis=(0, 0, 1),
                 mass=p['m2'], com=(p['lc2'], 0, 0), inertia=np.diag([0.1 * p['I2'], p['I2'], p['I2']])),
    ], gravity=(0.0, -g, 0.0))


def test_two_link_planar_M_C_G_closed_form():
    """Spong, Hutchinson & Vidyasagar, *Robot Modeling and Control*, §7.4.2 (two-link planar
    elbow arm): I1, I2 are the moments of inertia about the com, perpendicular to the plane."""
    rng = np.random.default_rng(21)
    errs = {'M': [], 'C': [], 'Cv': [], 'G': [], 'C_fd': []}
    for _ in range(5):
        p = dict(m1=rng.uniform(0.5, 3), m2=rng.uniform(0.5, 3), l1=rng.uniform(0.3, 1.5),
                 I1=rng.uniform(0.01, 0.3), I2=rng.uniform(0.01, 0.3))
        p['lc1'] = rng.uniform(0.1, 0.9) * p['l1']
        p['lc2'] = rng.uniform(0.1, 1.0)
        g = rng.uniform(5, 15)
        m = _two_link(p, g)
        m1, m2, l1, lc1, lc2, I1, I2 = (p[k] for k in ('m1', 'm2', 'l1', 'lc1', 'lc2', 'I1', 'I2'))
        for _ in range(4):
            q1, q2 = rng.uniform(-np.pi, np.pi, size=2)
            qd1, qd2 = rng.normal(size=2) * 2
            d11 = m1 * lc1 ** 2 + m2 * (l1 ** 2 + lc2 ** 2 + 2 * l1 * lc2 * np.cos(q2)) + I1 + I2
            d12 = m2 * (lc2 ** 2 + l1 * lc2 * np.cos(q2)) + I2
            d22 = m2 * lc2 ** 2 + I2
            M_ref = np.array([[d11, d12], [d12, d22]])
            h = -m2 * l1 * lc2 * np.sin(q2)
            C_ref = np.array([[h * qd2, h * qd2 + h * qd1], [-h * qd1, 0.0]])
            G_ref = np.array([(m1 * lc1 + m2 * l1) * g * np.cos(q1) + m2 * lc2 * g * np.cos(q1 + q2),
                              m2 * lc2 * g * np.cos(q1 + q2)])
            q, v, z = np.array([q1, q2]), np.array([qd1, qd2]), np.zeros(2)
            G = dyn.rnea(m, q, z, z)
            errs['M'].append(rel(dyn.crba(m, q), M_ref))
            errs['G'].append(rel(G, G_ref))
            errs['Cv'].append(rel(dyn.rnea(m, q, v, z) - G, C_ref @ v))
            errs['C'].append(rel(rnea_C(m, q, v), C_ref))
            # and the finite-difference Christoffel helper used on the random trees
            errs['C_fd'].append(rel(christoffel_C(dM_dq(m, q), v), C_ref))
    assert all(len(e) == 20 for e in errs.values())
    for k, e in errs.items():
        assert max(e) < (1e-8 if k == 'C_fd' else 1e-11), k


# ----------------------------------------------------------------------------------------------
# 5. energy
# ----------------------------------------------------------------------------------------------

def _simulate(m, y0, T, n_out, rtol, atol, rise_tol, fall_tol=np.inf):
    """Integrate ``[q; v]`` with DOP853 and sample E = KE + PE and KE at n_out times.

    A terminal event stops the run as soon as E leaves ``[E0 - fall_tol, E0 + rise_tol]``, so a
    broken kernel makes the test fail at once instead of integrating a blow-up for minutes.
    """
    def rhs(t, y):
        q, v = y[:m.nq], y[m.nq:]
        return np.concatenate([v, dyn.aba(m, q, v, dyn.passive_forces(m, v))])

    E0 = total_energy(m, y0[:m.nq], y0[m.nq:])

    def leaves_band(t, y):
        dE = total_energy(m, y[:m.nq], y[m.nq:]) - E0
        return min(rise_tol - dE, fall_tol + dE)
    leaves_band.terminal = True
    ts = np.linspace(0.0, T, n_out)
    sol = solve_ivp(rhs, (0.0, T), y0, method='DOP853', rtol=rtol, atol=atol, t_eval=ts, events=leaves_band)
    assert sol.status == 0, f'stopped at t = {sol.t[-1]:.3f} s: {sol.message} (energy left its band?)'
    E = np.array([total_energy(m, y[:m.nq], y[m.nq:]) for y in sol.y.T])
    KE = np.array([dyn.kinetic_energy(m, y[:m.nq], y[m.nq:]) for y in sol.y.T])
    return sol, E, KE


def test_energy_conserved_without_damping():
    """A random 5-link chain, no damping, 5 s of DOP853 at rtol 1e-11: E = KE + PE drifts by less
    than 2e-9 of the largest kinetic energy reached (a reference-free energy scale; measured 2.4e-11)."""
    rng = np.random.default_rng(22)
    m = random_tree(5, rng, prismatic_fraction=0.0, chain=True)
    assert not m.damping.any()
    y0 = np.concatenate([rng.uniform(-1, 1, size=5), rng.normal(size=5)])
    KE0 = dyn.kinetic_energy(m, y0[:5], y0[5:])
    sol, E, KE = _simulate(m, y0, 5.0, 501, 1e-11, 1e-12, rise_tol=1e-4 * KE0, fall_tol=1e-4 * KE0)
    assert len(E) == 501
    assert KE.max() > 1.0  # it really moves
    assert np.abs(E - E[0]).max() / KE.max() < 2e-9


def test_energy_decreases_with_damping():
    """The same kind of chain with viscous joint damping: E never increases, and dE/dt = -vᵀ D v."""
    rng = np.random.default_rng(23)
    m0 = random_tree(5, rng, prismatic_fraction=0.2, chain=True)
    m = build_model([dataclasses.replace(s, damping=float(rng.uniform(0.05, 0.5))) for s in m0.specs],
                    gravity=m0.gravity)
    assert (m.damping > 0).all()
    y0 = np.concatenate([rng.uniform(-1, 1, size=5), rng.normal(size=5)])
    KE0 = dyn.kinetic_energy(m, y0[:5], y0[5:])
    sol, E, KE = _simulate(m, y0, 3.0, 601, 1e-10, 1e-12, rise_tol=1e-6 * KE0)
    dE = np.diff(E)
    assert len(dE) == 600
    assert dE.max() < 1e-9 * KE.max()
    assert E[-1] < E[0] - 0.05 * KE.max()
    # instantaneous power of the damper at the sampled states (central difference along the flow)
    errs = []
    hstep = 1e-5
    for y in sol.y.T[::60]:
        q, v = y[:5], y[5:]
        a = dyn.aba(m, q, v, dyn.passive_forces(m, v))
        Ep = total_energy(m, q + hstep * v + 0.5 * hstep ** 2 * a, v + hstep * a)
        Em = total_energy(m, q - hstep * v + 0.5 * hstep ** 2 * a, v - hstep * a)
        errs.append(abs((Ep - Em) / (2 * hstep) + v @ (m.damping * v)) / (1.0 + KE.max()))
    assert len(errs) == 11
    assert max(errs) < 1e-6


# ----------------------------------------------------------------------------------------------
# 6. spatial algebra
# ----------------------------------------------------------------------------------------------

def test_plux_xinv_and_point_velocity():
    rng = np.random.default_rng(31)
    errs = []
    for _ in range(20):
        R, p = random_rotation(rng), rng.normal(size=3)
        X = pose_of(R, p)
        errs.append(rel(X @ xinv(X), np.eye(6)))
        errs.append(rel(xinv(X), plux(R, -R.T @ p)))
        # a twist (w, v_o) given at A's origin in A axes; B's origin moves with v_o + w × p
        w, vo = rng.normal(size=3), rng.normal(size=3)
        errs.append(rel(X @ np.concatenate([w, vo]), np.concatenate([R.T @ w, R.T @ (vo + np.cross(w, p))])))
        # a force f at A's origin becomes the moment n - p × f about B's origin
        n, fo = rng.normal(size=3), rng.normal(size=3)
        errs.append(rel(np.linalg.inv(X).T @ np.concatenate([n, fo]),
                        np.concatenate([R.T @ (n - np.cross(p, fo)), R.T @ fo])))
        errs.append(rel(xinv(X).T, np.linalg.inv(X).T))
    assert len(errs) == 100
    assert max(errs) < 1e-13


def test_cross_products():
    """crm against the 3D cross products it stands for; crf = -crmᵀ (the duality
    (v×m)·f + m·(v×*f) = 0); the transform law X (v×) X⁻¹ = (Xv)×."""
    rng = np.random.default_rng(32)
    errs = []
    for _ in range(20):
        v, mvec, f = rng.normal(size=6), rng.normal(size=6), rng.normal(size=6)
        w, u = v[:3], v[3:]
        errs.append(rel(crm(v) @ mvec, np.concatenate([np.cross(w, mvec[:3]),
                                                        np.cross(w, mvec[3:]) + np.cross(u, mvec[:3])])))
        errs.append(rel(crf(v) @ f, np.concatenate([np.cross(w, f[:3]) + np.cross(u, f[3:]), np.cross(w, f[3:])])))
        errs.append(rel(crf(v), -crm(v).T))
        errs.append(abs((crm(v) @ mvec) @ f + mvec @ (crf(v) @ f)) / 10)
        X = pose_of(random_rotation(rng), rng.normal(size=3))
        errs.append(rel(X @ crm(v) @ xinv(X), crm(X @ v)))
        errs.append(rel(skew(w) @ u, np.cross(w, u)))
    assert len(errs) == 120
    assert max(errs) < 1e-13


def test_spatial_inertia_roundtrip_and_energy():
    """mcI / inertia_parts round trip, and ½ vᵀ I v = ½ m |v_c|² + ½ ωᵀ Ic ω with v_c = v_o + ω × c."""
    rng = np.random.default_rng(33)
    errs = []
    for _ in range(20):
        mass, c = rng.uniform(0.1, 10), rng.normal(size=3)
        Q = random_rotation(rng)
        Ic = Q @ np.diag(rng.uniform(0.01, 1.0, size=3)) @ Q.T
        I = mcI(mass, c, Ic)
        m2, c2, Ic2 = inertia_parts(I)
        errs.append(rel([m2], [mass]))
        errs.append(rel(c2, c))
        errs.append(rel(Ic2, Ic))
        w, vo = rng.normal(size=3), rng.normal(size=3)
        vc = vo + np.cross(w, c)
        sv = np.concatenate([w, vo])
        errs.append(rel(0.5 * sv @ I @ sv, 0.5 * mass * vc @ vc + 0.5 * w @ Ic @ w))
        # a spatial inertia transforms as X*ᵀ... i.e. I_B = X⁻ᵀ I_A X⁻¹ keeps the energy
        X = pose_of(random_rotation(rng), rng.normal(size=3))
        IB = xinv(X).T @ I @ xinv(X)
        errs.append(rel(0.5 * (X @ sv) @ IB @ (X @ sv), 0.5 * sv @ I @ sv))
    assert len(errs) == 100
    assert max(errs) < 1e-12


def test_quaternion_helpers():
    rng = np.random.default_rng(34)
    errs = []
    rots = [random_rotation(rng) for _ in range(20)]
    # near-π rotations about each axis reach every branch of Shepperd's method
    rots += [rot_axis(np.eye(3)[k], np.pi - 0.1) for k in range(3)] + [rot_axis(np.eye(3)[k], np.pi) for k in range(3)]
    for R in rots:
        q = R_to_quat(R)
        errs.append(abs(np.linalg.norm(q) - 1.0))
        errs.append(rel(quat_to_R(q), R))
        errs.append(0.0 if q[3] >= 0 else 1.0)
    for _ in range(20):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        q2 = R_to_quat(quat_to_R(q))
        errs.append(min(rel(q2, q), rel(q2, -q)))
        R = quat_to_R(q)
        errs.append(rel(R @ R.T, np.eye(3)))
        errs.append(abs(np.linalg.det(R) - 1.0))
        b = rng.normal(size=4)
        b /= np.linalg.norm(b)
        errs.append(rel(quat_to_R(quat_mul(q, b)), quat_to_R(q) @ quat_to_R(b)))
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        ang = rng.uniform(-3, 3)
        errs.append(rel(quat_to_R(quat_exp(axis * ang)), rot_axis(axis, ang)))
        # q = (sin(θ/2) axis, cos(θ/2)) written out
        errs.append(rel(quat_exp(axis * ang), np.concatenate([np.sin(ang / 2) * axis, [np.cos(ang / 2)]])))
    errs.append(rel(quat_exp(np.array([1e-10, 0, 0])), [5e-11, 0, 0, 1]))
    assert len(errs) == 3 * 26 + 6 * 20 + 1
    assert max(errs) < 1e-12


def test_rpy_roundtrip_and_elementary_rotations():
    rng = np.random.default_rng(35)
    errs = []
    for _ in range(30):
        rpy = np.array([rng.uniform(-np.pi, np.pi), rng.uniform(-1.4, 1.4), rng.uniform(-np.pi, np.pi)])
        R = rpy_to_R(rpy)
        errs.append(rel(R_to_rpy(R), rpy))
        errs.append(rel(R, rot_axis([0, 0, 1], rpy[2]) @ rot_axis([0, 1, 0], rpy[1]) @ rot_axis([1, 0, 0], rpy[0])))
        a = rng.uniform(-np.pi, np.pi)
        for k, f in enumerate((rotx, roty, rotz)):
            errs.append(rel(f(a), rot_axis(np.eye(3)[k], a)))
        R = random_rotation(rng)
        errs.append(rel(rpy_to_R(R_to_rpy(R)), R))
    # a 90° rotation about z maps x to y (right-handed, active)
    errs.append(rel(rot_axis([0, 0, 1], np.pi / 2) @ [1, 0, 0], [0, 1, 0]))
    # at gimbal lock the angles are not unique but the rotation still round-trips
    for p in (np.pi / 2, -np.pi / 2):
        R = rpy_to_R([0.3, p, -0.7])
        errs.append(rel(rpy_to_R(R_to_rpy(R)), R))
    assert len(errs) == 30 * 6 + 3
    assert max(errs) < 1e-9


def test_rpy_roundtrip_near_gimbal_lock():
    """Within 1e-12..1e-5 rad of pitch ±90° the URDF angles still reproduce the rotation."""
    errs = []
    for d in (1e-12, 1e-10, 1e-8, 1e-7, 1e-6, 1e-5):
        for s in (1.0, -1.0):
            R = rpy_to_R([0.3, s * (np.pi / 2 - d), -0.7])
            errs.append(rel(rpy_to_R(R_to_rpy(R)), R))
    assert len(errs) == 12
    assert max(errs) < 1e-12


# ----------------------------------------------------------------------------------------------
# free-floating base: kinematics of the FREE joint, conservation of momentum
# ----------------------------------------------------------------------------------------------

def _free_floating(rng, gravity=(0.0, 0.0, 0.0)):
    """A free base carrying a branched arm (revolute, prismatic and a welded link)."""
    def spec(name, joint, parent, kind, **kw):
        ev = np.sort(rng.uniform(0.02, 0.2, size=3))
        ev[2] = min(ev[2], ev[0] + ev[1] - 1e-3)
        Q = random_rotation(rng)
        return LinkSpec(name=name, joint=joint, parent=parent, joint_type=kind,
                        origin_xyz=tuple(rng.uniform(-0.5, 0.5, size=3)),
                        origin_rpy=tuple(rng.uniform(-np.pi, np.pi, size=3)), mass=float(rng.uniform(0.5, 3)),
                        com=tuple(rng.uniform(-0.2, 0.2, size=3)), inertia=Q @ np.diag(ev) @ Q.T, **kw)
    return build_model([spec('base', 'base_free', None, 'free'),
                        spec('upper', 'shoulder', 'base', 'revolute', axis=tuple(rng.normal(size=3))),
                        spec('bracket', 'weld', 'upper', 'fixed'),
                        spec('fore', 'elbow', 'bracket', 'revolute', axis=tuple(rng.normal(size=3))),
                        spec('slide', 'rail', 'base', 'prismatic', axis=tuple(rng.normal(size=3)))],
                       gravity=gravity, name='floater')


def _random_free_q(m, rng):
    q = rng.uniform(-np.pi, np.pi, size=m.nq)
    q[:3] = rng.normal(size=3)
    quat = rng.normal(size=4)
    q[3:7] = quat / np.linalg.norm(quat)
    return q


def test_body_twists_are_derivatives_of_body_poses():
    """For every body (FREE, revolute, prismatic, welded): Rᵀ dR/dt = ω× and Rᵀ dp/dt = v_o with
    (ω, v_o) = body_velocities, dR/dt and dp/dt by central differences of body_poses along
    q ⊕ ±h v (integrate_configuration); and qdot is the derivative of integrate_configuration."""
    rng = np.random.default_rng(51)
    m = _free_floating(rng)
    assert m.jtype[0] != FIXED and m.nq == m.nv + 1
    errs, qd_errs = [], []
    hstep = 1e-6
    for _ in range(5):
        q, v = _random_free_q(m, rng), rng.normal(size=m.nv)
        Rp, pp = dyn.body_poses(m, dyn.integrate_configuration(m, q, v, hstep))
        Rm, pm = dyn.body_poses(m, dyn.integrate_configuration(m, q, v, -hstep))
        R, p = dyn.body_poses(m, q)
        vb = dyn.body_velocities(m, q, v)
        for i in range(m.nb):
            W = R[i].T @ (Rp[i] - Rm[i]) / (2 * hstep)
            errs.append(rel(np.concatenate([[W[2, 1], W[0, 2], W[1, 0]], R[i].T @ (pp[i] - pm[i]) / (2 * hstep)]),
                            vb[i]))
            errs.append(rel(W + W.T, np.zeros((3, 3))))
        qd = (dyn.integrate_configuration(m, q, v, hstep) - dyn.integrate_configuration(m, q, v, -hstep)) / (2 * hstep)
        qd_errs.append(rel(dyn.qdot(m, q, v), qd))
    assert len(errs) == 2 * 5 * m.nb and len(qd_errs) == 5
    assert max(errs) < 1e-7
    assert max(qd_errs) < 1e-7


def test_free_floating_momentum_and_energy_conserved():
    """No gravity, no applied forces: the spatial momentum about the root origin and the kinetic
    energy stay constant along a DOP853 trajectory of the free-floating tree (unit quaternion in
    the state, rate from qdot); and the momentum is the sum of M v's free-joint block mapped to
    the root (a check of spatial_momentum against CRBA)."""
    rng = np.random.default_rng(52)
    m = _free_floating(rng)
    q0, v0 = _random_free_q(m, rng), rng.normal(size=m.nv)

    def rhs(t, y):
        q, v = y[:m.nq], y[m.nq:]
        return np.concatenate([dyn.qdot(m, q, v), dyn.aba(m, q, v, np.zeros(m.nv))])
    KE0 = dyn.kinetic_energy(m, q0, v0)

    def ke_leaves_band(t, y):  # stop a broken kernel's blow-up at once
        return 1e-4 * KE0 - abs(dyn.kinetic_energy(m, y[:m.nq], y[m.nq:]) - KE0)
    ke_leaves_band.terminal = True
    ts = np.linspace(0.0, 3.0, 61)
    sol = solve_ivp(rhs, (0.0, 3.0), np.concatenate([q0, v0]), method='DOP853', rtol=1e-11, atol=1e-12, t_eval=ts,
                    events=ke_leaves_band)
    assert sol.status == 0, f'stopped at t = {sol.t[-1]:.3f} s: {sol.message} (energy left its band?)'
    assert sol.y.shape[1] == 61
    H = np.array([dyn.spatial_momentum(m, y[:m.nq], y[m.nq:]) for y in sol.y.T])
    KE = np.array([dyn.kinetic_energy(m, y[:m.nq], y[m.nq:]) for y in sol.y.T])
    quat_norm = np.linalg.norm(sol.y[3:7], axis=0)
    assert np.abs(quat_norm - 1.0).max() < 1e-8
    assert np.abs(H - H[0]).max() / np.abs(H[0]).max() < 1e-8
    assert np.abs(KE - KE[0]).max() / KE[0] < 1e-8
    # the momentum of the whole tree in base coordinates is the base rows of M v ([angular; linear])
    h_base = (dyn.crba(m, q0) @ v0)[:6]
    X0 = dyn.forward_kinematics(m, q0)[0]
    assert rel(X0.T @ h_base, dyn.spatial_momentum(m, q0, v0)) < 1e-12
