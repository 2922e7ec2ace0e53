"""Seeded fuzzing of real URDFs (example-robot-data files mutated by test/urdf_mutations.py:
deleted attributes, NaN/inf/huge numbers, negative masses, truncated tags, cycles, duplicated
names, swapped parent/child, point masses, mimics): no traceback, no hang, either a clean load
or a one-line refusal; through the API (each mutant timed in a worker process that is killed when it
hangs), ``robodyn run`` and the ``sim`` node."""
from __future__ import annotations

import json
import queue
import random
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from robodyn_ros.scene import load_scene
from robodyn_ros.simulation import Simulator, run_headless
from robodyn_ros.systems.base import backend_scope
from robodyn_ros.urdf import example_robot_data_dir
from ros_helpers import Domain, start_sim
from urdf_mutations import FILES, mutate

ERD = example_robot_data_dir()
SEED, CASES = 20240, 400
#: wall seconds one mutant may take in a worker process (load, preflight, 20 ms of simulation; most take
#: well under a second), and a worker's start (imports, the compiled kernels loaded from their cache)
CASE_TIMEOUT, START_TIMEOUT = 60, 300
#: worker processes running the mutants side by side
WORKERS = 2
WORKER = Path(__file__).resolve().parent / 'urdf_fuzz_worker.py'


def _pump(stream, lines: queue.Queue):
    """Every line of a worker's stdout into ``lines``, then None at its end."""
    for x in stream:
        lines.put(x)
    lines.put(None)


def _serve(paths: list, out: dict, case_timeout: float, start_timeout: float):
    """Run ``paths`` in order in worker processes (test/urdf_fuzz_worker.py), one at a time: each result
    line must come within ``case_timeout`` s of sending its path (``start_timeout`` for a new worker's
    first). A mutant past its time is recorded as 'bug: hang' and its process killed (a hang in compiled
    code is a hang of the process, which no signal handler inside it can interrupt); a fresh worker takes
    the paths left. ``out[path] = (outcome, message)``."""
    todo = list(paths)
    while todo:
        proc = subprocess.Popen([sys.executable, str(WORKER)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                stderr=subprocess.DEVNULL, text=True, bufsize=1)
        lines = queue.Queue()
        threading.Thread(target=_pump, args=(proc.stdout, lines), daemon=True).start()
        try:
            try:
                lines.get(timeout=start_timeout)   # {"ready": true}
            except queue.Empty:
                raise AssertionError(f'a fuzz worker did not start within {start_timeout} s') from None
            while todo:
                path = todo[0]
                proc.stdin.write(path + '\n')
                proc.stdin.flush()
                try:
                    line = lines.get(timeout=case_timeout)
                except queue.Empty:
                    line = ''
                if not line:   # no line in time (a hang), or the worker's output ended (a crash)
                    proc.kill()
                    out[path] = ('bug: hang', f'no result within {case_timeout} s') if line == '' else \
                        ('bug: crash', f'the worker ended with status {proc.wait()}')
                    todo.pop(0)
                    break
                r = json.loads(line)
                assert r['path'] == path, (r, path)
                out[path] = (r['outcome'], r['message'])
                todo.pop(0)
        finally:
            proc.kill()
            proc.wait()


def run_mutants(paths, workers: int = WORKERS, case_timeout: float = CASE_TIMEOUT,
                start_timeout: float = START_TIMEOUT) -> dict:
    """``{path: (outcome, message)}`` of every mutant file, run by ``workers`` worker processes side by side
    (the paths dealt round-robin), each mutant timed (:func:`_serve`)."""
    out, paths = {}, [str(p) for p in paths]
    threads = [threading.Thread(target=_serve, args=(paths[k::workers], out, case_timeout, start_timeout))
               for k in range(workers)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return out


def test_the_hang_check_fires_on_a_mutant_that_never_returns_and_the_rest_still_run(tmp_path):
    """A worker spinning in a loop no signal inside it could end (what a hang in compiled code is): its
    mutant is reported as a hang within the timeout, and the mutants after it run in a fresh worker."""
    files = [ERD / FILES[0], tmp_path / 'spin.hang', ERD / FILES[0]]
    files[1].write_text('')
    got = run_mutants([files[0], files[1], tmp_path / 'again.urdf'], workers=1, case_timeout=10)
    assert got[str(files[1])][0] == 'bug: hang', got
    assert got[str(files[0])][0] == 'ran' and got[str(tmp_path / 'again.urdf')][0] == 'refused', got
    assert len(got) == 3


@pytest.fixture(scope='module')
def fuzzed(tmp_path_factory):
    """``[(path, what, outcome, message)]``: each mutant loaded, built and run for 20 ms in a worker
    process (:func:`run_mutants`); outcome 'ran', 'refused' (SceneError at load), 'preflight' (the
    Simulator refuses the initial state or step), 'stopped' (SimulationError), 'bug: hang' or
    'bug: <exception type>'."""
    d = tmp_path_factory.mktemp('fuzz')
    rng = random.Random(SEED)
    texts = {f: (ERD / f).read_text() for f in FILES}
    cases = []
    for k in range(CASES):
        f = rng.choice(FILES)
        text, what = mutate(texts[f], rng)
        p = d / f'm{k:03d}_{f.split("/")[-1]}'
        p.write_text(text, encoding='utf-8', errors='surrogatepass')
        cases.append((p, what))
    got = run_mutants([p for p, _ in cases])
    assert len(got) == CASES
    return [(p, what, *got[str(p)]) for p, what in cases]


def test_fuzzed_urdfs_load_and_run_or_are_refused_in_one_line(fuzzed):
    bugs = [(p.name, what, o, m[:300]) for p, what, o, m in fuzzed if o.startswith('bug')]
    assert not bugs, bugs
    counts = {o: sum(1 for _, _, x, _ in fuzzed if x == o) for o in ('ran', 'refused', 'preflight', 'stopped')}
    print(f'{len(fuzzed)} mutants (seed {SEED}):', counts)
    assert sum(counts.values()) == CASES and counts['ran'] >= 30 and counts['refused'] >= 100, counts
    for p, what, o, m in fuzzed:
        if o == 'refused':  # '<file>: <where>: <reason>' on one line
            assert m.startswith(f'{p}: ') and '\n' not in m and m.count(': ') >= 2, (what, m)
        elif o != 'ran':
            assert '\n' not in m, (what, m)


def _cases(fuzzed, outcome, n):
    picked = [c for c in fuzzed if c[2] == outcome][:n]
    assert len(picked) == n
    return picked


def test_fuzzed_urdfs_through_robodyn_run_exit_0_or_2_without_a_traceback(fuzzed):
    """Refused mutants exit 2 with the refusal as the one line on stderr; loading ones run (exit 0);
    warnings are one line each."""
    cases = _cases(fuzzed, 'refused', 4) + _cases(fuzzed, 'ran', 3)
    procs = [subprocess.Popen([sys.executable, '-m', 'robodyn_ros.cli', 'run', str(p), '--duration', '0.02',
                               '--backend', 'numba'], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for p, *_ in cases]
    for (p, what, outcome, msg), proc in zip(cases, procs):
        out, err = proc.communicate(timeout=240)
        assert 'Traceback' not in err, (what, err)
        errors = [ln for ln in err.splitlines() if not ln.startswith('robodyn: warning: ')]
        if outcome == 'ran':
            assert proc.returncode == 0 and errors == [] and 'simulated 0.020 s' in out, (what, err)
        else:
            assert proc.returncode == 2 and len(errors) == 1 and errors[0].startswith('robodyn run: '), (what, err)
            assert errors[0] == f'robodyn run: {msg}', (what, err)


def test_fuzzed_urdfs_through_the_sim_node_never_crash_it(fuzzed, tmp_path):
    """The node on a refused mutant: one error line and exit 2; on a loading one: it runs to its
    duration and exits 0. Each node in its own ROS domain, always cleaned up."""
    cases = _cases(fuzzed, 'refused', 2) + _cases(fuzzed, 'ran', 1)
    doms = [Domain() for _ in cases]
    nodes = []
    try:
        for k, ((p, *_), dom) in enumerate(zip(cases, doms)):
            nodes.append(start_sim(dom, {'robot_description_file': str(p), 'mode': 'max', 'duration': 0.05,
                                         'backend': 'numba'}, tmp_path / f'node{k}.log'))
        for (p, what, outcome, msg), node in zip(cases, nodes):
            rc = node.wait(timeout=120)
            log = node.output()
            assert 'Traceback' not in log, (what, log)
            if outcome == 'ran':
                assert rc == 0 and 'simulated 0.050 s' in log, (what, log)
            else:
                errors = [ln for ln in log.splitlines() if ln.startswith('sim: ')]
                assert rc == 2 and errors == [f'sim: {msg}'], (what, log)
    finally:
        for node in nodes:
            node.cleanup()
        for dom in doms:
            dom.release()


def test_a_leaf_without_inertia_about_its_axis_gets_armature_or_is_refused_on_every_backend(tmp_path):
    """A point mass on its own joint's axis at a leaf: the mass matrix is singular in every
    configuration. The generated backend used to divide by that constant zero while writing its
    code (a ZeroDivisionError traceback, exit 1). Asked for no armature, it now declines the model and
    every backend's preflight refuses it naming the joint; by default the joint gets the smallest
    armature that makes M regular (its d is then that constant), and every backend runs it."""
    f = tmp_path / 'point_mass.urdf'
    f.write_text('<robot name="pm"><link name="a"/>'
                 '<link name="b"><inertial><mass value="1"/><inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0" ixz="0" '
                 'iyz="0"/></inertial></link><link name="c"><inertial><mass value="1"/><inertia ixx="0" iyy="0" '
                 'izz="0" ixy="0" ixz="0" iyz="0"/></inertial></link>'
                 '<joint name="j1" type="continuous"><parent link="a"/><child link="b"/><axis xyz="0 1 0"/></joint>'
                 '<joint name="j2" type="continuous"><parent link="b"/><child link="c"/><origin xyz="0 0 -1"/>'
                 '<axis xyz="0 0 1"/></joint></robot>')
    bare = tmp_path / 'bare.yaml'
    bare.write_text(f'name: pm\nparts:\n  - {{kind: urdf, name: pm, file: {f}, armature: 0}}\n')
    from robodyn_ros.kernels import codegen
    ran = 0
    for backend in ('generated', 'numba', 'numpy'):
        with backend_scope(backend):
            sc = load_scene(bare)
            with pytest.raises(ValueError, match=r"joint\(s\) j2 move a subtree with no mass or inertia about"):
                Simulator(sc.system, sc.y0, integrator='rk4', dt=1e-3)
            assert codegen.trace(sc.system.model) is None
            with pytest.warns(UserWarning, match=r'a motion of joint j2 meets no inertia there\): armature 1e-06'):
                sc = load_scene(f)
            assert list(sc.system.model.armature) == [0.0, 1e-6]
            sim = Simulator(sc.system, sc.y0, integrator='rk4', dt=1e-3)
            run_headless(sim, 0.02, 100.0)
            ran += 1
    assert ran == 3 and codegen.trace(sc.system.model) is not None
    p = subprocess.run([sys.executable, '-m', 'robodyn_ros.cli', 'run', str(bare), '--duration', '0.02'],
                       capture_output=True, text=True, timeout=240)
    assert p.returncode == 2 and 'Traceback' not in p.stderr and len(p.stderr.splitlines()) == 1, p.stderr


def test_a_huge_length_is_refused_by_the_preflight_in_words(tmp_path):
    """An origin of 1e308 m (finite, but its square overflows): the mass matrix is not finite, and the
    message names the joints whose entries are not. The preflight's eigen-analysis used to raise numpy's
    'Eigenvalues did not converge'."""
    f = tmp_path / 'huge.urdf'
    f.write_text((ERD / FILES[1]).read_text().replace('<origin rpy="0.0 0.0 0.0" xyz="0.0 -0.1197 0.425"/>',
                                                      '<origin rpy="0.0 0.0 0.0" xyz="0.0 -1e308 0.425"/>', 1))
    assert '1e308' in f.read_text()
    with backend_scope('numba'):
        sc = load_scene(f)
        with pytest.raises(ValueError, match='the mass matrix is not finite') as e:
            Simulator(sc.system, sc.y0, integrator='rk4', dt=1e-3)
    assert type(e.value) is ValueError
    assert str(e.value).endswith(': at joints shoulder_pan_joint, shoulder_lift_joint'), e.value   # named
