"""Measuring the sim node from outside: a private ROS domain, node subprocesses, and a probe node.

Used by the node benchmark (:mod:`robodyn_ros.bench.node`) and the ROS tests. rclpy is imported
inside the functions and methods that need it.
"""
from __future__ import annotations

import fcntl
import os
import subprocess
import sys
import time

#: environment of every process of a measurement: discovery on this machine only
DISCOVERY_ENV = {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', 'RCUTILS_COLORIZED_OUTPUT': '0',
                 'PYTHONUNBUFFERED': '1'}
LOCK_DIR = os.path.join('/tmp', f'robodyn_ros_domains.{os.getuid()}')


class Domain:
    """An exclusively claimed ROS_DOMAIN_ID in 1..100 (lock file per id); release() frees it.

    Parallel test runs and benchmarks on one machine therefore never share a domain.
    """

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
        """Give the id back (also happens when the process exits)."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


def ros_args(params: dict) -> list:
    """``--ros-args -p k:=v ...`` for a parameter dict (bools, numbers, strings, number lists)."""
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


def sim_command(params: dict, namespace: str | None = None) -> list:
    """argv that starts the sim node with ``params`` (this interpreter, ``-m robodyn_ros.nodes.sim``)."""
    cmd = [sys.executable, '-m', 'robodyn_ros.nodes.sim'] + ros_args(params)
    if namespace:
        cmd += ['-r', f'__ns:={namespace}']
    return cmd


def start_sim(domain: Domain, params: dict, stdout=subprocess.DEVNULL, namespace=None, cwd=None):
    """Start the sim node in ``domain``; returns the Popen (the caller stops it)."""
    return subprocess.Popen(sim_command(params, namespace), env=domain.env(), stdout=stdout,
                            stderr=subprocess.STDOUT, start_new_session=True, cwd=cwd)


class Probe:
    """An rclpy context, node and executor in ``domain`` (set ``DISCOVERY_ENV`` before use)."""

    _count = 0

    def __init__(self, domain: Domain, name='robodyn_probe'):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        for k, v in DISCOVERY_ENV.items():
            os.environ.setdefault(k, v)
        self.rclpy = rclpy
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain.id)
        Probe._count += 1
        self.node = rclpy.create_node(f'{name}_{os.getpid()}_{Probe._count}', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin_until(self, pred, timeout: float, proc=None, step=0.02) -> bool:
        """Spin until ``pred()`` is true (True) or ``timeout`` s pass (False); stop early if proc exited."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if pred():
                return True
            if proc is not None and proc.poll() is not None:
                return bool(pred())
            self.executor.spin_once(timeout_sec=step)
        return bool(pred())

    def spin_for(self, seconds: float):
        """Spin for ``seconds`` of wall time."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=min(0.02, max(end - time.monotonic(), 0.0)))

    def call(self, srv_type, name: str, request, timeout: float = 10.0):
        """Call service ``name`` and return the response (TimeoutError if it does not answer)."""
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

    def subscribe_count(self, topic: str, sink: list, type_name='sensor_msgs/msg/JointState'):
        """Subscribe ``topic`` (depth 1000) appending the receive time of every message to ``sink``."""
        import importlib
        pkg, _, name = type_name.split('/')
        cls = getattr(importlib.import_module(f'{pkg}.msg'), name)
        return self.node.create_subscription(cls, topic, lambda m: sink.append(time.perf_counter()), 1000)

    def lockstep_latency(self, n: int, command, timeout: float = 60.0) -> list:
        """Wall seconds from publishing a command to receiving the ``joint_states`` it produced.

        Talks to a node in lockstep mode: waits for the initial state, then ``n`` times publishes
        ``command`` on ``effort_commands`` and waits for the next state stamp.
        """
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64MultiArray
        got = []
        sub = self.node.create_subscription(JointState, 'joint_states', lambda m: got.append(
            (time.perf_counter(), m.header.stamp.sec, m.header.stamp.nanosec)), 10)
        pub = self.node.create_publisher(Float64MultiArray, 'effort_commands', 10)
        try:
            if not self.spin_until(lambda: got and pub.get_subscription_count(), timeout):
                raise TimeoutError('no joint_states from a lockstep node (is it running?)')
            msg = Float64MultiArray(data=[float(x) for x in command])
            out = []
            for _ in range(n):
                last = got[-1][1:]
                t0 = time.perf_counter()
                pub.publish(msg)
                while got[-1][1:] == last:
                    self.executor.spin_once(timeout_sec=0.5)
                    if time.perf_counter() - t0 > timeout:
                        raise TimeoutError('lockstep node stopped answering')
                out.append(got[-1][0] - t0)
            return out
        finally:
            self.node.destroy_subscription(sub)
            self.node.destroy_publisher(pub)

    def close(self):
        """Destroy the node and shut the context down."""
        self.executor.shutdown()
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.context)
