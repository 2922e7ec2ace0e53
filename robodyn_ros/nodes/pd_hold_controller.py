"""``pd_hold_controller``: a joint-space PD about a posture as a ROS 2 node, in its own process.

The example of a user controller against the ``sim`` node for a robot on the ground: subscribe to
``joint_states``, answer each new state with ``effort_commands``. The law is the scene's ``pd_hold``
command profile (posture, kp, kd: :func:`robodyn_ros.profiles._pd_hold_profile`), evaluated by its one
implementation :func:`robodyn_ros.kernels.profiles.command_eval` on the actuated joints' positions and
velocities as ``joint_states`` carries them, so the node and ``robodyn run`` use one law with one set
of parameters (in the scene file)::

    sim --ros-args -p scene:=a1_stand -p mode:=lockstep -p scripted_commands:=false -p record:=a1.mcap &
    pd_hold_controller --ros-args -p scene:=a1_stand

In lockstep the recording equals the headless run's (test/test_node_pd_hold.py). Each state stamp is
answered once. A profile with ``gravity_compensation: true`` needs the whole state (the base pose of
a floating robot): refused here. The node stops after ``max_periods`` commands (0 = no limit), when
the sim node leaves (no subscriber on ``effort_commands``), or after ``timeout`` wall seconds.
Parameters: ``scene`` (name or path), ``max_periods``, ``timeout`` (s), ``result`` (optional JSON
file: commands sent, last stamp).
"""
from __future__ import annotations

import sys

import numpy as np

#: parameter -> default
PARAMETERS = {'scene': 'a1_stand', 'max_periods': 0, 'timeout': 300.0, 'result': ''}


class PdHoldController:
    """The law of a scene's pd_hold profile on joint_states messages.

    scene: the loaded scene (its ``commands.effort`` must be a pd_hold profile); publish(list of
    floats): sends one effort command; max_periods: 0 = no limit. Raises ValueError for a scene
    without a pd_hold profile or with gravity compensation.
    """

    def __init__(self, scene, publish, max_periods=0):
        from ..kernels import profiles as kp
        f = (getattr(scene.script, 'profiles', None) or {}).get('effort')
        spec = (scene.data.get('commands') or {}).get('effort') or {}
        if f is None or spec.get('profile') != 'pd_hold':
            raise ValueError(f'scene {scene.name!r} has no pd_hold profile on its effort port')
        kind, P, _, _, _, _ = f.program
        if P[3, 0] != 0.0:
            raise ValueError('pd_hold with gravity_compensation needs the whole state (the base pose): run it '
                             'headless (robodyn run), or leave the compensation out')
        self.names = list(scene.system.actuated)
        n = len(self.names)
        e2 = np.zeros((0, 0))
        self.program = (kind, P, np.zeros(0), e2, np.eye(n), np.eye(n))   # on the actuated joints' (q, v)
        self.eval, self.publish, self.max_periods = kp.command_eval, publish, int(max_periods)
        self.sent, self.answered, self.done = 0, -1, False
        self._index = None

    def on_joint_states(self, msg):
        """Answer the state of this message (once per stamp) with the law's efforts."""
        t_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if self.done or t_ns <= self.answered:
            return
        if self._index is None:
            names = list(msg.name)
            self._index = np.array([names.index(j) for j in self.names])
        self.answered = t_ns
        if self.max_periods and self.sent >= self.max_periods:
            self.done = True
            return
        q = np.ascontiguousarray(np.asarray(msg.position, dtype=float)[self._index])
        v = np.ascontiguousarray(np.asarray(msg.velocity, dtype=float)[self._index])
        u = np.empty(len(self.names))
        self.eval(*self.program, q, v, np.zeros(0), t_ns * 1e-9, u)
        self.publish(u.tolist())
        self.sent += 1

    def report(self) -> dict:
        return {'sent': self.sent, 'last_ns': self.answered if self.answered >= 0 else None, 'done': self.done}


def main(args=None) -> int:
    """Entry point of the ``pd_hold_controller`` console script (exit 0 when the run ended normally)."""
    from .controller_loop import run_controller
    return run_controller('pd_hold_controller', PARAMETERS, PdHoldController, args)


if __name__ == '__main__':
    sys.exit(main())
