"""The free-flying base of seed 003: conservation laws, closed forms, two formulations, Pinocchio.

Each test compares against something independent of the code under test: conservation laws
(momentum of a free-floating system), closed-form motion (a torque-free axisymmetric body, a
rotor on a platform), a second formulation of the same mechanics (minimal coordinates with the
recursive algorithms vs the seed's extended coordinates with Lagrange multipliers), Pinocchio
loading our URDF with its own free-flyer joint, and statics (the table carries the weight).
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from robodyn_ros import dynamics as dyn
from robodyn_ros.integrators import make_integrator
from robodyn_ros.model import LinkSpec
from robodyn_ros.scene import SceneError, load_scene, parse_scene
from robodyn_ros.spatial import R_to_quat, quat_to_R, rot_axis, rotz, roty
from robodyn_ros.systems.augmented import AugmentedFreeFlyerSystem
from robodyn_ros.systems.freeflyer import FreeFlyerSystem, free_flyer_model

CLASSES = {'minimal': FreeFlyerSystem, 'augmented': AugmentedFreeFlyerSystem}
#: joint torques of the momentum and agreement runs: A cos(w t), internal to the system
TAU_A = np.array([0.1, 0.08, 0.05, 0.004, 0.0005])
TAU_W = np.array([1.3, 1.7, 2.1, 2.9, 3.7])


def system_of(scene, formulation, **opts):
    """The scene's model in the given formulation (same environment and options unless overridden)."""
    s = load_scene(scene)
    return CLASSES[formulation](s.system.model, **{**s.system.options, **opts}), s


def inputs(t, wrench=False):
    """Time-varying joint torques (and optionally thruster wrench) for the runs."""
    bw = np.array([1.5 * np.sin(0.9 * t), -1.0, 0.5 * np.cos(1.1 * t), 0.05, -0.08 * np.sin(t), 0.1]) \
        if wrench else np.zeros(6)
    return {'effort': TAU_A * np.cos(TAU_W * t), 'base_wrench': bw}


def run(system, y0, times, u=inputs, integrator=('dop853', None, 1e-10, 1e-12)):
    """States at ``times`` from y0 at times[0] with ``u(t)`` evaluated continuously."""
    integ = make_integrator(*integrator)
    f = lambda t, y: system.rhs(t, y, u(t))  # noqa: E731
    ys = [np.array(y0)]
    for t0, t1 in zip(times[:-1], times[1:]):
        y, _ = integ.advance(f, t0, ys[-1], t1, project=system.project)
        ys.append(y)
    return ys


def vec(extra, key):
    return np.array([extra[f'{key}_{a}'] for a in 'xyz'])


def moving_state(system):
    """A generic orbit state: the scene posture, base tumbling and drifting, joints moving."""
    s = load_scene('unfried_free_flyer')
    q = s.system.minimal(s.y0)[0]
    v = np.array([0.3, -0.2, 0.5, 0.05, 0.02, -0.03, 0.2, -0.1, 0.3, 0.4, -0.5])
    return system.initial_state(q, v)


# ---------------------------------------------------------------------------------------------
# zero gravity: momentum
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize('formulation', ['minimal', 'augmented'])
def test_zero_g_momentum_conserved_and_com_drifts_uniformly(formulation):
    """Internal joint torques only: p and L about the CoM constant to 1e-9 (DOP853), the CoM moves
    with p/m; cross-checked with dynamics.spatial_momentum (an independent sum over bodies)."""
    sy, _ = system_of('unfried_free_flyer', formulation)
    y0 = moving_state(sy)
    times = np.linspace(0.0, 2.0, 5)
    ys = run(sy, y0, times)
    e0 = sy.outputs(0.0, y0, inputs(0.0)).extra
    p0, L0, c0 = vec(e0, 'momentum_linear'), vec(e0, 'momentum_angular_com'), vec(e0, 'com')
    assert np.linalg.norm(p0) > 0.1 and np.linalg.norm(L0) > 0.1  # a real test: nonzero momenta
    for t, y in zip(times, ys):
        e = sy.outputs(t, y, inputs(t)).extra
        p, L, c = vec(e, 'momentum_linear'), vec(e, 'momentum_angular_com'), vec(e, 'com')
        # ~100x the figure of docs/accuracy.md (2e-15: DOP853 rtol 1e-10 keeps these at round-off)
        assert np.linalg.norm(p - p0) <= 2e-13 * np.linalg.norm(p0), t
        assert np.linalg.norm(L - L0) <= 2e-13 * np.linalg.norm(L0), t
        assert np.linalg.norm(c - (c0 + p0 / sy.mass * t)) <= 2e-13 * max(1.0, np.linalg.norm(c0)), t
        # the same from the minimal model's spatial momentum about the odom origin
        q, v = sy.minimal(y)
        h = dyn.spatial_momentum(sy.model, q, v)
        com, _ = dyn.center_of_mass(sy.model, q)
        assert np.allclose(h[3:], p, rtol=0, atol=1e-12)
        assert np.allclose(h[:3] - np.cross(com, h[3:]), L, rtol=0, atol=1e-12)
    # the arm really moved
    assert np.abs(sy.minimal(ys[-1])[0][7:] - sy.minimal(y0)[0][7:]).max() > 0.3


def test_rotor_on_platform_counter_rotates_by_momentum_balance():
    """A rotor whose axis passes through both CoMs: I_b ω_b + I_r (ω_b + θ̇) = 0, closed form."""
    Ib, Ir = 2.0, 0.5
    base = LinkSpec(name='base_link', joint='base_joint', parent=None, joint_type='free', mass=10.0,
                    inertia=np.diag([1.5, 1.7, Ib]))
    rotor = LinkSpec(name='rotor', joint='spin', parent='base_link', origin_xyz=(0.0, 0.0, 0.2), axis=(0, 0, 1),
                     mass=3.0, inertia=np.diag([0.3, 0.3, Ir]))
    m = free_flyer_model(base, [rotor], name='rotor_platform')
    for cls in CLASSES.values():
        sy = cls(m, environment='orbit')
        y0 = sy.initial_state()
        tau = 0.4
        times = np.linspace(0.0, 2.0, 5)
        ys = run(sy, y0, times, u=lambda t: {'effort': np.array([tau]), 'base_wrench': np.zeros(6)})
        for t, y in zip(times, ys):
            q, v = sy.minimal(y)
            wz, thd = v[2], v[6]
            # the rotor's relative rate is driven by tau with the reduced inertia Ib Ir / (Ib + Ir)
            assert thd == pytest.approx(tau * t * (Ib + Ir) / (Ib * Ir), abs=1e-9)
            assert wz == pytest.approx(-Ir * thd / (Ib + Ir), abs=1e-9)
            assert np.allclose(v[[0, 1, 3, 4, 5]], 0.0, atol=1e-12)
            yaw = 2.0 * np.arctan2(q[5], q[6])
            assert yaw == pytest.approx(-Ir * q[7] / (Ib + Ir), abs=1e-9)


def test_seed_arm_base_counter_rotates_with_momentum_balance():
    """From rest, shoulder yaw torque: the base yaws the other way, and its twist is the
    momentum balance's: v_b = −H_bb⁻¹ H_bm θ̇ with the blocks of the CRBA mass matrix."""
    sy, s = system_of('unfried_free_flyer', 'minimal')
    y0 = sy.initial_state(s.system.minimal(s.y0)[0])  # the scene's (augmented) state -> minimal
    u = lambda t: {'effort': np.array([0.05, 0.0, 0.0, 0.0, 0.0]), 'base_wrench': np.zeros(6)}  # noqa: E731
    times = np.linspace(0.0, 1.5, 4)
    for t, y in zip(times[1:], run(sy, y0, times, u=u)[1:]):
        q, v = sy.minimal(y)
        R = quat_to_R(q[3:7])
        assert v[6] > 0.01 and (R @ v[0:3])[2] < -1e-3  # joint 1 forward, base yaw backward
        H = dyn.crba(sy.model, q)
        vb = -np.linalg.solve(H[:6, :6], H[:6, 6:] @ v[6:])
        assert np.allclose(v[:6], vb, rtol=0, atol=1e-10), t
        # angular momentum about the system CoM: the platform's share cancels the arm's
        ms, c, cd, Ls = sy.body_coms(q, v)
        com = (ms[:, None] * c).sum(0) / ms.sum()
        Lb = Ls + ms[:, None] * np.cross(c - com, cd)
        assert np.linalg.norm(Lb[0]) > 1e-3
        assert np.allclose(Lb[0], -Lb[1:].sum(0), rtol=0, atol=1e-12)


# ---------------------------------------------------------------------------------------------
# minimal vs augmented
# ---------------------------------------------------------------------------------------------
def _table_state(sy):
    """A table state: platform sliding and yawing, arm moving (velocities consistent with the table)."""
    s = load_scene('unfried_air_bearing')
    q = s.system.minimal(s.y0)[0]
    q[0:2] = [0.2, -0.1]
    q[3:7] = R_to_quat(rotz(0.6))
    v = np.array([0.0, 0.0, 0.4, 0.05, -0.03, 0.0, 0.2, -0.1, 0.3, 0.4, -0.5])
    return sy.initial_state(q, v)


@pytest.mark.parametrize('scene', ['unfried_free_flyer', 'unfried_air_bearing'])
def test_minimal_and_augmented_agree(scene):
    """Same trajectory and the same joint reaction forces: the multipliers of the augmented
    formulation (world) equal the force part of the minimal formulation's transmitted wrenches
    rotated to world; the table's wrench too; the recovered moments' axis parts are the torques."""
    A, _ = system_of(scene, 'minimal')
    B, _ = system_of(scene, 'augmented')
    ya = _table_state(A) if A.table else moving_state(A)
    yb = _table_state(B) if B.table else moving_state(B)
    u = lambda t: inputs(t, wrench=True)  # noqa: E731
    times = np.linspace(0.0, 1.2, 4)
    ra = run(A, ya, times, u=u)
    rb = run(B, yb, times, u=u)
    worst = {'q': 0.0, 'v': 0.0, 'force': 0.0, 'wrench': 0.0}  # wrench errors relative to the largest wrench
    for t, y1, y2 in zip(times, ra, rb):
        q1, v1 = A.minimal(y1)
        q2, v2 = B.minimal(y2)
        worst['q'] = max(worst['q'], np.abs(q1 - q2).max())
        worst['v'] = max(worst['v'], np.abs(v1 - v2).max())
        oa, ob = A.outputs(t, y1, u(t)), B.outputs(t, y2, u(t))
        a, lam, info, kin, *_ = B.solve(y2, u(t))
        assert info.m == B.n_constraints and info.rank == info.m
        lamj = B.joint_forces_world(lam)
        R, _ = dyn.body_poses(A.model, q1)
        scale = max(np.abs(w).max() for _, w in oa.wrenches.values())
        for i in range(1, A.model.nb):
            name = A.model.joint_names[i]
            fmin = oa.wrenches[name][1]
            worst['force'] = max(worst['force'], np.abs(R[i] @ fmin[3:] - lamj[i - 1]).max() / scale)
            worst['wrench'] = max(worst['wrench'], np.abs(fmin - ob.wrenches[name][1]).max() / scale)
            # the moment recovered from Euler's equations carries the joint torque on its axis
            k = A.joint_names.index(name)
            tau = u(t)['effort'][k] - A.model.damping[6 + k] * v2[6 + k]
            assert ob.wrenches[name][1][:3] @ A.model.axis[i] == pytest.approx(tau, abs=1e-10)
        if A.table:
            worst['wrench'] = max(worst['wrench'],
                                  np.abs(oa.wrenches['base_plane'][1] - ob.wrenches['base_plane'][1]).max() / scale)
    print(scene, {k: f'{v:.2e}' for k, v in worst.items()})
    # ~100x the measured: orbit q 1.9e-15, v 4.8e-14, forces 2.5e-13; table (Baumgarte, stiffer)
    # q 1.0e-10, v 6.9e-10, forces 9.5e-12
    tol = {'unfried_free_flyer': {'q': 2e-13, 'v': 5e-12, 'force': 3e-11, 'wrench': 3e-11},
           'unfried_air_bearing': {'q': 1e-8, 'v': 7e-8, 'force': 1e-9, 'wrench': 1e-9}}[scene]
    assert all(worst[k] < tol[k] for k in tol), (worst, tol)
    assert np.abs(A.minimal(ra[-1])[0][7:] - A.minimal(ra[0])[0][7:]).max() > 0.1  # it moved


# ---------------------------------------------------------------------------------------------
# Pinocchio with its own free-flyer joint on our URDF
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize('scene', ['unfried_free_flyer', 'unfried_air_bearing'])
def test_against_pinocchio_free_flyer(scene):
    """Mass matrix, forward dynamics and transmitted joint wrenches against Pinocchio.

    Pinocchio: q = [x y z qx qy qz qw, θ], v = [v_lin (local); ω (local); θ̇], forces (linear,
    angular); ours v = [ω; v_lin; θ̇], forces [angular; linear]. The URDF is the one published
    as robot_description (base_link as root, carrying the platform's inertia).
    """
    s = load_scene(scene)
    model = s.system.model
    pm = pin.buildModelFromXML(s.system.urdf(), pin.JointModelFreeFlyer())
    pm.gravity.linear = np.asarray(model.gravity, dtype=float)
    pd = pm.createData()
    assert (pm.nq, pm.nv) == (model.nq, model.nv) == (12, 11)
    perm = np.r_[3, 4, 5, 0, 1, 2, 6:11]  # our v[k] = Pinocchio v[perm[k]]
    jid = {i: pm.getJointId(model.joint_names[i]) for i in range(1, model.nb)}
    rng = np.random.default_rng(7)
    worst = {'M': 0.0, 'aba': 0.0, 'wrench': 0.0, 'aug_wrench': 0.0}
    for _ in range(4):
        q = model.neutral()
        q[:3] = rng.normal(size=3)
        quat = rng.normal(size=4)
        q[3:7] = quat / np.linalg.norm(quat)
        q[7:] = rng.uniform(-np.pi, np.pi, size=5)
        v, tau = rng.normal(size=11), rng.normal(size=11)
        tau[:6] = 0.0
        tau_tot = tau + dyn.passive_forces(model, v)  # the systems add joint damping themselves
        wr = rng.normal(size=6)  # base wrench [f; t] in base_link
        vp = np.empty(11)
        vp[perm] = v
        taup = np.empty(11)
        taup[perm] = tau_tot
        Mp = pin.crba(pm, pd, q)
        Mp = np.triu(Mp) + np.triu(Mp, 1).T
        worst['M'] = max(worst['M'], np.abs(dyn.crba(model, q) - Mp[np.ix_(perm, perm)]).max())
        fext = pin.StdVec_Force([pin.Force.Zero() for _ in range(pm.njoints)])
        fext[1] = pin.Force(wr[:3], wr[3:])
        ap = pin.aba(pm, pd, q, vp, taup, fext)
        f_ext = np.zeros((model.nb, 6))
        f_ext[0] = np.r_[wr[3:], wr[:3]]
        a = dyn.aba(model, q, v, tau_tot, f_ext)
        worst['aba'] = max(worst['aba'], np.abs(a - ap[perm]).max())
        pin.rnea(pm, pd, q, vp, ap, fext)
        _, f = dyn.rnea_wrenches(model, q, v, a, f_ext)
        for i, j in jid.items():
            fj = np.r_[pd.f[j].angular, pd.f[j].linear]
            worst['wrench'] = max(worst['wrench'], np.abs(f[i] - fj).max())
        if not np.any(model.gravity):  # the augmented formulation's wrenches, in orbit
            B = AugmentedFreeFlyerSystem(model, environment='orbit')
            u = {'effort': tau[6:], 'base_wrench': wr}
            ob = B.outputs(0.0, B.initial_state(q, v), u)
            for i, j in jid.items():
                fj = np.r_[pd.f[j].angular, pd.f[j].linear]
                worst['aug_wrench'] = max(worst['aug_wrench'], np.abs(ob.wrenches[model.joint_names[i]][1] - fj).max())
    print(scene, {k: f'{v:.2e}' for k, v in worst.items()})
    assert max(worst.values()) < 3e-11   # measured 3.1e-13 (ABA)


# ---------------------------------------------------------------------------------------------
# torque-free rigid body
# ---------------------------------------------------------------------------------------------
_BODY = """
name: spinning_body
gravity: [0.0, 0.0, 0.0]
parts:
  - {kind: free_base, name: body, environment: orbit, formulation: FORM, mass: 12.0,
     inertia: [IT, IT, IA, 0.0, 0.0, 0.0]}
"""


@pytest.mark.parametrize('formulation', ['minimal', 'augmented'])
def test_torque_free_axisymmetric_body_closed_form(formulation):
    """Kane & Levinson: body-frame ω precesses about the symmetry axis at λ = (I_a − I_t)/I_t ω_3,
    ω_3 constant; h = R I ω fixed in space; R(t) = exp(t [h]× / I_t) R0 exp(−λ t [e3]×)."""
    It, Ia = 0.8, 1.4
    sy = parse_scene(_BODY.replace('FORM', formulation).replace('IT', str(It)).replace('IA', str(Ia))).system
    R0 = rot_axis(np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5]), 0.9)
    w0 = np.array([0.7, -0.4, 2.5])
    q0 = np.r_[0.1, 0.2, 0.3, R_to_quat(R0)]
    y0 = sy.initial_state(q0, np.r_[w0, 0.2, -0.1, 0.05])
    lam = (Ia - It) / It * w0[2]
    h = R0 @ (np.diag([It, It, Ia]) @ w0)
    times = np.linspace(0.0, 10.0, 11)
    worst_w = worst_R = 0.0
    u = lambda t: sy.zero_inputs()  # noqa: E731
    for t, y in zip(times, run(sy, y0, times, u=u, integrator=('dop853', None, 1e-11, 1e-12))):
        q, v = sy.minimal(y)
        c, s = np.cos(lam * t), np.sin(lam * t)
        w_ref = np.array([c * w0[0] - s * w0[1], s * w0[0] + c * w0[1], w0[2]])
        R_ref = rot_axis(h / np.linalg.norm(h), np.linalg.norm(h) / It * t) @ R0 @ rotz(-lam * t)
        worst_w = max(worst_w, np.abs(v[:3] - w_ref).max())
        worst_R = max(worst_R, np.abs(quat_to_R(q[3:7]) - R_ref).max())
        assert np.allclose(quat_to_R(q[3:7]) @ (np.diag([It, It, Ia]) @ v[:3]), h, rtol=0, atol=1e-9)
        assert abs(np.linalg.norm(q[3:7]) - 1.0) < 1e-14
    print(formulation, f'omega err {worst_w:.2e}, R err {worst_R:.2e}')
    assert worst_w < 1e-9 and worst_R < 1e-9   # measured ω 6.9e-12, R 1.1e-11 (augmented)


def test_tumble_through_pitch_90_degrees():
    """A tumble about body y from level: the pitch passes +90° and −90° (where Bryan-angle rates
    are singular) and the quaternion integration follows R = R_y(ω t) exactly, with RK4 too."""
    sy = parse_scene(_BODY.replace('FORM', 'minimal').replace('IT', '0.8').replace('IA', '1.4')).system
    wy = 1.3
    y0 = sy.initial_state(None, np.r_[0.0, wy, 0.0, 0.0, 0.0, 0.0])
    t90 = np.pi / 2 / wy
    times = np.array([0.0, 0.5 * t90, t90, 2 * t90, 3 * t90, 3.5 * t90, 4 * t90])
    for integ, tol in ((('dop853', None, 1e-12, 1e-13), 1e-10), (('rk4', 1e-2), 1e-8)):
        for t, y in zip(times, run(sy, y0, times, u=lambda t: sy.zero_inputs(), integrator=integ)):
            q, _ = sy.minimal(y)
            R = quat_to_R(q[3:7])
            assert np.abs(R - roty(wy * t)).max() < tol, (integ, t)
            if t in (t90, 3 * t90):  # pitch = asin(-R[2, 0]) = ±90°
                assert abs(abs(R[2, 0]) - 1.0) < 1e-12


# ---------------------------------------------------------------------------------------------
# air-bearing table
# ---------------------------------------------------------------------------------------------
def _gravity_hold(sy):
    """Joint torques that hold the arm still against gravity (static RNEA on minimal coordinates)."""
    z = np.zeros(sy.model.nv)
    return lambda t, y: {'effort': sy.B.T @ dyn.rnea(sy.model, sy.minimal(y)[0], z, z), 'base_wrench': np.zeros(6)}


@pytest.mark.parametrize('formulation', ['minimal', 'augmented'])
def test_table_at_rest_carries_the_weight(formulation):
    """At rest the table's normal force is the total weight and its tilting moments are the
    weight's moment about the base_link origin; nothing accelerates."""
    sy, s = system_of('unfried_air_bearing', formulation)
    y = s.y0 if formulation == 'minimal' else sy.initial_state(*s.system.minimal(s.y0))
    hold = _gravity_hold(sy)
    u = hold(0.0, y)
    out = sy.outputs(0.0, y, u)
    W = sy.model.total_mass() * 9.81
    frame, w = out.wrenches['base_plane']
    assert frame == 'base_link'
    com, _ = dyn.center_of_mass(sy.model, sy.minimal(y)[0])
    r = com - sy.minimal(y)[0][:3]  # level platform at yaw 0: base_link axes = world axes
    assert w[5] == pytest.approx(W, rel=1e-12)
    assert np.allclose(w[3:5], 0.0, atol=1e-10)
    assert np.allclose(w[:3], np.cross(r, [0.0, 0.0, W]), rtol=0, atol=1e-10)
    assert np.abs(sy.rhs(0.0, y, u)[sy.nq:]).max() < 1e-10
    assert out.extra['constraint_rank'] == sy.n_constraints


def _posture_hold(sy, q0):
    """Gravity compensation plus a soft PD hold of the arm posture of q0 (ω_n = 2 rad/s, ζ = 1,
    gains scaled by each joint's inertia so that the wrist is not stiff)."""
    z = np.zeros(sy.model.nv)
    th0 = q0[7:].copy()
    Ij = np.diag(dyn.crba(sy.model, q0))[6:]
    Kp, Kd = 4.0 * Ij, 4.0 * Ij

    def law(t, y):
        q, v = sy.minimal(y)
        return {'effort': sy.B.T @ dyn.rnea(sy.model, q, z, z) + Kp * (th0 - q[7:]) - Kd * v[6:],
                'base_wrench': np.zeros(6)}
    return law


def test_table_drift_bounded_for_60s_and_shrinks_from_perturbation():
    """Baumgarte (the scene's α = β = 20 1/s): over 60 s of the platform gliding and yawing on the
    table with the arm held, |φ| and |φ̇| stay below DRIFT_TOL while the table carries the weight
    and the gyroscopic tilting moment; from a perturbed start (1 mm, 1 mrad, 1 mm/s) the
    residual shrinks by > 1e4 within 1 s in both formulations, and not at all without
    stabilisation."""
    # m, rad, m/s, rad/s. Measured: <= 7.5e-15 with Baumgarte; the same run without stabilisation
    # drifts as ~t² to 1.4e-11 at 60 s, so this bound tells the two apart.
    DRIFT_TOL = 1e-13
    sy, s = system_of('unfried_air_bearing', 'minimal')
    q0, v0 = sy.minimal(_table_state(sy))
    v0[6:] = 0.0
    v0[2] = 0.1  # yaw rate, rad/s
    y0 = sy.initial_state(q0, v0)
    hold = _posture_hold(sy, q0)
    times = np.linspace(0.0, 60.0, 13)
    res = []
    for t, y in zip(times, _run_feedback(sy, y0, times, hold, ('dop853', None, 1e-5, 1e-7))):
        out = sy.outputs(t, y, hold(t, y))
        res.append(max(out.extra['constraint_residual'], out.extra['constraint_velocity_residual']))
        assert out.wrenches['base_plane'][1][5] == pytest.approx(sy.weight, rel=1e-2)
    print('table drift over 60 s', f'{max(res):.2e}')
    assert max(res) < DRIFT_TOL
    assert np.hypot(*(sy.minimal(y)[0][:2] - q0[:2])) > 1.0  # it glided
    # perturbed start, both formulations, with and without stabilisation
    integ = ('dop853', None, 1e-7, 1e-9)
    for form in ('minimal', 'augmented'):
        for method in ('baumgarte', 'none'):
            sy, s = system_of('unfried_air_bearing', form, stabilisation=method)
            q, v = s.system.minimal(s.y0)
            q[2] += 1e-3
            q[3:7] = R_to_quat(rot_axis(np.array([1.0, 0.0, 0.0]), 1e-3))
            v[5] += 1e-3
            y = sy.initial_state(q, v)
            hold = _gravity_hold(sy)
            r0 = sy.outputs(0.0, y, hold(0.0, y)).extra['constraint_residual']
            y1 = _run_feedback(sy, y, np.array([0.0, 1.0]), hold, integ)[-1]
            r1 = sy.outputs(1.0, y1, hold(1.0, y1)).extra['constraint_residual']
            if method == 'baumgarte':
                assert r1 < 1e-4 * r0, (form, r0, r1)
            else:
                assert r1 > 0.5 * r0, (form, r0, r1)


def _run_feedback(sy, y0, times, law, integrator):
    """Like :func:`run`, with inputs ``law(t, y)`` evaluated at every right-hand-side call."""
    integ = make_integrator(*integrator)
    f = lambda t, y: sy.rhs(t, y, law(t, y))  # noqa: E731
    ys = [np.array(y0)]
    for t0, t1 in zip(times[:-1], times[1:]):
        ys.append(integ.advance(f, t0, ys[-1], t1, project=sy.project)[0])
    return ys


@pytest.mark.parametrize('formulation', ['minimal', 'augmented'])
def test_table_projection_removes_drift_in_one_step(formulation):
    """stabilisation: projection puts a perturbed state back on the table (and the joint
    connections) after the first accepted step."""
    sy, s = system_of('unfried_air_bearing', formulation, stabilisation='projection')
    q, v = s.system.minimal(s.y0)
    q[2] += 1e-3
    q[3:7] = R_to_quat(rot_axis(np.array([0.0, 1.0, 0.0]), 2e-3))
    v[5] += 1e-3
    y = sy.initial_state(q, v)
    hold = _gravity_hold(sy)
    y1 = _run_feedback(sy, y, np.array([0.0, 0.01]), hold, ('rk4', 0.01))[-1]
    e = sy.outputs(0.01, y1, hold(0.01, y1)).extra
    assert e['constraint_residual'] < 1e-12 and e['constraint_velocity_residual'] < 1e-12


# ---------------------------------------------------------------------------------------------
# scenes
# ---------------------------------------------------------------------------------------------
def test_scenes_choose_formulation_and_report_outputs():
    ff = load_scene('unfried_free_flyer')
    ab = load_scene('unfried_air_bearing')
    assert isinstance(ff.system, AugmentedFreeFlyerSystem) and ff.system.nv == 26 and ff.system.n_constraints == 15
    assert isinstance(ab.system, FreeFlyerSystem) and ab.system.table and ab.system.n_constraints == 3
    for s in (ff, ab):
        assert set(s.system.inputs) == {'effort', 'base_wrench'}
        out = s.system.outputs(0.0, s.y0, {**s.system.zero_inputs(), **s.script(0.0, s.y0)})
        assert out.joint_names == ['joint1', 'joint2', 'joint3', 'joint4', 'joint5']
        assert set(out.wrenches) == set(out.joint_names) | ({'base_plane'} if s.system.table else set())
        assert all(frame == f'link{k + 1}' for k, (frame, _) in enumerate(out.wrenches[j] for j in out.joint_names))
        assert set(out.odom) == {'position', 'orientation', 'linear', 'angular'}
        for k in ('momentum_linear_x', 'momentum_angular_com_z', 'com_z', 'constraint_residual', 'constraint_rank'):
            assert k in out.extra
        assert all(np.all(np.isfinite(w)) for _, w in out.wrenches.values())


@pytest.mark.parametrize('change, path', [
    (('gravity: [0.0, 0.0, 0.0]', 'gravity: [0.0, 0.0, -9.81]'), 'gravity'),
    (('formulation: augmented', 'formulation: lagrange'), 'parts[0].formulation'),
    (('environment: orbit', 'environment: moon'), 'parts[0].environment'),
    (('mount: platform', 'mount: world'), 'parts[1].mount'),
    (('method: baumgarte', 'method: penalty'), 'parts[0].stabilisation.method'),
])
def test_free_base_scene_errors_name_the_key(change, path):
    text = load_scene('unfried_free_flyer').text.replace(*change)
    with pytest.raises(SceneError, match=path.replace('[', r'\[').replace(']', r'\]')):
        parse_scene(text, file='ff.yaml')
