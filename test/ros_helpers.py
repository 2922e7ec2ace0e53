"""Helpers for the ROS tests: private DDS domains, node subprocesses, an in-test ROS client,
and the lockstep PD controller that runs in its own process (``python test/ros_helpers.py pd``).

Every test gets its own ROS_DOMAIN_ID (1..100), claimed with an exclusive lock file so parallel
test runs on this machine never share a domain, and discovery limited to localhost.
"""
from __future__ import annotations

import argparse
import fcntl
import json
import os
import signal
import subprocess
import sys
import time

LOCK_DIR = os.path.join('/tmp', f'robodyn_ros_domains.{os.getuid()}')
REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DISCOVERY_ENV = {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', 'RCUTILS_COLORIZED_OUTPUT': '0',
                 'PYTHONUNBUFFERED': '1'}
# the test process itself talks ROS too: same discovery settings as the nodes it starts
for _k, _v in DISCOVERY_ENV.items():
    os.environ.setdefault(_k, _v)


class Domain:
    """An exclusively claimed ROS_DOMAIN_ID; release() (or process exit) frees it."""

    def __init__(self):
        os.makedirs(LOCK_DIR, exist_ok=True)
        start = (os.getpid() * 7919 + int(time.monotonic() * 1000)) % 100
        for k in range(100):
            did = (start + k) % 100 + 1
            fd = os.open(os.path.join(LOCK_DIR, f'{did}.lock'), os.O_CREAT | os.O_RDWR, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                os.close(fd)
                continue
            self.id, self._fd = did, fd
            return
        raise RuntimeError('no free ROS domain id in 1..100')

    def env(self) -> dict:
        """Environment for a subprocess in this domain."""
        return dict(os.environ, ROS_DOMAIN_ID=str(self.id), **DISCOVERY_ENV)

    def release(self):
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


def ros_args(params: dict) -> list:
    """``--ros-args -p k:=v ...`` with YAML-formatted values."""
    out = ['--ros-args']
    for k, v in params.items():
        if isinstance(v, bool):
            v = 'true' if v else 'false'
        elif isinstance(v, (list, tuple)):
            v = '[' + ','.join(repr(float(x)) for x in v) + ']'
        elif isinstance(v, str) and v == '':
            v = "''"
        out += ['-p', f'{k}:={v}']
    return out


class Proc:
    """A subprocess whose output goes to a log file; always stopped by :meth:`cleanup`."""

    def __init__(self, cmd, env, log_path):
        self.cmd, self.log_path = cmd, str(log_path)
        self._log = open(self.log_path, 'wb')
        self.p = subprocess.Popen(cmd, env=env, cwd=REPO, stdout=self._log, stderr=subprocess.STDOUT,
                                  start_new_session=True)

    @property
    def pid(self):
        return self.p.pid

    def alive(self) -> bool:
        return self.p.poll() is None

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


def start_sim(domain: Domain, params: dict, log_path, namespace=None) -> Proc:
    """Start the sim node (``python -m robodyn_ros.nodes.sim``) with parameters in ``domain``."""
    cmd = [sys.executable, '-m', 'robodyn_ros.nodes.sim'] + ros_args(params)
    if namespace:
        cmd += ['-r', f'__ns:={namespace}']
    return Proc(cmd, domain.env(), log_path)


def start_pd(domain: Domain, log_path, **kw) -> Proc:
    """Start the lockstep PD controller of this file in its own process (see :func:`pd_main`)."""
    cmd = [sys.executable, os.path.abspath(__file__), 'pd']
    for k, v in kw.items():
        cmd += [f'--{k.replace("_", "-")}', ','.join(map(repr, v)) if isinstance(v, (list, tuple)) else str(v)]
    return Proc(cmd, domain.env(), log_path)


class RosClient:
    """An rclpy context, node and executor of the test process in ``domain``."""

    _count = 0

    def __init__(self, domain: Domain, name='test_client'):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        self.rclpy = rclpy
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain.id)
        RosClient._count += 1
        self.node = rclpy.create_node(f'{name}_{os.getpid()}_{RosClient._count}', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin_until(self, pred, timeout: float, proc: Proc | None = None) -> bool:
        """Spin until ``pred()`` is true (True) or ``timeout`` s pass (False); stop early if proc died."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if pred():
                return True
            if proc is not None and not proc.alive():
                return bool(pred())
            self.executor.spin_once(timeout_sec=0.02)
        return bool(pred())

    def spin_for(self, seconds: float):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.02)

    def call(self, srv_type, name, request, timeout=10.0):
        """Call a service and return its response (raises on timeout)."""
        cli = self.node.create_client(srv_type, name)
        try:
            if not cli.wait_for_service(timeout_sec=timeout):
                raise TimeoutError(f'service {name} not available')
            fut = cli.call_async(request)
            if not self.spin_until(fut.done, timeout):
                raise TimeoutError(f'service {name} did not answer')
            return fut.result()
        finally:
            self.node.destroy_client(cli)

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.context)


def diag_values(msg) -> dict:
    """key -> value strings of the first status of a DiagnosticArray."""
    return {kv.key: kv.value for kv in msg.status[0].values}


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
