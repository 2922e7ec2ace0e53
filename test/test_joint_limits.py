"""Joint-limit moments, Huston eq. (20.2.1) (seed 000, ch. 20), against closed forms.

A single body turning about a fixed vertical axis in zero gravity (effective inertia I exactly)
is thrown into its upper stop. Piece by piece:

1. inside the range: no moment, constant rate;
2. beyond θmax moving outward: ``I Δ̈ = -k Δ - c Δ̇`` with ``Δ(0) = 0, Δ̇(0) = ω0``, i.e.
   ``Δ = (ω0/ωd) e^{-ζωn τ} sin(ωd τ)`` up to the turning point ``tan(ωd τ1) = ωd/(ζ ωn)``;
3. moving back (``θ̇ < 0``): the printed law (``return: none``) has M = 0 — the joint stays at the
   turning point (its rate stays 0⁻, to the step size); ``return: spring`` keeps the spring
   without its damper, ``Δ = Δpk cos(ωn (τ - τ1))``, leaving the range with rate ``-ωn Δpk``;
4. back inside: constant rate again.

The simulator's work quadrature must equal the energy lost (E − E0 = W, the stop's work), and a
too stiff stop must be refused by the step preflight naming the joint and its time constant.
The same stop written as a URDF ``<limit lower upper>`` and enforced by a ``kind: urdf`` part's
``position_limits`` mapping must give the same pieces.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from robodyn_ros import kernels
from robodyn_ros.model import LinkSpec, ModelError, build_model
from robodyn_ros.simulation import Simulator
from robodyn_ros.systems.arm import ArmSystem

# numba is a hard dependency: without it these tests fail, never skip (joint-limit moments are compiled kernels only)
assert kernels.AVAILABLE, kernels.UNAVAILABLE_REASON

I_AX, K, C, LO, HI = 0.2, 50.0, 0.6, -0.5, 0.5


def one_joint(ret='none', k=K, c=C, damping=0.0):
    link = LinkSpec(name='arm', joint='hinge', parent=None, joint_type='revolute', axis=(0, 0, 1), mass=2.0,
                    com=(0.0, 0.0, 0.0), inertia=np.diag([0.15, 0.15, I_AX]), limits=(LO, HI),
                    limit_stiffness=k, limit_damping=c, limit_return=ret, damping=damping)
    return ArmSystem(build_model([link], gravity=(0, 0, 0), name='stop'), backend='numba')


def urdf_text(lower=LO, upper=HI, kind='revolute'):
    """One link turning about z, the same body as :func:`one_joint`, as a URDF."""
    lim = f'<limit effort="100" velocity="10" lower="{lower}" upper="{upper}"/>'
    return (f'<robot name="stop"><link name="base"/>'
            f'<link name="arm"><inertial><mass value="2.0"/>'
            f'<inertia ixx="0.15" iyy="0.15" izz="{I_AX}" ixy="0" ixz="0" iyz="0"/></inertial></link>'
            f'<joint name="hinge" type="{kind}"><parent link="base"/><child link="arm"/><axis xyz="0 0 1"/>'
            f'{lim}</joint></robot>')


def urdf_scene(position_limits=None, text=None, extra=''):
    import yaml
    part = {'kind': 'urdf', 'name': 'stop', 'urdf': text or urdf_text()}
    if position_limits is not None:
        part['position_limits'] = position_limits
    return yaml.safe_dump({'name': 'stop', 'gravity': [0.0, 0.0, -9.81], 'parts': [part]}, sort_keys=False) + extra


def urdf_joint(ret='none', k=K, c=C):
    """The stop of :func:`one_joint` imported from a URDF with ``position_limits`` (gravity along the axis)."""
    from robodyn_ros.scene import parse_scene
    from robodyn_ros.systems.base import backend_scope
    with backend_scope('numba'):
        return parse_scene(urdf_scene({'stiffness': k, 'damping': c, 'return': ret}), 'stop.yaml').system


def run(system, y0, t_end, dt=1e-4, samples=2001):
    sim = Simulator(system, y0, integrator='rk4', dt=dt)
    ts = np.linspace(0.0, t_end, samples)
    out = [sim.y.copy()]
    for t in ts[1:]:
        out.append(sim.advance(t).copy())
    return ts, np.array(out), sim


def closed_form(t, th0, w0, ret):
    """θ(t), θ̇(t) of the four pieces (module docstring)."""
    wn = math.sqrt(K / I_AX)
    zeta = C / (2.0 * math.sqrt(K * I_AX))
    wd = wn * math.sqrt(1.0 - zeta ** 2)
    t0 = (HI - th0) / w0
    tau1 = math.atan2(wd, zeta * wn) / wd
    dpk = (w0 / wd) * math.exp(-zeta * wn * tau1) * math.sin(wd * tau1)
    if t <= t0:
        return th0 + w0 * t, w0
    tau = t - t0
    if tau <= tau1:
        e = math.exp(-zeta * wn * tau)
        d = (w0 / wd) * e * math.sin(wd * tau)
        dd = w0 * e * (math.cos(wd * tau) - zeta * wn / wd * math.sin(wd * tau))
        return HI + d, dd
    if ret == 'none':
        return HI + dpk, 0.0
    tau2 = tau1 + math.pi / (2 * wn)
    if tau <= tau2:
        return HI + dpk * math.cos(wn * (tau - tau1)), -wn * dpk * math.sin(wn * (tau - tau1))
    return HI - wn * dpk * (tau - tau2), -wn * dpk


@pytest.mark.parametrize('source', ['linkspec', 'urdf'])
@pytest.mark.parametrize('ret', ['none', 'spring'])
def test_stop_follows_eq_20_2_1_piece_by_piece(ret, source):
    th0, w0 = 0.3, 2.0
    sys_ = one_joint(ret) if source == 'linkspec' else urdf_joint(ret)
    assert sys_.model.nv == 1 and sys_._lim.shape[0] == 1
    ts, ys, sim = run(sys_, np.array([th0, w0]), 0.8)
    ref = np.array([closed_form(t, th0, w0, ret) for t in ts])
    wn = math.sqrt(K / I_AX)
    # every piece is visited
    beyond = ys[:, 0] > HI
    assert beyond.any() and (~beyond).any()
    assert (ys[beyond, 1] < -1e-3).any() if ret == 'spring' else True
    h = 1e-4
    # ret 'none' after the turning point: the exact rate is 0⁻ but a step that lands on θ̇ ≈ 0
    # leaves at most one step of spring acceleration, a creep |θ̇| <= k Δpk h / I
    dpk = closed_form(1.0, th0, w0, 'none')[0] - HI
    creep = K * dpk / I_AX * h
    t_turn = (HI - th0) / w0 + math.atan2(math.sqrt(1 - C ** 2 / (4 * K * I_AX)), C / (2 * math.sqrt(K * I_AX))) / (
        wn * math.sqrt(1 - C ** 2 / (4 * K * I_AX)))
    pre = ts <= t_turn
    err_th = np.abs(ys[:, 0] - ref[:, 0])
    err_w = np.abs(ys[:, 1] - ref[:, 1])
    # RK4, h = 1e-4 s, ωn h = 1.6e-3; the kinks (entering the stop, turning back) cost O(h)
    assert pre.sum() > 100 and (~pre).sum() > 100
    print(f'{ret}: before the turn θ {err_th[pre].max():.1e} rad, θ̇ {err_w[pre].max():.1e} rad/s; after θ '
          f'{err_th[~pre].max():.1e}, θ̇ {err_w[~pre].max():.1e}')
    assert err_th[pre].max() < 2e-5, err_th[pre].max()
    assert err_w[pre].max() < 2e-3 * w0, err_w[pre].max()
    if ret == 'none':   # no restoring moment: the joint rests at its deepest point
        assert dpk > 0.01
        assert err_w[~pre].max() <= creep, (err_w[~pre].max(), creep)
        assert err_th[~pre].max() <= creep * (ts[-1] - t_turn) + 2e-5
    else:               # elastic return, undamped, then free motion
        # measured 4.4e-5 rad and 8e-5 rad/s: an O(h) rate error from the two kinks, then carried
        assert err_w[~pre].max() < 5e-4, err_w[~pre].max()
        assert err_th[~pre].max() < 2e-5 + 5e-4 * (ts[-1] - t_turn), err_th[~pre].max()
        assert ys[-1, 1] == pytest.approx(-wn * dpk, rel=1e-3)   # exits at the undamped rate -ωn Δpk
        assert ys[-1, 0] < HI
    # the stop's work is what the joint lost; in the printed law it is dissipation only
    E0 = 0.5 * I_AX * w0 ** 2
    E1 = 0.5 * I_AX * ys[-1, 1] ** 2
    rep = sim.energy_report()
    assert rep["work"] == pytest.approx(E1 - E0, rel=1e-6)   # fixed-step RK4 over the kinks: O(h) per kink
    assert rep['work'] < -0.05 * E0
    # the stop is the only non-conservative element: its own work (integrated apart) is all of it
    assert rep['limit_work'] == pytest.approx(rep['work'], rel=1e-12, abs=0.0)
    assert wn > 0


def test_inside_the_range_no_moment_and_one_sided_damping():
    """Pointwise: zero inside; the damper acts only while moving outward (both modes), the spring
    on the way back only in 'spring' mode."""
    for ret, spring_back in (('none', False), ('spring', True)):
        km = kernels.CompiledModel(one_joint(ret).model)
        assert km.limit_forces(np.array([0.2]), np.array([5.0]))[0] == 0.0
        out = km.limit_forces(np.array([HI + 0.1]), np.array([0.5]))[0]
        assert out == pytest.approx(-K * 0.1 - C * 0.5, rel=1e-14)
        back = km.limit_forces(np.array([HI + 0.1]), np.array([-0.5]))[0]
        assert back == pytest.approx(-K * 0.1 if spring_back else 0.0, rel=1e-14, abs=0.0)
        low = km.limit_forces(np.array([LO - 0.2]), np.array([-1.0]))[0]
        assert low == pytest.approx(K * 0.2 + C * 1.0, rel=1e-14)
        low_back = km.limit_forces(np.array([LO - 0.2]), np.array([1.0]))[0]
        assert low_back == pytest.approx(K * 0.2 if spring_back else 0.0, rel=1e-14, abs=0.0)


def test_spherical_limit_moment_is_the_gradient_of_its_spring():
    """A spherical joint's limit acts per rotation-vector component φ (joint frame): in 'spring'
    mode moving back, the generalised force on ω is the gradient of V = ½ k Σ (φ_j − lim_j)² along
    the rotation, checked by finite differences of V along exp(ω dt) (an independent route)."""
    from robodyn_ros.spatial import quat_exp, quat_mul
    link = LinkSpec(name='ball', joint='ball_joint', parent=None, joint_type='spherical', mass=1.0,
                    inertia=np.diag([0.1, 0.12, 0.08]), limits=((-0.2, 0.2), (-0.3, 0.1), (-np.inf, np.inf)),
                    limit_stiffness=K, limit_damping=0.0, limit_return='spring')
    km = kernels.CompiledModel(build_model([link], gravity=(0, 0, 0)))
    rng = np.random.default_rng(3)

    def phi(q):
        qq = q if q[3] >= 0 else -q
        s = np.linalg.norm(qq[:3])
        return 2 * math.atan2(s, qq[3]) * qq[:3] / s

    def V(q):
        p = phi(q)
        return 0.5 * K * (max(p[0] - 0.2, 0) ** 2 + max(-0.2 - p[0], 0) ** 2 + max(p[1] - 0.1, 0) ** 2
                          + max(-0.3 - p[1], 0) ** 2)
    checked = 0
    for _ in range(20):
        q = quat_exp(rng.uniform(-0.5, 0.5, size=3) * 2)   # rotation vector up to ~1 rad per component
        q = q / np.linalg.norm(q)
        if V(q) == 0.0:
            continue
        tau = km.limit_forces(q, np.zeros(3))      # θ̇ = 0 counts as outward; c = 0: the spring alone
        h = 1e-6
        grad = np.array([(V(quat_mul(q, quat_exp(h * e))) - V(quat_mul(q, quat_exp(-h * e)))) / (2 * h)
                         for e in np.eye(3)])
        assert np.abs(tau + grad).max() < 1e-6 * max(1.0, np.abs(grad).max()), (tau, -grad)
        checked += 1
    assert checked >= 5


def test_stiff_stop_is_refused_naming_its_time_constant():
    """k = 1e8 N·m/rad on I = 0.2 kg·m²: ωn = 2.2e4 1/s; RK4 at dt = 1 ms cannot follow it."""
    sys_ = one_joint(k=1e8, c=0.0)
    with pytest.raises(ValueError) as e:
        Simulator(sys_, np.array([0.0, 0.0]), integrator='rk4', dt=1e-3)
    msg = str(e.value)
    assert "joint limit of 'hinge'" in msg and 'sqrt(I/k) = ' in msg, msg
    assert f'{math.sqrt(I_AX / 1e8):.3g} s' in msg, msg
    # the moderate stop of the other tests passes the same check at its step
    Simulator(one_joint(), np.array([0.0, 0.0]), integrator='rk4', dt=1e-4)


def restitution(zeta):
    """The stop law's coefficient of restitution with ``return: spring`` (closed form): the joint enters at
    ``Δ̇ = ω0`` under ``Δ̈ + 2ζωn Δ̇ + ωn² Δ = 0`` until it turns at ``ωd τ1 = atan(√(1 − ζ²)/ζ)`` with
    ``Δpk = (ω0/ωn) e^{−ζωn τ1}``, then leaves under the spring alone at ``ωn Δpk``: ``e = e^{−ζωn τ1}``."""
    if zeta == 0.0:
        return 1.0
    s = math.sqrt(1.0 - zeta * zeta)
    return math.exp(-zeta * math.atan2(s, zeta) / s)


def bounce_ratios(method, h_tau, zeta, phases=16, w0=1.0):
    """The hinge of :func:`one_joint` (``return: spring``, c for the damping ratio zeta) coasting into its upper
    stop at w0, integrated by the fused compiled loop of ``method`` at ``h = h_tau / ωn`` from ``phases``
    positions spread over the last step before contact; returns the rates it leaves with, over w0 (the
    loop itself: the step check that refuses such steps is the next test)."""
    wn = math.sqrt(K / I_AX)
    c = 2.0 * zeta * math.sqrt(K * I_AX)
    km = one_joint('spring', c=c)._km
    h = h_tau / wn
    tau = np.zeros(1)
    out = []
    for j in range(phases):
        z = np.array([HI - (j + 0.5) / phases * w0 * h, w0, 0.0])
        for _ in range(int(40.0 / h_tau) + 10):
            assert km.integrate_arm(method, z, tau, h, 1, 0.0) < 0
            if z[0] < HI and z[1] < 0.0:
                break
        assert z[0] < HI and z[1] < 0.0, (method, h_tau, zeta, z)   # it came back
        out.append(-z[1] / w0)
    return np.array(out)


@pytest.mark.parametrize('method, h_bad, faster', [('rk4', 2.5, 1.5), ('semi_implicit_euler', 1.5, 2.0)])
def test_an_explicit_step_through_a_bounce_is_refused_where_it_throws_the_joint_back_faster(method, h_bad, faster):
    """A joint coasting into its stop can leave no faster than it came (the law only dissipates: its damper acts
    going in). An explicit step that does not resolve the bounce breaks that at steps its linear stability
    allows (h/τ = 2.5 < rk4's 2.785, 1.5 < symplectic Euler's 2): measured, rk4 throws a damped joint (ζ = 0.5)
    back 1.8 times as fast as it came, symplectic Euler 2.7 times. At the steps the check allows
    (``stability.STOP_RESOLUTION``: h/τ <= 1.5 for rk4, 1 for symplectic Euler) a damped stop (ζ = 0.05,
    0.5) sends it back slower than it came and an undamped one (e = 1) within 2.5 % of its speed; the
    Simulator refuses the longer step, naming the stop, and auto takes rosenbrock2 there."""
    from robodyn_ros.stability import STOP_RESOLUTION
    limit = STOP_RESOLUTION[method]
    assert bounce_ratios(method, h_bad, 0.5).max() > faster
    checked = 0
    for h_tau in (limit, 0.5):
        for zeta, bound in ((0.0, 1.025), (0.05, 1.0), (0.5, 1.0)):
            r = bounce_ratios(method, h_tau, zeta)
            assert r.max() < bound, (h_tau, zeta, r.max())
            checked += 1
    assert checked == 6
    sys_ = one_joint('spring', k=5e4)
    tau = math.sqrt(I_AX / 5e4)
    with pytest.raises(ValueError) as e:
        Simulator(sys_, np.array([0.0, 0.0]), integrator=method, dt=h_bad * tau)
    assert 'does not resolve a joint stop' in str(e.value) and "joint limit of 'hinge'" in str(e.value), str(e.value)
    Simulator(sys_, np.array([0.0, 0.0]), integrator=method, dt=0.99 * limit * tau)
    auto = Simulator(sys_, np.array([0.0, 0.0]), integrator='auto', dt=2.0 * tau)
    assert auto.settings['integrator'] == 'rosenbrock2', auto.choice.reason
    assert 'does not resolve a joint stop' in auto.choice.reason, auto.choice.reason


def test_rk4_converges_on_the_bounce_to_the_laws_restitution():
    """rk4 through the bounce of a damped stop (ζ = 0.5) against the law's restitution (closed form, 0.546):
    the error over the step's phases shrinks with h (the law's kinks, at contact and where the joint turns,
    make it first order), to within 1 % at h/τ = 0.01."""
    e = restitution(0.5)
    err = [np.abs(bounce_ratios('rk4', h_tau, 0.5) - e).max() for h_tau in (1.0, 0.1, 0.01)]
    assert err[0] > err[1] > err[2] and err[2] < 0.01 * e, err


def test_bad_limit_data_refused():
    with pytest.raises(ModelError, match='limit_return'):
        build_model([LinkSpec(name='a', joint='j', parent=None, limits=(0, 1), limit_stiffness=1.0,
                              limit_return='bounce')])
    with pytest.raises(ModelError, match='without limits'):
        build_model([LinkSpec(name='a', joint='j', parent=None, limit_stiffness=1.0)])
    with pytest.raises(ModelError, match='3 pairs'):
        build_model([LinkSpec(name='a', joint='j', parent=None, joint_type='spherical', limits=(0, 1),
                              limit_stiffness=1.0)])
    with pytest.raises(ValueError, match='compiled kernels only'):
        ArmSystem(one_joint().model, backend='numpy')


def test_dh_scene_limits_mapping_gives_limit_moments():
    """A DH row's ``limits: {lower, upper, stiffness, damping}`` reaches the model's limit table; the
    list form stays reported only."""
    from robodyn_ros.model import limit_table
    from robodyn_ros.scene import parse_scene
    text = """
name: dh_stop
parts:
  - kind: arm
    name: arm
    dh:
      convention: standard
      links:
        - {type: revolute, a: 0.5, alpha: 0.0, d: 0.0, theta: 0.0, mass: 1.0, com: [-0.25, 0, 0],
           limits: {lower: -1.0, upper: 1.0, stiffness: 40.0, damping: 0.5, return: none}}
        - {type: revolute, a: 0.5, alpha: 0.0, d: 0.0, theta: 0.0, mass: 1.0, com: [-0.25, 0, 0], limits: [-2.0, 2.0]}
"""
    m = parse_scene(text, 'dh.yaml').system.model
    lim = limit_table(m)
    assert lim.shape == (1, 12)
    assert tuple(lim[0, [3, 4, 5, 10, 11]]) == (1.0, -1.0, 1.0, 40.0, 0.5)   # mode 1 = 'none'
    assert m.specs[1].limits == (-2.0, 2.0) and m.specs[1].limit_stiffness == 0.0


def test_urdf_position_limits_reach_every_limited_joint_and_are_off_by_default():
    """Without ``position_limits`` a URDF stop is reported only (the joint passes through it freely,
    as before); with it, every revolute/prismatic joint with ``<limit lower upper>`` gets the law,
    continuous and locked joints none."""
    from robodyn_ros.model import limit_table
    from robodyn_ros.scene import SceneError, parse_scene
    from robodyn_ros.systems.base import backend_scope
    with backend_scope('numba'):
        free = parse_scene(urdf_scene(), 'stop.yaml').system
    assert free.model.specs[0].limits == (LO, HI) and limit_table(free.model).shape == (0, 12)
    ts, ys, _ = run(free, np.array([0.3, 2.0]), 0.8, samples=81)
    assert np.allclose(ys[:, 0], 0.3 + 2.0 * ts, atol=1e-9) and ys[-1, 0] > HI + 1.0
    text = ('<robot name="three"><link name="base"/>' + ''.join(
        f'<link name="l{i}"><inertial><mass value="1"/><inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0" ixz="0" '
        f'iyz="0"/></inertial></link>' for i in range(4)) +
        '<joint name="r" type="revolute"><parent link="base"/><child link="l0"/><axis xyz="0 0 1"/>'
        '<limit effort="1" velocity="1" lower="-1" upper="1.5"/></joint>'
        '<joint name="c" type="continuous"><parent link="l0"/><child link="l1"/><axis xyz="0 1 0"/>'
        '<origin xyz="0 0 0.3"/><limit effort="1" velocity="1"/></joint>'
        '<joint name="p" type="prismatic"><parent link="l1"/><child link="l2"/><axis xyz="1 0 0"/>'
        '<origin xyz="0 0 0.3"/><limit effort="1" velocity="1" lower="-0.1" upper="0.2"/></joint>'
        '<joint name="lk" type="revolute"><parent link="l2"/><child link="l3"/><axis xyz="0 1 0"/>'
        '<origin xyz="0 0 0.3"/><limit effort="1" velocity="1" lower="-1" upper="1"/></joint></robot>')
    import yaml
    doc = yaml.safe_load(urdf_scene({'stiffness': 30.0, 'damping': 0.2}, text=text))
    doc['parts'][0]['locked'] = {'lk': 0.5}
    with backend_scope('numba'):
        m = parse_scene(yaml.safe_dump(doc), 'three.yaml').system.model
    lim = limit_table(m)
    # rows: [jtype, q index, v index, mode, lo0, hi0, ..., k, c]; 'spring' (the default) is mode 2
    assert lim[:, 1].tolist() == [0.0, 2.0]            # joints r and p (q indices 0 and 2), not c
    assert lim[:, [4, 5]].tolist() == [[-1.0, 1.5], [-0.1, 0.2]]
    assert lim[:, 10].tolist() == [30.0, 30.0] and lim[:, 11].tolist() == [0.2, 0.2]
    assert lim[:, 3].tolist() == [2.0, 2.0]
    with pytest.raises(SceneError, match=r'^s\.yaml: parts\[0\]\.position_limits\.return: unknown return mode'):
        parse_scene(urdf_scene({'stiffness': 1.0, 'return': 'bounce'}), 's.yaml')
    with pytest.raises(SceneError, match=r'parts\[0\]\.position_limits\.stiffness: '):
        parse_scene(urdf_scene({'stiffness': -1.0}), 's.yaml')
    with pytest.raises(SceneError, match=r'parts\[0\]\.position_limits\.stifness: unknown key'):
        parse_scene(urdf_scene({'stifness': 1.0}), 's.yaml')
    doc = yaml.safe_load(urdf_scene({'stiffness': 1.0}))
    doc['parts'][0]['floating'] = True
    with pytest.raises(SceneError, match=r'parts\[0\]\.position_limits: joint-limit moments are supported for a '
                                         r'URDF mounted on the world only'):
        parse_scene(yaml.safe_dump(doc), 's.yaml')


def _split_run(integrator, d, reference=False):
    sys_ = one_joint('spring', damping=d)
    if reference:   # an instance attribute named like a fused method: the fused loop declines
        sys_.rhs = sys_.rhs
    kw = {'dt': 1e-4} if integrator == 'rk4' else {'dt': None, 'rtol': 1e-10, 'atol': 1e-12}
    return sys_, Simulator(sys_, np.array([0.3, 2.0]), integrator=integrator, **kw)


@pytest.mark.parametrize('integrator', ['rk4', 'dop853'])
def test_limit_work_is_integrated_as_its_own_part(integrator):
    """With viscous joint damping d as well, the work splits: ``W = W_lim + W_damp`` with
    ``W_damp = -d ∫ θ̇² dt`` (quadrature of the sampled rate, an independent route); W_lim is
    exactly 0 before the joint reaches its stop and < 0 after (dissipation). rk4 takes the fused
    compiled loop, dop853 the Simulator's reference quadrature."""
    d = 0.05
    sys_, sim = _split_run(integrator, d)
    assert sys_.work_components == ('limit',)
    ts = np.linspace(0.0, 0.8, 8001)
    ys = [sim.y.copy()]
    early = None
    for t in ts[1:]:
        ys.append(sim.advance(t).copy())
        if early is None and t >= 0.05:    # inside the range (the stop is reached at t ≈ 0.1 s)
            early = sim.energy_report()
    ys = np.array(ys)
    assert early['limit_work'] == 0.0 and early['work'] < -1e-4
    rep = sim.energy_report()
    from scipy.integrate import simpson
    w_damp = -d * simpson(ys[:, 1] ** 2, x=ts)
    assert rep['limit_work'] < -0.01
    assert rep['work'] - rep['limit_work'] == pytest.approx(w_damp, rel=1e-4)
    assert abs(rep['drift']) < 1e-8
    if integrator == 'rk4':   # the fused compiled loop and the Simulator's reference quadrature agree
        _, ref = _split_run('rk4', d, reference=True)
        ref.advance(0.8)
        assert ref.energy_report()['limit_work'] == pytest.approx(rep['limit_work'], rel=1e-10)
        assert ref.diag.work == pytest.approx(rep['work'], rel=1e-10)
        gen = Simulator(ArmSystem(sys_.model, backend='generated'), np.array([0.3, 2.0]), integrator='rk4', dt=1e-4)
        gen.advance(0.8)   # the generated loop of kernels.codegen
        assert gen.energy_report()['limit_work'] == pytest.approx(rep['limit_work'], rel=1e-10)
    vals = sim.diagnostics_values()
    assert vals['limit_work'] == rep['limit_work']
    from types import SimpleNamespace

    from robodyn_ros.runs import summary
    text = summary(SimpleNamespace(name='stop', system=sys_), sim, {'integrator': integrator, 'dt': 1e-4}, 1.0, None,
                   [])
    assert f'; joint-limit work {rep["limit_work"]:.6g} J' in text, text
    # a system without limit moments has no such part
    free = Simulator(one_joint(k=0.0, c=0.0), np.array([0.3, 2.0]), integrator='rk4', dt=1e-3)
    assert free.system.work_components == ()
    free.advance(0.5)
    assert 'limit_work' not in free.diagnostics_values() and 'limit_work' not in free.energy_report()


@pytest.mark.parametrize('host', ['free_base', 'diff_drive'])
def test_limit_moments_on_a_platform_are_refused_not_dropped(host):
    """FreeFlyerSystem and DiffDriveSystem do not compute joint-limit moments: an arm carrying them
    on such a platform is refused at load (before, the moments were silently left out)."""
    import yaml

    from robodyn_ros.scene import SceneError, parse_scene
    link = {'name': 'l1', 'joint': 'j1', 'parent': 'base_link', 'type': 'revolute', 'mass': 1.0,
            'inertia': [0.1, 0.1, 0.1, 0, 0, 0], 'limits': {'lower': -0.1, 'upper': 0.1, 'stiffness': 100.0}}
    if host == 'free_base':
        platform = {'kind': 'free_base', 'name': 'base', 'environment': 'orbit', 'formulation': 'minimal',
                    'link': 'base_link', 'joint': 'base_joint', 'mass': 10.0, 'inertia': [1, 1, 1, 0, 0, 0]}
        gravity = [0.0, 0.0, 0.0]
    else:
        platform = {'kind': 'diff_drive', 'name': 'base',
                    'chassis': {'mass': 3.0, 'yaw_inertia': 0.2, 'com': [0, 0, 0.2]},
                    'wheels': {'radius': 0.1, 'half_track': 0.2, 'mass': 0.3, 'spin_inertia': 0.002},
                    'motor': {'kind': 'dc_motor', 'torque_constant': 0.06, 'resistance': 1.7}}
        gravity = [0.0, 0.0, -9.81]
    doc = {'name': 'x', 'gravity': gravity, 'parts': [platform, {'kind': 'arm', 'name': 'arm', 'mount': 'base',
                                                                 'links': [link]}]}
    with pytest.raises(SceneError, match=rf"^x\.yaml: parts\[1\]: joint 'j1': joint-limit moments .* on a {host} "
                                         r"platform"):
        parse_scene(yaml.safe_dump(doc), 'x.yaml')
    link['limits'] = [-0.1, 0.1]    # reported only: accepted
    sc = parse_scene(yaml.safe_dump(doc), 'x.yaml')
    assert sc.system.model.specs[-1].limits == (-0.1, 0.1)


def test_cli_position_limits_option_on_a_urdf_file(tmp_path):
    """``robodyn run robot.urdf --position-limits K,C``: a pendulum (1 kg at r = 0.5 m, horizontal at
    q = 0, joint damping 0.5) falls into its upper stop at 0.3 rad and comes to rest where the
    stop's spring holds the weight, ``k Δ = m g r cos(0.3 + Δ)`` (statics, solved by bisection);
    without the option it swings through its URDF limits, as before."""
    import subprocess
    import sys

    from robodyn_ros.recording import read_messages
    urdf = tmp_path / 'pendulum.urdf'
    urdf.write_text('<robot name="pendulum"><link name="base"/>'
                    '<link name="bob"><inertial><origin xyz="0.5 0 0"/><mass value="1.0"/>'
                    '<inertia ixx="0.001" iyy="0.001" izz="0.001" ixy="0" ixz="0" iyz="0"/></inertial></link>'
                    '<joint name="swing" type="revolute"><parent link="base"/><child link="bob"/><axis xyz="0 1 0"/>'
                    '<dynamics damping="0.5"/><limit effort="10" velocity="100" lower="-0.3" upper="0.3"/></joint>'
                    '</robot>')
    cmd = [sys.executable, '-m', 'robodyn_ros.cli', 'run', str(urdf), '--duration', '15', '--integrator', 'rk4',
           '--dt', '1e-3', '--rate', '10']

    def final_q(extra, name):
        out = tmp_path / f'{name}.mcap'
        p = subprocess.run(cmd + extra + ['--record', str(out)], capture_output=True, text=True, timeout=240)
        assert p.returncode == 0, p.stderr
        js = [m for *_, m in read_messages(out, topics=['/joint_states'])]
        return float(js[-1].position[0]), p.stdout
    k, m, g, r = 50.0, 1.0, 9.81, 0.5
    lo, hi = 0.0, 1.0
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if k * mid < m * g * r * math.cos(0.3 + mid) else (lo, mid)
    q_rest, text = final_q(['--position-limits', f'{k},0.6'], 'stop')
    assert q_rest == pytest.approx(0.3 + lo, abs=1e-6), (q_rest, 0.3 + lo)
    assert '; joint-limit work -' in text, text
    q_free, text = final_q([], 'free')
    assert q_free > 1.0 and 'joint-limit work' not in text
    bad = subprocess.run(cmd + ['--position-limits', '50'], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and '--position-limits: expected K,C or K,C,RETURN' in bad.stderr, bad.stderr
    bad = subprocess.run(cmd + ['--position-limits', '50,1,bounce'], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and 'parts[0].position_limits.return: unknown return mode' in bad.stderr, bad.stderr
    bad = subprocess.run(cmd[:4] + ['stanford_arm', '--duration', '0.1', '--position-limits', '50,1'],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and 'applies to a URDF file only' in bad.stderr, bad.stderr
