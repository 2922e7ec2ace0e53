"""``robodyn bench peers``: each peer row, robodyn fully recorded against MuJoCo stepped from Python on the
same URDF, with CPU and wall time, peak RSS and where robodyn's time per step goes.

Rows (the peer comparison of the speed targets; each side in its own child process, the repeats
interleaved robodyn recorded, robodyn without a recorder, MuJoCo, robodyn recorded, ...):

* ``a1_stand``: the scene's settings (rosenbrock2 at 1 ms, 200 Hz, its PD hold) against MuJoCo
  implicitfast at 1 ms with the same PD in Python at the same rate and its state copied out every period
  (:class:`~robodyn_ros.bench.contact.MujocoPD`, solref time constant ``contact.MUJOCO_TIMECONST0``);
* ``xarm7``: example-robot-data's xarm7 with damping only (:func:`~robodyn_ros.bench.stiff.damping_only`),
  ``robodyn run FILE`` defaults (integrator auto at 1 ms, 100 Hz, no command) against MuJoCo implicitfast
  at 1 ms, one ``mj_step`` per Python call (:func:`~robodyn_ros.bench.stiff.mujoco_fall`);
* ``stanford_arm``: its default settings (RK4 at 1 kHz, 100 Hz, scripted commands) against MuJoCo RK4 at
  1 ms on the exported URDF, ``mj_step(nstep)`` per period with its state copied out
  (:func:`~robodyn_ros.bench.references.mujoco_recorded_loop`).

robodyn runs as ``robodyn run SCENE --record OUT.mcap`` does (the default backend, auto: the generic
kernels, then the model's generated code once a child process has compiled it after
``kernels.GENERATE_AFTER`` s of integration; a tree on a ground stays generic), every default topic
recorded. The report says which kernels each run ended on. CPU and wall seconds cover the run (the
scene loading and the imports are not in them); peak RSS is the child process's ``ru_maxrss`` (imports,
scene, the run). Figures are medians of ``--repeat`` interleaved runs.

The split of robodyn's recorded run per integration step (µs), derived by subtraction from whole runs:
``dynamics`` the tree dynamics evaluations the run did, timed alone in a compiled loop at the run's
final state on the kernels it ended on (rk4: four forward dynamics per step; rosenbrock2: the bias/mass
pass and one forward dynamics per step; on a ground the contact path's: the kinematics ``kin``, then ABA
``fdx`` or the bias/mass pass ``bmx`` under the contacts' forces); ``contact`` (a1_stand) the ground's forces
and Jacobian of a step (the points' forces twice, their Jacobian, the touching count: the kinematics they
read taken off), timed alone the same way; ``integrator`` the rest of the compiled integration: CPU time inside the
integration calls (``Simulator.advance``, the block path's ``fused_periods``) of the run without a
recorder, minus dynamics and contact; ``other`` that run's remaining CPU (the loop's Python, the outputs);
``recording`` the recorded run minus the run without a recorder (the sink, and the outputs only it asks
for: joint and contact wrenches; and the CPU the recorded run's second thread costs: it computes the next
blocks while the recorder writes, ``robodyn_ros.blocks``). A part that comes out negative (noise between
runs) is shown as 0. The clocks around calls are per thread (``time.thread_time``).
"""
from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
import warnings

import numpy as np

from .timing import machine_line, peak_rss_bytes, rss_bytes, table

HELP = 'peer rows (a1_stand, xarm7, stanford_arm) recorded vs MuJoCo: CPU, wall, peak RSS, split per step'
#: the rows, in report order, and their default simulated seconds (long enough for backend auto to have
#: switched where it does: 0.5 s of integration on the generic kernels is ~40 s of stanford_arm, ~70 s of xarm7)
ROWS = {'a1_stand': 20.0, 'xarm7': 120.0, 'stanford_arm': 300.0}
#: the parts of the split, in report order
PARTS = ('dynamics', 'contact', 'integrator', 'other', 'recording')
#: evaluations per batch of the compiled timing loops of the split
EVALS = 20000


def add_arguments(p):
    """Options of ``robodyn bench peers``."""
    p.add_argument('--out', default=None, help='also write the markdown report to this file')
    p.add_argument('--rows', nargs='*', default=list(ROWS), choices=list(ROWS), help='rows to run (default: all)')
    p.add_argument('--duration', type=float, default=None,
                   help='simulated seconds of every row (default: ' + ', '.join(f'{k} {v:g}' for k, v in ROWS.items())
                        + ')')
    p.add_argument('--repeat', type=int, default=3, help='interleaved runs of each side (median; default 3)')
    p.add_argument('--keep', default=None, help='directory to keep the rows\' recordings in (default: none kept)')


def main(args) -> int:
    """Run the rows and print (and optionally write) the markdown report."""
    start = machine_line()
    rows = measure(args.rows, args.duration, args.repeat, args.keep)
    text = report(rows, args.repeat, start)
    print(text)
    if args.out:
        with open(args.out, 'w', encoding='utf-8') as f:
            f.write(text)
    return 0


# ------------------------------------------------------------------------------------------------
# the child processes
# ------------------------------------------------------------------------------------------------
def _spawn(job: dict) -> dict:
    """Run ``child(job)`` in a new Python process; its result dict (RuntimeError with its stderr on failure)."""
    code = 'import json, sys; from robodyn_ros.bench.peers import child; print(json.dumps(child(json.loads(sys.argv[1]))))'
    r = subprocess.run([sys.executable, '-c', code, json.dumps(job)], capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f'{job["row"]} {job["side"]}: child failed:\n{r.stderr[-3000:]}')
    return json.loads(r.stdout.strip().splitlines()[-1])


def child(job: dict) -> dict:
    """One side of a row in this (child) process: ``job = {'row', 'side', 'duration', 'path'}``; side
    'full' (robodyn recorded to path), 'none' (robodyn without a recorder, then the dynamics and contact
    timed alone), 'mujoco' or 'prime' (the row's generated code compiled into the cache)."""
    warnings.simplefilter('ignore')
    from ..kernels import jit
    jit.set_mode('interpret')   # as robodyn run: a kernel missing from the cache runs as Python meanwhile
    if job['side'] == 'mujoco':
        out = _mujoco(job['row'], job['duration'])
    elif job['side'] == 'prime':
        out = _prime(job['row'])
    else:
        out = _ours(job['row'], job['duration'], job['side'], job.get('path'))
    out['peak_rss'] = peak_rss_bytes()
    return out


def row_scene(row: str):
    """The row's scene as ``robodyn run`` loads it (default backend), and for xarm7 its URDF text."""
    from ..scene import load_scene
    from ..systems.base import backend_scope, tools_backend
    if row == 'xarm7':
        from .stiff import _load_urdf, damping_only, erd_urdfs
        files = erd_urdfs(['xarm7'])
        if not files:
            raise RuntimeError('example-robot-data is not installed')
        with open(files[0]) as f:
            text = damping_only(f.read())
        return _load_urdf(files[0], text=text), text
    with backend_scope(tools_backend()):
        return load_scene(row), None


def _prime(row: str) -> dict:
    """Compile (or find) the row's generated code in the kernels' cache, as backend auto's child would."""
    from ..kernels import codegen
    scene, _ = row_scene(row)
    km = scene.system._km
    if km is None or km.coupled is not None:
        return {'generated': False}
    ground = getattr(scene.system, 'contact', None) is not None   # (a tree on a ground: its contact path's code)
    return {'generated': codegen.specialize(km.model, ground=ground) is not None}


class _Clock:
    """CPU seconds spent inside the wrapped callables (``wrap(obj, name)`` replaces an instance attribute)."""

    def __init__(self):
        self.cpu = 0.0
        self.calls = 0

    def wrap(self, obj, name):
        f = getattr(obj, name)
        clock = time.thread_time   # (the block path computes ahead on a second thread)

        def timed(*a, **k):
            c0 = clock()
            try:
                return f(*a, **k)
            finally:
                self.cpu += clock() - c0
                self.calls += 1
        setattr(obj, name, timed)


def _ours(row: str, duration: float, side: str, path) -> dict:
    """robodyn's run of the row (after a short warm-up run in this process, on its own scene): CPU and wall
    seconds, steps, the kernels it ended on, the CPU inside its integration calls (side 'none') or inside
    its sink (side 'full'), and for side 'none' the dynamics and contact per step timed alone."""
    _run(row, min(duration, 0.05), side, None if path is None else path + '.warm')   # compiled code loaded
    r = _run(row, duration, side, path)
    if path is not None and os.path.exists(path + '.warm'):
        os.remove(path + '.warm')
    if side == 'none':
        r.update(split_timings(r.pop('sim')))
    else:
        r.pop('sim')
    return r


def _run(row, duration, side, path) -> dict:
    """One run of the row as ``robodyn run`` makes it (side 'full': recorded to path; 'none': no sink)."""
    from ..recording.run_sink import HEADLESS_BATCH, McapRunSink
    from ..runs import DIAGNOSTICS_PERIOD, plan_run, resolve_settings
    from ..simulation import Simulator, run_headless
    from ..systems.base import recorded_backend, tools_backend
    scene, _ = row_scene(row)
    st = resolve_settings(scene, duration=duration)
    st['backend'] = recorded_backend(tools_backend())
    plan, st = plan_run(st, scene.system, scene.y0)
    sim = Simulator(scene.system, scene.y0, plan=plan)
    integ, sink_clock, start = _Clock(), _Clock(), _Clock()
    integ.wrap(sim, 'advance')
    if getattr(scene.system, 'fused_periods', None) is not None:
        integ.wrap(scene.system, 'fused_periods')
    sinks = []
    if side == 'full':
        if os.path.exists(path):
            os.remove(path)
        sink = McapRunSink(path, scene, {**st, 'mode': 'headless'}, record_wrenches=True, record_tf=True,
                           diagnostics_period=DIAGNOSTICS_PERIOD, batch=HEADLESS_BATCH, embed_meshes=True)
        start.wrap(sink, 'on_start')
        for name in ('on_command', 'on_output', 'on_block', 'block_periods', 'close'):
            sink_clock.wrap(sink, name)
        sinks.append(sink)
    rss = rss_bytes()
    w0, c0 = time.perf_counter(), time.process_time()
    try:
        run_headless(sim, st['duration'], st['rate'], scene.script, sinks, stop=scene.stop)
    finally:
        for s in sinks:
            s.close()
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    km = getattr(scene.system, '_km', None)
    ended = 'generated' if km is not None and km.gen is not None else 'generic'
    return {'cpu': cpu, 'wall': wall, 'steps': int(sim.diag.steps), 'rhs_evals': int(sim.diag.rhs_evals),
            'method': sim.settings['integrator'], 'dt': sim.settings.get('dt'), 'rate': st['rate'], 't': sim.t,
            'kernels': ended, 'generic_s': float(getattr(km, '_spent', 0.0)) if km is not None else 0.0,
            'integrating_cpu': integ.cpu, 'sink_cpu': sink_clock.cpu + start.cpu, 'sink_start_cpu': start.cpu,
            'messages': sum(getattr(s, 'count', 0) for s in sinks), 'rss_before': rss, 'sim': sim}


# ------------------------------------------------------------------------------------------------
# the dynamics and the contact of a step, timed alone (compiled loops)
# ------------------------------------------------------------------------------------------------
_LOOPS = []


def _loops():
    """``(fd_loop, bm_loop, contact_loop)``: compiled loops that call the dynamics at their addresses
    (:mod:`robodyn_ros.kernels.treefn`) n times (on a ground, ``kin`` then ``fdx`` or ``bmx``: the contact path's),
    and a ground's per-step contact code n times (``on`` False: the kinematics alone, which the dynamics
    also compute, to be taken off)."""
    if _LOOPS:
        return _LOOPS
    from numba import njit

    from ..kernels.contact import contact_jacobian_add, ground_fext_ws, touching_points
    from ..kernels.tree import transforms, world_kinematics_ws
    from ..kernels.treefn import bm_at, bmx_at, fd_at, fdx_at, kin_at

    @njit(cache=True, error_model='numpy')
    def fd_loop(dyn, ground, mi, mf, q, v, tau, fx, qdd, W, n):
        for _ in range(n):
            if ground:
                kin_at(dyn[3])(mi, mf, q, v, W)
                fdx_at(dyn[4])(mi, mf, q, v, tau, fx, qdd, W)
            else:
                fd_at(dyn[0])(mi, mf, q, v, tau, qdd, W)

    @njit(cache=True, error_model='numpy')
    def bm_loop(dyn, ground, mi, mf, q, v, zero, fx, bias, H, G, W, n):
        for _ in range(n):
            if ground:
                kin_at(dyn[3])(mi, mf, q, v, W)
                bmx_at(dyn[5])(mi, mf, q, v, zero, fx, bias, H, G, W)
            else:
                bm_at(dyn[1])(mi, mf, q, v, zero, bias, H, G, W)

    @njit(cache=True, error_model='numpy')
    def contact_loop(con, mi, mf, q, v, fx, Dc, Kc, J, cols, W, n, on):
        for _ in range(n):   # arm_rosenbrock_step on a ground: contact_bias_mass, arm_rhs, contact_stage_jacobian
            transforms(mi, mf, q, W)
            world_kinematics_ws(mi, mf, v, W)
            if on:
                ground_fext_ws(con, W, fx)
                contact_jacobian_add(con, mi, mf, W, Dc, Kc, J, cols)
            world_kinematics_ws(mi, mf, v, W)
            if on:
                ground_fext_ws(con, W, fx)
                touching_points(con, W)
    _LOOPS.extend((fd_loop, bm_loop, contact_loop))
    return _LOOPS


def _per_eval(fn, n=EVALS, repeat=5) -> float:
    """CPU seconds per evaluation of ``fn(n)`` (a compiled loop of n evaluations), best of repeat."""
    fn(1)
    best = float('inf')
    for _ in range(repeat):
        c0 = time.process_time()
        fn(n)
        best = min(best, (time.process_time() - c0) / n)
    return best


def split_timings(sim) -> dict:
    """Dynamics and contact CPU seconds per step of the run sim made, timed alone at its final state on the
    kernels it ended on (module docstring): ``{'dyn_step', 'contact_step', 'fd', 'bm'}``."""
    from ..kernels import tree
    s = sim.system
    km = s._km
    nv = s.nv
    fd_loop, bm_loop, contact_loop = _loops()
    q = np.ascontiguousarray(sim.y[:s.nq])
    v = np.ascontiguousarray(sim.y[s.nq:s.nq + nv])
    dyn, _ = km.dynamics(sim.y)
    ground = km.con is not None
    W = tree.workspace(km.mi_r.shape[0])
    tau, zero, out = np.zeros(nv), np.zeros(nv), np.empty(nv)
    H, G = np.empty((nv, nv)), np.empty((nv, nv))
    fx = np.zeros((km.mi_r.shape[0], 6))
    t_fd = _per_eval(lambda n: fd_loop(dyn, ground, km.mi_r, km.mf_r, q, v, tau, fx, out, W, n))
    t_bm = _per_eval(lambda n: bm_loop(dyn, ground, km.mi_r, km.mf_r, q, v, zero, fx, out, H, G, W, n))
    steps = max(sim.diag.steps, 1)
    method = sim.settings['integrator']
    if method == 'rosenbrock2':   # per step: the bias/mass pass at z_n, one ABA at the stage point
        dyn = (sim.diag.rhs_evals / 2) * (t_fd + t_bm) / steps
    else:
        dyn = sim.diag.rhs_evals * t_fd / steps
    contact = 0.0
    if ground:
        Dc, Kc = np.zeros((nv, nv)), np.zeros((nv, nv))
        J, cols = np.empty((3, nv)), np.empty(nv, dtype=np.int64)

        def loop(on):
            return lambda n: contact_loop(km.con, km.mi_r, km.mf_r, q, v, fx, Dc, Kc, J, cols, W, n, on)
        contact = max(_per_eval(loop(True)) - _per_eval(loop(False)), 0.0)
    return {'dyn_step': dyn, 'contact_step': contact, 'fd': t_fd, 'bm': t_bm}


# ------------------------------------------------------------------------------------------------
# MuJoCo
# ------------------------------------------------------------------------------------------------
def _mujoco(row: str, duration: float) -> dict:
    """MuJoCo's side of the row (module docstring), after a short warm-up: CPU and wall seconds."""
    from .contact import MUJOCO_TIMECONST0, MujocoPD, mujoco_ground_model, urdf_path
    from .references import mujoco_model, mujoco_recorded_loop
    from .stiff import mujoco_fall
    scene, text = row_scene(row)
    s = scene.system
    if row == 'a1_stand':
        m, why = mujoco_ground_model(urdf_path(scene), s.contact.ground.friction, MUJOCO_TIMECONST0)
        if m is None:
            return {'why': why}
        pd = MujocoPD(m, scene)

        def run(d):
            pd.run(d, copy_state=True)
        what = 'implicitfast 1 ms, PD in Python at 200 Hz, state copied out'
    elif row == 'xarm7':
        names, q0 = list(s.joint_names), scene.y0[:s.nq]
        r = mujoco_fall(text, names, 'implicitfast', q0, repeat=1, horizon=min(duration, 0.05), cpu=True)
        if r[0] is None:
            return {'why': r[1]}
        rss = rss_bytes()
        r = mujoco_fall(text, names, 'implicitfast', q0, repeat=1, horizon=duration, cpu=True)
        return {'cpu': r[2], 'wall': r[1], 'rss_before': rss,
                'what': 'implicitfast 1 ms, mj_step per call, qpos read at 100 Hz'}
    else:
        from ..model import to_urdf
        m, why = mujoco_model(to_urdf(s.model))
        if m is None:
            return {'why': why}
        q0, v0 = scene.y0[:s.nq], scene.y0[s.nq:]

        def run(d):
            mujoco_recorded_loop(m, q0, v0, d)
        what = 'RK4 1 ms, mj_step(10) per period, state copied out'
    run(min(duration, 0.05))
    rss = rss_bytes()
    w0, c0 = time.perf_counter(), time.process_time()
    run(duration)
    return {'cpu': time.process_time() - c0, 'wall': time.perf_counter() - w0, 'rss_before': rss, 'what': what}


# ------------------------------------------------------------------------------------------------
# the table
# ------------------------------------------------------------------------------------------------
def measure(rows, duration=None, repeat=3, keep=None) -> dict:
    """``{row: figures}`` (:func:`row_figures`) of the rows, their children interleaved per repeat."""
    with tempfile.TemporaryDirectory() as tmp:
        out_dir = keep or tmp
        os.makedirs(out_dir, exist_ok=True)
        runs = {r: {'full': [], 'none': [], 'mujoco': []} for r in rows}
        for r in rows:
            _spawn({'row': r, 'side': 'prime', 'duration': 0.0})
        for i in range(repeat):
            for r in rows:
                d = ROWS[r] if duration is None else duration
                path = os.path.join(out_dir, f'{r}.mcap')
                for side in ('full', 'none', 'mujoco'):
                    runs[r][side].append(_spawn({'row': r, 'side': side, 'duration': d, 'path': path}))
        return {r: row_figures(runs[r], os.path.join(keep, f'{r}.mcap') if keep else None) for r in rows}


def row_figures(runs: dict, recording=None) -> dict:
    """A row's figures from its children's results: medians of CPU, wall and peak RSS per side, the ratio
    of real-time factors (ours / MuJoCo) and the split per step (µs; :data:`PARTS`, and ``whole``)."""
    def med(side, key):
        vals = [x[key] for x in runs[side] if x.get(key) is not None]
        return statistics.median(vals) if vals else None
    full, none = runs['full'], runs['none']
    steps = full[0]['steps']
    whole = med('full', 'cpu') / steps
    n_cpu = statistics.median(x['cpu'] for x in none) / steps
    integ = statistics.median(x['integrating_cpu'] for x in none) / steps
    dyn = statistics.median(x['dyn_step'] for x in none)
    con = statistics.median(x['contact_step'] for x in none)
    raw = {'dynamics': dyn, 'contact': con, 'integrator': integ - dyn - con, 'other': n_cpu - integ,
           'recording': whole - n_cpu}
    split = {k: max(v, 0.0) * 1e6 for k, v in raw.items()}
    mj_cpu, mj_wall = med('mujoco', 'cpu'), med('mujoco', 'wall')
    cpu, wall = med('full', 'cpu'), med('full', 'wall')
    # each repeat's own ratio (its two children ran minutes apart at most): the machine's speed drifting
    # between repeats, which moves both medians, cancels in it
    pairs = [m['cpu'] / f['cpu'] for f, m in zip(full, runs['mujoco']) if m.get('cpu') and f.get('cpu')]
    pairs_wall = [m['wall'] / f['wall'] for f, m in zip(full, runs['mujoco']) if m.get('wall') and f.get('wall')]
    # the simulation alone: the same repeat's run without a recorder (MuJoCo's side records nothing either)
    pairs_none = [m['cpu'] / n['cpu'] for n, m in zip(none, runs['mujoco']) if m.get('cpu') and n.get('cpu')]
    return {'duration': full[0]['t'], 'method': full[0]['method'], 'dt': full[0]['dt'], 'rate': full[0]['rate'],
            'steps': steps, 'kernels': [x['kernels'] for x in full], 'generic_s': med('full', 'generic_s'),
            'cpu': cpu, 'wall': wall, 'rss': med('full', 'peak_rss'), 'rss_before': med('full', 'rss_before'),
            'messages': full[0]['messages'],
            'sink_cpu': med('full', 'sink_cpu'), 'sink_start_cpu': med('full', 'sink_start_cpu'),
            'none_cpu': statistics.median(x['cpu'] for x in none),
            'mujoco_cpu': mj_cpu, 'mujoco_wall': mj_wall, 'mujoco_rss': med('mujoco', 'peak_rss'),
            'mujoco_rss_before': med('mujoco', 'rss_before'),
            'mujoco_what': runs['mujoco'][0].get('what', runs['mujoco'][0].get('why')),
            'ratio_cpu': mj_cpu / cpu if mj_cpu else None, 'ratio_wall': mj_wall / wall if mj_wall else None,
            'ratio_pairs': pairs, 'ratio_pairs_wall': pairs_wall, 'ratio_pairs_none': pairs_none,
            'split': split, 'whole': whole * 1e6, 'fd': statistics.median(x['fd'] for x in none),
            'bm': statistics.median(x['bm'] for x in none), 'recording': recording}


def _computes_ahead() -> bool:
    """Whether the children's recorded runs compute their next blocks ahead (``blocks.PIPELINE``, from the
    environment they inherit)."""
    from .. import blocks
    return blocks.PIPELINE


def _pairs(r) -> str:
    """Each repeat's ratios as 'median (range)'."""
    return '—' if not r else f'×{statistics.median(r):.2f} (×{min(r):.2f}–{max(r):.2f})'


def report(rows: dict, repeat: int, start: str | None = None) -> str:
    """The markdown of :func:`measure`'s rows; start: the machine line (load average) before they ran."""
    mb = 1024.0 ** 2
    head = ['row', 'robodyn (kernels at the end)', 'robodyn CPU / wall s', 'RTF (CPU)', 'peak RSS (before the run)',
            'MuJoCo', 'MuJoCo CPU / wall s', 'RTF (CPU)', 'peak RSS (before the run)',
            'ratio robodyn / MuJoCo (CPU; wall)', 'ratio of each repeat (CPU): median (range)',
            'ratio of each repeat (wall): median (range)', 'without the recording (CPU), each repeat']
    main_rows, split_rows = [], []
    for name, f in rows.items():
        kernels = ', '.join(sorted(set(f['kernels'])))
        main_rows.append([
            f'`{name}`, {f["duration"]:g} s', f'{f["method"]} {f["dt"] * 1e3:g} ms, {f["rate"]:g} Hz, every topic '
            f'({f["messages"]} messages); {kernels} (generic for {f["generic_s"]:.2f} s)',
            f'{f["cpu"]:.3f} / {f["wall"]:.3f}', f'{f["duration"] / f["cpu"]:.0f}',
            f'{f["rss"] / mb:.0f} MiB ({f["rss_before"] / mb:.0f})',
            f['mujoco_what'], '—' if f['mujoco_cpu'] is None else f'{f["mujoco_cpu"]:.3f} / {f["mujoco_wall"]:.3f}',
            '—' if f['mujoco_cpu'] is None else f'{f["duration"] / f["mujoco_cpu"]:.0f}',
            '—' if f['mujoco_rss'] is None else f'{f["mujoco_rss"] / mb:.0f} MiB ({f["mujoco_rss_before"] / mb:.0f})',
            '—' if f['ratio_cpu'] is None else f'×{f["ratio_cpu"]:.2f}; ×{f["ratio_wall"]:.2f}',
            _pairs(f['ratio_pairs']), _pairs(f.get('ratio_pairs_wall')), _pairs(f.get('ratio_pairs_none'))])
        sp = f['split']
        split_rows.append([f'`{name}`', f'{f["whole"]:.2f}'] + [f'{sp[k]:.2f}' for k in PARTS]
                          + [f'{sum(sp.values()):.2f}', f'{f["fd"] * 1e6:.2f} / {f["bm"] * 1e6:.2f}',
                             f'{f["sink_cpu"] / f["steps"] * 1e6:.2f} (start {f["sink_start_cpu"]:.2f} s)'])
    return '\n'.join([
        '# Peers: robodyn fully recorded against MuJoCo from Python', '',
        f'`robodyn bench peers` (`make bench`). At the end: {machine_line()}'
        + (f'. At the start: {start.split(";")[0]}.' if start else '.'), '',
        f'Medians of {repeat} interleaved runs per side, each in its own child process; CPU and wall seconds of '
        'the run alone (no imports, no scene loading); peak RSS: the child process\'s ru_maxrss, and in brackets '
        'its resident set just before the timed run (imports, scene, a short warm-up run). The MuJoCo child loads '
        'robodyn\'s scene too (the URDF, initial state and PD gains it is set up from), so its RSS includes '
        'robodyn\'s imports (numba): MuJoCo\'s own share is roughly the peak minus the bracket. RTF: simulated '
        '/ CPU seconds. Ratio: robodyn\'s real-time factor over MuJoCo\'s (> 1: robodyn faster), from the medians '
        'of each side; the two columns after it take the ratio within each repeat (its robodyn and MuJoCo '
        'children run seconds apart), so that the machine\'s speed drifting between repeats cancels, and give '
        'their median and range. The last column compares the simulation alone, the same way: the same repeat\'s '
        'robodyn run without a recorder (its CPU seconds: the same steps, no sink, one thread) against the MuJoCo '
        'run, which records nothing either. ' + (
            'The recorded run computes its next blocks of periods on a second thread while the recorder writes '
            '(the block path computing ahead): its CPU time counts both threads, and its wall time is less.'
            if _computes_ahead() else
            'Computing ahead was off (`ROBODYN_PIPELINE=0`): every run on one thread.'), '',
        table(head, main_rows), '',
        '## Where robodyn\'s recorded run spends its time, per integration step (µs of CPU)', '',
        table(['row', 'whole (recorded run)'] + list(PARTS) + ['sum of parts', 'fd / bm per call',
                                                                'the sink alone (its start: robot_description)'],
              split_rows), '',
        'Derived by subtraction from whole runs, not instrumented inside the compiled loop: *dynamics* is the '
        'tree dynamics evaluations the run did (rk4: 4 forward dynamics per step; rosenbrock2: the bias/mass '
        'pass and one forward dynamics per step), each timed alone in a compiled loop at the run\'s final state '
        'on the kernels the run ended on (on a ground, the contact path\'s: the kinematics, then ABA or the '
        'bias/mass pass under the contacts\' forces); *contact* the ground\'s per-step forces and Jacobian '
        'timed alone the same way (the points\' forces twice, their Jacobian, the touching count; minus the '
        'kinematics they read, which the dynamics compute); *integrator* the CPU time inside the '
        'integration calls of a run without a recorder (`Simulator.advance`, the block path\'s compiled '
        '`fused_periods`) minus dynamics and contact; *other* the rest of that run (the loop\'s Python, the '
        'outputs); *recording* the recorded run minus the run without a recorder (the sink, and the outputs '
        'only it asks for: joint and contact wrenches). Each is a median over the runs; a part that comes out '
        'negative is shown as 0, so the sum of parts may differ from the whole by the noise between runs. '
        '"the sink alone": CPU time inside the recorder\'s calls in the recorded run (of the thread making them), '
        'the robot_description (meshes embedded) written at its start included. The run without a recorder '
        'runs on one thread (with nothing to overlap, the block path does not compute ahead), so *recording* '
        'includes what computing ahead costs in CPU.', ''])
