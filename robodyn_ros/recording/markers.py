"""The run's markers: what a 3D view draws beside the robot, built from a period's outputs.

One topic, ``markers`` (visualization_msgs/MarkerArray), recorded and published like the other
outputs (its CDR from :class:`Markers`, the recorder's encoder, so the recording, the ROS topic and
the live viewers get the same bytes). Each message replaces the previous one: its first marker is
a ``DELETEALL``, then what the period's outputs hold. Now:

* namespace ``contact_points``: the points touching the ground (a ``SPHERE_LIST``);
* namespace ``contact_forces``: one ``ARROW`` per touching point, from the point along the ground's
  force on it, :data:`ARROW_AT_WEIGHT` m long for a force equal to the robot's weight.

All in the ground's (world) frame, stamped with simulation time. A system that draws nothing (no
ground) has no ``markers`` topic: its recordings keep their bytes.

Adding a kind (an IMU's axes, a force-torque sensor's wrench): give :class:`MarkerInputs` its field,
fill it in :meth:`MarkerInputs.of_outputs` (and :meth:`MarkerInputs.of_state` for the block path),
and append its markers in :meth:`Markers._items`; the layout cache and the encoding take any list.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

__all__ = ['Markers', 'MarkerInputs', 'TOPIC', 'TYPE', 'ARROW_AT_WEIGHT', 'marker_array_bytes']

TOPIC = 'markers'
TYPE = 'visualization_msgs/msg/MarkerArray'
#: metres of arrow for a force equal to the robot's weight (m g)
ARROW_AT_WEIGHT = 0.5
#: diameter (m) of a touching point's sphere, per metre of arrow at the robot's weight
POINT_SIZE = 0.04
# visualization_msgs/Marker types and actions
ARROW, SPHERE_LIST = 0, 7
ADD, DELETEALL = 0, 3
POINT_COLOR = (1.0, 0.55, 0.0, 1.0)   # orange
FORCE_COLOR = (0.85, 0.1, 0.1, 1.0)   # red


@dataclass
class MarkerInputs:
    """What one period's markers are drawn from. contact_points: (n, 6) ``[x; F]`` of the points
    touching the ground (world frame; m, N), or None."""

    contact_points: np.ndarray | None = None

    @classmethod
    def of_outputs(cls, out) -> 'MarkerInputs':
        """From a period's SystemOutputs."""
        return cls(contact_points=getattr(out, 'contact_points', None))

    @classmethod
    def of_state(cls, system, y) -> 'MarkerInputs':
        """From the system's state y (the block path builds no outputs per period)."""
        return cls(contact_points=system.contact_points(y))


class _Writer:
    """Canonical CDR (see :mod:`.cdr`) written field by field, noting where the numbers go."""

    def __init__(self):
        self.b = bytearray(b'\x00\x01\x00\x00')
        self.stamps = []    # offsets of (sec, nanosec) pairs
        self.floats = []    # offsets of float64 slots, in value order

    def align(self, n):
        pad = -(len(self.b) - 4) % n
        if pad:
            self.b += bytes(pad)

    def pack(self, fmt, size, *v):
        self.align(size)
        self.b += struct.pack('<' + fmt, *v)

    def string(self, s: str):
        data = s.encode('utf-8')
        self.pack('I', 4, len(data) + 1)
        self.b += data + b'\x00'

    def stamp(self):
        self.align(4)
        self.stamps.append(len(self.b))
        self.b += bytes(8)

    def slots(self, n: int):
        """n float64 values to be filled per message (8-aligned)."""
        self.align(8)
        at = len(self.b)
        self.floats.extend(range(at, at + 8 * n, 8))
        self.b += bytes(8 * n)

    def marker(self, frame, ns, mid, mtype, action, scale, color, n_points):
        self.stamp()                                  # header
        self.string(frame)
        self.string(ns)
        self.pack('iii', 4, mid, mtype, action)
        self.pack('7d', 8, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)   # pose: identity
        self.pack('3d', 8, *scale)
        self.pack('4f', 4, *color)
        self.pack('iI', 4, 0, 0)                      # lifetime: forever (until the next message)
        self.b += b'\x00'                             # frame_locked
        self.pack('I', 4, n_points)                   # points
        if n_points:
            self.slots(3 * n_points)
        self.pack('I', 4, 0)                          # colors
        self.string('')                               # texture_resource
        self.pack('iI', 4, 0, 0)                      # texture: header stamp, frame_id, format, data
        self.string('')
        self.string('')
        self.pack('I', 4, 0)
        self.pack('I', 4, 0)                          # uv_coordinates
        self.string('')                               # text
        self.string('')                               # mesh_resource
        self.string('')                               # mesh_file: filename, data
        self.pack('I', 4, 0)
        self.b += b'\x00'                             # mesh_use_embedded_materials


def marker_array_bytes(frame: str, items) -> tuple:
    """``(template bytes, stamp offsets, float offsets)`` of a MarkerArray of ``items``:
    ``[(ns, id, type, action, scale (3,), color (4,), number of points)]``; a message is the template
    with each stamp and the points' coordinates (in item order) written in."""
    w = _Writer()
    w.pack('I', 4, len(items))
    for ns, mid, mtype, action, scale, color, n in items:
        w.marker(frame, ns, mid, mtype, action, scale, color, n)
    return bytes(w.b), w.stamps, w.floats


class _Layout:
    """A MarkerArray of fixed shape: its template and where its numbers go."""

    def __init__(self, frame, items):
        tpl, stamps, floats = marker_array_bytes(frame, items)
        self.template = tpl
        self.stamp_at = stamps
        self.n_f64 = (len(tpl) - 4) // 8
        self.float_at = (np.array(floats, dtype=np.int64) - 4) // 8   # float64 index from byte 4

    def fill(self, sec: int, nsec: int, values) -> bytes:
        buf = bytearray(self.template)
        stamp = _STAMP.pack(sec, nsec)
        for at in self.stamp_at:
            buf[at:at + 8] = stamp
        if len(self.float_at):
            np.frombuffer(buf, dtype='<f8', count=self.n_f64, offset=4)[self.float_at] = values
        return bytes(buf)


_STAMP = struct.Struct('<iI')


class Markers:
    """The markers of one run: its frame and scale, and a layout per shape (number of touching points).

    frame: the world frame the contact outputs use; weight: the robot's weight (N) for the arrow
    scale (arrows :data:`ARROW_AT_WEIGHT` m long at it).
    """

    def __init__(self, frame: str, weight: float):
        self.frame = frame
        self.scale = ARROW_AT_WEIGHT / weight if weight > 0 else 1e-3   # m of arrow per N
        self.size = POINT_SIZE * ARROW_AT_WEIGHT
        self._layouts = {}

    @classmethod
    def of(cls, system) -> 'Markers | None':
        """The markers of ``system``'s runs, or None when it draws none (no ground contact)."""
        contact = getattr(system, 'contact', None)
        if contact is None or not hasattr(system, 'contact_points'):
            return None
        model = system.model
        return cls(contact.frame, model.total_mass() * float(np.linalg.norm(model.gravity)))

    def _items(self, n: int) -> list:
        """The markers of a period with n touching points (see :func:`marker_array_bytes`); their
        points' coordinates are :meth:`_values`."""
        items = [('', 0, ARROW, DELETEALL, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0), 0)]
        if n:
            d = self.size
            items.append(('contact_points', 0, SPHERE_LIST, ADD, (d, d, d), POINT_COLOR, n))
            items += [('contact_forces', i, ARROW, ADD, (0.25 * d, 0.5 * d, 0.75 * d), FORCE_COLOR, 2)
                      for i in range(n)]
        return items

    def _values(self, P):
        """The coordinates of :meth:`_items`' markers, as rows ``[x, x, x + s F]`` (n, 9) of the touching
        points: the sphere list's point, each arrow's tail and tip (:meth:`_order` puts them in order)."""
        x = P[:, 0:3]
        return np.concatenate((x, x, x + self.scale * P[:, 3:6]), axis=1)

    @staticmethod
    def _order(n: int) -> np.ndarray:
        """Where each of the (n, 9) values of :meth:`_values` (row-major) goes among the float slots of
        :meth:`_items`' markers (the n sphere points first, then tail and tip of each arrow)."""
        rows = np.arange(n)[:, None]
        sphere = 3 * rows + np.arange(3)                  # slots 0 .. 3n-1
        arrows = 3 * n + 6 * rows + np.arange(6)          # then 6 per arrow: tail, tip
        return np.concatenate((sphere, arrows), axis=1).ravel()

    def message(self, t_ns: int, m: MarkerInputs) -> bytes:
        """The MarkerArray CDR of one period at simulation time t_ns."""
        P = m.contact_points
        n = 0 if P is None else len(P)
        layout = self._layouts.get(n)
        if layout is None:
            layout = self._layouts[n] = _Layout(self.frame, self._items(n))
            layout.float_at = layout.float_at[self._order(n)] if n else layout.float_at
        sec, nsec = divmod(int(t_ns), 1_000_000_000)
        return layout.fill(sec, nsec, self._values(P).ravel() if n else ())
