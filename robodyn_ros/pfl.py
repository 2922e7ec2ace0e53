"""Collocated partial feedback linearisation (PFL) of a tree in free flight: the diver's controller.

A planar-base system (:mod:`robodyn_ros.systems.planar`) has ``n = 3 + m`` coordinates: the base
``b = [x, z, pitch]`` (unactuated) and ``m`` inner joints ``a`` (all actuated). Its dynamics
(M and h = C v + g + D v from the compiled CRBA and RNEA, :mod:`robodyn_ros.kernels`)::

    M_bb q̈_b + M_ba q̈_a + h_b = 0                    (3 unactuated rows)
    M_ab q̈_b + M_aa q̈_a + h_a = τ                    (m actuated rows)

Choosing the inner accelerations ``q̈_a = α = q̈_d + K_d (q̇_d − q̇_a) + K_p (q_d − q_a)`` and
eliminating the base accelerations with the first rows (``q̈_b = −M_bb⁻¹ (M_ba α + h_b)``) gives::

    τ = M_ab q̈_b + M_aa α + h_a

so every inner error ``e = q_d − q_a`` obeys ``ë + K_d ė + K_p e = 0`` exactly (between
controller updates), while the base moves as the momentum allows: the torques are internal, so
the centre of mass stays on its parabola and the angular momentum about it stays constant.
Uniform gravity is the generalised force ``−M g_b`` of a rigid translation, so it cancels: τ
is the same for g = 9.81 and g = 0.

Desired paths (:class:`PosturePath`): from the initial posture to a target posture along a
quintic (zero velocity and acceleration at both ends) between ``schedule[0]`` and
``schedule[1]``, held, and back to the initial posture between ``schedule[2]`` and
``schedule[3]`` (before the entry into the water).

The same :class:`PFLController` runs in the ``pfl`` command profile of a scene
(:mod:`robodyn_ros.profiles`; headless ``robodyn run``, scripted commands of the sim node) and
in the ``diver_controller`` node, and
both compute it from the same published values (``joint_states`` + ``odom``: the node through
:func:`state_from_outputs`, the profile through ``PlanarBaseSystem.published_state``, the same
numbers without building the outputs; time from the integer stamp), so a lockstep node run equals
the headless run byte for byte. The law itself is one call per update into
:mod:`robodyn_ros.kernels.pfl`, its one implementation (compiled; plain Python without numba).
Scene keys (``commands: {effort: {profile: pfl, ...}}``)::

    kp: 100.0            # 1/s², scalar or one per inner joint
    kd: 20.0             # 1/s, scalar or one per inner joint
    target: {hip: 2.3, knee: 2.3, ...}   # posture (rad) by inner joint name; others keep the initial angle
    schedule: [t0, t1, t2, t3]           # s: go t0 -> t1, hold, return t2 -> t3 (increasing)
"""
from __future__ import annotations

import numpy as np

__all__ = ['quintic', 'PosturePath', 'PFLController', 'state_from_outputs', 'controller_from_scene',
           'stamp_seconds']


def quintic(t, t0, t1):
    """``(s, ṡ, s̈)`` of the quintic 10τ³ − 15τ⁴ + 6τ⁵ from 0 at t0 to 1 at t1 (constant outside)."""
    if t <= t0:
        return 0.0, 0.0, 0.0
    if t >= t1:
        return 1.0, 0.0, 0.0
    T = t1 - t0
    r = (t - t0) / T
    return (r ** 3 * (10.0 - 15.0 * r + 6.0 * r * r), 30.0 * r * r * (1.0 - r) ** 2 / T,
            60.0 * r * (1.0 - r) * (1.0 - 2.0 * r) / (T * T))


class PosturePath:
    """Desired inner angles: ``start`` -> ``target`` (quintic, schedule[0..1]), hold, -> ``start``
    (quintic, schedule[2..3]). start, target: (m,) rad; schedule: 4 increasing times (s)."""

    def __init__(self, start, target, schedule):
        self.start = np.ascontiguousarray(start, dtype=float)
        self.delta = np.ascontiguousarray(np.asarray(target, dtype=float) - self.start)
        self.schedule = tuple(float(x) for x in schedule)

    def coefficients(self, t):
        """``(s, ṡ, s̈)`` at time t (s): the path is ``start + s δ`` (δ = target − start)."""
        t0, t1, t2, t3 = self.schedule
        s1, d1, a1 = quintic(t, t0, t1)
        s2, d2, a2 = quintic(t, t2, t3)
        return s1 - s2, d1 - d2, a1 - a2

    def __call__(self, t):
        """``(q_d, q̇_d, q̈_d)`` at time t (s)."""
        s, d, a = self.coefficients(t)
        return self.start + s * self.delta, d * self.delta, a * self.delta


class PFLController:
    """The control law above for a planar-base system, computed by :mod:`robodyn_ros.kernels.pfl`
    (one call per update; compiled, or plain Python on a machine without numba).

    system: a :class:`~robodyn_ros.systems.planar.PlanarBaseSystem` whose inner joints are all
    actuated; path: a :class:`PosturePath` over the inner joints; kp, kd: (m,) gains.
    :meth:`torques` returns the ``effort`` command (actuated-joint order).
    """

    def __init__(self, system, path: PosturePath, kp, kd):
        from .kernels import pack_model
        model = system.model
        self.model = model
        self.nv = model.nv
        m = self.nv - 3
        inner = list(system.inner_joint_names)
        if list(system.actuated) != inner:
            raise ValueError(f'PFL needs every inner joint actuated, in joint order {inner}; '
                             f'actuated are {list(system.actuated)}')
        self.kp = np.broadcast_to(np.asarray(kp, dtype=float), (m,)).copy()
        self.kd = np.broadcast_to(np.asarray(kd, dtype=float), (m,)).copy()
        self.path = path
        self.damping = np.ascontiguousarray(model.damping, dtype=float)
        # the tree packed with fixed bodies welded: the system's compiled model's when it has one
        km = getattr(system, '_km', None)
        self._mi, self._mf = (km.mi_r, km.mf_r) if km is not None else pack_model(model, merge=True)
        self._k = _kpfl()

    def mass_and_bias(self, q, v):
        """``(M (n, n), h (n,))`` with h = C v + g + D v (CRBA and RNEA)."""
        M, h = np.zeros((self.nv, self.nv)), np.empty(self.nv)
        self._k.mass_and_bias_into(self._mi, self._mf, self.damping, np.ascontiguousarray(q, dtype=float),
                                   np.ascontiguousarray(v, dtype=float), M, h)
        return M, h

    def desired_accelerations(self, t, q, v):
        """``α = q̈_d + K_d (q̇_d − q̇_a) + K_p (q_d − q_a)`` (m,) of the inner joints."""
        alpha = np.empty(self.nv - 3)
        self._k.accelerations_into(self.path.start, self.path.delta, *self.path.coefficients(t), self.kp, self.kd,
                                   np.ascontiguousarray(q, dtype=float), np.ascontiguousarray(v, dtype=float), alpha)
        return alpha

    def torques(self, t, q, v):
        """Inner joint torques (m,) at time t (s), coordinates q (n,), velocities v (n,)."""
        tau = np.empty(self.nv - 3)
        s, d, a = self.path.coefficients(t)
        self._k.torques_into(self._mi, self._mf, self.damping, self.path.start, self.path.delta, s, d, a,
                             self.kp, self.kd, np.ascontiguousarray(q, dtype=float),
                             np.ascontiguousarray(v, dtype=float), tau)
        return tau


def _kpfl():
    """:mod:`robodyn_ros.kernels.pfl`, the law's one implementation."""
    from .kernels import pfl
    return pfl


def state_from_outputs(system, names, position, velocity, odom):
    """``(q, v)`` of a planar-base system from published values.

    names, position, velocity: ``joint_states`` fields (any order, names of the inner joints);
    odom: dict with 'position', 'orientation' (x, y, z, w), 'linear', 'angular' (the
    ``nav_msgs/Odometry`` pose and twist, :func:`robodyn_ros.systems.planar.odom_of`).
    """
    from .systems.planar import base_state_from_odom
    index = {n: k for k, n in enumerate(names)}
    try:
        idx = [index[n] for n in system.inner_joint_names]
    except KeyError as e:
        raise ValueError(f'joint_states lacks joint {e.args[0]!r}; expected {system.inner_joint_names}') from None
    qb, vb = base_state_from_odom(odom['position'], odom['orientation'], odom['linear'], odom['angular'])
    position, velocity = np.asarray(position, dtype=float), np.asarray(velocity, dtype=float)
    return np.concatenate([qb, position[idx]]), np.concatenate([vb, velocity[idx]])


def stamp_seconds(t_ns: int) -> float:
    """Controller time (s) from a message stamp in integer nanoseconds (both paths use this)."""
    return t_ns * 1e-9


def controller_from_scene(scene) -> PFLController:
    """The :class:`PFLController` of a loaded scene's ``pfl`` effort profile (ValueError if none)."""
    if scene.script is None:
        raise ValueError(f'scene {scene.name!r} has no scripted commands (a pfl effort profile)')
    f = scene.script.profiles.get('effort') if hasattr(scene.script, 'profiles') else None
    ctl = getattr(f, 'controller', None)
    if ctl is None:
        raise ValueError(f"scene {scene.name!r}: its effort command is not a 'pfl' profile")
    return ctl
