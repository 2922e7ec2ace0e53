"""``robodyn run``: a headless run of a scene with its scripted commands, recorded to MCAP."""
from __future__ import annotations

import math
import os
import sys
import time


#: simulated seconds between diagnostics messages in a recording (robodyn run, robodyn sweep)
DIAGNOSTICS_PERIOD = 0.1

def add_parser(sub):
    """Register the subcommand and its options."""
    p = sub.add_parser('run', help='simulate a scene headless with its scripted commands')
    p.add_argument('scene', help='bundled scene name, path to a scene YAML file, or a URDF file (robot.urdf: '
                                 'the robot on a fixed base, no commands)')
    p.add_argument('--duration', type=float, default=None, help='simulated seconds (default: the scene\'s)')
    p.add_argument('--record', default=None, help='MCAP file to write (default: none); an existing file is refused')
    p.add_argument('--overwrite', action='store_true', help='replace the --record file if it exists')
    p.add_argument('--integrator', default=None, help='euler, semi_implicit_euler, rk4, rk45, dop853, radau, ...')
    p.add_argument('--dt', type=float, default=None, help='fixed step (s) for fixed-step integrators')
    p.add_argument('--rtol', type=float, default=None, help='relative tolerance (adaptive integrators)')
    p.add_argument('--atol', type=float, default=None, help='absolute tolerance (adaptive integrators)')
    p.add_argument('--rate', type=float, default=None, help='publication/recording rate in Hz (default 100)')
    p.add_argument('--no-wrenches', action='store_true', help='do not compute or record constraint wrenches')
    p.add_argument('--no-tf', action='store_true', help='do not record /tf and /tf_static')
    p.add_argument('--backend', choices=('numpy', 'numba', 'generated'), default=None,
                   help='dynamics kernels (default: $ROBODYN_BACKEND, else generated: specialised per scene, '
                        'compiled once and cached)')
    p.add_argument('--position-limits', default=None, metavar='K,C[,RETURN]',
                   help='URDF file only: enforce its <limit lower upper> with joint-limit moments of stiffness K '
                        '(N·m/rad or N/m) and damping C (N·m·s/rad or N·s/m), return spring (default) or none '
                        '(Huston eq. 20.2.1; a scene file gives position_limits on its kind: urdf part)')
    p.add_argument('--diagnostics-period', type=float, default=DIAGNOSTICS_PERIOD,
                   help='simulated seconds between recorded diagnostics messages (default 0.1)')
    return p


def resolve_settings(scene, args) -> dict:
    """Integrator settings: command-line values over the scene's ``simulation`` defaults."""
    s = dict(scene.settings)
    out = {'integrator': args.integrator or s.get('integrator', 'rk4'),
           'dt': args.dt if args.dt is not None else s.get('dt', 1e-3),
           'rtol': args.rtol if args.rtol is not None else s.get('rtol'),
           'atol': args.atol if args.atol is not None else s.get('atol'),
           'rate': args.rate if args.rate is not None else s.get('publish_rate', 100.0),
           'duration': args.duration if args.duration is not None else s.get('duration', 10.0)}
    from ..integrators import INTEGRATORS
    spec = INTEGRATORS.get(out['integrator'])
    if spec is not None and spec.kind == 'adaptive':
        out['rtol'] = out['rtol'] if out['rtol'] is not None else 1e-8
        out['atol'] = out['atol'] if out['atol'] is not None else 1e-10
    return out


def main(args) -> int:
    """Run, record, print a summary; exit 1 with the cause if the simulation fails."""
    from ..recording.run_sink import HEADLESS_BATCH, McapRunSink
    from ..scene import SceneError, load_scene
    from ..simulation import SimulationError, Simulator, run_headless
    from ..systems.base import backend_scope, tools_backend
    if args.record:
        from ..recording.target import RecordPathError, check_record_path
        try:  # before anything is simulated: never overwrite silently, never fail at the end
            check_record_path(args.record, overwrite=args.overwrite)
        except RecordPathError as e:
            print(f'robodyn run: {e}', file=sys.stderr)
            return 2
    backend = tools_backend(getattr(args, 'backend', None))
    limits = None
    if args.position_limits is not None:
        f = args.position_limits.split(',')
        try:
            if len(f) not in (2, 3):
                raise ValueError
            limits = {'stiffness': float(f[0]), 'damping': float(f[1])}
            if len(f) == 3:
                limits['return'] = f[2].strip()
        except ValueError:
            print(f'robodyn run: --position-limits: expected K,C or K,C,RETURN (numbers, then spring or none), '
                  f'got {args.position_limits!r}', file=sys.stderr)
            return 2
    try:
        with backend_scope(backend):
            scene = load_scene(args.scene, position_limits=limits)
    except SceneError as e:
        print(f'robodyn run: {e}', file=sys.stderr)
        return 2
    st = resolve_settings(scene, args)
    st['backend'] = backend  # recorded: robodyn resim rebuilds the system on the same kernels
    try:
        sim = Simulator(scene.system, scene.y0, integrator=st['integrator'], dt=st['dt'], rtol=st['rtol'],
                        atol=st['atol'])
    except ValueError as e:
        print(f'robodyn run: {e}', file=sys.stderr)
        return 2
    sinks = []
    if args.record:
        sinks.append(McapRunSink(args.record, scene, {**st, 'mode': 'headless'},
                                 record_wrenches=not args.no_wrenches, record_tf=not args.no_tf,
                                 diagnostics_period=args.diagnostics_period, batch=HEADLESS_BATCH))
    w0, c0 = time.perf_counter(), time.process_time()
    status = 0
    try:
        run_headless(sim, st['duration'], st['rate'], scene.script, sinks, stop=scene.stop)
    except SimulationError as e:
        print(f'robodyn run: simulation stopped: {e}', file=sys.stderr)
        status = 1
    finally:
        for s in sinks:
            s.close()
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    print(summary(scene, sim, st, wall, args.record, sinks, cpu=cpu))
    return status


def summary(scene, sim, st, wall, record, sinks, cpu=None) -> str:
    """Human-readable summary of a finished run (cpu: process CPU seconds of the run, if known)."""
    e = sim.energy_report()
    d = sim.diag
    method = st['integrator'] + (f' dt={st["dt"]:g} s' if st.get('dt') and not st.get('rtol')
                                 else f' rtol={st["rtol"]:g} atol={st["atol"]:g}')
    lines = [
        f'scene        {scene.name} ({scene.system.__class__.__name__}, {scene.system.ny} states)',
        f'integrator   {method}; {d.steps} steps, {d.rhs_evals} rhs evaluations, {d.rejected_steps} rejected',
        f'time         simulated {sim.t:.3f} s in {wall:.3f} s wall '
        f'(real-time factor {sim.t / wall if wall > 0 else math.inf:.1f}, {d.wall:.3f} s integrating'
        + (f', {cpu:.3f} s CPU' if cpu is not None else '') + ')',
        f'energy       E0 {e["energy0"]:.6g} J, E {e["energy"]:.6g} J, work in {e["work"]:.6g} J, '
        f'drift {e["drift"]:.3g} J ({e["relative_drift"]:.2e} relative)',
    ]
    if 'limit_work' in e:   # joint-limit moments (Huston eq. 20.2.1): their part of the work
        lines[-1] += f'; joint-limit work {e["limit_work"]:.6g} J'
    if d.velocity_limit_exceeded:   # URDF <limit velocity>: reported, not enforced
        lines.append(f'limits       {d.velocity_limit_exceeded} published joint velocities above the velocity limits')
    clamped = {k: p.clamped for k, p in sim.ports.items() if p.clamped}
    if clamped:  # actuator effort limits (URDF <limit effort>, effort_limit)
        lines.append('limits       ' + ', '.join(f'{n} {k} command components clamped to the effort limits'
                                                 for k, n in clamped.items()))
    if record:
        n = sum(getattr(s, 'count', 0) for s in sinks)
        lines.append(f'recording    {os.path.abspath(record)} ({n} messages; check with: robodyn check {record})')
    report = getattr(scene.system, 'run_report', None)  # e.g. a planar base: rotations at the end
    if report is not None:
        lines.append(report(sim.y))
    if sim.failed:
        lines.append(f'FAILED       {sim.failed}')
    return '\n'.join(lines)
