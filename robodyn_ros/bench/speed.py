"""``robodyn bench speed``: how fast, next to references measured in the same run.

Sections (each can be skipped with ``--skip``):

* ``kernels``  per-call time of inverse dynamics (RNEA), mass matrix (CRBA) and forward
  dynamics (ABA) for every bundled scene's kinematic tree: the numpy reference, the compiled
  kernels and Pinocchio on the exported URDF (``pin.buildModelFromXML(to_urdf(model))``), all
  called from Python;
* ``systems``  the right-hand side of the constrained and floating-base systems (diff drive, mobile
  manipulator, free base in minimal and augmented coordinates, prescribed path): numpy reference
  against the compiled kernels, per evaluation and per fused period; the augmented/minimal ratio;
* ``rtf``      real-time factor of ``--duration`` s (default 10) at 1 kHz RK4 headless (Simulator
  + run_headless, scripted commands, joint states recorded at 100 Hz to a temporary MCAP),
  next to a Python loop of RK4 over ``pin.aba`` and MuJoCo's RK4 (same URDF, timestep 1 ms)
  stepped from Python (one ``mj_step`` per step, and ``mj_step(nstep=10)`` per 10 ms);
* ``recording`` per scene, the integration-only and the fully recorded real-time factor
  (every default topic of ``robodyn run``) and their ratio, the recorder's cost per period and per
  message (batched, and message by message as the node writes) next to zstd's cost for the same
  bytes, and MuJoCo's RK4 stepped from Python with its state copied out every period;
* ``scaling``  forward dynamics of 8/16/32/64-link random chains (O(n): 64 links should cost
  at most 10x 8 links);
* ``memory``   peak RSS and RSS growth after warm-up of a long recorded run (``--long``: one
  simulated hour), in a child process;
* ``compile``  first-run cost of the compiled kernels (cold numba cache) against a warm start,
  in child processes;
* ``node``     the ROS node's figures from ``robodyn_ros.bench.node.bench_node()`` when present;
* ``stiff``    stiff robots at 1 ms (:mod:`robodyn_ros.bench.stiff`): xarm7 by rosenbrock2 beside MuJoCo's
  implicitfast, implicit and Euler integrators stepped from Python, errors against Pinocchio + Radau;
  human17 and the inductive-motor platform at 1 ms (the example-robot-data table is
  ``robodyn bench stiff``);
* ``targets``  the speed targets against the figures measured above (met or not, by how much).

Per-call timings are CPU time of this process, the minimum over interleaved repeats; run
figures (real-time factors) are wall time with the CPU-time figure beside them. They are figures
to read, never asserted by tests.
"""
from __future__ import annotations

import contextlib
import math
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

from .references import (RTF_DT, RTF_RATE, mujoco_loop, mujoco_model, mujoco_recorded_loop, pin_reference,
                         pin_rk4_loop)
from .timing import best_of, fmt_ratio, fmt_time, machine_line, peak_rss_bytes, per_call, rss_bytes, table

HELP = 'per-call ID/M/FD, real-time factors, O(n) scaling, memory and compile cost vs Pinocchio/MuJoCo'
SECTIONS = ('kernels', 'systems', 'rtf', 'recording', 'scaling', 'memory', 'compile', 'node', 'stiff', 'targets')
#: simulated seconds of the numpy-reference RTF run (it is ~100x slower than the compiled one)
REFERENCE_HORIZON = 0.5
#: simulated seconds for systems without a compiled path (their numpy constraint solvers are slow)
NUMPY_SYSTEM_HORIZON = 1.0
CHAIN_SIZES = (8, 16, 32, 64)


def add_arguments(p):
    """Options of the speed benchmark."""
    p.add_argument('--out', default=None, help='also write the markdown report to this file')
    p.add_argument('--scenes', nargs='*', default=None, help='bundled scene names (default: all)')
    p.add_argument('--repeat', type=int, default=7, help='interleaved repeats per timing (default 7)')
    p.add_argument('--duration', type=float, default=10.0, help='simulated seconds of the RTF runs (default 10)')
    p.add_argument('--memory-duration', type=float, default=120.0,
                   help='simulated seconds of the memory run (default 120; --long: 3600)')
    p.add_argument('--long', action='store_true', help='memory run of one simulated hour')
    p.add_argument('--quick', action='store_true', help='few repeats and short runs (a smoke test)')
    p.add_argument('--skip', nargs='*', default=[], choices=SECTIONS, help='sections to leave out')
    return p


def main(args) -> int:
    """Run the benchmark, print the markdown report, optionally write it to ``--out``."""
    if args.quick:
        args.repeat = min(args.repeat, 3)
        args.duration = min(args.duration, 1.0)
        args.memory_duration = min(args.memory_duration, 5.0)
    if args.long:
        args.memory_duration = 3600.0
    parts = [f'## robodyn bench speed\n\nCommand: `robodyn bench speed {" ".join(_argv_echo(args))}`'.rstrip()
             + f'  \nMachine: {machine_line()}\n']
    print(parts[0], flush=True)
    sections = [s for s in SECTIONS if s not in args.skip]
    names = _scene_names(args.scenes)
    args.figures = {}  # key figures the sections measure, for the targets table
    for s in sections:
        text = globals()[f'section_{s}'](args, names)
        parts.append(text)
        print(text + '\n', flush=True)
    if args.out:
        with open(args.out, 'w') as f:
            f.write('\n\n'.join(parts) + '\n')
    return 0


def _argv_echo(args) -> list:
    """The options as given (for the report heading)."""
    out = []
    if args.scenes:
        out += ['--scenes'] + list(args.scenes)
    for flag in ('quick', 'long'):
        if getattr(args, flag):
            out.append('--' + flag)
    if args.skip:
        out += ['--skip'] + list(args.skip)
    if args.out:
        out += ['--out', args.out]
    return out


def _scene_names(requested):
    """Bundled scene names to benchmark (all of them by default)."""
    from ..scene import list_scenes
    names = [n for n, _ in list_scenes()]
    if requested:
        unknown = [n for n in requested if n not in names]
        if unknown:
            raise SystemExit(f'robodyn bench speed: unknown scene(s) {unknown}; bundled: {names}')
        return list(requested)
    return names


@contextlib.contextmanager
def _backend(name):
    """Temporarily select the default ArmSystem backend (``ROBODYN_BACKEND``) for scene loading."""
    old = os.environ.get('ROBODYN_BACKEND')
    os.environ['ROBODYN_BACKEND'] = name
    try:
        yield
    finally:
        if old is None:
            os.environ.pop('ROBODYN_BACKEND', None)
        else:
            os.environ['ROBODYN_BACKEND'] = old


def _load(name, backend='numba'):
    """Load a bundled scene with ArmSystems on the given backend (warnings silenced)."""
    import warnings
    from ..scene import load_scene
    with _backend(backend), warnings.catch_warnings():
        warnings.simplefilter('ignore')
        return load_scene(name)


#: robots imported from example-robot-data (test extras) for the kernels table: label -> scene part
IMPORTED_ROBOTS = {
    'panda (URDF)': "file: {d}/panda_description/urdf/panda.urdf, "
                    "locked: {{panda_finger_joint1: 0.0, panda_finger_joint2: 0.0}}",
    'solo12 (URDF)': "file: {d}/solo_description/robots/solo12.urdf, floating: true",
}


def _imported_robots(notes) -> dict:
    """label -> Scene of :data:`IMPORTED_ROBOTS` (empty, with a note, without example-robot-data)."""
    from ..scene import parse_scene
    from ..urdf import example_robot_data_dir
    d = example_robot_data_dir()
    if d is None:
        notes.append('imported robots (Panda, Solo12) left out: example-robot-data is not installed')
        return {}
    with _backend('numba'):
        return {k: parse_scene(f'name: x\nparts:\n  - {{kind: urdf, name: robot, {v.format(d=d)}}}\n')
                for k, v in IMPORTED_ROBOTS.items()}


def _random_state(model, rng):
    """A random (q, v, a) valid for the model (unit quaternions for free joints)."""
    from ..model import FREE
    q = rng.uniform(-1.0, 1.0, size=model.nq)
    for i in range(model.nb):
        if model.jtype[i] == FREE:
            s = model.q_idx[i] + 3
            quat = rng.normal(size=4)
            q[s:s + 4] = quat / np.linalg.norm(quat)
    return q, rng.normal(size=model.nv), rng.normal(size=model.nv)


# ----------------------------------------------------------------------------------------------
# per-call kernels
# ----------------------------------------------------------------------------------------------
def section_kernels(args, names) -> str:
    """Per-call ID/M/FD: numpy reference, compiled, Pinocchio."""
    from .. import dynamics as dyn
    from .. import kernels
    rows = []
    notes = []
    imported = _imported_robots(notes)
    for name in names + list(imported):
        try:
            scene = imported[name] if name in imported else _load(name)
        except Exception as e:  # a scene that does not load is reported, not fatal
            notes.append(f'{name}: not loaded ({type(e).__name__}: {e})')
            continue
        model = getattr(scene.system, 'model', None)
        if model is None:
            notes.append(f'{name}: no kinematic tree')
            continue
        rng = np.random.default_rng(0)
        q, v, a = _random_state(model, rng)
        km = kernels.CompiledModel(model) if kernels.AVAILABLE else None
        kg = kernels.CompiledModel(model, specialize=True) if kernels.AVAILABLE else None
        kg = kg if kg is not None and kg.gen is not None else None
        pin_md, why = pin_reference(model)
        if pin_md is not None:
            import pinocchio as pin
            pm, pd = pin_md
            qp = pin.neutral(pm) if pm.nq != model.nq else q.copy()
            if pm.nq == model.nq and pm.nq != pm.nv:
                qp = pin.randomConfiguration(pm, -np.ones(pm.nq), np.ones(pm.nq))
            vp, ap = v.copy()[:pm.nv], a.copy()[:pm.nv]
        no_np = model.has_spherical   # kernels only: no numpy reference to time or compare
        ops = {
            'ID': (lambda: dyn.rnea(model, q, v, a),
                   (lambda: km.rnea(q, v, a)) if km else None,
                   (lambda: pin.rnea(pm, pd, qp, vp, ap)) if pin_md else None),
            'M': (lambda: dyn.crba(model, q),
                  (lambda: km.crba(q)) if km else None,
                  (lambda: pin.crba(pm, pd, qp)) if pin_md else None),
            'FD': (lambda: dyn.aba(model, q, v, a),
                   (lambda: km.aba(q, v, a)) if km else None,
                   (lambda: pin.aba(pm, pd, qp, vp, ap)) if pin_md else None),
        }
        agree = {}
        if no_np:
            ops = {op: (None,) + fns[1:] for op, fns in ops.items()}
        elif km:
            agree = {'ID': _rel(km.rnea(q, v, a), dyn.rnea(model, q, v, a)),
                     'M': _rel(km.crba(q), dyn.crba(model, q)),
                     'FD': _rel(km.aba(q, v, a), dyn.aba(model, q, v, a))}
        if kg and not no_np:
            agree['FD (generated)'] = _rel(kg.forward(q, v, a), dyn.aba(model, q, v, a))
        for op, (f_np, f_c, f_pin) in ops.items():
            f_g = (lambda: kg.forward(q, v, a)) if (op == 'FD' and kg) else None
            t = per_call({'numpy': f_np, 'compiled': f_c, 'generated': f_g, 'pin': f_pin}, repeat=args.repeat)
            tn, tc, tg, tp = (t[k][0] if t[k] else None for k in ('numpy', 'compiled', 'generated', 'pin'))
            if op == 'FD':
                getattr(args, 'figures', {}).setdefault('fd', {})[name] = {'compiled': tc, 'generated': tg, 'pin': tp}
            dev = f'{agree[op]:.1e}' if op in agree else '—'
            if tg is not None:
                dev += f' (generated {agree["FD (generated)"]:.1e})'
            rows.append([name, f'{model.nb}/{model.nv}', op, fmt_time(tn), fmt_time(tc), fmt_time(tg), fmt_time(tp),
                         fmt_ratio(tc, tp), fmt_ratio(tg, tp), fmt_ratio(tn, tc), dev])
        if not pin_md:
            notes.append(f'{name}: Pinocchio column empty ({why})')
    text = ['### Per-call time (called from Python; CPU time, minimum of interleaved repeats)\n',
            table(['scene', 'bodies/dof', 'op', 'numpy reference', 'compiled', 'generated (method of Zs)', 'Pinocchio',
                   'compiled / Pinocchio', 'generated / Pinocchio', 'numpy / compiled',
                   'max rel. diff vs numpy'], rows)]
    text += ['', 'ID = RNEA, M = CRBA, FD = ABA; Pinocchio on `pin.buildModelFromXML(to_urdf(model))` (trees with '
             'spherical joints: JointModelSpherical, built joint by joint by robodyn_ros.bench.pinbridge), '
             'random state (seed 0). "generated": forward dynamics generated for that tree '
             '(`ArmSystem(backend="generated")`, robodyn_ros.kernels.codegen; not for FREE joints).',
             _call_floor(args)] + [f'- {n}' for n in notes]
    return '\n'.join(text)


def _call_floor(args) -> str:
    """The cost of the Python call itself: FD of a 1-link model, compiled and Pinocchio."""
    from .. import kernels
    from ..model import random_tree
    m = random_tree(1, np.random.default_rng(0))
    z = np.zeros(1)
    fns = {'compiled': (lambda: km.aba(z, z, z)) if kernels.AVAILABLE else None}
    km = kernels.CompiledModel(m) if kernels.AVAILABLE else None
    pin_md, _ = pin_reference(m)
    if pin_md:
        import pinocchio as pin
        pm, pd = pin_md
        fns['pin'] = lambda: pin.aba(pm, pd, z, z, z)
    t = {k: (v[0] if v else None) for k, v in per_call(fns, repeat=args.repeat).items()}
    return (f'Cost of the call itself (FD of a 1-link model): compiled {fmt_time(t["compiled"])}, '
            f'Pinocchio {fmt_time(t.get("pin"))}.')


def _rel(x, y) -> float:
    """Largest deviation relative to the largest reference entry."""
    y = np.asarray(y, dtype=float)
    return float(np.abs(np.asarray(x) - y).max() / max(1.0, np.abs(y).max()))


# ----------------------------------------------------------------------------------------------
# constrained and floating-base systems
# ----------------------------------------------------------------------------------------------
def _system_pair(scene, formulation=None):
    """(compiled system, numpy system) of a scene's constrained/floating-base system."""
    from ..systems.augmented import AugmentedFreeFlyerSystem
    from ..systems.freeflyer import FreeFlyerSystem
    s = scene.system
    if not (hasattr(s, 'rebuilt') and hasattr(s, '_u_vec')):   # CompiledSystem kinds (the planar base is a tree)
        return None
    kw = {}
    if formulation is not None:
        kw['cls'] = {'minimal': FreeFlyerSystem, 'augmented': AugmentedFreeFlyerSystem}[formulation]
    return s.rebuilt('numba', **kw), s.rebuilt('numpy', **kw)


def section_systems(args, names) -> str:
    """Right-hand side of the constrained / floating-base systems: numpy reference vs compiled."""
    import warnings
    from .. import kernels
    rows = []
    figures = getattr(args, 'figures', {})
    if not kernels.AVAILABLE:
        return '### Constrained and floating-base systems\n\nskipped: numba unavailable'
    for name in names:
        scene = _load(name)
        forms = ['minimal', 'augmented'] if hasattr(scene.system, 'formulation') and \
            scene.system.formulation in ('minimal', 'augmented') else [None]
        for form in forms:
            pair = _system_pair(scene, form)
            if pair is None:
                continue
            fast, ref = pair
            q0v0 = scene.system.minimal(scene.y0) if hasattr(scene.system, 'minimal') else None
            y = fast.initial_state(*q0v0) if q0v0 is not None else np.array(scene.y0, dtype=float)
            u = {k: np.full(p.size, 0.1) for k, p in fast.inputs.items()}
            t = 0.1
            with warnings.catch_warnings():
                warnings.simplefilter('ignore')
                uv = fast._u_vec(u)
                z0 = np.append(y, 0.0)
                n = int(round(1.0 / (RTF_RATE * RTF_DT)))

                def ref_eval():  # what the Simulator's reference path calls per stage
                    if hasattr(ref, '_cache'):
                        ref._cache = None  # the prescribed path caches its solve per (t, y, u)
                    return ref.rhs(t, y, u), ref.input_power(t, y, u)
                tt = per_call({'numpy': ref_eval, 'compiled': lambda: fast._cs.evaluate(t, y, uv),
                               'period': lambda: fast.fused_advance('rk4', RTF_DT, t, z0, t + n * RTF_DT, u)},
                              repeat=args.repeat)
            tn, tc, tp = (tt[k][0] for k in ('numpy', 'compiled', 'period'))
            label = name + (f' ({form})' if form else '')
            rows.append([label, type(fast).__name__, fast.ny, fmt_time(tn), fmt_time(tc), fmt_time(tp / (4 * n)),
                         fmt_ratio(tn, tp / (4 * n))])
            figures.setdefault('systems', {})[label] = {'numpy': tn, 'compiled': tc, 'in_loop': tp / (4 * n)}
    text = ['### Constrained and floating-base systems: one evaluation of [dy/dt; power] (CPU time)\n',
            table(['scene (formulation)', 'system', 'states', 'numpy reference (rhs + input_power)',
                   'compiled, called from Python', 'compiled, inside the fused RK4 loop', 'numpy / in-loop'], rows)]
    ff = figures.get('systems', {})
    mini, aug = ff.get('unfried_free_flyer (minimal)'), ff.get('unfried_free_flyer (augmented)')
    if mini and aug:
        r_c = aug['in_loop'] / mini['in_loop']
        r_n = aug['numpy'] / mini['numpy']
        figures['augmented_ratio'] = r_c
        text += ['', f'unfried_free_flyer, augmented (26 velocities, 15 multipliers) against minimal (11 velocities) '
                     f'coordinates: {r_c:.1f}x compiled (inside the loop), {r_n:.1f}x numpy. The compiled KKT '
                     'solve uses the block-diagonal mass matrix (dense rotational block, m_i 1 for the CoMs), the '
                     'sparsity of the constraint rows, and a Cholesky of the Schur complement certified full-rank '
                     '(λ_min ≥ 1/tr(A⁻¹) > rcond·tr(A)) before falling back to the eigen-decomposition.']
    text += ['', '"inside the fused RK4 loop": one 10 ms period of 1 ms RK4 steps in one compiled call '
                 '(`fused_advance`) divided by its 40 evaluations (projection after each step included). The '
                 'compiled kernels are tested equal to the numpy reference to 1e-12 (test_compiled_systems).']
    return '\n'.join(text)


# ----------------------------------------------------------------------------------------------
# real-time factor
# ----------------------------------------------------------------------------------------------
def run_robodyn(name, duration, record=True, backend='numba', rate=RTF_RATE, dt=RTF_DT, tf=False,
                advance_only=False, full=False):
    """Wall seconds of a headless RK4 run (dt, rate) of a bundled scene, recording joint states.

    record: McapRunSink with joint_states, /clock, the scripted commands and 1 Hz diagnostics
    (no wrenches; ``/tf`` too when tf), in batches as ``robodyn run`` writes; full: every default
    topic of ``robodyn run`` (wrenches, /tf, diagnostics every 0.1 s); advance_only: only
    ``Simulator.advance`` per period is timed (the scene's scripted commands are applied between
    the timed calls, so the same motion is integrated; the two clock reads per period are
    measured and taken off; no outputs or sinks: the floor of this loop). Returns ``(wall, simulator, cpu)``: the
    Simulator and sink are built before the clocks start (scene loading is not timed), the sink's
    ``close()`` is inside the timing.
    """
    import warnings
    from ..recording.run_sink import HEADLESS_BATCH, McapRunSink
    from ..simulation import Simulator, run_headless
    scene = _load(name, backend)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        sim = Simulator(scene.system, scene.y0, integrator='rk4', dt=dt)
    if advance_only:   # the scene's commands applied (not timed), so that the same motion is integrated
        n = int(round(duration * rate))
        script = scene.script
        clock, wall = time.process_time, time.perf_counter
        cpu = w = 0.0
        for k in range(n):
            if script is not None:
                for port, values in script(sim.t, sim.y).items():
                    sim.set_command(port, values)
            c0, t0 = clock(), wall()
            sim.advance((k + 1) / rate)
            cpu += clock() - c0
            w += wall() - t0
        c0 = clock()   # what the two clock reads add per period, taken off
        for k in range(n):
            clock(), wall()
        per = (clock() - c0) / n
        return max(w - n * per, 0.0), sim, max(cpu - n * per, 0.0)
    with tempfile.TemporaryDirectory() as d:
        sinks = [McapRunSink(os.path.join(d, 'bench.mcap'), scene,
                             {'integrator': 'rk4', 'dt': dt, 'rate': rate, 'mode': 'bench'},
                             record_wrenches=full, record_tf=tf or full, batch=HEADLESS_BATCH,
                             diagnostics_period=0.1 if full else 1.0)] if record else []
        c0, t0 = time.process_time(), time.perf_counter()
        try:
            run_headless(sim, duration, rate, scene.script, sinks)
        finally:
            for s in sinks:
                s.close()
        return time.perf_counter() - t0, sim, time.process_time() - c0


def best_run(fn, repeat=3) -> tuple:
    """``(min wall, median wall, min CPU)`` over ``repeat`` calls of a :func:`run_robodyn` call
    ``fn`` (its own timing of the run, without the scene loading)."""
    import statistics
    runs = [fn() for _ in range(repeat)]
    walls = [r[0] for r in runs]
    return min(walls), statistics.median(walls), min(r[2] for r in runs)


def _timed_scenes(names, args, notes):
    """The scenes a timing section measures: ``(name, scene, arm, backend, fused, horizon, repeats)``
    per scene that loads (a scene that does not is a line in ``notes``). backend: the fastest
    kernels (generated for arms, ``--backend generated``; numba otherwise; the numba column beside
    it is the default of robodyn run and the node); horizon: ``args.duration``, or
    :data:`NUMPY_SYSTEM_HORIZON` for systems without a compiled fused path (run once)."""
    from ..systems.arm import ArmSystem
    for name in names:
        try:
            scene = _load(name)
        except Exception as e:
            notes.append(f'{name}: not loaded ({type(e).__name__}: {e})')
            continue
        arm = type(scene.system) is ArmSystem
        fused = has_fused_path(scene.system)
        yield (name, scene, arm, 'generated' if arm else 'numba', fused,
               args.duration if fused else min(args.duration, NUMPY_SYSTEM_HORIZON),
               (args.repeat if args.quick else 3) if fused else 1)


def has_fused_path(system) -> bool:
    """True when the system runs whole periods in compiled code (``fused_advance`` accepts rk4)."""
    fused = getattr(system, 'fused_advance', None)
    if fused is None:
        return False
    u = system.zero_inputs()
    z = np.zeros(system.ny + 1)
    try:
        return fused('rk4', RTF_DT, 0.0, z, 0.0, u) is not None  # t1 = t0: no step is taken
    except Exception:  # noqa: BLE001 - a system that cannot even be asked has no fast path
        return False


def section_rtf(args, names) -> str:
    """Real-time factors of the robodyn runs and the references."""
    from ..model import to_urdf
    rows, notes = [], []
    dur = args.duration
    figures = getattr(args, 'figures', {})
    for name, scene, arm, tools, fused, d, n_rec in _timed_scenes(names, args, notes):
        try:
            run_robodyn(name, 0.05)  # warm-up (compiled code, caches)
            run_robodyn(name, 0.05, backend=tools)
            t_tools = best_run(lambda: run_robodyn(name, d, backend=tools), n_rec)
            t_numba = best_run(lambda: run_robodyn(name, d), n_rec) if arm else None
            t_tf = best_run(lambda: run_robodyn(name, d, backend=tools, tf=True), n_rec)
            t_norec = best_run(lambda: run_robodyn(name, d, record=False, backend=tools), n_rec)
            t_adv = best_run(lambda: run_robodyn(name, d, backend=tools, advance_only=True), n_rec)
            ref_h = min(REFERENCE_HORIZON, dur / 10.0)
            t_ref = None if getattr(scene.system.model, 'has_spherical', False) else \
                best_run(lambda: run_robodyn(name, ref_h, backend='numpy'), 1)
        except Exception as e:
            why = ' '.join(str(e).split())[:300]
            notes.append(f'{name}: RK4 at {RTF_DT * 1e3:g} ms not run ({type(e).__name__}: {why})')
            continue
        horizon = '' if d == dur else f' ({d:g} s run)'
        figures.setdefault('rtf', {})[name] = {'wall': d / t_tools[0], 'cpu': d / t_tools[2],
                                               'advance_cpu': d / t_adv[2], 'backend': tools}
        row = [name + horizon, tools,
               f'{d / t_tools[0]:.0f} (CPU {d / t_tools[2]:.0f})',
               f'{d / t_numba[2]:.0f}' if t_numba else 'same',
               f'{d / t_tf[2]:.0f}', f'{d / t_norec[2]:.0f}', f'{d / t_adv[2]:.0f}',
               f'{ref_h / t_ref[2]:.1f}' if t_ref else 'n/a (kernels only)']
        model = scene.system.model if arm else None
        if model is None:
            row += ['n/a', 'n/a', 'n/a']
            notes.append(f'{name}: {type(scene.system).__name__} has constraints/actuators the URDF does not '
                         'carry, so no Pinocchio/MuJoCo equivalent')
        else:
            q0, v0 = scene.y0[:model.nq], scene.y0[model.nq:]
            if model.has_spherical:   # Pinocchio's joint order and free-joint (linear, angular) velocity
                from .pinbridge import pin_model
                _, qmap, vmap, _ = pin_model(model)
                q0, v0 = np.empty_like(q0), np.empty_like(v0)
                q0[qmap], v0[vmap] = scene.y0[:model.nq], scene.y0[model.nq:]
            pin_md, why = pin_reference(model)
            if pin_md is not None:
                pm, pd = pin_md
                t = best_of(lambda: pin_rk4_loop(pm, pd, q0, v0, model.damping, dur), 1 if args.quick else 2)
                row.append(f'{dur / t[0]:.0f} (CPU {dur / t[2]:.0f})')
                figures.setdefault('rtf_pin', {})[name] = dur / t[2]
            else:
                row.append(f'n/a ({why})')
            m, why = mujoco_model(to_urdf(model))
            if m is not None and m.nq == model.nq:
                t1 = best_of(lambda: mujoco_loop(m, q0, v0, dur, 1), 1 if args.quick else 2)
                t10 = best_of(lambda: mujoco_loop(m, q0, v0, dur, 10), 1 if args.quick else 2)
                row += [f'{dur / t1[0]:.0f} (CPU {dur / t1[2]:.0f})', f'{dur / t10[0]:.0f}']
            else:
                why = why or f'MuJoCo model has nq={m.nq}, ours {model.nq}'
                row += ['n/a', 'n/a']
                notes.append(f'{name}: no MuJoCo reference ({why})')
        rows.append(row)
    text = [f'### Real-time factor: {dur:g} s simulated, RK4 at {RTF_DT * 1e3:g} ms, headless\n',
            table(['scene', 'kernels', 'robodyn + MCAP at 100 Hz: wall (CPU)', 'same, numba kernels: the default (CPU)',
                   'same + /tf (CPU)', 'no recording (CPU)', 'integration only (CPU)',
                   f'numpy reference + MCAP ({min(REFERENCE_HORIZON, dur / 10.0):g} s run, CPU)',
                   'Python RK4 loop over pin.aba', 'MuJoCo RK4, mj_step per step from Python',
                   'MuJoCo RK4, mj_step(nstep=10) per 10 ms'], rows),
            '', 'RTF = simulated / wall time (higher is faster; "CPU": simulated / CPU time of this process, '
            'which leaves out time other processes held the cores). robodyn runs: Simulator + run_headless with the '
            "scene's scripted commands, the fused compiled loop per 10 ms period, joint_states + /clock + commands + "
            '1 Hz diagnostics written by McapRunSink (no wrenches; "+ /tf" adds the TF of every joint, as '
            '`robodyn run` records by default); "kernels": the fastest (generated = `--backend generated`, '
            'specialised per model, for arms; the other systems run their compiled kernels, so the numba column '
            'is the same); "numba kernels": the default of `robodyn run` and the node; "integration only": `Simulator.advance` per period and nothing else. References '
            'integrate the same arm (URDF export) unforced (gravity + damping), without recording.',
            _kernel_floor(args)] + [f'- {n}' for n in notes]
    return '\n'.join(text)


def _kernel_floor(args) -> str:
    """The compiled integration of one 10 ms period of stanford_arm alone (no Python around it)."""
    from .. import kernels
    if not kernels.AVAILABLE:
        return ''
    out = []
    for backend in ('numba', 'generated'):
        scene = _load('stanford_arm', backend)
        s = scene.system
        km = s._km
        z0 = np.append(scene.y0, 0.0)
        tau = np.zeros(s.nv)
        n = int(round(1.0 / (RTF_RATE * RTF_DT)))
        t = per_call({'k': lambda: km.integrate_arm('rk4', z0.copy(), tau, RTF_DT, n, 0.0)}, repeat=args.repeat)['k'][0]
        out.append(f'{backend} {fmt_time(t)} ({fmt_time(t / (4 * n))} per forward dynamics; RTF at most '
                   f'{1.0 / RTF_RATE / t:.0f})')
        getattr(args, 'figures', {}).setdefault('kernel_period', {})[backend] = t
    return ('Floor: the compiled RK4 integration of one 10 ms period of stanford_arm (40 forward dynamics, '
            'CPU time, nothing else) takes ' + '; '.join(out) + '. No headless loop around it can be faster.')


# ----------------------------------------------------------------------------------------------
# recording at the speed of the dynamics (issue 15)
# ----------------------------------------------------------------------------------------------
class _StoredCalls:
    """A sink that keeps what :func:`run_headless` hands its sinks (outputs computed, wrenches
    wanted), to hand the same calls to a recorder later (:meth:`replay`)."""

    wants_wrenches = True

    def __init__(self):
        self.calls = []     # ('cmd', t, port, values) and ('out', t, outputs), in run order
        self.outputs = []   # the ('out', t, outputs) calls

    def on_start(self, sim):
        pass

    def on_command(self, t, port, values):
        self.calls.append(('cmd', t, port, values))

    def on_output(self, t, out, sim):
        self.calls.append(('out', t, out))
        self.outputs.append(self.calls[-1])

    def close(self):
        pass

    def replay(self, sink, sim):
        for kind, t, *rest in self.calls:
            if kind == 'cmd':
                sink.on_command(t, *rest)
            else:
                sink.on_output(t, rest[0], sim)


def _replay_cost(scene, backend, periods, batch, repeat):
    """CPU seconds per period of recording ``periods`` stored publications of a scene (outputs
    computed beforehand, as run_headless hands them over) with McapRunSink(batch), every default
    topic; also the messages and bytes it wrote and the zstd time of those bytes per period."""
    import warnings
    import zstandard
    from ..recording import mcap_sink
    from ..recording.run_sink import McapRunSink
    from ..simulation import Simulator, run_headless
    from ..systems.base import LazyWrenches
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        sim = Simulator(scene.system, scene.y0, integrator='rk4', dt=RTF_DT)
    stored = _StoredCalls()
    run_headless(sim, periods / RTF_RATE, RTF_RATE, scene.script, [stored])
    best, info = None, None
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, 'replay.mcap')
        for _ in range(repeat):
            for *_, out in stored.outputs:
                if isinstance(out.wrenches, LazyWrenches):
                    out.wrenches._f = None   # computed again, as in a run
            sink = McapRunSink(path, scene, {'mode': 'bench'}, diagnostics_period=0.1, batch=batch)
            sink.on_start(sim)
            c0 = time.process_time()
            stored.replay(sink, sim)
            sink.close()
            c = (time.process_time() - c0) / len(stored.outputs)
            best = c if best is None else min(best, c)
            if info is None:
                from mcap.records import Chunk
                from mcap.stream_reader import StreamReader
                with open(path, 'rb') as f:
                    raw = [zstandard.decompress(r.data, max_output_size=r.uncompressed_size)
                           if r.compression == 'zstd' else r.data
                           for r in StreamReader(f, emit_chunks=True).records if isinstance(r, Chunk)]
                zc = zstandard.ZstdCompressor(level=mcap_sink.ZSTD_LEVEL)
                t_z = min(best_of(lambda: [zc.compress(x) for x in raw], 3)[2], 1e9)
                info = {'messages': sink.count, 'bytes': sum(len(x) for x in raw), 'zstd': t_z / len(stored.outputs),
                        'raw': b''.join(raw)}
    return best, info


_RECORDING_NOTE = (
    '"integration only": `Simulator.advance` per period and nothing else. "full recorded": the loop and the '
    "sink of `robodyn run`: the scene's scripted commands, outputs, and every default topic (joint_states, odom, "
    'constraint wrenches, /tf, /clock, commands, diagnostics every 0.1 s) written in batches of at most {batch} periods '
    '(and no more rows than the open chunk has room for). "periods in compiled blocks": the share of that run\'s periods (of a 1 s run) that '
    "`run_headless`'s block path ran, many per compiled call with the scripted commands compiled (arms whose "
    'joint_states are their state; the rest run period by period in Python). "no recording": the same loop without a sink. "recorder per period": McapRunSink alone on '
    "stored publications (outputs computed beforehand; the recorder computes the arms' joint wrenches, one "
    'compiled call per state in runs this short, per batch after 10 000 states), CPU time including chunking, '
    'zstd and the file writes; "message by message" is '
    "the path the node uses (it writes its own messages between the recorder's). \"zstd of those bytes\": "
    'zstd at the level the recorder writes (1, the MCAP C++ writer\'s default) of the same uncompressed chunks. MuJoCo: the same arm (URDF '
    'export), unforced, RK4 at 1 ms, `mj_step(m, d, 10)` per 10 ms with time, qpos, qvel, qacc and actuator '
    'forces copied into arrays every period.')


def _compression_trade(raw: bytes, period_bytes: float) -> list:
    """Rows: chunk size x compression (zstd levels, lz4, none) -> size ratio and CPU time."""
    import zstandard
    from ..recording import mcap_sink
    rows = []
    written = (mcap_sink.ZSTD_LEVEL, mcap_sink.DEFAULT_CHUNK_SIZE)
    for size in (16 * 1024, 64 * 1024, 256 * 1024, 768 * 1024):
        pieces = [raw[i:i + size] for i in range(0, len(raw), size)]
        codecs = [(f'zstd {lv}' + (' (written)' if (lv, size) == written else ''),
                   zstandard.ZstdCompressor(level=lv).compress) for lv in (-5, -1, 1, 3, 6)]
        try:
            import lz4.frame
            codecs.append(('lz4', lz4.frame.compress))
        except ImportError:
            pass
        for label, fn in codecs:
            t = best_of(lambda: [fn(p) for p in pieces], 3)[2]
            out = sum(len(fn(p)) for p in pieces)
            rows.append([f'{size // 1024} KiB', label, f'{out / len(raw) * 100:.1f} %', f'{t / len(raw) * 1e6 * 1e3:.2f} ms',
                         f'{t / len(raw) * period_bytes * 1e6:.2f} µs'])
    return rows


def section_recording(args, names) -> str:
    """Integration-only vs fully recorded real-time factor per scene, recorder cost per period and
    per message, and MuJoCo RK4 from Python with its state copied out every period."""
    from ..model import to_urdf
    from ..recording.run_sink import HEADLESS_BATCH
    rows, notes, zrows = [], [], []
    dur = args.duration
    figures = getattr(args, 'figures', {})
    periods = 100 if args.quick else 300
    for name, scene, arm, backend, fused, d, n_rec in _timed_scenes(names, args, notes):
        try:
            run_robodyn(name, 0.05, backend=backend, full=True)   # warm-up
            t_adv = best_run(lambda: run_robodyn(name, d, backend=backend, advance_only=True), n_rec)
            t_full = best_run(lambda: run_robodyn(name, d, backend=backend, full=True), n_rec)
            blocks = run_robodyn(name, 1.0, backend=backend, full=True)[1].diag.block_periods / round(1.0 * RTF_RATE)
            t_none = best_run(lambda: run_robodyn(name, d, backend=backend, record=False), n_rec)
            sc = _load(name, backend)
            c_batch, info = _replay_cost(sc, backend, periods, HEADLESS_BATCH, 3)
            c_msg, _ = _replay_cost(sc, backend, periods, 0, 3)
        except Exception as e:
            why = ' '.join(str(e).split())[:300]
            notes.append(f'{name}: not run ({type(e).__name__}: {why})')
            continue
        adv, full, none = d / t_adv[2], d / t_full[2], d / t_none[2]
        per_msg = info['messages'] / (periods + 1)
        row = [name, backend, f'{blocks:.0%}', f'{adv:.0f}', f'{full:.0f} (wall {d / t_full[0]:.0f})', f'{full / adv:.2f}',
               f'{none:.0f}', f'{per_msg:.1f} / {info["bytes"] / (periods + 1):.0f} B',
               f'{c_batch * 1e6:.1f} µs ({c_batch * 1e6 / per_msg:.2f} µs/msg)',
               f'{c_msg * 1e6:.1f} µs ({c_msg * 1e6 / per_msg:.2f} µs/msg)',
               f'{info["zstd"] * 1e6:.1f} µs', f'{c_batch / info["zstd"]:.1f}']
        fig = {'advance': adv, 'full': full, 'ratio': full / adv, 'blocks': blocks, 'batched_period': c_batch,
               'message_period': c_msg, 'zstd_period': info['zstd'], 'messages': per_msg}
        model = scene.system.model if arm else None
        m, why = mujoco_model(to_urdf(model)) if model is not None else (None, 'no URDF equivalent')
        if m is not None and m.nq == model.nq:
            q0, v0 = scene.y0[:model.nq], scene.y0[model.nq:]
            t = best_of(lambda: mujoco_recorded_loop(m, q0, v0, dur), 1 if args.quick else 3)
            fig['mujoco'] = dur / t[2]
            row += [f'{dur / t[2]:.0f}', f'{full / fig["mujoco"]:.1f}']
        else:
            row += ['n/a', 'n/a']
            if model is not None:
                notes.append(f'{name}: no MuJoCo peer ({why or f"MuJoCo model has nq={m.nq}"})')
        figures.setdefault('recording', {})[name] = fig
        rows.append(row)
        if name == 'stanford_arm':
            zrows = _compression_trade(info['raw'], info['bytes'] / (periods + 1))
    text = [f'### Recording at the speed of the dynamics: {dur:g} s simulated, RK4 at {RTF_DT * 1e3:g} ms, '
            f'published at {RTF_RATE:g} Hz\n',
            table(['scene', 'kernels', 'periods in compiled blocks', 'integration only (CPU RTF)', 'full recorded (CPU RTF)', 'full / integration',
                   'no recording (CPU RTF)', 'messages / bytes per period', 'recorder per period, batched',
                   'recorder per period, message by message', 'zstd of those bytes', 'batched / zstd',
                   'MuJoCo RK4 from Python + state copied out (CPU RTF)', 'full recorded / MuJoCo'], rows),
            '', _RECORDING_NOTE.format(batch=HEADLESS_BATCH)] + [f'- {n}' for n in notes]
    if zrows:
        text += ['', '#### Compression of a chunk: size against time (stanford_arm, every default topic)\n',
                 table(['chunk size', 'compression', 'file size (of raw)', 'CPU per MB', 'per publication period'],
                       zrows),
                 '', 'The raw message records of the recording above cut into chunks of each size and compressed '
                     'alone (CPU time, best of 3). The recorder writes zstd level 1 in 768 KiB chunks, the MCAP C++ '
                     "writer's defaults (what `ros2 bag record -s mcap` writes). A chunk shorter than the recording "
                     'compresses as a whole chunk would only when the recording holds at least that many bytes.']
    return '\n'.join(text)


# ----------------------------------------------------------------------------------------------
# O(n) scaling
# ----------------------------------------------------------------------------------------------
def section_scaling(args, names) -> str:
    """Forward dynamics of random chains of 8..64 links."""
    from .. import dynamics as dyn
    from .. import kernels
    from ..model import random_tree
    rows = []
    base = {}
    for nb in CHAIN_SIZES:
        model = random_tree(nb, np.random.default_rng(nb), prismatic_fraction=0.3, chain=True)
        q, v, a = _random_state(model, np.random.default_rng(1))
        km = kernels.CompiledModel(model) if kernels.AVAILABLE else None
        pin_md, _ = pin_reference(model)
        fns = {'numpy': lambda: dyn.aba(model, q, v, a),
               'compiled': (lambda: km.aba(q, v, a)) if km else None}
        if km:
            z = np.concatenate([q, v, [0.0]])
            zero = np.zeros(model.nv)
            n_in = 1000
            fns['in-loop'] = lambda: km.integrate_arm('euler', z.copy(), zero, 1e-6, n_in, 0.0)
        if pin_md:
            import pinocchio as pin
            pm, pd = pin_md
            fns['pin'] = lambda: pin.aba(pm, pd, q, v, a)
        t = per_call(fns, repeat=args.repeat)
        tt = {k: (t[k][0] if t.get(k) else None) for k in ('numpy', 'compiled', 'in-loop', 'pin')}
        if tt['in-loop'] is not None:
            tt['in-loop'] /= n_in
        if nb == CHAIN_SIZES[0]:
            base = dict(tt)
        getattr(args, 'figures', {}).setdefault('scaling', {})[nb] = dict(tt)
        rows.append([nb] + [f'{fmt_time(tt[k])} (×{fmt_ratio(tt[k], base.get(k))})'
                            for k in ('numpy', 'compiled', 'in-loop', 'pin')])
    text = ['### O(n) scaling: forward dynamics of random chains (×: cost relative to 8 links)\n',
            table(['links', 'numpy reference', 'compiled, from Python', 'compiled, inside the fused loop', 'Pinocchio'],
                  rows),
            '', 'Target: 64 links at most 10× 8 links. "inside the fused loop": one explicit-Euler step '
            '(ABA + q̇ + power) per call of `integrate_arm`, 1000 steps per call, no Python in between. '
            'Per-call figures are CPU time (see above).']
    return '\n'.join(text)


# ----------------------------------------------------------------------------------------------
# memory (child process)
# ----------------------------------------------------------------------------------------------
def memory_child(duration: float, scene_name='stanford_arm') -> dict:
    """Run a recorded headless run in this process and report RSS figures (bytes)."""
    import warnings
    from ..recording.run_sink import HEADLESS_BATCH, McapRunSink
    from ..simulation import Simulator, run_headless
    from ..systems.base import TOOLS_BACKEND
    scene = _load(scene_name, TOOLS_BACKEND)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        sim = Simulator(scene.system, scene.y0, integrator='rk4', dt=RTF_DT)
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, 'memory.mcap')
        sink = McapRunSink(path, scene, {'integrator': 'rk4', 'dt': RTF_DT, 'rate': RTF_RATE, 'mode': 'bench'},
                           diagnostics_period=0.1, batch=HEADLESS_BATCH)   # every default topic of robodyn run
        probe = _RssProbe(every=max(1, int(duration * RTF_RATE) // 20))
        t0 = time.perf_counter()
        try:
            run_headless(sim, duration, RTF_RATE, scene.script, [sink, probe])
        finally:
            sink.close()
        wall = time.perf_counter() - t0
        size = os.path.getsize(path)
    samples = probe.samples + [rss_bytes()]
    k = min(1, len(samples) - 1)  # samples every 5 %: index 1 is after 10 % of the run
    return {'duration': duration, 'wall': wall, 'rss_warm': samples[k], 'rss_end': samples[-1],
            'rss_max_after_warm': max(samples[k:]), 'peak_rss': peak_rss_bytes(),
            'mcap_bytes': size, 'messages': sink.count}


class _RssProbe:
    """A sink that samples the resident set size every ``every`` publications."""

    wants_wrenches = False

    def __init__(self, every):
        self.every = every
        self.n = 0
        self.samples = []

    def on_start(self, sim):
        pass

    def on_command(self, t, port, values):
        pass

    def on_output(self, t, out, sim):
        self.n += 1
        if self.n % self.every == 0:
            self.samples.append(rss_bytes())

    def close(self):
        pass


def section_memory(args, names) -> str:
    """Peak RSS and RSS growth of a long recorded run (stanford_arm), measured in a child process."""
    code = ('import json, sys; from robodyn_ros.bench.speed import memory_child; '
            f'print(json.dumps(memory_child({float(args.memory_duration)!r})))')
    r = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True)
    if r.returncode != 0:
        return f'### Memory\n\nchild process failed:\n```\n{r.stderr[-2000:]}\n```'
    m = json.loads(r.stdout.strip().splitlines()[-1])
    mb = 1024.0 ** 2
    growth = (m['rss_max_after_warm'] - m['rss_warm']) / m['rss_warm'] * 100.0
    getattr(args, 'figures', {})['memory'] = {'growth': growth, 'duration': m['duration'], 'peak': m['peak_rss']}
    rows = [['stanford_arm', f'{m["duration"]:g} s', f'{m["wall"]:.1f} s', f'{m["rss_warm"] / mb:.1f} MiB',
             f'{m["rss_end"] / mb:.1f} MiB', f'{growth:+.2f} %', f'{m["peak_rss"] / mb:.1f} MiB',
             f'{m["messages"]} msgs, {m["mcap_bytes"] / mb:.1f} MiB']]
    return '\n'.join([
        '### Memory: recorded RK4 run at 1 kHz, every default topic of robodyn run at 100 Hz (child process)\n',
        table(['scene', 'simulated', 'wall', 'RSS after warm-up (10 %)', 'RSS at end',
               'growth after warm-up (max)', 'peak RSS', 'recording'], rows),
        '', 'Target: growth < 10 % over one simulated hour (`--long`).'])


# ----------------------------------------------------------------------------------------------
# first-run (compilation) cost (child processes)
# ----------------------------------------------------------------------------------------------
_START_CODE = r'''
import json, time, warnings
t0 = time.perf_counter()
from robodyn_ros import kernels
t1 = time.perf_counter()
w = kernels.warmup()
t2 = time.perf_counter()
from robodyn_ros.bench.speed import run_robodyn
warnings.simplefilter('ignore')
run_robodyn('stanford_arm', 0.1, record=True)
t3 = time.perf_counter()
spec = platform = flyer = None
if kernels.AVAILABLE:
    run_robodyn('stanford_arm', 0.1, record=True, backend='generated')
    t4 = time.perf_counter()
    spec = t4 - t3
    run_robodyn('betancur_platform', 0.1, record=True)
    t5 = time.perf_counter()
    run_robodyn('unfried_free_flyer', 0.1, record=True)
    platform, flyer = t5 - t4, time.perf_counter() - t5
print(json.dumps({'import': t1 - t0, 'warmup': t2 - t1, 'first_run': t3 - t2, 'available': kernels.AVAILABLE,
                  'cache': kernels.CACHE_DIR, 'specialize': spec, 'platform': platform, 'flyer': flyer}))
'''


def _start(env) -> dict:
    r = subprocess.run([sys.executable, '-c', _START_CODE], capture_output=True, text=True, env=env)
    if r.returncode != 0:
        raise RuntimeError(r.stderr[-2000:])
    return json.loads(r.stdout.strip().splitlines()[-1])


def section_compile(args, names) -> str:
    """Cold (empty numba cache) and warm start of the compiled kernels, and the numpy-only start."""
    rows = []
    with tempfile.TemporaryDirectory() as d:
        env = dict(os.environ, NUMBA_CACHE_DIR=d, ROBODYN_GENERATED_DIR=os.path.join(d, 'generated'))
        env.pop('ROBODYN_BACKEND', None)
        try:
            cold = _start(env)
            warm = _start(env)
            ref = _start(dict(env, ROBODYN_BACKEND='numpy'))
        except RuntimeError as e:
            return f'### First-run cost\n\nchild process failed:\n```\n{e}\n```'
    for label, r in (('cold cache (first start of an install)', cold), ('warm cache (every later start)', warm),
                     ('ROBODYN_BACKEND=numpy (no numba)', ref)):
        rows.append([label, fmt_time(r['import']), fmt_time(r['warmup']), fmt_time(r['first_run']),
                     fmt_time(r['import'] + r['warmup'] + r['first_run']), fmt_time(r.get('specialize')),
                     fmt_time(r.get('platform')), fmt_time(r.get('flyer'))])
    getattr(args, 'figures', {})['compile'] = {'cold': cold, 'warm': warm}
    return '\n'.join([
        '### First-run cost of the compiled kernels (child processes)\n',
        table(['start', 'import kernels', 'load/compile all kernels', 'first 0.1 s stanford_arm run', 'total',
               'then the same run with backend=generated (generate + compile/load)',
               'then 0.1 s of betancur_platform (constrained kernels)', 'then 0.1 s of unfried_free_flyer'], rows),
        '', 'numba caches the machine code on disk (here a temporary NUMBA_CACHE_DIR; normally '
        "`~/.cache/robodyn_ros/numba`, one directory per version of the kernels' sources), so only the first "
        'start of an install of new sources on a machine pays the compilation.'])


# ----------------------------------------------------------------------------------------------
# node (written by the node engineer)
# ----------------------------------------------------------------------------------------------
def section_node(args, names) -> str:
    """The node's figures from ``robodyn_ros.bench.node.bench_node()`` when that module exists."""
    import importlib
    try:
        node = importlib.import_module('.node', __package__)
    except ModuleNotFoundError as e:
        if e.name != f'{__package__}.node':
            raise
        return '### Node\n\nskipped: `robodyn_ros.bench.node` is not in this install yet.'
    rows = node.bench_node()
    getattr(args, 'figures', {})['node'] = rows
    if not rows:
        return '### Node\n\n(no figures)'
    header = list(rows[0])
    for r in rows[1:]:
        header += [k for k in r if k not in header]
    return '\n'.join(['### Node\n', table(header, [[r.get(k, '') for k in header] for r in rows])])


# ----------------------------------------------------------------------------------------------
# the issue's targets against the figures above
# ----------------------------------------------------------------------------------------------
def section_stiff(args, names) -> str:
    """xarm7 against MuJoCo's implicit integrators, human17 and the inductive platform (bench.stiff)."""
    from types import SimpleNamespace

    from . import stiff
    ns = SimpleNamespace(repeat=args.repeat, robots=None, skip=['robots'])
    args.figures['stiff'] = {}
    return '### Stiff robots at 1 ms\n\n' + stiff.section_mujoco(ns, args.figures['stiff']) + '\n' \
        + stiff.section_scenes(ns)


def section_targets(args, names) -> str:
    """One row per target of issue 7: the figure measured in this run, the target, met or not."""
    f = getattr(args, 'figures', {})
    rows = []

    def add(target, value, goal, met, note=''):
        rows.append([target, value, goal, '—' if met is None else ('met' if met else 'not met'), note])

    fd = f.get('fd', {})
    for name, goal in (('stanford_arm', 1.0), ('unfried_free_flyer', 1.5)):
        r = fd.get(name)
        if r and r['pin']:
            best = min(x for x in (r['compiled'], r['generated']) if x)
            add(f'forward dynamics per call, {name} / Pinocchio', f'{best / r["pin"]:.2f}', f'<= {goal}',
                best / r['pin'] <= goal, 'best of compiled and generated kernels, called from Python')
    rtf = f.get('rtf', {}).get('stanford_arm')
    kp = f.get('kernel_period', {})
    if rtf:
        floor = f' (the compiled integration alone allows at most {0.01 / kp["generated"]:.0f})' \
            if kp.get('generated') else ''
        add('headless RK4 1 kHz + MCAP joint states 100 Hz, stanford_arm', f'{rtf["wall"]:.0f} (CPU {rtf["cpu"]:.0f})',
            '>= 1000', rtf['wall'] >= 1000, f'{rtf["backend"]} kernels{floor}')
    sc = f.get('scaling', {})
    if 8 in sc and 64 in sc:
        r = [sc[64][k] / sc[8][k] for k in ('compiled', 'in-loop') if sc[8].get(k) and sc[64].get(k)]
        if r:
            add('forward dynamics, 64-link / 8-link chain', ' / '.join(f'{x:.1f}x' for x in r), '<= 10x',
                all(x <= 10 for x in r), 'compiled from Python / inside the fused loop')
    if 'augmented_ratio' in f:
        add('unfried_free_flyer augmented / minimal formulation', f'{f["augmented_ratio"]:.1f}x', '<= 5x',
            f['augmented_ratio'] <= 5, 'one right-hand-side evaluation inside the fused loop')
    for r in f.get('node', []):
        if r.get('figure') == 'real-time factor' and r.get('mode') == 'max' and r.get('publish_rate_hz') == 100.0:
            add('sim node, max mode, 100 Hz, stanford_arm', f'{r["value"]:.0f}', '>= 200', r['value'] >= 200,
                r.get('notes', ''))
    rec = f.get('recording', {})
    if rec:
        worst = min(rec, key=lambda n: rec[n]['ratio'])
        add('full recorded / integration-only RTF, every scene',
            ', '.join(f'{n} {r["ratio"]:.2f}' for n, r in rec.items()), '>= 0.5 on every scene',
            all(r['ratio'] >= 0.5 for r in rec.values()), f'lowest: {worst}; CPU time, every default topic')
        r = rec.get('stanford_arm')
        if r and r.get('mujoco'):
            add('stanford_arm full recorded RTF / MuJoCo RK4 from Python with state copied out',
                f'{r["full"] / r["mujoco"]:.2f} ({r["full"]:.0f} / {r["mujoco"]:.0f})', '>= 3',
                r['full'] / r['mujoco'] >= 3, 'CPU time, same run')
        if r:
            add('stanford_arm recorder cost per period / zstd of its bytes',
                f'{r["batched_period"] / r["zstd_period"]:.1f} ({r["batched_period"] * 1e6:.1f} µs / '
                f'{r["zstd_period"] * 1e6:.1f} µs)', 'a small multiple', None,
                f'{r["messages"]:.0f} messages per period; message by message {r["message_period"] * 1e6:.1f} µs')
    st = f.get('stiff', {})
    ours = next((v for k, v in st.items() if k.startswith('robodyn')), None)
    mj = st.get('MuJoCo implicitfast')
    if ours:
        add('xarm7 (damping only) 1 s at 1 ms: error', f'{ours[0]:.2g} rad', '<= 1e-5 rad', ours[0] <= 1e-5,
            f'MuJoCo implicitfast {mj[0]:.2g} rad' if mj else 'MuJoCo not measured')
        if mj and math.isfinite(mj[1]):
            add('xarm7 RTF / MuJoCo implicitfast from Python', f'{ours[1] / mj[1]:.2f} ({ours[1]:.0f} / {mj[1]:.0f})',
                '>= 1', ours[1] >= mj[1], 'wall time, same run, best of --repeat')
        fine = [(k, v) for k, v in st.items() if k.startswith('MuJoCo implicitfast at') and math.isfinite(v[0])]
        near = [(k, v) for k, v in fine if v[0] <= 10 * ours[0]] or fine[-1:]
        if near:
            k, v = near[0]
            add('xarm7 RTF / MuJoCo implicitfast at its first step within 10x our error',
                f'{ours[1] / v[1]:.2f} ({ours[1]:.0f} / {v[1]:.0f})', '(reported)', None,
                f'{k}: error {v[0]:.2g} rad; ours {ours[0]:.2g} rad at 1 ms')
    m = f.get('memory')
    if m:
        add(f'memory growth after warm-up ({m["duration"]:g} s recorded run)', f'{m["growth"]:+.2f} %', '< 10 %',
            m['growth'] < 10 if m['duration'] >= 3600 else None,
            f'peak RSS {m["peak"] / 1024 ** 2:.0f} MiB'
            + ('' if m['duration'] >= 3600 else '; the target is one hour (--long)'))
    if 'compile' in f:
        c = f['compile']
        add('first-run cost reported and cached', f'cold {c["cold"]["warmup"] + c["cold"]["first_run"]:.1f} s, '
            f'warm {c["warm"]["warmup"] + c["warm"]["first_run"]:.2f} s', 'reported, cached', True,
            'numba kernels and the first stanford_arm run; see the first-run table')
    if not rows:
        return '### Targets\n\n(no figures: run the other sections)'
    return '\n'.join(['### Targets against this run\n',
                      table(['target', 'measured', 'target value', 'status', 'note'], rows)])
