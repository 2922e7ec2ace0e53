"""An arm whose joints follow prescribed functions of time: the torques come from inverse dynamics.

Betancur's DH animation (seed 001, section 3.1) moves every joint of the 4-link arm along a given
function of t. Nothing is integrated: the motion is known, and what a user wants is the actuator
effort that makes the arm follow it, ``tau(t) = RNEA(q(t), q̇(t), q̈(t)) + D q̇(t)`` (inverse
dynamics of the prescribed q, q̇, q̈, plus what overcomes the joint damping D), and the joint
wrenches that come with it.

State. So that the :class:`~robodyn_ros.simulation.Simulator` steps, publishes and records this
system like any other, its state is its own clock: ``y = [s]`` with ``ds/dt = 1`` and ``s(t0) =
t0``; every fixed-step or adaptive integrator reproduces s = t to rounding. The joint motion is
then a function of the state, ``q = q(s)``, so energies, outputs and the work quadrature
``dW/dt = q̇ · RNEA`` (power put into the arm by the actuators, net of damping) need no
special case, and the Simulator's energy check ``E − E0 − W`` becomes a check of the torques:
the work they do must equal the change of the arm's mechanical energy.

The motion: one :class:`~robodyn_ros.expressions.TimeFunction` per 1-DOF joint (exact q̇, q̈ by
forward-mode jets). RNEA and the joint wrenches are the existing ones (the compiled
:mod:`robodyn_ros.kernels` on a compiled backend, :mod:`robodyn_ros.dynamics` on ``numpy``):
no new dynamics here.
"""
from __future__ import annotations

import numpy as np

from .. import dynamics as dyn
from .. import kernels
from ..model import FIXED, PRISMATIC, REVOLUTE, Model
from .base import LazyValues, System, SystemOutputs, resolve_backend


class KinematicArmSystem(System):
    """A fixed-base arm driven along prescribed joint motions; outputs the efforts needed.

    model: the kinematic tree (1-DOF and fixed joints only); motion: joint name -> TimeFunction
    (``jet(t) -> (q, q̇, q̈)``), one for every 1-DOF joint; backend: 'numpy' | 'numba' |
    'generated' (the last two use the compiled RNEA). State ``y = [s]`` (s = simulation time);
    no input ports. Outputs: joint_states with effort = the inverse-dynamics actuator effort,
    joint wrenches (parent on child, child frame), energies.
    """

    inputs: dict = {}

    def __init__(self, model: Model, motion: dict, backend=None):
        self.backend = resolve_backend(backend)
        if any(int(j) not in (REVOLUTE, PRISMATIC, FIXED) for j in model.jtype):
            raise ValueError(f'{model.name}: a prescribed-motion arm takes revolute, prismatic and fixed joints only')
        self.model = model
        self.joint_names = list(model.dof_joint_names)
        missing = [j for j in self.joint_names if j not in motion]
        extra = [j for j in motion if j not in self.joint_names]
        if missing or extra:
            raise ValueError(f'{model.name}: the motion must give every 1-DOF joint exactly once; '
                             f'missing {missing}, unknown {extra}; joints are {self.joint_names}')
        self.motion = {j: motion[j] for j in self.joint_names}
        # one function per v index: with 1-DOF and fixed joints only, v is in joint_names order
        self._fns = [self.motion[j] for j in self.joint_names]
        self._km = kernels.CompiledModel(model) if self.backend != 'numpy' else None
        self.nq, self.nv, self.ny = 1, 0, 1
        self.initial_state_sizes = (model.nv, model.nv)

    # -- the prescribed motion -------------------------------------------------------------
    def joint_motion(self, s: float):
        """``(q, q̇, q̈)`` (nv,) each at time s; FloatingPointError naming the joint if non-finite."""
        n = self.model.nv
        q, qd, qdd = np.empty(n), np.empty(n), np.empty(n)
        with np.errstate(all='ignore'):
            for k, f in enumerate(self._fns):
                q[k], qd[k], qdd[k] = f.jet(s)
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd)) and np.all(np.isfinite(qdd))):
            bad = [j for k, j in enumerate(self.joint_names)
                   if not np.isfinite([q[k], qd[k], qdd[k]]).all()]
            raise FloatingPointError(f'the prescribed motion of {bad} is not finite at t={s!r} s '
                                     f'({", ".join(self.motion[j].text for j in bad)})')
        return q, qd, qdd

    def inverse_dynamics(self, q, v, a):
        """``(tau (nv,), f (nb, 6))``: RNEA of (q, v, a) and the joint wrenches (parent on child)."""
        if self._km is not None:
            return self._km.rnea_wrenches(q, v, a)
        return dyn.rnea_wrenches(self.model, q, v, a)

    def efforts(self, s: float):
        """``(q, q̇, q̈, tau, f)``: the motion at s, the actuator efforts ``RNEA + D q̇`` and the wrenches."""
        q, qd, qdd = self.joint_motion(s)
        tau, f = self.inverse_dynamics(q, qd, qdd)
        return q, qd, qdd, tau - dyn.passive_forces(self.model, qd), f

    # -- System interface ------------------------------------------------------------------
    def initial_state(self, q0=None, v0=None):
        """``[0.0]`` (the clock); q0/v0 are refused: the motion expressions fix the state."""
        if q0 is not None or v0 is not None:
            raise ValueError('the joints follow the prescribed motion, which fixes q and v at every t; '
                             'remove initial_state (or shift the expressions in t)')
        return np.zeros(1)

    def rhs(self, t, y, u):
        """``[1]``: the clock. (The work quadrature's :meth:`input_power`, evaluated with it at
        every stage, raises FloatingPointError where the motion is not finite.)"""
        return np.ones(1)

    def config_rate(self, q, w):
        return np.ones(1)

    def outputs(self, t, y, u, wrenches=True):
        """Joint states (effort = inverse-dynamics actuator effort), joint wrenches, energies."""
        q, qd, _, tau, f = self.efforts(float(y[0]))
        w = {}
        if wrenches:
            for i in range(self.model.nb):
                w[self.model.joint_names[i]] = (self.model.link_names[i], f[i].copy())

        def energy():
            kin, pot = self._energies(q, qd)
            return {'kinetic': kin, 'potential': pot}
        return SystemOutputs(joint_names=list(self.joint_names), position=q.copy(), velocity=qd.copy(),
                             effort=tau.copy(), wrenches=w, energy=LazyValues(energy))

    def _energies(self, q, v):
        if self._km is not None:
            return self._km.energies(q, v)
        return dyn.kinetic_energy(self.model, q, v), dyn.potential_energy(self.model, q)

    def total_energy(self, y):
        """Kinetic plus gravitational potential energy of the arm at time y[0] (J)."""
        q, qd, _ = self.joint_motion(float(y[0]))
        kin, pot = self._energies(q, qd)
        return kin + pot

    def input_power(self, t, y, u):
        """``q̇ · RNEA``: actuator power net of damping dissipation (W), = dE/dt of the motion."""
        q, qd, qdd = self.joint_motion(float(y[0]))
        return float(qd @ self.inverse_dynamics(q, qd, qdd)[0])
