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

import sys

import numpy as np

#: parameter -> default
PARAMETERS = {'scene': 'diver_tuck', 'max_periods': 0, 'timeout': 300.0, 'result': ''}


def stamp_ns(msg) -> int:
    """The message's header stamp in integer nanoseconds."""
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def odom_values(msg) -> dict:
    """A nav_msgs/Odometry as the dict :func:`robodyn_ros.pfl.state_from_outputs` takes."""
    p, o, tw = msg.pose.pose.position, msg.pose.pose.orientation, msg.twist.twist
    return {'position': np.array([p.x, p.y, p.z]), 'orientation': np.array([o.x, o.y, o.z, o.w]),
            'linear': np.array([tw.linear.x, tw.linear.y, tw.linear.z]),
            'angular': np.array([tw.angular.x, tw.angular.y, tw.angular.z])}


class DiverController:
    """The controller's state between messages: pairs joint_states and odom by stamp, answers
    each stamp once. scene: the loaded scene (its system, stop_when and pfl profile);
    publish(list of floats): sends one effort command; max_periods: 0 = no limit."""

    def __init__(self, scene, publish, max_periods=0):
        from ..pfl import controller_from_scene
        self.scene, self.system, self.publish = scene, scene.system, publish
        self.law = controller_from_scene(scene)          # ValueError if the scene has no pfl profile
        self.max_periods = int(max_periods)
        self.joints, self.odoms = {}, {}                 # stamp (ns) -> message, until answered
        self.sent, self.answered, self.done = 0, -1, False
        self.pitch = None                                # unwrapped base pitch (report only)

    def on_joint_states(self, msg):
        self.joints[stamp_ns(msg)] = msg
        self._answer(stamp_ns(msg))

    def on_odom(self, msg):
        self.odoms[stamp_ns(msg)] = msg
        self._answer(stamp_ns(msg))

    def _answer(self, t_ns):
        """Publish the torques for the state at t_ns once both of its messages are here."""
        from ..pfl import stamp_seconds, state_from_outputs
        if self.done or t_ns <= self.answered or t_ns not in self.joints or t_ns not in self.odoms:
            return
        js, od = self.joints.pop(t_ns), self.odoms.pop(t_ns)
        for d in (self.joints, self.odoms):              # older stamps will never be answered
            for k in [k for k in d if k < t_ns]:
                del d[k]
        self.answered = t_ns
        q, v = state_from_outputs(self.system, list(js.name), js.position, js.velocity, odom_values(od))
        # odom keeps the pitch modulo 2 pi: count the turns by continuity
        prev = q[2] if self.pitch is None else self.pitch
        self.pitch = prev + (q[2] - prev + np.pi) % (2.0 * np.pi) - np.pi
        t = stamp_seconds(t_ns)
        stop = self.scene.stop
        if (stop is not None and stop(t, np.concatenate([q, v]))) or \
                (self.max_periods and self.sent >= self.max_periods):
            self.done = True                             # the entry (or the limit): no more commands
            return
        self.publish(self.law.torques(t, q, v).tolist())
        self.sent += 1

    def report(self) -> dict:
        turns = None if self.pitch is None else float(self.pitch / (2.0 * np.pi))
        return {'sent': self.sent, 'last_ns': self.answered if self.answered >= 0 else None, 'turns': turns,
                'done': self.done}


def main(args=None) -> int:
    """Entry point of the ``diver_controller`` console script (exit 0 when the run ended normally)."""
    from nav_msgs.msg import Odometry

    from .controller_loop import run_controller

    def before(node, ctl):
        # odom first, joint_states once odom and the command topic are matched: a lockstep sim re-sends
        # its initial state (all topics) when a joint_states subscriber appears, and both must arrive
        odom_sub = node.create_subscription(Odometry, 'odom', ctl.on_odom, 10)
        return lambda: odom_sub.get_publisher_count() > 0

    def describe(r):
        return f', base pitch {r["turns"] if r["turns"] is not None else float("nan"):.4f} turns'
    return run_controller('diver_controller', PARAMETERS, DiverController, args, before, describe)


if __name__ == '__main__':
    sys.exit(main())
