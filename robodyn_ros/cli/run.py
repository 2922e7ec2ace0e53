"""``robodyn run``: a headless run of a scene with its scripted commands, recorded to MCAP."""
from __future__ import annotations

import sys
import time

from ..integrator_choice import DEFAULT_DT, STEP_BUDGET
from ..runs import DEFAULT_RATE, DIAGNOSTICS_PERIOD, plan_run, resolve_settings, summary

#: one line for ``robodyn --help``
HELP = 'simulate a scene headless with its scripted commands'


def add_parser(sub):
    """Register the subcommand and its options."""
    p = sub.add_parser('run', help=HELP)
    p.add_argument('scene', help='bundled scene name, path to a scene YAML file, or a URDF file (robot.urdf: '
                                 'the robot on a fixed base, no commands)')
    p.add_argument('--duration', type=float, default=None, help='simulated seconds (default: the scene\'s)')
    p.add_argument('--record', default=None, help='MCAP file to write (default: none); an existing file is refused')
    p.add_argument('--overwrite', action='store_true', help='replace the --record file if it exists')
    p.add_argument('--integrator', default=None,
                   help='auto (default unless the scene names one: rk4, else rosenbrock2 for stiff passive forces, '
                        'else radau), euler, semi_implicit_euler, rk4, rosenbrock2, rk45, dop853, radau, ...')
    p.add_argument('--dt', type=float, default=None,
                   help=f'fixed step (s) for fixed-step integrators (default: the scene\'s, else {DEFAULT_DT:g})')
    p.add_argument('--rtol', type=float, default=None, help='relative tolerance (adaptive integrators)')
    p.add_argument('--atol', type=float, default=None, help='absolute tolerance (adaptive integrators)')
    p.add_argument('--rate', type=float, default=None,
                   help=f'publication/recording rate in Hz (default: the scene\'s, else {DEFAULT_RATE:g})')
    p.add_argument('--step-budget', type=float, default=None, metavar='N',
                   help='error-controlled integrators: stop (exit 1, naming the stiff mode) past N accepted steps '
                        f'per simulated second (default: the scene\'s simulation.step_budget, else {STEP_BUDGET:g}; '
                        'inf: none)')
    p.add_argument('--no-wrenches', action='store_true', help='do not compute or record constraint wrenches')
    p.add_argument('--no-tf', action='store_true', help='do not record /tf and /tf_static')
    p.add_argument('--backend', choices=('numpy', 'numba', 'generated'), default=None,
                   help='dynamics kernels (default: $ROBODYN_BACKEND, else numba: generic, compiled once per '
                        'install; generated: specialised per model, compiled once per model and cached)')
    p.add_argument('--position-limits', default=None, metavar='K,C[,RETURN]',
                   help='URDF file only: enforce its <limit lower upper> with joint-limit moments of stiffness K '
                        '(N·m/rad or N/m) and damping C (N·m·s/rad or N·s/m), return spring (default) or none '
                        '(Huston eq. 20.2.1; a scene file gives position_limits on its kind: urdf part)')
    p.add_argument('--command-interface', choices=('effort', 'position', 'velocity'), default=None,
                   help='URDF file only: every actuated joint takes this command (position: held setpoints and '
                        'joint_trajectory, tracked by a joint servo; a scene file gives command_interfaces on '
                        'its part)')
    p.add_argument('--diagnostics-period', type=float, default=DIAGNOSTICS_PERIOD,
                   help=f'simulated seconds between recorded diagnostics messages (default {DIAGNOSTICS_PERIOD:g})')
    return p


def main(args) -> int:
    """Run, record, print a summary; exit 1 with the cause if the simulation fails.

    Imports what the run uses when it uses it (the recorder only with ``--record``), so a short
    run starts fast (``robodyn bench startup``)."""
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
            scene = load_scene(args.scene, position_limits=limits, command_interface=args.command_interface)
    except SceneError as e:
        print(f'robodyn run: {e}', file=sys.stderr)
        return 2
    st = resolve_settings(scene, args.integrator, args.dt, args.rtol, args.atol, args.rate, args.duration,
                          args.step_budget)
    st['backend'] = backend  # recorded: robodyn resim rebuilds the system on the same kernels
    try:
        plan, st = plan_run(st, scene.system, scene.y0)   # which integrator, which step, and why: decided once
        sim = Simulator(scene.system, scene.y0, plan=plan)
    except ValueError as e:
        print(f'robodyn run: {e}', file=sys.stderr)
        return 2
    sinks = []
    if args.record:
        from ..recording.run_sink import HEADLESS_BATCH, McapRunSink
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
