"""A tree on a planar root joint (free flight in the x–z plane), torque driven at its inner joints.

The model's first three bodies are the planar composite of :func:`robodyn_ros.model.planar_links`
(``J_x``, ``J_z`` prismatic, ``J_pitch`` revolute about y, attached to the root frame ``odom``),
so the dynamics is exactly :class:`~robodyn_ros.systems.arm.ArmSystem`'s (same kernels, fused and
generated paths); what differs is what it publishes, as for the other systems with a base
(GUIDE §2, REP 105):

- ``odom``: the pose of the base link ``L`` (the planar joint's child) in ``odom``:
  ``position = [x, 0, z]``, orientation the pitch about y, twist in ``L``'s axes
  (``linear = Rᵀ [ẋ, 0, ż]``, ``angular = [0, pitch rate, 0]``);
- ``joint_states``: the inner joints only (the three virtual joints are in ``odom``);
- ``robot_description``/TF: the tree rooted at ``base_link`` with ``L`` welded to it (joint
  ``J``, fixed, identity), so ``odom -> base_link`` is the odometry pose and the rest is the
  ordinary URDF.

The base joints are never actuated: the ``effort`` port drives inner joints (default all).
State ``y = [x, z, pitch, q_inner, ẋ, ż, pitch rate, v_inner]``; ``coordinate_names`` names them.
:meth:`initial_state` can place the centre of mass and set its velocity (``com``,
``com_velocity``, both ``[x, z]`` in odom), adjusting the base translation and its rate.
"""
from __future__ import annotations

import math

import numpy as np

from .. import dynamics as dyn
from ..model import LinkSpec, Model, build_model, planar_root
from .arm import ArmSystem
from .base import LazyWrenches

__all__ = ['PlanarBaseSystem', 'odom_of', 'base_state_from_odom']


def _odom_values(x, z, pitch, xd, zd, pitch_rate) -> tuple:
    """The 13 numbers of :func:`odom_of`: position (3), orientation (4), linear (3), angular (3).

    ``math.sin``/``math.cos`` (the C library's) take a tenth of ``np.sin``'s time on scalars; numpy
    may use its own SIMD code instead, so its bits are not the C library's on every machine.
    """
    c, s = math.cos(pitch), math.sin(pitch)
    return (x, 0.0, z, 0.0, math.sin(0.5 * pitch), 0.0, math.cos(0.5 * pitch),
            c * xd - s * zd, 0.0, s * xd + c * zd, 0.0, pitch_rate, 0.0)


def odom_of(x, z, pitch, xd, zd, pitch_rate) -> dict:
    """The ``odom`` output of a planar base at pose (x, z, pitch) with rates (ẋ, ż, pitch rate)
    (the four values are views of one (13,) array)."""
    a = np.array(_odom_values(x, z, pitch, xd, zd, pitch_rate))
    return {'position': a[0:3], 'orientation': a[3:7], 'linear': a[7:10], 'angular': a[10:13]}


def _base_from_odom(x, z, qy, qw, lx, lz, wy) -> tuple:
    """``((x, z, pitch), (ẋ, ż, pitch rate))`` from the odometry numbers :func:`base_state_from_odom` reads."""
    pitch = float(2.0 * np.arctan2(qy, qw))   # the one arctan2 of every path that rebuilds the pitch from odom
    c, s = math.cos(pitch), math.sin(pitch)
    return (x, z, pitch), (c * lx + s * lz, -s * lx + c * lz, wy)


def base_state_from_odom(position, orientation, linear, angular):
    """``(q_base [x, z, pitch], v_base [ẋ, ż, pitch rate])`` from odometry (inverse of :func:`odom_of`).

    position (3,), orientation quaternion (x, y, z, w), linear and angular twist (3,) in the base
    link's axes, as a ``nav_msgs/Odometry`` carries them. The pitch comes back through
    ``2 atan2(q_y, q_w)`` (equal to the simulated one to round-off, not bit for bit).
    """
    qb, vb = _base_from_odom(position[0], position[2], orientation[1], orientation[3], linear[0], linear[2],
                             angular[1])
    return np.array(qb), np.array(vb)


class PlanarBaseSystem(ArmSystem):
    """:class:`ArmSystem` on a model whose root joint is a planar composite; see the module docstring.

    model: the tree (bodies 0-2 the planar composite, everything else hanging from its child);
    actuated: driven inner joints (default all 1-DOF inner joints); backend: as ArmSystem.
    """

    def __init__(self, model: Model, actuated=None, backend=None):
        pr = planar_root(model)
        if pr is None:
            raise ValueError(f'{model.name}: the root joint is not a planar joint (bodies 0-2 must be its '
                             'x, z, pitch joints; see robodyn_ros.model.planar_links)')
        self.planar_joint, base_body = pr
        if any(model.parent[i] < 0 for i in range(1, model.nb)):
            raise ValueError(f'{model.name}: with a planar root every other link must hang from '
                             f'{model.link_names[2]!r} (one body in free flight)')
        inner = list(model.dof_joint_names[3:])
        if actuated is not None:
            bad = [j for j in actuated if j not in inner]
            if bad:
                raise ValueError(f'actuated joints {bad} are not inner joints of {model.name}; the planar root '
                                 f'joints are never actuated; inner joints are {inner}')
        super().__init__(model, actuated=inner if actuated is None else actuated, backend=backend)
        self.inner_joint_names = inner
        self.joint_names = list(inner)   # published in joint_states (the base is in odom)
        self.coordinate_names = ['x', 'z', 'pitch'] + inner
        base = model.link_names[base_body]
        root = 'base_link' if base != 'base_link' else 'base_footprint'
        specs = [LinkSpec(name=base, joint=self.planar_joint, parent=root, joint_type='fixed',
                          mass=model.specs[2].mass, com=model.specs[2].com, inertia=model.specs[2].inertia)]
        specs += list(model.specs[3:])
        self.urdf_model = build_model(specs, gravity=model.gravity, name=model.name, root=root)
        self.initial_state_keys = ('com', 'com_velocity')
        # outputs.wrenches: the planar root's (its pitch joint's row, at the base link) as the planar
        # joint's, then every inner joint's: rows 2.. of the tree's joint wrenches
        self._wrench_names = (self.planar_joint,) + tuple(model.joint_names[3:])
        self._wrench_frames = tuple(model.link_names[2:model.nb])
        self._wrench_index = {n: i for i, n in enumerate(self._wrench_names)}

    def rebuilt(self, backend):
        """The same system on another backend."""
        return PlanarBaseSystem(self.model, actuated=self.actuated, backend=backend)

    def urdf(self) -> str:
        """URDF of the tree rooted at base_link (the planar joint's child welded to it)."""
        from ..model import to_urdf
        return to_urdf(self.urdf_model)

    # -- centre of mass -------------------------------------------------------------------------
    def com(self, q, v):
        """``(c (3,), ċ (3,))``: centre of mass and its velocity in odom (m, m/s)."""
        if self._km is not None:
            p, _, c = self._km.momentum(q, v)
            return c, p / self.model.total_mass()
        h = dyn.spatial_momentum(self.model, q, v)
        c = dyn.center_of_mass(self.model, q)[0]
        return c, h[3:] / self.model.total_mass()

    def initial_state(self, q0=None, v0=None, com=None, com_velocity=None):
        """State from q0 (nq,), v0 (nv,) and optionally the CoM position/velocity ``[x, z]`` in odom.

        ``com`` shifts the base translation (x, z) so that the centre of mass is there;
        ``com_velocity`` sets the base translation rates so that it moves at that velocity (the
        other rates as given): the base x/z joints translate the whole body, so both are exact.
        """
        y = super().initial_state(q0, v0)
        q, v = y[:self.nq], y[self.nq:]
        for name, val in (('com', com), ('com_velocity', com_velocity)):
            if val is not None and np.shape(val) != (2,):
                raise ValueError(f'{name} must be [x, z] (2 values), got {val!r}')
        if com is None and com_velocity is None:
            return y
        c, cd = self.com(q, v)
        if com is not None:
            q[0] += com[0] - c[0]
            q[1] += com[1] - c[2]
        if com_velocity is not None:
            v[0] += com_velocity[0] - cd[0]
            v[1] += com_velocity[1] - cd[2]
        return y

    def run_report(self, y) -> str:
        """One summary line (``robodyn run``): base pitch in turns (the somersault count) and the CoM."""
        q, v = self.split(y)
        c, _ = self.com(q, v)
        return (f'rotation     base pitch {q[2]:.6f} rad = {q[2] / (2.0 * np.pi):.4f} turns; '
                f'CoM at x {c[0]:.4f} m, z {c[2]:.4f} m')

    # -- outputs -------------------------------------------------------------------------------
    def outputs(self, t, y, u, wrenches=True):
        """Inner joint states, odometry of the base link, joint wrenches (the planar root's as ``J``;
        computed when read, or per batch by a recorder, on the compiled backends)."""
        out = super().outputs(t, y, u, wrenches=wrenches)
        q, v = out.position, out.velocity   # copies of the state's
        out.odom = odom_of(*q[:3].tolist(), *v[:3].tolist())
        out.position, out.velocity, out.effort = q[3:], v[3:], out.effort[3:]
        if wrenches and not isinstance(out.wrenches, LazyWrenches):   # the numpy reference: every body's
            w = out.wrenches
            out.wrenches = {n: w[j] for n, j in zip(self._wrench_names, self.model.joint_names[2:])}
        return out

    def _wrenches_one(self, q, v, tau):
        return super()._wrenches_one(q, v, tau)[2:]

    def _wrenches_many(self, args):
        # ArmSystem's: per state through _wrenches_one (rows 2.. already), or one batch kernel call (every row)
        f = super()._wrenches_many(args)
        return f[:, 2:] if f.ndim == 3 and f.shape[1] != len(self._wrench_names) else f

    def published_state(self, y):
        """``(q (nq,), v (nv,))`` as a subscriber rebuilds them from this state's ``joint_states``
        and ``odom`` (:func:`robodyn_ros.pfl.state_from_outputs` of :meth:`outputs`, bit for bit):
        the base pose and rates go through :func:`odom_of` and :func:`base_state_from_odom`."""
        nq = self.nq
        o = _odom_values(*y[:3].tolist(), *y[nq:nq + 3].tolist())
        q, v = y[:nq].copy(), y[nq:nq + self.nv].copy()
        q[:3], v[:3] = _base_from_odom(o[0], o[2], o[4], o[6], o[7], o[9], o[11])
        return q, v
