"""The block path of run_headless (many publication periods per compiled call) against the
per-period path it replaces: the same recording byte for byte, the same final Simulator, the
same errors at the same period.

The per-period path (``Simulator.advance`` per period, the scripted command evaluated in Python,
outputs built per period) is the reference the rest of the suite checks against Pinocchio,
closed forms and the oracle recorder; here it is switched on by disabling the block planner.
Each case also asserts that the block path really ran most periods, so that a planner that
silently declines fails the test instead of comparing the reference with itself.
"""
from __future__ import annotations

import re
import warnings

import numpy as np
import pytest

from robodyn_ros import dynamics as dyn
from robodyn_ros import blocks as B
from robodyn_ros.bench import speed
from robodyn_ros.kernels import profiles as kprofiles
from robodyn_ros.recording.run_sink import HEADLESS_BATCH, McapRunSink
from robodyn_ros.scene import find_scene, load_scene, parse_scene
from robodyn_ros.simulation import CommandError, SimulationError, Simulator, run_headless


def _stanford_text(commands: str | None = None, limits: bool = False) -> str:
    text = find_scene('stanford_arm').read_text()
    if commands is not None:
        i = text.index('\ncommands:')
        j = text.index('\nsimulation:')
        text = text[:i] + '\ncommands:\n' + commands + text[j:]
    if limits:   # joint 5 (+-90 deg, at 0.8 rad) gets the joint-limit law: the work quadrature gains W_lim
        text = text.replace('limits: [-1.5707963267948966, 1.5707963267948966]}',
                            'limits: {lower: 0.7, upper: 0.85, stiffness: 40.0, damping: 0.5}}')
    return text


VARIANTS = {
    'sine': '  effort: {profile: sine, amplitude: [3.0, 4.0, 4.0, 0.15, 0.2, 0.001], '
            'frequency_hz: [0.2, 0.25, 0.3, 0.4, 0.35, 0.5], phase: [0.1, 0.0, 0.3, 0.0, 0.0, 2.0], '
            'offset: [0.0, 30.0, 40.0, 0.0, 0.0, 0.0]}',
    'piecewise_constant': '  effort: {profile: piecewise_constant, times: [0.1, 0.35, 0.6], '
                          'values: [[1, 40, 45, 0, 0, 0], [-1, 35, 40, 0.1, 0, 0], [0, 42, 43, 0, -0.1, 0]]}',
    'constant': '  effort: {profile: constant, value: [0.5, 40.0, 42.0, 0.0, 0.0, -0.0]}',
    'zero': '  effort: {profile: zero}',
}


def _scene(case: str, backend: str):
    with speed._backend(backend), warnings.catch_warnings():
        warnings.simplefilter('ignore')
        if case in VARIANTS:
            return parse_scene(_stanford_text(VARIANTS[case]), file=f'stanford_{case}.yaml')
        if case == 'limits':
            return parse_scene(_stanford_text(limits=True), file='stanford_limits.yaml')
        return load_scene(case)


class _Count:
    """Counts the periods the block path commits (to prove it ran)."""

    def __init__(self, monkeypatch):
        self.periods = 0
        self.calls = 0   # the pieces handed to the sinks
        orig = B.BlockRunner._commit

        def commit(runner, a, b, *rest):
            self.periods += b - a
            self.calls += 1
            return orig(runner, a, b, *rest)
        monkeypatch.setattr(B.BlockRunner, '_commit', commit)


def _run(tmp_path, scene, tag, duration, integrator='rk4', dt=1e-3, script=None, record=True, rate=100.0,
         diagnostics_periods=(0.05,), chunk_size=3000, refuse=None, halt_at=None):
    """refuse: (t_a, t_b), the first recorder refuses blocks whose first period ends in [t_a, t_b);
    halt_at: run_headless's ``halt`` says stop once the Simulator has reached this time."""
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        sim = Simulator(scene.system, scene.y0, integrator=integrator, dt=dt)
    paths = [tmp_path / f'{tag}{i or ""}.mcap' for i in range(len(diagnostics_periods))]
    sinks = [McapRunSink(path, scene, {'integrator': integrator, 'dt': dt}, batch=HEADLESS_BATCH,
                         diagnostics_period=d) for path, d in zip(paths, diagnostics_periods)] if record else []
    for s in sinks:
        s.writer.chunk_size = chunk_size   # chunk boundaries inside batches and blocks
    if refuse is not None:
        takes = sinks[0].block_periods
        def refusing(t_out, *a):   # none in the window; up to it before (a lone recorder takes whole blocks)
            if refuse[0] <= t_out[0] < refuse[1]:
                return 0
            return min(takes(t_out, *a), int(np.searchsorted(t_out, refuse[0], 'left')) or len(t_out))
        sinks[0].block_periods = refusing
    err = None
    try:
        n = run_headless(sim, duration, rate, {None: scene.script, 'none': None}.get(script, script), sinks,
                         halt=None if halt_at is None else (lambda: sim.t >= halt_at))
    except (CommandError, SimulationError) as e:
        n, err = None, e
    finally:
        for s in sinks:
            s.close()
    data = b''.join(p.read_bytes() + b'|' for p in paths) if record else None
    return data, n, sim, err


def _both(tmp_path, monkeypatch, scene, duration, **kw):
    count = _Count(monkeypatch)
    fast = _run(tmp_path, scene, 'block', duration, **kw)
    blocked = count.periods
    monkeypatch.setattr(B.BlockRunner, 'plan', classmethod(lambda cls, *a: None))
    slow = _run(tmp_path, scene, 'period', duration, **kw)
    return fast, slow, blocked


def _same_simulator(a: Simulator, b: Simulator):
    assert a.t == b.t
    assert np.array_equal(a.y, b.y) and np.array_equal(np.signbit(a.y), np.signbit(b.y))
    assert a.diag.work == b.diag.work and a.diag.work_parts == b.diag.work_parts
    assert (a.diag.steps, a.diag.rhs_evals) == (b.diag.steps, b.diag.rhs_evals)
    assert a.integrator.stats == b.integrator.stats
    for k in a.ports:
        assert np.array_equal(a.ports[k].value, b.ports[k].value) and a.ports[k].stamp == b.ports[k].stamp
    assert a.diagnostics_values() == b.diagnostics_values()


CASES = [('stanford_arm', 'generated'), ('stanford_arm', 'numba'), ('betancur_pendulum', 'generated'),
         ('huston_p19_2_3', 'numba'), ('huston_p19_4_1', 'generated'), ('huston_p19_4_1', 'numba'),
         ('sine', 'generated'), ('piecewise_constant', 'numba'), ('constant', 'generated'), ('zero', 'numba'),
         ('limits', 'generated'), ('limits', 'numba')]


@pytest.mark.parametrize('case,backend', CASES)
def test_block_path_records_the_per_period_bytes(tmp_path, monkeypatch, case, backend):
    scene = _scene(case, backend)
    (fast, n, sim_f, err_f), (slow, n_s, sim_s, err_s), blocked = _both(tmp_path, monkeypatch, scene, 1.0)
    assert err_f is None and err_s is None and n == n_s == 100
    assert blocked >= 90, f'the block path ran {blocked} of 100 periods'
    assert sim_f.diag.block_periods == blocked and sim_s.diag.block_periods == 0
    assert fast == slow, f'{case}: recordings differ ({len(fast)} vs {len(slow)} bytes)'
    _same_simulator(sim_f, sim_s)
    if case == 'limits':   # the case does exercise the limit law (the W_lim part is not zero)
        assert abs(sim_f.diag.work_parts['limit']) > 1e-6


@pytest.mark.parametrize('integrator', ['euler', 'semi_implicit_euler'])
def test_block_path_other_fixed_step_methods(tmp_path, monkeypatch, integrator):
    scene = _scene('stanford_arm', 'numba')
    (fast, n, sim_f, _), (slow, _, sim_s, _), blocked = _both(tmp_path, monkeypatch, scene, 0.5,
                                                              integrator=integrator, dt=5e-4)
    assert blocked >= 45 and fast == slow
    _same_simulator(sim_f, sim_s)


def test_block_path_without_a_recorder(tmp_path, monkeypatch):
    scene = _scene('stanford_arm', 'generated')
    (_, n, sim_f, _), (_, _, sim_s, _), blocked = _both(tmp_path, monkeypatch, scene, 0.6, record=False)
    assert n == 60 and blocked == 59   # period 0 on the per-period path, then one block
    _same_simulator(sim_f, sim_s)


def _piecewise_script(scene, times, values):
    """A script of one piecewise-constant effort profile, Python and compiled forms, built
    without the scene loader (which refuses non-finite values)."""
    times, values = np.array(times, dtype=float), np.array(values, dtype=float)

    def f(t, y):
        j = int(np.searchsorted(times, t, side='right')) - 1
        return (np.zeros(values.shape[1]) if j < 0 else values[j]).copy()

    def script(t, y):
        return {'effort': f(t, y)}
    e = np.zeros((0, 0))
    script.programs = {'effort': (kprofiles.CMD_PIECEWISE, e, times, values, e, e)}
    return script


def test_a_non_finite_command_is_refused_at_the_same_period(tmp_path, monkeypatch):
    scene = _scene('stanford_arm', 'generated')
    g = scene.script(0.0, scene.y0)['effort']
    bad = g.copy()
    bad[2] = np.nan
    script = _piecewise_script(scene, [0.0, 0.42], [g, bad])
    (fast, _, sim_f, err_f), (slow, _, sim_s, err_s), blocked = _both(tmp_path, monkeypatch, scene, 1.0,
                                                                      script=script)
    assert isinstance(err_f, CommandError) and isinstance(err_s, CommandError)
    assert str(err_f) == str(err_s) and 'non-finite' in str(err_f)
    assert abs(sim_f.t - 0.42) < 1e-12 and blocked == 40   # periods 0 and 1 start a recorder's layouts
    assert fast == slow   # the recording keeps every period before the refused command
    _same_simulator(sim_f, sim_s)
    assert sim_f.ports['effort'].rejected == 1


def test_a_diverging_state_fails_at_the_same_period_keeping_the_last_good_state(tmp_path, monkeypatch):
    scene = _scene('stanford_arm', 'numba')
    g = scene.script(0.0, scene.y0)['effort']
    script = _piecewise_script(scene, [0.0, 0.23], [g, g + 1e305])
    (fast, _, sim_f, err_f), (slow, _, sim_s, err_s), blocked = _both(tmp_path, monkeypatch, scene, 1.0,
                                                                      script=script)
    assert isinstance(err_f, SimulationError) and isinstance(err_s, SimulationError)
    assert str(err_f) == str(err_s) and re.search(r'non-finite', str(err_f))
    assert abs(sim_f.t - 0.23) < 1e-12 and blocked == 21 and np.all(np.isfinite(sim_f.y))
    assert fast == slow
    _same_simulator(sim_f, sim_s)


def _formula(params: dict, model, t, q):
    """A profile's command written out from its scene keys (the README's formulas), numpy; the
    gravity torques by the numpy reference RNEA (``dynamics.rnea``, not the compiled tree kernels)."""
    n = model.nv
    get = lambda k, default=0.0: np.asarray(params.get(k, np.full(n, default)), dtype=float)  # noqa: E731
    kind = params['profile']
    if kind == 'zero':
        return np.zeros(n)
    if kind == 'constant':
        return get('value')
    if kind == 'piecewise_constant':
        times, values = np.asarray(params['times'], float), np.asarray(params['values'], float)
        return np.zeros(n) if t < times[0] else values[np.searchsorted(times, t, side='right') - 1]
    sine = get('amplitude') * np.sin(2.0 * np.pi * get('frequency_hz') * t + get('phase'))
    if kind == 'sine':
        return get('offset') + sine
    assert kind == 'gravity_compensation_sine'
    z = np.zeros(n)
    return dyn.rnea(model, q, z, z) + get('stiffness') * (get('center') - q) + sine


@pytest.mark.parametrize('case', ['sine', 'piecewise_constant', 'constant', 'zero', 'stanford_arm', 'huston_p19_4_1'])
def test_profiles_give_the_commands_their_formulas_say(case):
    """Each profile's f(t, y) -- :func:`kernels.profiles.command_eval`, the profiles' one
    implementation, which the block path also runs -- against its formula from the scene's keys at
    random times and states: exactly for the piecewise, constant and zero profiles (signs of zero
    included), to 1e-12 for the sines (the sum's order) and the gravity compensation (another RNEA)."""
    scene = _scene(case, 'numba')
    params = scene.data['commands']['effort']
    f = scene.script.profiles['effort']
    assert scene.script.programs['effort'] is not None   # the block path runs it too
    sys_ = scene.system
    model = sys_.model
    assert sys_._B_is_selection and list(sys_.actuated) == list(model.dof_joint_names)   # B = 1
    rng = np.random.default_rng(15)
    worst = 0.0
    times = np.r_[0.0, 0.1, 0.35, 0.6, rng.uniform(0, 20, 40)]
    for t in times:
        y = scene.y0 + np.r_[rng.normal(0, 0.3, sys_.nq), rng.normal(0, 1, sys_.nv)]
        got = f(t, y)
        want = _formula(params, model, t, y[:sys_.nq])
        if params['profile'] in ('zero', 'constant', 'piecewise_constant'):
            assert np.array_equal(got, want) and np.array_equal(np.signbit(got), np.signbit(want)), (t, got - want)
        worst = max(worst, float(np.abs(got - want).max() / max(1.0, np.abs(want).max())))
    print(f'{case}: profile vs its formula, largest relative difference {worst:.1e}')
    assert worst <= 1e-12 and len(times) == 44


def test_the_planner_declines_what_it_cannot_run_in_blocks():
    # a profile without a compiled form, a stop condition, a per-period sink: the per-period path
    scene = _scene('stanford_arm', 'numba')
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        sim = Simulator(scene.system, scene.y0, integrator='rk4', dt=1e-3)
    plan = B.BlockRunner.plan
    assert plan(sim, scene.script, [], None, False) is not None

    def python_only(t, y):
        return scene.script(t, y)
    assert plan(sim, python_only, [], None, False) is None
    assert plan(sim, scene.script, [], lambda t, y: False, False) is None

    class PerPeriodSink:
        pass
    assert plan(sim, scene.script, [PerPeriodSink()], None, False) is None
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        adaptive = Simulator(scene.system, scene.y0, integrator='dop853', rtol=1e-8, atol=1e-10)
    assert plan(adaptive, scene.script, [], None, False) is None


def test_the_planner_asks_the_system_once_and_declines_for_spherical_joints(monkeypatch):
    # huston_human17 publishes Bryan angles (not its quaternion state): its arm declines blocks,
    # so the run never tries them (no block attempt per period)
    scene = _scene('huston_human17', 'numba')
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        sim = Simulator(scene.system, scene.y0, integrator='rk4', dt=1e-3)
    assert scene.script.programs['effort'] is not None
    assert B.BlockRunner.plan(sim, scene.script, [], None, False) is None
    tries = []
    monkeypatch.setattr(B.BlockRunner, 'run', lambda self, *a: tries.append(a) or a[0])
    assert run_headless(sim, 0.05, 100.0, scene.script, []) == 5 and tries == []


_WITHOUT_NUMBA = '''
import sys, warnings
sys.modules['numba'] = None   # as if numba were not installed (README: optional)
from robodyn_ros import kernels
assert not kernels.AVAILABLE
from robodyn_ros.recording.run_sink import HEADLESS_BATCH, McapRunSink
from robodyn_ros.scene import load_scene
from robodyn_ros.simulation import Simulator, run_headless
scene = load_scene(sys.argv[1])
for batch, path in ((HEADLESS_BATCH, sys.argv[2]), (0, sys.argv[3])):
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        sim = Simulator(scene.system, scene.y0, integrator='rk4', dt=1e-3)
    sink = McapRunSink(path, scene, {}, batch=batch, diagnostics_period=0.05)
    sink.writer.chunk_size = 3000
    assert run_headless(sim, 0.3, 100.0, scene.script, [sink]) == 30
    sink.close()
'''


@pytest.mark.parametrize('scene_name', ['stanford_arm', 'betancur_platform'])
def test_recording_without_numba_batches_the_message_by_message_bytes(tmp_path, scene_name):
    # the recorder's compiled loops (kernels/records.py: rows, record headers, message indexes,
    # /tf) run as Python without numba: a batched recording is still the file the
    # message-by-message path (batch=0, none of those loops) writes
    import subprocess
    import sys
    a, b = tmp_path / 'batched.mcap', tmp_path / 'by_message.mcap'
    r = subprocess.run([sys.executable, '-c', _WITHOUT_NUMBA, scene_name, str(a), str(b)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert a.stat().st_size > 30_000 and a.read_bytes() == b.read_bytes()


@pytest.mark.parametrize('kw,periods,blocked_min', [
    (dict(duration=0.0), 0, 0), (dict(duration=0.01), 1, 0), (dict(duration=0.02), 2, 0), (dict(duration=0.03), 3, 1),
    (dict(duration=0.77, rate=30.0), 23, 21),           # another rate, a duration not a multiple of its period
    (dict(duration=0.5013, rate=250.0), 125, 123),
    (dict(duration=0.5, diagnostics_periods=(0.003,)), 50, 48),   # a diagnostics message every period
    (dict(duration=1.5, diagnostics_periods=(2.0,)), 150, 148),   # one, at t0 (blocks of 64 in one piece)
    (dict(duration=1.5, diagnostics_periods=(0.137,)), 150, 148),
    (dict(duration=0.5, chunk_size=1), 50, 48),        # a chunk per message
    (dict(duration=1.0, diagnostics_periods=(0.05, 0.13)), 100, 98),   # two recorders, pieces where either wants
    (dict(duration=1.5, refuse=(0.3, 0.55)), 150, 100),   # a recorder refusing blocks for a while
])
def test_block_path_edge_cases_record_the_per_period_bytes(tmp_path, monkeypatch, kw, periods, blocked_min):
    scene = _scene('stanford_arm', 'numba')
    (fast, n, sim_f, err_f), (slow, n_s, sim_s, err_s), blocked = _both(tmp_path, monkeypatch, scene, **kw)
    assert err_f is None and err_s is None and n == n_s == periods
    assert blocked >= blocked_min and sim_f.diag.block_periods == blocked
    if 'refuse' in kw:   # the periods refused ran on the per-period path, the others in blocks
        assert blocked <= periods - 25
    assert fast == slow
    _same_simulator(sim_f, sim_s)


def test_a_lone_recorder_takes_a_block_in_one_piece(tmp_path, monkeypatch):
    """A lone recorder takes each block in one piece and puts the Simulator at each diagnostics
    message's period itself (``PeriodBlock.arrive``): the per-period path's bytes and Simulator."""
    scene = _scene('stanford_arm', 'numba')
    count = _Count(monkeypatch)
    fast = _run(tmp_path, scene, 'block', 1.0, diagnostics_periods=(0.05,))
    assert count.periods >= 98 and count.calls <= 3, (count.periods, count.calls)   # not a piece per message (20)
    monkeypatch.setattr(B.BlockRunner, 'plan', classmethod(lambda cls, *a: None))
    slow = _run(tmp_path, scene, 'period', 1.0, diagnostics_periods=(0.05,))
    assert fast[0].count(b'diagnostic_msgs/msg/DiagnosticArray') >= 1 and fast[0] == slow[0]
    _same_simulator(fast[2], slow[2])


def test_is_selection():
    from robodyn_ros.systems.arm import _is_selection
    assert _is_selection(np.eye(3)) and _is_selection(np.eye(4)[:, [2, 0]]) and _is_selection(np.zeros((3, 2)))
    assert not _is_selection(2.0 * np.eye(3))                         # a gear ratio
    assert not _is_selection(np.array([[1.0, 1.0], [0.0, 0.0]]))      # one torque from two inputs
    assert not _is_selection(np.array([[1.0, 0.0], [1.0, 0.0]]))      # one input on two joints
    assert not _is_selection(np.array([[-1.0, 0.0], [0.0, 1.0]]))     # a sign flip


def test_fused_periods_declines_where_fused_advance_does():
    # a work state other than [y, W] / [y, W, W_lim], or a method the fused loop does not have
    scene = _scene('stanford_arm', 'numba')
    sys_ = scene.system
    u = np.zeros(sys_.inputs['effort'].size)
    t0, t1 = np.array([0.0]), np.array([0.01])
    for z in (np.r_[scene.y0, 0.0], np.r_[scene.y0, 0.0, 0.0]):
        assert sys_.fused_periods('rk4', 1e-3, z.copy(), t0, t1, u.copy()) is not None
        assert sys_.fused_advance('rk4', 1e-3, 0.0, z.copy(), 0.01, {'effort': u}) is not None
    for name, z in (('rk4', np.r_[scene.y0, 0.0, 0.0, 0.0]), ('rk4', scene.y0.copy()),
                    ('midpoint', np.r_[scene.y0, 0.0])):
        assert sys_.fused_advance(name, 1e-3, 0.0, z.copy(), 0.01, {'effort': u}) is None
        assert sys_.fused_periods(name, 1e-3, z.copy(), t0, t1, u.copy()) is None, (name, z.shape)


def test_a_command_timeout_acts_as_on_the_per_period_path(tmp_path, monkeypatch):
    # a command set before the run, no script: it times out after 0.05 s (the block path would
    # hold it; the planner declines timeouts, so the run is the per-period one)
    scene = _scene('stanford_arm', 'numba')
    g = scene.script(0.0, scene.y0)['effort']

    def run(tag):
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            sim = Simulator(scene.system, scene.y0, integrator='rk4', dt=1e-3, command_timeout=0.05)
        sim.set_command('effort', g)
        sink = McapRunSink(tmp_path / f'{tag}.mcap', scene, {}, batch=HEADLESS_BATCH, diagnostics_period=0.05)
        assert run_headless(sim, 0.5, 100.0, None, [sink]) == 50
        sink.close()
        return (tmp_path / f'{tag}.mcap').read_bytes(), sim
    fast, sim_f = run('block')
    monkeypatch.setattr(B.BlockRunner, 'plan', classmethod(lambda cls, *a: None))
    slow, sim_s = run('period')
    assert sim_s.ports['effort'].timed_out and sim_f.ports['effort'].timed_out
    assert fast == slow
    _same_simulator(sim_f, sim_s)


def test_an_arm_whose_outputs_are_replaced_is_recorded_as_they_say(tmp_path, monkeypatch):
    # the block path computes joint_states and wrenches in its compiled loop instead of calling
    # outputs(): an arm whose outputs() is replaced (here on the instance: effort read by a
    # sensor with an offset) runs per period, and the recording shows what outputs() says
    scene = _scene('stanford_arm', 'numba')
    sys_ = scene.system
    orig = sys_.outputs

    def outputs(t, y, u, wrenches=True):
        out = orig(t, y, u, wrenches)
        out.effort = out.effort + 0.25
        return out
    monkeypatch.setattr(sys_, 'outputs', outputs, raising=False)
    (fast, n, sim_f, err_f), (slow, _, sim_s, _), blocked = _both(tmp_path, monkeypatch, scene, 0.3)
    assert err_f is None and n == 30 and blocked == 0
    assert fast == slow
    _same_simulator(sim_f, sim_s)


@pytest.mark.parametrize('record', [False, True])
@pytest.mark.parametrize('kind', ['nan', 'diverge'])
def test_a_failure_at_period_1_is_that_of_the_per_period_path(tmp_path, monkeypatch, record, kind):
    # the first period a block can run: the compiled loop refuses at its first period (done = 0)
    scene = _scene('stanford_arm', 'numba')
    g = scene.script(0.0, scene.y0)['effort']
    bad = g.copy()
    bad[0] = np.nan if kind == 'nan' else 1e305
    script = _piecewise_script(scene, [0.0, 0.01], [g, bad])
    from robodyn_ros.systems.arm import ArmSystem
    calls = []
    fused = ArmSystem.fused_periods

    def spy(self, *a, **k):
        res = fused(self, *a, **k)
        calls.append(None if res is None else (len(a[3]), res[0], res[1]))
        return res
    monkeypatch.setattr(ArmSystem, 'fused_periods', spy)
    (fast, _, sim_f, err_f), (slow, _, sim_s, err_s), blocked = _both(tmp_path, monkeypatch, scene, 0.5,
                                                                      script=script, record=record)
    want = CommandError if kind == 'nan' else SimulationError
    assert isinstance(err_f, want) and isinstance(err_s, want) and str(err_f) == str(err_s)
    assert blocked == 0 and abs(sim_f.t - 0.01) < 1e-12 and np.all(np.isfinite(sim_f.y))
    if not record:   # the compiled loop ran period 1 and refused it (a recorder takes periods 0 and 1 itself)
        assert calls[-1] == (49, 0, 1 if kind == 'nan' else 2), calls
    assert fast == slow
    _same_simulator(sim_f, sim_s)


class _Ahead:
    """The BlockRunners of a test's runs and their blocks computed ahead (``BlockRunner.ahead``: used, dropped),
    pipelining forced on whatever CPUs this machine has (``blocks._pipelines``)."""

    def __init__(self, monkeypatch, on=True):
        self.runners = []
        monkeypatch.setattr(B, '_pipelines', lambda: on)
        init = B.BlockRunner.__init__

        def spy(runner, *a, **k):
            init(runner, *a, **k)
            self.runners.append(runner)
        monkeypatch.setattr(B.BlockRunner, '__init__', spy)

    def counts(self):
        return [sum(r.used[0] for r in self.runners), sum(r.dropped[0] for r in self.runners)]


@pytest.mark.parametrize('case,backend,kw', [
    ('limits', 'generated', {}), ('sine', 'numba', {}), ('piecewise_constant', 'generated', {}),
    ('stanford_arm', 'numba', dict(diagnostics_periods=(0.05, 0.13))),   # two recorders: pieces
    ('stanford_arm', 'numba', dict(record=False)),
    ('stanford_arm', 'generated', dict(script='none')),                    # no script: the command held
    ('a1_stand', 'numba', dict(integrator='rosenbrock2', rate=200.0)),    # a free root on a ground
    # the same with the recorder's own chunks: its batches then take many periods, whose markers come from the
    # block's contact points (with 3000-byte chunks a batch takes one A1 period)
    ('a1_stand', 'numba', dict(integrator='rosenbrock2', rate=200.0, chunk_size=768 * 1024)),
])
def test_the_block_computed_ahead_gives_the_bytes_of_the_block_computed_in_turn(tmp_path, monkeypatch, case,
                                                                                  backend, kw):
    """While the sinks take a block, the next is computed on a second thread from where the block ends: the
    same recording and Simulator as without it and as the per-period path, and it is used (not dropped and
    computed again)."""
    scene = _scene(case, backend)
    duration = 2.0
    ahead = _Ahead(monkeypatch)
    piped = _run(tmp_path, scene, 'piped', duration, **kw)
    used, dropped = ahead.counts()
    monkeypatch.setattr(B, '_pipelines', lambda: False)
    plain = _run(tmp_path, scene, 'plain', duration, **kw)
    assert ahead.counts() == [used, dropped]   # (nothing computed ahead without pipelining)
    monkeypatch.setattr(B.BlockRunner, 'plan', classmethod(lambda cls, *a: None))
    slow = _run(tmp_path, scene, 'period', duration, **kw)
    n = int(round(duration * kw.get('rate', 100.0)))
    blocks = -(-(n - 2) // B.BLOCK_PERIODS)   # periods 0 and 1 on the per-period path, then blocks of 64
    # every block after the first computed ahead and taken; without a sink nothing is (nothing to overlap)
    assert (used, dropped) == ((blocks - 1) if kw.get('record', True) else 0, 0)
    assert piped[1] == plain[1] == slow[1] == n and piped[3] is None and slow[3] is None
    assert piped[0] == plain[0] == slow[0]
    _same_simulator(piped[2], plain[2])
    _same_simulator(piped[2], slow[2])


def test_a_block_computed_ahead_is_dropped_where_the_sinks_stop_taking_blocks(tmp_path, monkeypatch):
    scene = _scene('stanford_arm', 'numba')
    ahead = _Ahead(monkeypatch)
    piped = _run(tmp_path, scene, 'piped', 1.5, refuse=(0.3, 0.55))
    used, dropped = ahead.counts()
    assert dropped >= 1   # the block ahead of the one refused from 0.3 on
    monkeypatch.setattr(B.BlockRunner, 'plan', classmethod(lambda cls, *a: None))
    slow = _run(tmp_path, scene, 'period', 1.5, refuse=(0.3, 0.55))
    assert piped[1] == slow[1] == 150 and piped[0] == slow[0]
    _same_simulator(piped[2], slow[2])


def test_a_block_computed_ahead_is_taken_only_from_the_same_bits():
    """``_Ahead.take`` compares the inputs bit for bit: a command of -0.0 where +0.0 was assumed is another block;
    after the thread's last block it says None."""
    class _Sim:
        diag = type('D', (), {'wall': 0.0})()
    runner = B.BlockRunner(_Sim(), 'effort', None, [], False)
    ahead = B._Ahead.__new__(B._Ahead)
    import queue
    ahead.runner, ahead.done, ahead.taken = runner, queue.Queue(), 0
    z, t_cmd, t_out = np.arange(4.0), np.array([0.1, 0.2]), np.array([0.2, 0.3])
    cases = [(np.array([0.0, 1.0]), True), (np.array([-0.0, 1.0]), False),
             (np.array([0.0, 1.0 + 2 ** -52]), False), (np.array([0.0]), False)]
    for _ in cases:
        ahead.done.put(((z.copy(), t_cmd, t_out, np.array([0.0, 1.0])), 'res', 0.5, None))
    ahead.done.put(None)
    for u_now, taken in cases:
        got = ahead.take((z, t_cmd, t_out, u_now))
        assert got == ('res' if taken else None), (u_now, got)
    assert ahead.take((z, t_cmd, t_out, cases[0][0])) is None and ahead.take((z, t_cmd, t_out, cases[0][0])) is None
    assert (runner.used, ahead.taken) == ([1], 1) and _Sim.diag.wall == 0.5


def test_a_sweeps_runs_take_blocks_on_one_thread(tmp_path, monkeypatch):
    """A sweep's runs fill the pool's cores already: its block path computes nothing ahead, while
    robodyn run's recorded runs of the same scene do (``_Ahead`` counted both ways)."""
    from robodyn_ros import sweep as S
    ahead = _Ahead(monkeypatch)
    spec = tmp_path / 'spec.yaml'
    spec.write_text('scene: stanford_arm\nduration: 2.0\ngrid: {integrator: [rk4]}\nfigures: [energy_drift]\n')
    (task,) = S.expand(S.load_spec(str(spec)))
    row = S.execute_run(task)['row']
    assert row['status'] == 'ok', row
    assert ahead.runners and sum(r.sim.diag.block_periods for r in ahead.runners) >= 190
    assert ahead.counts() == [0, 0]
    _run(tmp_path, _scene('stanford_arm', 'numba'), 'run', 2.0)
    assert ahead.counts()[0] == 3


def test_a_sink_failing_mid_run_leaves_no_thread_computing_ahead(tmp_path, monkeypatch):
    """A recorder raising in the middle of a run (a full disk): run_headless raises its error, and the thread
    computing ahead has stopped by then (it shares the loop's work arrays with whatever runs next)."""
    import threading
    scene = _scene('stanford_arm', 'numba')
    ahead = _Ahead(monkeypatch)
    calls = []
    orig = McapRunSink.on_block

    def on_block(sink, blk, sim, *a, **k):
        calls.append(len(blk.t_out))
        if len(calls) == 3:
            raise OSError(28, 'No space left on device')
        return orig(sink, blk, sim, *a, **k)
    monkeypatch.setattr(McapRunSink, 'on_block', on_block)
    with pytest.raises(OSError, match='No space left'):
        _run(tmp_path, scene, 'full', 5.0)
    assert len(calls) == 3 and ahead.counts()[0] == 2   # blocks 2 and 3 came from the thread
    assert not [t for t in threading.enumerate() if t.name == 'robodyn-blocks']
    assert ahead.counts()[1] >= 1   # what it had computed beyond block 3 was dropped


@pytest.mark.parametrize('path,kw,piece', [
    ('blocks', {}, B.BLOCK_PERIODS),                                  # a lone recorder: whole blocks
    ('blocks', dict(diagnostics_periods=(0.05, 0.13)), 13),           # two recorders: pieces
    ('periods', {}, 1),
    ('blocks', dict(integrator='rosenbrock2', rate=200.0, case='a1_stand'), B.BLOCK_PERIODS),
])
def test_a_halted_run_ends_where_its_recording_ends(tmp_path, monkeypatch, path, kw, piece):
    """``halt`` (a Ctrl-C's flag) asked at each period boundary: the run stops at the first boundary after it
    holds, with every period up to the Simulator's state in the recording and none after it. The halted files
    are byte for byte those of a run whose duration ends there, and so is the Simulator; the blocks computed
    ahead past it are dropped."""
    kw = dict(kw)
    scene = _scene(kw.pop('case', 'stanford_arm'), 'numba')
    rate = kw.get('rate', 100.0)
    ahead = _Ahead(monkeypatch)
    if path == 'periods':
        monkeypatch.setattr(B.BlockRunner, 'plan', classmethod(lambda cls, *a: None))
    halted = _run(tmp_path, scene, 'halted', 5.0, halt_at=1.7, **kw)
    n = halted[1]
    assert halted[3] is None and 1.7 <= n / rate < 1.7 + piece / rate + 1e-9, n   # the first boundary after
    assert abs(halted[2].t - n / rate) < 1e-12
    if path == 'blocks':
        assert ahead.counts()[0] >= 1 and halted[2].diag.block_periods > n // 2   # (the block path ran)
    short = _run(tmp_path, scene, 'short', n / rate, **kw)
    assert short[1] == n
    assert halted[0] == short[0]
    _same_simulator(halted[2], short[2])


XARM_MIXED = """name: xarm7_mixed
parts:
  - kind: urdf
    name: xarm7
    file: package://example-robot-data/robots/xarm_description/urdf/xarm7.urdf
    command_interfaces: {position: [joint1, joint2, joint3, joint4], velocity: [joint5]}
commands:
  effort: {profile: sine, amplitude: [0.5, 40.0], frequency_hz: [1.0, 1.5], phase: [0.0, 0.5], offset: [0.0, 0.1]}
  trajectory:
    profile: trajectory
    messages:
      - {points: [{time_from_start: 0.5, positions: [0.2, -0.1, 0.1, 0.5]}]}
      - {send_at: 0.355, points: [{time_from_start: 0.3, positions: [0.4, 0.1, -0.1, 0.8], velocities: [0, 0, 0, 0]}]}
      - {send_at: 0.8, points: [{time_from_start: 0.2, positions: [0.0, 0.0, 0.0, 0.3]},
                                {time_from_start: 0.6, positions: [0.1, 0.1, 0.1, 0.4]}]}
sensors:
  - {kind: force_torque, joint: joint7, frame: link_eef, name: wrist, noise: {force: 0.5}, seed: 3}
  - {kind: imu, link: link7, name: hand, noise: {linear_acceleration: 0.1}, bias: {angular_velocity: [0.001, 0, 0]},
     seed: 4}
simulation: {integrator: rosenbrock2, dt: 1.0e-3}
"""


def _a1_text(servo: bool) -> str:
    """a1_stand with an IMU on the trunk and a force-torque sensor in a calf (on a floating base on the ground);
    servo: its joints position-commanded, a trajectory message holding the posture at 0.25 s, instead of pd_hold."""
    text = find_scene('a1_stand').read_text()
    sensors = ('\nsensors:\n  - {kind: imu, link: trunk, name: body, noise: {angular_velocity: 0.01}, seed: 2}\n'
               '  - {kind: force_torque, joint: FR_calf_joint, frame: FR_calf, name: fr_knee}')
    if not servo:
        j = text.index('\ninitial_state:')
        return text[:j] + sensors + text[j:]
    text = text.replace('    floating: true\n', '    floating: true\n    command_interfaces: position\n')
    i, j = text.index('\ncommands:'), text.index('\ninitial_state:')
    posture = '[0.0, 0.8, -1.5, 0.0, 0.8, -1.5, 0.0, 0.8, -1.5, 0.0, 0.8, -1.5]'
    commands = ('\ncommands:\n  trajectory:\n    profile: trajectory\n    send_at: 0.25\n'
                f'    points: [{{time_from_start: 0.2, positions: {posture}}}]')
    return text[:i] + commands + sensors + text[j:]


def _servo_scene(case):
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        if case == 'xarm7_trajectory':
            return load_scene(case)
        if case in ('a1_sensors', 'a1_servo'):
            return parse_scene(_a1_text(case == 'a1_servo'), file=f'{case}.yaml')
        text = XARM_MIXED if case == 'mixed' else XARM_MIXED.replace('    command_interfaces', '    #')
        if case == 'sensors_only':   # no servo: one effort port, its sine over all seven joints
            i = text.index('commands:')
            text = text[:i] + 'commands:\n  effort: {profile: sine, amplitude: [0.5, 0.4, 0.3, 0.3, 0.2, 0.2, 0.1], ' \
                'frequency_hz: [1.0, 1.5, 2.0, 1.0, 1.5, 2.0, 1.0]}\n' + text[text.index('sensors:'):]
        return parse_scene(text, file=f'{case}.yaml')


@pytest.mark.parametrize('case,pieces', [('xarm7_trajectory', False), ('mixed', False), ('mixed', True),
                                         ('sensors_only', False), ('a1_sensors', False), ('a1_servo', False)])
def test_a_servo_and_sensors_take_blocks_with_the_per_period_bytes(tmp_path, monkeypatch, case, pieces):
    """An arm on position, velocity and effort commands (a joint servo with the model feed-forward, trajectory
    messages sent at 0, 0.355 and 0.8 s, an effort sine on the rest, one joint's effort clamped) with a
    force-torque sensor and an IMU, both noisy: its block path computes the servo at every stage and the
    sensors' messages of each period as outputs() does, so the recording (servo desired and error states,
    sensor readings, their markers) and the Simulator are those of the per-period path, byte for byte; so are the
    A1's on its ground (a floating base; its sensors read the contacts' forces), on pd_hold or position-commanded.
    Blocks end before each period at whose start a message is due (that period runs on the per-period path),
    and are computed ahead."""
    scene = _servo_scene(case)
    a1 = case.startswith('a1')   # a floating base on a ground, 200 Hz
    duration = 1.0 if a1 else 1.5
    kw = dict(integrator='rosenbrock2', diagnostics_periods=(0.05, 0.13) if pieces else (0.05,),
              rate=200.0 if a1 else 100.0)
    ahead = _Ahead(monkeypatch)
    count = _Count(monkeypatch)
    piped = _run(tmp_path, scene, 'piped', duration, **kw)
    blocked = count.periods
    monkeypatch.setattr(B.BlockRunner, 'plan', classmethod(lambda cls, *a: None))
    slow = _run(tmp_path, scene, 'period', duration, **kw)
    n = int(round(duration * kw['rate']))
    # the periods that send a message: mixed 36 and 80, a1_servo 50
    messages = {'xarm7_trajectory': 0, 'mixed': 2, 'sensors_only': 0, 'a1_sensors': 0, 'a1_servo': 1}[case]
    # period 0 (and 1, where the recorder first meets the commands' layout) and the messages' on the other path
    assert n - 2 - messages <= blocked <= n - 1 - messages and piped[2].diag.block_periods == blocked
    assert ahead.counts()[0] >= 1 and ahead.counts()[1] == 0
    assert piped[1] == slow[1] == n and piped[3] is None and slow[3] is None
    assert piped[0] == slow[0]
    _same_simulator(piped[2], slow[2])
    from robodyn_ros.recording.reader import summarize
    topics = summarize(tmp_path / 'piped.mcap')['topics']
    servo = case not in ('sensors_only', 'a1_sensors')
    want = {'/markers'} | ({'/joint_trajectory_desired', '/joint_trajectory_error'} if servo else set())
    want |= {'/imu/body', '/ft/fr_knee'} if a1 else {'/imu/hand', '/ft/wrist'}
    assert want <= set(topics), sorted(topics)
    if a1:   # standing on its feet: contacts in the recording and touching at the end
        assert sum('contact' in t for t in topics) >= 4 and piped[2].diagnostics_values()['contact_active'] >= 3
    if case == 'mixed':   # the clamped joint: its command beyond the URDF's effort limit
        assert piped[2].ports['effort'].clamped > 0
