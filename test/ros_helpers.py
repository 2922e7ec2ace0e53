"""Helpers for the ROS tests: private DDS domains, node subprocesses, an in-test ROS client,
and the lockstep PD controller that runs in its own process (``python test/ros_helpers.py pd``).

Every test gets its own ROS_DOMAIN_ID (1..100), claimed with an exclusive lock file so parallel
test runs on this machine never share a domain, and discovery limited to localhost.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time

from robodyn_ros.nodes.probe import DISCOVERY_ENV, Domain, Probe, sim_command  # noqa: F401

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# the test process itself talks ROS too: same discovery settings as the nodes it starts
for _k, _v in DISCOVERY_ENV.items():
    os.environ.setdefault(_k, _v)


def _die_with_parent():
    """preexec_fn: the child gets SIGKILL when the test process dies (Linux ``PR_SET_PDEATHSIG``),
    so a killed or crashed pytest leaves no node running in its ROS domain for later tests to meet."""
    import ctypes
    ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)   # 1 = PR_SET_PDEATHSIG


class Proc:
    """A subprocess whose output goes to a log file; always stopped by :meth:`cleanup`, and killed
    after the test that started it at the latest (conftest: :func:`kill_left_over`)."""

    #: every Proc started in this test process, in order (conftest kills those left running)
    started: list = []

    def __init__(self, cmd, env, log_path):
        self.cmd, self.log_path = cmd, str(log_path)
        self._log = open(self.log_path, 'wb')
        self.p = subprocess.Popen(cmd, env=env, cwd=REPO, stdout=self._log, stderr=subprocess.STDOUT,
                                  start_new_session=True, preexec_fn=_die_with_parent)
        Proc.started.append(self)

    @property
    def pid(self):
        return self.p.pid

    def alive(self) -> bool:
        return self.p.poll() is None

    def poll(self):
        return self.p.poll()

    def wait(self, timeout) -> int:
        return self.p.wait(timeout=timeout)

    def stop(self, sig=signal.SIGINT, timeout=30.0) -> int:
        """Send ``sig`` to the process (only it, by pid) and wait; SIGKILL if it does not exit."""
        if self.alive():
            self.p.send_signal(sig)
            try:
                return self.p.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.p.kill()
        return self.p.wait(timeout=10)

    def cleanup(self):
        if self.alive():
            self.p.kill()
            self.p.wait(timeout=10)
        self._log.close()

    def output(self) -> str:
        if not self._log.closed:
            self._log.flush()
        with open(self.log_path, 'rb') as f:
            return f.read().decode('utf-8', 'replace')


def kill_left_over(since: int = 0) -> list:
    """Kill every :class:`Proc` started at index ``since`` or later that still runs; returns their
    commands (a fixture or test that failed before its own cleanup leaves them)."""
    left = [p for p in Proc.started[since:] if p.alive()]
    for p in left:
        p.cleanup()
    return [p.cmd for p in left]


def start_sim(domain: Domain, params: dict, log_path, namespace=None) -> Proc:
    """Start the sim node (``python -m robodyn_ros.nodes.sim``) with parameters in ``domain``."""
    return Proc(sim_command(params, namespace), domain.env(), log_path)


def run_sim_to_end(params: dict, log_path, timeout=90) -> tuple:
    """Run the sim node with ``params`` (a ``duration`` or ``stop_when`` ends it) in its own ROS
    domain until it exits; returns ``(exit status, log text)``. The process is always cleaned up."""
    dom = Domain()
    try:
        node = start_sim(dom, params, log_path)
        try:
            rc = node.wait(timeout=timeout)
        finally:
            node.cleanup()
        return rc, node.output()
    finally:
        dom.release()


def start_pd(domain: Domain, log_path, **kw) -> Proc:
    """Start the lockstep PD controller of this file in its own process (see :func:`pd_main`)."""
    cmd = [sys.executable, os.path.abspath(__file__), 'pd']
    for k, v in kw.items():
        cmd += [f'--{k.replace("_", "-")}', ','.join(map(repr, v)) if isinstance(v, (list, tuple)) else str(v)]
    return Proc(cmd, domain.env(), log_path)


def lockstep_pd_run(tmp, sim_params: dict, setpoint, periods: int, timeout=90, **pd_kw):
    """Generator for a module fixture: a lockstep node recording to ``tmp/lockstep.mcap`` while the
    PD controller process closes the loop to ``setpoint`` for ``periods`` commands; then SIGINT. The
    PD process exits once the state its last command produced has arrived, so the node is idle
    (waiting for a command) when the signal comes: nothing else is left to publish or record.

    Yields ``{record, pd_rc, node_rc, tmp, pd (its JSON result or None), node_log, pd_log}``; the
    processes and the domain are always released.
    """
    import json
    dom = Domain()
    rec = tmp / 'lockstep.mcap'
    node = start_sim(dom, {**sim_params, 'mode': 'lockstep', 'record': str(rec)}, tmp / 'node.log')
    pd = start_pd(dom, tmp / 'pd.log', setpoint=setpoint, periods=periods, out=str(tmp / 'pd.json'),
                  timeout=timeout, **pd_kw)
    try:
        pd_rc = pd.wait(timeout=timeout + 10)
        node_rc = node.stop(signal.SIGINT)
        yield {'record': rec, 'pd_rc': pd_rc, 'node_rc': node_rc, 'tmp': tmp,
               'pd': json.loads((tmp / 'pd.json').read_text()) if (tmp / 'pd.json').exists() else None,
               'node_log': node.output(), 'pd_log': pd.output()}
    finally:
        pd.cleanup()
        node.cleanup()
        dom.release()


class RosClient(Probe):
    """The test process's rclpy context, node and executor in a domain (see Probe)."""


def stamp_ns(msg) -> int:
    """A message's header stamp in ns."""
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def lockstep_step(client, pub, msg, states, node, timeout=60.0, also=()) -> int:
    """Publish one command to a lockstep node and wait for the state of the period it ran: the last
    message of ``states`` (and of each list in ``also``, e.g. odom) stamped later than before.
    Counting messages is not enough: until its first command a lockstep node re-sends its initial
    state to new subscribers, and such a late copy must not pass for the next period's state
    (commands sent early on two topics may then be taken in another order). Returns the stamp (ns)."""
    last = stamp_ns(states[-1])
    pub.publish(msg)
    lists = (states, *also)
    assert client.spin_until(lambda: all(xs and stamp_ns(xs[-1]) > last for xs in lists)
                             and len({stamp_ns(xs[-1]) for xs in lists}) == 1, timeout, node), node.output()
    return stamp_ns(states[-1])


def diag_values(msg) -> dict:
    """key -> value strings of the first status of a DiagnosticArray."""
    return {kv.key: kv.value for kv in msg.status[0].values}


def headless_lockstep(sim, sink, periods, rate):
    """What a lockstep node does, without ROS: publish the state at t0, then per period set and
    record its commands (``periods[k]``: ``[(port, values)]`` received at its start, possibly none:
    a refused command still runs a period), advance one period and publish. The t0 state is
    published before any command is known (README: its effort is the command in force then, zero)."""
    sink.on_start(sim)
    sink.on_output(sim.t, sim.outputs(wrenches=True), sim)
    t_start = sim.t
    for k, commands in enumerate(periods):
        for port, values in commands:
            sim.set_command(port, values)
            sink.on_command(sim.t, port, sim.ports[port].value)
        sim.advance(t_start + (k + 1) / rate)   # the node's arithmetic for a period's end
        sink.on_output(sim.t, sim.outputs(wrenches=True), sim)
    sink.close()


def assert_lockstep_recording_equals_headless(rec, out, scene_path=None):
    """Re-run a lockstep node recording ``rec`` headless (the bundled scene it names, or the scene
    file ``scene_path``; its recorded settings, its recorded commands per period) into ``out``;
    every state message (joint_states, odom, constraint wrenches, /tf, /tf_static) and every
    command must be byte-identical. Returns the number of periods."""
    from robodyn_ros import messages as M
    from robodyn_ros.nodes.ports import command_values
    from robodyn_ros.recording import decode, read_raw_messages, summarize
    from robodyn_ros.recording.run_sink import McapRunSink
    from robodyn_ros.scene import load_scene
    from robodyn_ros.simulation import Simulator
    from robodyn_ros.systems.base import backend_scope
    s = summarize(rec)
    md = s['metadata']['robodyn']
    st = json.loads(md['settings'])
    assert st['mode'] == 'lockstep'
    with backend_scope(st['backend']):
        scene = load_scene(scene_path or md['scene_name'])
    assert scene.text == md['scene']
    sim = Simulator(scene.system, st['y0'], integrator=st['integrator'], dt=st['dt'], rtol=st['rtol'],
                    atol=st['atol'], command_timeout=st['command_timeout'])
    port_of = {'/' + M.PORT_TOPICS[p]: p for p in scene.system.inputs if p in M.PORT_TOPICS}
    stamps = [t for _, _, t, _ in read_raw_messages(rec, topics=['/joint_states'])]
    assert stamps == sorted(set(stamps)) and len(stamps) > 2
    periods = [[] for _ in stamps[1:]]
    index = {t: k for k, t in enumerate(stamps)}
    for topic, ty, t, raw in read_raw_messages(rec, topics=list(port_of)):
        periods[index[t]].append((port_of[topic], command_values(port_of[topic], decode(ty, raw))))
    assert sum(map(len, periods)) > 0
    headless_lockstep(sim, McapRunSink(out, scene, {'mode': 'headless'}), periods, st['rate'])
    topics = [t for t in s['topics'] if t.rsplit('/', 1)[-1] in ('joint_states', 'odom', 'tf', 'tf_static')
              or '/constraint_wrenches/' in t or t in port_of]
    assert '/joint_states' in topics and any(t in port_of for t in topics)
    for topic in topics:
        a = [(t, raw) for _, _, t, raw in read_raw_messages(rec, topics=[topic])]
        b = [(t, raw) for _, _, t, raw in read_raw_messages(out, topics=[topic])]
        assert a and a == b, topic
    return len(periods)


def assert_lockstep_recording_reproduced(rec, tmp, periods, scene_path=None):
    """A lockstep node recording of ``periods`` periods equals the headless run fed the same
    commands (:func:`assert_lockstep_recording_equals_headless`, ``scene_path`` as there), and
    ``robodyn resim`` reproduces every state message of it exactly (joint_states, odom, wrenches, TF)."""
    import contextlib
    import io

    from robodyn_ros.cli import main as robodyn
    assert assert_lockstep_recording_equals_headless(rec, os.path.join(tmp, 'headless.mcap'), scene_path) == periods
    text = io.StringIO()
    with contextlib.redirect_stdout(text):
        assert robodyn(['resim', str(rec), '--record', os.path.join(tmp, 'resim.mcap'), '--json']) == 0
    report = json.loads(text.getvalue())
    assert report['max_deviation'] == 0.0
    for topic in ('/joint_states', '/odom'):
        assert report['topics'][topic] == {'original': periods + 1, 'resimulated': periods + 1,
                                           'identical': periods + 1, 'max_deviation': 0.0}, topic
    assert all(v['identical'] == v['original'] == v['resimulated'] for v in report['topics'].values())


# ------------------------------------------------------------------------------------------
# The PD controller process: computed-torque PD on stanford_arm, one command per new state
# ------------------------------------------------------------------------------------------
def pd_main(argv=None) -> int:
    """Close a computed-torque PD loop through the topics; write a JSON result and exit.

    Waits until its command publisher is matched, then subscribes ``joint_states``; answers
    every new state stamp exactly once with ``u = M(q) (Kp (q* - q) - Kd v) + h(q, v)``
    (RNEA at the desired acceleration), until ``--periods`` commands were sent.
    """
    ap = argparse.ArgumentParser()
    ap.add_argument('--setpoint', required=True)
    ap.add_argument('--periods', type=int, required=True)
    ap.add_argument('--out', required=True)
    ap.add_argument('--kp', type=float, default=100.0)
    ap.add_argument('--kd', type=float, default=20.0)
    ap.add_argument('--scene', default='stanford_arm')
    ap.add_argument('--timeout', type=float, default=60.0)
    a = ap.parse_args(argv)
    import numpy as np
    import rclpy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    from robodyn_ros import dynamics as dyn
    from robodyn_ros.scene import load_scene
    model = load_scene(a.scene).system.model
    qstar = np.array([float(x) for x in a.setpoint.split(',')])
    rclpy.init()
    node = rclpy.create_node('pd_controller')
    pub = node.create_publisher(Float64MultiArray, 'effort_commands', 10)
    state = {'sent': 0, 'last': None, 'q': None, 'sent_at': None}

    def on_state(msg):
        stamp = (msg.header.stamp.sec, msg.header.stamp.nanosec)
        if stamp == state['last']:
            return  # a re-sent state: answer each stamp once
        state['last'] = stamp
        q, v = np.array(msg.position), np.array(msg.velocity)
        state['q'] = q.tolist()
        if state['sent'] >= a.periods:
            return
        qdd = a.kp * (qstar - q) - a.kd * v
        u = dyn.rnea(model, q, v, qdd)
        pub.publish(Float64MultiArray(data=u.tolist()))
        state['sent'] += 1
        state['sent_at'] = stamp

    end = time.monotonic() + a.timeout
    while pub.get_subscription_count() == 0 and time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    node.create_subscription(JointState, 'joint_states', on_state, 10)
    # run until the state produced by the last command has arrived
    while time.monotonic() < end and not (state['sent'] >= a.periods and state['last'] != state['sent_at']):
        rclpy.spin_once(node, timeout_sec=0.05)
    with open(a.out, 'w') as f:
        json.dump({'sent': state['sent'], 'q': state['q'], 'stamp': state['last']}, f)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0 if state['sent'] >= a.periods else 1


if __name__ == '__main__':
    if len(sys.argv) > 1 and sys.argv[1] == 'pd':
        sys.exit(pd_main(sys.argv[2:]))
    sys.exit(f'usage: {sys.argv[0]} pd --setpoint q1,q2,... --periods N --out result.json')
