"""ROS 2 messages as plain dicts (field layout of the .msg definitions), built from simulator output.

Part of the recording layer: the MCAP sink encodes these dicts to canonical CDR, and the node
fills rclpy messages from the same dicts (:func:`fill`), so the recorded bytes of a message
do not depend on which path produced it. No rclpy import here.
"""
from __future__ import annotations

import math

import numpy as np

# topic name -> message type of the interface contract (GUIDE §2); relative names
TOPIC_TYPES = {
    'joint_states': 'sensor_msgs/msg/JointState',
    'effort_commands': 'std_msgs/msg/Float64MultiArray',
    'wheel_voltage_commands': 'std_msgs/msg/Float64MultiArray',
    'base_wrench_command': 'geometry_msgs/msg/WrenchStamped',
    'odom': 'nav_msgs/msg/Odometry',
    'robot_description': 'std_msgs/msg/String',
    '/clock': 'rosgraph_msgs/msg/Clock',
    'diagnostics': 'diagnostic_msgs/msg/DiagnosticArray',
    '/tf': 'tf2_msgs/msg/TFMessage',         # see robodyn_ros.tf
    '/tf_static': 'tf2_msgs/msg/TFMessage',  # transient local, once at start
    'position_commands': 'std_msgs/msg/Float64MultiArray',
    'velocity_commands': 'std_msgs/msg/Float64MultiArray',
    'joint_trajectory': 'trajectory_msgs/msg/JointTrajectory',
    'command_joint_names': 'std_msgs/msg/String',   # transient local: the joints of each command topic
    'joint_trajectory_desired': 'sensor_msgs/msg/JointState',
    'joint_trajectory_error': 'sensor_msgs/msg/JointState',
}
WRENCH_TYPE = 'geometry_msgs/msg/WrenchStamped'
WRENCH_PREFIX = 'constraint_wrenches/'
#: the ground's wrench on a link (``SystemOutputs.contacts``): world axes, about the link's centre of pressure
CONTACT_PREFIX = 'contact_wrenches/'


def wrench_topic(name: str, prefix: str = WRENCH_PREFIX) -> str:
    """Topic ``constraint_wrenches/<name>`` of a joint or contact wrench (``contact_wrenches/<link>`` with
    ``prefix=CONTACT_PREFIX``); characters a ROS topic name cannot hold (URDF joint names such as
    ``wrist_3_link-tool0_fixed_joint``) become ``_``, and a token starting with a digit gets a leading ``_``."""
    import re
    token = re.sub(r'[^A-Za-z0-9_]', '_', name)
    return prefix + ('_' + token if token[:1].isdigit() else token)


def contact_topic(link: str) -> str:
    """Topic ``contact_wrenches/<link>`` of the ground's wrench on a link (:func:`wrench_topic`)."""
    return wrench_topic(link, CONTACT_PREFIX)

PORT_TOPICS = {'effort': 'effort_commands', 'wheel_voltage': 'wheel_voltage_commands',
               'base_wrench': 'base_wrench_command', 'position': 'position_commands',
               'velocity': 'velocity_commands', 'trajectory': 'joint_trajectory'}


def command_joint_names(system) -> str:
    """The ``command_joint_names`` text: one line ``<topic>: [j1, j2, ...]`` per command topic of a system's
    joint ports (effort, position, velocity; trajectory: the joints it may name), in each topic's order
    (YAML; what the node logs at start and latches)."""
    lines = []
    for port, spec in system.inputs.items():
        if port in ('effort', 'position', 'velocity', 'trajectory') and spec.labels:
            lines.append(f'{PORT_TOPICS[port]}: [{", ".join(spec.labels)}]')
    return '\n'.join(lines)


def stamp(t_ns: int) -> dict:
    """``builtin_interfaces/Time`` from integer nanoseconds of simulation time."""
    return {'sec': int(t_ns // 1_000_000_000), 'nanosec': int(t_ns % 1_000_000_000)}


def to_ns(t: float) -> int:
    """Simulation seconds to integer nanoseconds, rounded (1 ms steps stay exact)."""
    return int(round(t * 1e9))


def header(t_ns: int, frame_id: str = '') -> dict:
    """``std_msgs/Header``."""
    return {'stamp': stamp(t_ns), 'frame_id': frame_id}


def clock(t_ns: int) -> dict:
    """``rosgraph_msgs/Clock``."""
    return {'clock': stamp(t_ns)}


def joint_state(t_ns: int, names, position, velocity, effort) -> dict:
    """``sensor_msgs/JointState``; arrays as float64 numpy arrays."""
    return {'header': header(t_ns), 'name': list(names),
            'position': np.asarray(position, dtype=float), 'velocity': np.asarray(velocity, dtype=float),
            'effort': np.asarray(effort, dtype=float)}


def float64_array(values, label: str = '') -> dict:
    """``std_msgs/Float64MultiArray`` with one dimension labelled ``label``."""
    values = np.asarray(values, dtype=float)
    dim = [{'label': label, 'size': int(values.size), 'stride': int(values.size)}] if label else []
    return {'layout': {'dim': dim, 'data_offset': 0}, 'data': values}


def wrench_stamped(t_ns: int, frame_id: str, w) -> dict:
    """``geometry_msgs/WrenchStamped`` from a spatial force ``w = [torque; force]`` (6,)."""
    return {'header': header(t_ns, frame_id),
            'wrench': {'force': vec3(w[3:6]), 'torque': vec3(w[0:3])}}


def vec3(v) -> dict:
    """``geometry_msgs/Vector3`` (also Point)."""
    return {'x': float(v[0]), 'y': float(v[1]), 'z': float(v[2])}


def odometry(t_ns: int, odom: dict, frame='odom', child='base_link') -> dict:
    """``nav_msgs/Odometry``: pose in ``odom``, twist in ``base_link`` (REP 105)."""
    q = odom['orientation']
    return {'header': header(t_ns, frame), 'child_frame_id': child,
            'pose': {'pose': {'position': vec3(odom['position']),
                              'orientation': {'x': float(q[0]), 'y': float(q[1]), 'z': float(q[2]), 'w': float(q[3])}},
                     'covariance': np.zeros(36)},
            'twist': {'twist': {'linear': vec3(odom['linear']), 'angular': vec3(odom['angular'])},
                      'covariance': np.zeros(36)}}


def string(text: str) -> dict:
    """``std_msgs/String``."""
    return {'data': text}


def _fmt(v) -> str:
    t = type(v)
    if t is float:   # the common case first (the same strings as below)
        return repr(v) if math.isfinite(v) else str(v)
    if t is int:
        return str(v)
    if isinstance(v, (bool, np.bool_)):
        return 'true' if v else 'false'
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return repr(float(v)) if math.isfinite(v) else str(float(v))
    return str(v)


#: a diagnostics value as its string (public name of the formatting diagnostic_pairs uses)
format_value = _fmt


def diagnostic_pairs(values: dict) -> list:
    """``[(key, value string)]`` of a diagnostics status: booleans true/false, integers in
    decimal, floats as ``repr`` (shortest round-trip), the rest by ``str``."""
    return [(k, _fmt(v)) for k, v in values.items()]


def diagnostic_array(t_ns: int, name: str, level: int, message: str, values: dict, hardware_id='robodyn_ros') -> dict:
    """``diagnostic_msgs/DiagnosticArray`` with one status; level 0 OK, 1 WARN, 2 ERROR."""
    return {'header': header(t_ns), 'status': [{
        'level': bytes([level]), 'name': name, 'message': message, 'hardware_id': hardware_id,
        'values': [{'key': k, 'value': v} for k, v in diagnostic_pairs(values)]}]}


def output_messages(t_ns: int, out, wrenches: bool = True, tf=None):
    """The state messages of one publication: ``[(topic, type, dict), ...]`` (no /clock, diagnostics).

    out: :class:`robodyn_ros.systems.SystemOutputs`; wrenches: include constraint wrenches (the
    ground's ``contact_wrenches/<link>`` are always in, after them);
    tf: a :class:`robodyn_ros.tf.TfTree` to append ``/tf`` (last; left out when it has no
    transform), or None.
    """
    msgs = [('joint_states', TOPIC_TYPES['joint_states'],
             joint_state(t_ns, out.joint_names, out.position, out.velocity, out.effort))]
    if out.odom is not None:
        msgs.append(('odom', TOPIC_TYPES['odom'], odometry(t_ns, out.odom, child=out.odom_child)))
    if wrenches:
        for name, (frame, w) in out.wrenches.items():
            msgs.append((wrench_topic(name), WRENCH_TYPE, wrench_stamped(t_ns, frame, w)))
    for link, (frame, w) in out.contacts.items():
        msgs.append((contact_topic(link), WRENCH_TYPE, wrench_stamped(t_ns, frame, w)))
    msgs.extend(out.messages)
    if tf is not None:
        tf_msg = tf.message(t_ns, out)
        if tf_msg['transforms']:
            msgs.append(('/tf', TOPIC_TYPES['/tf'], tf_msg))
    return msgs


def fill(msg, data):
    """Copy a message dict into an rclpy message object (recursively) and return it.

    msg: an rclpy message instance; data: dict as built here. numpy arrays become lists.
    """
    for k, v in data.items():
        cur = getattr(msg, k)
        if isinstance(v, dict):
            fill(cur, v)
        elif isinstance(v, list) and v and isinstance(v[0], dict):
            elem_type = _list_elem_type(msg, k)
            setattr(msg, k, [fill(elem_type(), item) for item in v])
        elif isinstance(v, np.ndarray):
            setattr(msg, k, v.tolist() if not isinstance(cur, np.ndarray) else v)
        else:
            setattr(msg, k, v)
    return msg


def _list_elem_type(msg, field):
    """The rclpy class of the elements of a sequence-of-messages field."""
    import importlib
    slot_type = msg.get_fields_and_field_types()[field]  # e.g. 'sequence<diagnostic_msgs/DiagnosticStatus>'
    inner = slot_type.split('<', 1)[1].rstrip('>').split(',')[0]
    pkg, name = inner.split('/')
    return getattr(importlib.import_module(f'{pkg}.msg'), name)
