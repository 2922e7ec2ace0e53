"""The joint servo of an arm's position- and velocity-commanded joints: which joints, their gains, and
the packed arrays its kernel (:mod:`robodyn_ros.kernels.servo`, the law (S1)) runs on.

**Default gains.** Unless the scene gives them, every servo joint j gets
``kp_j = I_j ω²`` and ``kd_j = 2 ζ I_j ω`` with ``I_j = 1 / (M⁻¹)_jj`` from the mass matrix at the
initial state: the inertia joint j presents when the other joints move freely (its articulated
inertia; the diagonal ``M_jj``, the inertia with the others held, can be 10x larger at a shoulder, and
gains from it make the light distal joints' coupled modes many times faster than ω: xArm7's reach
``h|λ| = 3.3`` at 1 ms with ``M_jj``, 0.21 with ``I_j``). The damping ratio ``ζ = 1``
(:data:`DEFAULT_DAMPING_RATIO`) and the natural frequency ``ω = 2π · 10 Hz``
(:data:`DEFAULT_FREQUENCY_HZ`); ω is lowered where needed so that the servo's fastest mode at the
initial state (the eigenvalues of ``[[0, 1], [−M⁻¹ Kp, −M⁻¹ Kd]]``, which scale with ω) has
``h |λ| <=`` :data:`DEFAULT_STEP_MARGIN` at the scene's step h: the defaults are stable for the robot's
inertia at its step under every fixed-step method the package has (RK4 is stable to ``h |λ| = 2.8``),
and the feed-forward (on by default on a fixed base) carries the tracking, so the gains only reject
errors.
"""
from __future__ import annotations

import math

import numpy as np

#: natural frequency (Hz) of the default gains
DEFAULT_FREQUENCY_HZ = 10.0
#: damping ratio of the default gains
DEFAULT_DAMPING_RATIO = 1.0
#: largest ``h |λ|`` of the default gains' fastest mode at the scene's step
DEFAULT_STEP_MARGIN = 1.0
#: command interfaces a joint may take
INTERFACES = ('effort', 'position', 'velocity')


def default_gains(M, position, velocity, dt, frequency_hz=DEFAULT_FREQUENCY_HZ, zeta=DEFAULT_DAMPING_RATIO):
    """``(kp, kd, omega)`` of the servo joints (module docstring): M (nv, nv) the mass matrix at the
    initial state (its inverse's diagonal gives each joint's articulated inertia); position, velocity: v indices of the position- and velocity-commanded joints (their
    order is the returned arrays'); dt: the step (s); kp of a velocity joint is 0."""
    idx = list(position) + list(velocity)
    Minv = np.linalg.inv(M)
    diag = np.array([1.0 / Minv[i, i] for i in idx], dtype=float)   # articulated inertia of each joint
    npos = len(position)

    def gains(w):
        kp = diag * w * w
        kp[npos:] = 0.0
        return kp, 2.0 * zeta * diag * w
    w = 2.0 * math.pi * frequency_hz
    kp, kd = gains(w)
    nv = M.shape[0]
    Kp = np.zeros((nv, nv))
    Kd = np.zeros((nv, nv))
    Kp[idx, idx] = kp
    Kd[idx, idx] = kd
    A = np.zeros((2 * nv, 2 * nv))
    A[:nv, nv:] = np.eye(nv)
    A[nv:, :nv] = -Minv @ Kp
    A[nv:, nv:] = -Minv @ Kd
    lam = float(np.max(np.abs(np.linalg.eigvals(A)))) if A.size else 0.0
    if dt and lam * dt > DEFAULT_STEP_MARGIN:   # the eigenvalues scale with ω
        w *= DEFAULT_STEP_MARGIN / (lam * dt)
        kp, kd = gains(w)
    return kp, kd, w


class JointServo:
    """The servo of an arm's commanded joints (law (S1) of :mod:`robodyn_ros.kernels.servo`).

    model: the tree; position, velocity: joint names (1-DOF joints) commanded by position (held
    setpoints and trajectories) and by velocity; kp, kd (ns,): gains in that order (position joints
    first); feedforward: add the inverse dynamics of the desired motion. Each joint's effort limit
    (``LinkSpec.effort_limit``, URDF ``<limit effort>``) saturates its torque.
    """

    def __init__(self, model, position, velocity, kp, kd, feedforward: bool):
        from ..kernels import servo as ks
        self.position, self.velocity = tuple(position), tuple(velocity)
        self.names = self.position + self.velocity
        ns = len(self.names)
        self.si = np.zeros((ns, 4), dtype=np.int64)
        self.sf = np.zeros((ns, 3))
        for j, name in enumerate(self.names):
            body, vi = model.state_index(name)
            pos = j < len(self.position)
            self.si[j] = (vi, int(model.q_idx[body]), ks.SERVO_POSITION if pos else ks.SERVO_VELOCITY,
                          j if pos else j - len(self.position))
            lim = model.specs[body].effort_limit
            self.sf[j, ks.SF_UMAX] = lim if lim else np.inf
        self.sf[:, ks.SF_KP] = kp
        self.sf[:, ks.SF_KD] = kd
        self.feedforward = bool(feedforward)
        fixed = sorted(int(v) for v in self.si[:, 0]) == list(range(model.nv))   # every joint a servo joint
        self.opt = np.array([1.0 if feedforward else 0.0, 0.0, 1.0 if fixed else 0.0, np.nan, -1.0])   # ks.OPT_*
        self.sw = np.zeros((ks.NSW, max(model.nq, model.nv, 1)))
        self.v_index = self.si[:, 0].copy()
        self._packed = (None, None, None)

    @property
    def kp(self) -> np.ndarray:
        """Position gains (ns,) (N·m/rad or N/m; 0 for velocity joints)."""
        return self.sf[:, 0].copy()

    @property
    def kd(self) -> np.ndarray:
        """Velocity gains (ns,) (N·m·s/rad or N·s/m)."""
        return self.sf[:, 1].copy()

    def pack(self, program, vset):
        """The kernel's ``srv`` tuple for a setpoint program of the position joints (a
        :class:`robodyn_ros.setpoints.SetpointProgram`, or an array of held positions) and velocity
        setpoints vset (nvel,); the same tuple while both are unchanged."""
        key_p, key_v, packed = self._packed
        vset = np.ascontiguousarray(vset if vset is not None else np.zeros(0), dtype=float).reshape(-1)
        if packed is not None and program is key_p and np.array_equal(vset, key_v):
            return packed
        from ..setpoints import SetpointProgram
        if isinstance(program, SetpointProgram):
            T, C = program.T, program.C
        else:   # a plain array: held positions
            pr = SetpointProgram.hold(self.position, np.zeros(len(self.position)) if program is None else program,
                                      0.0)
            T, C = pr.T, pr.C
        if C.shape[1] != len(self.position):
            raise ValueError(f'setpoint program for {C.shape[1]} joints, the servo has {len(self.position)} '
                             'position-commanded joints')
        packed = (self.si, self.sf, T, C, vset.copy(), self.sw, self.opt)
        self.opt[3] = np.nan   # ks.OPT_CT: the feed-forward cached in sw is of another program
        self._packed = (program, vset.copy(), packed)
        return packed


#: topics of a servo's desired and error states (sensor_msgs/JointState, the servo's joints)
DESIRED_TOPIC, ERROR_TOPIC = 'joint_trajectory_desired', 'joint_trajectory_error'


def control_messages(system, t, y, u, st=None) -> list:
    """The messages of an arm's servo and sensors at time t (s), state y and inputs u:
    ``joint_trajectory_desired`` (position q*, velocity q̇*, effort the feed-forward torque) and
    ``joint_trajectory_error`` (position q* − q, velocity q̇* − q̇, effort the torque the servo applies)
    over the servo's joints (position-commanded first; a velocity joint's position error is 0), then the
    sensors' readings (:mod:`robodyn_ros.systems.sensors`) at the joint accelerations of the dynamics. st: the
    servo's state at (t, y) (``CompiledModel.servo_state``), when already computed."""
    from .. import messages as M
    out = []
    q, v = system.split(np.asarray(y, dtype=float))
    km = system._km
    t_ns = M.to_ns(t)
    if system.servo is not None:
        s = system.servo
        if st is None:
            st = km.servo_state(system._srv(u), t, q, v)[0]
        js = M.TOPIC_TYPES['joint_states']
        out.append((DESIRED_TOPIC, js, M.joint_state(t_ns, s.names, st[:, 0], st[:, 1], st[:, 3])))
        out.append((ERROR_TOPIC, js, M.joint_state(t_ns, s.names, st[:, 0] - q[s.si[:, 1]], st[:, 1] - v[s.v_index],
                                                   st[:, 4])))
    if system.sensors is not None:
        qdd = system.sensor_accelerations(t, y, u, st)
        fext = None
        if system.contact is not None:
            fext = system.contact.body_forces(km, q, system.contact.point_outputs(km, q, v))
        out.extend(system.sensors.messages(km, t, q, v, qdd, fext))
    return out
