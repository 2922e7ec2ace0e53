"""``robodyn bench control``: what position and trajectory commands cost (figures, never asserted).

* ``cost``: xArm7 (example-robot-data) for 10 s at 1 ms under rosenbrock2 (what integrator auto picks
  for it), integration alone (``Simulator.advance`` per 10 ms period, the compiled loop): effort commands
  (zero), every joint holding a position (the servo with its feed-forward), and the bundled
  ``xarm7_trajectory`` trajectory; each one's wall time against the effort run's (target: at most 1.2x).
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


def _scene(interfaces: str, trajectory: bool):
    """The bundled scene with its part's command_interfaces replaced (effort: the URDF robot as it is),
    without the scripted trajectory unless asked."""
    from ..scene import find_scene, parse_scene
    path = find_scene(SCENE)
    text = path.read_text()
    text = text.replace('command_interfaces: position', f'command_interfaces: {interfaces}')
    if not trajectory:
        text = re.sub(r'\ncommands:.*?(?=\nsensors:)', '', text, flags=re.DOTALL)
    return parse_scene(text, file=str(path))


def _advance_wall(scene, repeat) -> float:
    """Best wall seconds of HORIZON s of Simulator.advance at RATE periods (rosenbrock2 at DT), the scene's
    scripted commands set at each period's start."""
    from ..simulation import Simulator
    best = math.inf
    for _ in range(max(1, repeat)):
        sim = Simulator(scene.system, scene.y0, integrator='rosenbrock2', dt=DT)
        n = int(round(HORIZON * RATE))
        w0 = time.perf_counter()
        for k in range(n):
            if scene.script is not None:
                for port, value in scene.script(sim.t, sim.y).items():
                    sim.set_command(port, value)
            sim.advance((k + 1) / RATE)
        best = min(best, time.perf_counter() - w0)
    return best


def cost_figures(repeat=3) -> dict:
    """``{label: wall seconds}`` of the three runs of the ``cost`` section."""
    return {'effort (zero)': _advance_wall(_scene('effort', False), repeat),
            'position held (servo + feed-forward)': _advance_wall(_scene('position', False), repeat),
            'trajectory (servo + feed-forward)': _advance_wall(_scene('position', True), repeat)}


def section_cost(repeat=3) -> str:
    """The ``cost`` section."""
    fig = cost_figures(repeat)
    base = fig['effort (zero)']
    lines = [f'## servo cost: xarm7, {HORIZON:g} s at {DT * 1e3:g} ms, rosenbrock2, integration alone '
             f'(Simulator.advance per {1e3 / RATE:g} ms period)', '',
             '| commands | wall (s) | real-time factor | x effort run (target <= 1.2) |', '|---|---|---|---|']
    for label, wall in fig.items():
        lines.append(f'| {label} | {wall:.3f} | {HORIZON / wall:.0f} | {wall / base:.2f} |')
    return '\n'.join(lines)


def robodyn_recorded(repeat=3) -> tuple:
    """``(best wall s, largest tracking error rad)`` of the bundled scene run and recorded as ``robodyn run
    --record`` runs it."""
    from ..recording.run_sink import HEADLESS_BATCH, McapRunSink
    from ..runs import resolve_auto, resolve_settings
    from ..scene import load_scene
    from ..simulation import Simulator, run_headless
    best, err = math.inf, None
    with tempfile.TemporaryDirectory(prefix='robodyn-bench-control-') as tmp:
        for _ in range(max(1, repeat)):
            scene = load_scene(SCENE)
            st = resolve_auto(resolve_settings(scene, duration=HORIZON), scene.system, scene.y0)
            sim = Simulator(scene.system, scene.y0, integrator=st['integrator'], dt=st['dt'])
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
