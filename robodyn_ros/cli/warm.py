"""``robodyn warm``: compile, once, every kernel the bundled scenes and URDF robots run on.

numba compiles a kernel the first time a process calls it and caches the machine code on disk
(:mod:`robodyn_ros.kernels.cache`); a fresh install would pay that (about a minute in all) in its
first runs. This command pays it up front, as ``make run`` does once after installing: every
bundled scene, and a URDF robot (stanford_arm's arm written to URDF and read back, the path of
``robodyn run robot.urdf``; again with joint friction and effort limits, and with a ``<mimic>``
joint), each run for :data:`DURATION` s the two ways the tools run them:

* as ``robodyn run SCENE --record FILE`` runs it (compiled blocks of periods, the batched
  recorder, every default topic), and
* as the sim node and ``robodyn run`` without a compiled block path run it: period by period,
  outputs with joint wrenches, /tf, each message recorded as it comes.

The kernels' argument types do not depend on the robot, so a robot that was never run loads
the same machine code (``robodyn bench startup`` measures it). A second ``robodyn warm`` only
loads. It prints what it compiled and how long each scene took.
"""
from __future__ import annotations

import sys

#: one line for ``robodyn --help``
HELP = 'compile once the kernels every bundled scene and URDF robot uses (make run does it)'
#: simulated seconds of each warm-up run (two diagnostics periods, a block of periods)
DURATION = 0.2


def add_parser(sub):
    """Register the subcommand and its options."""
    p = sub.add_parser('warm', help=HELP, description=__doc__.split('\n\n')[1])
    p.add_argument('--backend', choices=('numba', 'generated'), default=None,
                   help='kernels to warm (default: those of robodyn run: $ROBODYN_BACKEND, else numba)')
    p.add_argument('--quiet', action='store_true', help='print only the last line')
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
    from ..runs import resolve_settings
    from ..simulation import Simulator, run_headless
    from ..systems.base import backend_scope
    with backend_scope(backend):
        scene = load()
    st = resolve_settings(scene, duration=DURATION)
    st['backend'] = backend
    for batch, chunk_span in ((HEADLESS_BATCH, None), (0, NODE_CHUNK_SPAN)):
        sim = Simulator(scene.system, scene.y0, integrator=st['integrator'], dt=st['dt'], rtol=st['rtol'],
                        atol=st['atol'])
        sink = McapRunSink(os.path.join(scratch, 'warm.mcap'), scene, {**st, 'mode': 'warm'}, batch=batch,
                           chunk_span=chunk_span, diagnostics_period=0.1)
        try:
            run_headless(sim, DURATION, st['rate'], scene.script, [sink])
        finally:
            sink.close()
        os.remove(os.path.join(scratch, 'warm.mcap'))


def main(args) -> int:
    """Warm every scene; print one line per scene and a total; 1 when the kernels are unavailable."""
    import tempfile
    import time
    import warnings

    from .. import kernels
    from ..kernels.cache import compiled_here
    from ..systems.base import tools_backend
    backend = tools_backend(args.backend)
    if backend == 'numpy' or not kernels.AVAILABLE:
        print(f'robodyn warm: nothing to compile (backend {backend}'
              f'{"" if kernels.AVAILABLE else "; " + kernels.UNAVAILABLE_REASON})', file=sys.stderr)
        return 1
    t0 = time.perf_counter()
    n0 = 0
    with tempfile.TemporaryDirectory(prefix='robodyn-warm-') as scratch, warnings.catch_warnings():
        warnings.simplefilter('ignore')
        for label, load in _scene_runs(scratch):
            t = time.perf_counter()
            warm_scene(load, backend, scratch)
            n = len(compiled_here())
            if not args.quiet:
                print(f'{label:32s} {time.perf_counter() - t:6.1f} s, {n - n0} kernel signatures compiled', flush=True)
            n0 = n
    print(f'robodyn warm: {n0} kernel signatures compiled in {time.perf_counter() - t0:.1f} s '
          f'({backend} backend; cache {kernels.CACHE_DIR})')
    return 0
