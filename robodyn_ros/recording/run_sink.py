"""The simulator-to-MCAP sink: every published and received message, stamped with simulation time."""
from __future__ import annotations

import json
import warnings

import numpy as np

from .. import messages as M
from ..kernels.records import fill_rows
from ..systems.base import LazyWrenches
from ..version import __version__
from . import cdr
from .fanout import Fanout
from .markers import TOPIC as MARKERS_TOPIC
from .markers import TYPE as MARKERS_TYPE
from .markers import MarkerInputs, Markers
from .mcap_sink import McapSink


#: the gap a message record's header is written into (mcap_sink's 31-byte record header)
_GAP = bytes(31)
#: periods per vectorised pass in headless runs (``robodyn run``) at most; a pass also holds no more
#: rows than the file's open chunk has room for (see ``McapRunSink``)
HEADLESS_BATCH = 1024
#: seconds of simulation after which the node's recorder closes a chunk (a killed node loses at
#: most this much, plus one publication); headless runs chunk by size only (0.5 s of simulation
#: is a few milliseconds of their wall time, and their files stay as they were)
NODE_CHUNK_SPAN = 0.5


def resolve(topic: str, namespace: str = '') -> str:
    """Fully qualified topic name as rosbag2 records it (relative names go under the namespace)."""
    if topic.startswith('/'):
        return topic
    ns = '/' + namespace.strip('/') if namespace.strip('/') else ''
    return f'{ns}/{topic}'


def output_records(t_ns: int, out, wrenches: bool, tf=None, want=None, tf_layouts=None) -> list:
    """The state messages of one publication as CDR: ``[(topic, type, bytes), ...]``.

    The messages of :func:`robodyn_ros.messages.output_messages` (same topics, same order), each
    the bytes ``cdr.encode`` gives its dict, but written straight from the outputs (joint_states,
    odom, wrenches, /tf) without building the dicts. out: SystemOutputs; wrenches: include the
    constraint wrenches; tf: a :class:`robodyn_ros.tf.TfTree` or None; want: optional predicate
    ``topic -> bool`` (messages it refuses are not built); tf_layouts: a dict the caller keeps
    to cache the /tf byte layout. Shared by the recorder and the node (which publishes the bytes).
    """
    sec, nsec = divmod(t_ns, 1_000_000_000)
    recs = []
    if want is None or want('joint_states'):
        js = cdr.joint_state_bytes(sec, nsec, cdr.joint_state_names('', tuple(out.joint_names)),
                                   out.position, out.velocity, out.effort)
        if js is None:  # arrays of another type: the dicts (which convert them) and the generic encoder
            return [(topic, tn, cdr.encode(tn, msg)) for topic, tn, msg in M.output_messages(t_ns, out, wrenches, tf)
                    if want is None or want(topic)]
        recs.append(('joint_states', M.TOPIC_TYPES['joint_states'], js))
    if out.odom is not None and (want is None or want('odom')):
        recs.append(('odom', M.TOPIC_TYPES['odom'], cdr.odometry_bytes(sec, nsec, out.odom, child=out.odom_child)))
    if wrenches:
        for name, (frame, w) in out.wrenches.items():
            topic = M.wrench_topic(name)
            if want is None or want(topic):
                recs.append((topic, M.WRENCH_TYPE, cdr.wrench_stamped_bytes(sec, nsec, frame, w)))
    for link, (frame, w) in out.contacts.items():
        topic = M.contact_topic(link)
        if want is None or want(topic):
            recs.append((topic, M.WRENCH_TYPE, cdr.wrench_stamped_bytes(sec, nsec, frame, w)))
    js_type = M.TOPIC_TYPES['joint_states']
    for topic, type_name, msg in out.messages:   # sensors, a servo's desired and error states
        if want is None or want(topic):
            data = None
            if type_name == js_type:   # the fast encoders (the same bytes as cdr.encode)
                data = cdr.joint_state_bytes(sec, nsec, cdr.joint_state_names(msg['header']['frame_id'],
                                                                              tuple(msg['name'])),
                                             msg['position'], msg['velocity'], msg['effort'])
            elif type_name == M.WRENCH_TYPE:
                n, f = msg['wrench']['torque'], msg['wrench']['force']
                data = cdr.wrench_stamped_bytes(sec, nsec, msg['header']['frame_id'],
                                                (n['x'], n['y'], n['z'], f['x'], f['y'], f['z']))
            recs.append((topic, type_name, cdr.encode(type_name, msg) if data is None else data))
    if tf is not None and (want is None or want('/tf')):
        trs = tf.transforms(out.joint_names, out.position, out.odom)
        if trs:
            layouts = {} if tf_layouts is None else tf_layouts
            key = (id(tf), len(trs), trs[0][0], trs[0][1])  # the frames only change with the odom entry
            layout = layouts.get(key)
            if layout is None:
                layout = layouts[key] = cdr.tf_layout(tuple((pa, ch) for pa, ch, _, _ in trs))
            recs.append(('/tf', M.TOPIC_TYPES['/tf'],
                         cdr.tf_message_bytes(layout, [(sec, nsec)] * len(trs), [(*p, *q) for _, _, p, q in trs])))
    return recs


class _PeriodLayout:
    """The records of one publication period laid out once: commands applied at its start, then
    joint_states, odom, constraint wrenches, contact wrenches, the further messages (sensors, a servo's
    states: JointState, WrenchStamped, Imu), /tf and /clock, each a 31-byte record-header gap
    and its CDR, back to back in a row of fixed length whose numbers sit at fixed offsets.

    K periods are K copies of the row (a ``(K, R)`` uint8 array); their numbers are written with
    one gather and one scatter per kind (float64 values, stamps), see :meth:`rows`. Built from
    the first period of a kind (the templates are those of the per-message fast encoders).

    cmds: ``[(port, n values)]``; out: the period's SystemOutputs; wrenches, tf: the sink's
    choices; channel: ``topic, type -> channel id`` (all already registered).
    """

    def __init__(self, cmds, out, wrenches: bool, tf, channel):
        msgs = []          # (topic, type, template, is_cmd, [(payload offset, value column)], [stamp offsets])
        col = 0
        self.cmd_cols = []
        for port, n in cmds:
            topic = M.PORT_TOPICS[port]
            if port == 'base_wrench':   # values [fx, fy, fz, tx, ty, tz] = the message's order
                tpl, at = cdr.wrench_stamped_layout('base_link')
                stamps = [cdr.STAMP_AT]
            else:
                tpl, at = cdr.float64_array_layout(n)
                stamps = []
            msgs.append((topic, M.TOPIC_TYPES[topic], tpl, True, [(at + 8 * i, col + i) for i in range(n)], stamps))
            self.cmd_cols.append(slice(col, col + n))
            col += n
        names = tuple(out.joint_names)
        counts = (len(out.position), len(out.velocity), len(out.effort))
        tpl, ats = cdr.joint_state_layout(cdr.joint_state_names('', names), counts)
        vals, self.js_cols = [], []
        for at, n in zip(ats, counts):
            vals += [(at + 8 * i, col + i) for i in range(n)]
            self.js_cols.append(slice(col, col + n))
            col += n
        self.pos_cols = self.js_cols[0]
        msgs.append(('joint_states', M.TOPIC_TYPES['joint_states'], tpl, False, vals, [cdr.STAMP_AT]))
        self.odom_cols = None
        if out.odom is not None:    # position 3, orientation 4, linear 3, angular 3
            tpl, at = cdr.odometry_layout(child=out.odom_child)
            self.odom_cols = col
            vals = [(at + 8 * i, col + i) for i in range(7)] + [(at + 8 * (43 + i), col + 7 + i) for i in range(6)]
            msgs.append(('odom', M.TOPIC_TYPES['odom'], tpl, False, vals, [cdr.STAMP_AT]))
            col += 13
        self.wrench_cols = []
        self.lazy = wrenches and isinstance(out.wrenches, LazyWrenches)   # computed in one call per batch
        self.wrench_block = slice(col, col + 6 * len(out.wrenches)) if wrenches else None
        self.many = out.wrenches.many if self.lazy else None
        self.wrench_args = []
        if wrenches:
            items = zip(out.wrenches.names, out.wrenches.frames) if self.lazy else \
                ((name, frame) for name, (frame, _) in out.wrenches.items())
            for name, frame in items:   # w = [torque; force], the message: force, torque
                tpl, at = cdr.wrench_stamped_layout(frame)
                msgs.append((M.wrench_topic(name), M.WRENCH_TYPE, tpl, False,
                             [(at + 8 * i, col + (3 + i) % 6) for i in range(6)], [cdr.STAMP_AT]))
                self.wrench_cols.append(slice(col, col + 6))
                col += 6
        self.contact_cols = []
        for link, (frame, _) in out.contacts.items():   # the ground's wrenches, computed with the outputs
            tpl, at = cdr.wrench_stamped_layout(frame)
            msgs.append((M.contact_topic(link), M.WRENCH_TYPE, tpl, False,
                         [(at + 8 * i, col + (3 + i) % 6) for i in range(6)], [cdr.STAMP_AT]))
            self.contact_cols.append(slice(col, col + 6))
            col += 6
        self.msg_cols = []
        for topic, type_name, msg in out.messages:   # sensors, a servo's states: after the contacts (output_records)
            frame = msg['header']['frame_id']
            if type_name == _JS_TYPE:
                counts = (len(msg['position']), len(msg['velocity']), len(msg['effort']))
                tpl, ats = cdr.joint_state_layout(cdr.joint_state_names(frame, tuple(msg['name'])), counts)
                starts = np.cumsum((0,) + counts)
                vals = [(at + 8 * i, col + int(c0) + i) for at, c0, n in zip(ats, starts, counts) for i in range(n)]
                n_vals = int(starts[-1])
            else:   # a WrenchStamped (force, torque) or an Imu: their numbers back to back after the header
                tpl, at = cdr.wrench_stamped_layout(frame) if type_name == M.WRENCH_TYPE else cdr.imu_layout(frame)
                n_vals = 6 if type_name == M.WRENCH_TYPE else 37
                vals = [(at + 8 * i, col + i) for i in range(n_vals)]
            msgs.append((topic, type_name, tpl, False, vals, [cdr.STAMP_AT]))
            self.msg_cols.append((slice(col, col + n_vals), type_name))
            col += n_vals
        self.n_values = col
        self.tf = None
        if tf is not None:
            frames = tf.frames(out.odom is not None)
            if frames:
                self.tf, self.joint_names = tf, names
                tpl, stamp_at, values_at = cdr.tf_layout(tuple(frames))
                vals = [(at + 8 * i, col + 7 * j + i) for j, at in enumerate(values_at) for i in range(7)]
                msgs.append(('/tf', M.TOPIC_TYPES['/tf'], tpl, False, vals, list(stamp_at)))
                col += 7 * len(frames)
        msgs.append(('/clock', M.TOPIC_TYPES['/clock'], cdr.clock_bytes(0, 0), False, [], [cdr.STAMP_AT]))
        row, rec_off, value_at, value_col, stamp_at, stamp_src = bytearray(), [], [], [], [], []
        for topic, type_name, tpl, is_cmd, vals, stamps in msgs:
            rec_off.append(len(row))
            row += bytes(31)
            base = len(row)
            row += tpl
            value_at += [base + a for a, _ in vals]
            value_col += [c for _, c in vals]
            stamp_at += [base + a for a in stamps]
            stamp_src += [0 if is_cmd else 1] * len(stamps)
        self.template = np.frombuffer(bytes(row), dtype=np.uint8)
        self.rec_off = np.array(rec_off, dtype=np.int64)
        self.channels = np.array([channel(m[0], m[1]) for m in msgs], dtype=np.int64)
        self.is_cmd = np.array([m[3] for m in msgs], dtype=bool)
        self.value_col = np.array(value_col, dtype=np.int64)
        self.value_at = np.array(value_at, dtype=np.int64)
        self.stamp_at = np.array(stamp_at, dtype=np.int64)
        self.stamp_of = np.array(stamp_src, dtype=np.int64)   # 0: the commands' time, 1: the outputs'
        self.n_msgs = len(msgs)
        self._starts = (None, None, None)   # record_starts' last K and its arrays

    def record_starts(self, K):
        """``(offsets (K, n), channels (K n,))`` of K rows' records: each record's start in the rows'
        bytes and its channel id, row by row (kept for the last K)."""
        if self._starts[0] != K:
            R = self.template.size
            self._starts = (K, np.arange(K, dtype=np.int64)[:, None] * R + self.rec_off, np.tile(self.channels, K))
        return self._starts[1], self._starts[2]

    def fill(self, row, cmds, out):
        """Write one period's numbers into ``row`` (n_values,); cmds: ``[(t, port, values)]``."""
        for sl, (_, _, values) in zip(self.cmd_cols, cmds):
            row[sl] = values
        js = self.js_cols
        row[js[0]] = out.position
        row[js[1]] = out.velocity
        row[js[2]] = out.effort
        if self.odom_cols is not None:
            o, c = out.odom, self.odom_cols
            row[c:c + 3] = o['position']
            row[c + 3:c + 7] = o['orientation']
            row[c + 7:c + 10] = o['linear']
            row[c + 10:c + 13] = o['angular']
        if self.lazy:
            self.wrench_args.append(out.wrenches.args)
        elif self.wrench_cols:
            for sl, (_, w) in zip(self.wrench_cols, out.wrenches.values()):
                row[sl] = w
        for sl, (_, w) in zip(self.contact_cols, out.contacts.values()):
            row[sl] = w
        for (sl, type_name), (_, _, msg) in zip(self.msg_cols, out.messages):
            row[sl] = _message_values(type_name, msg)

    def fill_block(self, rows, blk, i, m):
        """Write periods ``i..i+m`` of a :class:`robodyn_ros.blocks.PeriodBlock` into ``rows`` (m, n_values),
        as :meth:`fill` does one period (wrenches included: the block computed them; the servo's and sensors'
        messages from the block's ``control``)."""
        if self.msg_cols:
            if blk.control is None:
                raise RuntimeError('a period layout with sensor or servo messages needs the block\'s control outputs')
            for j in range(m):
                row = rows[j]
                for (sl, type_name), (_, _, msg) in zip(self.msg_cols, blk.control[i + j][0]):
                    row[sl] = _message_values(type_name, msg)
        for sl, values in zip(self.cmd_cols, blk.commands.values()):
            rows[:, sl] = values[i:i + m]
        js = self.js_cols
        rows[:, js[0]] = blk.position[i:i + m]
        rows[:, js[1]] = blk.velocity[i:i + m]
        rows[:, js[2]] = blk.effort[i:i + m]
        if self.odom_cols is not None:
            rows[:, self.odom_cols:self.odom_cols + 13] = blk.odom[i:i + m]
        if self.wrench_block is not None:
            rows[:, self.wrench_block] = blk.wrenches[i:i + m].reshape(m, -1)
        for j, sl in enumerate(self.contact_cols):
            rows[:, sl] = blk.contacts[i:i + m, j]

    def rows(self, values, times, filled=False):
        """The records of K periods: ``(K, R)`` uint8 (record headers left for the writer).

        values: (K, n_values) from :meth:`fill` (or :meth:`fill_block`: filled, wrenches included);
        times: (K, 2) int64 ns, (commands, outputs).
        """
        K = values.shape[0]
        if self.lazy and not filled:
            args, self.wrench_args = self.wrench_args, []
            if len(args) != K:
                raise RuntimeError(f'{len(args)} wrench states held for {K} periods')
            values[:, self.wrench_block] = self.many(args).reshape(K, -1)
        if self.tf is not None:
            odom = None if self.odom_cols is None else values[:, self.odom_cols:self.odom_cols + 7]
            tfv = self.tf.transform_values(self.joint_names, values[:, self.pos_cols], odom).reshape(K, -1)
            values = np.concatenate([values, tfv], axis=1)
        out = np.empty((K, self.template.size), dtype=np.uint8)
        fill_rows(self.template, np.ascontiguousarray(values).view(np.int64), self.value_col, self.value_at,
                  np.ascontiguousarray(times, dtype=np.int64), self.stamp_at, self.stamp_of, out)
        return out


_JS_TYPE = M.TOPIC_TYPES['joint_states']
_IMU_TYPE = 'sensor_msgs/msg/Imu'


def _message_kind(msgs):
    """What periods encoded together share about their further messages (``SystemOutputs.messages``: sensors, a
    servo's desired and error states): topic, type, frame_id and, for a JointState, its names and array sizes;
    None when one is of a type the batched layout does not lay out, or a JointState's arrays are not float
    arrays (then the periods are written message by message)."""
    kind = []
    for topic, type_name, msg in msgs:
        frame = msg['header']['frame_id']
        if type_name == _JS_TYPE:
            arrays = (msg['position'], msg['velocity'], msg['effort'])
            if not all(isinstance(a, np.ndarray) and a.ndim == 1 and a.dtype.kind == 'f' for a in arrays):
                return None
            kind.append((topic, type_name, frame, tuple(msg['name'])) + tuple(a.shape[0] for a in arrays))
        elif type_name == M.WRENCH_TYPE or type_name == _IMU_TYPE:
            kind.append((topic, type_name, frame))
        else:
            return None
    return tuple(kind)


def _message_values(type_name, msg):
    """The numbers of a message :func:`_message_kind` lays out, in the order of its CDR."""
    if type_name == _JS_TYPE:
        return np.concatenate((msg['position'], msg['velocity'], msg['effort']))
    if type_name == M.WRENCH_TYPE:
        f, n = msg['wrench']['force'], msg['wrench']['torque']
        return (f['x'], f['y'], f['z'], n['x'], n['y'], n['z'])
    o, w, a = msg['orientation'], msg['angular_velocity'], msg['linear_acceleration']
    return np.concatenate(((o['x'], o['y'], o['z'], o['w']), msg['orientation_covariance'], (w['x'], w['y'], w['z']),
                           msg['angular_velocity_covariance'], (a['x'], a['y'], a['z']),
                           msg['linear_acceleration_covariance']))


def _wrench_kind(w):
    """What a batch of periods must share about their wrenches (names, frames, how computed)."""
    if type(w) is LazyWrenches:
        return (w.names, w.frames, w.many)
    return tuple((k, f) for k, (f, _) in w.items())


def _diagnostics_bytes(t_ns: int, sim, level: int, message: str) -> bytes:
    """The recorded diagnostics message as CDR: the bytes ``cdr.encode`` gives
    ``messages.diagnostic_array(t_ns, 'robodyn_ros: simulation', level, message,
    sim.diagnostics_values())``, without building the dicts."""
    sec, nsec = divmod(t_ns, 1_000_000_000)
    return cdr.diagnostic_values_bytes(sec, nsec, '', level, 'robodyn_ros: simulation', message, 'robodyn_ros',
                                       sim.diagnostics_values(), M.format_value)


def run_metadata(scene, settings: dict, extra: dict | None = None) -> dict:
    """The ``robodyn`` metadata record: scene text and name, integrator settings, package version."""
    md = {'scene_name': scene.name, 'scene': scene.text, 'settings': json.dumps(settings, sort_keys=True),
          'package_version': __version__}
    md.update(extra or {})
    return md


class McapRunSink:
    """Records a run: robot_description and /tf_static once, commands as received, state at every
    publication.

    path: output .mcap; scene: the loaded Scene (its text goes into the metadata); settings:
    integrator/rate settings (JSON in the metadata); record_wrenches: also record
    ``constraint_wrenches/*``; diagnostics_period: seconds of simulation time between
    ``diagnostics`` messages; namespace: ROS namespace for relative topic names; record_tf: also
    record ``/tf`` at every publication and ``/tf_static`` once at the start (transient local),
    see :mod:`robodyn_ros.tf`; batch: publication periods encoded together in one vectorised
    pass (0: every message as it comes). A batch is written when it holds ``batch`` periods or
    as many rows as the file's open chunk has room for (the last row closes the chunk, so that a
    killed run loses about one chunk: the open one and the periods held), when the kind of period
    changes, and on :meth:`close`; the file is the same byte for byte. Only for a sink that is the sole writer of
    its file (headless runs): the node, which also writes messages of its own, uses 0.
    chunk_span: close a chunk once it spans this many seconds of simulation (see
    :class:`McapSink`; the node, paced by the wall clock, uses :data:`NODE_CHUNK_SPAN`).
    taps: where the same records also go (a live server's, :mod:`robodyn_ros.recording.fanout`);
    path None with taps: nothing is recorded, the taps get what would be. embed_meshes: the recorded
    ``robot_description`` carries its meshes as ``data:`` URIs (:func:`robodyn_ros.assets.embed_meshes`).
    """

    def __init__(self, path, scene, settings: dict, record_wrenches=True, diagnostics_period=1.0,
                 namespace='', extra_metadata=None, record_tf=True, batch: int = 0, chunk_span=None,
                 taps=(), embed_meshes=True):
        self.path = None if path is None else str(path)
        self.scene = scene
        self.wants_wrenches = record_wrenches
        self.record_tf = record_tf
        self.tf = None   # the TfTree, built in on_start when record_tf
        self.diagnostics_period = diagnostics_period
        self.namespace = namespace
        self.embed_meshes = embed_meshes
        mcap = None if path is None else \
            McapSink(self.path, metadata=run_metadata(scene, settings, extra_metadata), chunk_span=chunk_span)
        self.writer = mcap if not taps else Fanout(mcap, taps)
        self._next_diag = None
        self.count = 0
        self._channels = {}   # relative topic -> channel id (resolved and registered on first use)
        self._tf_layouts = {}
        self.batch = max(0, int(batch))
        self._cmds = []       # commands applied since the last publication: (t, port, values)
        self._layouts = {}    # kind of period -> _PeriodLayout
        self._layout = None   # the layout of the periods held
        self._kind = None     # the kind of period of _layout
        self._kind_of = (None, None, None)   # block_periods' last (template, commands, kind of period)
        self._diag_topic = resolve('diagnostics', namespace)
        self._values = None   # (batch, n_values) numbers of the periods held
        self._times = None    # (batch, 2) int64 ns: commands, outputs
        self._after = {}      # period index -> [(topic, type, CDR)] written after it (markers, diagnostics)
        self.markers = None   # the run's Markers (recording.markers), set in on_start; None: no markers topic
        self._held = 0        # periods held
        self._cap = 0         # periods the batch being held takes (_batch_cap, when it starts)
        self._filled = False  # the periods held came from blocks (their wrenches are in _values)

    def _write(self, topic, type_name, msg, t_ns):
        self.writer.write(resolve(topic, self.namespace), type_name, msg, t_ns)
        self.count += 1

    def _write_data(self, topic, type_name, data, t_ns):
        """Record CDR bytes (the fast path of :meth:`_write`: same channel, same record)."""
        cid = self._channels.get(topic)
        if cid is None:
            cid = self._channels[topic] = self.writer.channel(resolve(topic, self.namespace), type_name)
        self.writer.write_data(cid, data, t_ns)
        self.count += 1

    def on_start(self, sim):
        """Record ``robot_description`` (``command_joint_names`` with position or velocity commands, and
        ``/tf_static``) at the start time."""
        t_ns = M.to_ns(sim.t)
        self.writer.add_topic(resolve('robot_description', self.namespace), M.TOPIC_TYPES['robot_description'],
                              qos='transient_local')
        self._write_data('robot_description', M.TOPIC_TYPES['robot_description'],
                         cdr.string_message_bytes(self.description_parts(sim)), t_ns)
        if any(p in sim.system.inputs for p in ('position', 'velocity')):   # the joints of each command topic
            self.writer.add_topic(resolve('command_joint_names', self.namespace),
                                  M.TOPIC_TYPES['command_joint_names'], qos='transient_local')
            self._write('command_joint_names', M.TOPIC_TYPES['command_joint_names'],
                        M.string(M.command_joint_names(sim.system)), t_ns)
        if self.record_tf:
            from ..tf import TfTree
            self.tf = TfTree(sim.system)
            self.write_tf_static(t_ns)
        self.markers = Markers.of(sim.system)
        self._next_diag = sim.t

    def description_parts(self, sim) -> tuple:
        """The recorded robot_description, the system's URDF with its meshes embedded (``embed_meshes``), as the
        UTF-8 bytes of its pieces (:func:`robodyn_ros.assets.embed_meshes_parts`), which the record joins once."""
        urdf = sim.system.urdf()
        if not self.embed_meshes:
            return (urdf.encode('utf-8'),)
        from ..assets import embed_meshes_parts
        parts, notes = embed_meshes_parts(urdf)
        for note in notes:
            warnings.warn(f'recording {self.path or "(live)"}: {note}', stacklevel=2)
        return parts

    def hand_over(self):
        """Write the periods held for the next vectorised pass now (a live run about to wait: its
        viewers see every period written so far). The file is the same byte for byte."""
        if not self.writer.closed:
            self._write_held()

    def write_tf_static(self, t_ns):
        """Record ``/tf_static`` (transient local) when the tree has fixed joints."""
        msg = self.tf.static_message(t_ns)
        if msg['transforms']:
            self.writer.add_topic('/tf_static', M.TOPIC_TYPES['/tf_static'], qos='transient_local')
            self._write('/tf_static', M.TOPIC_TYPES['/tf_static'], msg, t_ns)

    def on_command(self, t, port, values):
        """Record a command as it was applied (Float64MultiArray for effort/voltage ports, the
        JointTrajectory message for a trajectory)."""
        if port == 'trajectory':   # a message, not numbers: after the periods held, as it comes
            self._write_held()
            self._write('joint_trajectory', M.TOPIC_TYPES['joint_trajectory'], values, M.to_ns(t))
            return
        if self.batch:
            self._cmds.append((t, port, np.array(values, dtype=float)))
            return
        self._write_command(t, port, values)

    def _write_command(self, t, port, values):
        topic = M.PORT_TOPICS[port]
        t_ns = M.to_ns(t)
        # the bytes cdr.encode gives the message dicts (M.wrench_stamped, M.float64_array), without the dicts
        if port == 'base_wrench':  # [fx, fy, fz, tx, ty, tz] -> the spatial force [torque; force]
            w = list(values[3:6]) + list(values[0:3])
            data = cdr.wrench_stamped_bytes(*divmod(t_ns, 1_000_000_000), 'base_link', w)
        else:
            data = cdr.float64_array_bytes(values)
            if data is None:
                self._write(topic, M.TOPIC_TYPES[topic], M.float64_array(values), t_ns)
                return
        self._write_data(topic, M.TOPIC_TYPES[topic], data, t_ns)

    def on_output(self, t, out, sim, level=0, message='running'):
        """Record the state messages, ``/clock``, and ``diagnostics`` every diagnostics_period.

        The messages of :func:`robodyn_ros.messages.output_messages` in that order; joint_states,
        odom, wrenches, /tf and /clock are encoded straight from the outputs (the bytes the message
        dicts encode to, without building them).
        """
        if self.batch and self._hold(t, out, sim, level, message):
            return
        t_ns = M.to_ns(t)
        for topic, type_name, data in output_records(t_ns, out, self.wants_wrenches, self.tf,
                                                     tf_layouts=self._tf_layouts):
            self._write_data(topic, type_name, data, t_ns)
        self._write_data('/clock', M.TOPIC_TYPES['/clock'], cdr.clock_bytes(*divmod(t_ns, 1_000_000_000)), t_ns)
        if self.markers is not None:
            data = self.markers.message(t_ns, MarkerInputs.of_outputs(out))
            self._write_data(MARKERS_TOPIC, MARKERS_TYPE, data, t_ns)
        if self._diag_due(t):
            self._write('diagnostics', M.TOPIC_TYPES['diagnostics'],
                        M.diagnostic_array(t_ns, 'robodyn_ros: simulation', level, message,
                                             sim.diagnostics_values()), t_ns)
            self._next_diag += self.diagnostics_period

    def _diag_due(self, t) -> bool:
        """True when the publication at t (s) carries a diagnostics message (one per diagnostics_period)."""
        return self._next_diag is not None and t >= self._next_diag - 1e-9

    # -- batches of periods --------------------------------------------------------------
    def _batch_cap(self) -> int:
        """Periods the batch starting now takes at most: ``batch``, and no more rows of the layout than
        the file's open chunk has room for (rounded up: the last one closes the chunk)."""
        room = self.writer.room()
        if room is None:   # no file: only the taps
            return self.batch
        return min(self.batch, max(1, -(-room // self._layout.template.size)))

    def _batch_done(self) -> bool:
        """True when the periods held are to be written (the batch's cap reached)."""
        return self._held >= self._cap

    def _period_kind(self, cmd_kind, out) -> tuple:
        """What periods encoded together share: commands (port, size), joint_states names and
        sizes, odom or not, the wrenches' names, frames and how they are computed."""
        return (cmd_kind, tuple(out.joint_names), len(out.position), len(out.velocity), len(out.effort),
                out.odom is None, _wrench_kind(out.wrenches) if self.wants_wrenches else (),
                tuple((k, f) for k, (f, _) in out.contacts.items()), _message_kind(out.messages))

    @property
    def takes_blocks(self) -> bool:
        """True when batching: the Simulator's block path may hand this sink many periods at once."""
        return self.batch > 0

    #: with a lone sink, :class:`robodyn_ros.blocks.BlockRunner` hands this one the periods of a
    #: block in one piece: :meth:`on_block` puts the Simulator at each diagnostics message's period
    arrives_in_blocks = True

    def block_periods(self, t_out, template, cmd_kind, arriving=False) -> int:
        """How many of the periods ending at ``t_out`` (s) :meth:`on_block` can take in one block:
        up to the first one that ends with a diagnostics message (inclusive: the Simulator is then
        at its end), all of them when arriving (the block's ``arrive`` puts the Simulator at each
        such period), 0 when they are not of the kind of the periods held so far (the per-period
        path registers new channels and layouts first)."""
        if not self.batch or self._cmds or self._layout is None:
            return 0
        if template is not self._kind_of[0] or cmd_kind != self._kind_of[1]:   # the kind of a template, once
            self._kind_of = (template, cmd_kind, self._period_kind(cmd_kind, template))
        if self._kind_of[2] != self._kind:
            return 0
        if self._next_diag is None:
            return len(t_out)
        if self._diag_topic not in self.writer._channels:
            return 0
        if arriving:
            return len(t_out)
        due = int(np.searchsorted(t_out, self._next_diag - 1e-9, 'left'))   # the first t_out >= it (ascending)
        return due + 1 if due < len(t_out) else len(t_out)

    def on_block(self, blk, sim, level=0, message='running'):
        """Record K periods run in one block (:class:`robodyn_ros.blocks.PeriodBlock`): the
        records :meth:`on_command` and :meth:`on_output` write for each, batch by batch as they
        would be (:meth:`block_periods` said this sink takes them). A diagnostics message is due
        at most after the last one, where ``sim`` is, or, when the block has ``arrive``, after
        any of them: ``blk.arrive(j)`` puts ``sim`` at the end of period j first."""
        if self._held and not self._filled:
            self._write_held()   # periods of the per-period path: their wrenches are computed when written
        L = self._layout
        K = blk.t_out.shape[0]
        t_out = np.rint(blk.t_out * 1e9).astype(np.int64)   # messages.to_ns of each
        t_cmd = np.rint(blk.t_cmd * 1e9).astype(np.int64) if blk.commands else t_out
        # the periods that end with a diagnostics message (_diag_due of each, in turn)
        due = []
        if self._next_diag is not None:
            nd = self._next_diag
            j = int(np.searchsorted(blk.t_out, nd - 1e-9, 'left'))
            while j < K:
                due.append((j, nd))
                nd += self.diagnostics_period   # one message per period at most, as on_output writes them
                j = max(j + 1, int(np.searchsorted(blk.t_out, nd - 1e-9, 'left')))
            if due and blk.arrive is None and due[0][0] != K - 1:
                raise RuntimeError(f'a diagnostics message is due at period {due[0][0]} of {K}, '
                                   'before the Simulator')
        d = 0
        i = 0
        while i < K:
            h = self._held
            if not h:
                self._cap = self._batch_cap()
            m = min(K - i, self._cap - h)   # as many as the batch takes
            L.fill_block(self._values[h:h + m], blk, i, m)
            self._times[h:h + m, 0] = t_cmd[i:i + m]
            self._times[h:h + m, 1] = t_out[i:i + m]
            if self.markers is not None:   # drawn from each period's state (the block has no outputs)
                ny = sim.system.ny
                many = getattr(sim.system, 'contact_point_outputs', None)
                P = None
                if blk.control is None:   # the block's own (the compiled loop's, of the same states), else computed
                    P = blk.points[i:i + m] if blk.points is not None else \
                        many(blk.z[i:i + m, :ny]) if many is not None else None
                if P is not None:   # the m periods' markers at once: the same bytes
                    data = self.markers.state_messages(t_out[i:i + m], P)
                elif blk.control is not None:   # the sensors' frames and readings of each period (and contacts)
                    data = [self.markers.message(int(t_out[i + j]), MarkerInputs(
                        contact_points=sim.system.contact_points(blk.z[i + j, :ny]), imu_poses=blk.control[i + j][1],
                        ft_wrenches=blk.control[i + j][2])) for j in range(m)]
                else:
                    data = [self.markers.message(int(t_out[i + j]), MarkerInputs.of_state(sim.system, blk.z[i + j, :ny]))
                            for j in range(m)]
                for j in range(m):
                    self._after[h + j] = [(MARKERS_TOPIC, MARKERS_TYPE, data[j])]
            self._held = h + m
            self._filled = True
            while d < len(due) and due[d][0] < i + m:   # the diagnostics of these periods, the Simulator at each
                j, nd = due[d]
                if blk.arrive is not None:
                    blk.arrive(j)
                data = _diagnostics_bytes(int(t_out[j]), sim, level, message)
                self._after.setdefault(h + j - i, []).append(('diagnostics', M.TOPIC_TYPES['diagnostics'], data))
                self._next_diag = nd + self.diagnostics_period
                d += 1
            i += m
            if self._batch_done():
                self._write_held()

    def _hold(self, t, out, sim, level, message) -> bool:
        """Keep this period for the next vectorised pass; False when it must be written message
        by message now (a new topic is registered on its first message, so that channel records
        land where the per-message path puts them; odd arrays take the generic encoder)."""
        cmds = self._cmds
        if self._filled:
            self._write_held()   # periods of blocks first (their wrenches are in _values)
        kind = self._period_kind(tuple([(p, v.shape[0]) for _, p, v in cmds]), out)
        # the kind of the previous period (tuple equality, no hashing), else one seen before
        layout = self._layout if kind == self._kind else self._layouts.get(kind)
        diag = self._diag_due(t)
        if layout is None:
            self._write_held()
            if not self._layout_ready(kind, out):
                for tc, port, values in cmds:   # message by message: registers the new channels in order
                    self._write_command(tc, port, values)
                self._cmds = []
                return False
            layout = self._layouts[kind] = _PeriodLayout([(p, v.shape[0]) for _, p, v in cmds], out,
                                                         self.wants_wrenches, self.tf, self._channel)
        if (diag and resolve('diagnostics', self.namespace) not in self.writer._channels) or \
                (len(cmds) > 1 and any(c[0] != cmds[0][0] for c in cmds)):   # a new topic, commands at several times
            self._write_held()
            for tc, port, values in cmds:
                self._write_command(tc, port, values)
            self._cmds = []
            return False
        if layout is not self._layout:
            self._write_held()
            self._layout, self._kind = layout, kind
            self._values = np.empty((self.batch, layout.n_values))
            self._times = np.empty((self.batch, 2), dtype=np.int64)
        k = self._held
        if not k:
            self._cap = self._batch_cap()
        t_ns = M.to_ns(t)
        layout.fill(self._values[k], cmds, out)
        self._times[k] = (M.to_ns(cmds[0][0]) if cmds else t_ns, t_ns)
        self._cmds = []
        self._held = k + 1
        if self.markers is not None:
            self._after[k] = [(MARKERS_TOPIC, MARKERS_TYPE, self.markers.message(t_ns, MarkerInputs.of_outputs(out)))]
        if diag:
            self._after.setdefault(k, []).append(
                ('diagnostics', M.TOPIC_TYPES['diagnostics'], _diagnostics_bytes(t_ns, sim, level, message)))
            self._next_diag += self.diagnostics_period
        if self._batch_done():
            self._write_held()
        return True

    def _layout_ready(self, kind, out) -> bool:
        """True when every topic of this kind of period has its channel and the arrays are floats."""
        arrays = (out.position, out.velocity, out.effort)
        if kind[-1] is None or not all(isinstance(a, np.ndarray) and a.ndim == 1 and a.dtype.kind == 'f'
                                       for a in arrays):
            return False   # (further messages of other types: written one by one)
        topics = [M.PORT_TOPICS[p] for p, _ in kind[0]] + ['joint_states', '/clock']
        topics += [topic for topic, _, _ in out.messages]
        topics += [] if out.odom is None else ['odom']
        topics += [M.wrench_topic(k) for k in out.wrenches] if self.wants_wrenches else []
        topics += [M.contact_topic(k) for k in out.contacts]
        if self.tf is not None and self.tf.frames(out.odom is not None):
            topics.append('/tf')
        if self.markers is not None:
            topics.append(MARKERS_TOPIC)
        return all(t in self._channels for t in topics)

    def _channel(self, topic, type_name) -> int:
        cid = self._channels.get(topic)
        if cid is None:
            cid = self._channels[topic] = self.writer.channel(resolve(topic, self.namespace), type_name)
        return cid

    def _write_held(self):
        """Encode the periods held in one pass and hand their records to the writer."""
        K = self._held
        if not K:
            return
        L = self._layout
        rows = L.rows(self._values[:K], self._times[:K], filled=self._filled)
        R = rows.shape[1]
        times = np.where(L.is_cmd, self._times[:K, 0:1], self._times[:K, 1:2])
        offs, chans = L.record_starts(K)   # (K, n) each record's start in the rows, (K * n,) its channel
        if not self._after:
            records, offsets = rows.reshape(-1), offs.ravel()
            channels, log_times = chans, times.ravel()
        else:   # records after some periods (markers, diagnostics): inserted after their rows, in one pass
            n = L.n_msgs
            mv = rows.reshape(-1).data
            pieces, after, e_offs, e_chans = [], [], [], []
            shift = np.zeros(K + 1, dtype=np.int64)    # extra bytes right before row k (cumulated below)
            a = 0        # bytes of the rows taken so far
            added = 0    # bytes of the records inserted so far
            for k in sorted(self._after):
                end = (k + 1) * R
                if end > a:
                    pieces.append(mv[a:end])
                    a = end
                for topic, type_name, data in self._after[k]:
                    pieces.append(_GAP)
                    pieces.append(data)
                    e_offs.append(end + added)
                    e_chans.append(self._channel(topic, type_name))
                    after.append(k)
                    added += 31 + len(data)
                    shift[k + 1] += 31 + len(data)
            pieces.append(mv[a:])
            records = np.frombuffer(bytearray().join(pieces), dtype=np.uint8)
            # the i-th inserted record (after row k) lands at (k + 1) n + i in the records' order
            pos = np.array(after, dtype=np.int64)
            rest = np.ones(K * n + len(after), dtype=bool)
            ins = (pos + 1) * n + np.arange(len(after))
            rest[ins] = False
            offsets = np.empty(rest.size, dtype=np.int64)
            offsets[rest] = (offs + np.cumsum(shift[:K])[:, None]).ravel()
            offsets[ins] = e_offs
            channels = np.empty(rest.size, dtype=np.int64)
            channels[rest] = chans
            channels[ins] = e_chans
            log_times = np.empty(rest.size, dtype=np.int64)
            log_times[rest] = times.ravel()
            log_times[ins] = self._times[pos, 1]
        self.writer.write_records(records, offsets, channels, log_times)
        self.count += len(offsets)
        self._held = 0
        self._filled = False
        self._after = {}

    def close(self):
        """Finish the file (periods held, summary, footer); idempotent."""
        if not self.writer.closed:
            self._write_held()
            for tc, port, values in self._cmds:   # applied, but no publication followed (a failed run)
                self._write_command(tc, port, values)
            self._cmds = []
        self.writer.close()
