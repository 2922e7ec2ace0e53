"""Seeded fuzzing of real URDFs (example-robot-data files mutated by test/urdf_mutations.py:
deleted attributes, NaN/inf/huge numbers, negative masses, truncated tags, cycles, duplicated
names, swapped parent/child, point masses, mimics): no traceback, no hang, either a clean load
or a one-line refusal; through the API, ``robodyn run`` and the ``sim`` node."""
from __future__ import annotations

import random
import signal
import subprocess
import sys
import warnings

import pytest

from robodyn_ros.scene import SceneError, load_scene
from robodyn_ros.simulation import SimulationError, Simulator, run_headless
from robodyn_ros.systems.base import backend_scope
from robodyn_ros.urdf import example_robot_data_dir
from ros_helpers import Domain, start_sim
from urdf_mutations import FILES, mutate

ERD = example_robot_data_dir()
SEED, CASES = 20240, 400
#: wall seconds one in-process case may take (load, preflight, 20 ms of simulation)
CASE_TIMEOUT = 20


class _Hang(Exception):
    pass


def _alarm(signum, frame):
    raise _Hang()


@pytest.fixture(scope='module')
def fuzzed(tmp_path_factory):
    """``[(path, what, outcome, message)]``: each mutant loaded, built and run for 20 ms in
    process; outcome 'ran', 'refused' (SceneError at load), 'preflight' (the Simulator refuses
    the initial state or step), 'stopped' (SimulationError) or 'bug: <exception type>'."""
    d = tmp_path_factory.mktemp('fuzz')
    rng = random.Random(SEED)
    texts = {f: (ERD / f).read_text() for f in FILES}
    out = []
    old = signal.signal(signal.SIGALRM, _alarm)
    try:
        for k in range(CASES):
            f = rng.choice(FILES)
            text, what = mutate(texts[f], rng)
            p = d / f'm{k:03d}_{f.split("/")[-1]}'
            p.write_text(text, encoding='utf-8', errors='surrogatepass')
            signal.alarm(CASE_TIMEOUT)
            stage = 'refused'
            try:
                with warnings.catch_warnings(), backend_scope('numba'):
                    warnings.simplefilter('ignore')
                    sc = load_scene(p)                  # may raise SceneError only
                    stage = 'preflight'
                    sim = Simulator(sc.system, sc.y0, integrator='rk4', dt=1e-3)   # a ValueError only
                    stage = 'stopped'
                    run_headless(sim, 0.02, 100.0, sc.script)                     # a SimulationError only
                res = ('ran', '')
            except _Hang:
                res = ('bug: hang', what)
            except (SceneError, SimulationError, ValueError) as e:
                ok = {'refused': SceneError, 'preflight': ValueError, 'stopped': SimulationError}[stage]
                plain = type(e) in (SceneError, SimulationError, ValueError)  # not e.g. numpy's LinAlgError
                res = (stage, str(e)) if isinstance(e, ok) and plain else (f'bug: {type(e).__name__}', str(e))
            except Exception as e:  # noqa: BLE001 - what the test looks for
                res = (f'bug: {type(e).__name__}', str(e))
            finally:
                signal.alarm(0)
            out.append((p, what, *res))
    finally:
        signal.signal(signal.SIGALRM, old)
    return out


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


def test_a_leaf_without_inertia_about_its_axis_is_refused_by_the_preflight_on_every_backend(tmp_path):
    """A point mass on its own joint's axis at a leaf: the mass matrix is singular in every
    configuration. The generated backend used to divide by that constant zero while writing its
    code (a ZeroDivisionError traceback, exit 1); now it declines the model and every backend's
    preflight refuses it naming the joint."""
    f = tmp_path / 'point_mass.urdf'
    f.write_text('<robot name="pm"><link name="a"/>'
                 '<link name="b"><inertial><mass value="1"/><inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0" ixz="0" '
                 'iyz="0"/></inertial></link><link name="c"><inertial><mass value="1"/><inertia ixx="0" iyy="0" '
                 'izz="0" ixy="0" ixz="0" iyz="0"/></inertial></link>'
                 '<joint name="j1" type="continuous"><parent link="a"/><child link="b"/><axis xyz="0 1 0"/></joint>'
                 '<joint name="j2" type="continuous"><parent link="b"/><child link="c"/><origin xyz="0 0 -1"/>'
                 '<axis xyz="0 0 1"/></joint></robot>')
    from robodyn_ros.kernels import codegen
    for backend in ('generated', 'numba', 'numpy'):
        with backend_scope(backend):
            sc = load_scene(f)
            with pytest.raises(ValueError, match=r"joint\(s\) j2 move a subtree with no mass or inertia about"):
                Simulator(sc.system, sc.y0, integrator='rk4', dt=1e-3)
    assert codegen.aba_source(sc.system.model) is None
    p = subprocess.run([sys.executable, '-m', 'robodyn_ros.cli', 'run', str(f), '--duration', '0.02'],
                       capture_output=True, text=True, timeout=240)
    assert p.returncode == 2 and 'Traceback' not in p.stderr and len(p.stderr.splitlines()) == 1, p.stderr


def test_a_huge_length_is_refused_by_the_preflight_in_words(tmp_path):
    """An origin of 1e308 m (finite, but its square overflows): the mass matrix is not finite.
    The preflight's eigen-analysis used to raise numpy's 'Eigenvalues did not converge'."""
    f = tmp_path / 'huge.urdf'
    f.write_text((ERD / FILES[1]).read_text().replace('<origin rpy="0.0 0.0 0.0" xyz="0.0 -0.1197 0.425"/>',
                                                      '<origin rpy="0.0 0.0 0.0" xyz="0.0 -1e308 0.425"/>', 1))
    assert '1e308' in f.read_text()
    with backend_scope('numba'):
        sc = load_scene(f)
        with pytest.raises(ValueError, match='the mass matrix is not finite') as e:
            Simulator(sc.system, sc.y0, integrator='rk4', dt=1e-3)
    assert type(e.value) is ValueError
