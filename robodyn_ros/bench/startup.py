"""``robodyn bench startup``: how long a run takes before and around its simulation.

Every figure is a whole process (``robodyn ...`` as a user types it, or a peer's script), timed
from the outside: wall time, CPU time (user + system) and peak resident memory of that process
(``getrusage(RUSAGE_CHILDREN)`` in a bare interpreter that starts it), median of ``--repeat``
where a row says so. "beyond the simulation" is the process's wall time minus the simulation's
own (the ``simulated ... in X s wall`` of the run summary): importing, building the robot,
loading (or compiling) the kernels, exiting; its CPU form subtracts the run's CPU time.

Sections (each can be skipped with ``--skip``):

* ``commands``  ``robodyn --help``; a short run (``robodyn run stanford_arm --duration 0.01``,
  without and with ``--record``) with the kernels' cache filled, beside the floor it stands on
  (the interpreter, numpy, numba and its first call of a cached function);
* ``scenes``    the first run of every bundled scene (its own duration) after ``robodyn warm``;
* ``urdf``      the first ``robodyn run FILE --duration 0.2`` of every example-robot-data URDF
  after ``robodyn warm`` (the robot never ran before; test extras);
* ``cold``      a fresh install (an empty cache directory): ``robodyn warm`` as ``make test`` runs
  it, again once filled, and without it the first runs that compile: a scene, a URDF robot,
  then another robot in the same cache;
* ``generated`` the per-model backend against the generic one: RK4 cost per 10 ms period (CPU,
  in this process), the generation and compilation of each model (a child with empty caches),
  and the simulated time after which it has paid for itself;
* ``peers``     the same 0.2 s of a robot as whole processes in MuJoCo (``MjModel.from_xml_path`` +
  RK4 steps) and Pinocchio (``buildModelFromUrdf`` + a Python RK4 loop over ``aba``), on the URDF
  our importer exports for it (no meshes), beside ``robodyn run`` of the original file;
* ``targets``   the start-up targets against the figures above.

The children run without ``PYTHONDONTWRITEBYTECODE`` (Python's bytecode cache is in use, as on
any install) and without ``ROBODYN_BACKEND`` (the default kernels). Figures to read, never
asserted by tests.
"""
from __future__ import annotations

import json
import os
import re
import statistics
import subprocess
import sys
import tempfile

HELP = 'start-up of robodyn --help, short and first runs (warm and fresh cache) vs MuJoCo/Pinocchio'
SECTIONS = ('commands', 'scenes', 'urdf', 'cold', 'generated', 'peers', 'targets')
#: simulated seconds of a URDF robot's first run (the issue's "first 0.2 s")
URDF_DURATION = 0.2
#: robots of the cold, generated and peers sections (example-robot-data stems), when installed
COLD_ROBOTS = ('go2', 'g1_29dof_rev_1_0')
GENERATED_MODELS = ('stanford_arm', 'huston_p19_4_1', 'go2', 'human')
PEER_ROBOTS = ('go2', 'g1_29dof_rev_1_0')
_SIM = re.compile(r'simulated ([0-9.]+) s in ([0-9.]+) s wall')
_SIM_CPU = re.compile(r' ([0-9.]+) s CPU\)')


def add_arguments(p):
    """Options of the start-up benchmark."""
    p.add_argument('--out', default=None, help='also write the markdown report to this file')
    p.add_argument('--repeat', type=int, default=5, help='runs per figure of the commands section (median; default 5)')
    p.add_argument('--robots', nargs='*', default=None,
                   help='example-robot-data URDF stems for the urdf section (default: all)')
    p.add_argument('--quick', action='store_true', help='3 repeats, 4 robots, no cold compile of everything')
    p.add_argument('--skip', nargs='*', default=[], choices=SECTIONS, help='sections to leave out')
    return p


def main(args) -> int:
    """Run the sections, print the markdown report, optionally write it to ``--out``."""
    from .timing import machine_line
    if args.quick:
        args.repeat = min(args.repeat, 3)
        args.robots = args.robots or ['so100', 'ur5_robot', 'go2', 'human']
    argv = ' '.join(([f'--robots {" ".join(args.robots)}'] if args.robots else [])
                    + (['--quick'] if args.quick else []) + ([f'--skip {" ".join(args.skip)}'] if args.skip else []))
    parts = [f'## robodyn bench startup\n\nCommand: `robodyn bench startup {argv}`'.rstrip()
             + f'  \nMachine: {machine_line()}\n']
    print(parts[0], flush=True)
    args.figures = {}
    warm = measure(robodyn('warm', '--quiet'))   # the state every warm figure below is measured in
    if warm['rc'] != 0:
        raise SystemExit(f'robodyn bench startup: robodyn warm failed:\n{warm["stderr"][-2000:]}')
    args.figures['warm_filled'] = warm
    for s in SECTIONS:
        if s not in args.skip:
            text = globals()[f'section_{s}'](args)
            parts.append(text)
            print(text + '\n', flush=True)
    if args.out:
        with open(args.out, 'w') as f:
            f.write('\n\n'.join(parts) + '\n')
    return 0


# ----------------------------------------------------------------------------------------------
# whole processes
# ----------------------------------------------------------------------------------------------
def child_env(**extra) -> dict:
    """The environment of a measured child: this one without ``PYTHONDONTWRITEBYTECODE`` and
    ``ROBODYN_BACKEND`` (and without ``OPENBLAS_THREAD_TIMEOUT`` when importing robodyn_ros set it: a
    robodyn child sets it again itself, a peer's runs as its users run it), plus ``extra`` (a value of
    None removes the variable)."""
    import robodyn_ros
    drop = ('PYTHONDONTWRITEBYTECODE', 'ROBODYN_BACKEND')
    if robodyn_ros.SET_BLAS_TIMEOUT:
        drop += ('OPENBLAS_THREAD_TIMEOUT',)
    env = {k: v for k, v in os.environ.items() if k not in drop}
    for k, v in extra.items():
        if v is None:
            env.pop(k, None)
        else:
            env[k] = str(v)
    return env


def robodyn(*argv) -> list:
    """The command line of ``robodyn ARGV`` (the console script beside this interpreter)."""
    exe = os.path.join(os.path.dirname(sys.executable), 'robodyn')
    return [exe, *argv] if os.path.exists(exe) else [sys.executable, '-m', 'robodyn_ros.cli', *argv]


#: the child that starts each measured process: a bare interpreter (``-S -E``, the standard library
#: only), so that the measured process's peak RSS is its own (Linux carries the RSS of the process
#: that starts another over into the new program's peak: this benchmark's own, hundreds of MiB)
_RUNNER = r'''
import json, os, subprocess, sys, time
a = json.loads(sys.stdin.read())
t0 = time.perf_counter()
p = subprocess.Popen(a['cmd'], stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=a['env'])
out, err = p.communicate(timeout=a['timeout'])
wall = time.perf_counter() - t0
ru = __import__('resource').getrusage(__import__('resource').RUSAGE_CHILDREN)
print(json.dumps({'wall': wall, 'cpu': ru.ru_utime + ru.ru_stime, 'rss': ru.ru_maxrss * 1024, 'rc': p.returncode,
                  'stdout': out.decode(errors='replace'), 'stderr': err.decode(errors='replace')}))
'''


def measure(cmd, env=None, timeout=1800) -> dict:
    """Run ``cmd`` as a new process and time it from the outside (through :data:`_RUNNER`).

    Returns ``{'wall', 'cpu' (user + system), 'rss' (peak, bytes), 'rc', 'stdout', 'stderr',
    'simulated', 'sim_wall', 'sim_cpu'}``; the last three parsed from a robodyn run summary (None
    otherwise).
    """
    arg = json.dumps({'cmd': list(cmd), 'env': child_env() if env is None else env, 'timeout': timeout})
    r = subprocess.run([sys.executable, '-S', '-E', '-c', _RUNNER], input=arg, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f'measuring {cmd}: {r.stderr[-2000:]}')
    out = json.loads(r.stdout)
    m, c = _SIM.search(out['stdout']), _SIM_CPU.search(out['stdout'])
    out['simulated'], out['sim_wall'] = (float(m.group(1)), float(m.group(2))) if m else (None, None)
    out['sim_cpu'] = float(c.group(1)) if m and c else None
    return out


def compiler_children() -> list:
    """The pids of the compiler children running on this machine (``python -m robodyn_ros.kernels.jit``, which a
    first run leaves compiling after it ends), read from ``/proc``."""
    pids = []
    for name in os.listdir('/proc') if os.path.isdir('/proc') else ():
        if name.isdigit():
            try:
                with open(f'/proc/{name}/cmdline', 'rb') as f:
                    args = f.read().split(b'\0')
            except OSError:
                continue
            if b'robodyn_ros.kernels.jit' in args:
                pids.append(int(name))
    return pids


def wait_for_compilers(timeout: float = 900.0) -> float:
    """Wait until no compiler child runs (the earlier first runs' children compile on after their runs end, and
    would take a core from the next run measured); returns the seconds waited."""
    import time
    t0 = time.monotonic()
    while compiler_children() and time.monotonic() - t0 < timeout:
        time.sleep(0.5)
    return time.monotonic() - t0


def median_of(cmd, n, env=None) -> dict:
    """:func:`measure` ``n`` times: the median wall, CPU and peak RSS (and the first run's output)."""
    runs = [measure(cmd, env) for _ in range(max(1, n))]
    out = dict(runs[0])
    for k in ('wall', 'cpu', 'rss'):
        out[k] = statistics.median(r[k] for r in runs)
    out['min_wall'] = min(r['wall'] for r in runs)
    out['n'] = len(runs)
    return out


def beyond(r) -> float | None:
    """Wall seconds of a run outside its simulation (None when it did not simulate)."""
    return None if r['sim_wall'] is None else r['wall'] - r['sim_wall']


def beyond_cpu(r) -> float | None:
    """CPU seconds of a run outside its simulation (None when it did not simulate): the wall figure
    of a machine whose cores are free (on a loaded one the wall figure includes waiting)."""
    return None if r.get('sim_cpu') is None else r['cpu'] - r['sim_cpu']


def _s(x, digits=2) -> str:
    return '—' if x is None else f'{x:.{digits}f} s'


def _mib(b) -> str:
    return f'{b / 1024 ** 2:.0f} MiB'


def _verdict(r) -> str:
    if r['sim_wall'] is not None:
        return 'ran'
    last = (r['stderr'].strip().splitlines() or ['?'])[-1]
    return 'refused: ' + ('stiff at the default step' if 'unstable for this system' in last else last[-120:])


def _table(header, rows) -> str:
    from .timing import table
    return table(header, rows)


# ----------------------------------------------------------------------------------------------
# sections
# ----------------------------------------------------------------------------------------------
_FLOOR = ('import numba\n'
          '@numba.njit(cache=True)\n'
          'def f(x):\n'
          '    return x + 1.0\n'
          'f(1.0)\n')


def section_commands(args) -> str:
    """``robodyn --help`` and a short run, with the interpreter/numpy/numba floor beside them."""
    n = args.repeat
    with tempfile.TemporaryDirectory() as d:
        floor_file = os.path.join(d, 'floor.py')
        with open(floor_file, 'w') as f:
            f.write(_FLOOR)
        measure([sys.executable, floor_file])   # its cache, once
        rows = [('`python -c pass`', [sys.executable, '-c', 'pass']),
                ('`python -c "import numpy"`', [sys.executable, '-c', 'import numpy']),
                ('`import numba` and one call of a cached function (the floor of a compiled run)',
                 [sys.executable, floor_file]),
                ('`robodyn --help`', robodyn('--help')),
                ('`robodyn run stanford_arm --duration 0.01`', robodyn('run', 'stanford_arm', '--duration', '0.01')),
                ('the same `--record run.mcap`', robodyn('run', 'stanford_arm', '--duration', '0.01', '--record',
                                                         os.path.join(d, 'run.mcap'), '--overwrite')),
                ('`robodyn run stanford_arm --duration 1` (long enough to load numba)',
                 robodyn('run', 'stanford_arm', '--duration', '1'))]
        res = {label: median_of(cmd, n) for label, cmd in rows}
    fig = args.figures
    fig['help'] = res['`robodyn --help`']
    fig['short'] = res['`robodyn run stanford_arm --duration 0.01`']
    fig['short_record'] = res['the same `--record run.mcap`']
    fig['floor'] = res[rows[2][0]]
    fig['numba_run'] = res[rows[6][0]]
    table_rows = [[label, _s(r['wall']), _s(r['min_wall']), _s(r['cpu']), _mib(r['rss'])] for label, r in res.items()]
    return '\n'.join([
        f'### Commands (median of {n} processes; kernels cache filled)\n',
        _table(['command', 'wall', 'min wall', 'CPU', 'peak RSS'], table_rows), '',
        '"the floor": a script that imports numba and calls one cached function; numba then loads its '
        'compiler registries and scipy.linalg (for its BLAS bindings) before the first compiled call of '
        'any process. A short `robodyn run` does not stand on it: its kernels run as Python (the same '
        'operations) and numba is loaded only when the run is expected to, or does, spend more than '
        '`kernels.jit.INTERPRET_BUDGET` (0.25 s) in them; the 1 s run loads it before its first step.'])


def section_scenes(args) -> str:
    """The first run of every bundled scene after ``robodyn warm``."""
    from ..scene import list_scenes
    rows, out = [], {}
    for name, _ in list_scenes():
        r = measure(robodyn('run', name))
        out[name] = r
        rows.append([name, _s(r['simulated'], 1), _s(r['sim_wall']), _s(r['wall']), _s(beyond(r)), _s(r['cpu']),
                     _s(beyond_cpu(r)), _mib(r['rss']), 'ok' if r['rc'] == 0 else f'exit {r["rc"]}'])
    args.figures['scenes'] = out
    return '\n'.join(['### First run of every bundled scene, after robodyn warm (one process each)\n',
                      _table(['scene', 'simulated', 'simulation wall', 'process wall', 'beyond the simulation',
                              'CPU', 'CPU beyond the simulation', 'peak RSS', 'exit'], rows)])


def _robot_files(only=None) -> list:
    """``[(stem, path)]`` of the example-robot-data URDFs (empty when not installed)."""
    from ..urdf import example_robot_data_dir
    d = example_robot_data_dir()
    if d is None:
        return []
    files = sorted(d.rglob('*.urdf'), key=lambda p: (p.stem.lower(), str(p)))
    stems = [p.stem for p in files]
    return [(p.stem if stems.count(p.stem) == 1 else f'{p.parent.parent.name}/{p.stem}', str(p)) for p in files
            if only is None or p.stem in only]


def section_urdf(args) -> str:
    """The first ``robodyn run FILE --duration 0.2`` of every example-robot-data robot, cache filled."""
    files = _robot_files(args.robots)
    if not files:
        return '### URDF robots\n\nskipped: example-robot-data is not installed (test extras).'
    rows, out = [], {}
    for stem, path in files:
        r = measure(robodyn('run', path, '--duration', str(URDF_DURATION)))
        out[stem] = r
        rows.append([stem, _verdict(r), _s(r['sim_wall'], 3), _s(r['wall']), _s(beyond(r)), _s(r['cpu']),
                     _s(beyond_cpu(r)), _mib(r['rss'])])
    args.figures['urdf'] = out
    ran = {k: beyond(r) for k, r in out.items() if beyond(r) is not None}
    cpu = {k: beyond_cpu(r) for k, r in out.items() if beyond_cpu(r) is not None}
    worst = max(ran, key=ran.get) if ran else None
    summary = (f'{len(ran)} of {len(out)} ran; beyond the simulation: median {statistics.median(ran.values()):.2f} s, '
               f'largest {ran[worst]:.2f} s ({worst}); in CPU time median {statistics.median(cpu.values()):.2f} s, '
               f'largest {max(cpu.values()):.2f} s. Refused robots stop before simulating (the refusal is '
               'their start-up).') if ran and cpu else 'none ran'
    return '\n'.join([f'### First `robodyn run FILE --duration {URDF_DURATION}` of every example-robot-data URDF, '
                      'after robodyn warm (one process each)\n',
                      _table(['robot', 'verdict', 'simulation wall', 'process wall', 'beyond the simulation', 'CPU',
                              'CPU beyond the simulation', 'peak RSS'], rows), '', summary])


def section_cold(args) -> str:
    """A fresh install: ``robodyn warm`` into an empty cache, and first runs that compile."""
    rows = []
    cold = {}
    robots = dict(_robot_files(COLD_ROBOTS))
    with tempfile.TemporaryDirectory(prefix='robodyn-cold-') as d:
        if not args.quick:
            for k, (label, extra) in enumerate((
                    ('`robodyn warm --jobs 1` into an empty cache (one process)', ('--jobs', '1')),
                    ('`robodyn warm` into an empty cache (one worker per processor; `make test` runs it)', ()),
                    ('`robodyn warm` again', ()))):
                env = child_env(NUMBA_CACHE_DIR=os.path.join(d, 'filled' if k else 'serial'))
                r = measure(robodyn('warm', '--quiet', *extra), env)
                cold[label] = r
                rows.append([label, '—', _s(r['wall']), _s(r['cpu']), _mib(r['rss'])])
        env = child_env(NUMBA_CACHE_DIR=os.path.join(d, 'runs'))
        firsts = [('stanford_arm', robodyn('run', 'stanford_arm'))]
        firsts += [(f'{stem}.urdf --duration {URDF_DURATION}', robodyn('run', path, '--duration', str(URDF_DURATION)))
                   for stem, path in robots.items()]
        firsts += [('diver_tuck', robodyn('run', 'diver_tuck')), ('a1_stand', None)]
        for k, (label, cmd) in enumerate(firsts):
            if cmd is None:   # the scene that compiles the most, in its own empty cache
                env = child_env(NUMBA_CACHE_DIR=os.path.join(d, 'a1'))
                cmd = robodyn('run', *label.split())
            if k == 0 or label.startswith('a1'):   # a first run alone on the machine (not beside earlier children)
                wait_for_compilers()
            r = measure(cmd, env)
            cold[label] = r
            what = 'first run, empty cache' if k == 0 or label.startswith('a1') else 'then, same cache'
            rows.append([f'`robodyn run {label}` ({what})', _s(r['sim_wall'], 3), _s(r['wall']), _s(r['cpu']),
                         _mib(r['rss'])])
    args.figures['cold'] = cold
    return '\n'.join(['### A fresh install: empty kernel cache (a temporary NUMBA_CACHE_DIR)\n',
                      _table(['process', 'simulation wall', 'process wall', 'CPU', 'peak RSS'], rows), '',
                      'Without `robodyn warm`, a first run interprets its kernels while a child process compiles '
                      'them into the cache, and goes on compiling after the run ends; every robot of the same kind '
                      'then loads them (the kernels take the robot as arrays of fixed types). Each "first run, empty '
                      'cache" starts once no earlier run\'s compiler child is left; the runs after it share the cache '
                      'and the machine with the children still compiling.'])


_GENERATE = r'''
import json, sys, time, warnings
warnings.simplefilter('ignore')
t0 = time.perf_counter()
from robodyn_ros.scene import load_scene
from robodyn_ros.systems.base import backend_scope
with backend_scope('numpy'):
    model = load_scene(sys.argv[1]).system.model
from robodyn_ros import kernels
import numpy as np
t1, c1 = time.perf_counter(), time.process_time()
km = kernels.CompiledModel(model, specialize=True)
z = np.concatenate([model.neutral(), np.zeros(model.nv), [0.0]])
km.integrate_arm('rk4', z, np.zeros(model.nv), 1e-3, 10, 0.0)
print(json.dumps({'generate_compile': time.perf_counter() - t1, 'cpu': time.process_time() - c1,
                  'specialised': km.gen is not None,
                  'lines': len(kernels.codegen.module_source(model).splitlines()) if km.gen is not None else 0}))
'''


def _period_cost(model, repeat=7) -> dict:
    """CPU seconds of one 10 ms period (10 RK4 steps) of ``model`` on each backend, this process."""
    import numpy as np

    from .. import kernels
    from .timing import per_call
    kms = {'numba': kernels.CompiledModel(model), 'generated': kernels.CompiledModel(model, specialize=True)}
    z0 = np.concatenate([model.neutral(), np.zeros(model.nv), [0.0]])
    tau = np.zeros(model.nv)

    def period(km):   # the same 10 ms from the same state every call (a long run may leave it)
        z = z0.copy()

        def run():
            z[:] = z0
            return km.integrate_arm('rk4', z, tau, 1e-3, 10, 0.0)
        return run
    return {k: v[0] for k, v in per_call({k: period(km) for k, km in kms.items()}, repeat=repeat).items()}


def section_generated(args) -> str:
    """The per-model backend: faster per step, compiled per model; when it pays for itself."""
    import warnings

    from ..scene import load_scene
    from ..systems.base import backend_scope
    from ..scene import list_scenes
    robots = dict(_robot_files(GENERATED_MODELS))
    bundled = {n for n, _ in list_scenes()}
    names = [n for n in GENERATED_MODELS if n in bundled or n in robots]
    rows, out = [], {}
    with tempfile.TemporaryDirectory(prefix='robodyn-gen-') as d:
        for name in names:
            src = robots.get(name, name)
            with warnings.catch_warnings(), backend_scope('numpy'):
                warnings.simplefilter('ignore')
                try:
                    model = load_scene(src).system.model
                except ValueError as e:
                    rows.append([name, '—', '—', '—', '—', '—', f'not loaded: {e}'])
                    continue
            env = child_env(NUMBA_CACHE_DIR=os.path.join(d, name), ROBODYN_GENERATED_DIR=os.path.join(d, name, 'gen'))
            r = measure([sys.executable, '-c', _GENERATE, src], env)
            if r['rc'] != 0:
                rows.append([name, model.nv, '—', '—', '—', '—', f'failed: {r["stderr"].strip()[-200:]}'])
                continue
            g = json.loads(r['stdout'].strip().splitlines()[-1])
            # the child compiled the generic kernels too (empty cache): its generated part alone
            cost = _period_cost(model, repeat=args.repeat)
            saved = cost['numba'] - cost['generated']   # CPU s saved per simulated 10 ms
            gen = g['cpu']
            even = gen / saved * 0.01 if saved > 0 else None
            out[name] = {'nv': model.nv, **cost, 'generate_compile': gen, 'break_even': even}
            rows.append([f'{name} ({model.nv} DOF)', f'{cost["numba"] * 1e6:.1f} µs',
                         f'{cost["generated"] * 1e6:.1f} µs', f'{cost["numba"] / cost["generated"]:.2f}x',
                         f'{gen:.1f} s (wall {g["generate_compile"]:.1f} s)', f'{g["lines"]} lines',
                         '—' if even is None else f'{even / 60:.0f} simulated minutes'])
    args.figures['generated'] = out
    return '\n'.join([
        '### The per-model (generated) backend against the generic one\n',
        _table(['model', 'RK4 10 ms period, numba (CPU)', 'generated (CPU)', 'speed-up',
                'generate + compile (CPU, fresh cache)', 'generated code', 'pays for itself after (CPU)'], rows), '',
        'Generation and compilation happen once per model (then cached on disk); the speed-up is that of the '
        'integration alone (a recorded run also encodes and writes its messages, which both backends share). '
        'So the generic kernels are the default of `robodyn run`, the node and sweeps, and `--backend generated` '
        '(node parameter `backend`) is for long runs of one model.'])


_MUJOCO = r'''
import sys
import mujoco
m = mujoco.MjModel.from_xml_path(sys.argv[1])
m.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
m.opt.timestep = 1e-3
d = mujoco.MjData(m)
for _ in range(int(round(float(sys.argv[2]) / 1e-3))):
    mujoco.mj_step(m, d)
'''
_PINOCCHIO = r'''
import sys
import numpy as np
import pinocchio as pin
m = pin.buildModelFromUrdf(sys.argv[1])
d = m.createData()
q, v, h = pin.neutral(m), np.zeros(m.nv), 1e-3
tau = np.zeros(m.nv)
for _ in range(int(round(float(sys.argv[2]) / h))):
    a1 = pin.aba(m, d, q, v, tau)
    a2 = pin.aba(m, d, q + 0.5 * h * v, v + 0.5 * h * a1, tau)
    a3 = pin.aba(m, d, q + 0.5 * h * (v + 0.5 * h * a1), v + 0.5 * h * a2, tau)
    a4 = pin.aba(m, d, q + h * (v + 0.5 * h * a2), v + h * a3, tau)
    q = q + h / 6 * (v + 2 * (v + 0.5 * h * a1) + 2 * (v + 0.5 * h * a2) + (v + h * a3))
    v = v + h / 6 * (a1 + 2 * a2 + 2 * a3 + a4)
'''


def section_peers(args) -> str:
    """0.2 s of a robot as whole processes: robodyn run, MuJoCo, Pinocchio (same run)."""
    import warnings

    from ..scene import load_scene
    from ..systems.base import backend_scope
    robots = [('stanford_arm', None)] + list(_robot_files(PEER_ROBOTS))
    rows, out = [], {}
    with tempfile.TemporaryDirectory(prefix='robodyn-peers-') as d:
        for stem, path in robots:
            with warnings.catch_warnings(), backend_scope('numpy'):
                warnings.simplefilter('ignore')
                system = load_scene(path or stem).system
            exported, for_mujoco = os.path.join(d, f'{stem}.urdf'), os.path.join(d, f'{stem}_mujoco.urdf')
            text = system.urdf()
            with open(exported, 'w') as f:
                f.write(text)
            with open(for_mujoco, 'w') as f:   # MuJoCo refuses zero principal moments: bound them (as bench speed)
                f.write(text.replace('<link ', '<mujoco><compiler boundinertia="1e-9"/></mujoco>\n  <link ', 1))
            ours = path or exported
            cmds = {'robodyn run': robodyn('run', ours, '--duration', str(URDF_DURATION)),
                    'MuJoCo': [sys.executable, '-c', _MUJOCO, for_mujoco, str(URDF_DURATION)],
                    'Pinocchio': [sys.executable, '-c', _PINOCCHIO, exported, str(URDF_DURATION)]}
            res = {k: median_of(c, args.repeat) for k, c in cmds.items()}
            out[stem] = res
            for k, r in res.items():
                rows.append([f'{stem} ({system.model.nv} DOF)', k, 'ok' if r['rc'] == 0 else f'failed (exit {r["rc"]})',
                             _s(r['wall']), _s(r['cpu']), _mib(r['rss']),
                             f'{r["wall"] / res["robodyn run"]["wall"]:.2f}' if r['rc'] == 0 else '—'])
    args.figures['peers'] = out
    return '\n'.join([
        f'### {URDF_DURATION} s of a robot, start to exit, against the peers (median of {args.repeat} processes)\n',
        _table(['robot', 'process', 'status', 'wall', 'CPU', 'peak RSS', 'wall / robodyn run'], rows), '',
        f'MuJoCo: `import mujoco`, `MjModel.from_xml_path`, {int(URDF_DURATION * 1000)} RK4 steps of 1 ms. '
        'Pinocchio: `import pinocchio`, `buildModelFromUrdf`, the same steps as a Python RK4 loop over `aba`. '
        'Both read the URDF our importer exports for the robot (the same links, joints and inertias, no '
        'meshes); `robodyn run` reads the original file (example-robot-data) or the export (stanford_arm) '
        'and also checks the step, prints its summary and exits the same way.'])


def section_targets(args) -> str:
    """The start-up targets against this run's figures."""
    f = args.figures
    rows = []

    def add(target, value, goal, met, note=''):
        rows.append([target, value, goal, '—' if met is None else ('met' if met else 'not met'), note])
    if 'help' in f:
        add('`robodyn --help`', _s(f['help']['wall']), '<= 0.2 s', f['help']['wall'] <= 0.2,
            f'median of {f["help"]["n"]}; python -c pass alone: see the commands table')
    if 'short' in f:
        s, fl = f['short'], f.get('floor')
        add('`robodyn run stanford_arm --duration 0.01`, cache filled', f'{_s(s["wall"])} (CPU {_s(s["cpu"])})',
            '<= 0.5 s', s['wall'] <= 0.5,
            (f'numba not loaded (a run this short interprets its kernels; numba\'s own start is {_s(fl["wall"])}, '
             f'CPU {_s(fl["cpu"])}); ' if fl else '') + f'peak RSS {_mib(s["rss"])}')
    sc = {k: beyond(r) for k, r in f.get('scenes', {}).items() if beyond(r) is not None}
    if sc:
        worst = max(sc, key=sc.get)
        cpu = [beyond_cpu(r) for r in f['scenes'].values() if beyond_cpu(r) is not None]
        add('first run of every bundled scene after the cache is filled, beyond its simulation',
            f'largest {sc[worst]:.2f} s ({worst})', '<= 1 s', sc[worst] <= 1.0,
            f'{len(sc)} scenes; in CPU time at most {max(cpu):.2f} s' if cpu else f'{len(sc)} scenes')
    ur = {k: beyond(r) for k, r in f.get('urdf', {}).items() if beyond(r) is not None}
    if ur:
        worst = max(ur, key=ur.get)
        add(f'first `robodyn run FILE --duration {URDF_DURATION}` of each example-robot-data robot, beyond the '
            'simulation', f'largest {ur[worst]:.2f} s ({worst}); median {statistics.median(ur.values()):.2f} s',
            '<= 2 s', ur[worst] <= 2.0, f'{len(ur)} robots that run, cache filled by robodyn warm; in CPU time at '
            f'most {max(beyond_cpu(r) for r in f["urdf"].values() if beyond_cpu(r) is not None):.2f} s')
    c = f.get('cold', {})
    for label, r in c.items():
        if label.startswith('`robodyn warm') and 'into' in label:
            add(f'fresh install: {label.split(" into")[0]}', _s(r['wall'], 1), 'reported', None,
                f'CPU {r["cpu"]:.0f} s, peak RSS {_mib(r["rss"])}')
    for label in ('stanford_arm', 'a1_stand'):
        if label in c:
            r = c[label]
            add(f'first `robodyn run {label}` (its own duration) with an empty kernel cache',
                f'{_s(r["wall"])} (CPU {_s(r["cpu"])})', '<= 10 s', r['wall'] <= 10.0,
                'its kernels run as Python (the same operations) while a child process compiles them, each taken up '
                'as it is ready; the child, not counted here, goes on compiling for the next runs')
    if not rows:
        return '### Targets\n\n(no figures: run the other sections)'
    return '\n'.join(['### Start-up targets against this run\n',
                      _table(['target', 'measured', 'target value', 'status', 'note'], rows)])
