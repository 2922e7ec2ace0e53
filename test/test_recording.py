"""Tests of the recording layer: canonical CDR, ros2msg schemas, the MCAP sink and readers.

Independent references: rosbags (``Stores.ROS2_JAZZY`` typestore and ``AnyReader``) and
mcap-ros2-support (its dynamic serializer/decoder, and mcap's own summary reader).
"""
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.exceptions import EndOfFile
from mcap.reader import make_reader
from mcap_ros2._dynamic import generate_dynamic, serialize_dynamic
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from robodyn_ros.recording import (McapSink, canonical_name, decode, encode, full_text,
                                   get_msgdef, read_messages, read_raw_messages, summarize)

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
REPO = Path(__file__).resolve().parents[1]


def _stamp(sec, nanosec):
    return {'sec': sec, 'nanosec': nanosec}


def _header(sec, nanosec, frame_id):
    return {'stamp': _stamp(sec, nanosec), 'frame_id': frame_id}


# Sample messages: complete (every field given), strings of odd lengths so that padding after
# them is exercised, empty and non-empty sequences next to each other.
SAMPLES = {
    'sensor_msgs/msg/JointState': {
        'header': _header(12, 345_000_000, 'abc'),
        'name': ['shoulder', 'elbow', 'w'],
        'position': np.array([0.1, -2.5, 3.0]),
        'velocity': [],
        'effort': [1e-3, 2.0, -7.25],
    },
    'std_msgs/msg/Float64MultiArray': {
        'layout': {'dim': [{'label': 'rows', 'size': 2, 'stride': 6},
                           {'label': 'cols_x', 'size': 3, 'stride': 3}],
                   'data_offset': 1},
        'data': np.arange(6, dtype=float) * 0.5,
    },
    'std_msgs/msg/String': {'data': '<robot name="arm"/>'},
    'rosgraph_msgs/msg/Clock': {'clock': _stamp(3, 999_999_999)},
    'diagnostic_msgs/msg/DiagnosticArray': {
        'header': _header(1, 2, 'x'),
        'status': [
            {'level': 0, 'name': 'energy', 'message': 'drift ok', 'hardware_id': 'sim',
             'values': [{'key': 'E', 'value': '1.25'}, {'key': 'dE_rel', 'value': '3e-9'}]},
            {'level': 2, 'name': 'constraints', 'message': 'residual', 'hardware_id': '',
             'values': []},
        ],
    },
    'geometry_msgs/msg/WrenchStamped': {
        'header': _header(0, 500, 'link_3'),
        'wrench': {'force': {'x': 1.0, 'y': -2.0, 'z': 9.81},
                   'torque': {'x': 0.0, 'y': 0.5, 'z': -0.25}},
    },
    'nav_msgs/msg/Odometry': {
        'header': _header(7, 8, 'odom'),
        'child_frame_id': 'base_link',
        'pose': {'pose': {'position': {'x': 1.0, 'y': 2.0, 'z': 0.0},
                          'orientation': {'x': 0.0, 'y': 0.0, 'z': 0.6, 'w': 0.8}},
                 'covariance': np.linspace(0.0, 3.5, 36)},
        'twist': {'twist': {'linear': {'x': 0.3, 'y': 0.0, 'z': 0.0},
                            'angular': {'x': 0.0, 'y': 0.0, 'z': -0.1}},
                  'covariance': [0.0] * 35 + [1.0]},
    },
    # bundled definition (robodyn_ros/recording/msg) where tf2_msgs is not installed; strings of
    # 4, 9, 0 and 2 UTF-8 bytes put the float64 block after different amounts of padding
    'tf2_msgs/msg/TFMessage': {
        'transforms': [
            {'header': _header(5, 6, 'odom'), 'child_frame_id': 'base_link',
             'transform': {'translation': {'x': 1.0, 'y': -2.0, 'z': 0.0},
                           'rotation': {'x': 0.0, 'y': 0.0, 'z': 0.6, 'w': 0.8}}},
            {'header': _header(5, 6, ''), 'child_frame_id': 'é',
             'transform': {'translation': {'x': 0.25, 'y': 0.5, 'z': 0.75},
                           'rotation': {'x': 0.5, 'y': 0.5, 'z': 0.5, 'w': -0.5}}},
        ],
    },
}
TYPES = sorted(SAMPLES)

_NUMPY_DTYPES = {'float64': np.float64, 'float32': np.float32, 'int8': np.int8,
                 'uint8': np.uint8, 'byte': np.uint8, 'char': np.uint8, 'int16': np.int16,
                 'uint16': np.uint16, 'int32': np.int32, 'uint32': np.uint32,
                 'int64': np.int64, 'uint64': np.uint64, 'bool': np.bool_}


def _field(value, name):
    return value[name] if isinstance(value, dict) else getattr(value, name)


def to_rosbags(type_name, value):
    """Build a rosbags message object (its dataclass constructor insists on every field)."""
    cls = TYPESTORE.types[canonical_name(type_name)]
    kwargs = {}
    for f in get_msgdef(type_name).fields:
        v = _field(value, f.name)
        if f.is_nested:
            v = [to_rosbags(f.type, x) for x in v] if f.array else to_rosbags(f.type, v)
        elif f.array and f.type not in ('string', 'wstring'):
            v = np.asarray(v, dtype=_NUMPY_DTYPES[f.type])
        kwargs[f.name] = v
    return cls(**kwargs)


def to_plain(type_name, value):
    """Nested dict of Python scalars/lists from a dict, rosbags, mcap_ros2 or rclpy message."""
    out = {}
    for f in get_msgdef(type_name).fields:
        v = _field(value, f.name)
        if f.is_nested:
            out[f.name] = ([to_plain(f.type, x) for x in v] if f.array
                           else to_plain(f.type, v))
        elif f.array and f.type not in ('string', 'wstring'):
            out[f.name] = [x.item() if hasattr(x, 'item') else x for x in v]
        elif isinstance(v, bytes):
            out[f.name] = list(v) if f.array else v[0]
        else:
            out[f.name] = list(v) if f.array else (v.item() if hasattr(v, 'item') else v)
    return out


def to_lists(value):
    """mcap_ros2's serializer wants lists, not numpy arrays."""
    if isinstance(value, dict):
        return {k: to_lists(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [to_lists(v) for v in value]
    return value


# ---------------------------------------------------------------------------------------------
# CDR encoding against independent serializers


@pytest.mark.parametrize('type_name', TYPES)
def test_encode_matches_rosbags_bytes(type_name):
    ours = encode(type_name, SAMPLES[type_name])
    theirs = TYPESTORE.serialize_cdr(to_rosbags(type_name, SAMPLES[type_name]), type_name)
    assert ours[:4] == b'\x00\x01\x00\x00'
    assert len(ours) == len(theirs)
    assert ours == theirs


@pytest.mark.parametrize('type_name', TYPES)
def test_encode_matches_mcap_ros2_bytes(type_name):
    serializer = serialize_dynamic(type_name, full_text(type_name))[type_name]
    theirs = serializer(to_lists(SAMPLES[type_name]))
    assert encode(type_name, SAMPLES[type_name]) == theirs


@pytest.mark.parametrize('type_name', TYPES)
def test_our_bytes_decode_with_rosbags_mcap_ros2_and_ours(type_name):
    data = encode(type_name, SAMPLES[type_name])
    expected = to_plain(type_name, SAMPLES[type_name])
    by_rosbags = TYPESTORE.deserialize_cdr(data, type_name)
    by_mcap = generate_dynamic(type_name, full_text(type_name))[type_name](data)
    assert to_plain(type_name, by_rosbags) == expected
    assert to_plain(type_name, by_mcap) == expected
    assert to_plain(type_name, decode(type_name, data)) == expected


def test_padding_after_odd_strings_is_zero():
    # Offsets after the header: names 'shoulder' (24..33), 'elbow' (40..46), 'w' (52..54), then
    # 2 bytes of padding, the position count at 56..60 and 4 bytes of padding before the float64
    # data at 64. Padding must be zero (rclpy/Fast DDS leaves whatever was in memory there).
    data = encode('sensor_msgs/JointState', SAMPLES['sensor_msgs/msg/JointState'])
    body = data[4:]
    assert body[52:54] == b'w\x00'
    assert body[54:56] == bytes(2)
    assert int.from_bytes(body[56:60], 'little') == 3
    assert body[60:64] == bytes(4)
    assert np.frombuffer(body[64:88], '<f8').tolist() == [0.1, -2.5, 3.0]


def test_missing_fields_take_msg_defaults_or_zero():
    # geometry_msgs/Quaternion declares w = 1; everything else defaults to zero/empty.
    data = encode('nav_msgs/msg/Odometry', {'child_frame_id': 'b'})
    msg = TYPESTORE.deserialize_cdr(data, 'nav_msgs/msg/Odometry')
    assert msg.child_frame_id == 'b'
    assert msg.header.frame_id == ''
    assert msg.pose.pose.orientation.w == 1.0
    assert msg.pose.pose.orientation.z == 0.0
    assert msg.pose.covariance.shape == (36,)
    assert not msg.pose.covariance.any()


def test_encode_rejects_wrong_fixed_array_length():
    with pytest.raises(ValueError, match='exactly 36'):
        encode('geometry_msgs/PoseWithCovariance', {'covariance': [0.0] * 35})


def test_empty_message_is_one_zero_byte_like_rosbags():
    theirs = TYPESTORE.serialize_cdr(TYPESTORE.types['std_msgs/msg/Empty'](), 'std_msgs/msg/Empty')
    assert encode('std_msgs/msg/Empty', {}) == theirs == b'\x00\x01\x00\x00\x00'


def test_rclpy_messages_encode_like_dicts():
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from nav_msgs.msg import Odometry
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray, MultiArrayDimension

    js = JointState()
    js.header.stamp.sec, js.header.stamp.nanosec, js.header.frame_id = 12, 345_000_000, 'abc'
    js.name = ['shoulder', 'elbow', 'w']
    js.position = [0.1, -2.5, 3.0]
    js.effort = [1e-3, 2.0, -7.25]

    arr = Float64MultiArray()
    arr.layout.dim = [MultiArrayDimension(label='rows', size=2, stride=6),
                      MultiArrayDimension(label='cols_x', size=3, stride=3)]
    arr.layout.data_offset = 1
    arr.data = [0.0, 0.5, 1.0, 1.5, 2.0, 2.5]

    diag = DiagnosticArray()
    diag.header.stamp.sec, diag.header.stamp.nanosec, diag.header.frame_id = 1, 2, 'x'
    diag.status = [
        DiagnosticStatus(level=DiagnosticStatus.OK, name='energy', message='drift ok',
                         hardware_id='sim', values=[KeyValue(key='E', value='1.25'),
                                                    KeyValue(key='dE_rel', value='3e-9')]),
        DiagnosticStatus(level=DiagnosticStatus.ERROR, name='constraints', message='residual'),
    ]

    odom = Odometry()
    odom.header.stamp.sec, odom.header.stamp.nanosec, odom.header.frame_id = 7, 8, 'odom'
    odom.child_frame_id = 'base_link'
    odom.pose.pose.position.x, odom.pose.pose.position.y = 1.0, 2.0
    odom.pose.pose.orientation.z, odom.pose.pose.orientation.w = 0.6, 0.8
    odom.pose.covariance = np.linspace(0.0, 3.5, 36)
    odom.twist.twist.linear.x, odom.twist.twist.angular.z = 0.3, -0.1
    odom.twist.covariance[35] = 1.0

    cases = [('sensor_msgs/msg/JointState', js, JointState),
             ('std_msgs/msg/Float64MultiArray', arr, Float64MultiArray),
             ('diagnostic_msgs/msg/DiagnosticArray', diag, DiagnosticArray),
             ('nav_msgs/msg/Odometry', odom, Odometry)]
    assert len(cases) == 4
    encoded = [(t, encode(t, obj), encode(t, SAMPLES[t]), cls) for t, obj, cls in cases]
    assert [ours_obj == ours_dict for _, ours_obj, ours_dict, _ in encoded] == [True] * 4
    # rclpy itself reads our canonical bytes back to an equal message.
    back = [(deserialize_message(data, cls), obj) for (_, data, _, cls), (_, obj, _) in
            zip(encoded, cases)]
    assert [decoded == original for decoded, original in back] == [True] * 4


# ---------------------------------------------------------------------------------------------
# Schema text


def test_full_text_has_rosbag2_layout():
    text = full_text('nav_msgs/Odometry')
    with open(get_msgdef_path('nav_msgs/Odometry'), encoding='utf-8') as f:
        assert text.startswith(f.read())
    msg_lines = [line for line in text.splitlines() if line.startswith('MSG: ')]
    # rosbag2: dependencies sorted, depth first, each once.
    assert msg_lines == ['MSG: geometry_msgs/PoseWithCovariance', 'MSG: geometry_msgs/Pose',
                         'MSG: geometry_msgs/Point', 'MSG: geometry_msgs/Quaternion',
                         'MSG: geometry_msgs/TwistWithCovariance', 'MSG: geometry_msgs/Twist',
                         'MSG: geometry_msgs/Vector3', 'MSG: std_msgs/Header',
                         'MSG: builtin_interfaces/Time']
    assert text.count('\n' + '=' * 80 + '\nMSG: ') == len(msg_lines)
    # Absolute references (std_msgs/Header) and same-package relative ones (MultiArrayDimension
    # inside std_msgs/MultiArrayLayout) both resolve to canonical names.
    assert get_msgdef('sensor_msgs/JointState').fields[0].type == 'std_msgs/msg/Header'
    assert get_msgdef('std_msgs/MultiArrayLayout').fields[0].type == \
        'std_msgs/msg/MultiArrayDimension'
    assert full_text('std_msgs/Float64MultiArray').count('MSG: std_msgs/MultiArrayDimension') == 1


def get_msgdef_path(type_name):
    from robodyn_ros.recording.msgdefs import find_msg_file
    return find_msg_file(type_name)


def test_recording_package_does_not_import_rclpy():
    code = 'import sys, robodyn_ros.recording; print("rclpy" in sys.modules)'
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         cwd=REPO, timeout=60, check=True)
    assert out.stdout.strip() == 'False'


# ---------------------------------------------------------------------------------------------
# MCAP files

TOPICS = {
    'joint_states': 'sensor_msgs/msg/JointState',
    'effort_commands': 'std_msgs/msg/Float64MultiArray',
    'robot_description': 'std_msgs/msg/String',
    '/clock': 'rosgraph_msgs/msg/Clock',
    'diagnostics': 'diagnostic_msgs/msg/DiagnosticArray',
    'constraint_wrenches/joint_1': 'geometry_msgs/msg/WrenchStamped',
    'odom': 'nav_msgs/msg/Odometry',
}
METADATA = {'scene': 'name: stanford_arm\nlinks: []\n', 'integrator': 'rk4 dt=0.001',
            'version': '0.1.0'}
STEPS = 5


def write_sample_file(path, chunk_size=64 * 1024):
    """Write robot_description once, then STEPS rounds of every other topic; return counts."""
    counts = {t: 0 for t in TOPICS}
    with McapSink(path, METADATA, chunk_size=chunk_size) as sink:
        sink.write('robot_description', TOPICS['robot_description'],
                   SAMPLES['std_msgs/msg/String'], 0)
        counts['robot_description'] += 1
        for k in range(STEPS):
            t_ns = k * 10_000_000
            for topic, type_name in TOPICS.items():
                if topic == 'robot_description':
                    continue
                msg = dict(SAMPLES[type_name])
                if 'header' in msg:
                    msg['header'] = _header(0, t_ns, msg['header']['frame_id'])
                if topic == '/clock':
                    msg = {'clock': _stamp(0, t_ns)}
                sink.write(topic, type_name, msg, t_ns)
                counts[topic] += 1
    return counts


def test_file_reads_back_with_mcap_ros2_and_rosbags(tmp_path):
    path = tmp_path / 'run.mcap'
    counts = write_sample_file(path)
    total = sum(counts.values())
    assert total == 1 + STEPS * (len(TOPICS) - 1)

    # Our summary (streams the file).
    summary = summarize(path)
    assert summary['message_count'] == total
    assert summary['statistics_message_count'] == total
    assert {t: v['count'] for t, v in summary['topics'].items()} == counts
    assert {t: v['type'] for t, v in summary['topics'].items()} == TOPICS
    assert summary['finished'] is True and summary['error'] is None
    assert summary['profile'] == 'ros2'
    assert summary['metadata'] == {'robodyn': METADATA}
    assert (summary['start_time_ns'], summary['end_time_ns']) == (0, (STEPS - 1) * 10_000_000)
    assert 'durability: transient_local' in \
        summary['topics']['robot_description']['offered_qos_profiles']
    assert 'durability: volatile' in summary['topics']['joint_states']['offered_qos_profiles']

    # mcap's own indexed reader: layout of schemas and channels.
    with open(path, 'rb') as f:
        reader = make_reader(f)
        assert reader.get_header().profile == 'ros2'
        mcap_summary = reader.get_summary()
        assert mcap_summary is not None
        assert mcap_summary.statistics.message_count == total
        schemas = mcap_summary.schemas.values()
        channels = mcap_summary.channels.values()
        assert sorted(s.name for s in schemas) == sorted(set(TOPICS.values()))
        assert {s.encoding for s in schemas} == {'ros2msg'}
        assert {c.message_encoding for c in channels} == {'cdr'}
        assert sorted(c.topic for c in channels) == sorted(TOPICS)
        assert [m.name for m in reader.iter_metadata()] == ['robodyn']

    # mcap-ros2-support decoding, through read_messages.
    decoded = list(read_messages(path))
    assert len(decoded) == total
    by_topic = {}
    for topic, type_name, log_time, msg in decoded:
        by_topic.setdefault(topic, []).append((type_name, log_time, msg))
    assert {t: len(v) for t, v in by_topic.items()} == counts
    assert by_topic['robot_description'][0][2].data == SAMPLES['std_msgs/msg/String']['data']
    assert [m.clock.nanosec for _, _, m in by_topic['/clock']] == \
        [k * 10_000_000 for k in range(STEPS)]
    assert [lt for _, lt, _ in by_topic['odom']] == [k * 10_000_000 for k in range(STEPS)]
    last_odom = by_topic['odom'][-1][2]
    assert list(last_odom.pose.covariance) == list(np.linspace(0.0, 3.5, 36))
    assert last_odom.header.stamp.nanosec == (STEPS - 1) * 10_000_000
    diag = by_topic['diagnostics'][0][2]
    assert [s.name for s in diag.status] == ['energy', 'constraints']
    assert [(kv.key, kv.value) for kv in diag.status[0].values] == [('E', '1.25'),
                                                                    ('dE_rel', '3e-9')]
    layout = by_topic['effort_commands'][0][2].layout
    assert [(d.label, d.size, d.stride) for d in layout.dim] == [('rows', 2, 6), ('cols_x', 3, 3)]

    # rosbags: AnyReader opens a bare .mcap (rosbags >= 0.10; no metadata.yaml needed) and
    # builds its types from the ros2msg schemas stored in the file (no default typestore).
    with AnyReader([path]) as reader:
        assert {c.topic: c.msgcount for c in reader.connections} == counts
        assert {c.topic: c.msgtype for c in reader.connections} == TOPICS
        durability = {c.topic: c.ext.offered_qos_profiles[0].durability.name
                      for c in reader.connections}
        assert durability['robot_description'] == 'TRANSIENT_LOCAL'
        assert durability['odom'] == 'VOLATILE'
        rb = [(c.topic, t, reader.deserialize(raw, c.msgtype)) for c, t, raw in
              reader.messages()]
    assert len(rb) == total
    rb_joint = [(t, m) for topic, t, m in rb if topic == 'joint_states']
    assert len(rb_joint) == STEPS
    assert [t for t, _ in rb_joint] == [k * 10_000_000 for k in range(STEPS)]
    assert list(rb_joint[-1][1].name) == ['shoulder', 'elbow', 'w']
    assert rb_joint[-1][1].effort.tolist() == [1e-3, 2.0, -7.25]
    rb_wrench = [m for topic, _, m in rb if topic == 'constraint_wrenches/joint_1']
    assert len(rb_wrench) == STEPS
    assert rb_wrench[0].header.frame_id == 'link_3'
    assert rb_wrench[0].wrench.force.z == 9.81

    # Raw bytes are exactly our encoder's output.
    raw = [d for topic, _, _, d in read_raw_messages(path, topics=['robot_description'])]
    assert raw == [encode('std_msgs/String', SAMPLES['std_msgs/msg/String'])]


def test_equal_runs_give_byte_identical_files(tmp_path):
    a, b = tmp_path / 'a.mcap', tmp_path / 'b.mcap'
    write_sample_file(a, chunk_size=1024)
    time.sleep(0.01)  # any wall-clock leak would now differ
    write_sample_file(b, chunk_size=1024)
    assert a.stat().st_size > 0
    assert a.read_bytes() == b.read_bytes()
    assert summarize(a)['chunk_count'] > 1


def test_sink_close_is_idempotent_and_rejects_misuse(tmp_path):
    sink = McapSink(tmp_path / 'c.mcap', {'k': 'v'})
    sink.write('odom', 'nav_msgs/Odometry', {}, 5)
    with pytest.raises(ValueError, match='already has type'):
        sink.write('odom', 'std_msgs/String', {}, 6)
    sink.close()
    sink.close()
    assert sink.closed
    with pytest.raises(ValueError, match='closed'):
        sink.write('odom', 'nav_msgs/Odometry', {}, 7)
    with pytest.raises(TypeError):
        McapSink(tmp_path / 'd.mcap', {'n': 1})
    assert summarize(tmp_path / 'c.mcap')['message_count'] == 1


# ---------------------------------------------------------------------------------------------
# Crash safety

_KILLED_WRITER = textwrap.dedent('''
    import sys
    from robodyn_ros.recording import McapSink
    sink = McapSink(sys.argv[1], {'scene': 'crash'}, chunk_size=2048)
    flushed = 0
    i = 0
    while i < 20000 and (sink.chunk_count < 4
                         or sink.message_count - sink.flushed_message_count < 3):
        t_ns = i * 1_000_000
        sink.write('joint_states', 'sensor_msgs/msg/JointState',
                   {'header': {'stamp': {'sec': 0, 'nanosec': t_ns}, 'frame_id': 'f'},
                    'name': ['a', 'b'], 'position': [float(i), 0.5]}, t_ns)
        i += 1
        if sink.flushed_message_count != flushed:
            flushed = sink.flushed_message_count
            print('FLUSHED', flushed, sink.chunk_count, flush=True)
    print('READY', sink.message_count, flush=True)
    sys.stdin.read()   # blocks until the test kills this process (its stdin is never closed before)
''')


@pytest.mark.processes
def test_killed_writer_keeps_every_complete_chunk(tmp_path):
    path = tmp_path / 'killed.mcap'
    proc = subprocess.Popen([sys.executable, '-c', _KILLED_WRITER, str(path)],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=REPO)
    flushed = chunks = written = None
    try:
        for line in proc.stdout:
            words = line.split()
            if words[0] == 'FLUSHED':
                flushed, chunks = int(words[1]), int(words[2])
            elif words[0] == 'READY':
                written = int(words[1])
                break
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
    assert proc.returncode == -signal.SIGKILL
    assert chunks == 4
    assert written is not None and written > flushed > 0  # the open chunk held messages

    summary = summarize(path)
    assert summary['finished'] is False
    assert summary['error'].startswith('truncated')
    assert summary['message_count'] == flushed
    assert summary['chunk_count'] == chunks
    assert summary['metadata'] == {'robodyn': {'scene': 'crash'}}
    msgs = list(read_messages(path))
    assert len(msgs) == flushed
    assert [m.position[0] for _, _, _, m in msgs] == [float(i) for i in range(flushed)]
    with pytest.raises(EndOfFile):
        list(read_messages(path, strict=True))


def test_file_truncated_inside_a_chunk_yields_the_chunks_before(tmp_path):
    path = tmp_path / 'cut.mcap'
    with McapSink(path, {'scene': 'cut'}, chunk_size=1024) as sink:
        for i in range(200):
            sink.write('/clock', 'rosgraph_msgs/Clock', {'clock': _stamp(i, 0)}, i * 10 ** 9)
    # Where the chunks are, and what they hold, from mcap's own index of the finished file.
    with open(path, 'rb') as f:
        chunk_indexes = make_reader(f).get_summary().chunk_indexes
    assert len(chunk_indexes) >= 3
    third = chunk_indexes[2]
    in_first_two = sum(1 for _, _, t, _ in read_raw_messages(path)
                       if t <= chunk_indexes[1].message_end_time)
    assert in_first_two > 0
    cut = tmp_path / 'cut_short.mcap'
    cut.write_bytes(path.read_bytes()[:third.chunk_start_offset + third.chunk_length // 2])

    summary = summarize(cut)
    assert summary['finished'] is False
    assert summary['error'].startswith('truncated')
    assert summary['message_count'] == in_first_two
    assert summary['chunk_count'] == 2
    times = [t for _, _, t, _ in read_messages(cut)]
    assert times == [i * 10 ** 9 for i in range(in_first_two)]
