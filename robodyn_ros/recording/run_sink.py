"""The simulator-to-MCAP sink: every published and received message, stamped with simulation time."""
from __future__ import annotations

import json

from .. import messages as M
from ..version import __version__
from . import cdr
from .mcap_sink import McapSink


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
    see :mod:`robodyn_ros.tf`.
    """

    def __init__(self, path, scene, settings: dict, record_wrenches=True, diagnostics_period=1.0,
                 namespace='', extra_metadata=None, record_tf=True):
        self.path = str(path)
        self.scene = scene
        self.wants_wrenches = record_wrenches
        self.record_tf = record_tf
        self.tf = None   # the TfTree, built in on_start when record_tf
        self.diagnostics_period = diagnostics_period
        self.namespace = namespace
        self.writer = McapSink(self.path, metadata=run_metadata(scene, settings, extra_metadata))
        self._next_diag = None
        self.count = 0
        self._channels = {}   # relative topic -> channel id (resolved and registered on first use)
        self._tf_layouts = {}

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
        """Record ``robot_description`` (and ``/tf_static``) at the start time."""
        t_ns = M.to_ns(sim.t)
        self.writer.add_topic(resolve('robot_description', self.namespace), M.TOPIC_TYPES['robot_description'],
                              qos='transient_local')
        self._write('robot_description', M.TOPIC_TYPES['robot_description'], M.string(sim.system.urdf()), t_ns)
        if self.record_tf:
            from ..tf import TfTree
            self.tf = TfTree(sim.system)
            self.write_tf_static(t_ns)
        self._next_diag = sim.t

    def write_tf_static(self, t_ns):
        """Record ``/tf_static`` (transient local) when the tree has fixed joints."""
        msg = self.tf.static_message(t_ns)
        if msg['transforms']:
            self.writer.add_topic('/tf_static', M.TOPIC_TYPES['/tf_static'], qos='transient_local')
            self._write('/tf_static', M.TOPIC_TYPES['/tf_static'], msg, t_ns)

    def on_command(self, t, port, values):
        """Record a command as it was applied (Float64MultiArray for effort/voltage ports)."""
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
        t_ns = M.to_ns(t)
        for topic, type_name, data in output_records(t_ns, out, self.wants_wrenches, self.tf,
                                                     tf_layouts=self._tf_layouts):
            self._write_data(topic, type_name, data, t_ns)
        self._write_data('/clock', M.TOPIC_TYPES['/clock'], cdr.clock_bytes(*divmod(t_ns, 1_000_000_000)), t_ns)
        if self._next_diag is not None and t >= self._next_diag - 1e-9:
            self._write('diagnostics', M.TOPIC_TYPES['diagnostics'],
                        M.diagnostic_array(t_ns, 'robodyn_ros: simulation', level, message,
                                             sim.diagnostics_values()), t_ns)
            self._next_diag += self.diagnostics_period

    def close(self):
        """Finish the file (summary, footer); idempotent."""
        self.writer.close()
