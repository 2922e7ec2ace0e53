"""A1's drop and stand (a1_stand) against MuJoCo on the same URDF (robodyn_ros.bench.contact): MuJoCo
reads the URDF's collision primitives, the robot on a free joint over a plane, the same μ, the same PD
at the same rate, its contact time constant calibrated so that its feet sink as deep as ours at rest.

Tolerances (stated in docs/contact.md): first impact within 2 ms of MuJoCo's and 1 ms of the free
fall's closed form ``√(2 h / g)`` (h = 0.1 m: impacts are found at 1 ms resolution, and MuJoCo sees a
contact one step after the crossing); base height at rest within 6 mm (the landings differ: MuJoCo's
feet stick in its friction cone where ours slip and creep at the regularisation, so the stances end
a few millimetres apart); vertical ground force at rest within 1 % of m g on both.
"""
import math

import mujoco  # noqa: F401  (a test extra: the comparison needs it)
import numpy as np
import pytest


@pytest.fixture(scope='module')
def comparison():
    from robodyn_ros.bench import contact as bc
    return bc.compare(3.0)


def test_first_impact_matches_mujoco_and_the_free_fall(comparison):
    a, b = comparison['ours'], comparison['mujoco']
    assert b is not None, comparison.get('why')
    t_fall = math.sqrt(2 * 0.1 / 9.81)
    assert t_fall <= a['impact'] <= t_fall + 1e-3 + 1e-12, a['impact']
    assert abs(a['impact'] - b['impact']) <= 2e-3 + 1e-12, (a['impact'], b['impact'])


def test_rest_height_and_weight_match_mujoco(comparison):
    from robodyn_ros.bench.contact import rest
    a, b = comparison['ours'], comparison['mujoco']
    mg = comparison['mass'] * 9.81
    za, fa = rest(a)
    zb, fb = rest(b)
    assert abs(np.mean(b['depth']) / np.mean(a['depth']) - 1.0) < 0.1      # the calibration held
    assert abs(za - zb) < 6e-3, (za, zb)
    assert abs(fa / mg - 1.0) < 0.01 and abs(fb / mg - 1.0) < 0.01, (fa, fb, mg)
    assert 0.25 < za < 0.31     # standing, below the posture's 0.312 m (the PD sags under the weight)
