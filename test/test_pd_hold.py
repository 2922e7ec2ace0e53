"""The pd_hold command profile: its commands against its formula from the scene's keys, on a fixed
arm (with gravity compensation: RNEA) and on a floating robot (A1: positions and velocities picked
from a state whose q and v differ in layout); the block path runs it in the arm's compiled loop, with
the recording of the per-period path byte for byte; bad keys refused."""
from __future__ import annotations

import warnings

import numpy as np
import pytest
from test_block_path import _both, _same_simulator, _stanford_text

from robodyn_ros import dynamics as dyn
from robodyn_ros.scene import load_scene, parse_scene
from robodyn_ros.validation import SceneError

POSTURE = [0.1, 0.8, 0.3, 0.0, 0.5, -0.2]
PD_STANFORD = ('  effort: {profile: pd_hold, kp: [50.0, 80.0, 200.0, 2.0, 2.0, 0.2], kd: [5.0, 8.0, 20.0, 0.02, 0.02, 0.002], '
               f'posture: {POSTURE}, gravity_compensation: true}}')


def _stanford():
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        return parse_scene(_stanford_text(PD_STANFORD), file='stanford_pd.yaml')


def test_pd_hold_gives_the_command_its_formula_says():
    """u = kp (q* − q) − kd v + g(q) on the Stanford arm (g by the numpy reference RNEA: 1e-12), and
    kp (q* − q) − kd v exactly on A1, whose actuated joints sit at q[7:], v[6:]."""
    sc = _stanford()
    f, model = sc.script.profiles['effort'], sc.system.model
    kp = np.array([50.0, 80.0, 200.0, 2.0, 2.0, 0.2])
    kd = np.array([5.0, 8.0, 20.0, 0.02, 0.02, 0.002])
    rng = np.random.default_rng(4)
    worst = 0.0
    for _ in range(20):
        y = sc.y0 + rng.normal(0, 0.3, sc.system.ny)
        q, v = y[:6], y[6:]
        want = kp * (np.array(POSTURE) - q) - kd * v + dyn.rnea(model, q, np.zeros(6), np.zeros(6))
        worst = max(worst, float(np.abs(f(0.0, y) - want).max() / np.abs(want).max()))
    assert worst < 1e-12, worst
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        a1 = load_scene('a1_stand')
    f = a1.script.profiles['effort']
    keys = a1.data['commands']['effort']
    post = np.array([keys['posture'][j] for j in a1.system.actuated])
    for _ in range(20):
        y = a1.y0 + rng.normal(0, 0.3, a1.system.ny)
        assert np.array_equal(f(0.0, y), keys['kp'] * (post - y[7:19]) - keys['kd'] * y[25:37])


def test_pd_hold_in_the_block_path_records_the_per_period_bytes(tmp_path, monkeypatch):
    (fast, n, sim_a, err_a), (slow, n2, sim_b, err_b), blocked = _both(tmp_path, monkeypatch, _stanford(), 1.0)
    assert err_a is None and err_b is None and n == n2 == 100
    assert blocked >= 90            # the block path ran the profile in its compiled loop
    assert fast == slow
    _same_simulator(sim_a, sim_b)


@pytest.mark.parametrize('keys, where', [
    ('kp: -1.0, kd: 1.0', 'commands.effort.kp: must be >= 0.0'),
    ('kp: 1.0, kd: [1.0, 2.0]', 'commands.effort.kd'),
    ('kp: 1.0, kd: 1.0, posture: {nope: 0.0}', 'commands.effort.posture'),
    ('kd: 1.0', 'commands.effort'),
])
def test_bad_pd_hold_keys_are_refused(keys, where):
    with pytest.raises(SceneError) as e:
        parse_scene(_stanford_text('  effort: {profile: pd_hold, ' + keys + '}'), file='bad.yaml')
    assert str(e.value).startswith('bad.yaml: ' + where), str(e.value)
