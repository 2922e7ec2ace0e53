"""Command topics <-> simulator input ports, shared by the node and the offline tools (no rclpy).

Each input port of a system has one command topic (``messages.PORT_TOPICS``) and one message
type; this module turns a received message (an rclpy message, a decoded dict, or an
mcap_ros2 object: anything with the fields as attributes or keys) into the port's value vector.
"""
from __future__ import annotations

from .. import messages as M
from ..simulation import CommandError

#: input port -> message type of its command topic (GUIDE §2)
PORT_TYPES = {port: M.TOPIC_TYPES[topic] for port, topic in M.PORT_TOPICS.items()}
#: frames a base wrench command may be expressed in ('' = base_link by convention)
BASE_WRENCH_FRAMES = ('', 'base_link')


def _field(msg, name):
    return msg[name] if isinstance(msg, dict) else getattr(msg, name)


def command_values(port: str, msg) -> list:
    """The value vector a command message carries for ``port``.

    port: 'effort', 'wheel_voltage', 'position' or 'velocity' (std_msgs/Float64MultiArray: ``data``
    after ``layout.data_offset``), 'base_wrench' (geometry_msgs/WrenchStamped in ``base_link``:
    ``[fx, fy, fz, tx, ty, tz]``) or 'trajectory' (trajectory_msgs/JointTrajectory: the message as a
    dict, :func:`trajectory_dict`, validated by the Simulator). Raises :class:`CommandError` for a port
    without a topic mapping or a wrench in another frame (this node does not transform frames).
    """
    if port == 'trajectory':
        return trajectory_dict(msg)
    if port == 'base_wrench':
        frame = _field(_field(msg, 'header'), 'frame_id')
        if frame not in BASE_WRENCH_FRAMES:
            raise CommandError(f'base_wrench: frame_id {frame!r} is not base_link; '
                               f'express the wrench in base_link (or leave frame_id empty)')
        w = _field(msg, 'wrench')
        f, tq = _field(w, 'force'), _field(w, 'torque')
        return [float(_field(v, a)) for v in (f, tq) for a in ('x', 'y', 'z')]
    if port in PORT_TYPES:
        offset = int(_field(_field(msg, 'layout'), 'data_offset'))
        return list(_field(msg, 'data'))[offset:]
    raise CommandError(f'input port {port!r} has no command topic; known: {sorted(PORT_TYPES)}')


def trajectory_dict(msg) -> dict:
    """A trajectory_msgs/JointTrajectory (rclpy message, decoded dict or mcap_ros2 object) as the message
    dict the recorder encodes (``messages.py``'s layout), its numbers as float arrays."""
    import numpy as np

    def stamp(x):
        return {'sec': int(_field(x, 'sec')), 'nanosec': int(_field(x, 'nanosec'))}
    header = _field(msg, 'header')
    points = []
    for p in _field(msg, 'points'):
        points.append({k: np.array(list(_field(p, k)), dtype=float)
                       for k in ('positions', 'velocities', 'accelerations', 'effort')})
        points[-1]['time_from_start'] = stamp(_field(p, 'time_from_start'))
    return {'header': {'stamp': stamp(_field(header, 'stamp')), 'frame_id': str(_field(header, 'frame_id'))},
            'joint_names': [str(n) for n in _field(msg, 'joint_names')], 'points': points}


def command_topics(system) -> dict:
    """``{port: (topic, type)}`` for every input port of ``system`` (relative topic names).

    Raises ValueError for a port this package has no topic for (a new system must add one to
    ``messages.PORT_TOPICS``).
    """
    out = {}
    for port in system.inputs:
        if port not in M.PORT_TOPICS:
            raise ValueError(f'input port {port!r} of {type(system).__name__} has no command topic; '
                             f'add it to robodyn_ros.messages.PORT_TOPICS')
        out[port] = (M.PORT_TOPICS[port], PORT_TYPES[port])
    return out
