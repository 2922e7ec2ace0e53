"""Simulated IMU and force-torque sensors of a tree: which links and joints, their noise, and their
messages (the readings are computed by :mod:`robodyn_ros.kernels.sensors`).

``imu/<name>`` (sensor_msgs/Imu, ``header.frame_id`` = the link; REP 145): orientation of the link
relative to the world (the tree's root frame: ``odom`` of a floating tree, the fixed base's root
otherwise), angular velocity in the link frame, linear acceleration = specific force ``a − g`` in the
link frame (+g upward at rest, 0 in free fall). ``ft/<name>`` (geometry_msgs/WrenchStamped,
``header.frame_id`` = the sensor frame): the wrench of ``constraint_wrenches/<joint>`` (the parent's on
the child through the joint, fixed joints included) about the frame's origin in its axes.

**Noise** (optional, per sensor): a constant bias and white Gaussian noise of a stated standard
deviation per sample, drawn per publication from a generator seeded with ``(seed, sensor, time in
ns)``, so the same run gives the same numbers whatever else is published, and a run is
byte-identical to its repeat. Units: ``orientation`` rad (a rotation vector), ``angular_velocity``
rad/s, ``linear_acceleration`` m/s², ``force`` N, ``torque`` N·m. Covariances (REP 145, row major,
in the message's frame) are the noise variances on the diagonal; a noiseless reading has zero
covariance, which the message defines as "unknown" but which here means exact.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import messages as M
from ..spatial import R_to_quat, quat_exp, quat_mul

IMU_TYPE = 'sensor_msgs/msg/Imu'
#: noise keys of each kind, with their units
NOISE_KEYS = {'imu': {'orientation': 'rad', 'angular_velocity': 'rad/s', 'linear_acceleration': 'm/s²'},
              'force_torque': {'force': 'N', 'torque': 'N·m'}}
#: bias keys (3-vectors) of each kind
BIAS_KEYS = {'imu': ('angular_velocity', 'linear_acceleration'), 'force_torque': ('force', 'torque')}


@dataclass
class Sensor:
    """One sensor: kind ('imu' | 'force_torque'), name (topic ``imu/<name>`` or ``ft/<name>``), frame (the
    link its readings are expressed in), body (the IMU's link, or the joint's child body, full tree),
    frame_body (the frame's body), joint (force-torque: the joint's name), noise (key -> σ), bias
    (key -> (3,)), seed."""

    kind: str
    name: str
    frame: str
    body: int
    frame_body: int
    joint: str = ''
    noise: dict = field(default_factory=dict)
    bias: dict = field(default_factory=dict)
    seed: int = 0

    @property
    def topic(self) -> str:
        return M.wrench_topic(self.name, 'imu/' if self.kind == 'imu' else 'ft/')


class SensorSet:
    """The sensors of one tree (a list of :class:`Sensor`)."""

    def __init__(self, sensors):
        self.sensors = list(sensors)
        self.imu = [s for s in self.sensors if s.kind == 'imu']
        self.ft = [s for s in self.sensors if s.kind == 'force_torque']
        self._imu_bodies = np.array([s.body for s in self.imu], dtype=np.int64)
        self._ft_bodies = np.array([[s.body, s.frame_body] for s in self.ft], dtype=np.int64).reshape(-1, 2)

    def topics(self) -> list:
        """``[(topic, type)]`` of every sensor, in publication order (IMUs, then force-torque sensors)."""
        return [(s.topic, IMU_TYPE) for s in self.imu] + [(s.topic, M.WRENCH_TYPE) for s in self.ft]

    def messages(self, km, t, q, v, qdd, fext=None) -> list:
        """``[(topic, type, message dict)]`` of every sensor at time t (s) and state (q, v) with the joint
        accelerations qdd of the dynamics (and the external body forces fext it applied)."""
        imu, ft = km.sensor_readings(q, v, qdd, self._imu_bodies, self._ft_bodies, fext)
        t_ns = M.to_ns(t)
        out = []
        for k, s in enumerate(self.imu):
            E0 = imu[k, 0:9].reshape(3, 3)
            quat = R_to_quat(E0.T)                       # the link's rotation relative to the world
            w = imu[k, 9:12].copy()
            f = imu[k, 12:15].copy()
            cov = {}
            if s.noise or s.bias:
                rng = np.random.default_rng([s.seed, k, t_ns])
                sig = {key: float(s.noise.get(key, 0.0)) for key in NOISE_KEYS['imu']}
                quat = quat_mul(quat, quat_exp(sig['orientation'] * rng.standard_normal(3)))
                w = w + s.bias.get('angular_velocity', 0.0) + sig['angular_velocity'] * rng.standard_normal(3)
                f = f + s.bias.get('linear_acceleration', 0.0) + sig['linear_acceleration'] * rng.standard_normal(3)
                cov = {key: np.diag(np.full(3, sig[key] ** 2)).reshape(9) for key in sig}
            z9 = np.zeros(9)
            out.append((s.topic, IMU_TYPE, {
                'header': M.header(t_ns, s.frame),
                'orientation': {'x': float(quat[0]), 'y': float(quat[1]), 'z': float(quat[2]), 'w': float(quat[3])},
                'orientation_covariance': cov.get('orientation', z9),
                'angular_velocity': M.vec3(w), 'angular_velocity_covariance': cov.get('angular_velocity', z9),
                'linear_acceleration': M.vec3(f),
                'linear_acceleration_covariance': cov.get('linear_acceleration', z9)}))
        for k, s in enumerate(self.ft):
            wr = ft[k].copy()                            # [torque; force]
            if s.noise or s.bias:
                rng = np.random.default_rng([s.seed, len(self.imu) + k, t_ns])
                wr[3:] += np.asarray(s.bias.get('force', 0.0)) + float(s.noise.get('force', 0.0)) * \
                    rng.standard_normal(3)
                wr[:3] += np.asarray(s.bias.get('torque', 0.0)) + float(s.noise.get('torque', 0.0)) * \
                    rng.standard_normal(3)
            out.append((s.topic, M.WRENCH_TYPE, M.wrench_stamped(t_ns, s.frame, wr)))
        return out

    def world_frames(self, km, q, msgs) -> tuple:
        """``(imu (ni, 12), ft (nf, 9))``: what the markers draw of the sensors at configuration q, in the
        world (the tree's root frame, the frame of the IMUs' orientation). Per IMU its link's pose
        ``[p; R]``: origin p (m) and the rotation R (row major; its columns are the link's axes in world
        coordinates). Per force-torque sensor its frame's origin p and the reading of ``msgs`` (this set's
        messages, :meth:`messages`' order: noise and bias included) turned into world axes ``[p; R f; R n]``
        (m, N, N·m). The poses are the kernels' (``CompiledModel.body_poses``)."""
        R, p = km.body_poses(q)
        ni = len(self.imu)
        imu = np.concatenate((p[self._imu_bodies], R[self._imu_bodies].reshape(-1, 9)), axis=1).reshape(ni, 12)
        ft = np.empty((len(self.ft), 9))
        for k, s in enumerate(self.ft):
            w = msgs[ni + k][2]['wrench']
            o = s.frame_body
            ft[k, 0:3] = p[o]
            ft[k, 3:6] = R[o] @ [w['force'][a] for a in 'xyz']
            ft[k, 6:9] = R[o] @ [w['torque'][a] for a in 'xyz']
        return imu, ft
