"""One process of the URDF fuzz test (test_urdf_fuzz.py): runs the mutants whose paths it reads on
stdin, one per line, and prints one JSON line per mutant as soon as it is done:
``{"path", "outcome", "message"}``, outcome 'ran', 'refused' (SceneError at load), 'preflight' (the
Simulator refuses the initial state or step), 'stopped' (SimulationError) or 'bug: <exception type>'.

Its parent times each line (a mutant that hangs, even inside compiled code, is killed with its
process, which the parent then replaces for the mutants left). A path ending in ``.hang`` makes
this worker spin forever: the parent's own test that its timeout fires.
"""
from __future__ import annotations

import json
import sys
import warnings


def run_case(path: str) -> tuple:
    """``(outcome, message)`` of one mutant: loaded, built and run for 20 ms on the numba backend."""
    from robodyn_ros.scene import SceneError, load_scene
    from robodyn_ros.simulation import SimulationError, Simulator, run_headless
    from robodyn_ros.systems.base import backend_scope
    stage = 'refused'
    try:
        with warnings.catch_warnings(), backend_scope('numba'):
            warnings.simplefilter('ignore')
            sc = load_scene(path)                   # may raise SceneError only
            stage = 'preflight'
            sim = Simulator(sc.system, sc.y0, integrator='rk4', dt=1e-3)   # a ValueError only
            stage = 'stopped'
            run_headless(sim, 0.02, 100.0, sc.script)                     # a SimulationError only
        return 'ran', ''
    except (SceneError, SimulationError, ValueError) as e:
        ok = {'refused': SceneError, 'preflight': ValueError, 'stopped': SimulationError}[stage]
        plain = type(e) in (SceneError, SimulationError, ValueError)  # not e.g. numpy's LinAlgError
        return (stage, str(e)) if isinstance(e, ok) and plain else (f'bug: {type(e).__name__}', str(e))
    except Exception as e:  # noqa: BLE001 - what the fuzz test looks for
        return f'bug: {type(e).__name__}', str(e)


def main() -> int:
    print(json.dumps({'ready': True}), flush=True)
    for line in sys.stdin:
        path = line.rstrip('\n')
        if not path:
            continue
        if path.endswith('.hang'):
            while True:   # the parent's timeout must end this process
                pass
        outcome, message = run_case(path)
        print(json.dumps({'path': path, 'outcome': outcome, 'message': message}), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
