"""An articulated tree, torque driven: a fixed-base arm, or a tree on a free root (a floating body).

Joints: revolute, prismatic, fixed, spherical (anywhere), and one FREE joint at the root (the
tree floats; its pose is published on ``odom``). Optional joint-limit moments (Huston eq.
20.2.1, :func:`robodyn_ros.kernels.tree.limit_moment`) act on limited joints; their power is part
of :meth:`ArmSystem.input_power`, so the Simulator's work quadrature counts it (in the seed's law
the stop only dissipates: its power is never positive).

``joint_states``: one entry per revolute/prismatic joint (q, v, commanded effort) and three per
spherical joint, ``<joint>_x``, ``<joint>_y``, ``<joint>_z``: position = the Bryan angles
(α, β, γ) of Huston eq. (20.3.2), ``R = Rx(α) Ry(β) Rz(γ)`` — the angles of the three revolute
joints the URDF export writes for it, so TF and Foxglove agree — velocity = the components of the
joint's angular velocity in the child frame (not the Bryan-angle rates, which are singular at
β = ±90°), effort = the commanded torque components about the child axes.

Mimic joints (URDF ``<mimic>``, ``LinkSpec.mimic``): a following joint keeps its place in the
state and in ``joint_states`` but moves with its source, ``q_j = m q_i + o`` (set after every
step, :meth:`ArmSystem.project`); the dynamics is reduced to the independent joints in the
compiled kernels (:mod:`robodyn_ros.kernels.coupled`; not on the numpy backend, and the
generated backend keeps such a tree on the generic kernels). A following joint takes no effort
command; its ``joint_states`` effort is the generalised force the coupling applies to it (λ,
what a linkage or gear train transmits: the torque a sensor on that joint would read), since it
has no actuator of its own. Its constraint wrench is published like any joint's: RNEA's joint
wrench at the coupled accelerations.
"""
from __future__ import annotations

import numpy as np

from .. import dynamics as dyn
from .. import kernels
from ..integrators import IntegrationError, IntegratorStats, StepBudgetError, make_integrator
from ..model import FREE, PRISMATIC, REVOLUTE, SPHERICAL, Model, bryan_angles, limit_table
from .base import (BACKENDS, InputPort, LazyValues, LazyWrenches, System, SystemOutputs,  # noqa: F401
                   clamp_to_limit, default_backend, effort_actuation, keeps_methods)


#: recorded states after which joint wrenches are batched in one compiled call (kernels.outputs)
BATCH_KERNEL_AFTER = 10_000
#: the methods whose ArmSystem versions the fused loop reproduces
_FUSED_METHODS_OF = ('rhs', 'input_power', 'generalized_forces', 'project', 'config_rate')
#: what fused_periods computes in its compiled loop instead of calling it (each period's outputs)
_PERIOD_METHODS_OF = ('outputs', '_state_outputs', '_outputs', 'split', '_wrenches_one', '_contact_outputs', '_wrenches_fext')



def _is_selection(B) -> bool:
    """True when B has only 0/1 entries, at most one 1 per row and per column (``B @ u`` picks and
    places entries: every summation order gives the same bits, compiled or not)."""
    B = np.asarray(B)
    return bool(np.all((B == 0.0) | (B == 1.0)) and np.all(B.sum(axis=0) <= 1) and np.all(B.sum(axis=1) <= 1))

class ArmSystem(System):
    """Arm on a fixed base: state ``y = [q (nq), v (nv)]``; input ``effort`` per actuated joint.

    model: the kinematic tree; actuated: names of the driven joints (default: every 1-DOF
    joint); the others are passive (zero effort) but still damped by the model's damping.
    backend: ``'numpy'`` (the reference kernels of :mod:`robodyn_ros.dynamics`), ``'numba'``
    (the compiled :mod:`robodyn_ros.kernels`, equal to 1e-12, plus :meth:`fused_advance`),
    ``'generated'`` (as numba, the fused loop calling this model's own forward dynamics and bias/mass
    pass, :mod:`robodyn_ros.kernels.codegen`: the same operations, compiled before the first step, a few
    seconds on first use of a model, cached on disk; trees with free, spherical or mimic joints and trees on
    a ground stay generic) or ``'auto'`` (numba, taking up the generated code once a child process has
    compiled it: ``kernels.GENERATE_AFTER``); default :func:`default_backend`. The recordings of the last
    three are the same bytes.
    """

    #: the block path (fused_periods) clamps commands to the effort limits as the Simulator does
    clamps_in_blocks = True

    def __init__(self, model: Model, actuated=None, backend=None):
        backend = default_backend() if backend is None else str(backend).lower()
        if backend not in BACKENDS:
            raise ValueError(f'unknown backend {backend!r}; valid: {", ".join(BACKENDS)}')
        if backend != 'numpy' and not kernels.AVAILABLE:
            raise ValueError(f'backend {backend} unavailable (no numba): {kernels.UNAVAILABLE_REASON}')
        lim = limit_table(model)
        if backend == 'numpy' and (model.has_spherical or lim.shape[0] or model.has_mimic):
            what = 'spherical joints are' if model.has_spherical else 'joint-limit moments are' if lim.shape[0] \
                else 'mimic joints (the coupled dynamics) are'
            raise ValueError(f'{model.name}: {what} computed by the compiled kernels only; '
                             "backend 'numpy' cannot simulate this model (use 'numba' or 'generated')")
        self._lim = lim
        self.backend = backend
        self._km = kernels.CompiledModel(model, specialize={'generated': True, 'auto': 'auto'}.get(backend, False)) \
            if backend != 'numpy' else None
        self._grids = {}
        # a subclass that changes the dynamics keeps the reference path (see fused_advance)
        self._fused_class_ok = all(getattr(type(self), n) is getattr(ArmSystem, n) for n in _FUSED_METHODS_OF)
        self.model = model
        self.nq, self.nv = model.nq, model.nv
        self.ny = self.nq + self.nv
        self.joint_names = model.state_joint_names
        # mimic joints (URDF <mimic>) follow their source: no effort command of their own
        self._coupled = self._km is not None and self._km.coupled is not None
        followers = set(model.mimic_joint_names)
        self.actuated, self.B, port = effort_actuation(model, [n for n in self.joint_names if n not in followers],
                                                       actuated, what='joints that take an effort (mimic joints '
                                                       'follow their source)' if followers else 'joints')  # tau = B u
        self._mimic_v = np.array([model.state_index(n)[1] for n in model.mimic_joint_names], dtype=int)
        self.inputs = {'effort': port}
        self._B = np.ascontiguousarray(self.B, dtype=np.float64)
        self._B_is_selection = _is_selection(self.B)   # fused_periods' condition
        # Coulomb joint friction (URDF <dynamics friction>): compiled kernel (kernels.passive), in the fused loop too
        self._friction = np.ascontiguousarray(model.friction)
        self._has_friction = bool(np.any(self._friction > 0.0))
        if self._has_friction and not kernels.AVAILABLE:
            raise ValueError(f'{model.name}: Coulomb joint friction needs the compiled kernels (numba): '
                             f'{kernels.UNAVAILABLE_REASON}')
        if self._has_friction:   # imported once here, not at every right-hand side
            from ..kernels.passive import add_coulomb_friction
            from ..urdf import COULOMB_VELOCITY
            self._coulomb = (add_coulomb_friction, COULOMB_VELOCITY)
        free = [i for i in range(model.nb) if model.jtype[i] == FREE]
        if len(free) > 1:
            raise ValueError(f'{model.name}: at most one free joint (the root of the tree)')
        self.free_body = free[0] if free else None   # its pose and twist go to odom
        # joint_states layout: (kind, q index, v index) per 1-DOF / spherical joint, model order
        self._pub = [(int(model.jtype[i]), int(model.q_idx[i]), int(model.v_idx[i])) for i in range(model.nb)
                     if model.jtype[i] in (REVOLUTE, PRISMATIC, SPHERICAL)]
        self._pub_v = np.array([v0 + k for jt, _, v0 in self._pub for k in range(3 if jt == SPHERICAL else 1)],
                               dtype=int)
        self._simple = self.free_body is None and not model.has_spherical   # joint_states = (q, v) as they are
        # outputs.wrenches: every joint (fixed ones too), at its child link
        self._wrench_names = tuple(model.joint_names)
        self._wrench_frames = tuple(model.link_names[:model.nb])
        self._wrench_index = {n: i for i, n in enumerate(self._wrench_names)}
        self._wrenches_many = self._wrenches_many   # one bound method: a stable batch key
        self.contact = None   # ground contact (attach_ground)
        self.servo = None     # the joint servo of position/velocity-commanded joints (use_servo)
        self.sensors = None   # IMU and force-torque sensors (attach_sensors)

    def use_servo(self, servo):
        """Drive the joints of ``servo`` (a :class:`robodyn_ros.systems.servo.JointServo`) by position and
        velocity commands: they leave the ``effort`` port, which keeps the other actuated joints; ports
        ``position`` (setpoints, held), ``trajectory`` (trajectory_msgs/JointTrajectory, onto the position
        setpoints) and ``velocity`` are added for the joints that take them. Compiled kernels only."""
        if self._km is None:
            raise ValueError(f'{self.model.name}: position and velocity commands are tracked by the compiled '
                             "kernels only; backend 'numpy' cannot simulate them (use 'numba' or 'generated')")
        taken = set(servo.names)
        effort = [n for n in self.actuated if n not in taken]
        self.actuated, self.B, self.inputs['effort'] = effort_actuation(self.model, effort)
        self._B = np.ascontiguousarray(self.B, dtype=np.float64)
        self._B_is_selection = _is_selection(self.B)

        def unit(names, rate):
            kinds = sorted({'m' if self.model.jtype[self.model.state_index(n)[0]] == PRISMATIC else 'rad' for n in names})
            return '/'.join(k + rate for k in kinds) or '-'
        if servo.position:
            self.inputs['position'] = InputPort('position', len(servo.position), servo.position,
                                                unit(servo.position, ''), kind='setpoint')
            self.inputs['trajectory'] = InputPort('trajectory', 0, servo.position, 'trajectory_msgs/JointTrajectory',
                                                  kind='message', target='position')
        if servo.velocity:
            self.inputs['velocity'] = InputPort('velocity', len(servo.velocity), servo.velocity,
                                                unit(servo.velocity, '/s'))
        self.servo = servo

    def attach_sensors(self, sensors):
        """Publish the IMU and force-torque readings of ``sensors`` (a
        :class:`robodyn_ros.systems.sensors.SensorSet` of this model) with every output. Compiled kernels only."""
        if self._km is None:
            raise ValueError(f'{self.model.name}: sensors are read by the compiled kernels only; '
                             "backend 'numpy' cannot simulate them (use 'numba' or 'generated')")
        self.sensors = sensors

    # -- commands of the servo's ports (Simulator.set_command) ---------------------------------
    def initial_input(self, port, y, t):
        """Before any command the position setpoints hold the initial positions (a trajectory
        controller's hold); every other port is zero."""
        if port == 'position' and self.servo is not None:
            from ..setpoints import SetpointProgram
            q = self.split(np.asarray(y, dtype=float))[0]
            value = np.array([q[int(self.servo.si[j, 1])] for j in range(len(self.servo.position))])
            return value, SetpointProgram.hold(self.servo.position, value, float(t))
        return super().initial_input(port, y, t)

    def accept_input(self, port, value, t, applied):
        """A position command (held from t) or a trajectory (joint_trajectory_controller's semantics,
        :mod:`robodyn_ros.setpoints`) onto the setpoint program ``applied``; ValueError to refuse."""
        from ..setpoints import SetpointProgram, parse_trajectory
        if not isinstance(applied, SetpointProgram):
            raise ValueError(f'port {port!r}: no setpoint program to apply it to')
        if port == 'position':
            return applied.with_positions(np.asarray(value, dtype=float), float(t))
        if port == 'trajectory':
            return applied.with_trajectory(parse_trajectory(value, self.servo.position), float(t))
        return super().accept_input(port, value, t, applied)

    def _srv(self, u):
        """The kernel's servo tuple for inputs u (None without a servo)."""
        if self.servo is None:
            return None
        return self.servo.pack(u.get('position'), u.get('velocity'))

    def _tau_cmd(self, u):
        """``B u`` (nv,): the efforts commanded on the effort port."""
        return self.B @ u['effort'] if self.B.shape[1] else np.zeros(self.nv)

    def attach_ground(self, contact):
        """Put the tree on a ground: contact: a :class:`robodyn_ros.systems.contact.GroundContact` of this
        model. Its body forces enter the dynamics (compiled kernels only; not on a tree with mimic
        joints), its power the work (``work_components`` gains ``'contact'``), its wrenches and
        diagnostics the outputs. On a backend that takes generated code, the tree's contact path has its own
        (:meth:`robodyn_ros.kernels.CompiledModel.on_ground`)."""
        if self._km is None:
            raise ValueError(f'{self.model.name}: ground contact is computed by the compiled kernels only; '
                             "backend 'numpy' cannot simulate it (use 'numba')")
        if self._coupled:
            raise ValueError(f'{self.model.name}: ground contact on a tree with mimic joints is not supported '
                             '(lock the mimic joints)')
        self.contact = contact
        self._km.con = contact.con
        self._km.cpo = contact.point_rows
        self._km.on_ground()
        self._grids = {}

    def split(self, y):
        """Views ``(q, v)`` of the state vector."""
        return y[:self.nq], y[self.nq:self.nq + self.nv]

    def initial_state(self, q0=None, v0=None):
        """State vector from optional q0 (nq,) and v0 (nv,) (zeros / neutral otherwise)."""
        y = np.zeros(self.ny)
        y[:self.nq] = self.model.neutral() if q0 is None else q0
        if v0 is not None:
            y[self.nq:] = v0
        if self._coupled:  # mimic joints follow their sources
            self._km.couple(y[:self.nq], y[self.nq:])
        return y

    def config_rate(self, q, w):
        """``dq/dt`` from the velocities at the start of ``w`` (quaternion-aware)."""
        if self._km is not None:
            return self._km.qdot(np.ascontiguousarray(q, dtype=float), np.ascontiguousarray(w[:self.nv], dtype=float))
        return dyn.qdot(self.model, q, w[:self.nv])

    def project(self, y):
        """Renormalise free- and spherical-joint quaternions and set mimic joints from their sources
        (a no-op for a 1-DOF fixed-base arm without mimic joints)."""
        if self.nq != self.nv:
            y[:self.nq] = self._km.normalize(y[:self.nq]) if self._km is not None else \
                dyn.normalize_configuration(self.model, y[:self.nq])
        if self._coupled:
            self._km.couple(y[:self.nq], y[self.nq:self.nq + self.nv])
        return y

    def generalized_forces(self, y, u, t=0.0, servo_torque=None):
        """Applied plus passive generalised forces ``B u - D v - F tanh(v / v_s) + τ_lim(q, v)`` (nv,);
        F: Coulomb joint friction, τ_lim: joint-limit moments; plus the joint servo's torques at time t (s)
        (:mod:`robodyn_ros.kernels.servo`; servo_torque (ns,): those torques when already computed)."""
        q, v = self.split(y)
        tau = self._tau_cmd(u) + dyn.passive_forces(self.model, v)
        if self._has_friction:
            add_friction, v_s = self._coulomb
            add_friction(self._friction, v_s, np.ascontiguousarray(v, dtype=float), tau)
        if self._lim.shape[0]:
            tau += self._km.limit_forces(q, v)
        if self.servo is not None:
            if servo_torque is None:
                servo_torque = self._km.servo_state(self._srv(u), t, q, v)[0][:, 4]
            tau[self.servo.v_index] += servo_torque
        return tau

    @property
    def work_components(self) -> tuple:
        """Parts of the work quadrature the Simulator integrates on their own: ``'limit'``
        (:meth:`limit_power`) when the model has joint-limit moments, ``'contact'`` (the ground's,
        :meth:`contact_power`) on a ground, in that order."""
        return (('limit',) if self._lim.shape[0] else ()) + (('contact',) if self.contact is not None else ())

    def work_component_powers(self, t, y, u) -> np.ndarray:
        """The powers (W) of :attr:`work_components` at state y, in that order."""
        out = [self.limit_power(y)] if self._lim.shape[0] else []
        if self.contact is not None:
            out.append(self.contact_power(y))
        return np.array(out, dtype=float)

    def contact_fext(self, y):
        """``(fext (nb_r, 6), power)``: the ground's forces on the bodies of the merged tree (body
        coordinates, ``kernels.contact.ground_fext``) and their power (W) at state y."""
        from ..kernels.contact import ground_fext
        q, v = self.split(y)
        return ground_fext(self.contact.con, self._km.mi_r, self._km.mf_r, np.ascontiguousarray(q, dtype=float),
                           np.ascontiguousarray(v, dtype=float))

    def contact_jacobian(self, y):
        """``(D_c, K_c)`` (nv, nv): the ground's damping and stiffness at state y in velocity coordinates
        (``kernels.contact.contact_jacobian``: ``−∂τ_c/∂v``, ``−∂τ_c/∂q``, symmetric positive
        semi-definite), the contact's share of a linearly implicit step's Jacobian; zeros off the ground."""
        if self.contact is None:
            return np.zeros((self.nv, self.nv)), np.zeros((self.nv, self.nv))
        from ..kernels.contact import contact_jacobian
        q, v = self.split(y)
        return contact_jacobian(self.contact.con, self._km.mi_r, self._km.mf_r, np.ascontiguousarray(q, dtype=float),
                                np.ascontiguousarray(v, dtype=float))

    def analysis_states(self, y) -> list:
        """On a ground, for a tree with a free root whose points do not press the ground at y: y with the
        root moved along the ground's normal until its lowest point sinks ``m g / k`` (the whole weight on
        one point: the stiffest normal spring and friction slope ``μ m g / v_s`` a landing can meet), at
        rest: the state whose contact stiffness ``integrator: auto`` must see before choosing. [] otherwise."""
        c = self.contact
        if c is None or self.free_body is None:
            return []
        q = np.array(self.split(y)[0], dtype=float)
        g = c.ground
        mass = float(sum(sp.mass for sp in self.model.specs))
        target = mass * float(np.linalg.norm(self.model.gravity)) / g.stiffness
        from ..kernels.contact import PDEPTH
        n = np.asarray(g.normal, dtype=float) / np.linalg.norm(g.normal)
        q0 = int(self.model.q_idx[self.free_body])
        below = q.copy()   # every point's depth: the tree moved 100 m into the ground (no group culled), less 100 m
        below[q0:q0 + 3] -= 100.0 * n
        deepest = float(np.max(c.point_outputs(self._km, below, np.zeros(self.nv))[:, PDEPTH])) - 100.0
        if deepest >= target:
            return []
        q[q0:q0 + 3] -= n * (target - deepest)
        return [np.concatenate([q, np.zeros(self.nv)])]

    def contact_power(self, y) -> float:
        """Power (W) of the ground's forces at state y (0 off the ground)."""
        return float(self.contact_fext(y)[1]) if self.contact is not None else 0.0

    def limit_power(self, y) -> float:
        """Power (W) of the joint-limit moments at state y (<= 0 for the seed's law: dissipation)."""
        if not self._lim.shape[0]:
            return 0.0
        q, v = self.split(y)
        return float(v @ self._km.limit_forces(q, v))

    def fastest_time_constant(self, y):
        """The fastest joint-limit mode (s): for each limited DOF, the faster root of ``I λ² + c λ + k``
        with I the DOF's articulated inertia ``1/(M⁻¹)_jj`` at y (``sqrt(I/k)`` when underdamped);
        ``inf`` without limit moments. :attr:`time_constant_words` names the joint."""
        self.time_constant_words = ''
        if not self._lim.shape[0]:
            return float('inf')
        q, _ = self.split(y)
        Minv = np.linalg.inv(self._km.crba(np.ascontiguousarray(q, dtype=float)))
        best = None   # (time constant, v index, k, c, I) of the fastest mode so far
        for row in self._lim:
            jt, vi, k, c = int(row[0]), int(row[2]), float(row[10]), float(row[11])
            for j in range(3 if jt == SPHERICAL else 1):
                inertia = 1.0 / Minv[vi + j, vi + j]
                lam = np.abs(np.roots([inertia, c, k])).max() if (k or c) else 0.0
                if lam > 0 and 1.0 / lam < (float('inf') if best is None else best[0]):
                    best = (1.0 / lam, vi + j, k, c, inertia)
        if best is None:
            return float('inf')
        tau, vj, k, c, inertia = best
        name = self.model.state_joint_names[list(self._pub_v).index(vj)]   # its joint_states entry (v order)
        self.time_constant_words = (f'; the joint limit of {name!r} (stiffness k = {k:.3g}, damping c = {c:.3g}, '
                                    f'articulated inertia I = {inertia:.3g}): time constant 1/|λ| = {tau:.3g} s, '
                                    f'sqrt(I/k) = {np.sqrt(inertia / k) if k else float("inf"):.3g} s')
        return tau

    def stop_time_constant(self, y):
        """The fastest joint-stop mode (s): :meth:`fastest_time_constant`, whose modes are all joint stops."""
        return self.fastest_time_constant(y)

    def passive_jacobian(self, t, y, u, h=None):
        """J (ny, ny) of the linearly implicit step at y (``System.passive_jacobian``): ``[[0, Q], [−M⁻¹K Φ,
        −M⁻¹D]]`` with D, K from ``CompiledModel.passive_jacobian`` (damping, friction slope, joint-limit
        moments, on a ground the contacts' D_c, K_c, and at a step h the gravity stiffness of the 1-DOF
        joints; the reference backend: damping alone), Q = ∂q̇/∂v and Φ its left inverse (tangent
        coordinates of a change of q); with mimic joints M⁻¹ is the coupled one, ``G (Gᵀ M G)⁻¹ Gᵀ``. The
        fused loop assembles the same D and K itself."""
        q, v = self.split(np.asarray(y, dtype=float))
        nq, nv = self.nq, self.nv
        if self._km is not None:
            D, K = self._km.passive_jacobian(q, v, h, t, self._srv(u))
            M = self._km.crba(np.ascontiguousarray(q))
        else:
            D, K = np.diag(self.model.damping.astype(float)), np.zeros((nv, nv))
            M = dyn.crba(self.model, q)
        J = np.zeros((self.ny, self.ny))
        if nq == nv:
            Q = np.eye(nv)
        else:
            Q = np.column_stack([self.config_rate(q, e) for e in np.eye(nv)])
        J[:nq, nq:] = Q
        if self._km is not None and self._km.cpl is not None:   # mimic joints: v̇ = G M_r⁻¹ Gᵀ (...)
            Gc = np.zeros((nv, self._km.nr))
            Gc[np.arange(nv), self._km.col] = self._km.mul
            MinvDK = Gc @ np.linalg.solve(Gc.T @ M @ Gc, Gc.T @ np.hstack([D, K]))
        else:
            MinvDK = np.linalg.solve(M, np.hstack([D, K]))
        J[nq:, nq:] = -MinvDK[:, :nv]
        J[nq:, :nq] = -MinvDK[:, nv:] @ (np.eye(nv) if nq == nv else np.linalg.pinv(Q))
        return J

    def time_derivative(self, t, y, u):
        """``[0; M⁻¹ F_t]`` (ny,): the time rate of the joint servo's stiff part (``kp q̇* + kd q̈*`` on its
        unsaturated position joints, ``kernels.servo.servo_time_rate``) as the fused loop's linearly implicit
        step takes it; None without a servo."""
        if self.servo is None:
            return None
        from ..kernels.servo import servo_time_rate
        q, v = self.split(np.asarray(y, dtype=float))
        srv = self._srv(u)
        self._km.servo_state(srv, t, q, v)
        Ft = np.zeros(self.nv)
        servo_time_rate(srv, Ft)
        M = self._km.crba(np.ascontiguousarray(q))
        out = np.zeros(self.ny)
        if self._km.cpl is not None:   # mimic joints: M⁻¹ is the coupled one, G (Gᵀ M G)⁻¹ Gᵀ
            Gc = np.zeros((self.nv, self._km.nr))
            Gc[np.arange(self.nv), self._km.col] = self._km.mul
            out[self.nq:] = Gc @ np.linalg.solve(Gc.T @ M @ Gc, Gc.T @ Ft)
        else:
            out[self.nq:] = np.linalg.solve(M, Ft)
        return out

    def explicit_time_constant(self, y):
        """inf: the declared fastest modes (joint limits) are in :meth:`passive_jacobian`."""
        return float('inf')

    def urdf(self) -> str:
        """URDF for ``robot_description``: a free root's floating joint and world link are left out
        (``odom`` publishes that pose, REP 105), as for the free-flyer."""
        from ..model import to_urdf
        if self.free_body is None:
            return to_urdf(self.model)
        from .freeflyer import free_base_urdf
        return free_base_urdf(self.model)

    def rhs(self, t, y, u):
        """``[q̇; v̇]`` with v̇ from the articulated-body algorithm."""
        q, v = self.split(y)
        out = np.empty(self.ny)
        if self.contact is not None:   # ABA with the ground's body forces, on the merged tree
            from ..kernels.tree import aba_fext_into
            km = self._km
            out[:self.nq] = km.qdot(q, v)
            aba_fext_into(km.mi_r, km.mf_r, np.ascontiguousarray(q, dtype=float), np.ascontiguousarray(v, dtype=float),
                          self.generalized_forces(y, u, t), self.contact_fext(y)[0], out[self.nq:])
            return out
        if self._km is not None:
            out[:self.nq] = self._km.qdot(q, v)
            out[self.nq:] = self._km.aba(q, v, self.generalized_forces(y, u, t))
            return out
        out[:self.nq] = dyn.qdot(self.model, q, v)
        out[self.nq:] = dyn.aba(self.model, q, v, self.generalized_forces(y, u))
        return out

    def inverse_dynamics(self, q, v, a):
        """``tau = M(q) a + h(q, v)`` (nv,) by RNEA on this system's backend (e.g. for gravity compensation)."""
        if self._km is not None:
            return self._km.rnea(np.ascontiguousarray(q, dtype=float), np.ascontiguousarray(v, dtype=float),
                                 np.ascontiguousarray(a, dtype=float))
        return dyn.rnea(self.model, q, v, a)

    def _energies(self, q, v):
        """``(kinetic, potential)`` (J) on this system's backend."""
        if self._km is not None:
            return self._km.energies(q, v)
        return dyn.kinetic_energy(self.model, q, v), dyn.potential_energy(self.model, q)

    @property
    def fused_tolerance(self) -> bool:
        """True when :meth:`fused_advance` takes ``tol`` (rosenbrock2 under error control): this class's own
        (a subclass with its own fused loop, e.g. the prescribed path's, runs such a run on the Python path)."""
        return type(self).fused_advance is ArmSystem.fused_advance

    def fused_advance(self, integrator_name, dt, t0, z0, t1, u, tol=None):
        """Integrate ``z = [y, W]`` from t0 to t1 in one compiled call, or None to decline.

        The Simulator's fast path for fixed-step integrators (``euler``,
        ``semi_implicit_euler``, ``rk4``): the same method, step grid
        (``FixedStepIntegrator.step_grid``), projection after every step and work quadrature
        ``dW/dt = vᵀ (B u − D v)`` as ``Simulator._integrate`` with this system's ``rhs``,
        computed by :func:`robodyn_ros.kernels.arm.integrate_arm`. Declines (returns None) on
        the numpy backend, for other integrators, and in subclasses that change the dynamics.
        ``z = [y, W, W_lim]`` also integrates :meth:`limit_power` (the Simulator does so when
        :attr:`work_components` names it). tol: None, or ``(rtol, atol)``: rosenbrock2 under error control, dt
        its largest step (``kernels.arm.arm_controlled_steps``), or ``(rtol, atol, most steps)`` (then
        ``StepBudgetError`` where they do not reach t1). Returns ``(z1, IntegratorStats)``; raises
        ``IntegrationError`` like the reference integrator when the state becomes non-finite.
        """
        z = np.array(z0, dtype=np.float64)
        if not self._fuses(integrator_name, z):
            return None
        grid = self._grids.get(dt)
        if grid is None:
            grid = self._grids[dt] = make_integrator('rk4', dt=dt)
        n_full, h_last = grid.step_grid(float(t0), float(t1)) if t1 > t0 else (0, 0.0)
        n_steps = n_full + (1 if h_last > 0.0 else 0)
        tau_app = np.ascontiguousarray(self._tau_cmd(u), dtype=np.float64)
        k = self._km.integrate_arm(integrator_name, z, tau_app, dt, n_full, h_last, t0, self._srv(u), tol)
        if k == 0 and not np.isfinite(z0).all():  # checked after the fact: the loop reports step 0
            raise IntegrationError(integrator_name, t0, 'initial state is non-finite at components '
                                   f'{np.flatnonzero(~np.isfinite(np.asarray(z0)))[:8].tolist()}')
        if tol is not None:
            c = self._km.control_counts()
            accepted, rejected = c['accepted'], c['rejected']
            if c['budget']:
                raise StepBudgetError(integrator_name, t0 + c['done'], accepted)
            if c['underflow']:
                from ..integrators import tolerance_failure
                from ..kernels.arm import H_MIN
                t = t0 + c['done']
                raise IntegrationError(integrator_name, t, tolerance_failure(t, H_MIN * dt, tol[0], tol[1], dt))
            if k >= 0:
                t = t0 + k * dt
                raise IntegrationError(
                    integrator_name, t,
                    f'state became non-finite (components {np.flatnonzero(~np.isfinite(z))[:8].tolist()}) in a '
                    f'step after t={t:.12g} s (error-controlled, dt={dt:g} s its largest); check the model')
            st = IntegratorStats.of_fused_steps(integrator_name, accepted + rejected)
            st.steps, st.rejected_steps, st.projections = accepted, rejected, accepted
            return z, st
        if k >= 0:
            t = t0 + k * dt
            h = dt if k < n_full else h_last
            raise IntegrationError(
                integrator_name, t + h,
                f'state became non-finite (components {np.flatnonzero(~np.isfinite(z))[:8].tolist()}) in the '
                f'step from t={t:.12g} s with h={h:.6g} s; reduce dt or check the model')
        return z, IntegratorStats.of_fused_steps(integrator_name, n_steps)

    def fused_periods(self, integrator_name, dt, z, t_start, t_end, u, program=None, wrenches=False, held=None):
        """Run K publication periods in one compiled call (``kernels.arm.run_arm_periods`` through
        ``CompiledModel.run_periods``), or None to decline.

        The block path of :func:`robodyn_ros.simulation.run_headless`: per period the scripted
        command at its start (program: a compiled command profile ``(kind, P, times, values, BT,
        Bq)`` from :mod:`robodyn_ros.profiles`, None: u held), clamped to the port's effort limits,
        the fused integration of :meth:`fused_advance` over the same step grid, and the outputs at
        its end. z: ``[y, W(, W_lim)(, W_c)]`` (advanced in place: scratch, the periods' states are
        Zs); t_start, t_end (K,): the periods; u (n,): the command held before the first period
        (updated in place: the last command as commanded). Declines where :meth:`fused_advance`
        does, for spherical joints (joint_states hold their Bryan angles), for mimic joints (their
        efforts are the coupling's forces, computed per period), for input matrices that are not 0/1
        selections, and where :meth:`outputs` (or what it calls for joint states and wrenches) is
        not ArmSystem's own. A joint servo or sensors need ``held``, the inputs held over the periods
        (``Simulator.held_inputs``: the servo's setpoint program is fixed; the effort port's entry is each
        period's command, clamped): the compiled loop runs the servo at every stage and gives its state
        at each period's end, from which :meth:`control_outputs` builds that period's messages as
        :meth:`outputs` does (on a ground too: the sensors then read the contacts' forces). Returns ``(k, code, Zs, Us, (position, velocity,
        effort), Fs, steps, more)``: see ``kernels.arm.run_arm_periods``; the joint_states arrays (K, ·) of
        each period's end, Fs None without wrenches, steps (K,) per period; more: ``{'odom': (K, 13)
        position, orientation, linear, angular of a free root (else None), 'contacts': (K, nl, 6) the links'
        contact wrenches (else None), 'points': (K, np, NP) every contact point's outputs
        (:meth:`contact_point_outputs` of each period's end, else None), 'control': (K,) list of each period's ``(messages, imu_poses,
        ft_wrenches)`` with a servo or sensors (else None)}``.
        """
        control = self.servo is not None or self.sensors is not None
        if not self._fuses(integrator_name, z) or self.model.has_spherical or not self._B_is_selection \
                or (control and held is None) \
                or self._coupled or not keeps_methods(self, ArmSystem, _PERIOD_METHODS_OF):
            return None
        grid = self._grids.get(dt)
        if grid is None:
            grid = self._grids[dt] = make_integrator('rk4', dt=dt)
        K = len(t_start)
        n_full, h_last = grid.step_grids(t_start, t_end)
        nb = self.model.nb
        Zs = np.empty((K, z.shape[0]))
        Us = np.empty((K, u.shape[0]))
        TAUs = np.empty((K, self.nv))
        Fs = np.empty((K, nb, 6) if wrenches else (0, nb, 6))
        c = self.contact
        Cs = np.empty((K, len(c.links) if c is not None else 0, 6))
        CPs = None
        if c is not None:
            from ..kernels.contact import NP
            CPs = np.empty((K, c.n_points, NP))
        lim = self.inputs['effort'].limit
        ulim = np.full(u.shape[0], np.inf) if lim is None else np.asarray(lim, dtype=float)
        srv = self._srv(held) if self.servo is not None else None
        SVs = np.empty((K, 0 if srv is None else srv[0].shape[0], 6))
        t_end = np.ascontiguousarray(t_end, dtype=float)
        k, code, _ = self._km.run_periods(integrator_name, self._B, z, dt, np.ascontiguousarray(t_start, dtype=float),
                                          n_full, h_last, program, u, Zs, Us, TAUs, Fs, wrenches, ulim, Cs,
                                          t_end, srv, SVs, CPs=CPs)
        steps = n_full + (h_last > 0.0)
        more = {'odom': None, 'contacts': Cs if c is not None else None, 'control': None, 'points': CPs}
        if srv is not None:   # its joints publish the torque it applies (as _state_outputs sets them, not adds)
            TAUs[:k, self.servo.v_index] = SVs[:k, :, 4]
        if control:   # each period's servo and sensor messages, as outputs() builds them
            inputs = dict(held)
            more['control'] = ctl = []
            for j in range(k):
                inputs['effort'] = clamp_to_limit(Us[j], None if lim is None else ulim)   # as the port applies it
                ctl.append(self.control_outputs(float(t_end[j]), Zs[j, :self.ny], inputs,
                                                None if srv is None else SVs[j]))
        if self._simple:
            outs = (Zs[:, :self.nq], Zs[:, self.nq:self.nq + self.nv], TAUs)   # joint_states = (q, v) as they are
        else:   # a free root: its pose and twist go to odom, the 1-DOF joints to joint_states
            q0, v0 = int(self.model.q_idx[self.free_body]), int(self.model.v_idx[self.free_body])
            pq = np.array([q for _, q, _ in self._pub], dtype=int)
            outs = (Zs[:, pq], Zs[:, self.nq + self._pub_v], TAUs[:, self._pub_v])
            more['odom'] = np.concatenate([Zs[:, q0:q0 + 7], Zs[:, self.nq + v0 + 3:self.nq + v0 + 6],
                                           Zs[:, self.nq + v0:self.nq + v0 + 3]], axis=1)
        return k, code, Zs, Us, outs, (Fs if wrenches else None), steps, more

    def state_extra(self, y, points=None) -> dict:
        """The diagnostics values :meth:`outputs` puts in ``extra`` at state y (the contact ones on a
        ground; none otherwise), for the block path, which builds no outputs per period; points: the contact
        points' outputs at y (:meth:`contact_point_outputs`) where the caller has them."""
        if self.contact is None:
            return {}
        if points is None:
            q, v = self.split(y)
            points = self.contact.point_outputs(self._km, q, v)
        return self.contact.diagnostics(points)

    def _fuses(self, integrator_name, z) -> bool:
        """True when the fused loop computes what the Python path would for this integrator and
        ``z``: compiled kernels, a method it implements, this class's dynamics (:meth:`_fused_exact`),
        ``z = [y, W, W_parts]`` with the parts of :attr:`work_components` or without W_lim (``z = [y, W(, W_c)]``:
        the limit work not kept apart)."""
        nc = 1 if self.contact is not None else 0
        return self._km is not None and integrator_name in kernels.FUSED_METHODS and self._fused_exact() \
            and z.shape in ((self.ny + 1 + nc,), (self.ny + 2 + nc,))

    def _fused_exact(self) -> bool:
        """True when this object computes dy/dt, power, projection and q̇ exactly as ArmSystem
        (no subclass override, no method replaced on the instance)."""
        return self._fused_class_ok and self.__dict__.keys().isdisjoint(_FUSED_METHODS_OF)

    def outputs(self, t, y, u, wrenches=True):
        """Joint states, joint wrenches (optional) and energies at state y; with a joint servo its desired
        and error states, with sensors their readings (``SystemOutputs.messages``) and what the markers draw
        of them (``imu_poses``, ``ft_wrenches``)."""
        if self.servo is None and self.sensors is None:
            return self._state_outputs(t, y, u, wrenches)
        st = None   # the servo at (t, y): desired values and torques (kernels.servo.servo_state), once
        if self.servo is not None:
            q, v = self.split(y)
            st = self._km.servo_state(self._srv(u), t, q, v)[0]
        out = self._state_outputs(t, y, u, wrenches, st)
        msgs, out.imu_poses, out.ft_wrenches = self.control_outputs(t, y, u, st)
        out.messages.extend(msgs)
        return out

    def control_outputs(self, t, y, u, st=None) -> tuple:
        """``(messages, imu_poses, ft_wrenches)`` of the servo and sensors at time t, state y and inputs u
        (:func:`.servo.control_messages`; what the markers draw of the sensors, None without them); st: the
        servo's state there when known. :meth:`outputs` and the block path (:meth:`fused_periods`) both call it."""
        from .servo import control_messages
        msgs = control_messages(self, t, y, u, st)
        if self.sensors is None:
            return msgs, None, None
        n = len(self.sensors.sensors)   # the sensors' messages come last (control_messages)
        imu, ft = self.sensors.world_frames(self._km, self.split(y)[0], msgs[len(msgs) - n:])
        return msgs, imu, ft

    def sensor_accelerations(self, t, y, u, st=None):
        """The joint accelerations (nv,) the sensors read at time t, state y, inputs u: those of :meth:`rhs`, with
        the servo's torques taken from its state st (``CompiledModel.servo_state``) when given, and rhs is this
        class's own (else rhs itself, which evaluates the servo again)."""
        if st is None or self.contact is not None or self._km is None or not keeps_methods(self, ArmSystem, ('rhs',)):
            return self.rhs(t, y, u)[self.nq:self.nq + self.nv]
        q, v = self.split(y)
        return self._km.aba(q, v, self.generalized_forces(y, u, t, st[:, 4]))

    def _state_outputs(self, t, y, u, wrenches, st=None):
        """:meth:`outputs` without the servo's and sensors' messages (st: the servo's state at (t, y), if known)."""
        q, v = self.split(y)
        tau_cmd = self._tau_cmd(u)
        ts = None
        if self.servo is not None:   # the servo's joints publish the torque it applies now
            ts = (self._km.servo_state(self._srv(u), t, q, v)[0] if st is None else st)[:, 4].copy()
            tau_cmd[self.servo.v_index] = ts
        w = {}
        if self._coupled:  # a mimic joint's effort: what the coupling transmits to it (λ, kernels.coupled)
            _, f, lam = self._km.coupled_wrenches(q, v, self.generalized_forces(y, u, t, ts))
            tau_cmd[self._mimic_v] = lam[self._mimic_v]
            if wrenches:
                w = {self.model.joint_names[i]: (self.model.link_names[i], f[i].copy()) for i in range(self.model.nb)}
            return self._outputs(q.copy(), v.copy(), tau_cmd, w)
        if self.contact is not None:
            return self._contact_outputs(q.copy(), v.copy(), tau_cmd, self.generalized_forces(y, u, t, ts), wrenches)
        if wrenches:
            if self._km is not None:   # computed when read, or for many publications at once by a recorder
                q1, v1 = q.copy(), v.copy()
                return self._outputs(q1, v1, tau_cmd, LazyWrenches(
                    self._wrench_names, self._wrench_frames, self._wrenches_one, self._wrenches_many,
                    (q1, v1, self.generalized_forces(y, u, t, ts)), self._wrench_index))
            else:
                _, f = dyn.joint_wrenches(self.model, q, v, self.generalized_forces(y, u, t, ts))
            for i in range(self.model.nb):
                w[self.model.joint_names[i]] = (self.model.link_names[i], f[i].copy())
        return self._outputs(q.copy(), v.copy(), tau_cmd, w)

    def _contact_outputs(self, q, v, tau_cmd, tau, wrenches):
        """The outputs of a tree on the ground: the joint wrenches under the ground's forces too, one
        wrench per touching link (``SystemOutputs.contacts``) and the contact diagnostics (``extra``)."""
        c = self.contact
        P = c.point_outputs(self._km, q, v)
        w = {}
        if wrenches:
            fext = c.body_forces(self._km, q, P)
            w = LazyWrenches(self._wrench_names, self._wrench_frames, self._wrenches_fext, self._wrenches_fext_many,
                             (q, v, tau, fext), self._wrench_index)
        out = self._outputs(q, v, tau_cmd, w)
        out.contacts = {link: (c.frame, wr) for link, wr in zip(c.links, c.wrenches(P))}
        out.contact_points = c.touching(P)
        out.extra.update(c.diagnostics(P))
        return out

    def contact_points(self, y) -> np.ndarray | None:
        """``SystemOutputs.contact_points`` at state y (the touching points and their forces), None
        off the ground; for the block path, which builds no outputs per period."""
        if self.contact is None:
            return None
        q, v = self.split(y)
        return self.contact.touching(self.contact.point_outputs(self._km, q, v))

    def contact_point_outputs(self, Y) -> np.ndarray | None:
        """(m, nc, NP) every contact point's outputs (``kernels.contact.contact_points``, columns there) at
        each of the states Y (m, ny), None off the ground; for the block path's markers (one compiled call
        per state, without the per-state Python of :meth:`contact_points`)."""
        if self.contact is None:
            return None
        from ..kernels.contact import NP, contact_points
        km, con, nq = self._km, self.contact.con, self.nq
        Y = np.ascontiguousarray(Y, dtype=float)
        out = np.empty((Y.shape[0], self.contact.n_points, NP))
        for k in range(Y.shape[0]):
            out[k] = contact_points(con, km.mi_r, km.mf_r, Y[k, :nq], Y[k, nq:])
        return out

    def _wrenches_fext(self, q, v, tau, fext):
        return self._km.joint_wrenches(q, v, tau, fext)[1]

    def _wrenches_fext_many(self, args):
        return np.array([self._wrenches_fext(*a) for a in args])

    def _outputs(self, q, v, tau_cmd, w):
        def energy():
            kin, pot = self._energies(q, v)
            return {'kinetic': kin, 'potential': pot}
        if self._simple:
            return SystemOutputs(joint_names=list(self.joint_names), position=q, velocity=v, effort=tau_cmd,
                                 wrenches=w, energy=LazyValues(energy))
        pos = []
        for jt, q0, _ in self._pub:
            if jt == SPHERICAL:
                pos += bryan_angles(q[q0:q0 + 4])
            else:
                pos.append(q[q0])
        odom = None
        if self.free_body is not None:
            q0, v0 = int(self.model.q_idx[self.free_body]), int(self.model.v_idx[self.free_body])
            odom = {'position': q[q0:q0 + 3].copy(), 'orientation': q[q0 + 3:q0 + 7].copy(),
                    'linear': v[v0 + 3:v0 + 6].copy(), 'angular': v[v0:v0 + 3].copy()}
        return SystemOutputs(joint_names=list(self.joint_names), position=np.array(pos), velocity=v[self._pub_v],
                             effort=tau_cmd[self._pub_v], wrenches=w, odom=odom, energy=LazyValues(energy),
                             odom_child=self.model.link_names[self.free_body] if odom is not None else 'base_link')

    def _wrenches_one(self, q, v, tau):
        return self._km.joint_wrenches(q, v, tau)[1]

    def _wrenches_many(self, args):
        # the batch kernel takes ~15 ms to load from numba's cache in a new process and saves
        # ~1.5 us per state: it is loaded once this system has asked for BATCH_KERNEL_AFTER states
        # (about 100 s of simulation at 100 Hz); before, the per-state kernel (the same numbers)
        self._many_states = getattr(self, '_many_states', 0) + len(args)
        if self._many_states <= BATCH_KERNEL_AFTER:
            return np.array([self._wrenches_one(*a) for a in args])
        from ..kernels.outputs import joint_wrenches_many
        return joint_wrenches_many(self._km, *(np.array(a) for a in zip(*args)))

    def total_energy(self, y):
        """Kinetic plus gravitational potential energy (J)."""
        q, v = self.split(y)
        kin, pot = self._energies(q, v)
        return kin + pot

    def input_power(self, t, y, u):
        """``vᵀ (B u - D v + τ_lim)``: actuator power minus damping and joint-limit dissipation (W), plus
        the ground's power on a ground."""
        _, v = self.split(y)
        P = float(v @ self.generalized_forces(y, u, t))
        return P + self.contact_power(y) if self.contact is not None else P
