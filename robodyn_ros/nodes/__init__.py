"""ROS 2 nodes: thin adapters between topics/parameters and the Simulator.

``sim`` (:mod:`robodyn_ros.nodes.sim`) imports rclpy; :mod:`robodyn_ros.nodes.ports` does not
(the offline tools share it), so importing this package needs no ROS installation.
"""
