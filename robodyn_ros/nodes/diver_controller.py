"""``diver_controller``: the diver's posture controller as a ROS 2 node, in its own process.

An example of a user controller against the ``sim`` node: subscribe to ``joint_states`` and
``odom``, compute the command from each new state, publish ``effort_commands``. The control law
is :class:`robodyn_ros.pfl.PFLController` (collocated partial feedback linearisation), built
from the scene's ``pfl`` command profile, so the node and ``robodyn run`` use one law with one
set of parameters (gains, target posture, schedule: in the scene file)::

    sim --ros-args -p scene:=diver_tuck -p mode:=lockstep -p record:=tuck.mcap &
    diver_controller --ros-args -p scene:=diver_tuck

Each state stamp is answered exactly once, when both its ``joint_states`` and its ``odom`` have
arrived (the lockstep sim re-sends the initial state to late subscribers: same stamp, ignored).
The node stops when the received state meets the scene's ``stop_when`` (the entry into the
water; the sim stops there too), when the sim node leaves (no subscriber on ``effort_commands``
any more), after ``max_periods`` commands, or after ``timeout`` wall seconds. Parameters: ``scene`` (name or path), ``max_periods`` (0 = no limit), ``timeout`` (s),
``result`` (optional JSON file: commands sent, last stamp, rotation count).
"""
from __future__ import annotations

import json
import sys
import time

import numpy as np


def _vec(v):
    return np.array([v.x, v.y, v.z])


def main(args=None) -> int:
    """Entry point of the ``diver_controller`` console script (exit 0 when the run ended normally)."""
    import rclpy
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    from ..pfl import controller_from_scene, state_from_outputs, stamp_seconds
    from ..scene import SceneError, load_scene

    rclpy.init(args=args)
    node = rclpy.create_node('diver_controller')
    p = {k: node.declare_parameter(k, d).value
         for k, d in (('scene', 'diver_tuck'), ('max_periods', 0), ('timeout', 300.0), ('result', ''))}
    try:
        scene = load_scene(p['scene'])
        ctl = controller_from_scene(scene)
    except (SceneError, ValueError) as e:
        print(f'diver_controller: {e}', file=sys.stderr)
        node.destroy_node()
        rclpy.try_shutdown()
        return 2
    system = scene.system
    pub = node.create_publisher(Float64MultiArray, 'effort_commands', 10)
    joints, odoms = {}, {}                 # stamp (ns) -> message, until answered
    st = {'sent': 0, 'answered': -1, 'done': False, 'last': None, 'turns': None, 'pitch': None, 'sim_left': False}

    def stamp(msg) -> int:
        return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec

    def step(t_ns):
        """Answer the state at t_ns once both of its messages are here."""
        if t_ns <= st['answered'] or t_ns not in joints or t_ns not in odoms or st['done']:
            return
        js, od = joints.pop(t_ns), odoms.pop(t_ns)
        for d in (joints, odoms):          # older unanswered stamps will never be answered
            for k in [k for k in d if k < t_ns]:
                del d[k]
        st['answered'] = st['last'] = t_ns
        pose, tw = od.pose.pose, od.twist.twist
        o = pose.orientation
        q, v = state_from_outputs(system, list(js.name), js.position, js.velocity,
                                  {'position': _vec(pose.position), 'orientation': np.array([o.x, o.y, o.z, o.w]),
                                   'linear': _vec(tw.linear), 'angular': _vec(tw.angular)})
        # odom's quaternion keeps the pitch modulo 2 pi: count the turns by continuity (report only)
        prev = st['pitch'] if st['pitch'] is not None else q[2]
        st['pitch'] = prev + (q[2] - prev + np.pi) % (2.0 * np.pi) - np.pi
        st['turns'] = float(st['pitch'] / (2.0 * np.pi))
        y = np.concatenate([q, v])
        if (scene.stop is not None and scene.stop(stamp_seconds(t_ns), y)) or \
                (p['max_periods'] and st['sent'] >= p['max_periods']):
            st['done'] = True              # the entry (or the limit): no more commands
            return
        pub.publish(Float64MultiArray(data=ctl.torques(stamp_seconds(t_ns), q, v).tolist()))
        st['sent'] += 1

    # odom first, joint_states once odom and the command topic are matched: a lockstep sim re-sends
    # its initial state (all topics) when a joint_states subscriber appears, and then both must arrive
    odom_sub = node.create_subscription(Odometry, 'odom', lambda m: (odoms.__setitem__(stamp(m), m),
                                                                     step(stamp(m))), 10)
    end = time.monotonic() + float(p['timeout'])
    try:
        while time.monotonic() < end and not (odom_sub.get_publisher_count() and pub.get_subscription_count()):
            rclpy.spin_once(node, timeout_sec=0.05)
        node.create_subscription(JointState, 'joint_states',
                                 lambda m: (joints.__setitem__(stamp(m), m), step(stamp(m))), 10)
        seen_sim = False
        while not st['done'] and time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.05)
            n = pub.get_subscription_count()
            seen_sim = seen_sim or n > 0
            if seen_sim and n == 0:        # the sim has gone (it stopped at the entry or was shut down)
                st['done'] = True
                st['sim_left'] = True
    except KeyboardInterrupt:
        pass
    print(f'diver_controller: {st["sent"]} commands; last state t={(st["last"] or 0) * 1e-9:.3f} s, '
          f'base pitch {st["turns"] if st["turns"] is not None else float("nan"):.4f} turns'
          + ('' if st['done'] else ' (timed out)') + (' (the sim node left)' if st['sim_left'] else ''), flush=True)
    if p['result']:
        with open(p['result'], 'w') as f:
            json.dump({'sent': st['sent'], 'last_ns': st['last'], 'turns': st['turns'], 'done': st['done'],
                       'sim_left': st['sim_left']}, f)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0 if st['done'] else 1


if __name__ == '__main__':
    sys.exit(main())
