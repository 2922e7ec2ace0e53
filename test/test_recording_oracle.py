"""Recordings of every bundled scene equal, byte for byte, those of a deliberately simple recorder.

``robodyn run`` records through McapRunSink, whose fast paths (CDR written from precompiled
layouts, several publication periods encoded in one vectorised pass, message records and
indexes written in bulk) must not change a single byte of the file. The oracle here is the
slow, obvious way to record the same run, kept in test/ on purpose:

- every message is built as a dict by :mod:`robodyn_ros.messages` (the interface contract's
  field layout) and encoded by the generic per-field CDR encoder (``cdr._Encoder``: no fast
  path, no template);
- each is handed to ``mcap.Writer.add_message`` one at a time (``McapSink.write`` with the
  direct-record path switched off), so chunks, message indexes and statistics are mcap's own;
- what is recorded, and in which order, is spelled out below: ``robot_description`` (its meshes
  embedded as data: URIs, ``assets.embed_meshes``: tested in test_assets) and ``/tf_static`` at the
  start, each scripted command as it is applied, then per publication joint_states, odom,
  constraint wrenches, /tf, /clock, on a ground the markers (a MarkerArray dict built here from the
  touching points) and, every diagnostics period, diagnostics.

Each run is made twice in separate simulations (fast sink alone, oracle alone) and the files are
compared. Digests of old files are deliberately not stored: the recorded numbers may change for
good reasons (a new t = 0 effort, a physics fix); the fast path must equal the simple one for any
numbers.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from robodyn_ros import messages as M
from robodyn_ros.assets import embed_meshes
from robodyn_ros.recording import cdr, mcap_sink
from robodyn_ros.recording.mcap_sink import McapSink
from robodyn_ros.recording.run_sink import HEADLESS_BATCH, McapRunSink, resolve, run_metadata
from robodyn_ros.scene import list_scenes, load_scene
from robodyn_ros.simulation import Simulator, run_headless

SCENES = [name for name, _ in list_scenes()]


@pytest.fixture(autouse=True)
def _mcap_writers_level(monkeypatch):
    """The oracle's chunks are compressed by mcap.Writer (zstandard's level 3); the recorder's at that level too
    here, so that whole files compare (the level the recorder writes: test_recording_fast)."""
    monkeypatch.setattr(mcap_sink, 'ZSTD_LEVEL', 3)


def _generic(type_name: str, msg) -> bytes:
    """CDR by the generic per-field encoder only (cdr.encode would take the fast encoders)."""
    enc = cdr._Encoder()
    enc.message(type_name, msg)
    return bytes(enc.buf)


class OracleSink:
    """The obvious recorder: message dicts, generic CDR, one ``Writer.add_message`` per message."""

    def __init__(self, path, scene, settings, record_wrenches=True, record_tf=True, diagnostics_period=1.0,
                 chunk_size=None):
        self.wants_wrenches = record_wrenches
        self.record_tf = record_tf
        self.period = diagnostics_period
        self.writer = McapSink(str(path), metadata=run_metadata(scene, settings))
        self.writer._direct = None  # mcap.Writer.add_message for every record
        if chunk_size is not None:
            self.writer.chunk_size = chunk_size
        self.tf = None
        self.next_diag = None

    def write(self, topic, msg, t_ns, type_name=None):
        type_name = type_name or M.TOPIC_TYPES[topic]
        self.writer.write(resolve(topic), type_name, _generic(type_name, msg), t_ns)

    def on_start(self, sim):
        t_ns = M.to_ns(sim.t)
        self.writer.add_topic('/robot_description', M.TOPIC_TYPES['robot_description'], qos='transient_local')
        self.write('robot_description', M.string(embed_meshes(sim.system.urdf())[0]), t_ns)
        if any(p in sim.system.inputs for p in ('position', 'velocity')):   # the joints of each command topic
            self.writer.add_topic('/command_joint_names', 'std_msgs/msg/String', qos='transient_local')
            self.write('command_joint_names', M.string(M.command_joint_names(sim.system)), t_ns,
                       'std_msgs/msg/String')
        self.weight = None
        sensors = getattr(sim.system, 'sensors', None)
        self.imu = [s.topic for s in sensors.imu] if sensors is not None else []
        self.ft = [s.topic for s in sensors.ft] if sensors is not None else []
        if getattr(sim.system, 'contact', None) is not None or sensors is not None:
            self.weight = sim.system.model.total_mass() * float(np.linalg.norm(sim.system.model.gravity))
            contact = getattr(sim.system, 'contact', None)
            self.world = contact.frame if contact is not None else sim.system.model.root
        if self.record_tf:
            from robodyn_ros.tf import TfTree
            self.tf = TfTree(sim.system)
            msg = self.tf.static_message(t_ns)
            if msg['transforms']:
                self.writer.add_topic('/tf_static', M.TOPIC_TYPES['/tf_static'], qos='transient_local')
                self.write('/tf_static', msg, t_ns)
        self.next_diag = sim.t

    def on_command(self, t, port, values):
        t_ns = M.to_ns(t)
        topic = M.PORT_TOPICS[port]
        if port == 'trajectory':   # the JointTrajectory message as it was applied
            self.write(topic, values, t_ns, 'trajectory_msgs/msg/JointTrajectory')
            return
        if port == 'base_wrench':  # [fx, fy, fz, tx, ty, tz] -> the spatial force [torque; force]
            msg = M.wrench_stamped(t_ns, 'base_link', np.r_[values[3:6], values[0:3]])
        else:
            msg = M.float64_array(values)
        self.write(topic, msg, t_ns)

    def on_output(self, t, out, sim):
        t_ns = M.to_ns(t)
        for topic, type_name, msg in M.output_messages(t_ns, out, self.wants_wrenches, self.tf):
            self.write(topic, msg, t_ns, type_name)
        self.write('/clock', M.clock(t_ns), t_ns)
        if self.weight is not None:
            self.write('markers', _marker_array(t_ns, self.world, self.weight, out.contact_points, self.imu, self.ft,
                                                out.imu_poses, out.ft_wrenches), t_ns,
                       'visualization_msgs/msg/MarkerArray')
        if t >= self.next_diag - 1e-9:
            self.write('diagnostics', M.diagnostic_array(t_ns, 'robodyn_ros: simulation', 0, 'running',
                                                         sim.diagnostics_values()), t_ns)
            self.next_diag += self.period

    def close(self):
        self.writer.close()


def _marker_array(t_ns, frame, weight, points, imu=(), ft=(), imu_poses=None, ft_wrenches=None) -> dict:
    """The markers message as the recording module describes it: a DELETEALL, then (when points touch)
    a sphere list of the touching points and an arrow per point along its force, 0.5 m at the weight;
    then per IMU (namespace its topic) its link's x, y, z axes as three 0.1 m arrows (red, green, blue)
    from the link's origin, per force-torque sensor an arrow along its force (amber) and one along its
    moment (violet) from its frame's origin, at the contact arrows' scale."""
    sec, nsec = divmod(t_ns, 1_000_000_000)
    header = {'stamp': {'sec': sec, 'nanosec': nsec}, 'frame_id': frame}

    def marker(ns, mid, mtype, action, scale, color, points):
        return {'header': header, 'ns': ns, 'id': mid, 'type': mtype, 'action': action,
                'pose': {'orientation': {'w': 1.0}}, 'scale': dict(zip('xyz', scale)),
                'color': dict(zip('rgba', color)), 'points': [dict(zip('xyz', p)) for p in points]}
    out = [marker('', 0, 0, 3, (0, 0, 0), (0, 0, 0, 0), [])]
    if points is not None and len(points):
        d = 0.04 * 0.5
        out.append(marker('contact_points', 0, 7, 0, (d, d, d), (1.0, 0.55, 0.0, 1.0), points[:, :3]))
        for i, p in enumerate(points):
            tip = p[:3] + 0.5 / weight * p[3:]
            out.append(marker('contact_forces', i, 0, 0, (0.25 * d, 0.5 * d, 0.75 * d), (0.85, 0.1, 0.1, 1.0),
                              [p[:3], tip]))
    d = 0.04 * 0.5
    arrow = (0.25 * d, 0.5 * d, 0.75 * d)
    for k, ns in enumerate(imu):
        p, R = imu_poses[k, 0:3], imu_poses[k, 3:12].reshape(3, 3)
        for a, color in enumerate(((1.0, 0.0, 0.0, 1.0), (0.0, 0.8, 0.0, 1.0), (0.0, 0.2, 1.0, 1.0))):
            out.append(marker(ns, a, 0, 0, arrow, color, [p, p + 0.1 * R[:, a]]))
    for k, ns in enumerate(ft):
        o, f, n = ft_wrenches[k, 0:3], ft_wrenches[k, 3:6], ft_wrenches[k, 6:9]
        out.append(marker(ns, 0, 0, 0, arrow, (0.95, 0.75, 0.0, 1.0), [o, o + 0.5 / weight * f]))
        out.append(marker(ns, 1, 0, 0, arrow, (0.6, 0.2, 0.85, 1.0), [o, o + 0.5 / weight * n]))
    return {'markers': out}


def _record(path, name, sink_cls, duration, rate=None, chunk_size=None, integrator='rk4', dt=2e-3, batch=0, rtol=None,
            **kw):
    scene = load_scene(name)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        sim = Simulator(scene.system, scene.y0, integrator=integrator, dt=dt, rtol=rtol)
    settings = {'integrator': integrator, 'dt': dt, 'rtol': rtol, 'mode': 'oracle-test'}
    if sink_cls is OracleSink:
        sink = OracleSink(path, scene, settings, chunk_size=chunk_size, **kw)
    else:
        sink = McapRunSink(path, scene, settings, batch=batch, **kw)
        if chunk_size is not None:
            sink.writer.chunk_size = chunk_size
    try:
        n = run_headless(sim, duration, rate or scene.settings.get('publish_rate', 100.0), scene.script, [sink])
    finally:
        sink.close()
    return path.read_bytes(), n


def _compare(tmp_path, name, duration, batch=HEADLESS_BATCH, **kw):
    fast, n = _record(tmp_path / 'fast.mcap', name, McapRunSink, duration, batch=batch, **kw)
    slow, n_slow = _record(tmp_path / 'oracle.mcap', name, OracleSink, duration, **kw)
    assert n == n_slow > 0
    if fast != slow:  # say where, not only that
        k = next(i for i, (a, b) in enumerate(zip(fast, slow)) if a != b) if len(fast) == len(slow) else None
        pytest.fail(f'{name}: recordings differ: {len(fast)} bytes (fast) vs {len(slow)} (oracle), first '
                    f'difference at byte {k}')
    return fast


@pytest.mark.parametrize('batch', [0, 7, HEADLESS_BATCH])
@pytest.mark.parametrize('name', SCENES)
def test_every_scene_records_the_oracle_bytes(tmp_path, name, batch):
    # many small chunks: boundaries fall inside publication periods and inside batches; batch 0 is
    # the message-by-message path of the node, HEADLESS_BATCH the vectorised one of robodyn run
    # (one batch here), 7 many batches per run; RK4 at 2 ms, or at the scene's step where it needs a
    # smaller one (a body on the ground: contact is stiff)
    # smaller one (a body on the ground: contact is stiff); a scene on auto, by auto's choice (xarm7's
    # stiff joint damping refuses rk4: rosenbrock2 at its step); a scene under error control as it is
    # (solo12_drop, huston_human17_fall: rosenbrock2 with its rtol)
    from robodyn_ros.runs import plan_run
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        scene = load_scene(name)
        st = scene.settings
        if st['integrator'] == 'auto':
            st = plan_run(st, scene.system, scene.y0)[1]
    rtol = st.get('rtol') if st['integrator'] == 'rosenbrock2' else None
    integrator = 'rosenbrock2' if (st.get('auto') or rtol) and st['integrator'] == 'rosenbrock2' else 'rk4'
    dt = min(2e-3, st['dt']) if st['integrator'] == 'rk4' or integrator == 'rosenbrock2' else 2e-3
    data = _compare(tmp_path, name, 0.4, batch=batch, chunk_size=3000, diagnostics_period=0.05, dt=dt,
                    integrator=integrator, rtol=rtol)
    assert len(data) > 5000


@pytest.mark.parametrize('flags', [dict(record_tf=False), dict(record_wrenches=False),
                                   dict(record_tf=False, record_wrenches=False)])
@pytest.mark.parametrize('name', ['stanford_arm', 'mobile_manipulator', 'unfried_free_flyer'])
def test_topic_selections_record_the_oracle_bytes(tmp_path, name, flags):
    _compare(tmp_path, name, 0.3, batch=5, chunk_size=2000, diagnostics_period=0.1, **flags)


def test_default_chunking_long_run_records_the_oracle_bytes(tmp_path):
    # the default 768 KiB chunks and 1 s diagnostics, several chunks, 1 ms RK4 as robodyn run does it
    data = _compare(tmp_path, 'stanford_arm', 11.0, dt=1e-3)
    assert data.count(b'zstd') >= 3  # at least three chunks (the compression name is in every chunk record)


def test_odd_rate_and_euler_record_the_oracle_bytes(tmp_path):
    # a publication rate that does not divide the diagnostics period, and another fixed-step method
    _compare(tmp_path, 'betancur_pendulum', 0.3, rate=70.0, chunk_size=1500, integrator='euler', dt=5e-4,
             diagnostics_period=0.033)


def test_adaptive_integrator_records_the_oracle_bytes(tmp_path):
    _compare(tmp_path, 'huston_p19_2_3', 0.2, chunk_size=2500, integrator='dop853', dt=None, diagnostics_period=0.1)


def test_a_batch_holds_no_more_than_the_open_chunk_has_room_for(tmp_path, monkeypatch):
    # crash safety in bytes: what a killed headless run has not handed to the file (the open chunk
    # and the periods held) stays within about one chunk: when a batch is written, the open chunk and
    # the batch's rows but its last fit in one chunk; and the batches are not one period each
    seen = []
    write_held = McapRunSink._write_held

    def checked(self):
        if self._held:
            seen.append((self.writer._open_chunk_bytes, self._held, self._layout.template.size,
                         self.writer.chunk_size))
        write_held(self)
    monkeypatch.setattr(McapRunSink, '_write_held', checked)
    _compare(tmp_path, 'stanford_arm', 2.0, chunk_size=20_000, diagnostics_period=0.1, dt=1e-3)
    assert len(seen) > 10
    for open_bytes, held, row, chunk in seen:
        assert open_bytes + (held - 1) * row < chunk, (open_bytes, held, row, chunk)
    assert max(h for _, h, _, _ in seen) >= 8


@pytest.mark.parametrize('batch', [0, HEADLESS_BATCH])
def test_chunks_close_every_half_second_of_simulation(tmp_path, batch):
    # crash safety in time: a small recording (about 500 B per period, far below 64 KiB per
    # 0.5 s) still closes a chunk once it spans 0.5 s of simulation, as the node records
    from mcap.reader import make_reader
    kw = dict(record_tf=False, record_wrenches=False, diagnostics_period=1.0)
    scene = load_scene('betancur_pendulum')
    paths = []
    for cls in (McapRunSink, OracleSink):
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            sim = Simulator(scene.system, scene.y0, integrator='rk4', dt=1e-3)
        path = tmp_path / f'{cls.__name__}.mcap'
        if cls is McapRunSink:
            sink = McapRunSink(path, scene, {}, batch=batch, chunk_span=0.5, **kw)
        else:
            sink = OracleSink(path, scene, {}, **kw)
            sink.writer.chunk_span_ns = 500_000_000
        run_headless(sim, 3.0, 100.0, scene.script, [sink])
        sink.close()
        paths.append(path)
    assert paths[0].read_bytes() == paths[1].read_bytes()
    with open(paths[0], 'rb') as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    assert len(chunks) >= 6   # 3 s of simulation
    for c in chunks:
        assert c.message_end_time - c.message_start_time <= 500_000_000 + 10_000_000  # 0.5 s + one period
    starts = [c.message_start_time for c in chunks]
    assert max(np.diff(starts)) <= 510_000_000


@pytest.mark.processes
def test_node_recording_closes_chunks_every_half_second_of_simulation(tmp_path):
    # the node's recorder (chunk_span NODE_CHUNK_SPAN), not only a sink built with chunk_span:
    # betancur_pendulum writes about 0.5 KiB per period, so by size alone a 64 KiB chunk would
    # span over a second of simulation
    from mcap.reader import make_reader
    from ros_helpers import run_sim_to_end
    rec = tmp_path / 'node.mcap'
    rc, log = run_sim_to_end({'scene': 'betancur_pendulum', 'mode': 'max', 'duration': 3.0, 'record': str(rec)},
                             tmp_path / 'node.log')
    assert rc == 0, log
    with open(rec, 'rb') as f:
        summary = make_reader(f).get_summary()
    chunks = summary.chunk_indexes
    assert summary.statistics.message_end_time >= 3_000_000_000
    assert len(chunks) >= 6   # 3 s of simulation
    for c in chunks:
        assert c.message_end_time - c.message_start_time <= 500_000_000 + 10_000_000  # 0.5 s + one period


def _drive(sink, scene, calls):
    """Feed a sink a scripted sequence of on_command/on_output calls taken from a real run."""
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        sim = Simulator(scene.system, scene.y0, integrator='rk4', dt=1e-3)
    sink.on_start(sim)
    for kind, *args in calls:
        if kind == 'cmd':
            sink.on_command(*args)
        else:
            t, advance_to, mutate = args
            if advance_to is not None:
                sim.advance(advance_to)
            out = sim.outputs(wrenches=True)
            if mutate:
                mutate(out)
            sink.on_output(t, out, sim)
    sink.close()


@pytest.mark.parametrize('batch', [0, 3, HEADLESS_BATCH])
def test_irregular_calls_record_the_oracle_bytes(tmp_path, batch):
    # commands at two times in one period, periods without commands, a port that appears late,
    # integer arrays (the generic encoder), a wrench set that changes, and commands applied after
    # the last publication (a run that stopped): each kind change falls back or starts a new layout
    scene = load_scene('stanford_arm')
    e = np.linspace(0.1, 0.6, 6)

    def ints(out):
        out.position = np.round(out.position * 100).astype(np.int64)

    def fewer(out):
        out.wrenches = {k: out.wrenches[k] for k in list(out.wrenches)[:3]}
    calls = [('out', 0.0, None, None)]
    for k in range(1, 30):
        t = k * 0.01
        if k % 5:
            calls.append(('cmd', t - 0.01, 'effort', e * k))
        if k == 12:
            calls.append(('cmd', t - 0.005, 'effort', -e))   # a second command, later in the same period
        calls.append(('out', t, t, ints if k == 17 else fewer if 20 <= k < 24 else None))
    calls.append(('cmd', 0.29, 'effort', e))
    paths = []
    for cls in (McapRunSink, OracleSink):
        path = tmp_path / f'{cls.__name__}.mcap'
        sink = McapRunSink(path, scene, {}, batch=batch, diagnostics_period=0.07) if cls is McapRunSink else \
            OracleSink(path, scene, {}, diagnostics_period=0.07)
        _drive(sink, scene, calls)
        paths.append(path.read_bytes())
    assert len(paths[0]) > 10000 and paths[0] == paths[1]


@pytest.mark.parametrize('name', ['stanford_arm', 'betancur_pendulum', 'huston_prescribed_planar3'])
def test_batched_wrench_kernel_records_the_oracle_bytes(tmp_path, name, monkeypatch):
    # long runs switch to one compiled call per batch for the arms' joint wrenches: from the start here
    from robodyn_ros.systems import arm
    monkeypatch.setattr(arm, 'BATCH_KERNEL_AFTER', 0)
    _compare(tmp_path, name, 0.5, batch=9, chunk_size=3000, diagnostics_period=0.1)


def test_arm_wrenches_are_computed_when_read_and_batched_bit_for_bit(monkeypatch):
    from robodyn_ros import dynamics as dyn
    from robodyn_ros.systems import arm
    from robodyn_ros.systems.base import LazyWrenches
    scene = load_scene('stanford_arm')
    s = scene.system
    rng = np.random.default_rng(21)
    outs = []
    for _ in range(9):
        y = scene.y0 + rng.normal(size=s.ny) * 0.3
        outs.append(s.outputs(0.0, y, {'effort': rng.normal(size=6)}, wrenches=True))
    w = outs[0].wrenches
    assert isinstance(w, LazyWrenches) and w._f is None   # nothing computed yet
    assert list(w) == list(s.model.joint_names) and len(w) == s.model.nb and w._f is None
    frame, f0 = w[s.model.joint_names[2]]
    assert frame == s.model.link_names[2] and w._f is not None
    with pytest.raises(ValueError):
        f0[0] = 1.0                                        # read-only views of the computed array
    # the numpy reference (an independent implementation) agrees, and the batch is the same bits
    q, v, tau = w.args
    ref = dyn.joint_wrenches(s.model, q, v, tau)[1]
    assert np.allclose(w.array(), ref, rtol=1e-10, atol=1e-10 * np.abs(ref).max())
    one_by_one = np.array([o.wrenches.array() for o in outs]).tobytes()
    assert w.many([o.wrenches.args for o in outs]).tobytes() == one_by_one   # short run: per state
    monkeypatch.setattr(arm, 'BATCH_KERNEL_AFTER', 0)
    assert w.many([o.wrenches.args for o in outs]).tobytes() == one_by_one   # the batch kernel
