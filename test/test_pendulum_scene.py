"""Issue-2 acceptance checks on the bundled betancur_pendulum scene itself (not a stand-in model)."""
import numpy as np

from robodyn_ros.scene import load_scene
from robodyn_ros.simulation import Simulator


def _run(integrator, T, **kw):
    scene = load_scene('betancur_pendulum')
    sim = Simulator(scene.system, scene.y0, integrator=integrator, **kw)
    n = int(round(T * 100))
    for k in range(n):  # the scene's 100 Hz publication periods, as robodyn run advances
        sim.advance((k + 1) / 100)
    return sim


def test_dop853_energy_drift_below_5e9_over_10s():
    sim = _run('dop853', 10.0, rtol=1e-10, atol=1e-12)
    e = sim.energy_report()
    assert e['work'] == 0.0  # unactuated and undamped: the energy must stay E0
    # the chain really swings: kinetic energy is a sizeable part of the total at the end
    q, v = sim.system.split(sim.y)
    from robodyn_ros.dynamics import kinetic_energy
    assert kinetic_energy(sim.system.model, q, v) > 0.05 * abs(e['energy0'])
    assert abs(e['drift']) / abs(e['energy0']) < 5e-9   # measured 4.9e-11


def test_rk4_global_error_falls_by_16_when_the_step_halves():
    """In the asymptotic range. Measured ratios on this chaotic chain approach 16 from above as h
    shrinks (2→1 ms: 20.8, 1→0.5 ms: 18.9, then 17.6, 16.8), so the ladder starts at 0.5 ms."""
    T = 1.0
    ref = _run('dop853', T, rtol=3e-14, atol=1e-14).y
    errs = [np.abs(_run('rk4', T, dt=h).y - ref).max() for h in (5e-4, 2.5e-4, 1.25e-4)]
    ratios = [errs[0] / errs[1], errs[1] / errs[2]]
    assert len(ratios) == 2 and errs[2] > 1e-11  # well above the reference's own error (~2e-12)
    assert all(abs(r / 16.0 - 1.0) < 0.2 for r in ratios), (errs, ratios)
