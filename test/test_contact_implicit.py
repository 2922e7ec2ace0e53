"""Ground contact in the linearly implicit step (rosenbrock2): the contacts' damping and stiffness in its
Jacobian (kernels/contact.py (C4)-(C5), assembled by kernels/arm.py's iteration matrix and by
``CompiledModel.passive_jacobian`` for the Python path) against finite differences of the contact forces;
the compiled step against the generic W-method step; and the step on closed forms: a box at rest at
1 ms (weight, penetration m g / k, no drift), order 2 on a box sliding down a slope, contact work <= 0.
"""
from __future__ import annotations

import functools
import math

import numpy as np
import pytest
import yaml

from robodyn_ros import kernels
from robodyn_ros.kernels.contact import PACTIVE, PDEPTH, PF
from robodyn_ros.kernels.rosenbrock import GAMMA_STOP
from robodyn_ros.scene import parse_scene
from robodyn_ros.simulation import Simulator

from test_contact import MASS, SIZE, G, box_urdf, quat_y, run, scene

assert kernels.AVAILABLE, kernels.UNAVAILABLE_REASON


def _a1_in_contact(mu, d, depth):
    """A1 (example-robot-data) with its deepest foot ``depth`` (m) into a ground, moving: ``(system, q, v)``."""
    from robodyn_ros.urdf import example_robot_data_dir
    path = example_robot_data_dir() / 'a1_description/urdf/a1.urdf'
    data = {'name': 'a1', 'parts': [{'kind': 'urdf', 'name': 'a1', 'file': str(path), 'floating': True},
                                    {'kind': 'ground', 'stiffness': 3e4, 'dissipation': d, 'friction': mu,
                                     'slip_speed': 0.05, 'links': ['FR_foot', 'FL_foot', 'RR_foot', 'RL_foot']}]}
    s = parse_scene(yaml.safe_dump(data), file='a1.yaml').system
    km = s._km
    q = np.zeros(s.nq)
    q[6] = 1.0
    q[7:] = [0.1, 0.8, -1.5, -0.1, 0.9, -1.6, 0.05, 0.7, -1.4, -0.05, 0.85, -1.5]
    q[2] = s.contact.point_outputs(km, q, np.zeros(s.nv))[:, PDEPTH].max() - depth
    v = np.random.default_rng(5).normal(scale=0.2, size=s.nv)
    return s, q, v


@pytest.mark.parametrize('mu, d', [(0.0, 3.0), (0.7, 0.0)])
def test_assembled_jacobian_holds_the_contact_derivatives(mu, d):
    """The D and K the Python path's rosenbrock2 takes (``CompiledModel.passive_jacobian``; A1 has no
    joint damping, friction or stops, so they are the ground's alone) and the state Jacobian
    ``ArmSystem.passive_jacobian`` built from them (``J_vv = −M⁻¹ D``, ``J_vq = −M⁻¹ K Φ``) against central
    differences of the contact generalised force ``τ_c = M (v̇ − v̇_free)``: D exact for each law at
    fixed f_n (friction: d = 0; normal damping: μ = 0), K at a shallow touch without friction."""
    s, q, v = _a1_in_contact(mu, d, 4e-3)
    km = s._km
    assert not np.any(s.model.damping) and not s._lim.shape[0] and not s._has_friction
    on = int((s.contact.point_outputs(km, q, v)[:, PACTIVE] > 0).sum())
    assert on >= 1

    def tau_c(q, v):
        acc = s.rhs(0.0, np.concatenate([q, v]), {'effort': np.zeros(len(s.actuated))})[s.nq:]
        return km.crba(q) @ (acc - km.aba(q, v, np.zeros(s.nv)))

    eps = 1e-7
    D, K = km.passive_jacobian(q, v)
    assert np.abs(D).max() > 1.0                      # the ground is in it
    Dfd = np.column_stack([-(tau_c(q, v + eps * e) - tau_c(q, v - eps * e)) / (2 * eps) for e in np.eye(s.nv)])
    assert np.abs(D - Dfd).max() < 1e-5 * np.abs(D).max(), np.abs(D - Dfd).max()
    J = s.passive_jacobian(0.0, np.concatenate([q, v]), {'effort': np.zeros(len(s.actuated))})
    M = km.crba(q)
    np.testing.assert_allclose(J[s.nq:, s.nq:], -np.linalg.solve(M, Dfd), atol=1e-5 * np.abs(J[s.nq:, s.nq:]).max())
    if mu == 0.0:   # K at a shallow touch (the geometric stiffness ∂Jᵀ/∂q F it leaves out goes with F)
        s, q, v = _a1_in_contact(mu, d, 1e-7)
        km = s._km
        K = km.passive_jacobian(q, v)[1]

        def moved(dq):
            return km.normalize(q + km.qdot(q, dq))
        Kfd = np.column_stack([-(tau_c(moved(eps * e), v) - tau_c(moved(-eps * e), v)) / (2 * eps)
                               for e in np.eye(s.nv)])
        assert np.abs(K).max() > 1.0
        assert np.abs(K - Kfd).max() < 1e-4 * np.abs(K).max(), np.abs(K - Kfd).max() / np.abs(K).max()


def _two_link_on_ground():
    """A fixed-base two-link arm (hinges about y, damped) whose tip sphere presses into the ground while
    it slides along it: ``(system, y0)``."""
    link = ('<link name="{n}"><inertial><origin xyz="0.15 0 0"/><mass value="{m}"/><inertia ixx="1e-3" iyy="{i}" '
            'izz="{i}" ixy="0" ixz="0" iyz="0"/></inertial>{c}</link>')
    tip = '<collision><origin xyz="0.3 0 0"/><geometry><sphere radius="0.02"/></geometry></collision>'
    urdf = ('<robot name="two"><link name="post"/>' + link.format(n='a', m=1.2, i=0.012, c='')
            + link.format(n='b', m=0.8, i=0.008, c=tip)
            + '<joint name="j1" type="continuous"><parent link="post"/><child link="a"/><origin xyz="0 0 0.4"/>'
              '<axis xyz="0 1 0"/><dynamics damping="0.3"/></joint>'
              '<joint name="j2" type="continuous"><parent link="a"/><child link="b"/><origin xyz="0.3 0 0"/>'
              '<axis xyz="0 1 0"/><dynamics damping="0.1"/></joint></robot>')
    data = {'name': 'two', 'parts': [{'kind': 'urdf', 'name': 'two', 'urdf': urdf},
                                     {'kind': 'ground', 'stiffness': 2e5, 'dissipation': 3.0, 'friction': 0.6,
                                      'slip_speed': 0.01}]}
    s = parse_scene(yaml.safe_dump(data, sort_keys=False), file='two.yaml').system
    # tip z = 0.4 − 0.3 sin a − 0.3 sin(a + b) − r: a = 0.5, b chosen for a 1 mm penetration
    a = 0.5
    b = math.asin((0.4 - 0.02 + 1e-3 - 0.3 * math.sin(a)) / 0.3) - a
    return s, np.array([a, b, 0.4, -0.9])


def test_compiled_step_on_the_ground_is_the_generic_w_method_step():
    """One rosenbrock2 step of the compiled loop (the ground's forces in the residual, its D_c, K_c in
    M + γhD + γ²h²K, γ = 1 + 1/√2 with a contact touching) equals the generic LU step on [q, v] with
    ``ArmSystem.passive_jacobian`` (the same D_c, K_c from ``CompiledModel.passive_jacobian``) to round-off."""
    from test_rosenbrock import _one_step_both_ways
    s, y0 = _two_link_on_ground()
    P = s.contact.point_outputs(s._km, y0[:2], y0[2:])
    assert P[0, PACTIVE] > 0 and P[0, PDEPTH] > 5e-4
    for h in (1e-3, 2e-4):
        fused, generic = _one_step_both_ways(s, y0, {'effort': np.array([0.3, -0.1])}, h, GAMMA_STOP)
        assert np.abs(fused - y0).max() > 1e-5
        assert np.abs(fused - generic).max() < 1e-12 * (1 + np.abs(y0 - fused).max() / h), fused - generic


def test_box_rests_at_the_closed_form_penetration_at_1ms():
    """rosenbrock2 at h = 1 ms (the scenes' step): the box dropped 1 cm comes to rest with its 4 lower
    corners at m g / (4 k) (k = 1e5: the normal mode ω h = 0.45; friction slope μ f_n / v_s over the
    box's mass: h λ = 4 on the regularised Coulomb law) carrying m g, without drift over 10 s; the
    contact work is negative, and the step never adds energy: E − E₀ − W <= 0 (it takes some: with a
    contact touching, γ = 1 + 1/√2 damps the landing's bounce numerically, kernels/arm.py)."""
    k = 1.0e5
    sc = scene(box_urdf(), {'stiffness': k, 'dissipation': 5.0, 'friction': 0.8, 'slip_speed': 2e-3},
               [0, 0, SIZE[2] / 2 + 0.01, 0, 0, 0, 1], v=[0.05, 0, 0, 0, 0, 0])
    sysm = sc.system
    ts, ys, sim = run(sc, 1e-3, 10.0, 0.5, integrator='rosenbrock2')
    P = sysm.contact.point_outputs(sysm._km, sim.y[:sysm.nq], sim.y[sysm.nq:])
    on = P[:, PACTIVE] > 0
    assert on.sum() == 4
    F = P[on, PF:PF + 3].sum(axis=0)
    assert abs(F[2] / (MASS * G) - 1.0) < 1e-9, F
    np.testing.assert_allclose(P[on, PDEPTH], MASS * G / (4 * k), rtol=1e-6)
    i5 = int(np.flatnonzero(ts >= 5.0)[0])
    assert np.abs(ys[i5:, :7] - ys[-1, :7]).max() < 1e-9
    e = sim.energy_report()
    assert e['contact_work'] < 0.0
    assert e['drift'] < 1e-9 * e['energy0'], e
    assert -e['drift'] < MASS * G * 0.01, e     # at most the drop's potential energy


def _slide(h, integrator, T=0.4, k=1e4, rtol=None):
    """The box sliding down a 30° slope (μ = 0.3, v_s = 1 mm/s: saturated friction) from 0.5 m/s,
    resting on its 4 corners at the normal equilibrium (k = 1e4: its rocking mode ω = 220 rad/s):
    its state at T (rtol: rosenbrock2 under error control, h its largest step)."""
    theta, mu = math.radians(30.0), 0.3
    n = np.array([math.sin(theta), 0.0, math.cos(theta)])
    c = (SIZE[2] / 2 - MASS * G * math.cos(theta) / (4 * k)) * n
    sc = scene(box_urdf(), {'normal': n.tolist(), 'stiffness': k, 'dissipation': 5.0, 'friction': mu,
                            'slip_speed': 1e-3}, [*c, *quat_y(theta)], v=[0, 0, 0, 0.5, 0, 0])   # body axes
    sim = Simulator(sc.system, sc.y0, integrator=integrator, dt=h, rtol=rtol)
    sim.advance(T)
    return sim.y.copy(), sim


def test_rosenbrock2_converges_at_order_two_on_a_sliding_box():
    """Errors at T = 0.4 s against rk4 at 10 µs for h = 250, 125, 62.5 µs: log-log slope 2 (within 0.3;
    from 2 ms down the halvings divide it by 2.5, 1.8, 3.0, 3.6: pre-asymptotic, the rocking mode's
    ω h = 0.44 at 2 ms with γ = 1 + 1/√2's larger error constant);
    the contact work negative at every step size. (Tangent coordinates: the contacts' K acts on the free
    root's position increments in body axes; in world axes, as the stage increments are, the tilted box
    rocks away at 1 ms.)"""
    ref, _ = _slide(1e-5, 'rk4')
    hs = (2.5e-4, 1.25e-4, 6.25e-5)
    errs = []
    for h in hs:
        y, sim = _slide(h, 'rosenbrock2')
        errs.append(np.abs(y - ref).max())
        assert sim.energy_report()['contact_work'] < 0.0
    slope = np.polyfit(np.log(hs), np.log(errs), 1)[0]
    assert abs(slope - 2.0) < 0.3, (errs, slope)


def test_box_slides_down_a_stiff_slope_at_1ms_as_the_fine_reference():
    """k = 1e5 per corner (rocking mode ω h = 0.7 at 1 ms, in J): after 0.5 s of sliding the state is
    within 1e-5 of rk4 at 10 µs (measured 5.8e-7). The contacts' K acts on body-axis increments of the
    free root's position: applied to the stage's world-axis increments instead, the tilted box rocks
    away (error 1.3)."""
    ref, _ = _slide(1e-5, 'rk4', 0.5, 1e5)
    y, sim = _slide(1e-3, 'rosenbrock2', 0.5, 1e5)
    assert np.abs(y - ref).max() < 1e-5, np.abs(y - ref).max()


# --------------------------------------------------------------------------------------------
# integrator auto on a ground
# --------------------------------------------------------------------------------------------
def test_auto_sees_the_ground_a_body_will_land_on(monkeypatch):
    """a1_stand starts 0.1 m above the ground, where nothing is stiff; auto also analyses it resting on
    the ground (ArmSystem.analysis_states: m g / k deep), where the friction slope refuses rk4 at 1 ms,
    and chooses rosenbrock2, saying why. Without that state it would choose rk4, which the contact makes
    inaccurate (8.7e-2 rad, docs/contact.md)."""
    import warnings

    from robodyn_ros.integrator_choice import plan_integrator
    from robodyn_ros.scene import load_scene
    from robodyn_ros.systems.arm import ArmSystem
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        sc = load_scene('a1_stand')
    s = sc.system
    assert not (s.contact.point_outputs(s._km, sc.y0[:s.nq], sc.y0[s.nq:])[:, PACTIVE] > 0).any()
    (rest,) = s.analysis_states(sc.y0)
    P = s.contact.point_outputs(s._km, rest[:s.nq], rest[s.nq:])
    mass = float(sum(sp.mass for sp in s.model.specs))
    assert abs(P[:, PDEPTH].max() - mass * G / s.contact.ground.stiffness) < 1e-12
    c = plan_integrator(s, sc.y0, dt=1e-3)
    assert c.integrator == 'rosenbrock2' and 'resting on the ground' in c.reason, c.reason
    import re
    hl = float(re.search(r'h·\|λ\| = ([0-9.e+]+)', c.reason).group(1))
    assert 2.785 < hl < 278.5, c.reason          # beyond RK4's limit; docs/contact.md: 58
    monkeypatch.setattr(ArmSystem, 'analysis_states', lambda self, y: [])
    assert plan_integrator(s, sc.y0, dt=1e-3).integrator == 'rk4'


def test_broken_ground_refused_by_robodyn_run_with_exit_2(tmp_path):
    """The command line: μ < 0 in a bundled ground scene -> ``file: key: reason`` on stderr, exit 2."""
    import subprocess
    import sys

    from robodyn_ros.scene import find_scene
    bad = tmp_path / 'bad.yaml'
    bad.write_text(find_scene('a1_stand').read_text().replace('friction: 0.8', 'friction: -0.8', 1))
    p = subprocess.run([sys.executable, '-m', 'robodyn_ros.cli', 'run', str(bad), '--duration', '0.01'],
                       capture_output=True, text=True, timeout=240)
    assert p.returncode == 2, (p.returncode, p.stderr)
    assert f'{bad}: parts[1].friction: must be >= 0.0, got -0.8' in p.stderr, p.stderr
    assert 'Traceback' not in p.stderr


# --------------------------------------------------------------------------------------------
# the bundled ground scenes' integrator and step (figures in docs/contact.md)
# --------------------------------------------------------------------------------------------
@functools.lru_cache(maxsize=None)
def _scene_run(name, integrator=None, dt=None, text=None, rtol=None):
    """The scene over its duration with its settings (or integrator/dt, rtol: rosenbrock2 under error
    control): per publication the joint positions, the base height and whether a point touches (the run
    ``robodyn bench contact --steps`` tabulates: ``bench.contact.scene_run``). Cached: the tests below share
    their references (the runs are deterministic, and the callers only read them)."""
    from robodyn_ros.bench.contact import scene_run
    r = scene_run(name, integrator, dt, text=text, rtol=rtol, step_budget=math.inf if rtol else None)
    return r['q'], r['z'], r['first'], r['sim'], r['scene']


@pytest.mark.parametrize('name, setting, reference, q_err, z_err, q_rest', [
    ('a1_stand', ('rosenbrock2', 1e-3, None), ('rk4', 5e-5), 2e-2, 1e-4, 1e-2),   # docs: 4.9e-3, 4.3e-4 rad, 1.8e-5 m
    ('solo12_drop', ('rosenbrock2', 1e-3, 1e-5), ('rk4', 1e-5), 3e-3, 1e-5, 2e-3)])   # docs: 6.2e-4, 2.3e-4, 3.4e-8
def test_ground_scenes_at_their_step_against_a_fine_reference(name, setting, reference, q_err, z_err, q_rest):
    """The scene's own integrator, step and tolerance against rk4 at a fine step over the scene's duration: the
    same publication of first impact, the joint positions within q_err (q_rest at the end), the base height at
    the end within z_err; docs/contact.md's table gives the figures measured against rk4 at 25 µs (a1_stand)
    and 5 µs (solo12_drop, whose friction slope is stiff for rk4: 50 µs errs 1.2e-3 rad there, 10 µs 1.1e-4)."""
    q, z, first, sim, sc = _scene_run(name)
    assert (sc.settings['integrator'], sc.settings['dt'], sc.settings.get('rtol')) == setting
    q_ref, z_ref, first_ref, _, _ = _scene_run(name, *reference)
    assert first == first_ref
    assert np.abs(q - q_ref).max() < q_err, np.abs(q - q_ref).max()
    assert np.abs(q[-1] - q_ref[-1]).max() < q_rest, np.abs(q[-1] - q_ref[-1]).max()
    assert abs(z[-1] - z_ref[-1]) < z_err, (z[-1], z_ref[-1])


def test_solo12_drop_under_error_control_takes_a_quarter_of_the_steps_of_rk4_at_50us():
    """docs/contact.md: the scene's controlled rosenbrock2 (rtol 1e-5, at most 1 ms) is more accurate than rk4 at
    50 µs against rk4 at 10 µs (measured 6.2e-4 and 1.2e-3 rad against 5 µs) in fewer than a quarter of its
    60 000 steps (10 488 taken, 182 rejected), each of which evaluates the dynamics twice where rk4 does 4 times."""
    q, _, _, sim, _ = _scene_run('solo12_drop')
    q_ref, _, _, _, _ = _scene_run('solo12_drop', 'rk4', 1e-5)
    q_rk4, _, _, rk4, _ = _scene_run('solo12_drop', 'rk4', 5e-5)
    st = sim.integrator.stats
    assert rk4.integrator.stats.steps == 60000
    assert st.steps + st.rejected_steps < 0.25 * 60000, (st.steps, st.rejected_steps)
    assert st.rejected_steps > 0          # the control acted: steps were refused, and retaken smaller
    assert np.abs(q - q_ref).max() < np.abs(q_rk4 - q_ref).max(), (np.abs(q - q_ref).max(), np.abs(q_rk4 - q_ref).max())


def test_the_humans_fall_under_error_control_converges_where_rk4_cannot_follow():
    """huston_human17_fall (rosenbrock2, rtol 1e-4, at most 1 ms): its standing feet's friction slope is stiff for
    rk4, whose error falls slowly and irregularly with its step; over the first 0.2 s rk4 at 10, 5 and 2.5 µs
    approaches the controlled run at rtol 1e-6 (1.5e-2, 7.4e-3, 7.3e-4), the scene's run within 2e-3 of it (5.9e-4).
    Over the whole fall, which is sensitive (rk4 at 50 µs to 2.5 µs all end in another rest posture, 0.62 rad away),
    the scene's run is within 3e-2 rad of rtol 1e-5 (1.0e-2; 1e-5 is within 4e-4 of 1e-6), with an energy
    balance within 0.1 J (3e-2) where rk4 at 50 µs adds more than 10 J (37 J)."""
    import warnings
    from robodyn_ros.scene import load_scene
    sc = load_scene('huston_human17_fall')
    assert (sc.settings['integrator'], sc.settings['dt'], sc.settings['rtol']) == ('rosenbrock2', 1e-3, 1e-4)

    def short(integrator, dt, rtol=None):
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            sim = Simulator(sc.system, sc.y0, integrator=integrator, dt=dt, rtol=rtol, step_budget=math.inf)
        sim.advance(0.2)
        return sim.y.copy()
    ref = short('rosenbrock2', 1e-3, 1e-6)
    errs = [np.abs(short('rk4', h) - ref).max() for h in (1e-5, 5e-6, 2.5e-6)]
    assert errs[0] > errs[1] > errs[2] and errs[2] < 0.1 * errs[0] and errs[2] < 2e-3, errs
    assert np.abs(short('rosenbrock2', 1e-3, 1e-4) - ref).max() < 2e-3
    q, z, first, sim, _ = _scene_run('huston_human17_fall')
    q_ref, z_ref, first_ref, _, _ = _scene_run('huston_human17_fall', 'rosenbrock2', 1e-3, rtol=1e-5)
    assert first == first_ref
    assert np.abs(q - q_ref).max() < 3e-2, np.abs(q - q_ref).max()
    assert abs(z[-1] - z_ref[-1]) < 1e-4
    assert abs(sim.energy_report()['drift']) < 0.1, sim.energy_report()
    _, _, _, rk4, _ = _scene_run('huston_human17_fall', 'rk4', 5e-5)
    assert rk4.energy_report()['drift'] > 10.0, rk4.energy_report()


def test_the_steps_the_ground_scenes_do_not_take():
    """docs/contact.md's reasons, against rk4 at 50 µs: rk4 at 1 ms on a1_stand is off by more than 1e-2
    rad (8.7e-2: the contacts' friction slope is explicit); rosenbrock2 at 1 ms on the limp solo12_drop
    keeps the base height at rest (< 1e-4 m; 8e-6) but not the rest posture (> 5e-3 rad; 4.7e-2); rk4 at
    0.5 ms there stays bounded (its friction saturates) but errs 2.5e-2 rad (within 5e-3 .. 0.1); on the
    human's fall rosenbrock2 in fixed 1 ms steps is off by more than 0.1 rad (1.5) against the controlled run
    at rtol 1e-5."""
    q, _, _, _, _ = _scene_run('a1_stand', 'rk4', 1e-3)
    q_ref, _, _, _, _ = _scene_run('a1_stand', 'rk4', 5e-5)
    assert 1e-2 < np.abs(q - q_ref).max() < 1.0
    q, z, _, _, _ = _scene_run('solo12_drop', 'rosenbrock2', 1e-3)
    q_ref, z_ref, _, _, _ = _scene_run('solo12_drop', 'rk4', 5e-5)
    assert abs(z[-1] - z_ref[-1]) < 1e-4
    assert 5e-3 < np.abs(q[-1] - q_ref[-1]).max() < 0.5
    q, _, _, _, _ = _scene_run('solo12_drop', 'rk4', 5e-4)
    assert 5e-3 < np.abs(q - q_ref).max() < 0.1          # stable at 0.5 ms, and 30 times the 50 µs run's error
    q, _, _, _, _ = _scene_run('huston_human17_fall', 'rosenbrock2', 1e-3)
    q_ref, _, _, _, _ = _scene_run('huston_human17_fall', 'rosenbrock2', 1e-3, rtol=1e-5)
    assert np.abs(q - q_ref).max() > 0.1


def test_at_half_a_millisecond_solo12s_friction_costs_most_and_its_touch_downs_the_rest():
    """docs/contact.md: rk4 at 0.5 ms on solo12_drop against rk4 at 50 µs, the scene as bundled and without
    friction (μ = 0, the same ground otherwise): the friction's stick/slip makes most of the error (2.5e-2
    rad with it, 2.7e-3 without: measured against 25 µs), the touch-downs' kink in the normal force the
    rest, which stays far above the 50 µs run's own error (7.3e-4 with friction, 4.5e-5 without)."""
    from robodyn_ros.scene import load_scene
    text = load_scene('solo12_drop').text
    assert text.count('friction: 0.8') == 1
    bare = text.replace('friction: 0.8', 'friction: 0.0')
    errors = {}
    for label, t in (('friction', text), ('none', bare)):
        q, _, _, _, _ = _scene_run('solo12_drop', 'rk4', 5e-4, text=t)
        q_ref, _, _, _, _ = _scene_run('solo12_drop', 'rk4', 5e-5, text=t)
        errors[label] = np.abs(q - q_ref).max()
    assert 5e-4 < errors['none'] < 0.3 * errors['friction'], errors


def test_the_large_root_damps_a_bounce_by_7_percent_per_step_at_omega_h_045():
    """docs/contact.md's price of γ = 1 + 1/√2: one generic rosenbrock2 step (J exact) on an undamped
    oscillator at ω h = 0.45 shrinks its amplitude (the energy norm) by 7 %; the small root by 0.1 %."""
    from robodyn_ros.integrators import GAMMA, make_integrator
    w, h = 450.0, 1e-3
    J = np.array([[0.0, 1.0], [-w * w, 0.0]])
    loss = {}
    for g in (GAMMA_STOP, GAMMA):
        integ = make_integrator('rosenbrock2', dt=h, jac=lambda t, y: J, gamma=g)
        y1, _ = integ.advance(lambda t, y: J @ y, 0.0, np.array([1.0, 0.0]), h)
        loss[g] = 1.0 - math.hypot(y1[0], y1[1] / w)
    assert abs(loss[GAMMA_STOP] - 0.07) < 0.005, loss
    assert 0.0 < loss[GAMMA] < 0.002, loss
