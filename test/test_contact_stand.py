"""The bundled ground scenes: A1 standing under pd_hold (its weight carried, its centre of mass over
its feet, the ground only taking energy out), Solo-12 and the human fallen and at rest, and A1's drop
and stand against MuJoCo on the same URDF (robodyn_ros.bench.contact)."""
from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from robodyn_ros.kernels.contact import PACTIVE, PF, PX
from robodyn_ros.scene import load_scene
from robodyn_ros.simulation import Simulator, run_headless

G = 9.81


def _run(name, duration):
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        sc = load_scene(name)
        sim = Simulator(sc.system, sc.y0, integrator=sc.settings['integrator'], dt=sc.settings['dt'])
    run_headless(sim, duration, sc.settings['publish_rate'], sc.script)
    s = sim.system
    P = s.contact.point_outputs(s._km, sim.y[:s.nq], sim.y[s.nq:])
    return sc, sim, P


def _inside(p, hull):
    """Is point p (2,) strictly inside the convex polygon hull (k, 2), counter-clockwise? Its margin (m)."""
    margins = []
    for a, b in zip(hull, np.roll(hull, -1, axis=0)):
        e = b - a
        margins.append((e[0] * (p[1] - a[1]) - e[1] * (p[0] - a[0])) / np.linalg.norm(e))
    return min(margins)


def _hull(pts):
    """Convex hull (counter-clockwise) of 2-D points (monotone chain)."""
    pts = sorted(map(tuple, pts))

    def half(seq):
        out = []
        for p in seq:
            while len(out) >= 2 and ((out[-1][0] - out[-2][0]) * (p[1] - out[-2][1])
                                     - (out[-1][1] - out[-2][1]) * (p[0] - out[-2][0])) <= 0:
                out.pop()
            out.append(p)
        return out
    lower, upper = half(pts), half(reversed(pts))
    return np.array(lower[:-1] + upper[:-1])


def test_a1_stands_on_its_feet_carrying_its_weight():
    """After the drop and 5 s of pd_hold: the four feet touch and carry m g (the body at rest up to its
    last oscillation, < 1 %), the horizontal forces cancel, the centre of mass is over the support
    polygon of the feet (by more than 5 cm), and the contact work is negative: the ground takes
    energy (the landing's and the friction's) out and stores the springs' ½ k δ²."""
    sc, sim, P = _run('a1_stand', 5.0)
    s = sim.system
    mass = float(sum(sp.mass for sp in s.model.specs))
    on = P[:, PACTIVE] > 0
    links = {s.contact.points[k].link for k in np.flatnonzero(on)}
    assert links == {'FR_foot', 'FL_foot', 'RR_foot', 'RL_foot'}, links
    F = P[on, PF:PF + 3].sum(axis=0)
    assert abs(F[2] / (mass * G) - 1.0) < 0.01, (F, mass * G)
    assert np.hypot(F[0], F[1]) < 0.01 * mass * G
    _, _, com = s._km.momentum(sim.y[:s.nq], sim.y[s.nq:])
    margin = _inside(com[:2], _hull(P[on, PX:PX + 2]))
    assert margin > 0.05, margin
    e = sim.energy_report()
    assert e['contact_work'] < 0.0
    # the balance E − E₀ − W closes to the step's numerical dissipation (rosenbrock2 at 1 ms with a
    # contact touching: γ = 1 + 1/√2; docs/contact.md: −0.59 J of W = −15.9 J, 3.7 %; −0.29 J at 0.5 ms):
    # it takes, never adds
    assert -0.1 * abs(e['work']) < e['drift'] < 0.0, e


@pytest.mark.parametrize('name, duration, links', [
    ('solo12_drop', 3.0, None),
    ('huston_human17_fall', 4.0, None)])
def test_dropped_bodies_come_to_rest_on_the_ground(name, duration, links):
    """Solo-12 (limp) and the human fall, land and lie still: the ground carries m g."""
    sc, sim, P = _run(name, duration)
    s = sim.system
    mass = float(sum(sp.mass for sp in s.model.specs))
    F = P[P[:, PACTIVE] > 0, PF:PF + 3].sum(axis=0)
    assert abs(F[2] / (mass * G) - 1.0) < 0.05, (F, mass * G)
    assert sim.y[2] < sc.y0[2] - 0.05     # it fell
    e = sim.energy_report()
    assert e['contact_work'] < 0.0


def test_block_path_runs_a_floating_robot_on_the_ground_to_the_same_bytes(tmp_path, monkeypatch):
    """a1_stand in compiled blocks (odom, contact wrenches, joint wrenches under the contacts, the
    commands clamped to the effort limits in the loop): the recording and the final Simulator of the
    per-period path, byte for byte; kp raised so that the landing saturates the knees (clamps
    counted alike)."""
    from test_block_path import _both, _same_simulator

    from robodyn_ros.scene import find_scene, parse_scene
    text = find_scene('a1_stand').read_text().replace('kp: 40.0', 'kp: 200.0')
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        sc = parse_scene(text, file=str(find_scene('a1_stand')))
    (fast, n, sim_a, err_a), (slow, n2, sim_b, err_b), blocked = _both(
        tmp_path, monkeypatch, sc, 0.5, dt=sc.settings['dt'], rate=sc.settings['publish_rate'])
    assert err_a is None and err_b is None and n == n2 == 100
    assert blocked >= 90
    assert fast == slow
    _same_simulator(sim_a, sim_b)
    assert sim_a.ports['effort'].clamped > 0
