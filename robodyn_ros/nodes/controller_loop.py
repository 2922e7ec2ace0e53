"""The rclpy loop of a controller node (``diver_controller``, ``pd_hold_controller``), written once.

A controller object answers each ``joint_states`` message with one ``effort_commands`` message
(``on_joint_states``), counts what it sent and says when it is ``done``; ``report()`` gives the
figures of its run. This loop declares the node's parameters (``scene``, ``max_periods``,
``timeout``, ``result`` and the controller's own), builds the controller from the scene, waits for
the sim node, answers until the controller is done, the sim node leaves or the timeout passes, and
prints one summary line (and writes the report as JSON to ``result`` when given).
"""
from __future__ import annotations

import json
import sys
import time


def run_controller(name: str, parameters: dict, make, args=None, before=None, describe=None) -> int:
    """Run controller node ``name``; returns the exit status (0 done, 1 timed out, 2 bad scene).

    parameters: name -> default of the node's parameters; make(scene, publish, max_periods): the
    controller; before(node, ctl) -> ready(): optional, creates subscriptions the controller needs
    before its first joint_states and returns a predicate that is true once their publishers are
    matched; describe(report) -> str: optional words appended to the summary's state clause.
    """
    import rclpy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    from ..scene import SceneError, load_scene

    rclpy.init(args=args)
    node = rclpy.create_node(name)
    p = {k: node.declare_parameter(k, d).value for k, d in parameters.items()}
    pub = node.create_publisher(Float64MultiArray, 'effort_commands', 10)
    try:
        ctl = make(load_scene(p['scene']), lambda u: pub.publish(Float64MultiArray(data=u)), p['max_periods'])
    except (SceneError, ValueError) as e:
        print(f'{name}: {e}', file=sys.stderr)
        node.destroy_node()
        rclpy.try_shutdown()
        return 2
    ready = before(node, ctl) if before is not None else (lambda: True)
    end = time.monotonic() + float(p['timeout'])
    sim_left = False
    try:
        while time.monotonic() < end and not (ready() and pub.get_subscription_count()):   # the sim is there
            rclpy.spin_once(node, timeout_sec=0.05)
        node.create_subscription(JointState, 'joint_states', ctl.on_joint_states, 10)
        while not ctl.done and time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.05)
            if pub.get_subscription_count() == 0:        # the sim has gone (its run ended, or it shut down)
                sim_left = ctl.done = True
    except KeyboardInterrupt:
        pass
    r = {**ctl.report(), 'sim_left': sim_left}
    print(f'{name}: {r["sent"]} commands; last state t={(r["last_ns"] or 0) * 1e-9:.3f} s'
          + (describe(r) if describe is not None else '')
          + ('' if r['done'] else ' (timed out)') + (' (the sim node left)' if sim_left else ''), flush=True)
    if p['result']:
        with open(p['result'], 'w') as f:
            json.dump(r, f)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0 if r['done'] else 1
