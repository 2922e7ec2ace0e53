"""The huston_human17 scene (Huston ch. 20, seed 000): structure, conservation laws, limits, singularity.

* structure: the lower body array L(K) of sec. 20.3 and the body names of table 20.3.1, a free
  pelvis and 16 spherical joints (54 DOF), de Leva (1996) male masses summing to 73 kg;
* zero gravity, joint torques only (internal): linear and angular momentum, and the CoM velocity,
  constant to 3e-11 relative over 10 s (RK4, h = 0.1 ms; measured 3e-13) on the scene's model
  without its stops (nothing to hit), and to 5e-13 on the scene itself (stops hit) with DOP853
  (measured 5e-15);
* with the stops: ``E − E0 = W_torques + W_limits + W_damping`` with ``W_limits < 0`` (the stops
  dissipate) to 2e-13 of the energy scale (measured 2e-15), the three works as separate quadratures;
* the quaternions stay unit to 1e-12;
* the pelvis pitches through ±90°: the quaternion run passes smoothly, while the same body
  orientation integrated in Bryan angles (Huston eq. 20.3.2, the oracle that has the singularity)
  sees its rates blow up and loses the orientation.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from robodyn_ros import kernels
from robodyn_ros.model import FREE, SPHERICAL, bryan_angles, build_model
from robodyn_ros.scene import load_scene
from robodyn_ros.simulation import Simulator
from robodyn_ros.spatial import quat_mul, quat_to_R
from robodyn_ros.systems.arm import ArmSystem

# numba is a hard dependency: without it these tests fail, never skip (spherical joints need the compiled kernels)
assert kernels.AVAILABLE, kernels.UNAVAILABLE_REASON

L_K = [0, 0, 1, 2, 3, 4, 5, 3, 7, 3, 9, 10, 1, 12, 13, 1, 15, 16]   # Huston sec. 20.3, K = 0..17
NAMES = ['lower_torso', 'mid_torso', 'upper_torso', 'upper_left_arm', 'lower_left_arm', 'left_hand', 'neck', 'head',
         'upper_right_arm', 'lower_right_arm', 'right_hand', 'upper_right_leg', 'lower_right_leg', 'right_foot',
         'upper_left_leg', 'lower_left_leg', 'left_foot']


@pytest.fixture(scope='module')
def scene():
    return load_scene('huston_human17')


def without_stops(system):
    """The scene's system with the limit moments removed (same tree, damping, actuation)."""
    m = system.model
    specs = [dataclasses.replace(s, limit_stiffness=0.0, limit_damping=0.0) for s in m.specs]
    return ArmSystem(build_model(specs, gravity=m.gravity, name=m.name, root=m.root), actuated=system.actuated,
                     backend='numba')


def test_structure_is_hustons_17_body_model(scene):
    m = scene.system.model
    assert list(m.link_names) == NAMES
    assert [int(p) + 1 for p in m.parent] == L_K[1:]
    assert m.jtype[0] == FREE and all(m.jtype[1:] == SPHERICAL)
    assert (m.nb, m.nv, m.nq) == (17, 54, 7 + 16 * 4)
    assert m.total_mass() == pytest.approx(73.0, abs=1e-5)
    # de Leva Table 4 (male) fractions of 73 kg, the neck cut out of the head segment
    mass = dict(zip(m.link_names, m.I[:, 5, 5]))
    assert mass['upper_left_arm'] == pytest.approx(0.0271 * 73, rel=1e-4)
    assert mass['upper_right_leg'] == pytest.approx(0.1416 * 73, rel=1e-4)
    assert mass['neck'] + mass['head'] == pytest.approx(0.0694 * 73, rel=1e-4)
    assert mass['lower_torso'] + mass['mid_torso'] + mass['upper_torso'] == pytest.approx(0.4346 * 73, rel=1e-4)
    assert scene.settings['duration'] == 10.0
    assert scene.system.urdf().count('type="revolute"') == 48   # 16 spherical joints x 3, no floating joint


def _run(system, y0, script, t_end, dt, integrator='rk4', period=0.01, every=None, **kw):
    sim = Simulator(system, y0, integrator=integrator, dt=dt, **kw)
    n = int(round(t_end / period))
    out = []
    for k in range(1, n + 1):
        if script is not None:
            sim.set_command('effort', script(sim.t, sim.y)['effort'])
        sim.advance(k * period)
        if every is not None:
            every(sim)
    return sim, out


def _momentum_errors(system, y0, sim_y_list):
    km = system._km
    nq = system.model.nq
    p0, L0, c0 = km.momentum(y0[:nq], y0[nq:])
    return p0, L0, c0, [km.momentum(y[:nq], y[nq:]) for y in sim_y_list]


def test_momentum_and_com_velocity_constant_without_stops(scene):
    """No stops to hit, shoulder torques on (internal), zero g, 10 s of RK4 at h = 0.1 ms."""
    sys_ = without_stops(scene.system)
    states, times = [], []

    def grab(sim):
        if abs(sim.t - round(sim.t)) < 1e-9:
            states.append(sim.y.copy())
            times.append(sim.t)
    sim, _ = _run(sys_, scene.y0, scene.script, 10.0, 1e-4, every=grab)
    p0, L0, c0, got = _momentum_errors(sys_, scene.y0, states)
    M = sys_.model.total_mass()
    v0 = p0 / M
    assert len(got) == 10 and np.linalg.norm(p0) > 10.0 and np.linalg.norm(L0) > 10.0
    worst_p = max(np.linalg.norm(p - p0) for p, _, _ in got) / np.linalg.norm(p0)
    worst_L = max(np.linalg.norm(L - L0) for _, L, _ in got) / np.linalg.norm(L0)
    worst_c = max(np.linalg.norm(c - (c0 + v0 * t)) / (np.linalg.norm(c0) + np.linalg.norm(v0) * t)
                  for (_, _, c), t in zip(got, times))
    print(f'momentum over 10 s: p {worst_p:.1e}, L {worst_L:.1e}, CoM {worst_c:.1e} (relative)')
    assert worst_p < 3e-11, worst_p     # the bounds: ~100x the figures docs/accuracy.md quotes
    assert worst_L < 3e-11, worst_L
    assert worst_c < 3e-11, worst_c
    # the torques did move the arms (the run is not trivially rigid)
    out = sys_.outputs(sim.t, sim.y, sim.held_inputs(), wrenches=False)
    pos = dict(zip(out.joint_names, out.position))
    assert abs(pos['left_shoulder_x']) > 0.5
    # quaternions unit after every projection
    q = sim.y[:sys_.model.nq]
    norms = [np.linalg.norm(q[s:s + 4]) for s in list(sys_.model.q_idx[1:]) + [3]]
    assert max(abs(n - 1.0) for n in norms) < 1e-12


def test_energy_balance_with_stops(scene):
    """The scene itself for 3 s (both arms driven into their abduction stops): DOP853 on
    ``[y, W_torques, W_limits, W_damping]``; E − E0 equals their sum to 2e-13 of the energy scale,
    the stops dissipate (W_limits < 0), momentum stays constant and a stop is really hit."""
    from scipy.integrate import solve_ivp
    sys_ = scene.system
    m = sys_.model
    nq, ny = m.nq, sys_.ny
    D = m.damping
    hit = {'max_limit_power': 0.0}

    def f(t, z):
        y = z[:ny]
        u = scene.script(t, y)
        dz = np.empty(ny + 3)
        dz[:ny] = sys_.rhs(t, y, u)
        v = y[nq:]
        dz[ny] = float(v @ (sys_.B @ u['effort']))
        lp = sys_.limit_power(y)
        hit['max_limit_power'] = max(hit['max_limit_power'], abs(lp))
        dz[ny + 1] = lp
        dz[ny + 2] = -float(v @ (D * v))
        return dz
    # the command switches at 0.6 and 2.0 s: integrate piecewise so that no step straddles a switch
    z = np.concatenate([scene.y0, np.zeros(3)])
    E0 = sys_.total_energy(scene.y0)
    for a, b in ((0.0, 0.6), (0.6, 2.0), (2.0, 2.6), (2.6, 3.0)):
        sol = solve_ivp(f, (a, b), z, method='DOP853', rtol=1e-12, atol=1e-12)
        assert sol.success, sol.message
        z = sol.y[:, -1].copy()
        z[:ny] = sys_.project(z[:ny])
    E1 = sys_.total_energy(z[:ny])
    Wt, Wl, Wd = z[ny:]
    scale = max(abs(E0), abs(E1), abs(Wt))
    assert Wl < -1e-3 * scale, (Wl, scale)          # the stops took energy out
    assert Wd < 0.0
    assert hit['max_limit_power'] > 1.0
    err = abs(E1 - E0 - (Wt + Wl + Wd)) / scale
    print(f'energy balance with stops: {err:.1e} of {scale:.3g} J; W_torques {Wt:.4g}, W_limits {Wl:.4g}, '
          f'W_damping {Wd:.4g} J')
    assert err < 2e-13, err
    p0, L0, _ = sys_._km.momentum(scene.y0[:nq], scene.y0[nq:])
    p1, L1, _ = sys_._km.momentum(z[:nq], z[nq:ny])
    dL, dp = np.linalg.norm(L1 - L0) / np.linalg.norm(L0), np.linalg.norm(p1 - p0) / np.linalg.norm(p0)
    print(f'momentum with stops: p {dp:.1e}, L {dL:.1e} (relative)')
    assert dL < 5e-13 and dp < 5e-13


def _bryan_rates(abg, w):
    """(α̇, β̇, γ̇) of R = Rx(α) Ry(β) Rz(γ) from the body angular velocity w (singular at cos β = 0)."""
    a, b, g = abg
    cb, sb, cg, sg = math.cos(b), math.sin(b), math.cos(g), math.sin(g)
    ad = (cg * w[0] - sg * w[1]) / cb
    return np.array([ad, sg * w[0] + cg * w[1], w[2] - sb * ad])


def _R_bryan(abg):
    a, b, g = abg
    ca, sa, cb, sb, cg, sg = (math.cos(a), math.sin(a), math.cos(b), math.sin(b), math.cos(g), math.sin(g))
    Rx = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
    Ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    Rz = np.array([[cg, -sg, 0], [sg, cg, 0], [0, 0, 1]])
    return Rx @ Ry @ Rz


def test_tumbling_through_pitch_90_no_singularity(scene):
    """The pelvis' orientation over 6 s of the scene (RK4, 1 ms, as the node runs it) passes within
    a degree of β = ±90°. Oracles from its sampled angular velocity ω(t) (linear between samples),
    both RK4 at 1 ms: quaternion kinematics ``q̇ = ½ q ⊗ ω`` follows the simulated orientation;
    Bryan-angle kinematics (eq. 20.3.2) sees its rates blow up near the lock and loses it."""
    sys_ = scene.system
    h = 1e-3
    qs, ws = [scene.y0[3:7].copy()], [scene.y0[sys_.model.nq:sys_.model.nq + 3].copy()]

    def grab(sim):
        qs.append(sim.y[3:7].copy())
        ws.append(sim.y[sys_.model.nq:sys_.model.nq + 3].copy())
        assert abs(np.linalg.norm(sim.y[3:7]) - 1.0) < 1e-12
    _run(sys_, scene.y0, scene.script, 6.0, h, period=h, every=grab)
    qs, ws = np.array(qs), np.array(ws)
    betas = np.array([bryan_angles(q)[1] for q in qs])
    assert np.min(np.abs(np.cos(betas))) < 0.02, np.min(np.abs(np.cos(betas)))   # within 1.2° of the lock

    def oracle(stride):
        """Max orientation errors (quaternion, Bryan) and the largest Bryan rate, RK4 at stride·h."""
        H = stride * h

        def w_at(k, frac):
            return ws[k] + frac * (ws[k + stride] - ws[k])
        q = qs[0].copy()
        abg = np.array(bryan_angles(qs[0]))
        err_q = err_b = max_rate = 0.0
        for k in range(0, len(qs) - stride, stride):
            def fq(qq, frac):
                w = w_at(k, frac)
                return 0.5 * quat_mul(qq, np.array([w[0], w[1], w[2], 0.0]))

            def fb(x, frac):
                return _bryan_rates(x, w_at(k, frac))
            k1 = fq(q, 0.0)
            k2 = fq(q + 0.5 * H * k1, 0.5)
            k3 = fq(q + 0.5 * H * k2, 0.5)
            k4 = fq(q + H * k3, 1.0)
            q = q + H / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            q /= np.linalg.norm(q)
            b1 = fb(abg, 0.0)
            b2 = fb(abg + 0.5 * H * b1, 0.5)
            b3 = fb(abg + 0.5 * H * b2, 0.5)
            b4 = fb(abg + H * b3, 1.0)
            abg = abg + H / 6 * (b1 + 2 * b2 + 2 * b3 + b4)
            max_rate = max(max_rate, float(np.abs(b1).max()))
            Rsim = quat_to_R(qs[k + stride])
            err_q = max(err_q, float(np.abs(quat_to_R(q) - Rsim).max()))
            err_b = max(err_b, float(np.abs(_R_bryan(abg) - Rsim).max()) if np.all(np.isfinite(abg)) else np.inf)
        return err_q, err_b, max_rate
    err_q, err_b, max_rate = oracle(1)      # at the simulator's own step
    err_q10, err_b10, _ = oracle(10)        # at the publication period, 10 ms
    w_max = float(np.abs(ws).max())
    print(f'quaternion oracle err {err_q:.2e} / {err_q10:.2e}, Bryan {err_b:.2e} / {err_b10:.2e} (1 ms / 10 ms), '
          f'Bryan rate max {max_rate:.3g} vs |ω| max {w_max:.3g}')
    assert err_q < 1e-5 and err_q10 < 1e-3, (err_q, err_q10)   # quaternions: the run is followed
    assert max_rate > 40 * w_max, (max_rate, w_max)   # the Bryan rates blow up near β = ±90° (~1/cos β)
    assert err_b10 > 20 * err_q10, (err_b10, err_q10)   # ... and its error at 10 ms is ~80x the quaternion one
