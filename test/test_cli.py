"""The offline CLI end to end: run -> MCAP -> check, independent readers, byte-identical reruns."""
import subprocess
import sys

import numpy as np
import pytest

ROBODYN = [sys.executable, '-m', 'robodyn_ros.cli']


def _run(*args, check=True):
    p = subprocess.run(ROBODYN + list(args), capture_output=True, text=True, timeout=240)
    if check and p.returncode != 0:
        raise AssertionError(f'robodyn {" ".join(args)} exited {p.returncode}\n{p.stdout}\n{p.stderr}')
    return p


@pytest.fixture(scope='module')
def stanford_run(tmp_path_factory):
    """One second of stanford_arm at 100 Hz, recorded twice."""
    d = tmp_path_factory.mktemp('cli')
    a, b = d / 'a.mcap', d / 'b.mcap'
    pa = _run('run', 'stanford_arm', '--duration', '1', '--record', str(a))
    _run('run', 'stanford_arm', '--duration', '1', '--record', str(b))
    return a, b, pa.stdout


def test_run_prints_summary(stanford_run):
    _, _, out = stanford_run
    for word in ('scene', 'stanford_arm', 'real-time factor', 'energy', 'drift', 'recording'):
        assert word in out


def test_recording_counts_then_contents(stanford_run):
    from robodyn_ros.recording.reader import read_messages, summarize
    from robodyn_ros.scene import load_scene
    a, _, _ = stanford_run
    s = summarize(a)
    n_joints = load_scene('stanford_arm').system.model.nb
    topics = s['topics']
    assert s['finished'] and s['profile'] == 'ros2'
    assert topics['/joint_states']['count'] == 101
    assert topics['/clock']['count'] == 101
    assert topics['/effort_commands']['count'] == 100
    assert topics['/robot_description']['count'] == 1
    assert topics['/diagnostics']['count'] == 11  # every 0.1 s of simulated time, both ends included
    assert topics['/tf']['count'] == 101          # moving joints, every publication
    assert topics['/tf_static']['count'] == 1     # the fixed tool joint, once, latched
    assert 'transient_local' in topics['/tf_static']['offered_qos_profiles']
    wrench_topics = [t for t in topics if t.startswith('/constraint_wrenches/')]
    assert len(wrench_topics) == n_joints
    assert 'transient_local' in topics['/robot_description']['offered_qos_profiles']
    md = s['metadata']['robodyn']
    assert 'stanford_arm' in md['scene_name'] and md['package_version'] and 'rk4' in md['settings']
    assert 'name: stanford_arm' in md['scene'] or 'stanford' in md['scene']
    # contents: log_time = header stamp = 10 ms grid; positions finite
    js = [(t, m) for topic, _, t, m in read_messages(a, topics=['/joint_states'])]
    assert len(js) == 101
    times = np.array([t for t, _ in js])
    assert np.array_equal(times, np.arange(101) * 10_000_000)
    stamps = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, m in js])
    assert np.array_equal(stamps, times)
    assert len(js[-1][1].name) == 6 and np.all(np.isfinite(js[-1][1].position))


def test_equal_runs_are_byte_identical(stanford_run):
    a, b, _ = stanford_run
    assert a.read_bytes() == b.read_bytes()


def test_rosbags_reads_every_message(stanford_run):
    from rosbags.highlevel import AnyReader
    from robodyn_ros.recording.reader import summarize
    a, _, _ = stanford_run
    n = 0
    with AnyReader([a]) as reader:
        for conn, t, raw in reader.messages():
            reader.deserialize(raw, conn.msgtype)
            n += 1
    assert n == summarize(a)['message_count'] > 300


def test_check_accepts_and_rejects(stanford_run, tmp_path):
    a, _, _ = stanford_run
    p = _run('check', str(a))
    assert 'OK' in p.stdout and '/joint_states' in p.stdout
    cut = tmp_path / 'cut.mcap'
    data = a.read_bytes()
    cut.write_bytes(data[: len(data) * 2 // 3])
    p = _run('check', str(cut), check=False)
    assert p.returncode == 1 and 'not finished' in p.stdout


def test_scenes_lists_bundled_scenes():
    p = _run('scenes')
    for name in ('stanford_arm', 'betancur_pendulum', 'huston_p19_2_3'):
        assert name in p.stdout


def test_broken_scene_refused_with_file_key_reason(tmp_path):
    from robodyn_ros.scene import load_scene
    text = open(load_scene('betancur_pendulum').path).read()
    bad = tmp_path / 'bad.yaml'
    bad.write_text(text.replace('mass: 0.1', 'mass: -0.1', 1))
    assert bad.read_text() != text  # the mutation happened
    p = _run('run', str(bad), '--duration', '0.1', check=False)
    assert p.returncode != 0
    assert 'bad.yaml' in p.stderr and 'mass' in p.stderr


@pytest.mark.parametrize('option, value', [('--rate', '-1'), ('--dt', '-1'), ('--dt', 'nan'), ('--duration', '-0.5'),
                                           ('--rtol', '0'), ('--rate', 'abc')])
def test_a_bad_number_is_refused_in_one_line_naming_the_option(option, value):
    # (a negative rate ended in a traceback, a negative dt in a stability diagnosis, a negative duration in a run
    # of no periods)
    p = _run('run', 'stanford_arm', option, value, check=False)
    assert p.returncode == 2 and 'Traceback' not in p.stderr, p.stderr
    last = p.stderr.strip().splitlines()[-1]
    assert last.startswith('robodyn run: error: argument ' + option) and repr(value) in last, last


def test_unknown_integrator_refused():
    p = _run('run', 'betancur_pendulum', '--duration', '0.1', '--integrator', 'leapfrogg', check=False)
    assert p.returncode == 2 and 'leapfrogg' in p.stderr and 'rk4' in p.stderr


@pytest.mark.processes
@pytest.mark.parametrize('signame,status,said', [('SIGINT', 130, 'Ctrl-C'), ('SIGTERM', 143, 'SIGTERM')])
def test_ctrl_c_finishes_the_recording_up_to_the_period_it_stopped_at(tmp_path, signame, status, said):
    """Ctrl-C (or SIGTERM: a container stopped) during a long recorded run on the block path (its next blocks
    computed ahead): exit 128 + the signal, a line saying where it stopped, and a finished recording whose last
    period is that time, every period before it there once. The signal is sent once the file has grown past its
    first chunks (the run is recording), not after a sleep; wherever it lands, the run ends at the next boundary
    where the recording and the Simulator agree."""
    import signal
    import time
    from robodyn_ros.recording.reader import read_messages, summarize
    out = tmp_path / 'int.mcap'
    p = subprocess.Popen(ROBODYN + ['run', 'stanford_arm', '--duration', '36000', '--record', str(out)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 200
        while not (out.exists() and out.stat().st_size > 3_000_000):
            assert p.poll() is None and time.monotonic() < deadline, p.communicate()
            time.sleep(0.02)
        p.send_signal(getattr(signal, signame))
        stdout, stderr = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == status, (stdout, stderr)
    assert 'Traceback' not in stderr, stderr
    line = next(x for x in stdout.splitlines() if x.startswith('stopped'))
    assert f'by {said} at t=' in line, line
    t_stop = float(line.split('t=')[1].split(' s')[0])
    assert 1.0 < t_stop < 36000.0, line
    s = summarize(out)
    assert s['finished']
    n = int(round(t_stop * 100))   # 100 Hz: periods 0..n published
    assert s['topics']['/joint_states']['count'] == s['topics']['/clock']['count'] == n + 1
    last = None
    for _, _, _, m in read_messages(out, topics=['/clock']):
        last = m.clock
    assert abs(last.sec + last.nanosec * 1e-9 - t_stop) < 1e-6
