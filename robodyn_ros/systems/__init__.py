"""Systems the seeds describe, each with its state layout, inputs and outputs.

A system is the physics behind a scene: it owns a state vector ``y`` (flat float64), named
input ports (``effort``, ``wheel_voltage``, ``base_wrench``) and knows how to compute
``dy/dt``. It imports nothing from ROS.
"""
from .base import InputPort, System, SystemOutputs
from .arm import ArmSystem

__all__ = ['InputPort', 'System', 'SystemOutputs', 'ArmSystem']
