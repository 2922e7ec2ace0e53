"""Benchmark of live streaming: ``robodyn bench live`` (figures, never asserted).

The overhead of serving a run to one viewer: ``robodyn run SCENE --rate-factor 0 --record`` (as fast
as possible, every default topic recorded) with ``--live`` and one client subscribed to every
channel and reading everything (another process, as a browser would be), against the same run
without ``--live``; the real-time factor of each is its summary's (simulated time over the wall
time of the run, the paused start left out). The client is this module run as a script: written
from the protocol's specification on the ``websockets`` package (connect, subscribe to all channels,
resume the paused run with the ``pause`` service, read until the server closes).
"""
from __future__ import annotations

import json
import os
import re
import statistics
import struct
import subprocess
import sys
import tempfile
import time

HELP = 'live streaming overhead: real-time factor of robodyn run --live with a viewer against without'
#: (scene, simulated seconds): a few tenths of a second of wall time each as fast as possible
RUNS = (('stanford_arm', 60.0), ('a1_stand', 20.0))
_SUMMARY = re.compile(r'simulated ([0-9.]+) s in ([0-9.]+) s wall')


def add_arguments(p):
    p.add_argument('--repeat', type=int, default=3, help='runs of each kind (the median is printed)')
    p.add_argument('--scale', type=float, default=1.0, help='multiply the simulated durations')


def _rtf(text: str) -> float:
    m = _SUMMARY.search(text)
    if not m:
        raise RuntimeError(f'no run summary in:\n{text[-2000:]}')
    return float(m.group(1)) / float(m.group(2))


def _run(scene: str, duration: float, live: bool) -> tuple:
    """``(real-time factor, messages the client read or None)`` of one run."""
    with tempfile.TemporaryDirectory() as d:
        args = [sys.executable, '-m', 'robodyn_ros.cli', 'run', scene, '--duration', str(duration),
                '--record', os.path.join(d, 'run.mcap'), '--rate-factor', '0'] if live else \
            [sys.executable, '-m', 'robodyn_ros.cli', 'run', scene, '--duration', str(duration),
             '--record', os.path.join(d, 'run.mcap')]
        if not live:
            p = subprocess.run(args, capture_output=True, text=True, timeout=3600)
            return _rtf(p.stdout), None
        run = subprocess.Popen(args + ['--live', '--port', '0', '--start-paused'], stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True, env=dict(os.environ, PYTHONUNBUFFERED='1'))
        url = None
        lines = []
        for line in run.stdout:
            lines.append(line)
            m = re.search(r'^live\s+(ws://\S+)', line)
            if m:
                url = m.group(1)
                break
        if url is None:
            run.wait()
            raise RuntimeError(''.join(lines))
        client = subprocess.run([sys.executable, '-m', 'robodyn_ros.bench.live', 'client', url], capture_output=True,
                                text=True, timeout=3600)
        rest = run.stdout.read()
        run.wait()
        if client.returncode:
            raise RuntimeError(client.stderr[-2000:])
        return _rtf(''.join(lines) + rest), json.loads(client.stdout)['messages']


def bench_live(repeat: int = 3, scale: float = 1.0) -> list:
    """Rows ``{scene, duration, rtf_plain, rtf_live, ratio, messages}``: medians of ``repeat`` runs of each
    kind, the ratio the median of the ratios of the pairs run one after the other."""
    rows = []
    for scene, duration in RUNS:
        duration *= scale
        plain, live = [], []
        for _ in range(repeat):   # interleaved, so that a change of the machine's load hits both alike
            plain.append(_run(scene, duration, False)[0])
            live.append(_run(scene, duration, True))
        rp, rl = statistics.median(plain), statistics.median(r for r, _ in live)
        rows.append({'scene': scene, 'duration': duration, 'rtf_plain': rp, 'rtf_live': rl,
                     'ratio': statistics.median(r / p for (r, _), p in zip(live, plain)),
                     'messages': int(statistics.median(n for _, n in live))})
    return rows


def main(args) -> int:
    rows = bench_live(args.repeat, args.scale)
    print('### Live streaming to one viewer (`robodyn bench live`)\n')
    print('| scene, as fast as possible, every topic recorded | real-time factor without live | with --live and '
          'one viewer reading every channel | ratio, median of pairs (target >= 0.7) | messages the viewer read |')
    print('|---|---|---|---|---|')
    for r in rows:
        print(f'| {r["scene"]}, {r["duration"]:g} s simulated | {r["rtf_plain"]:.1f} | {r["rtf_live"]:.1f} | '
              f'{r["ratio"]:.2f} | {r["messages"]} |')
    return 0


# -- the viewer: a client from the protocol's specification (github.com/foxglove/ws-protocol) -----------
def _client(url: str) -> dict:
    """Subscribe to every channel of a paused run, resume it, read until it closes; the count read."""
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect
    channels, services, n = {}, {}, 0
    with connect(url, subprotocols=['foxglove.websocket.v1'], max_size=None) as ws:
        end = time.monotonic() + 120
        while not (services and any(c['topic'].endswith('/diagnostics') for c in channels.values())):
            if time.monotonic() > end:
                raise RuntimeError('the run advertised no diagnostics')
            frame = ws.recv(timeout=60)
            if isinstance(frame, str):
                msg = json.loads(frame)
                if msg['op'] == 'advertise':
                    channels.update({c['id']: c for c in msg['channels']})
                elif msg['op'] == 'advertiseServices':
                    services.update({s['name']: s for s in msg['services']})
        ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [{'id': i, 'channelId': i} for i in channels]}))
        pause = services['/robodyn/pause']['id']
        ws.send(struct.pack('<BIII', 2, pause, 1, 3) + b'cdr' + b'\x00\x01\x00\x00\x00')   # SetBool data: false
        try:
            while True:
                frame = ws.recv()
                if isinstance(frame, bytes) and frame[0] == 1:
                    n += 1
                elif isinstance(frame, str):
                    msg = json.loads(frame)
                    if msg['op'] == 'advertise':   # a channel that appears later: subscribe too
                        ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [
                            {'id': c['id'], 'channelId': c['id']} for c in msg['channels']]}))
        except ConnectionClosed:
            pass
    return {'messages': n}


if __name__ == '__main__' and len(sys.argv) == 3 and sys.argv[1] == 'client':
    print(json.dumps(_client(sys.argv[2])))
