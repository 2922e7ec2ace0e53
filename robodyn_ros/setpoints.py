"""Setpoints of position-commanded joints: held positions and trajectories as joint_trajectory_controller
takes them, as one piecewise-polynomial program per run (evaluated by :mod:`robodyn_ros.kernels.servo`).

**The program** (:class:`SetpointProgram`): segments k starting at ``T[k]`` (s, increasing); per segment
and joint the origin ``t₀`` and coefficients of ``q*(t) = Σᵢ cᵢ (t − t₀)ⁱ`` (i <= 5). A held position is
a constant; a trajectory adds one segment per pair of points. Only the segment in force at the current
time and those after it are kept.

**A position command** (``position_commands``, forward_command_controller's meaning) holds its values
from the time it is applied: the program from then on is that constant.

**A trajectory** (``joint_trajectory``, trajectory_msgs/JointTrajectory) follows
joint_trajectory_controller (ros2_controllers, ``joint_trajectory_controller/src/trajectory.cpp``
``Trajectory::sample`` and ``interpolate_between_points``; ``joint_trajectory_controller.cpp``
``validate_trajectory_msg`` and ``fill_partial_goal``; the replacement rule of ``doc/trajectory.rst``,
"Trajectory Replacement"):

* ``header.stamp`` 0 means now (the simulation time the message is applied at); otherwise it is the
  simulation time the trajectory starts at (``t_s``); point i is due at ``t_s + time_from_start_i``;
* it takes over at ``t_h = max(t_s, now)``: before that the current program runs on (a future start
  splices it there), from then on the new one (replacement from the new start);
* from ``t_h`` to the first point (if it is later) it interpolates from the desired state at ``t_h``
  (position, velocity, acceleration of the program it replaces: the controller's ``open_loop_control``
  point before the trajectory, so the desired motion has no jump) to the first point; between points
  i and i + 1 it interpolates from point i to point i + 1, in the polynomial of the controller:
  **linear** when either point carries positions only, **cubic** when both carry velocities,
  **quintic** when both carry velocities and accelerations (the controller's coefficients, in the
  time since point i);
* after the last point its position is held (velocity and acceleration 0; the controller repeats the
  last point, velocities included, which a servo would chase as a moving target);
* joints it does not name hold their desired position at ``t_h`` (``fill_partial_goal``: hold in place);
* a trajectory with no points holds every joint's desired position from ``t_h``
  (``set_hold_position``).

It is refused, with the reason, and the current program stays, for (:class:`TrajectoryError`): empty
or duplicate joint names, a joint that is not position-commanded, a point whose positions are not one
per joint or whose velocities, accelerations or efforts are neither empty nor one per joint,
accelerations without velocities (the controller would sample zeros), ``time_from_start`` negative or
not strictly increasing, a non-finite number anywhere, and a non-zero stamp whose last point is
already past (the controller's "ends in the past"). Efforts are accepted and not used (the
controller uses them only with an effort command interface).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ['SetpointProgram', 'Trajectory', 'TrajectoryError', 'parse_trajectory', 'segment_coefficients',
           'trajectory_message']

#: columns of a program row: the origin t0, then c0..c5 (kernels.servo.NC)
NC = 7


class TrajectoryError(ValueError):
    """A trajectory that is refused; the message says why."""


def _field(msg, name, default=None):
    if isinstance(msg, dict):
        return msg.get(name, default)
    return getattr(msg, name, default)


def _list(msg, name) -> list:
    """A sequence field as a list ([] when absent; numpy arrays, lists and rclpy arrays alike)."""
    v = _field(msg, name)
    return [] if v is None else list(v)


def _seconds(value, what: str) -> float:
    """Seconds of a builtin_interfaces Time/Duration (``{sec, nanosec}``) or of a number."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    sec, nsec = _field(value, 'sec'), _field(value, 'nanosec')
    if sec is None or nsec is None:
        raise TrajectoryError(f'{what} must be a time {{sec, nanosec}}, got {value!r}')
    return int(sec) + int(nsec) / 1e9   # (a correctly rounded quotient: 600000000 ns is the double 0.6)


@dataclass(frozen=True)
class Trajectory:
    """A validated trajectory: joint_names (n,) in the message's order, stamp (s; 0 = now), times (m,)
    its points' time_from_start (s), positions (m, n), velocities and accelerations (m, n) or None per
    point (what each point carries). The message itself is kept (``message``) for the recorder."""

    joint_names: tuple
    stamp: float
    times: np.ndarray
    positions: np.ndarray
    velocities: tuple
    accelerations: tuple
    message: object = None


def parse_trajectory(msg, joints) -> Trajectory:
    """Validate a trajectory_msgs/JointTrajectory (a dict, an rclpy message or a decoded record) against
    the position-commanded ``joints``; raises :class:`TrajectoryError` naming what is wrong (module
    docstring)."""
    names = [str(n) for n in _list(msg, 'joint_names')]
    if not names:
        raise TrajectoryError('empty joint_names')
    known = set(joints)
    for n in names:
        if n not in known:
            raise TrajectoryError(f'joint {n!r} is not position-commanded; the position-commanded joints are '
                                  f'{list(joints)}')
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise TrajectoryError(f'duplicate joint names {dup}')
    header = _field(msg, 'header')
    stamp = 0.0 if header is None else _seconds(_field(header, 'stamp', 0.0), 'header.stamp')
    if not math.isfinite(stamp) or stamp < 0.0:
        raise TrajectoryError(f'header.stamp must be a finite time >= 0, got {stamp!r}')
    n = len(names)
    pts = _list(msg, 'points')
    times, pos, vel, acc = [], [], [], []
    for i, p in enumerate(pts):
        t = _seconds(_field(p, 'time_from_start', 0.0), f'points[{i}].time_from_start')
        if not math.isfinite(t) or t < 0.0:
            raise TrajectoryError(f'points[{i}].time_from_start must be finite and >= 0, got {t!r}')
        if i and t <= times[-1]:
            raise TrajectoryError(f'time_from_start is not strictly increasing: points[{i - 1}] at {times[-1]:g} s, '
                                  f'points[{i}] at {t:g} s')
        row = {}
        for key, required in (('positions', True), ('velocities', False), ('accelerations', False),
                              ('effort', False)):
            vals = _list(p, key)
            if not vals and not required:
                row[key] = None
                continue
            if len(vals) != n:
                raise TrajectoryError(f'points[{i}].{key} has {len(vals)} values for {n} joint names'
                                      + ('' if required else ' (give none or one per joint)'))
            arr = np.array(vals, dtype=float)
            if not np.all(np.isfinite(arr)):
                raise TrajectoryError(f'points[{i}].{key} holds a non-finite value: {vals!r}')
            row[key] = arr
        if row['accelerations'] is not None and row['velocities'] is None:
            raise TrajectoryError(f'points[{i}] has accelerations but no velocities (a quintic segment needs both)')
        times.append(t)
        pos.append(row['positions'])
        vel.append(row['velocities'])
        acc.append(row['accelerations'])
    return Trajectory(joint_names=tuple(names), stamp=stamp, times=np.array(times, dtype=float),
                      positions=np.array(pos, dtype=float).reshape(len(pts), n), velocities=tuple(vel),
                      accelerations=tuple(acc), message=msg)


def segment_coefficients(T: float, pa, va, aa, pb, vb, ab) -> np.ndarray:
    """Coefficients ``c (n, 6)`` of the segment from state a to state b over T seconds, in the time since
    a, as joint_trajectory_controller's ``interpolate_between_points``: linear when va or vb is None,
    cubic when aa or ab is None, quintic otherwise (each of pa, pb (n,); va, vb, aa, ab (n,) or None)."""
    pa = np.asarray(pa, dtype=float)
    pb = np.asarray(pb, dtype=float)
    c = np.zeros((pa.shape[0], 6))
    c[:, 0] = pa
    if va is None or vb is None:                       # linear
        c[:, 1] = (pb - pa) / T
        return c
    c[:, 1] = va
    if aa is None or ab is None:                       # cubic
        c[:, 2] = (-3.0 * pa + 3.0 * pb - 2.0 * va * T - vb * T) / T ** 2
        c[:, 3] = (2.0 * pa - 2.0 * pb + va * T + vb * T) / T ** 3
        return c
    T2 = T * T                                         # quintic
    c[:, 2] = 0.5 * aa
    c[:, 3] = (-20.0 * pa + 20.0 * pb - 3.0 * aa * T2 + ab * T2 - 12.0 * va * T - 8.0 * vb * T) / (2.0 * T ** 3)
    c[:, 4] = (30.0 * pa - 30.0 * pb + 3.0 * aa * T2 - 2.0 * ab * T2 + 16.0 * va * T + 14.0 * vb * T) / (2.0 * T ** 4)
    c[:, 5] = (-12.0 * pa + 12.0 * pb - aa * T2 + ab * T2 - 6.0 * va * T - 6.0 * vb * T) / (2.0 * T ** 5)
    return c


class SetpointProgram:
    """The piecewise-polynomial setpoints of the position-commanded joints (module docstring).

    joints: their names, in the program's column order; T (K,) segment start times (s); C (K, n, 7)
    rows ``[t₀, c₀..c₅]``. Immutable: every command makes a new program.
    """

    __slots__ = ('joints', 'T', 'C')

    def __init__(self, joints, T, C):
        self.joints = tuple(joints)
        self.T = np.ascontiguousarray(T, dtype=float)
        self.C = np.ascontiguousarray(C, dtype=float)

    @classmethod
    def hold(cls, joints, positions, t: float) -> SetpointProgram:
        """Every joint held at positions (n,) from time t (s)."""
        C = np.zeros((1, len(joints), NC))
        C[0, :, 0] = t
        C[0, :, 1] = positions
        return cls(joints, [t], C)

    def sample(self, t: float) -> np.ndarray:
        """``(n, 3)``: q*, q̇*, q̈* of every joint at time t (``kernels.servo.setpoints_many``)."""
        return self.sample_many(np.array([float(t)]))[0]

    def sample_many(self, times) -> np.ndarray:
        """``(m, n, 3)``: q*, q̇*, q̈* of every joint at each of times (m,)."""
        from .kernels.servo import setpoints_many
        times = np.ascontiguousarray(times, dtype=float)
        out = np.empty((times.shape[0], len(self.joints), 3))
        setpoints_many(self.T, self.C, np.arange(len(self.joints), dtype=np.int64), times, out)
        return out

    def _spliced(self, now: float, t_h: float, T_new, C_new) -> SetpointProgram:
        """This program up to t_h (only its segments still in force at ``now`` or later), then the new
        segments (their start times T_new > every kept one)."""
        keep = [k for k in range(self.T.shape[0]) if self.T[k] < t_h and (k + 1 == self.T.shape[0] or
                                                                          self.T[k + 1] > now)]
        T = np.concatenate([self.T[keep], np.asarray(T_new, dtype=float)])
        C = np.concatenate([self.C[keep], np.asarray(C_new, dtype=float).reshape(-1, len(self.joints), NC)])
        return SetpointProgram(self.joints, T, C)

    def with_positions(self, positions, now: float) -> SetpointProgram:
        """A position command applied at now: every joint held at positions (n,) from now on."""
        return self._spliced(now, now, [now], SetpointProgram.hold(self.joints, positions, now).C)

    def with_trajectory(self, traj: Trajectory, now: float) -> SetpointProgram:
        """This program with ``traj`` taking over at ``max(stamp, now)`` (module docstring); raises
        :class:`TrajectoryError` when its last point is already past."""
        t_s = traj.stamp if traj.stamp != 0.0 else now
        t_h = max(t_s, now)
        n = len(self.joints)
        before = self.sample(t_h)                    # the desired state at the hand-over
        col = np.array([self.joints.index(j) for j in traj.joint_names], dtype=int)
        held = np.zeros((1, n, NC))                  # every joint held where it is at t_h
        held[0, :, 0] = t_h
        held[0, :, 1] = before[:, 0]
        m = traj.times.shape[0]
        if m == 0:
            return self._spliced(now, t_h, [t_h], held)
        due = t_s + traj.times
        if due[-1] < t_h:
            raise TrajectoryError(f'the trajectory ends in the past: its last point is due at {due[-1]:.9g} s, '
                                  f'before the hand-over at {t_h:.9g} s')
        T_new, C_new = [], []

        def segment(start, t0, T, c):
            row = held[0].copy()
            row[col, 0] = t0
            row[col, 1:] = c
            T_new.append(start)
            C_new.append(row)
        if t_h < due[0]:   # from the desired state at t_h to the first point
            b = before[col]
            segment(t_h, t_h, due[0] - t_h,
                    segment_coefficients(due[0] - t_h, b[:, 0], b[:, 1], b[:, 2], traj.positions[0],
                                         traj.velocities[0], traj.accelerations[0]))
        for i in range(m - 1):
            if due[i + 1] <= t_h:
                continue
            segment(max(due[i], t_h), due[i], due[i + 1] - due[i],
                    segment_coefficients(due[i + 1] - due[i], traj.positions[i], traj.velocities[i],
                                         traj.accelerations[i], traj.positions[i + 1], traj.velocities[i + 1],
                                         traj.accelerations[i + 1]))
        end = np.zeros((len(col), 6))
        end[:, 0] = traj.positions[-1]
        segment(max(due[-1], t_h), due[-1], 0.0, end)
        return self._spliced(now, t_h, T_new, np.array(C_new))


def trajectory_message(joint_names, points, stamp: float = 0.0) -> dict:
    """A trajectory_msgs/JointTrajectory as a message dict (messages.py's layout): points as mappings
    ``{time_from_start (s), positions, velocities?, accelerations?, effort?}``; stamp (s, 0 = now)."""
    def dur(s):
        sec = math.floor(s)
        nsec = int(round((s - sec) * 1e9))
        if nsec >= 1_000_000_000:
            sec, nsec = sec + 1, nsec - 1_000_000_000
        return {'sec': int(sec), 'nanosec': nsec}
    out = []
    for p in points:
        out.append({'positions': np.asarray(p.get('positions', []), dtype=float),
                    'velocities': np.asarray(p.get('velocities', []), dtype=float),
                    'accelerations': np.asarray(p.get('accelerations', []), dtype=float),
                    'effort': np.asarray(p.get('effort', []), dtype=float),
                    'time_from_start': dur(float(p['time_from_start']))})
    return {'header': {'stamp': dur(float(stamp)), 'frame_id': ''}, 'joint_names': list(joint_names), 'points': out}
