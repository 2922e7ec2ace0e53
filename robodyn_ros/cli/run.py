"""``robodyn run``: a headless run of a scene with its scripted commands, recorded to MCAP."""
from __future__ import annotations

import math
import os
import sys
import time

from ..integrator_choice import DEFAULT_DT, STEP_BUDGET
from ..runs import DEFAULT_RATE, DIAGNOSTICS_PERIOD, StopSignals, plan_run, resolve_settings, summary

#: one line for ``robodyn --help``
HELP = 'simulate a scene headless with its scripted commands'


def _number(lowest: float, strict: bool, unit: str):
    """An argparse type: a finite number above ``lowest`` (at least it when not strict), else argparse's
    one-line usage error naming the option."""
    import argparse
    import math

    def parse(text: str) -> float:
        try:
            x = float(text)
        except ValueError:
            x = math.nan
        if not math.isfinite(x) or x < lowest or (strict and x == lowest):
            raise argparse.ArgumentTypeError(f'expected a finite number{" of " + unit if unit else ""} '
                                             f'{">" if strict else ">="} {lowest:g}, got {text!r}')
        return x
    return parse


def add_parser(sub):
    """Register the subcommand and its options."""
    p = sub.add_parser('run', help=HELP)
    p.add_argument('scene', help='bundled scene name, path to a scene YAML file, or a URDF file (robot.urdf: '
                                 'the robot on a fixed base, no commands)')
    p.add_argument('--duration', type=_number(0.0, False, 'seconds'), default=None, help='simulated seconds (default: the scene\'s)')
    p.add_argument('--record', default=None, help='MCAP file to write (default: none); an existing file is refused')
    p.add_argument('--overwrite', action='store_true', help='replace the --record file if it exists')
    p.add_argument('--integrator', default=None,
                   help='auto (default unless the scene names one: rk4, else rosenbrock2 for stiff passive forces, '
                        'else radau), euler, semi_implicit_euler, rk4, rosenbrock2, rk45, dop853, radau, ...')
    p.add_argument('--dt', type=_number(0.0, True, 'seconds'), default=None,
                   help=f'fixed step (s) for fixed-step integrators (default: the scene\'s, else {DEFAULT_DT:g})')
    p.add_argument('--rtol', type=_number(0.0, True, ''), default=None,
                   help='relative tolerance (error-controlled integrators; with rosenbrock2: error control, --dt '
                        'its largest step)')
    p.add_argument('--atol', type=_number(0.0, True, ''), default=None,
                   help='absolute tolerance (error-controlled integrators; rosenbrock2: m, rad, m/s, rad/s, default '
                        'rtol)')
    p.add_argument('--rate', type=_number(0.0, True, 'Hz'), default=None,
                   help=f'publication/recording rate in Hz (default: the scene\'s, else {DEFAULT_RATE:g})')
    p.add_argument('--step-budget', type=float, default=None, metavar='N',
                   help='error-controlled integrators: stop (exit 1, naming the stiff mode) past N accepted steps '
                        f'per simulated second (default: the scene\'s simulation.step_budget, else {STEP_BUDGET:g}; '
                        'inf: none)')
    p.add_argument('--no-wrenches', action='store_true', help='do not compute or record constraint wrenches')
    p.add_argument('--no-tf', action='store_true', help='do not record /tf and /tf_static')
    p.add_argument('--no-embed-meshes', action='store_true',
                   help='record robot_description with its package:// mesh references (by default it carries the '
                        'meshes as data: URIs, so that Foxglove draws them without ROS: 9 MB for the A1)')
    p.add_argument('--backend', choices=('numpy', 'numba', 'generated', 'auto'), default=None,
                   help='dynamics kernels (default: $ROBODYN_BACKEND, else auto: the generic compiled kernels, '
                        'then the model\'s own code once a background process has compiled it, the same bytes; '
                        'numba: generic only; generated: the model\'s own from the first step)')
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
    live = p.add_argument_group('live', 'watch and steer the run in Foxglove (a Foxglove WebSocket server)')
    live.add_argument('--live', action='store_true',
                      help='serve the run on a Foxglove WebSocket, paced to real time x --rate-factor; clients may '
                           'publish commands, call reset and pause, set rate_factor; Ctrl-C stops (the recording '
                           'is kept)')
    live.add_argument('--port', type=int, default=None, help='--live: TCP port (default 8765; 0: any free one)')
    live.add_argument('--host', default=None, help='--live: address to serve on (default 127.0.0.1: this machine only)')
    live.add_argument('--rate-factor', type=float, default=None,
                      help='--live: simulated seconds per wall second (default 1; 0: as fast as possible)')
    live.add_argument('--start-paused', action='store_true',
                      help='--live: wait at t = 0 until a client calls pause with data: false')
    return p


#: --live defaults
LIVE_PORT, LIVE_HOST = 8765, '127.0.0.1'


def main(args) -> int:
    """Run, record, print a summary; exit 1 with the cause if the simulation fails.

    Imports what the run uses when it uses it (the recorder only with ``--record``, the live server
    only with ``--live``), so a short run starts fast (``robodyn bench startup``). On a cold kernel
    cache the kernels run as Python while a child process compiles them (``kernels.jit``, mode 'interpret'),
    the same bytes."""
    if 'robodyn_ros.kernels' not in sys.modules:   # numba loads when the run needs it (kernels.jit.DEFERRED)
        os.environ['_ROBODYN_DEFER_NUMBA'] = '1'
        try:
            from ..kernels import jit
        finally:
            del os.environ['_ROBODYN_DEFER_NUMBA']
    from ..kernels import jit
    mode = jit.MODE
    jit.set_mode('interpret')
    try:
        return _main(args)
    finally:
        jit.MODE = mode   # (an in-process caller keeps its own mode)


def _main(args) -> int:
    """:func:`main` in the cold-start mode it has set."""
    live_opts = [o for o, v in (('--port', args.port), ('--host', args.host), ('--rate-factor', args.rate_factor),
                                ('--start-paused', args.start_paused or None)) if v is not None]
    if live_opts and not args.live:
        print(f'robodyn run: {", ".join(live_opts)} only with --live', file=sys.stderr)
        return 2
    sock = None
    if args.live:   # first: a port in use is refused before anything runs
        from ..live.run import check_rate_factor
        from ..live.server import LivePortError, bind
        try:
            rate_factor = check_rate_factor(1.0 if args.rate_factor is None else args.rate_factor)
        except ValueError as e:
            print(f'robodyn run: --rate-factor: {e}', file=sys.stderr)
            return 2
        try:
            sock = bind(args.host or LIVE_HOST, LIVE_PORT if args.port is None else args.port)
        except LivePortError as e:
            print(f'robodyn run: --live: {e}; choose another with --port', file=sys.stderr)
            return 2
    try:
        return _run(args, sock, rate_factor if args.live else None)
    finally:
        if sock is not None:
            sock.close()


def _run(args, sock, rate_factor) -> int:
    """The run once the live port (if any) is bound."""
    from ..scene import SceneError, load_scene
    from ..simulation import SimulationError, Simulator, run_headless
    from ..systems.base import backend_scope, recorded_backend, tools_backend
    if args.record:
        from ..recording.target import RecordPathError, check_record_path
        try:  # before anything is simulated: never overwrite silently, never fail at the end
            also = ()
            if args.live:   # a client's reset continues the recording in <stem>-1.mcap, ...
                from ..recording.target import episode_files
                also = episode_files(args.record)
            check_record_path(args.record, overwrite=args.overwrite, also=also)
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
    try:
        st = resolve_settings(scene, args.integrator, args.dt, args.rtol, args.atol, args.rate, args.duration,
                              args.step_budget)
    except ValueError as e:
        print(f'robodyn run: {e}', file=sys.stderr)
        return 2
    st['backend'] = recorded_backend(backend)  # recorded: robodyn resim rebuilds the system on the same kernels
    try:
        expect_work(scene, st, args.live)
        plan, st = plan_run(st, scene.system, scene.y0)   # which integrator, which step, and why: decided once
        sim = Simulator(scene.system, scene.y0, plan=plan)
    except ValueError as e:
        print(f'robodyn run: {e}', file=sys.stderr)
        return 2
    if args.live:
        return _run_live(args, sock, rate_factor, scene, st, sim)
    sinks = []
    if args.record:
        from ..recording.run_sink import HEADLESS_BATCH, McapRunSink
        sinks.append(McapRunSink(args.record, scene, {**st, 'mode': 'headless'},
                                 record_wrenches=not args.no_wrenches, record_tf=not args.no_tf,
                                 diagnostics_period=args.diagnostics_period, batch=HEADLESS_BATCH,
                                 embed_meshes=not args.no_embed_meshes))
    w0, c0 = time.perf_counter(), time.process_time()
    status, at_once = 0, False
    with StopSignals() as stop:   # Ctrl-C, SIGTERM: the run ends at the next period boundary, the file finished
        try:
            run_headless(sim, st['duration'], st['rate'], scene.script, sinks, stop=scene.stop, halt=stop.asked)
        except SimulationError as e:
            print(f'robodyn run: simulation stopped: {e}', file=sys.stderr)
            status = 1
        except KeyboardInterrupt:   # a second signal: at once; the recording is finished with what it was handed
            at_once = True
        finally:
            for s in sinks:
                s.close()
    if stop.requested is not None and status == 0:
        status = StopSignals.STATUS[stop.requested]
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    print(summary(scene, sim, st, wall, args.record, sinks, cpu=cpu))
    if stop.requested is not None:
        if at_once:
            print(f'stopped      at once by a second {stop.requested} near t={sim.t:.6g} s of {st["duration"]:g} s'
                  + (' (the recording holds the periods it had been handed)' if args.record else ''))
        else:
            print(f'stopped      by {stop.requested} at t={sim.t:.6g} s of {st["duration"]:g} s'
                  + (' (the recording holds every period up to it)' if args.record else ''))
    from ..kernels import jit
    if jit.DEFERRED and not jit.LOADED and st['backend'] != 'numpy':
        print('kernels      run as Python, numba not loaded (a run this short ends before numba would have '
              'loaded; the same bytes)')
    return status


#: interpreted cost (s) per state of one right-hand-side evaluation called from Python (the integrator plan's
#: linearisation, 2 ny + 1 of them) and inside the fused loop, of a publication period beyond its steps, and the
#: evaluations per step by method (for :func:`expect_work`; measured: stanford_arm 12 states 1.2 ms / 150 µs,
#: a1_stand 37 states 3.5 ms, huston_human17 125 states 6.9 ms)
PY_RHS_PER_STATE = 100e-6
PY_LOOP_EVAL_PER_STATE = 15e-6
PY_PERIOD = 5e-4
EVALS_PER_STEP = {'euler': 1, 'semi_implicit_euler': 1, 'rk4': 4, 'rosenbrock2': 4}


def expect_work(scene, st, live) -> None:
    """Tell the kernels (:func:`robodyn_ros.kernels.jit.expect`) how long this run would spend in them
    interpreted, so a run that would outlast the deferral loads numba before it starts: a live run always,
    else the plan's linearisation plus steps × evaluations per step (an error-controlled or automatic method
    counted at 1 ms steps, 4 evaluations each) plus the publication periods."""
    from ..kernels import jit, start_compiler_if_cold
    if not jit.DEFERRED or jit.LOADED:
        return
    if live:
        jit.expect(math.inf, before=start_compiler_if_cold)
        return
    ny = scene.system.ny
    dt = st.get('dt') or DEFAULT_DT
    evals = EVALS_PER_STEP.get(st.get('integrator'), 4)
    duration = float(st['duration'])
    jit.expect((2 * ny + 1) * ny * PY_RHS_PER_STATE + duration / dt * evals * ny * PY_LOOP_EVAL_PER_STATE
               + duration * float(st['rate']) * PY_PERIOD, before=start_compiler_if_cold)


def _run_live(args, sock, rate_factor, scene, st, sim) -> int:
    """``--live``: serve, pace, steer (:mod:`robodyn_ros.live.run`); episodes after a client's reset."""
    from ..live.run import LiveReset, LiveRun, LiveStop
    from ..live.server import LiveServer, LiveTap
    from ..live.steering import RATE_FACTOR, SERVICES, Steering, trigger_response
    from ..nodes.ports import command_topics, command_values
    from ..recording.run_sink import HEADLESS_BATCH, McapRunSink, resolve
    from ..recording.target import episode_path
    from ..simulation import SimulationError, run_headless
    try:
        commands = {resolve(topic): (port, t) for port, (topic, t) in command_topics(scene.system).items()}
    except ValueError as e:
        print(f'robodyn run: --live: {e}', file=sys.stderr)
        return 2
    steering = Steering(commands, command_values)
    server = LiveServer(sock, f'robodyn_ros: {scene.name}', steering, services=SERVICES,
                        parameters={RATE_FACTOR: rate_factor}).start()
    steering.advertise(server)
    live = LiveRun(server, steering, command_values, rate_factor=rate_factor, paused=args.start_paused)
    print(f'live         {server.url}  (Foxglove: Open connection > Foxglove WebSocket)'
          + ('; paused: call pause with data false to start' if args.start_paused else ''), flush=True)
    layout_path = _live_layout(scene)
    if layout_path:
        print(f'layout       {layout_path}  (Foxglove: Layouts > Import from file)', flush=True)
    tap = LiveTap(server)
    recorders = []

    def recorder(episode):
        path = episode_path(args.record, episode) if args.record else None
        r = McapRunSink(path, scene, {**st, 'mode': 'headless'}, record_wrenches=not args.no_wrenches,
                        record_tf=not args.no_tf, diagnostics_period=args.diagnostics_period, batch=HEADLESS_BATCH,
                        taps=(tap,), embed_meshes=not args.no_embed_meshes)
        recorders.append(r)
        return r

    signals = StopSignals(on_request=steering.request_stop).__enter__()   # Ctrl-C, SIGTERM: at the next period
    w0, c0 = time.perf_counter(), time.process_time()
    status, episode, stopped = 0, 0, False
    try:
        while True:
            live.recorder = rec = recorder(episode)
            try:
                run_headless(sim, st['duration'], st['rate'], live.script(scene.script), [rec, live], stop=scene.stop)
                break
            except LiveReset as r:
                rec.close()
                sim.reset()
                live.owned.clear()
                episode += 1
                live.recorder = None
                r.reply(trigger_response(True, f'reset to the initial state at t={sim.t:g} s'
                                         + (f'; recording continues in {episode_path(args.record, episode)}'
                                            if args.record else '')))
            finally:
                rec.close()
    except (LiveStop, KeyboardInterrupt):   # (KeyboardInterrupt: a second signal, at once)
        stopped = True
    except SimulationError as e:
        print(f'robodyn run: simulation stopped: {e}', file=sys.stderr)
        status = 1
    finally:
        wall, cpu = time.perf_counter() - w0 - live.paused_wall, time.process_time() - c0
        signals.__exit__()
        for r in recorders:
            r.close()
        server.close()
    record = episode_path(args.record, episode) if args.record else None
    print(summary(scene, sim, st, wall, record, recorders, cpu=cpu))
    print(f'live         {server.clients_seen} client{"s" if server.clients_seen != 1 else ""} served'
          + (f'; stopped by {signals.requested} at t={sim.t:.3f} s' if stopped else '')
          + (f'; {live.refused} client commands refused' if live.refused else '')
          + (f'; {server.dropped} messages dropped for slow clients' if server.dropped else ''))
    return status


def _live_layout(scene) -> str | None:
    """Write the scene's live layout (:mod:`robodyn_ros.layout`) to the temporary directory; its path
    (the same for the same scene, replaced atomically), or None when it cannot be written."""
    import tempfile

    from ..layout import layout_text, scene_info
    d = os.path.join(tempfile.gettempdir(), 'robodyn_layouts')
    path = os.path.join(d, f'{scene.name}.live.json')
    try:
        os.makedirs(d, exist_ok=True)
        tmp = f'{path}.{os.getpid()}'
        with open(tmp, 'w') as f:
            f.write(layout_text(scene_info(scene), live=True))
        os.replace(tmp, path)
    except OSError:
        return None
    return path
