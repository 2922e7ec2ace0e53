"""One built part of a scene (what every part kind's builder returns).
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass
class Part:
    """One built part of a scene.

    name: part name; kind: its PART_KINDS key; mount: 'world' or the part it sits on;
    system: the part's :class:`robodyn_ros.systems.System` (None for a part that is not one, the
    ground); path: its key path in the file; data: what such a part parsed (the ground's law and points);
    control: its ``command_interfaces`` and ``servo`` keys as :func:`robodyn_ros.scene.control.part_control`
    read them (None: effort, as without the keys).
    """

    name: str
    kind: str
    mount: str
    system: object
    path: str
    data: object = None
    control: object = None
