"""The run's markers: what a 3D view draws beside the robot, built from a period's outputs.

One topic, ``markers`` (visualization_msgs/MarkerArray), recorded and published like the other
outputs (its CDR from :class:`Markers`, the recorder's encoder, so the recording, the ROS topic and
the live viewers get the same bytes). Each message replaces the previous one: its first marker is
a ``DELETEALL``, then what the period's outputs hold. Now:

* namespace ``contact_points``: the points touching the ground (a ``SPHERE_LIST``);
* namespace ``contact_forces``: one ``ARROW`` per touching point, from the point along the ground's
  force on it, :data:`ARROW_AT_WEIGHT` m long for a force equal to the robot's weight;
* namespace ``imu/<name>`` per IMU: its link's axes, three ``ARROW`` s (ids 0, 1, 2: x red, y green,
  z blue) :data:`AXIS_LENGTH` m long from the link's origin;
* namespace ``ft/<name>`` per force-torque sensor: from its frame's origin, id 0 an ``ARROW`` along the
  force it reads, id 1 along the moment, at the contact arrows' scale (the moment's ``ARROW_AT_WEIGHT``
  m at the robot's weight times 1 m).

All in the world frame (the ground's, the tree's root frame: the frame of the IMUs' orientation),
stamped with simulation time. A system that draws nothing (no ground, no sensors) has no ``markers``
topic: its recordings keep their bytes; so does a system without sensors (the sensors' markers come
after the contact's).

Adding a kind: give :class:`MarkerInputs` its field, fill it in :meth:`MarkerInputs.of_outputs` (and
:meth:`MarkerInputs.of_state` for the block path), and append its markers in :meth:`Markers._items`
and their coordinates in :meth:`Markers._values`; the layout cache and the encoding take any list.
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
#: metres of each axis of an IMU's triad
AXIS_LENGTH = 0.1
# visualization_msgs/Marker types and actions
ARROW, SPHERE_LIST = 0, 7
ADD, DELETEALL = 0, 3
POINT_COLOR = (1.0, 0.55, 0.0, 1.0)   # orange
FORCE_COLOR = (0.85, 0.1, 0.1, 1.0)   # red
AXIS_COLORS = ((1.0, 0.0, 0.0, 1.0), (0.0, 0.8, 0.0, 1.0), (0.0, 0.2, 1.0, 1.0))   # x red, y green, z blue
FT_FORCE_COLOR = (0.95, 0.75, 0.0, 1.0)   # amber
FT_TORQUE_COLOR = (0.6, 0.2, 0.85, 1.0)   # violet


@dataclass
class MarkerInputs:
    """What one period's markers are drawn from. contact_points: (n, 6) ``[x; F]`` of the points
    touching the ground (world frame; m, N), or None; imu_poses: (ni, 12) ``[p; R]`` of each IMU's link
    (origin, m; rotation row major, the link's axes as columns; world frame); ft_wrenches: (nf, 9)
    ``[p; f; n]`` of each force-torque sensor (its frame's origin, its reading in world axes; m, N, N·m);
    both None without sensors (``SystemOutputs``' fields of the same names)."""

    contact_points: np.ndarray | None = None
    imu_poses: np.ndarray | None = None
    ft_wrenches: np.ndarray | None = None

    @classmethod
    def of_outputs(cls, out) -> 'MarkerInputs':
        """From a period's SystemOutputs."""
        return cls(contact_points=getattr(out, 'contact_points', None), imu_poses=getattr(out, 'imu_poses', None),
                   ft_wrenches=getattr(out, 'ft_wrenches', None))

    @classmethod
    def of_state(cls, system, y) -> 'MarkerInputs':
        """From the system's state y (the block path builds no outputs per period; a system with sensors gives
        their frames and readings with the block, ``PeriodBlock.control``)."""
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
    """The markers of one run: its frame and scale, its sensors, and a layout per shape (number of
    touching points).

    frame: the world frame the contact outputs and the sensors' poses use; weight: the robot's weight (N)
    for the arrow scale (arrows :data:`ARROW_AT_WEIGHT` m long at it); sensors: the system's
    :class:`robodyn_ros.systems.sensors.SensorSet`, or None.
    """

    def __init__(self, frame: str, weight: float, sensors=None):
        self.frame = frame
        self.scale = ARROW_AT_WEIGHT / weight if weight > 0 else 1e-3   # m of arrow per N (per N·m)
        self.size = POINT_SIZE * ARROW_AT_WEIGHT
        self.imu = [s.topic for s in sensors.imu] if sensors is not None else []
        self.ft = [s.topic for s in sensors.ft] if sensors is not None else []
        self._layouts = {}

    @classmethod
    def of(cls, system) -> 'Markers | None':
        """The markers of ``system``'s runs, or None when it draws none (no ground contact, no sensors)."""
        contact = getattr(system, 'contact', None)
        if contact is None or not hasattr(system, 'contact_points'):
            contact = None
        sensors = getattr(system, 'sensors', None)
        if contact is None and sensors is None:
            return None
        model = system.model
        frame = contact.frame if contact is not None else model.root
        return cls(frame, model.total_mass() * float(np.linalg.norm(model.gravity)), sensors)

    def _items(self, n: int) -> list:
        """The markers of a period with n touching points (see :func:`marker_array_bytes`); their
        points' coordinates are :meth:`_values`."""
        items = [('', 0, ARROW, DELETEALL, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0), 0)]
        d = self.size
        arrow = (0.25 * d, 0.5 * d, 0.75 * d)   # shaft diameter, head diameter, head length (m)
        if n:
            items.append(('contact_points', 0, SPHERE_LIST, ADD, (d, d, d), POINT_COLOR, n))
            items += [('contact_forces', i, ARROW, ADD, arrow, FORCE_COLOR, 2) for i in range(n)]
        for ns in self.imu:
            items += [(ns, a, ARROW, ADD, arrow, AXIS_COLORS[a], 2) for a in range(3)]
        for ns in self.ft:
            items += [(ns, 0, ARROW, ADD, arrow, FT_FORCE_COLOR, 2), (ns, 1, ARROW, ADD, arrow, FT_TORQUE_COLOR, 2)]
        return items

    def _values(self, P):
        """The coordinates of :meth:`_items`' contact markers, as rows ``[x, x, x + s F]`` (n, 9) of the
        touching points: the sphere list's point, each arrow's tail and tip (:meth:`_order` puts them in
        order); P (..., n, 6) gives (..., n, 9)."""
        x = P[..., 0:3]
        return np.concatenate((x, x, x + self.scale * P[..., 3:6]), axis=-1)

    def _sensor_values(self, m: MarkerInputs) -> np.ndarray:
        """The coordinates of :meth:`_items`' sensor markers, in their order: per IMU three arrows
        ``[p, p + L R e_a]`` (a = x, y, z), per force-torque sensor ``[p, p + s f]`` and ``[p, p + s n]``."""
        ni, nf = len(self.imu), len(self.ft)
        if not ni and not nf:
            return np.empty(0)
        if m.imu_poses is None or m.ft_wrenches is None or len(m.imu_poses) != ni or len(m.ft_wrenches) != nf:
            raise ValueError(f'markers: {ni} IMU poses and {nf} force-torque wrenches expected (SystemOutputs.'
                             f'imu_poses, ft_wrenches), got {m.imu_poses!r} and {m.ft_wrenches!r}')
        p = m.imu_poses[:, None, 0:3]                                            # (ni, 1, 3)
        axes = m.imu_poses[:, 3:12].reshape(ni, 3, 3).transpose(0, 2, 1)          # (ni, a, 3): R's columns
        imu = np.concatenate((np.broadcast_to(p, (ni, 3, 3)), p + AXIS_LENGTH * axes), axis=2)   # (ni, 3, 6)
        o = m.ft_wrenches[:, 0:3]
        s = self.scale
        ft = np.concatenate((o, o + s * m.ft_wrenches[:, 3:6], o, o + s * m.ft_wrenches[:, 6:9]), axis=1)
        return np.concatenate((imu.ravel(), ft.ravel()))

    @staticmethod
    def _order(n: int) -> np.ndarray:
        """Where each of the (n, 9) values of :meth:`_values` (row-major) goes among the float slots of
        :meth:`_items`' contact markers (the n sphere points first, then tail and tip of each arrow)."""
        rows = np.arange(n)[:, None]
        sphere = 3 * rows + np.arange(3)                  # slots 0 .. 3n-1
        arrows = 3 * n + 6 * rows + np.arange(6)          # then 6 per arrow: tail, tip
        return np.concatenate((sphere, arrows), axis=1).ravel()

    def _layout(self, n: int) -> _Layout:
        """The layout of a period with n touching points (made once per n)."""
        layout = self._layouts.get(n)
        if layout is None:
            layout = self._layouts[n] = _Layout(self.frame, self._items(n))
            k = len(layout.float_at) - 9 * n      # the sensors' values follow the contact's, in slot order
            layout.float_at = layout.float_at[np.concatenate((self._order(n), 9 * n + np.arange(k)))]
        return layout

    def message(self, t_ns: int, m: MarkerInputs) -> bytes:
        """The MarkerArray CDR of one period at simulation time t_ns."""
        P = m.contact_points
        n = 0 if P is None else len(P)
        layout = self._layout(n)
        sec, nsec = divmod(int(t_ns), 1_000_000_000)
        values = self._sensor_values(m)
        if n:
            values = np.concatenate((self._values(P).ravel(), values))
        return layout.fill(sec, nsec, values)

    def state_messages(self, t_ns, points) -> list:
        """The MarkerArray CDR of many periods of the block path, the bytes :meth:`message` makes of each
        period's :meth:`MarkerInputs.of_state`, built per group of periods with the same number of touching
        points instead of period by period.

        t_ns: (m,) integer simulation times (ns); points: (m, nc, NP) every contact point's outputs at each
        period's end (``kernels.contact.contact_points``' columns: the touching ones are drawn, in point
        order). A run with sensors draws them from its outputs, which the block path does not make: ValueError,
        as :meth:`message` raises."""
        from ..kernels.contact import PACTIVE, PF, PX
        self._sensor_values(MarkerInputs())       # raises when there are sensors to draw
        t_ns = np.asarray(t_ns, dtype=np.int64)
        sec, nsec = np.divmod(t_ns, 1_000_000_000)
        on = points[:, :, PACTIVE] > 0.0           # (m, nc)
        counts = on.sum(axis=1)
        out = [b''] * len(t_ns)
        for n in np.unique(counts).tolist():
            idx = np.flatnonzero(counts == n)
            g = len(idx)
            layout = self._layout(n)
            buf = np.tile(np.frombuffer(layout.template, dtype=np.uint8), (g, 1))
            stamp = np.empty(g, dtype=[('sec', '<i4'), ('nsec', '<u4')])   # _STAMP's bytes
            stamp['sec'], stamp['nsec'] = sec[idx], nsec[idx]
            stamp = stamp.view(np.uint8).reshape(g, 8)
            for at in layout.stamp_at:
                buf[:, at:at + 8] = stamp
            if n:
                P = points[idx][on[idx]].reshape(g, n, points.shape[2])   # the touching rows, in point order
                values = self._values(np.concatenate((P[:, :, PX:PX + 3], P[:, :, PF:PF + 3]), axis=2))
                f = np.ascontiguousarray(buf[:, 4:4 + 8 * layout.n_f64]).view('<f8')
                f[:, layout.float_at] = values.reshape(g, 9 * n)
                buf[:, 4:4 + 8 * layout.n_f64] = f.view(np.uint8)
            for j, k in enumerate(idx.tolist()):
                out[k] = buf[j].tobytes()
        return out
