"""Prescribed end-effector motion (Huston §19.16–19.18): path tracking, formulations, λ, energy, singularity.

The scene is ``huston_prescribed_planar3`` (three 0.5 m, 1 kg rods, free pins, E on a circle).
Every check compares with something the system does not compute itself:

* the path: E(q(t)) from forward kinematics against the analytic path;
* the two formulations (orthogonal complement vs KKT) against each other, and single solves
  against a dense KKT matrix solved here;
* λ against (a) inverse dynamics ``rnea(q, q', q'') = Bᵀλ`` with q'' from numerical
  differentiation of the recorded trajectory, and (b) Newton–Euler moment balances of the
  rod sub-chains about each pin, written here from scratch in absolute angles;
* the energy: ΔE against ``∫ λ·Ė_des dt`` (published λ, analytic path velocity, Simpson's rule);
* the Baumgarte drift against the closed-form solution of ``φ̈ + 2αφ̇ + β²φ = 0``.
"""
from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import yaml
from scipy.integrate import simpson

from robodyn_ros import dynamics as dyn
from robodyn_ros.constraints import ConstraintWarning
from robodyn_ros.scene import SceneError, load_scene, parse_scene
from robodyn_ros.simulation import Simulator
from robodyn_ros.systems.prescribed import (DRIVE_WRENCH, SINGULAR_RATIO, CirclePath, LinePath,
                                            PrescribedPathSystem, end_point_kinematics)

SCENE = 'huston_prescribed_planar3'
L, MASS = 0.5, 1.0                      # rod length (m) and mass (kg) of the scene
RTOL, ATOL = 1e-10, 1e-12               # DOP853 tolerances of the reference runs
PATH_TOL = 5e-10                        # |E(q(t)) − E_des(t)|∞ over the run (m); measured 5.0e-12
AGREE_Q_TOL, AGREE_LAM_TOL = 1e-10, 1e-10  # complement vs KKT: rad, N (integrated independently); measured ≤ 1.1e-12
T_RUN, DT_OUT = 2.0, 0.01               # one lap of the circle, sampled at 100 Hz


def _data():
    return yaml.safe_load(load_scene(SCENE).text)


def _build(path=None, formulation=None, plane=None, axis=None, baumgarte=None, q=None):
    """The bundled scene with some keys replaced (the extreme and vertical variants)."""
    data = _data()
    part = data['parts'][0]
    if path is not None:
        part['end_effector_path'] = path
    if formulation is not None:
        part['formulation'] = formulation
    if plane is not None:
        part['end_effector_path']['plane'] = plane
    if axis is not None:
        for link in part['links']:
            if link['type'] == 'revolute':
                link['axis'] = axis
    if baumgarte is not None:
        part['baumgarte'] = baumgarte
    if q is not None:
        data['initial_state']['q'] = q
    return parse_scene(yaml.safe_dump(data), file='variant.yaml')


def _run(scene, T, dt=DT_OUT, rtol=RTOL, atol=ATOL, y0=None):
    """Simulate with DOP853 and collect everything the tests need at the sample times."""
    sys_ = scene.system
    sim = Simulator(sys_, scene.y0 if y0 is None else y0, integrator='dop853', rtol=rtol, atol=atol)
    rec = {k: [] for k in ('t', 'q', 'v', 'lam', 'E', 'phi', 'rank', 'singular', 'ratio', 'torque_res',
                           'energy', 'drift', 'wrench_tool', 'solver')}
    n = int(round(T / dt))
    for k in range(n + 1):
        if k:
            sim.advance(k * dt)
        out = sim.outputs()
        q, v = out.position, out.velocity
        sol = sys_.solve(sim.t, sim.y, sim.held_inputs())
        frame, wrench = out.wrenches[DRIVE_WRENCH]
        assert frame == sys_.end_effector
        rec['t'].append(sim.t)
        rec['q'].append(q)
        rec['v'].append(v)
        rec['lam'].append(sol.lam.copy())
        rec['E'].append(dyn.body_poses(sys_.model, q)[1][sys_.body])
        rec['phi'].append(out.extra['constraint_residual'])
        rec['rank'].append(out.extra['constraint_rank'])
        rec['singular'].append(out.extra['singular'])
        rec['ratio'].append(out.extra['constraint_sigma_ratio'])
        rec['torque_res'].append(out.extra['joint_torque_residual'])
        rec['energy'].append(out.energy['kinetic'] + out.energy['potential'])
        rec['drift'].append(sim.energy_report()['drift'])
        rec['wrench_tool'].append(wrench.copy())
        rec['solver'].append(out.extra['solver'])
    rec = {k: (np.array(v) if k != 'solver' else v) for k, v in rec.items()}
    rec['sim'] = sim
    return rec


@pytest.fixture(scope='module')
def runs():
    """The circle scene integrated with both formulations (one lap)."""
    return {f: _run(_build(formulation=f), T_RUN) for f in ('complement', 'kkt')}


# ------------------------------------------------------------------------------------------
# building blocks
# ------------------------------------------------------------------------------------------
def test_scene_builds_the_stated_system():
    sc = load_scene(SCENE)
    s = sc.system
    assert isinstance(s, PrescribedPathSystem)
    assert s.joint_names == ['joint1', 'joint2', 'joint3'] and s.inputs == {}
    assert s.end_effector == 'tool' and s.formulation == 'complement' and s.plane == 'xy'
    assert s.model.total_mass() == pytest.approx(3 * MASS)
    # the initial state is on the path and moves E with the path velocity
    q, v = s.split(sc.y0)
    p, pd, _ = s.path(0.0)
    E, J, _, _ = end_point_kinematics(s.model, q, v, s.body)
    assert np.abs(E[:2] - p).max() < 1e-10 and np.abs(J[:2] @ v - pd).max() < 1e-10
    assert p == pytest.approx([1.0, 0.0]) and np.linalg.norm(pd) == pytest.approx(0.25 * math.pi)


@pytest.mark.parametrize('path', [CirclePath([0.3, -0.2], 0.4, 2.5, 0.3), LinePath([0.1, 0.2], [0.9, -0.4], 0.8, 0.1)])
def test_path_derivatives_match_finite_differences(path):
    h = 1e-5
    for t in (0.0, 0.13, 0.47, 0.8, 1.2):
        p, v, a = path(t)
        pp, vp, _ = path(t + h)
        pm, vm, _ = path(t - h)
        assert np.allclose(v, (pp - pm) / (2 * h), atol=1e-7), t
        assert np.allclose(a, (vp - vm) / (2 * h), atol=1e-5), t
    line = LinePath([0.0, 0.0], [1.0, 2.0], 1.0)
    assert np.allclose(line(-1.0)[0], 0.0) and np.allclose(line(5.0)[0], [1.0, 2.0])
    assert np.allclose(line(1.0)[1], 0.0) and np.allclose(line(0.0)[2], 0.0)


def test_end_point_jacobian_and_velocity_product_by_finite_differences():
    s = load_scene(SCENE).system
    rng = np.random.default_rng(5)
    h = 1e-6
    for _ in range(5):
        q, v = rng.uniform(-2, 2, 3), rng.normal(size=3)
        E, J, Jdv, _ = end_point_kinematics(s.model, q, v, s.body)
        # closed form of the planar three-rod chain in absolute angles
        th = np.cumsum(q)
        assert np.allclose(E[:2], L * np.array([np.cos(th).sum(), np.sin(th).sum()]), atol=1e-14)
        Jn = np.array([(end_point_kinematics(s.model, q + h * e, v, s.body)[0]
                        - end_point_kinematics(s.model, q - h * e, v, s.body)[0]) / (2 * h) for e in np.eye(3)]).T
        Jdvn = (end_point_kinematics(s.model, q + h * v, v, s.body)[1]
                - end_point_kinematics(s.model, q - h * v, v, s.body)[1]) @ v / (2 * h)
        assert np.abs(J - Jn).max() < 1e-8 and np.abs(Jdv - Jdvn).max() < 1e-7


@pytest.mark.filterwarnings('ignore::robodyn_ros.constraints.ConstraintWarning')
def test_single_solves_agree_with_a_dense_kkt_matrix():
    """complement and kkt solves equal the dense [[A, -Bᵀ], [B, 0]] solve at random states."""
    sc = load_scene(SCENE)
    sys_c, sys_k = _build(formulation='complement').system, _build(formulation='kkt').system
    rng = np.random.default_rng(11)
    worst = 0.0
    for k in range(10):
        y = np.concatenate([rng.uniform(-1.5, 1.5, 3), rng.normal(size=3)])
        t = 0.1 * k
        sc_, sk = sys_c.solve(t, y, {}), sys_k.solve(t, y, {})
        if sc_.singular:
            continue
        q, v = y[:3], y[3:]
        A = dyn.crba(sc.system.model, q)
        f = -dyn.rnea(sc.system.model, q, v, np.zeros(3))
        rhs_k = sys_c.constraint(t, q, v)[3] - 2 * sys_c.alpha * sc_.phidot - sys_c.beta ** 2 * sc_.phi
        K = np.block([[A, -sc_.B.T], [sc_.B, np.zeros((2, 2))]])
        x = np.linalg.solve(K, np.concatenate([f, rhs_k]))
        assert sc_.method == 'complement' and sk.method == 'kkt'
        worst = max(worst, np.abs(sc_.a - x[:3]).max(), np.abs(sk.a - x[:3]).max(),
                    np.abs(sc_.lam - x[3:]).max(), np.abs(sk.lam - x[3:]).max())
    assert worst < 1e-9


# ------------------------------------------------------------------------------------------
# the run: path, formulations, λ, energy
# ------------------------------------------------------------------------------------------
def test_end_point_stays_on_its_path(runs):
    r = runs['complement']
    s = r['sim'].system
    des = np.array([s.path(t)[0] for t in r['t']])
    err = np.abs(r['E'][:, :2] - des).max()
    assert err < PATH_TOL, f'path error {err:.3g} m'
    assert np.abs(r['E'][:, 2]).max() < 1e-12            # a planar arm stays in its plane
    assert r['phi'].max() < PATH_TOL                       # the published residual says the same
    assert not r['singular'].any() and (r['rank'] == 2).all()
    assert r['ratio'].min() > 2 * SINGULAR_RATIO           # this path stays clear of the singularity
    # the arm is not trivially still: the free self-motion and E both move substantially
    assert np.ptp(r["q"], axis=0).min() > 0.5


def test_complement_and_kkt_give_the_same_motion_and_force(runs):
    a, b = runs['complement'], runs['kkt']
    assert set(a['solver']) == {'complement'} and set(b['solver']) == {'kkt'}
    dq = np.abs(a['q'] - b['q']).max()
    dl = np.abs(a['lam'] - b['lam']).max()
    assert dq < AGREE_Q_TOL and dl < AGREE_LAM_TOL, (dq, dl)
    assert np.abs(a['lam']).max() > 1.0                    # a real driving force, not zero vs zero


def _five_point_derivative(x, h):
    """Central 5-point derivative of samples x (n, k) at the interior points 2..n-3 (O(h⁴))."""
    return (-x[4:] + 8 * x[3:-1] - 8 * x[1:-3] + x[:-4]) / (12 * h)


def test_lambda_equals_inverse_dynamics_of_the_recorded_motion(runs):
    """rnea(q, q', q'') = Bᵀλ with q'' from numerical differentiation of the trajectory (free pins)."""
    r = runs['complement']
    s = r['sim'].system
    qdd = _five_point_derivative(r['v'], DT_OUT)
    worst, scale = 0.0, 0.0
    for k in range(2, len(r['t']) - 2):
        q, v, t = r['q'][k], r['v'][k], r['t'][k]
        tau = dyn.rnea(s.model, q, v, qdd[k - 2])
        B = s.constraint(t, q, v)[2]
        worst = max(worst, np.abs(tau - B.T @ r['lam'][k]).max())
        scale = max(scale, np.abs(tau).max())
    assert scale > 1.0 and worst < 2e-4 * scale, (worst, scale)


def test_lambda_equals_newton_euler_moment_balances(runs):
    """Σ_{i≥k} [I θ̈_i + (G_i − J_k) × m a_Gi] = (E − J_k) × F for k = 1, 2, 3 (free pins, no gravity in-plane).

    Written here in absolute angles θ = cumsum(q); a_Gi from θ, θ̇ and θ̈ (numerical
    differentiation of the recorded velocities). Three equations for F (2,): least squares,
    and its residual must vanish too.
    """
    r = runs['complement']
    Ic = MASS * L ** 2 / 12.0
    qdd = _five_point_derivative(r['v'], DT_OUT)
    worst, scale, resid = 0.0, 0.0, 0.0
    for k in range(2, len(r['t']) - 2):
        th, w, al = np.cumsum(r['q'][k]), np.cumsum(r['v'][k]), np.cumsum(qdd[k - 2])
        u = np.stack([np.cos(th), np.sin(th)], 1)            # rod directions
        n = np.stack([-np.sin(th), np.cos(th)], 1)           # their normals
        J = np.vstack([[0.0, 0.0], np.cumsum(L * u, 0)])     # pins J1..J3 and E = J[3]
        G = J[:3] + 0.5 * L * u
        # accelerations: pin k+1 = pin k + L(α n − ω² u); centre = pin + L/2 (α n − ω² u)
        aJ = np.vstack([[0.0, 0.0], np.cumsum(L * (al[:, None] * n - (w ** 2)[:, None] * u), 0)])
        aG = aJ[:3] + 0.5 * L * (al[:, None] * n - (w ** 2)[:, None] * u)

        def cross(a, b):
            return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
        M = np.array([[-(J[3] - J[j])[1], (J[3] - J[j])[0]] for j in range(3)])   # (E − J_j) × F = M F
        rhs = np.array([sum(Ic * al[i] + MASS * cross(G[i] - J[j], aG[i]) for i in range(j, 3)) for j in range(3)])
        F, *_ = np.linalg.lstsq(M, rhs, rcond=None)
        worst = max(worst, np.abs(F - r['lam'][k]).max())
        resid = max(resid, np.abs(M @ F - rhs).max())
        scale = max(scale, np.abs(F).max())
    assert scale > 1.0
    assert worst < 2e-4 * scale and resid < 2e-4 * scale, (worst, resid, scale)


def test_published_drive_wrench_is_lambda_in_the_tool_frame(runs):
    r = runs['complement']
    s = r['sim'].system
    for k in range(0, len(r['t']), 20):
        R = dyn.body_poses(s.model, r['q'][k])[0][s.body]
        w = r['wrench_tool'][k]
        assert np.all(w[:3] == 0.0)
        assert np.allclose(R @ w[3:], [r['lam'][k][0], r['lam'][k][1], 0.0], atol=1e-12)
    # the joint wrenches are consistent: RNEA with the drive force reproduces zero pin torques
    assert r['torque_res'].max() < 1e-10


def test_energy_balance_closes_with_the_driving_force_power(runs):
    """ΔE = ∫ λ·Ė_des dt (driving force power; published λ, analytic path velocity)."""
    r = runs['complement']
    s = r['sim'].system
    vdes = np.array([s.path(t)[1] for t in r['t']])
    work = simpson(np.einsum('ij,ij->i', r['lam'], vdes), x=r['t'])
    dE = r['energy'][-1] - r['energy'][0]
    assert abs(dE) > 0.1                                  # the drive really changes the energy
    assert abs(dE - work) < 1e-6 * max(1.0, abs(dE)), (dE, work)
    # and the simulator's own quadrature of input_power closes to the integrator tolerance
    assert np.abs(r['drift']).max() < 1e-8


def test_energy_balance_in_a_vertical_plane_with_gravity():
    """The same arm in the x–z plane (pins along y): gravity does work too, the balance still closes."""
    sc = _build(plane='xz', axis=[0.0, 1.0, 0.0])
    assert sc.system.plane == 'xz'
    r = _run(sc, 1.0, rtol=1e-9, atol=1e-11)
    s = r['sim'].system
    des = np.array([s.path(t)[0] for t in r['t']])
    assert np.abs(r['E'][:, [0, 2]] - des).max() < 1e-7
    vdes = np.array([s.path(t)[1] for t in r['t']])
    work = simpson(np.einsum('ij,ij->i', r['lam'], vdes), x=r['t'])
    kin0 = dyn.kinetic_energy(s.model, r['q'][0], r['v'][0])
    pot = np.array([dyn.potential_energy(s.model, q) for q in r['q']])
    assert np.ptp(pot) > 1.0                               # gravity matters in this variant
    assert abs(r['energy'][-1] - r['energy'][0] - work) < 1e-5
    assert r['energy'][0] == pytest.approx(kin0 + pot[0])
    assert np.abs(r['drift']).max() < 1e-7


def test_baumgarte_drift_follows_its_closed_form():
    """From a start 1 cm off the path, φ obeys φ̈ + 2αφ̇ + α²φ = 0: φ(t) = (φ0 + (φ̇0 + α φ0) t) e^{−αt}."""
    alpha = 10.0
    sc = _build(baumgarte={'alpha': alpha, 'beta': alpha})
    s = sc.system
    y0 = sc.y0.copy()
    y0[:3] += np.array([0.02, -0.01, 0.015])             # off the path, velocity kept
    q0, v0 = y0[:3], y0[3:]
    phi0, phid0 = s.constraint(0.0, q0, v0)[:2]
    assert np.abs(phi0).max() > 5e-3
    r = _run(sc, 0.6, dt=0.02, rtol=1e-10, y0=y0)
    s = r['sim'].system
    des = np.array([s.path(t)[0] for t in r['t']])
    phi = r['E'][:, :2] - des
    t = r['t'][:, None]
    closed = (phi0 + (phid0 + alpha * phi0) * t) * np.exp(-alpha * t)
    assert np.abs(phi - closed).max() < 1e-6 * np.abs(phi0).max()
    assert np.abs(phi[-1]).max() < 0.05 * np.abs(phi0).max()
    # without stabilisation the same offset does not decay
    r0 = _run(_build(baumgarte={'alpha': 0.0, 'beta': 0.0}), 0.6, dt=0.1, rtol=1e-10, y0=y0)
    s0 = r0['sim'].system
    phi_free = r0['E'][-1, :2] - s0.path(r0['t'][-1])[0]
    assert np.abs(phi_free - (phi0 + phid0 * 0.6)).max() < 1e-6


# ------------------------------------------------------------------------------------------
# the singular (stretched) configuration
# ------------------------------------------------------------------------------------------
STRETCH_PATH = {'kind': 'line', 'start': [1.0, 0.0], 'end': [1.5, 0.0], 'duration': 1.0}
LAMBDA_BOUND = 500.0    # N: stated bound on the driving force through the stretched configuration
STRETCH_PATH_TOL = 0.08  # m: how far E may lag its path while the constraint is damped (5 % of reach)


def test_stretched_arm_warns_once_reports_rank_and_stays_finite():
    sc = _build(path=STRETCH_PATH)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        r = _run(sc, 1.6, dt=0.02, rtol=1e-8, atol=1e-10)
    cw = [w for w in caught if issubclass(w.category, ConstraintWarning)]
    assert len(cw) == 1, [str(w.message) for w in cw]   # once per episode
    assert 'lost rank' in str(cw[0].message) and 'damped least squares' in str(cw[0].message)
    # reported in outputs.extra
    assert r['singular'].any() and (r['rank'][r['singular']] == 1).all()
    assert 'kkt_damped' in r['solver'] and r['ratio'].min() < 0.5 * SINGULAR_RATIO
    # finite and bounded: state, λ, energy; E stays near its path (it reaches full stretch)
    for k in ('q', 'v', 'lam', 'energy', 'wrench_tool'):
        assert np.all(np.isfinite(r[k])), k
    assert np.abs(r['lam']).max() < LAMBDA_BOUND
    s = r['sim'].system
    des = np.array([s.path(t)[0] for t in r['t']])
    assert np.abs(r['E'][:, :2] - des).max() < STRETCH_PATH_TOL
    assert np.linalg.norm(r['E'][-1, :2]) > 1.5 - STRETCH_PATH_TOL
    # the equations of motion still hold exactly, so even the damped run balances its energy
    assert np.abs(r['drift']).max() < 1e-6
    # a new episode warns again
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        r['sim'].reset()
        r['sim'].advance(1.2)
    assert len([w for w in caught if issubclass(w.category, ConstraintWarning)]) == 1


def test_damping_is_continuous_at_the_threshold_and_only_below_it():
    """μ² → 0 as σ_min/σ_max → SINGULAR_RATIO from below; above it the exact solve is used."""
    s = _build(formulation='complement').system
    # configurations approaching the stretch: joint angles ε(1, −2, 1) keep E on the x axis
    ratios, damp, methods = [], [], []
    with pytest.warns(ConstraintWarning, match='lost rank'):
        sols = [s.solve(0.0, np.concatenate([eps * np.array([1.0, -2.0, 1.0]), np.zeros(3)]), {})
                for eps in np.linspace(0.02, 0.6, 60)]
    for sol in sols:
        ratios.append(sol.ratio)
        damp.append(sol.damping)
        methods.append(sol.method)
        assert np.all(np.isfinite(sol.a)) and np.all(np.isfinite(sol.lam))
    ratios, damp = np.array(ratios), np.array(damp)
    assert np.all(np.diff(ratios) > 0)                     # monotone approach
    below = ratios < SINGULAR_RATIO
    assert below.any() and (~below).any()
    assert np.all(damp[~below] == 0.0) and np.all(damp[below] > 0.0)
    assert all(m == 'kkt_damped' for m, b in zip(methods, below) if b)
    assert all(m == 'complement' for m, b in zip(methods, below) if not b)
    j = np.flatnonzero(below)[-1]                          # last damped sample, just below the threshold
    assert damp[j] < 0.2 * damp[0]


# ------------------------------------------------------------------------------------------
# scene validation
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize('change, where', [
    (lambda p: p.update(formulation='lagrange'), 'parts[0].formulation'),
    (lambda p: p['end_effector_path'].update(kind='spiral'), 'parts[0].end_effector_path.kind'),
    (lambda p: p['end_effector_path'].update(radius=-0.1), 'parts[0].end_effector_path.radius'),
    (lambda p: p['end_effector_path'].update(plane='xw'), 'parts[0].end_effector_path.plane'),
    (lambda p: p['end_effector_path'].update(speed=1.0), 'parts[0].end_effector_path.speed'),
    (lambda p: p.update(end_effector='gripper'), 'parts[0].end_effector'),
    (lambda p: p['end_effector_path'].update(center=[3.0, 0.0]), 'initial_state'),
])
def test_scene_errors_name_the_key(change, where):
    data = _data()
    change(data['parts'][0])
    with pytest.raises(SceneError) as e:
        parse_scene(yaml.safe_dump(data), file='bad.yaml')
    assert f'bad.yaml: {where}' in str(e.value)
