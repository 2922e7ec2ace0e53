"""The recorder's fast paths write exactly the bytes of the dict-and-encode path.

McapRunSink encodes joint_states, /tf, /clock and command arrays straight from the simulator's
outputs (cdr.joint_state_bytes, tf_message_bytes, clock_bytes, float64_array_bytes), and McapSink
writes message records straight into mcap's open chunk (_DirectMessages). Each is compared with
the path it replaces: the message dicts of robodyn_ros.messages through cdr.encode, and
mcap.Writer.add_message. Whole recordings of every scene kind must be byte-identical. mcap.Writer
compresses at zstd level 3 (``zstandard.compress``); the sink writes level 1, the MCAP C++ writer's
default, so the comparisons with mcap.Writer set the sink's level to 3, and
test_chunks_are_zstd_level_1_of_the_same_records checks the level the sink writes.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from robodyn_ros import messages as M
from robodyn_ros.recording import cdr, mcap_sink
from robodyn_ros.recording.run_sink import McapRunSink
from robodyn_ros.scene import load_scene
from robodyn_ros.simulation import Simulator, run_headless


def test_direct_builders_equal_the_dict_encoding():
    rng = np.random.default_rng(5)
    for k in range(20):
        n = int(rng.integers(0, 8))
        names = [f'j{i}' + 'é' * (k % 3) for i in range(n)]
        arrays = [rng.normal(size=n) * 10.0 ** rng.integers(-5, 5) for _ in range(3)]
        t_ns = int(rng.integers(0, 2 ** 50))
        sec, nsec = divmod(t_ns, 1_000_000_000)
        ref = cdr.encode('sensor_msgs/msg/JointState', M.joint_state(t_ns, names, *arrays))
        assert cdr.joint_state_bytes(sec, nsec, cdr.joint_state_names('', tuple(names)), *arrays) == ref
        assert cdr.clock_bytes(sec, nsec) == cdr.encode('rosgraph_msgs/msg/Clock', M.clock(t_ns))
        assert cdr.float64_array_bytes(arrays[0]) == cdr.encode('std_msgs/msg/Float64MultiArray',
                                                                M.float64_array(arrays[0]))
        w = rng.normal(size=6)
        for frame in ('', 'base_link', 'lïnk_' * (k % 3)):
            assert cdr.wrench_stamped_bytes(sec, nsec, frame, w) == cdr.encode('geometry_msgs/msg/WrenchStamped',
                                                                              M.wrench_stamped(t_ns, frame, w))
        odom = {'position': rng.normal(size=3), 'orientation': rng.normal(size=4), 'linear': rng.normal(size=3),
                'angular': rng.normal(size=3)}
        assert cdr.odometry_bytes(sec, nsec, odom) == cdr.encode('nav_msgs/msg/Odometry', M.odometry(t_ns, odom))
    assert cdr.joint_state_bytes(0, 0, cdr.joint_state_names('', ('a',)), np.array([1]), np.ones(1), np.ones(1)) \
        is None  # an integer array declines (the dict path converts it)
    assert cdr.float64_array_bytes(np.ones((2, 2))) is None
    for text in ('', 'abc', 'ab', 'lïnk ' * 1000, '<robot name="é"/>'):   # std_msgs/String (a robot_description)
        enc = cdr._Encoder()
        enc.message('std_msgs/msg/String', {'data': text})
        assert cdr.encode('std_msgs/msg/String', {'data': text}) == bytes(enc.buf)
    assert cdr._fast_string_message({'data': b'x'}) is None and cdr._fast_string_message({'data': 'x', 'y': 1}) is None


def test_the_imu_layout_is_the_cdr_rosbags_writes():
    """cdr.imu_layout (the recorder's batched Imu: a template, its 37 numbers from an offset, the stamp at
    STAMP_AT) against rosbags' own CDR serializer on seeded messages and frames."""
    import struct

    from rosbags.typesys import Stores, get_typestore
    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    rng = np.random.default_rng(9)
    for k in range(30):
        frame = ('', 'hand', 'lïnk_7', 'abc')[k % 4]
        x = rng.normal(size=37) * 10.0 ** rng.integers(-6, 6)
        sec, nsec = int(rng.integers(0, 2 ** 31)), int(rng.integers(0, 10 ** 9))
        vec = [T['geometry_msgs/msg/Vector3'](x=x[i], y=x[i + 1], z=x[i + 2]) for i in (13, 25)]
        msg = T['sensor_msgs/msg/Imu'](
            header=T['std_msgs/msg/Header'](stamp=T['builtin_interfaces/msg/Time'](sec=sec, nanosec=nsec),
                                            frame_id=frame),
            orientation=T['geometry_msgs/msg/Quaternion'](x=x[0], y=x[1], z=x[2], w=x[3]),
            orientation_covariance=x[4:13], angular_velocity=vec[0], angular_velocity_covariance=x[16:25],
            linear_acceleration=vec[1], linear_acceleration_covariance=x[28:37])
        tpl, at = cdr.imu_layout(frame)
        ours = bytearray(tpl)
        ours[at:at + 8 * 37] = x.astype('<f8').tobytes()
        ours[cdr.STAMP_AT:cdr.STAMP_AT + 8] = struct.pack('<iI', sec, nsec)
        assert bytes(ours) == bytes(ts.serialize_cdr(msg, 'sensor_msgs/msg/Imu')), (k, frame)


def test_a_servo_and_sensor_scene_is_recorded_in_batches(tmp_path, monkeypatch):
    """xarm7_trajectory's periods carry a servo's desired and error states, a force-torque sensor and an IMU:
    every period after the first (which registers the channels) goes to the batched layout, not message by
    message (test_recording_oracle compares the bytes with the oracle's at batch sizes 0, 7 and 1024). On the
    per-period path, as the node and a paced live run record (the block path's periods: test_block_path)."""
    from robodyn_ros import blocks
    from robodyn_ros.recording import run_sink
    monkeypatch.setattr(blocks.BlockRunner, 'plan', classmethod(lambda cls, *a, **k: None))
    from robodyn_ros.runs import plan_run, resolve_settings
    held = []
    real = run_sink.McapRunSink._hold
    monkeypatch.setattr(run_sink.McapRunSink, '_hold', lambda self, *a: held.append(real(self, *a)) or held[-1])
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        sc = load_scene('xarm7_trajectory')
    plan, st = plan_run(resolve_settings(sc, duration=0.3), sc.system, sc.y0)
    sim = Simulator(sc.system, sc.y0, plan=plan)
    sink = McapRunSink(str(tmp_path / 'x.mcap'), sc, st, batch=run_sink.HEADLESS_BATCH)
    try:
        run_headless(sim, 0.3, st['rate'], sc.script, [sink])
    finally:
        sink.close()
    out = sim.outputs()
    assert {t for t, _, _ in out.messages} >= {'joint_trajectory_desired', 'joint_trajectory_error', 'imu/hand',
                                               'ft/wrist'}
    assert len(held) == 31 and held[0] is False and all(held[1:])


def test_tf_bytes_equal_the_tf_message_encoding():
    from robodyn_ros.tf import TfTree
    for name in ('stanford_arm', 'mobile_manipulator', 'unfried_free_flyer'):
        sc = load_scene(name)
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            sim = Simulator(sc.system, sc.y0, integrator='rk4', dt=1e-3)
        sim.advance(0.05)
        out = sim.outputs(wrenches=False)
        tree = TfTree(sc.system)
        t_ns = 1_234_567_891_011
        trs = tree.transforms(out.joint_names, out.position, out.odom)
        layout = cdr.tf_layout(tuple((p, c) for p, c, _, _ in trs))
        data = cdr.tf_message_bytes(layout, [divmod(t_ns, 1_000_000_000)] * len(trs), [(*p, *q) for _, _, p, q in trs])
        assert data == cdr.encode('tf2_msgs/msg/TFMessage', tree.message(t_ns, out))


cdr_joint_state_bytes, cdr_float64_array_bytes = cdr.joint_state_bytes, cdr.float64_array_bytes


def _record(path, name, direct=True, fast=True, monkeypatch=None):
    sc = load_scene(name)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        sim = Simulator(sc.system, sc.y0, integrator='rk4', dt=2e-3)
    sink = McapRunSink(path, sc, {'integrator': 'rk4'}, record_wrenches=True, diagnostics_period=0.05)
    sink.writer.chunk_size = 4096  # many chunks
    if not direct:
        sink.writer._direct = None
    if not fast:
        monkeypatch.setattr(cdr, 'joint_state_bytes', lambda *a: None)
        monkeypatch.setattr(cdr, 'float64_array_bytes', lambda *a: None)
    try:
        run_headless(sim, 0.3, 50.0, sc.script, [sink])
    finally:
        sink.close()
        if not fast:
            monkeypatch.setattr(cdr, 'joint_state_bytes', cdr_joint_state_bytes)
            monkeypatch.setattr(cdr, 'float64_array_bytes', cdr_float64_array_bytes)
    return path.read_bytes()


@pytest.mark.parametrize('name', ['stanford_arm', 'mobile_manipulator', 'unfried_air_bearing', 'huston_prescribed_planar3',
                                  'unfried_free_flyer'])
def test_fast_recording_is_byte_identical_to_the_generic_path(tmp_path, name, monkeypatch):
    assert mcap_sink._DirectMessages._self_test()
    monkeypatch.setattr(mcap_sink, 'ZSTD_LEVEL', 3)   # mcap.Writer's
    fast = _record(tmp_path / 'fast.mcap', name)
    slow = _record(tmp_path / 'slow.mcap', name, direct=False, fast=False, monkeypatch=monkeypatch)
    assert len(fast) > 20000 and fast == slow


def test_sink_falls_back_to_add_message_when_mcap_internals_differ(tmp_path, monkeypatch):
    monkeypatch.setattr(mcap_sink, 'ZSTD_LEVEL', 3)   # mcap.Writer's
    monkeypatch.setattr(mcap_sink._DirectMessages, '_verified', False)
    with mcap_sink.McapSink(tmp_path / 'a.mcap') as s:
        assert s._direct is None
        s.write('/clock', 'rosgraph_msgs/msg/Clock', M.clock(5), 5)
    monkeypatch.setattr(mcap_sink._DirectMessages, '_verified', None)
    with mcap_sink.McapSink(tmp_path / 'b.mcap') as s:
        assert s._direct is not None
        s.write('/clock', 'rosgraph_msgs/msg/Clock', M.clock(5), 5)
    assert (tmp_path / 'a.mcap').read_bytes() == (tmp_path / 'b.mcap').read_bytes()


def _sample_files(tmp_path, seed, compression):
    """The same 600 random messages on three topics written by McapSink in small chunks (2500 B): through its
    direct records, and through mcap.Writer.add_message. Returns the two paths."""
    rng = np.random.default_rng(seed)
    msgs = [(f'/t{int(rng.integers(0, 3))}', int(t), rng.normal(size=int(rng.integers(1, 40))))
            for t in np.cumsum(rng.integers(0, 5_000_000, size=600))]
    paths = []
    for direct in (True, False):
        path = tmp_path / f'{direct}.mcap'
        with mcap_sink.McapSink(path, {'k': 'v'}, chunk_size=2500, compression=compression) as s:
            if not direct:
                s._direct = None
            assert (s._direct is not None) == direct
            for topic, t, data in msgs:
                s.write(topic, 'std_msgs/msg/Float64MultiArray', M.float64_array(data), t)
            assert s.chunk_count > 10
        paths.append(path)
    return paths


@pytest.mark.parametrize('compression', ['zstd', 'lz4', 'none'])
def test_direct_chunks_equal_mcap_writer_chunks_for_every_compression(tmp_path, compression, monkeypatch):
    # McapSink closes chunks itself (one reused zstd compressor, the chunk record in one piece);
    # the file must be the one mcap.Writer.flush writes, for each compression
    monkeypatch.setattr(mcap_sink, 'ZSTD_LEVEL', 3)   # mcap.Writer's
    direct, writer = _sample_files(tmp_path, 7, compression)
    assert direct.read_bytes() == writer.read_bytes()


def test_chunks_are_zstd_level_1_of_the_same_records(tmp_path):
    # the sink's own level (the MCAP C++ writer's CompressionLevel::Default, as rosbag2 writes):
    # each chunk is zstandard's level-1 frame of the records mcap.Writer's file holds in the same chunk
    import zstandard
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader
    assert mcap_sink.ZSTD_LEVEL == 1 and mcap_sink.DEFAULT_CHUNK_SIZE == 768 * 1024
    chunks = []
    for path in _sample_files(tmp_path, 8, 'zstd'):
        with open(path, 'rb') as f:
            chunks.append([r for r in StreamReader(f, emit_chunks=True).records if isinstance(r, Chunk)])
    ours, theirs = chunks
    assert len(ours) == len(theirs) > 10
    level1, level3 = zstandard.ZstdCompressor(level=1), zstandard.ZstdCompressor(level=3)
    for a, b in zip(ours, theirs):
        raw = zstandard.ZstdDecompressor().decompress(b.data, max_output_size=b.uncompressed_size)
        assert (a.compression, a.uncompressed_size, a.uncompressed_crc) == ('zstd', b.uncompressed_size, b.uncompressed_crc)
        assert a.data == level1.compress(raw) and b.data == level3.compress(raw)
    assert sum(a.data != b.data for a, b in zip(ours, theirs)) > 0
