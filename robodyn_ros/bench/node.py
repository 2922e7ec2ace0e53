"""Benchmark of the sim node: real-time factor in ``max`` mode, command latency in ``lockstep``.

:func:`bench_node` starts the node in a subprocess on a private ROS domain (discovery limited to
this machine) with a probe node in this process, and returns table rows; it prints nothing.

- real-time factor: ``stanford_arm``, RK4 at dt = 1 ms (1 kHz), mode ``max``, no commands (the
  arm moves under gravity; the scene's scripted gravity compensation would add its own cost),
  ``joint_states`` at 1000 Hz and at 100 Hz with one subscriber (the probe) attached so that
  messages are really built and published (the node skips building messages for topics
  nobody subscribes to); the figure is simulated time / wall time of the run as the node's exit
  summary reports it (process start-up and scene loading excluded).
- latency: mode ``lockstep``; wall time from publishing one ``effort_commands`` message to
  receiving the ``joint_states`` it produced (one control period of integration included),
  at publish_rate 100 Hz (10 RK4 steps per period) and 1000 Hz (1 step): median and 95th
  percentile over ``n`` round trips.
- command-to-display latency of a viewer: the same round trip over the node's Foxglove WebSocket
  (``foxglove_port``): a client in this process publishes ``effort_commands`` and waits for the
  ``joint_states`` message-data frame the command produced (lockstep, 100 Hz).
"""
from __future__ import annotations

import re
import signal
import subprocess
import tempfile
import time

import numpy as np

SCENE = 'stanford_arm'
#: RK4 at 1 kHz (the node benchmark figure of the issue)
INTEGRATOR = {'integrator': 'rk4', 'dt': 0.001}
_SUMMARY_TIME = re.compile(r'simulated ([0-9.]+) s in ([0-9.]+) s wall')
_SUMMARY_CPU = re.compile(r'([0-9.]+) s CPU\)')


def _stop(proc) -> None:
    """End a sim node started here: SIGINT (it writes its summary and closes its recording), SIGKILL if it
    has not exited within 30 s."""
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def _max_mode_rtf(publish_rate: float, duration: float, profile: str | None = None) -> dict:
    """One max-mode run with a joint_states subscriber; returns the row (profile: run the node
    under cProfile, writing its statistics to this file)."""
    from ..nodes import probe as probe_mod
    from ..nodes.probe import Domain, Probe
    if profile:
        def start_sim(dom, params, stdout):
            cmd = probe_mod.sim_command(params)
            i = cmd.index('-m')
            return subprocess.Popen(cmd[:i] + ['-m', 'cProfile', '-o', profile] + cmd[i:], env=dom.env(),
                                    stdout=stdout, stderr=subprocess.STDOUT, start_new_session=True)
    else:
        start_sim = probe_mod.start_sim
    dom = Domain()
    probe = Probe(dom, 'robodyn_bench')
    from std_srvs.srv import SetBool
    received = []
    sub = probe.subscribe_count('joint_states', received)
    with tempfile.TemporaryFile() as log:
        # start paused, resume once the probe's subscription is matched: the whole timed run
        # builds and publishes its messages (paused time is left out of the node's summary)
        proc = start_sim(dom, {'scene': SCENE, 'mode': 'max', 'command_timeout': 0.0, 'start_paused': True,
                               'publish_rate': float(publish_rate), 'duration': float(duration), **INTEGRATOR},
                         stdout=log)
        try:
            if not probe.spin_until(lambda: sub.get_publisher_count() > 0, 60, proc):
                raise RuntimeError('the sim node did not come up')
            probe.call(SetBool, '/robodyn_sim/pause', SetBool.Request(data=False))
            probe.spin_until(lambda: proc.poll() is not None, 60 + 20 * duration)
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
            proc.wait(timeout=30)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            probe.close()
            dom.release()
        log.seek(0)
        text = log.read().decode('utf-8', 'replace')
    m = _SUMMARY_TIME.search(text)
    if not m:
        raise RuntimeError(f'sim node did not print its summary:\n{text[-2000:]}')
    sim_t, wall = float(m.group(1)), float(m.group(2))
    c = _SUMMARY_CPU.search(text)
    cpu = f', node CPU {float(c.group(1)):.3f} s (CPU-time RTF {sim_t / float(c.group(1)):.0f})' \
        if c and float(c.group(1)) > 0 else ''
    return {'figure': 'real-time factor', 'mode': 'max', 'publish_rate_hz': publish_rate,
            'value': round(sim_t / wall, 3), 'unit': 'x real time',
            'notes': f'{SCENE}, rk4 dt=1 ms, {sim_t:g} s simulated in {wall:.3f} s wall{cpu}, '
                     f'{len(received)} joint_states received by one subscriber'}


def _dds_account(publish_rate: float, duration: float, unprofiled: dict) -> dict:
    """What DDS delivery takes of a max-mode period: the node under cProfile, the time of the
    ``publish_raw`` calls (Fast DDS sending the serialized message to the subscriber, a C call the
    profiler hardly inflates) against the node's CPU per period in the unprofiled run."""
    import os
    import pstats
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, 'node.prof')
        _max_mode_rtf(publish_rate, duration, profile=path)
        st = pstats.Stats(path).stats
    pub = [(v[1], v[2]) for k, v in st.items() if k[2] == "<built-in method rclpy._rclpy_pybind11.publish_raw>"]
    periods = [(v[1], v[3]) for k, v in st.items() if k[2] == '_run_period']
    if not pub or not periods:
        raise RuntimeError('no publish_raw/_run_period in the node profile')
    n_pub, t_pub = pub[0]
    n_per, t_per = periods[0]
    m = re.search(r'node CPU ([0-9.]+) s', unprofiled['notes'])
    sim_t = duration
    cpu_period = float(m.group(1)) / (sim_t * publish_rate) if m else float('nan')
    per_pub = t_pub / n_pub
    own = cpu_period - per_pub * n_pub / n_per
    return {'figure': 'DDS publish per message (profiled)', 'mode': 'max', 'publish_rate_hz': publish_rate,
            'value': round(per_pub * 1e6, 1), 'unit': 'us per publish',
            'notes': f'cProfile of the node: {n_pub} publish_raw calls take {per_pub * 1e6:.0f} us each of '
                     f'{t_per / n_per * 1e6:.0f} us per (profiled) period; unprofiled the node needs '
                     f'{cpu_period * 1e6:.0f} us CPU per period, so without the publish its own work is about '
                     f'{own * 1e6:.0f} us (RTF about {1.0 / publish_rate / own:.0f})' if own > 0 else ''}


def _lockstep_latency(publish_rate: float, n: int) -> dict:
    """Round trips command -> joint_states against a lockstep node; returns the row."""
    from ..nodes.probe import Domain, Probe, start_sim
    dom = Domain()
    probe = Probe(dom, 'robodyn_bench')
    proc = start_sim(dom, {'scene': SCENE, 'mode': 'lockstep', 'publish_rate': float(publish_rate), **INTEGRATOR})
    try:
        lat = np.array(probe.lockstep_latency(n, [0.0] * 6, timeout=90.0)) * 1e3
    finally:
        _stop(proc)
        probe.close()
        dom.release()
    steps = int(round(1.0 / publish_rate / INTEGRATOR['dt']))
    return {'figure': 'command -> joint_states latency', 'mode': 'lockstep', 'publish_rate_hz': publish_rate,
            'value': round(float(np.median(lat)), 3), 'unit': 'ms (median)',
            'notes': f'p95 {np.percentile(lat, 95):.3f} ms, min {lat.min():.3f} ms over {n} round trips; '
                     f'includes {steps} rk4 step{"s" if steps > 1 else ""} of {SCENE}'}


def _live_latency(publish_rate: float, n: int) -> dict:
    """Round trips command -> joint_states over the node's Foxglove WebSocket (lockstep); returns the row."""
    import json
    import socket
    import struct

    from websockets.sync.client import connect

    from ..nodes.probe import Domain, start_sim
    from ..recording import cdr
    with socket.create_server(('127.0.0.1', 0)) as s:
        port = s.getsockname()[1]
    dom = Domain()
    proc = start_sim(dom, {'scene': SCENE, 'mode': 'lockstep', 'publish_rate': float(publish_rate),
                           'foxglove_port': port, **INTEGRATOR})
    lat = []
    try:
        end = time.monotonic() + 120
        while True:   # the node serves once it has started
            try:
                conn = connect(f'ws://127.0.0.1:{port}', subprotocols=['foxglove.websocket.v1'], max_size=None)
                ws = conn.__enter__()
                break
            except OSError:
                if time.monotonic() > end or proc.poll() is not None:
                    raise RuntimeError('the sim node did not serve') from None
                time.sleep(0.1)
        js = None
        while js is None:
            frame = ws.recv(timeout=60)
            if isinstance(frame, str) and json.loads(frame)['op'] == 'advertise':
                js = next((c['id'] for c in json.loads(frame)['channels'] if c['topic'] == '/joint_states'), None)
        ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [{'id': 1, 'channelId': js}]}))
        ws.send(json.dumps({'op': 'advertise', 'channels': [{'id': 1, 'topic': '/effort_commands', 'encoding': 'cdr',
                                                             'schemaName': 'std_msgs/msg/Float64MultiArray'}]}))
        payload = struct.pack('<BI', 1, 1) + cdr.encode('std_msgs/msg/Float64MultiArray', {'data': [0.0] * 6})

        def next_state(after):
            while True:
                frame = ws.recv(timeout=60)
                if isinstance(frame, bytes) and frame[0] == 1:
                    t = struct.unpack_from('<Q', frame, 5)[0]
                    if after is None or t > after:
                        return t
        t = next_state(None)   # the initial state (the last message, on subscribing)
        for _ in range(n):
            t0 = time.perf_counter()
            ws.send(payload)
            t = next_state(t)
            lat.append(time.perf_counter() - t0)
        conn.__exit__(None, None, None)
    finally:
        _stop(proc)
        dom.release()
    lat = np.array(lat) * 1e3
    return {'figure': 'command -> displayed joint_states latency (Foxglove WebSocket)', 'mode': 'lockstep',
            'publish_rate_hz': publish_rate, 'value': round(float(np.median(lat)), 3), 'unit': 'ms (median)',
            'notes': f'p95 {np.percentile(lat, 95):.3f} ms, min {lat.min():.3f} ms over {n} round trips: a client '
                     f'publishes effort_commands on the node\'s foxglove_port and waits for the joint_states frame'}


def bench_node(duration: float = 20.0, round_trips: int = 300) -> list:
    """Rows ``{figure, mode, publish_rate_hz, value, unit, notes}`` of the node benchmark.

    duration: simulated seconds of each max-mode run; round_trips: lockstep commands per
    latency figure. Takes about ``2 x duration / rtf + round_trips x latency + 4 x startup``.
    """
    rtf100 = _max_mode_rtf(100.0, duration)
    return [_max_mode_rtf(1000.0, duration), rtf100, _dds_account(100.0, duration, rtf100),
            _lockstep_latency(100.0, round_trips), _lockstep_latency(1000.0, round_trips),
            _live_latency(100.0, round_trips)]
