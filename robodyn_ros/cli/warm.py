"""``robodyn warm``: compile, once, every kernel the bundled scenes and URDF robots run on.

numba compiles a kernel the first time a process calls it and caches the machine code on disk
(:mod:`robodyn_ros.kernels.cache`); a fresh install would pay that in its first runs (about a
minute of CPU for stanford_arm, several minutes for every scene). This command pays it up front, as
``make test`` does before its tests: every bundled scene, and a URDF robot (stanford_arm's arm written to URDF and read back, the path of
``robodyn run robot.urdf``; again with joint friction and effort limits, and with a ``<mimic>``
joint), each run for :data:`DURATION` s the two ways the tools run them:

* as ``robodyn run SCENE --record FILE`` runs it (compiled blocks of periods, the batched
  recorder, every default topic), and
* as the sim node and ``robodyn run`` without a compiled block path run it: period by period,
  outputs with joint wrenches, /tf, each message recorded as it comes.

The kernels' argument types do not depend on the robot, so a robot that was never run loads
the same machine code (``robodyn bench startup`` measures it). A second ``robodyn warm`` only
loads. It prints what it compiled and how long each scene took.

numba compiles in one thread per process, so the scenes are shared among ``--jobs`` worker
processes (default: the processors this process may use), the most expensive first
(:data:`HEAVY_FIRST`); they write one cache, whose files are locked per directory
(:mod:`robodyn_ros.kernels.cache`). This process then runs every scene once more: that pass only
loads, and compiles whatever a worker's signature did not reach the cache (it prints how many).
"""
from __future__ import annotations

import sys

#: one line for ``robodyn --help``
HELP = 'compile once the kernels every bundled scene and URDF robot uses (make test does it first)'
#: ``robodyn warm --help``'s text
DESCRIPTION = ('numba compiles a kernel the first time a process calls it and caches the machine code on disk; '
               'a fresh install pays that in its first runs (about a minute of CPU for stanford_arm, several '
               'minutes for every scene). robodyn warm pays it up front, in one worker process per processor '
               '(--jobs): every bundled scene and a URDF robot, each run briefly the ways robodyn run, the '
               'sim node and the recorder run them. A robot never run before then loads the same machine code. '
               'A second robodyn warm only loads. make test runs it first.')
#: simulated seconds of each warm-up run (two diagnostics periods, a block of periods)
DURATION = 0.2
#: labels of the runs that compile the most on an empty cache (measured, most first): the workers
#: start with them, so that the longest one does not start last; the others follow in list order
HEAVY_FIRST = ('a1_stand', 'betancur_platform', 'stanford_arm as URDF, mimic', 'unfried_free_flyer',
               'betancur_pendulum', 'unfried_air_bearing', 'huston_prescribed_planar3', 'diver_jackknife')


def add_parser(sub):
    """Register the subcommand and its options."""
    p = sub.add_parser('warm', help=HELP, description=DESCRIPTION)
    p.add_argument('--backend', choices=('numba', 'generated', 'auto'), default=None,
                   help='kernels to warm (default: those of robodyn run: $ROBODYN_BACKEND, else auto, whose '
                        'short runs use the generic kernels, as numba)')
    p.add_argument('--quiet', action='store_true', help='print only the last line')
    p.add_argument('--jobs', type=int, default=None, metavar='N',
                   help='worker processes compiling at once (default: the processors available; 1: all here)')
    p.add_argument('scenes', nargs='*', metavar='SCENE',
                   help='warm only these runs (a bundled scene name, or a label warm prints); default: all')
    return p


def _scene_runs(scratch):
    """``[(label, load)]``: every bundled scene and three URDF robots, each a ``load() -> Scene``."""
    import os
    from dataclasses import replace

    from ..model import build_model, to_urdf
    from ..scene import list_scenes, load_scene
    runs = [(name, lambda name=name: load_scene(name)) for name, _ in list_scenes()]

    def urdf_robot(variant, command_interface=None):
        """stanford_arm's arm as a URDF file: as it is, with Coulomb friction and effort limits on
        every joint (the right-hand side of URDF robots with ``<dynamics friction>``), with its last
        joint following the one before (``<mimic>``: the coupled dynamics), with stiff joint damping
        (integrator auto runs it with rosenbrock2, the linearly implicit step), or both; the plain one also with
        every joint position-commanded (the joint servo in rk4's stages; the bundled xarm7_trajectory scene runs
        it in rosenbrock2's)."""
        path = os.path.join(scratch, f'robot_{variant.replace(", ", "_")}.urdf')
        if not os.path.exists(path):
            m = load_scene('stanford_arm').system.model
            moving = [s for s in m.specs if s.joint_type != 'fixed']
            if variant == 'friction':
                specs = [replace(s, friction=1e-3, effort_limit=100.0) if s.joint_type != 'fixed' else s
                         for s in m.specs]
            elif variant == 'damped':
                specs = [replace(s, damping=50.0, friction=1e-3) if s.joint_type != 'fixed' else s for s in m.specs]
            elif variant == 'mimic':
                specs = [replace(s, mimic=(moving[-2].joint, 0.5, 0.0)) if s is moving[-1] else s for s in m.specs]
            elif variant == 'damped, mimic':   # rosenbrock2's stages in the independent joints (tiago, talos)
                specs = [replace(s, damping=50.0, friction=1e-3,
                                 mimic=(moving[-2].joint, 0.5, 0.0) if s is moving[-1] else None)
                         if s.joint_type != 'fixed' else s for s in m.specs]
            else:
                specs = m.specs
            with open(path, 'w') as f:
                f.write(to_urdf(build_model(specs, gravity=m.gravity, name=m.name, root=m.root)))
        return load_scene(path, command_interface=command_interface)
    return runs + [(f'stanford_arm as URDF{"" if v == "plain" else ", " + v}', lambda v=v: urdf_robot(v))
                   for v in ('plain', 'friction', 'mimic', 'damped', 'damped, mimic')] + \
        [('stanford_arm as URDF, position', lambda: urdf_robot('plain', 'position'))]


def warm_scene(load, backend, scratch) -> None:
    """Run one scene both ways (see the module docstring), recording into ``scratch``."""
    import os

    from ..recording.run_sink import HEADLESS_BATCH, NODE_CHUNK_SPAN, McapRunSink
    from ..runs import plan_run, resolve_settings
    from ..simulation import Simulator, run_headless
    from ..systems.base import backend_scope
    with backend_scope(backend):
        scene = load()
    plan, st = plan_run(resolve_settings(scene, duration=DURATION), scene.system, scene.y0)
    st['backend'] = backend
    for batch, chunk_span in ((HEADLESS_BATCH, None), (0, NODE_CHUNK_SPAN)):
        sim = Simulator(scene.system, scene.y0, plan=plan)
        sink = McapRunSink(os.path.join(scratch, 'warm.mcap'), scene, {**st, 'mode': 'warm'}, batch=batch,
                           chunk_span=chunk_span, diagnostics_period=0.1)
        try:
            run_headless(sim, DURATION, st['rate'], scene.script, [sink])
        finally:
            sink.close()
        os.remove(os.path.join(scratch, 'warm.mcap'))


def _ordered(labels) -> list:
    """The run labels, :data:`HEAVY_FIRST` first, then the others in their order."""
    heavy = [h for h in HEAVY_FIRST if h in labels]
    return heavy + [lb for lb in labels if lb not in heavy]


def _cannot_run() -> tuple:
    """The exceptions of a scene that cannot be loaded or run (its one-line message says why)."""
    from ..scene import SceneError
    from ..simulation import SimulationError
    return SceneError, SimulationError, ValueError, OSError


def _warm_in_worker(label: str, backend: str) -> tuple:
    """One run in a worker process: ``(label, seconds, kernel signatures this process compiled for it,
    why it could not run or '')``."""
    import tempfile
    import time
    import warnings

    from ..kernels.cache import compiled_here
    n0 = len(compiled_here())
    t = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix='robodyn-warm-') as scratch, warnings.catch_warnings():
        warnings.simplefilter('ignore')
        load = dict(_scene_runs(scratch))[label]
        try:
            warm_scene(load, backend, scratch)
        except _cannot_run() as e:
            return label, time.perf_counter() - t, len(compiled_here()) - n0, ' '.join(str(e).split())
    return label, time.perf_counter() - t, len(compiled_here()) - n0, ''


def _jobs(requested) -> int:
    """Worker processes: ``requested``, else the processors this process may run on."""
    import os
    if requested is not None:
        return max(1, int(requested))
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


def main(args) -> int:
    """Warm every scene (in ``--jobs`` workers, then a loading pass here); print one line per scene and
    a total; 1 when the kernels are unavailable, 2 for an unknown scene or when a scene cannot be loaded
    or run (one line each on stderr, the others warmed all the same)."""
    import multiprocessing
    import tempfile
    import time
    import warnings
    from concurrent.futures import ProcessPoolExecutor, as_completed

    from .. import kernels
    from ..kernels.cache import compiled_here
    from ..systems.base import tools_backend
    backend = tools_backend(args.backend)
    if backend == 'auto':   # auto's runs start on the generic kernels: warm those (a model's own code is
        backend = 'numba'   # compiled by a long run's child process, and cached per model)
    if backend == 'numpy' or not kernels.AVAILABLE:
        print(f'robodyn warm: nothing to compile (backend {backend}'
              f'{"" if kernels.AVAILABLE else "; " + kernels.UNAVAILABLE_REASON})', file=sys.stderr)
        return 1
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix='robodyn-warm-') as scratch, warnings.catch_warnings():
        warnings.simplefilter('ignore')
        runs = _scene_runs(scratch)
        labels = [lb for lb, _ in runs]
        wanted = list(getattr(args, 'scenes', None) or [])
        unknown = [w for w in wanted if w not in labels]
        if unknown:
            print(f'robodyn warm: unknown scene {unknown[0]!r} (expected one of: {", ".join(labels)})',
                  file=sys.stderr)
            return 2
        if wanted:
            runs = [(lb, load) for lb, load in runs if lb in wanted]
        jobs = min(_jobs(getattr(args, 'jobs', None)), len(runs))
        n_workers, failed = 0, []

        def fail(label, why):
            failed.append(label)
            print(f'robodyn warm: {label}: not warmed: {why}', file=sys.stderr, flush=True)
        if jobs > 1:
            ctx = multiprocessing.get_context('spawn')   # a fresh interpreter: no LLVM state forked
            with ProcessPoolExecutor(max_workers=jobs, mp_context=ctx) as pool:
                futures = [pool.submit(_warm_in_worker, lb, backend) for lb in _ordered([lb for lb, _ in runs])]
                for f in as_completed(futures):
                    label, dt, n, why = f.result()
                    n_workers += n
                    if why:
                        fail(label, why)
                    elif not args.quiet:
                        print(f'{label:32s} {dt:6.1f} s, {n} kernel signatures compiled (worker)', flush=True)
        n0 = 0
        for label, load in runs:   # here: loads what the workers compiled, compiles what they did not leave
            if label in failed:
                continue
            t = time.perf_counter()
            try:
                warm_scene(load, backend, scratch)
            except _cannot_run() as e:   # a scene that cannot run: say so, go on
                fail(label, ' '.join(str(e).split()))
                continue
            n = len(compiled_here())
            if not args.quiet and (jobs == 1 or n > n0):
                print(f'{label:32s} {time.perf_counter() - t:6.1f} s, {n - n0} kernel signatures compiled',
                      flush=True)
            n0 = n
    where = f'{jobs} processes: {n_workers} in the workers, {n0} after them' if jobs > 1 else 'one process'
    if failed:
        print(f'robodyn warm: {len(failed)} scene{"s" if len(failed) > 1 else ""} could not be warmed '
              f'({", ".join(failed)}); {n_workers + n0} kernel signatures compiled for the others in '
              f'{time.perf_counter() - t0:.1f} s ({where})', file=sys.stderr)
        return 2
    print(f'robodyn warm: {n_workers + n0} kernel signatures compiled in {time.perf_counter() - t0:.1f} s '
          f'({where}; {backend} backend; cache {kernels.CACHE_DIR})')
    return 0
