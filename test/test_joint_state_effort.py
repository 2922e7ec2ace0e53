"""Which command a ``joint_states`` effort is, read from recordings (README, "The node and its interface").

A message stamped t_k (k >= 1) carries the command held over the period (t_{k-1}, t_k] that ends
at its stamp. The message at t0 carries the command applied from t0 on: with scripted commands
(``robodyn run``, the node with ``scripted_commands``) that is the first scripted command, for
stanford_arm u(0) = g(q0), checked against Pinocchio's gravity torques; with commands from topics
(lockstep) nothing has been received at t0, so it is zero.
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from ros_helpers import run_sim_to_end

from robodyn_ros.cli import main as robodyn
from robodyn_ros.model import to_urdf
from robodyn_ros.recording import read_messages, read_raw_messages
from robodyn_ros.scene import load_scene

SCENE = load_scene('stanford_arm')


def _raw(path):
    return [(topic, t, bytes(data)) for topic, _, t, data in read_raw_messages(path) if topic != '/diagnostics']


def _stamp(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def efforts_and_commands(path):
    """``(joint_states [(t_ns, effort)], effort_commands [(t_ns, values)])`` in file order."""
    js, cmd = [], []
    for topic, _, t_ns, msg in read_messages(path, topics=['/joint_states', '/effort_commands']):
        if topic == '/joint_states':
            assert _stamp(msg) == t_ns
            js.append((t_ns, np.array(msg.effort)))
        else:
            cmd.append((t_ns, np.array(msg.data)))
    assert len(js) >= 5, f'{path}: only {len(js)} joint_states'
    return js, cmd


def assert_effort_is_the_command_held_over_the_period_ending_at_its_stamp(js, cmd):
    """The rule for every message after t0; returns the effort at t0."""
    for (t_prev, _), (t, effort) in zip(js, js[1:]):
        held = [c for tc, c in cmd if tc <= t_prev]  # commands set at or before the period's start
        assert not [tc for tc, _ in cmd if t_prev < tc < t], 'a command inside a period'
        np.testing.assert_array_equal(effort, held[-1] if held else 0.0, err_msg=f't = {t} ns')
    return js[0][1]


def gravity_torques(q):
    """g(q) by Pinocchio from the URDF we export (independent of our RNEA)."""
    model = SCENE.system.model
    pm = pin.buildModelFromXML(to_urdf(model))
    pm.gravity.linear = np.asarray(model.gravity, dtype=float)
    return pin.computeGeneralizedGravity(pm, pm.createData(), np.asarray(q, dtype=float))


def test_headless_t0_effort_is_the_command_applied_from_t0(tmp_path):
    rec = tmp_path / 'run.mcap'
    assert robodyn(['run', 'stanford_arm', '--duration', '0.1', '--record', str(rec)]) == 0
    js, cmd = efforts_and_commands(rec)
    assert [t for t, _ in js] == [k * 10_000_000 for k in range(11)] and len(cmd) == 10
    e0 = assert_effort_is_the_command_held_over_the_period_ending_at_its_stamp(js, cmd)
    assert cmd[0][0] == 0
    np.testing.assert_array_equal(e0, cmd[0][1])       # the command applied from t0 on
    g0 = gravity_torques(SCENE.y0[:SCENE.system.model.nq])
    assert np.abs(g0).max() > 1.0
    np.testing.assert_allclose(e0, g0, rtol=0, atol=1e-10 * np.abs(g0).max())   # u(0) = g(q0)
    # resim rebuilds the same messages, byte for byte and in the same order (the t0 command is
    # recorded before the t0 state); diagnostics (resim writes them at its own period) left out
    assert robodyn(['resim', str(rec), '--record', str(tmp_path / 'again.mcap')]) == 0
    assert _raw(tmp_path / 'again.mcap') == _raw(rec)


@pytest.mark.processes
def test_node_scripted_t0_effort_is_the_first_scripted_command_and_equals_headless(tmp_path):
    """The node with scripted commands follows the same rule, and its joint_states equal a headless run's."""
    rec = tmp_path / 'node.mcap'
    rc, log = run_sim_to_end({'scene': 'stanford_arm', 'mode': 'max', 'scripted_commands': True, 'duration': 0.1,
                              'record': str(rec)}, tmp_path / 'node.log')
    assert rc == 0, log
    js, cmd = efforts_and_commands(rec)
    e0 = assert_effort_is_the_command_held_over_the_period_ending_at_its_stamp(js, cmd)
    assert cmd[0][0] == 0
    np.testing.assert_array_equal(e0, cmd[0][1])
    head = tmp_path / 'headless.mcap'
    assert robodyn(['run', 'stanford_arm', '--duration', '0.1', '--record', str(head)]) == 0
    hjs, hcmd = efforts_and_commands(head)
    assert len(hjs) == len(js) and all(a == b and np.array_equal(x, y) for (a, x), (b, y) in zip(hjs, js))
    assert len(hcmd) == len(cmd) and all(a == b and np.array_equal(x, y) for (a, x), (b, y) in zip(hcmd, cmd))
