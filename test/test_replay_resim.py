"""``robodyn replay`` (real rclpy: the replay runs in a subprocess, the test subscribes) and
``robodyn resim`` (exact re-simulation, deviation detection, exit codes)."""
import json
import os
import subprocess
import sys
import time

import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ros_helpers import REPO, Domain, Proc, RosClient  # noqa: E402

from robodyn_ros.cli import main as robodyn  # noqa: E402
from robodyn_ros.nodes.ports import command_values  # noqa: E402
from robodyn_ros.recording import decode, read_raw_messages, summarize  # noqa: E402
from robodyn_ros.simulation import CommandError  # noqa: E402

pytestmark = pytest.mark.processes   # robodyn replay in a subprocess, paced by the wall clock

ROBODYN = [sys.executable, '-c', 'import sys; from robodyn_ros.cli import main; sys.exit(main())']


@pytest.fixture(scope='module')
def headless(tmp_path_factory):
    """0.3 s of stanford_arm from ``robodyn run`` (scripted commands, 100 Hz)."""
    path = tmp_path_factory.mktemp('headless') / 'run.mcap'
    assert robodyn(['run', 'stanford_arm', '--duration', '0.3', '--record', str(path)]) == 0
    return path


def test_replay_publishes_the_recording_with_clock_and_latched_description(headless, tmp_path):
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String
    from diagnostic_msgs.msg import DiagnosticArray
    recorded = [(t, decode(ty, raw)) for _, ty, t, raw in read_raw_messages(headless, topics=['/joint_states'])]
    dom = Domain()
    client = RosClient(dom)
    proc = None
    try:
        got = {'js': [], 'clock': [], 'rd': [], 'diag': []}
        n = client.node
        n.create_subscription(JointState, 'joint_states', lambda m: got['js'].append((time.monotonic(), m)), 100)
        n.create_subscription(Clock, '/clock', got['clock'].append, 100)
        n.create_subscription(DiagnosticArray, 'diagnostics', got['diag'].append, 10)
        n.create_subscription(String, 'robot_description', got['rd'].append,
                              QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
        t_start = time.monotonic()   # before the replay can publish anything
        proc = Proc(ROBODYN + ['replay', str(headless), '--rate', '1', '--delay', '20', '--wait-subscribers',
                               '--topics', '/joint_states', '/robot_description'],
                    dom.env(), tmp_path / 'replay.log')
        assert client.spin_until(lambda: len(got['js']) == len(recorded) == len(got['clock']), 120, proc), \
            (proc.output(), len(got['js']), len(got['clock']), len(recorded))
        assert client.spin_until(lambda: got['rd'], 60)
        assert proc.wait(timeout=20) == 0, proc.output()
    finally:
        client.close()
        if proc is not None:
            proc.cleanup()
        dom.release()
    js = [m for _, m in got['js']]
    assert [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in js] == [t for t, _ in recorded]
    for m, (_, d) in zip(js, recorded):
        np.testing.assert_array_equal(m.position, d['position'])
        np.testing.assert_array_equal(m.effort, d['effort'])
    clock = [c.clock.sec * 10**9 + c.clock.nanosec for c in got['clock']]
    assert clock == [t for t, _ in recorded]         # /clock follows even when not selected
    assert not got['diag']                            # --topics left diagnostics out
    # paced by log time: the last message (0.3 s after the first at x1) cannot arrive sooner than that
    # after the replay started; how much later depends on the machine's load (not asserted)
    assert got['js'][-1][0] - t_start >= 0.3, got['js'][-1][0] - t_start
    assert '<robot' in got['rd'][0].data
    assert 'replayed' in proc.output()


def test_replay_refuses_unknown_topic(headless, capsys):
    assert robodyn(['replay', str(headless), '--topics', '/nope']) == 2
    assert 'no topic /nope' in capsys.readouterr().err


def _tf2_msgs_importable():
    import importlib.util
    return importlib.util.find_spec('tf2_msgs') is not None


@pytest.mark.skipif(_tf2_msgs_importable(), reason='tf2_msgs is installed: /tf is replayed')
def test_replay_without_tf2_msgs_leaves_tf_out_with_a_note(headless, tmp_path, capsys):
    """The recording carries /tf and /tf_static (bundled definition); this machine cannot publish
    them: asked for, exit 2; otherwise the other topics are replayed and a note says why not TF."""
    assert robodyn(['replay', str(headless), '--topics', '/tf']) == 2
    assert 'tf2_msgs' in capsys.readouterr().err
    dom = Domain()
    try:
        p = subprocess.run(ROBODYN + ['replay', str(headless), '--rate', '0', '--delay', '0'], env=dom.env(),
                           capture_output=True, text=True, timeout=60)
    finally:
        dom.release()
    assert p.returncode == 0, p.stdout + p.stderr
    assert 'not replaying /tf (tf2_msgs/msg/TFMessage' in p.stdout and '/tf_static' in p.stdout
    n = summarize(headless)
    expected = n['message_count'] - n['topics']['/tf']['count'] - n['topics']['/tf_static']['count']
    assert f'replayed {expected} messages' in p.stdout, p.stdout


def test_resim_of_headless_run_is_exact(headless, tmp_path, capsys):
    out = tmp_path / 'resim.mcap'
    assert robodyn(['resim', str(headless), '--record', str(out), '--json']) == 0
    report = json.loads(capsys.readouterr().out)
    assert report['max_deviation'] == 0.0
    assert report['topics']['/joint_states'] == {'original': 31, 'resimulated': 31, 'identical': 31,
                                                 'max_deviation': 0.0}
    assert report['topics']['/tf'] == {'original': 31, 'resimulated': 31, 'identical': 31, 'max_deviation': 0.0}
    assert report['topics']['/tf_static']['identical'] == 1
    assert report['publications'] == 31 and report['commands'] == 30
    md = summarize(out)['metadata']['robodyn']
    assert json.loads(md['settings'])['resim_of'] == 'run.mcap'


def test_resim_detects_a_deviation_and_honours_tolerance(tmp_path, capsys):
    """A recording whose metadata claims dt = 2 ms while it was run at 1 ms: resim differs."""
    from robodyn_ros.recording.run_sink import McapRunSink
    from robodyn_ros.scene import load_scene
    from robodyn_ros.simulation import Simulator, run_headless
    scene = load_scene('stanford_arm')
    path = tmp_path / 'claims.mcap'
    sim = Simulator(scene.system, scene.y0, integrator='rk4', dt=1e-3)
    sink = McapRunSink(path, scene, {'integrator': 'rk4', 'dt': 2e-3, 'rtol': None, 'atol': None, 'rate': 100.0})
    run_headless(sim, 0.2, 100.0, scene.script, [sink])
    sink.close()
    assert robodyn(['resim', str(path), '--record', str(tmp_path / 'r1.mcap')]) == 1
    text = capsys.readouterr().out
    assert 'FAILED' in text
    dev = float(text.split('largest deviation ')[1].split()[0])
    assert 0 < dev < 1e-3
    assert robodyn(['resim', str(path), '--record', str(tmp_path / 'r2.mcap'), '--tolerance', '1e-3']) == 0


def test_resim_refuses_a_recording_without_metadata(tmp_path, capsys):
    from robodyn_ros.recording import McapSink
    path = tmp_path / 'bare.mcap'
    with McapSink(path) as s:
        s.write('/joint_states', 'sensor_msgs/msg/JointState', {'name': ['a'], 'position': [0.0]}, 0)
    assert robodyn(['resim', str(path), '--record', str(tmp_path / 'out.mcap')]) == 2
    assert 'no robodyn metadata' in capsys.readouterr().err


def test_command_values_shared_by_node_and_resim():
    """Float64MultiArray honours data_offset; WrenchStamped -> [f; tau] in base_link only."""
    fa = {'layout': {'dim': [], 'data_offset': 1}, 'data': np.array([9.0, 1.0, 2.0])}
    assert command_values('effort', fa) == [1.0, 2.0]
    ws = {'header': {'stamp': {'sec': 0, 'nanosec': 0}, 'frame_id': 'base_link'},
          'wrench': {'force': {'x': 1.0, 'y': 2.0, 'z': 3.0}, 'torque': {'x': 4.0, 'y': 5.0, 'z': 6.0}}}
    assert command_values('base_wrench', ws) == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    ws['header']['frame_id'] = 'odom'
    with pytest.raises(CommandError, match='not base_link'):
        command_values('base_wrench', ws)


def _params(**kw):
    from robodyn_ros.nodes.sim import PARAMETERS
    return {**{k: default for k, (default, _) in PARAMETERS.items()}, **kw}


@pytest.mark.parametrize('kw, words', [
    ({'mode': 'fast'}, "parameter 'mode' must be one of realtime, max, lockstep, got 'fast'"),
    ({'initial_positions': [0.1, 0.2]}, "parameter 'initial_positions' needs 6 values (joint1, joint2"),
    ({'initial_velocities': [0.0] * 5 + [float('nan')]}, "parameter 'initial_velocities' must be finite"),
    ({'mode': 'lockstep', 'scripted_commands': True}, 'scripted_commands needs mode realtime or max'),
    ({'integrator': 'rk5'}, "unknown integrator 'rk5'"),
    ({'publish_rate': -10}, "parameter 'publish_rate' must be >= 0"),
    ({'rate_factor': 0}, "parameter 'rate_factor' must be > 0"),
    ({'command_timeout': 'soon'}, "parameter 'command_timeout' must be a finite number"),
])
def test_node_parameter_validation_names_the_parameter(kw, words):
    from robodyn_ros.nodes.sim import ConfigError, resolve_config
    from robodyn_ros.scene import load_scene
    with pytest.raises(ConfigError) as e:
        resolve_config(_params(**kw), load_scene('stanford_arm'))
    assert words in str(e.value)


def test_node_parameters_take_scene_defaults_and_overrides():
    from robodyn_ros.nodes.sim import resolve_config
    from robodyn_ros.scene import load_scene
    scene = load_scene('stanford_arm')
    cfg = resolve_config(_params(), scene)
    assert (cfg.integrator, cfg.dt, cfg.rtol, cfg.publish_rate, cfg.mode) == ('rk4', 1e-3, None, 100.0, 'realtime')
    np.testing.assert_array_equal(cfg.y0, scene.y0)
    cfg = resolve_config(_params(integrator='dop853', publish_rate=1000, initial_positions=[0, 1, 0.5, 0, 1, 0],
                                 command_timeout=0), scene)
    assert (cfg.integrator, cfg.dt, cfg.publish_rate, cfg.command_timeout) == ('dop853', None, 1000.0, None)
    assert cfg.rtol > 0 and cfg.atol > 0
    np.testing.assert_array_equal(cfg.y0[:6], [0, 1, 0.5, 0, 1, 0])
    assert json.loads(json.dumps(cfg.settings('/ns')))['y0'] == cfg.y0.tolist()


def test_sim_node_exits_with_status_2_on_a_bad_parameter():
    """Validation happens before any ROS traffic: a clear message naming the parameter."""
    dom = Domain()
    try:
        r = subprocess.run([sys.executable, '-m', 'robodyn_ros.nodes.sim', '--ros-args', '-p', 'mode:=fast'],
                           cwd=REPO, env=dom.env(), capture_output=True, text=True, timeout=60)
    finally:
        dom.release()
    assert r.returncode == 2, r.stderr
    assert "sim: parameter 'mode' must be one of realtime, max, lockstep" in r.stderr


def test_initial_position_override_uses_minimal_coordinates_for_augmented_systems():
    """unfried_free_flyer is augmented (extended coordinates); overrides are minimal q (12 values)."""
    from robodyn_ros.nodes.sim import resolve_config
    from robodyn_ros.scene import load_scene
    scene = load_scene('unfried_free_flyer')
    nq0, _ = scene.system.initial_state_sizes
    assert nq0 == 12 and scene.system.nq != nq0  # the state really is in other coordinates
    q = np.array([0.1, -0.2, 0.3, 0.0, 0.0, np.sin(0.2), np.cos(0.2), 0.1, 0.2, -0.3, 0.4, 0.5])
    cfg = resolve_config(_params(initial_positions=q.tolist()), scene)
    np.testing.assert_allclose(cfg.y0, scene.system.initial_state(q, None), atol=1e-12)
    assert not np.allclose(cfg.y0, scene.y0)


def _free_flyer_pushed(tmp_path):
    """unfried_free_flyer with a scripted base wrench (thrusters) besides its arm torques."""
    from robodyn_ros.scene import load_scene
    text = load_scene('unfried_free_flyer').text
    anchor = '\ncommands:\n'
    assert text.count(anchor) == 1
    text = text.replace(anchor, anchor + '  base_wrench: {profile: constant, value: [3.0, 1.0, 0.0, 0.0, 0.0, 0.4]}\n')
    path = tmp_path / 'unfried_free_flyer_pushed.yaml'
    path.write_text(text, encoding='utf-8')
    return str(path)


@pytest.mark.parametrize('scene, commands', [('betancur_platform', '/wheel_voltage_commands'),
                                             ('betancur_platform_turn', '/wheel_voltage_commands'),
                                             ('free_flyer_pushed', '/base_wrench_command')])
def test_resim_reproduces_platform_and_free_flyer_recordings(scene, commands, tmp_path, capsys):
    """Voltage commands (the platform) and base wrenches (the free flyer): every state message
    (joint_states, odom, wrenches, /tf) of the re-simulation is byte-identical to the recording."""
    src = _free_flyer_pushed(tmp_path) if scene == 'free_flyer_pushed' else scene
    rec, out = tmp_path / 'run.mcap', tmp_path / 'resim.mcap'
    assert robodyn(['run', src, '--duration', '0.4', '--record', str(rec)]) == 0
    n = summarize(rec)['topics']
    periods = n['/joint_states']['count'] - 1
    assert periods >= 8 and n[commands]['count'] == periods
    capsys.readouterr()
    assert robodyn(['resim', str(rec), '--record', str(out), '--json']) == 0
    report = json.loads(capsys.readouterr().out)
    assert report['max_deviation'] == 0.0
    for topic in ('/joint_states', '/odom', '/tf'):
        assert report['topics'][topic] == {'original': periods + 1, 'resimulated': periods + 1,
                                           'identical': periods + 1, 'max_deviation': 0.0}, topic
    wrenches = [t for t in report['topics'] if t.startswith('/constraint_wrenches/')]
    assert wrenches and all(report['topics'][t]['identical'] == periods + 1 for t in wrenches)
    assert report['commands'] == sum(n[t]['count'] for t in n if t.endswith('_command') or t.endswith('_commands'))
    cmd = [raw for *_, raw in read_raw_messages(rec, topics=[commands])]
    assert cmd == [raw for *_, raw in read_raw_messages(out, topics=[commands])]
