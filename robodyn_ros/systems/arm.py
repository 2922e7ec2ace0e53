"""A fixed-base articulated arm (any tree of revolute/prismatic/fixed joints), torque driven."""
from __future__ import annotations

import numpy as np

from .. import dynamics as dyn
from ..model import PRISMATIC, REVOLUTE, Model
from .base import InputPort, System, SystemOutputs


class ArmSystem(System):
    """Arm on a fixed base: state ``y = [q (nq), v (nv)]``; input ``effort`` per actuated joint.

    model: the kinematic tree; actuated: names of the driven joints (default: every 1-DOF
    joint); the others are passive (zero effort) but still damped by the model's damping.
    """

    def __init__(self, model: Model, actuated=None):
        self.model = model
        self.nq, self.nv = model.nq, model.nv
        self.ny = self.nq + self.nv
        self.joint_names = model.dof_joint_names
        actuated = list(self.joint_names if actuated is None else actuated)
        unknown = [j for j in actuated if j not in self.joint_names]
        if unknown:
            raise ValueError(f'actuated joints {unknown} are not joints of {model.name}; '
                             f'joints are {self.joint_names}')
        self.actuated = actuated
        dof_index = {n: k for k, n in enumerate(self.joint_names)}
        self.B = np.zeros((self.nv, len(actuated)))  # actuation matrix: tau = B u
        for k, n in enumerate(actuated):
            self.B[dof_index[n], k] = 1.0
        units = ['N·m' if model.jtype[model.joint_names.index(n)] == REVOLUTE else 'N' for n in actuated]
        self.inputs = {'effort': InputPort('effort', len(actuated), tuple(actuated), '/'.join(sorted(set(units))) or '-')}
        # child link of each 1-DOF joint, for the wrench frames
        self._dof_bodies = [i for i in range(model.nb) if model.jtype[i] in (REVOLUTE, PRISMATIC)]

    def split(self, y):
        """Views ``(q, v)`` of the state vector."""
        return y[:self.nq], y[self.nq:self.nq + self.nv]

    def initial_state(self, q0=None, v0=None):
        """State vector from optional q0 (nq,) and v0 (nv,) (zeros / neutral otherwise)."""
        y = np.zeros(self.ny)
        y[:self.nq] = self.model.neutral() if q0 is None else q0
        if v0 is not None:
            y[self.nq:] = v0
        return y

    def config_rate(self, q, w):
        """``dq/dt`` from the velocities at the start of ``w`` (quaternion-aware)."""
        return dyn.qdot(self.model, q, w[:self.nv])

    def project(self, y):
        """Renormalise free-joint quaternions (a no-op for a fixed-base arm)."""
        if self.nq != self.nv:
            y[:self.nq] = dyn.normalize_configuration(self.model, y[:self.nq])
        return y

    def generalized_forces(self, y, u):
        """Applied plus passive generalised forces ``B u - D v`` (nv,)."""
        _, v = self.split(y)
        return self.B @ u['effort'] + dyn.passive_forces(self.model, v)

    def rhs(self, t, y, u):
        """``[q̇; v̇]`` with v̇ from the articulated-body algorithm."""
        q, v = self.split(y)
        out = np.empty(self.ny)
        out[:self.nq] = dyn.qdot(self.model, q, v)
        out[self.nq:] = dyn.aba(self.model, q, v, self.generalized_forces(y, u))
        return out

    def outputs(self, t, y, u, wrenches=True):
        """Joint states, joint wrenches (optional) and energies at state y."""
        q, v = self.split(y)
        tau_cmd = self.B @ u['effort']
        w = {}
        if wrenches:
            _, f = dyn.joint_wrenches(self.model, q, v, self.generalized_forces(y, u))
            for i in range(self.model.nb):
                w[self.model.joint_names[i]] = (self.model.link_names[i], f[i].copy())
        return SystemOutputs(joint_names=list(self.joint_names), position=q.copy(), velocity=v.copy(),
                             effort=tau_cmd, wrenches=w,
                             energy={'kinetic': dyn.kinetic_energy(self.model, q, v),
                                     'potential': dyn.potential_energy(self.model, q)})

    def total_energy(self, y):
        """Kinetic plus gravitational potential energy (J)."""
        q, v = self.split(y)
        return dyn.kinetic_energy(self.model, q, v) + dyn.potential_energy(self.model, q)

    def input_power(self, t, y, u):
        """``vᵀ (B u - D v)``: actuator power minus damping dissipation (W)."""
        _, v = self.split(y)
        return float(v @ self.generalized_forces(y, u))
