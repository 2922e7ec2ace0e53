"""``robodyn resim``: re-simulate a recording's commands and compare the states with the original.

The recording's ``robodyn`` metadata holds the scene file text, the run settings (integrator,
step/tolerances, publication rate, command timeout, initial state) and the package version.
A fresh simulator built from them walks the recording in file order:

- a command (``effort_commands``, ``wheel_voltage_commands``, ``base_wrench_command``) is applied
  at its log time (advancing to it first if it lies after the current time);
- a ``joint_states`` message marks a publication: advance to its log time, compute the outputs
  and record them like the original run did.

The node and ``robodyn run`` apply commands only at period boundaries and advance one period
per publication, so this replays exactly the same sequence of ``advance`` calls: a lockstep,
max-rate, real-time or headless recording re-simulates to byte-identical state messages.
"""
from __future__ import annotations

import json
import math
import os
import sys

#: one line for ``robodyn --help``
HELP = 're-simulate the commands of a recording and compare the states'


def add_parser(sub):
    """Register the subcommand and its options."""
    p = sub.add_parser('resim', help=HELP)
    p.add_argument('input', help='MCAP recording made by the sim node or robodyn run')
    p.add_argument('--record', required=True, help='MCAP file to write the re-simulation to (an existing file is '
                                                   'refused)')
    p.add_argument('--overwrite', action='store_true', help='replace the --record file if it exists')
    p.add_argument('--tolerance', type=float, default=0.0,
                   help='largest state deviation accepted (SI units of the fields; default 0: exact)')
    p.add_argument('--json', action='store_true', help='print the report as JSON')
    return p


def _relative(topic: str, namespace: str) -> str:
    """Topic name relative to the namespace (``/ns/joint_states`` -> ``joint_states``)."""
    ns = '/' + namespace.strip('/') if namespace.strip('/') else ''
    return topic[len(ns) + 1:] if topic.startswith(ns + '/') else topic


def _is_state(rel: str) -> bool:
    # /tf and /tf_static (absolute; 'tf' relative to an empty namespace) are derived from the
    # state (robodyn_ros.tf): compared too
    return (rel in ('joint_states', 'odom', 'joint_trajectory_desired', 'joint_trajectory_error')
            or rel.startswith(('constraint_wrenches/', 'contact_wrenches/', 'imu/', 'ft/'))
            or rel.lstrip('/') in ('tf', 'tf_static'))


def _numbers(msg, skip=('header',)) -> np.ndarray:
    """Every number in a decoded message dict, flattened in field order (headers skipped)."""
    import numpy as np
    out = []

    def walk(v):
        if isinstance(v, dict):
            for k, x in v.items():
                if k not in skip:
                    walk(x)
        elif isinstance(v, np.ndarray):
            out.extend(v.astype(float).ravel().tolist())
        elif isinstance(v, (list, tuple)):
            for x in v:
                walk(x)
        elif isinstance(v, (bool, int, float)):
            out.append(float(v))
    walk(msg)
    return np.array(out, dtype=float)


def _deviation(type_name, a: bytes, b: bytes) -> float:
    """Largest absolute difference between the numbers of two messages (inf if the layouts differ)."""
    from ..recording import decode
    da, db = decode(type_name, a), decode(type_name, b)
    ha, hb = da.get('header'), db.get('header')
    if ha is not None and ha != hb:
        return math.inf
    xa, xb = _numbers(da), _numbers(db)
    if xa.shape != xb.shape:
        return math.inf
    if xa.size == 0:
        return 0.0
    import numpy as np
    d = np.abs(xa - xb)
    d[(xa == xb) | (np.isnan(xa) & np.isnan(xb))] = 0.0
    return float(np.max(d))


class Resim:
    """Rebuild the run of ``path`` from its metadata (scene, settings, namespace)."""

    def __init__(self, path):
        from ..recording import summarize
        from ..scene import parse_scene
        self.path = str(path)
        self.summary = s = summarize(self.path)
        md = s['metadata'].get('robodyn')
        if not md or 'scene' not in md or 'settings' not in md:
            raise ValueError(f'{self.path}: no robodyn metadata record with the scene and settings '
                             f'(was it recorded by the sim node or robodyn run?)')
        self.metadata = md
        self.settings = json.loads(md['settings'])
        from ..systems.base import backend_scope
        with backend_scope(self.settings.get('backend')):  # the kernels of the run (older recordings: default)
            self.scene = parse_scene(md['scene'], file=f'{self.path} (recorded scene {md.get("scene_name", "?")})')
        ns = self.settings.get('namespace')
        if ns is None:  # infer from where joint_states was recorded
            js = [t for t in s['topics'] if t.rstrip('/').endswith('/joint_states')]
            ns = js[0][:-len('/joint_states')] if js else ''
        self.namespace = ns.strip('/')
        self.rate = float(self.settings['rate'])
        self.topics = {t: _relative(t, self.namespace) for t in s['topics']}
        self.wrenches = any(r.startswith('constraint_wrenches/') for r in self.topics.values())
        self.tf = '/tf' in self.topics   # recorded with TF (not with robodyn run --no-tf)

    def simulator(self):
        import numpy as np

        from ..simulation import Simulator
        st = self.settings
        y0 = np.array(st['y0'], dtype=float) if st.get('y0') is not None else self.scene.y0
        return Simulator(self.scene.system, y0, integrator=st['integrator'], dt=st.get('dt'),
                         rtol=st.get('rtol'), atol=st.get('atol'), command_timeout=st.get('command_timeout'),
                         step_budget=st.get('step_budget'))

    def time_of(self, t_ns: int, t_start: float) -> float:
        """Simulation time (s) of a log time, computed as the run computed it: ``t_start + k / rate``."""
        from ..messages import to_ns
        k = round((t_ns - to_ns(t_start)) * self.rate / 1e9)
        t = t_start + k / self.rate
        return t if to_ns(t) == t_ns else t_ns / 1e9

    def run(self, out_path) -> dict:
        """Re-simulate into ``out_path``; return counts (publications, commands, rejected)."""
        from .. import messages as M
        from ..nodes.ports import command_values
        from ..recording import decode, read_raw_messages
        from ..recording.run_sink import HEADLESS_BATCH, McapRunSink
        from ..simulation import CommandError
        sim = self.simulator()
        ports = {M.PORT_TOPICS[p]: p for p in sim.system.inputs if p in M.PORT_TOPICS}
        wanted = {t for t, r in self.topics.items() if r in ports or r == 'joint_states'}
        settings = dict(self.settings, resim_of=os.path.basename(self.path))
        os.makedirs(os.path.dirname(os.path.abspath(out_path)), exist_ok=True)
        sink = McapRunSink(out_path, self.scene, settings, record_wrenches=self.wrenches,
                           namespace=self.namespace, record_tf=self.tf, batch=HEADLESS_BATCH)
        n_pub = n_cmd = n_rej = 0
        t_start = sim.t
        try:
            sink.on_start(sim)
            for topic, type_name, t_ns, raw in read_raw_messages(self.path, topics=wanted):
                rel = self.topics[topic]
                t = self.time_of(t_ns, t_start)
                if rel == 'joint_states':
                    if t < sim.t - 1e-12:   # time went back: the run was reset
                        sim.reset()
                        t_start = sim.t
                        t = self.time_of(t_ns, t_start)
                    sim.advance(t)
                    sink.on_output(sim.t, sim.outputs(wrenches=self.wrenches), sim)
                    n_pub += 1
                else:
                    port = ports[rel]
                    if t > sim.t:
                        sim.advance(t)
                    try:
                        sim.set_command(port, command_values(port, decode(type_name, raw)))
                    except CommandError:
                        n_rej += 1
                        continue
                    sink.on_command(sim.t, port, sim.ports[port].value)
                    n_cmd += 1
        finally:
            sink.close()
        return {'publications': n_pub, 'commands': n_cmd, 'rejected': n_rej, 'sim': sim}


def compare(original, resimulated, namespace='') -> dict:
    """Per state topic: message counts, byte-identical count and largest deviation."""
    from ..recording import read_raw_messages
    a, b, types = {}, {}, {}
    for store, path in ((a, original), (b, resimulated)):
        for topic, type_name, t_ns, raw in read_raw_messages(path):
            if _is_state(_relative(topic, namespace)):
                store.setdefault(topic, []).append((t_ns, raw))
                types[topic] = type_name
    report = {}
    for topic in sorted(set(a) | set(b)):
        ma, mb = a.get(topic, []), b.get(topic, [])
        n = min(len(ma), len(mb))
        identical = sum(ma[i] == mb[i] for i in range(n))
        dev = 0.0
        for i in range(n):
            if ma[i] != mb[i]:
                dev = max(dev, math.inf if ma[i][0] != mb[i][0] else _deviation(types[topic], ma[i][1], mb[i][1]))
        if len(ma) != len(mb):
            dev = math.inf
        report[topic] = {'original': len(ma), 'resimulated': len(mb), 'identical': identical,
                         'max_deviation': dev}
    return report


def main(args) -> int:
    """Re-simulate, print the deviation table; 1 if any deviation exceeds --tolerance, 2 if unusable."""
    from ..scene import SceneError
    from ..recording.target import RecordPathError, check_record_path
    from ..simulation import SimulationError
    try:
        rs = Resim(args.input)
        check_record_path(args.record, overwrite=args.overwrite, source=args.input)
    except (OSError, ValueError, KeyError, SceneError, RecordPathError) as e:
        print(f'robodyn resim: {e}', file=sys.stderr)
        return 2
    status = 0
    try:
        counts = rs.run(args.record)
    except SimulationError as e:
        print(f'robodyn resim: simulation stopped: {e}', file=sys.stderr)
        counts, status = None, 1
    report = compare(args.input, args.record, rs.namespace)
    worst = max((r['max_deviation'] for r in report.values()), default=0.0)
    if not report:
        print('robodyn resim: the recording has no state messages to compare', file=sys.stderr)
        status = 2
    elif worst > args.tolerance:
        status = max(status, 1)
    if args.json:
        print(json.dumps({'input': args.input, 'output': args.record, 'max_deviation': worst,
                          'tolerance': args.tolerance, 'topics': report,
                          **({k: v for k, v in counts.items() if k != 'sim'} if counts else {})},
                         default=str, indent=1))
        return status
    st = rs.settings
    print(f'resim        {args.input} -> {args.record}')
    print(f'scene        {rs.scene.name}; {st["integrator"]} '
          + (f'dt={st["dt"]:g} s' if st.get('dt') else '') + (' ' if st.get('dt') and st.get('rtol') else '')
          + (f'rtol={st.get("rtol")} atol={st.get("atol")}' if st.get('rtol') else '')
          + f', {rs.rate:g} Hz, recorded in mode {st.get("mode", "?")} by robodyn_ros '
            f'{rs.metadata.get("package_version", "?")}')
    if counts:
        print(f'replayed     {counts["publications"]} publications, {counts["commands"]} commands'
              + (f', {counts["rejected"]} commands rejected' if counts['rejected'] else ''))
    print(f'{"topic":40s} {"messages":>9s} {"identical":>9s}  max deviation')
    for topic, r in report.items():
        n = r['original'] if r['original'] == r['resimulated'] else f'{r["original"]}/{r["resimulated"]}'
        print(f'{topic:40s} {n!s:>9s} {r["identical"]:9d}  {r["max_deviation"]:.3g}')
    verdict = 'OK' if status == 0 else 'FAILED'
    print(f'{verdict:12s} largest deviation {worst:.3g} (tolerance {args.tolerance:g})')
    return status
