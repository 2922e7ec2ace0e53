"""``robodyn bench control``: what position and trajectory commands cost (figures, never asserted).

* ``cost``: the compiled loop's cost per step on xArm7 (rosenbrock2, what integrator auto picks for it)
  and Panda (rk4 and rosenbrock2), 10 s at 1 ms: effort commands (zero), every joint position-commanded
  tracking a trajectory without and with the feed-forward; each against the effort run (target: at
  most 1.2x).
* ``mujoco``: the bundled ``xarm7_trajectory`` scene run and recorded as ``robodyn run --record`` runs
  it (10 s at 1 ms, 100 Hz publications with the servo's desired and error states and the sensors):
  real-time factor and largest tracking error, beside MuJoCo stepping the same URDF (meshes left out)
  with position actuators of the same gains (``kp``, ``kv``: the servo's), implicitfast at 1 ms, one
  ``mj_step`` per Python call, the same trajectory's desired positions set as ``ctrl`` before every step
  (MuJoCo's position actuator has no feed-forward: its tracking error is shown for what it is).
"""
from __future__ import annotations

import math
import os
import re
import tempfile
import time

import numpy as np

HELP = 'position, velocity and trajectory commands: servo cost against effort; xarm7 beside MuJoCo actuators'
SECTIONS = ('cost', 'mujoco')
#: simulated seconds and step of both sections
HORIZON, DT, RATE = 10.0, 1e-3, 100.0
SCENE = 'xarm7_trajectory'


def add_arguments(p):
    """Options of ``robodyn bench control``."""
    p.add_argument('--skip', nargs='*', default=[], choices=SECTIONS, help='sections to leave out')
    p.add_argument('--repeat', type=int, default=3, help='runs per figure (the best is kept)')


def main(args) -> int:
    """Print the sections."""
    print(report(args))
    return 0


def report(args) -> str:
    """The sections' text."""
    parts = []
    if 'cost' not in args.skip:
        parts.append(section_cost(args.repeat))
    if 'mujoco' not in args.skip:
        parts.append(section_mujoco(args.repeat))
    return '\n\n'.join(parts)


PANDA = 'package://example-robot-data/robots/panda_description/urdf/panda.urdf'
#: Panda's trajectory of the cost section: two quintic segments through these positions (rad), at rest at each
PANDA_POINTS = ((2.0, (0.5, -0.4, 0.3, -2.0, 0.4, 1.8, 0.6)), (4.0, (-0.3, 0.2, -0.2, -1.5, -0.3, 1.2, -0.4)))


def _robot(name: str, interfaces: str):
    """A robot of the ``cost`` section on the given command interfaces, with a trajectory when they are
    position: xarm7 (the bundled scene's part and trajectory) or Panda (fingers locked, :data:`PANDA_POINTS`)."""
    from ..scene import find_scene, parse_scene
    if name == 'xarm7':
        path = find_scene(SCENE)
        text = path.read_text().replace('command_interfaces: position', f'command_interfaces: {interfaces}')
        if interfaces != 'position':
            text = re.sub(r'\ncommands:.*?(?=\nsensors:)', '', text, flags=re.DOTALL)
        return parse_scene(text, file=str(path))
    text = (f'name: panda\nparts:\n  - kind: urdf\n    name: panda\n    file: {PANDA}\n'
            '    locked: {panda_finger_joint1: 0.0, panda_finger_joint2: 0.0}\n'
            f'    command_interfaces: {interfaces}\n')
    if interfaces == 'position':
        pts = ', '.join(f'{{time_from_start: {t}, positions: {list(p)}, velocities: {[0.0] * 7}, '
                        f'accelerations: {[0.0] * 7}}}' for t, p in PANDA_POINTS)
        text += f'commands:\n  trajectory: {{profile: trajectory, points: [{pts}]}}\n'
    return parse_scene(text, file='panda.yaml')


def cost_figures(repeat=3) -> list:
    """``[(robot, method, {commands: µs per step})]``: the compiled loop's cost per step (``integrate_arm``
    over 10-step periods from the initial state, HORIZON s in all), interleaved runs, the best of
    ``10 repeat``: effort commands (zero: the arm falls), and position commands tracking a trajectory without
    and with the feed-forward (both moving: an arm held exactly still makes its velocities decay into
    subnormal numbers, whose arithmetic is many times slower on x86)."""
    from ..simulation import Simulator
    out = []
    for robot, methods in (('xarm7', ('rosenbrock2',)), ('panda', ('rk4', 'rosenbrock2'))):
        for method in methods:
            runs = {}
            for label, ci, ff in (('effort', 'effort', None), ('position, no feed-forward', 'position', 0.0),
                                  ('position + feed-forward', 'position', 1.0)):
                sc = _robot(robot, ci)
                sim = Simulator(sc.system, sc.y0, integrator=method, dt=DT)
                if sc.script is not None:
                    for port, value in sc.script(0.0, sc.y0).items():
                        sim.set_command(port, value)
                srv = sc.system._srv(sim.held_inputs()) if sc.system.servo is not None else None
                runs[label] = (sc.system, ff, srv, np.concatenate([sim.y, [0.0]]))
            best = {k: math.inf for k in runs}
            n = int(round(HORIZON * RATE))
            per = int(round(1.0 / (RATE * DT)))
            for _ in range(10 * max(1, repeat)):
                for label, (system, ff, srv, z0) in runs.items():
                    if ff is not None:
                        system.servo.opt[0] = ff
                    z = z0.copy()
                    tau = np.zeros(system.nv)
                    w0 = time.perf_counter()
                    for k in range(n):
                        system._km.integrate_arm(method, z, tau, DT, per, 0.0, k / RATE, srv)
                    best[label] = min(best[label], (time.perf_counter() - w0) / (n * per) * 1e6)
            out.append((robot, method, best))
    return out


def section_cost(repeat=3) -> str:
    """The ``cost`` section."""
    lines = [f'## servo cost per step: the compiled loop alone ({HORIZON:g} s at {DT * 1e3:g} ms; position: '
             'tracking a trajectory)', '',
             '| robot | method | effort (µs/step) | position, no feed-forward | position + feed-forward |',
             '|---|---|---|---|---|']
    for robot, method, best in cost_figures(repeat):
        e = best['effort']
        lines.append(f'| {robot} | {method} | {e:.2f} | '
                     + ' | '.join(f'{best[k]:.2f} ({best[k] / e:.2f}x)'
                                  for k in ('position, no feed-forward', 'position + feed-forward')) + ' |')
    lines.append('')
    lines.append('Target: at most 1.2x the effort run. The feed-forward costs one RNEA per rosenbrock2 step and two '
                 'per rk4 step (cached across stages at the same time when every joint is a servo joint).')
    return '\n'.join(lines)


def robodyn_recorded(repeat=3) -> tuple:
    """``(best wall s, largest tracking error rad)`` of the bundled scene run and recorded as ``robodyn run
    --record`` runs it."""
    from ..recording.run_sink import HEADLESS_BATCH, McapRunSink
    from ..runs import plan_run, resolve_settings
    from ..scene import load_scene
    from ..simulation import Simulator, run_headless
    best, err = math.inf, None
    with tempfile.TemporaryDirectory(prefix='robodyn-bench-control-') as tmp:
        for _ in range(max(1, repeat)):
            scene = load_scene(SCENE)
            plan, st = plan_run(resolve_settings(scene, duration=HORIZON), scene.system, scene.y0)
            sim = Simulator(scene.system, scene.y0, plan=plan)
            path = os.path.join(tmp, 'run.mcap')
            sink = McapRunSink(path, scene, {**st, 'mode': 'bench'}, batch=HEADLESS_BATCH)
            w0 = time.perf_counter()
            run_headless(sim, HORIZON, RATE, scene.script, [sink])
            sink.close()
            best = min(best, time.perf_counter() - w0)
            os.remove(path)
            err = _tracking_error(scene, sim)
    return best, err


def _tracking_error(scene, sim) -> float:
    """Largest ``|q* − q|`` (rad) over the published periods of the scene run again with sim's settings (an
    untimed run that reads the ``joint_trajectory_error`` messages)."""
    from ..simulation import Simulator, run_headless

    class Worst:
        worst = 0.0

        def on_start(self, s):
            pass

        def on_command(self, *a):
            pass

        def on_output(self, t, out, s):
            for topic, _, msg in out.messages:
                if topic == 'joint_trajectory_error':
                    Worst.worst = max(Worst.worst, float(np.abs(msg['position']).max()))

        def close(self):
            pass
    s2 = Simulator(scene.system, scene.y0, integrator=sim.settings['integrator'], dt=sim.settings['dt'])
    run_headless(s2, HORIZON, RATE, scene.script, [Worst()])
    return Worst.worst


def mujoco_actuators(repeat=3):
    """``(best wall s, largest tracking error rad)`` of MuJoCo on xarm7 with position actuators of the servo's
    gains tracking the scene's trajectory (module docstring), or ``(None, reason)``."""
    try:
        import mujoco
    except ImportError:
        return None, 'mujoco not installed'
    from ..meshes import resolve_uri
    from ..scene import load_scene
    from ..simulation import Simulator
    scene = load_scene(SCENE)
    servo = scene.system.servo
    names = list(servo.position)
    sim = Simulator(scene.system, scene.y0, integrator='rosenbrock2', dt=DT)
    for port, value in scene.script(0.0, scene.y0).items():
        sim.set_command(port, value)
    prog = sim.ports['position'].applied
    steps = int(round(HORIZON / DT))
    desired = prog.sample_many(np.arange(steps) * DT)[:, :, 0]          # q*(t) before every step
    url = scene.data['parts'][0]['file']
    text = open(resolve_uri(url)).read()
    text = re.sub(r'<(visual|collision)\b.*?</\1>', '', text, flags=re.DOTALL)
    text = text.replace('<link ', '<mujoco><compiler boundinertia="1e-9"/></mujoco>\n  <link ', 1)
    spec = mujoco.MjSpec.from_string(text)
    for j, name in enumerate(names):
        act = spec.add_actuator()
        act.name = f'servo_{name}'
        act.target = name
        act.trntype = mujoco.mjtTrn.mjTRN_JOINT
        act.set_to_position(kp=float(servo.kp[j]), kv=float(servo.kd[j]))
    m = spec.compile()
    m.opt.timestep = DT
    m.opt.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    adr = np.array([m.joint(n).qposadr[0] for n in names])
    per = int(round(1.0 / (RATE * DT)))
    best, worst = math.inf, 0.0
    for _ in range(max(1, repeat)):
        d = mujoco.MjData(m)
        d.qpos[adr] = scene.y0[:len(names)]
        step = mujoco.mj_step
        q = np.empty((steps // per, len(names)))
        w0 = time.perf_counter()
        for k in range(steps // per):
            for i in range(per):
                d.ctrl[:] = desired[k * per + i]
                step(m, d)
            q[k] = d.qpos[adr]
        best = min(best, time.perf_counter() - w0)
        t_end = (np.arange(steps // per) + 1) * per * DT
        worst = float(np.abs(q - prog.sample_many(t_end)[:, :, 0]).max())
    return best, worst


def section_mujoco(repeat=3) -> str:
    """The ``mujoco`` section."""
    wall, err = robodyn_recorded(repeat)
    mj_wall, mj_err = mujoco_actuators(repeat)
    lines = [f'## xarm7 tracking a {HORIZON:g} s trajectory at {DT * 1e3:g} ms ({SCENE})', '',
             '| simulator | how | wall (s) | real-time factor | largest tracking error (rad) |', '|---|---|---|---|---|',
             f'| robodyn | rosenbrock2, servo + feed-forward, recorded (robodyn run --record) | {wall:.3f} | '
             f'{HORIZON / wall:.0f} | {err:.2g} |']
    if mj_wall is None:
        lines.append(f'| MuJoCo | ({mj_err}) | | | |')
    else:
        lines.append(f'| MuJoCo {mujoco.__version__ if (mujoco := _mujoco()) else ""} | implicitfast, position '
                     f'actuators (same kp, kv), ctrl set every step from Python, not recorded | {mj_wall:.3f} | '
                     f'{HORIZON / mj_wall:.0f} | {mj_err:.2g} |')
    return '\n'.join(lines)


def _mujoco():
    try:
        import mujoco
        return mujoco
    except ImportError:
        return None
