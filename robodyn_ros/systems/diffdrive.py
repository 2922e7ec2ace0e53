"""Voltage-driven differential-drive platform, alone or carrying an articulated arm (seed 001).

Coordinates and frames
----------------------
Generalised coordinates (all in one flat vector; ``nq = nv``)::

    q = [x, y, θ, φ_l, φ_r, q_arm...]        v = q̇                                (D1)

``(x, y)`` is the origin of ``base_link`` in ``odom`` and ``θ`` its yaw; ``base_link`` sits on
the ground at the midpoint between the two wheel contact points (x forward, y left, z up, REP
103/105). The wheels turn about ``+y`` of ``base_link``: the left wheel centre is at
``(0, +r_c, r_w)``, the right one at ``(0, −r_c, r_w)``; a positive wheel rate rolls forward
(a wheel spinning at ``φ̇`` about +y has its contact point moving at ``−r_w φ̇`` relative to
its centre along x). ``r_c`` is the half-track (the seed's "radius of the chassis"), ``r_w``
the wheel radius.

The dynamics tree (``self.model``, root frame ``odom``) is: two massless prismatic bodies
(``base_x``, ``base_y``), the chassis ``base_link`` on a revolute yaw joint ``base_yaw``, a fixed
``payload`` when one is given, the two wheels on revolute joints ``left_wheel_joint``,
``right_wheel_joint`` about +y, and, for the mobile manipulator, the arm's links hanging from
``base_link``. Gravity acts along −z: it loads the arm; the chassis–ground normal forces are not
modelled (the motion is planar: the root holds the chassis in the plane, and the reaction it
needs is reported as the ``base_plane`` wrench).

Mass matrix from first principles (platform without an articulated arm)
-----------------------------------------------------------------------
Each rigid part k on the chassis (chassis, payload, wheel hubs) has mass ``m_k``, centre of mass
``d_k`` (horizontal components, ``base_link`` coordinates) and yaw inertia ``I_k`` about its
centre of mass. Its centre moves at ``ṗ + θ̇ R(θ) E d_k`` with ``E = [[0, −1], [1, 0]]``, so::

    T = ½ m |ṗ|² + θ̇ ṗ·(R E S) + ½ J θ̇² + ½ I_s (φ̇_l² + φ̇_r²)                 (D2)

    m = Σ m_k = m_c + m_a + 2 m_w,     S = Σ m_k d_k,
    J = Σ (I_k + m_k |d_k|²) = I_c + m_c|d_c|² + I_a + m_a|d_a|² + 2 (I_d + m_w r_c²)

with ``I_s`` the wheel spin inertia (plus the reflected rotor inertia ``N² J_m``) and ``I_d`` its
diametral inertia (the wheel turns with the chassis about the vertical). The wheel's angular
velocity ``θ̇ e_z + φ̇ e_y`` has no cross term because e_y and e_z are principal axes. Hence::

    M = [[m I₂, R E S, 0], [(R E S)ᵀ, J, 0], [0, 0, I_s I₂]],
    h = [−θ̇² R S; 0; 0; 0]                (Coriolis/centrifugal; zero when S = 0)  (D3)

This is :meth:`DiffDriveSystem.planar_mass_matrix`; the tests check it against the CRBA of the
tree, which is what the mobile manipulator uses (``M = crba``, ``h = rnea(q, v, 0)``).

Where the seed has typos (corrected here from the derivation above)
------------------------------------------------------------------
* Eq. (49) ``ω_p = (v_l − v_r)/r_c``: the wheels are ``2 r_c`` apart and, with z up, a faster
  right wheel turns the platform left (positive), so ``ω_p = (v_r − v_l)/(2 r_c)``.
* Eq. (50), yaw term ``½ (I_c + I_a)(r_w ω_l/r_c − ½ r_w ω_r/r_c)²``: the factors and the sign
  are inconsistent; from (49) it is ``½ (I_c + I_a)(r_w (ω_r − ω_l)/(2 r_c))²``.
* Eq. (50) omits the wheels' rotation about the vertical axis (``I_d θ̇²`` per wheel, the ``I_d``
  term of ``J``); the wheels' ``m_w r_c² θ̇²`` is implicit in its ``½ m_w (r_w ω)²`` terms and is
  kept. Eq. (42) leaves out the wheel masses, which eq. (50) then adds (``m`` above).
* Eq. (54) ``R i = v − v_m`` is the armature circuit with back-EMF ``v_m = K ω`` (the seed's
  "rolling resistance" is the winding resistance); see :mod:`robodyn_ros.systems.motor`.
* Section 3.3.1 speaks of three degrees of freedom: the platform has a five-dimensional
  configuration (x, y, θ, φ_l, φ_r) but only two velocity degrees of freedom (the three
  constraints below).

Rolling constraints (nonholonomic) and ground forces
----------------------------------------------------
The contact point of wheel ``s`` (left: ``σ = +1``, right: ``σ = −1``) must not slip. In
``base_link`` axes (forward speed ``v_f = ẋ cos θ + ẏ sin θ``, lateral ``v_y = −ẋ sin θ + ẏ cos θ``)::

    longitudinal:  v_f − σ r_c θ̇ − r_w φ̇_s = 0        lateral:  v_y = 0          (D4)

Stacked as ``K(q) v = 0`` with rows ``[long_l, lat_l, long_r, lat_r]`` (4 × nv; the arm columns
are zero), and ``K̇ v = [θ̇ v_y, −θ̇ v_f, θ̇ v_y, −θ̇ v_f]``. Each row is the contact point's velocity
projected on a unit direction (the chassis heading, or its left normal), i.e. a row of the
contact Jacobian, so by the sign convention of :mod:`robodyn_ros.constraints`
(``M a = Q + Kᵀ λ``) the multipliers ``λ = [F_long_l, F_lat_l, F_long_r, F_lat_r]`` are the
horizontal forces the ground exerts on each wheel at its contact point (N, + forward / + left).
The two lateral rows are identical (both wheels sit on one axle line: the split of the lateral
force between them is statically indeterminate); :func:`~robodyn_ros.constraints.kkt_solve`
reports rank 3 of 4 and returns the minimum-norm multipliers, i.e. an equal split.

Drift of (D4) is removed after every step by the mass-orthogonal velocity projection in
:meth:`project` (positions are not constrained: the constraints are nonholonomic), which keeps
``‖K v‖∞`` at round-off; ``constraint_residual`` (m/s) in ``outputs.extra`` reports it. An
optional velocity-level Baumgarte term, ``K a = −K̇ v − α K v`` (``baumgarte_alpha``, 1/s),
makes the constraint manifold attractive between projections (e.g. for multistep solvers that
are projected once per call); it defaults to 0 because it adds a fast mode ``−α`` that an
explicit step must resolve: measured on the geared platform with RK4 at 10 ms over 5 s, α = 20
/s made the trajectory error 200 times larger (1.4e-6 against 6.8e-9 with projection alone).

Published wrenches (``outputs.wrenches``; only when ``wrenches=True``)
----------------------------------------------------------------------
* ``left_wheel_contact`` / ``right_wheel_contact``: frame ``<side>_wheel_contact``, a frame fixed
  to the chassis with its origin at the contact point and base_link's axes (x along the wheel's
  rolling direction, y along its axle, z up): ``[0, 0, 0, F_long, F_lat, 0]``. The normal force is
  not modelled (planar) and is reported as 0; a point contact transmits no torque.
* ``left_wheel_joint`` / ``right_wheel_joint`` and every arm joint: the wrench the parent body
  exerts on the child through the joint, in the child link frame (RNEA with the contact forces as
  external forces); its axis component is the joint torque.
* ``base_plane``: the wrench the ground plane (the unmodelled supports) exerts on ``base_link``
  to hold it in the plane, at the base_link origin in base_link axes. Its x, y force and z torque
  vanish (every horizontal force comes through the wheels); the z force is the total normal load.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial

import numpy as np

from .. import dynamics as dyn
from .. import kernels
from ..constraints import KKT_RCOND, SolveInfo, baumgarte_rhs, kkt_solve, null_space_basis
from ..model import LinkSpec, ModelError, build_model, to_urdf
from .base import (InputPort, LazyValues, LazyWrenches, System, SystemOutputs, compiled_fused_advance,
                   effort_actuation, keeps_methods, resolve_backend)
from .motor import DCMotor

__all__ = ['Body', 'PlatformParams', 'DiffDriveSystem', 'PLATFORM_LINKS', 'SIDES']

SIDES = ('left', 'right')
#: link names the platform uses (an arm mounted on it may not reuse them)
PLATFORM_LINKS = ('odom', 'base_x_link', 'base_y_link', 'base_link', 'chassis', 'payload', 'left_wheel',
                  'right_wheel', 'left_wheel_contact', 'right_wheel_contact')
#: relative tolerance on K v0 for an initial state to count as rolling without slip
INITIAL_STATE_TOL = 1e-9
_IX, _IY, _ITH, _IL, _IR = 0, 1, 2, 3, 4


@dataclass(frozen=True)
class Body:
    """A rigid part fixed to the chassis: mass (kg), yaw inertia (kg·m², about its centre of mass
    and the vertical) and centre of mass ``com`` (3,) in base_link (m). Its roll/pitch inertias
    do not enter planar motion; the URDF gets those of a thin plate (``Izz/2, Izz/2, Izz``)."""

    mass: float
    yaw_inertia: float
    com: tuple = (0.0, 0.0, 0.0)

    def inertia(self) -> np.ndarray:
        """3x3 inertia about the centre of mass (thin plate: Ixx = Iyy = Izz/2)."""
        return np.diag([0.5 * self.yaw_inertia, 0.5 * self.yaw_inertia, self.yaw_inertia])


@dataclass(frozen=True)
class PlatformParams:
    """Parameters of the platform (SI units; seed 001 values by default).

    chassis: the chassis body; payload: an optional rigid payload (the seed's arm as a rigid
    body: mass 0.4 kg, yaw inertia 0.975 kg·m²); wheel_radius r_w, half_track r_c (m);
    wheel_mass m_w; wheel_spin_inertia I_w (about the axle); wheel_diametral_inertia I_d (about
    a diameter; None = I_w/2, a thin disc); motors: (left, right) :class:`DCMotor`;
    baumgarte_alpha: velocity-level constraint stabilisation gain (1/s).
    """

    chassis: Body = Body(3.3, 0.18965, (0.0, 0.0, 0.28))
    payload: Body | None = Body(0.4, 0.975, (0.0, 0.0, 0.28))
    wheel_radius: float = 0.28
    half_track: float = 0.35
    wheel_mass: float = 0.3
    wheel_spin_inertia: float = 0.0037
    wheel_diametral_inertia: float | None = None
    motors: tuple = field(default_factory=lambda: (DCMotor(), DCMotor()))
    baumgarte_alpha: float = 0.0

    def __post_init__(self):
        for k in ('wheel_radius', 'half_track'):
            if not np.isfinite(getattr(self, k)) or getattr(self, k) <= 0.0:
                raise ValueError(f'{k}: must be a finite length > 0 m, got {getattr(self, k)!r}')
        for k in ('wheel_mass', 'wheel_spin_inertia', 'baumgarte_alpha'):
            if not np.isfinite(getattr(self, k)) or getattr(self, k) < 0.0:
                raise ValueError(f'{k}: must be finite and >= 0, got {getattr(self, k)!r}')
        for label, b in (('chassis', self.chassis), ('payload', self.payload)):
            if b is None:
                continue
            if not (np.isfinite(b.mass) and b.mass >= 0.0 and np.isfinite(b.yaw_inertia) and b.yaw_inertia >= 0.0):
                raise ValueError(f'{label}: mass and yaw_inertia must be finite and >= 0, got {b!r}')
            if len(b.com) != 3 or not np.all(np.isfinite(b.com)):
                raise ValueError(f'{label}: com must be 3 finite numbers, got {b.com!r}')
        if self.chassis.mass <= 0.0 or self.chassis.yaw_inertia <= 0.0:
            raise ValueError(f'chassis: mass and yaw_inertia must be > 0, got {self.chassis!r}')
        mr2 = self.wheel_mass * self.wheel_radius ** 2
        if self.wheel_spin_inertia > mr2 * (1.0 + 1e-12):
            raise ValueError(f'wheel_spin_inertia: {self.wheel_spin_inertia!r} kg·m² exceeds m_w r_w² = {mr2:.6g} '
                             'kg·m² (a thin ring); no wheel of that mass and radius has it')
        Id = self.diametral_inertia
        if not np.isfinite(Id) or 2.0 * Id < self.wheel_spin_inertia * (1.0 - 1e-12):
            raise ValueError(f'wheel_diametral_inertia: {Id!r} kg·m² is below half the spin inertia '
                             f'({0.5 * self.wheel_spin_inertia:.6g}); principal moments must obey the triangle inequality')
        if len(self.motors) != 2 or not all(isinstance(m, DCMotor) for m in self.motors):
            raise ValueError(f'motors: expected (left, right) DCMotor, got {self.motors!r}')

    @property
    def diametral_inertia(self) -> float:
        """Wheel inertia about a diameter (kg·m²)."""
        return 0.5 * self.wheel_spin_inertia if self.wheel_diametral_inertia is None else self.wheel_diametral_inertia


#: the methods whose DiffDriveSystem versions the compiled kernels reproduce
_COMPILED_METHODS = ('rhs', 'input_power', 'project', 'config_rate', 'electrical', 'generalized_forces', 'solve',
                     'mass_and_bias', 'constraint_jacobian', 'planar_mass_matrix', 'energies')
#: the methods ``dd_outputs`` also stands in for in :meth:`DiffDriveSystem.outputs`
_OUTPUTS_METHODS = _COMPILED_METHODS + ('contact_wrenches',)


def _computed(f):
    """The wrenches of one publication, already computed (``LazyWrenches.one``)."""
    return f


def _stacked(args):
    """The wrenches of K publications (K, n, 6) (``LazyWrenches.many``)."""
    return np.stack([a[0] for a in args])


class DiffDriveSystem(System):
    """Differential-drive platform with two DC motors, optionally carrying an articulated arm.

    params: :class:`PlatformParams`; arm_specs: LinkSpecs of an arm whose root-attached links
    hang from ``base_link`` (their origins already in base_link coordinates; ``None`` = no arm);
    arm_root: the name those specs use for their base frame; arm_actuated: arm joints driven by
    the ``effort`` port (default every 1-DOF arm joint); gravity: (3,) m/s² in odom; arm_root_visuals:
    the ``<visual>`` elements of an imported arm's root link, in base_link's frame (drawn on base_link by
    :meth:`urdf`); backend: ``'numpy'`` (the methods below, the reference) or ``'numba'``
    (``'generated'`` is taken as numba): :mod:`robodyn_ros.kernels.diffdrive` evaluates the right-hand
    side, projection and constrained solve (equal to 1e-12), :meth:`fused_advance` runs whole periods of fixed steps
    in one call and :meth:`outputs` is one call of ``dd_outputs`` (the numbers of the numpy
    method to round-off); default
    :func:`robodyn_ros.systems.base.default_backend`.

    State ``y = [q (nv), v (nv), i (n_L)]`` with q, v as in (D1) and one current per motor with
    ``L > 0`` (left first). Inputs: ``wheel_voltage`` ``[left, right]`` (V) and, with an arm
    that has actuated joints, ``effort`` (one per actuated arm joint).
    """

    def rebuilt(self, backend):
        """The same platform (and arm) built again on another ``backend``."""
        return DiffDriveSystem(self.params, arm_specs=self.arm_specs or None, arm_root=self.arm_root,
                               arm_actuated=self.actuated, gravity=tuple(self.model.gravity), name=self.model.name,
                               backend=backend, arm_root_visuals=self.arm_root_visuals)

    def __init__(self, params: PlatformParams | None = None, arm_specs=None, arm_root='base_link',
                 arm_actuated=None, gravity=(0.0, 0.0, -9.81), name='diff_drive', backend=None,
                 arm_root_visuals=()):
        self.backend = resolve_backend(backend)
        self.params = p = params or PlatformParams()
        self.motors = tuple(p.motors)
        self.has_arm = bool(arm_specs)
        self.arm_specs, self.arm_root = list(arm_specs or []), arm_root  # as given (rebuild with another backend)
        self.arm_root_visuals = tuple(arm_root_visuals)   # an imported arm's root link, drawn on base_link
        specs = self._platform_specs(p, dynamic=True)
        arm = self._rehome_arm(arm_specs or [], arm_root)
        self.model = build_model(specs + arm, gravity=gravity, name=name, root='odom')
        self.urdf_model = build_model(self._platform_specs(p, dynamic=False) + arm, gravity=gravity, name=name,
                                      root='base_link', mounted_visuals=(('base_link', self.arm_root_visuals),)
                                      if self.arm_root_visuals else ())
        m = self.model
        self.nv = m.nv
        self.nq = m.nv
        assert m.nq == m.nv
        for k, link in ((_IX, 'base_x_link'), (_IY, 'base_y_link'), (_ITH, 'base_link'), (_IL, 'left_wheel'),
                        (_IR, 'right_wheel')):
            assert m.v_idx[m.body(link)] == k, (link, m.v_idx[m.body(link)])
        self.arm_joint_names = [n for n in m.dof_joint_names if n not in
                                ('base_x', 'base_y', 'base_yaw', 'left_wheel_joint', 'right_wheel_joint')]
        self.joint_names = ['left_wheel_joint', 'right_wheel_joint'] + self.arm_joint_names
        #: names of the entries of q (and v): the planar pose, the wheels, the arm joints
        self.coordinate_names = ['x', 'y', 'yaw'] + self.joint_names
        self._arm_idx = np.array([m.v_idx[m.joint_names.index(n)] for n in self.arm_joint_names], dtype=int)
        self._pub_idx = np.concatenate([[_IL, _IR], self._arm_idx]).astype(np.int64)
        actuated, self.B, effort_port = effort_actuation(m, self.arm_joint_names, arm_actuated, 'arm joints')
        self.actuated = actuated  # arm actuation: tau = B u['effort']
        self._has_effort = self.B.shape[1] > 0
        self._cur = [k for k, mot in enumerate(self.motors) if mot.has_current_state]
        self.n_current = len(self._cur)
        self.ny = 2 * self.nv + self.n_current
        self.inputs = {'wheel_voltage': InputPort('wheel_voltage', 2, SIDES, 'V')}
        if actuated:
            self.inputs['effort'] = effort_port
        self._armature = np.zeros(self.nv)
        self._armature[[_IL, _IR]] = [mot.reflected_inertia for mot in self.motors]
        self._wheels = (m.body('left_wheel'), m.body('right_wheel'))
        compiled = self.backend != 'numpy'
        self._km = kernels.CompiledModel(m) if compiled else None  # CRBA/RNEA/wrenches of the tree
        self._zero_v = np.zeros(self.nv)
        self._zero_uv = np.zeros(2 + self.nv)   # the kernels' input vector of zero_inputs() (never written)
        self._planar_inertia()
        self._cs = self._pack() if compiled else None
        self._grids = {}
        # published wrenches: the contacts, then every body but the planar virtual ones (the yaw
        # joint's wrench is the ground plane's, see the module docstring); their rows in the RNEA
        self._wrench_bodies = np.array([i for i in range(m.nb) if m.joint_names[i] not in ('base_x', 'base_y')],
                                       dtype=np.int64)
        self._wrench_names = tuple([f'{side}_wheel_contact' for side in SIDES] + [
            'base_plane' if m.joint_names[i] == 'base_yaw' else m.joint_names[i] for i in self._wrench_bodies])
        self._wrench_frames = tuple([f'{side}_wheel_contact' for side in SIDES] +
                                    [m.link_names[i] for i in self._wrench_bodies])
        self._wheel_bodies = np.array(self._wheels, dtype=np.int64)
        self._wrench_index = {n: k for k, n in enumerate(self._wrench_names)}
        if compiled:   # where dd_outputs' blocks start in its output
            c, n = kernels.diffdrive, len(self._pub_idx)
            self._out_blocks = (n, 3 * n, 3 * n + c.DO_ODOM, 3 * n + c.DO_ODOM + c.NDR,
                                3 * n + c.DO_ODOM + c.NDR + c.DO_NEXTRA)

    def _pack(self):
        """The packed system for :mod:`robodyn_ros.kernels.diffdrive` (layout ``DIFFDRIVE``)."""
        p = self.params
        cur = [self._cur.index(k) if k in self._cur else -1 for k in range(2)]
        ip = [self.nv, int(self.has_arm), cur[0], cur[1], int(self.B.shape[1] > 0)]
        fp = [p.wheel_radius, p.half_track, p.baumgarte_alpha, self._m, self._S[0], self._S[1], self._J,
              self._Is[0], self._Is[1], KKT_RCOND]
        for mot in self.motors:
            fp += [mot.torque_constant, mot.resistance, mot.inductance, mot.gear_ratio, mot.viscous_friction,
                   mot.coulomb_friction, mot.coulomb_velocity, mot.supply_voltage]
        fp += list(self._armature) + list(self.model.damping.astype(float))
        return kernels.CompiledSystem(kernels.fixed_step.DIFFDRIVE, ip, fp, self.model, self.nq)

    def _compiled(self):
        """The packed system when the compiled path stands in for this object's methods, else None."""
        if self._cs is None or self._km is None or not keeps_methods(self, DiffDriveSystem, _COMPILED_METHODS):
            return None
        return self._cs

    def _u_vec(self, u):
        """Input vector of the kernels: ``[V_left, V_right, B u_effort (nv)]``."""
        uv = np.zeros(2 + self.nv)
        uv[:2] = u['wheel_voltage']
        if self._has_effort:
            uv[2:] = self.B @ u['effort']
        return uv

    def fused_advance(self, integrator_name, dt, t0, z0, t1, u):
        """Integrate ``z = [y, W]`` from t0 to t1 in one compiled call, or None to decline.

        The Simulator's fast path (see ``ArmSystem.fused_advance``): the same fixed-step method,
        step grid, velocity projection after every step and work quadrature as the reference path
        with :meth:`rhs`, :meth:`input_power` and :meth:`project`. Declines on the numpy backend,
        for error-controlled integrators and when a method was overridden.
        """
        cs = self._compiled()
        if cs is None:
            return None
        return compiled_fused_advance(cs, self._grids, integrator_name, dt, t0, z0, t1, self._u_vec(u), self.ny)

    # -- construction ----------------------------------------------------------------------
    @staticmethod
    def _platform_specs(p: PlatformParams, dynamic: bool):
        """LinkSpecs of the platform: with the planar virtual joints (dynamic tree, root odom) or
        rooted at base_link with the chassis as a fixed link and the contact frames (URDF)."""
        rw, rc = p.wheel_radius, p.half_track
        Iw = np.diag([p.diametral_inertia, p.wheel_spin_inertia, p.diametral_inertia])
        out = []
        if dynamic:
            out += [LinkSpec('base_x_link', 'base_x', None, 'prismatic', axis=(1.0, 0.0, 0.0)),
                    LinkSpec('base_y_link', 'base_y', 'base_x_link', 'prismatic', axis=(0.0, 1.0, 0.0)),
                    LinkSpec('base_link', 'base_yaw', 'base_y_link', 'revolute', axis=(0.0, 0.0, 1.0),
                             mass=p.chassis.mass, com=tuple(p.chassis.com), inertia=p.chassis.inertia())]
        else:
            out.append(LinkSpec('chassis', 'chassis_joint', 'base_link', 'fixed', mass=p.chassis.mass,
                                com=tuple(p.chassis.com), inertia=p.chassis.inertia()))
        if p.payload is not None and p.payload.mass > 0.0:
            out.append(LinkSpec('payload', 'payload_joint', 'base_link', 'fixed', mass=p.payload.mass,
                                com=tuple(p.payload.com), inertia=p.payload.inertia()))
        for side, sigma in zip(SIDES, (1.0, -1.0)):
            out.append(LinkSpec(f'{side}_wheel', f'{side}_wheel_joint', 'base_link', 'revolute',
                                origin_xyz=(0.0, sigma * rc, rw), axis=(0.0, 1.0, 0.0), mass=p.wheel_mass,
                                inertia=Iw))
        if not dynamic:
            for side, sigma in zip(SIDES, (1.0, -1.0)):
                out.append(LinkSpec(f'{side}_wheel_contact', f'{side}_wheel_contact_joint', 'base_link', 'fixed',
                                    origin_xyz=(0.0, sigma * rc, 0.0)))
        return out

    @staticmethod
    def _rehome_arm(arm_specs, arm_root):
        """Copies of the arm's LinkSpecs with root-attached links hung from base_link."""
        from dataclasses import replace
        clash = sorted({s.name for s in arm_specs} & set(PLATFORM_LINKS) - {arm_root})
        if clash:
            raise ModelError(f'arm links {clash} clash with the platform links {list(PLATFORM_LINKS)}')
        return [replace(s, parent='base_link') if s.parent in (None, arm_root) else replace(s) for s in arm_specs]

    def _planar_inertia(self):
        """Sums of (D2): total mass m, first moment S (2,), yaw inertia J, wheel spin inertia."""
        p = self.params
        bodies = [(p.chassis.mass, p.chassis.yaw_inertia, np.asarray(p.chassis.com[:2], float))]
        if p.payload is not None and p.payload.mass > 0.0:
            bodies.append((p.payload.mass, p.payload.yaw_inertia, np.asarray(p.payload.com[:2], float)))
        for sigma in (1.0, -1.0):
            bodies.append((p.wheel_mass, p.diametral_inertia, np.array([0.0, sigma * p.half_track])))
        self._m = sum(b[0] for b in bodies)
        self._S = sum(b[0] * b[2] for b in bodies)
        self._J = sum(b[1] + b[0] * float(b[2] @ b[2]) for b in bodies)
        self._Is = p.wheel_spin_inertia + self._armature[[_IL, _IR]]

    # -- state -----------------------------------------------------------------------------
    def split(self, y):
        """Views ``(q, v)`` of the state vector (nv each)."""
        return y[:self.nv], y[self.nv:2 * self.nv]

    def currents_state(self, y):
        """The current states (n_current,) (A); empty when every motor has L = 0."""
        return y[2 * self.nv:]

    def initial_state(self, q0=None, v0=None, i0=None):
        """State vector from q0 (nv,), v0 (nv,) (zeros by default) and currents i0 (n_current,).

        Raises ValueError when v0 violates the rolling constraints (D4) (the message gives the
        wheel rates that would roll without slip).
        """
        y = np.zeros(self.ny)
        if q0 is not None:
            y[:self.nv] = q0
        if v0 is not None:
            y[self.nv:2 * self.nv] = v0
        if i0 is not None:
            y[2 * self.nv:] = i0
        q, v = self.split(y)
        K, _ = self.constraint_jacobian(q, v)
        e = K @ v
        if np.abs(e).max() > INITIAL_STATE_TOL * (1.0 + np.abs(v).max()):
            th = q[_ITH]
            vf = np.cos(th) * v[_IX] + np.sin(th) * v[_IY]
            rw, rc = self.params.wheel_radius, self.params.half_track
            raise ValueError(
                f'initial velocity violates rolling without slip (residual {np.abs(e).max():.3g} m/s): lateral '
                f'speed must be 0 and the wheel rates must be φ̇_l = {(vf - rc * v[_ITH]) / rw:.6g}, '
                f'φ̇_r = {(vf + rc * v[_ITH]) / rw:.6g} rad/s for this chassis velocity')
        return y

    def project(self, y):
        """Mass-orthogonal projection of the velocities onto ``K(q) v = 0`` (in place)."""
        cs = self._compiled()
        if cs is not None:
            return cs.project(y) if y.flags.c_contiguous and y.dtype == np.float64 else \
                cs.project(np.ascontiguousarray(y, dtype=np.float64))
        q, v = self.split(y)
        K, _ = self.constraint_jacobian(q, v)
        if np.abs(K @ v).max() > 0.0:
            M, _ = self.mass_and_bias(q, v, bias=False)
            from scipy.linalg import cho_factor, cho_solve   # numpy backend only
            c = cho_factor(M)
            MinvKt = cho_solve(c, K.T)
            dl = np.linalg.lstsq(K @ MinvKt, K @ v, rcond=KKT_RCOND)[0]
            y[self.nv:2 * self.nv] = v - MinvKt @ dl
        return y

    # -- dynamics ----------------------------------------------------------------------------
    def planar_mass_matrix(self, theta):
        """First-principles mass matrix (D3) of the platform without an articulated arm (5, 5)."""
        c, s = np.cos(theta), np.sin(theta)
        RES = np.array([c * -self._S[1] - s * self._S[0], s * -self._S[1] + c * self._S[0]])  # R E S
        M = np.zeros((5, 5))
        M[0, 0] = M[1, 1] = self._m
        M[0:2, 2] = M[2, 0:2] = RES
        M[2, 2] = self._J
        M[3, 3], M[4, 4] = self._Is
        return M

    def mass_and_bias(self, q, v, bias=True):
        """``(M (nv, nv), h (nv,))``: (D3) without an arm, CRBA/RNEA with one (+ rotor inertia)."""
        if not self.has_arm:
            M = self.planar_mass_matrix(q[_ITH])
            if not bias:
                return M, None
            c, s = np.cos(q[_ITH]), np.sin(q[_ITH])
            h = np.zeros(5)
            h[0:2] = -v[_ITH] ** 2 * np.array([c * self._S[0] - s * self._S[1], s * self._S[0] + c * self._S[1]])
            return M, h
        if self._km is not None:
            M = self._km.crba(q) + np.diag(self._armature)
            return M, (self._km.rnea(q, v, self._zero_v) if bias else None)
        M = dyn.crba(self.model, q) + np.diag(self._armature)
        return M, (dyn.bias_forces(self.model, q, v) if bias else None)

    def constraint_jacobian(self, q, v):
        """``(K (4, nv), K̇ v (4,))`` of the rolling constraints (D4), rows [long_l, lat_l, long_r, lat_r]."""
        rw, rc = self.params.wheel_radius, self.params.half_track
        c, s = np.cos(q[_ITH]), np.sin(q[_ITH])
        K = np.zeros((4, self.nv))
        K[0, [_IX, _IY, _ITH, _IL]] = (c, s, -rc, -rw)
        K[1, [_IX, _IY]] = (-s, c)
        K[2, [_IX, _IY, _ITH, _IR]] = (c, s, rc, -rw)
        K[3, [_IX, _IY]] = (-s, c)
        vf = c * v[_IX] + s * v[_IY]
        vy = -s * v[_IX] + c * v[_IY]
        w = v[_ITH]
        return K, np.array([w * vy, -w * vf, w * vy, -w * vf])

    def electrical(self, y, u):
        """Motor quantities at state y: ``(v_applied (2,), i (2,), torque on the wheels (2,))``."""
        _, v = self.split(y)
        volts = np.array([mot.applied_voltage(x) for mot, x in zip(self.motors, u['wheel_voltage'])], dtype=float)
        w = v[[_IL, _IR]]
        i = np.empty(2)
        ic = self.currents_state(y)
        for k, mot in enumerate(self.motors):
            i[k] = ic[self._cur.index(k)] if mot.has_current_state else mot.current(volts[k], w[k])
        tau = np.array([mot.output_torque(i[k], w[k]) for k, mot in enumerate(self.motors)])
        return volts, i, tau

    def generalized_forces(self, y, u, tau_wheels=None):
        """Applied generalised forces (nv,): motor torques on the wheels, arm efforts, arm damping."""
        _, v = self.split(y)
        if tau_wheels is None:
            tau_wheels = self.electrical(y, u)[2]
        Q = dyn.passive_forces(self.model, v)
        Q[[_IL, _IR]] += tau_wheels
        if self.B.shape[1]:
            Q += self.B @ u['effort']
        return Q

    def solve(self, y, u, electrical=None):
        """Constrained accelerations and ground forces at state y.

        Returns ``(a (nv,), λ (4,) = [F_long_l, F_lat_l, F_long_r, F_lat_r] (N), SolveInfo)`` of
        ``M a = Q − h + Kᵀ λ``, ``K a = −K̇ v − α K v`` (see the module docstring).
        """
        cs = self._compiled()
        if cs is not None:
            a, lam, info, el = np.empty(self.nv), np.empty(4), np.empty(kernels.linalg.NINFO), np.empty(6)
            if kernels.diffdrive.dd_solve(cs.ip, cs.fp, cs.km.mi_r, cs.km.mf_r, self._u_vec(u),
                                            np.ascontiguousarray(y, dtype=np.float64), True, a, lam, info, el):
                raise np.linalg.LinAlgError('mass matrix is not positive definite')
            return a, lam, SolveInfo(m=4, rank=int(info[0]), sigma_min=float(info[1]), sigma_max=float(info[2]),
                                     residual=float(info[3]))
        q, v = self.split(y)
        if electrical is None:
            electrical = self.electrical(y, u)
        M, h = self.mass_and_bias(q, v)
        K, Kdv = self.constraint_jacobian(q, v)
        k = baumgarte_rhs(-Kdv, phidot=K @ v, alpha=self.params.baumgarte_alpha)
        return kkt_solve(M, self.generalized_forces(y, u, electrical[2]) - h, K, k)

    def rhs(self, t, y, u):
        """``[q̇; v̇; di/dt]`` (all NaN for a non-finite state: the integrator's guard reports it)."""
        cs = self._compiled()
        if cs is not None:
            return cs.evaluate(t, y, self._u_vec(u))[:self.ny]
        if not np.all(np.isfinite(y)):
            return np.full(self.ny, np.nan)
        _, v = self.split(y)
        el = self.electrical(y, u)
        a, _, _ = self.solve(y, u, el)
        out = np.empty(self.ny)
        out[:self.nv] = v
        out[self.nv:2 * self.nv] = a
        volts, i, _ = el
        w = v[[_IL, _IR]]
        for n, k in enumerate(self._cur):
            out[2 * self.nv + n] = self.motors[k].current_rate(volts[k], i[k], w[k])
        return out

    # -- outputs -----------------------------------------------------------------------------
    def contact_wrenches(self, y, u, a, lam):
        """Joint and contact wrenches ``{name: (frame, (6,) [torque; force])}`` (module docstring).

        a, lam: accelerations and multipliers from :meth:`solve`. The contact forces enter the
        RNEA as external forces on the wheels, so the joint wrenches see them.
        """
        if self._compiled() is not None:
            nv = self.nv
            y = np.ascontiguousarray(y, dtype=np.float64)
            f = np.empty((len(self._wrench_names), 6))
            kernels.diffdrive.dd_contact_wrenches(
                self._cs.fp, self._km.mi, self._km.mf, y[:nv], y[nv:2 * nv], np.ascontiguousarray(a, dtype=np.float64),
                np.ascontiguousarray(lam, dtype=np.float64), self._wrench_bodies, self._wheel_bodies, f)
            return dict(zip(self._wrench_names, zip(self._wrench_frames, f)))
        q, v = self.split(y)
        m = self.model
        R, p = dyn.body_poses(m, q)
        th = q[_ITH]
        heading = np.array([np.cos(th), np.sin(th), 0.0])
        left = np.array([-np.sin(th), np.cos(th), 0.0])
        f_ext = np.zeros((m.nb, 6))
        out = {}
        for k, (side, b) in enumerate(zip(SIDES, self._wheels)):
            F_long, F_lat = lam[2 * k], lam[2 * k + 1]
            F = F_long * heading + F_lat * left
            r = np.array([0.0, 0.0, -self.params.wheel_radius])  # contact point - wheel centre (odom)
            rxF = np.array([r[1] * F[2] - r[2] * F[1], r[2] * F[0] - r[0] * F[2], r[0] * F[1] - r[1] * F[0]])
            f_ext[b, :3] = R[b].T @ rxF  # r × F (np.cross costs ~25 µs of dispatch here)
            f_ext[b, 3:] = R[b].T @ F
            out[f'{side}_wheel_contact'] = (f'{side}_wheel_contact', np.array([0.0, 0.0, 0.0, F_long, F_lat, 0.0]))
        _, f = dyn.rnea_wrenches(m, q, v, a, f_ext)
        for i in range(m.nb):
            jn = m.joint_names[i]
            if jn in ('base_x', 'base_y'):
                continue
            out['base_plane' if jn == 'base_yaw' else jn] = (m.link_names[i], f[i].copy())
        return out

    def outputs(self, t, y, u, wrenches=True):
        """Joint states (wheels first), odometry, motor diagnostics and (optionally) wrenches."""
        if self._cs is not None and keeps_methods(self, DiffDriveSystem, _OUTPUTS_METHODS):
            return self._compiled_outputs(self._cs, y, u, wrenches)
        q, v = self.split(y)
        el = self.electrical(y, u)
        volts, i, tau = el
        friction = [mot.friction_loss(wk) for mot, wk in zip(self.motors, v[[_IL, _IR]])]
        arm_effort = (self.B @ u['effort'])[self._arm_idx] if self.B.shape[1] else np.zeros(len(self._arm_idx))
        effort = np.concatenate([tau, arm_effort])
        th = q[_ITH]
        c, s = np.cos(th), np.sin(th)
        odom = {'position': np.array([q[_IX], q[_IY], 0.0]),
                'orientation': np.array([0.0, 0.0, np.sin(0.5 * th), np.cos(0.5 * th)]),
                'linear': np.array([c * v[_IX] + s * v[_IY], -s * v[_IX] + c * v[_IY], 0.0]),
                'angular': np.array([0.0, 0.0, v[_ITH]])}
        extra = {}
        for k, side in enumerate(SIDES):
            extra[f'{side}_motor_voltage'] = float(volts[k])
            extra[f'{side}_motor_current'] = float(i[k])
            extra[f'{side}_motor_power'] = float(volts[k] * i[k])
            extra[f'{side}_motor_torque'] = float(tau[k])
            extra[f'{side}_motor_friction_loss'] = float(friction[k])
        extra['electrical_power'] = float(volts @ i)
        extra['copper_loss'] = float(sum(mot.resistance * x * x for mot, x in zip(self.motors, i)))
        extra['voltage_saturated'] = bool(np.any(volts != np.asarray(u['wheel_voltage'], dtype=float)))
        K, _ = self.constraint_jacobian(q, v)
        extra['constraint_residual'] = float(np.abs(K @ v).max())
        wr = {}
        if wrenches:
            a, lam, info = self.solve(y, u, el)
            wr = self.contact_wrenches(y, u, a, lam)
            extra['constraint_rank'] = int(info.rank)
        return SystemOutputs(joint_names=list(self.joint_names), position=q[self._pub_idx].copy(),
                             velocity=v[self._pub_idx].copy(), effort=effort, wrenches=wr, odom=odom,
                             energy=self.energies(y), extra=extra)

    #: names of the ``extra`` values of :meth:`outputs` in the order of ``dd_outputs``' block
    _EXTRA_NAMES = tuple(f'{side}_motor_{k}' for side in SIDES for k in
                         ('voltage', 'current', 'power', 'torque', 'friction_loss')) + (
        'electrical_power', 'copper_loss', 'voltage_saturated', 'constraint_residual')

    def _compiled_outputs(self, cs, y, u, wrenches):
        """:meth:`outputs` on the compiled path: one call of ``kernels.diffdrive.dd_outputs``
        fills one array; the published arrays are views of it."""
        n, o, r, e, w = self._out_blocks   # joint states, odometry, report, extra values, wrenches
        nw = len(self._wrench_names) if wrenches else 0
        out = np.empty(w + 6 * nw)
        if kernels.diffdrive.dd_outputs(cs.ip, cs.fp, *cs.tree, self._u_vec(u), np.ascontiguousarray(y, dtype=np.float64),
                                          self._pub_idx, bool(wrenches), self._wrench_bodies, self._wheel_bodies, out):
            raise np.linalg.LinAlgError('mass matrix is not positive definite')
        ex = out[e:w].tolist()
        extra = dict(zip(self._EXTRA_NAMES, ex))
        extra['voltage_saturated'] = ex[12] != 0.0
        wr = {}
        if wrenches:   # computed with the diagnostics (their rank is one), copied K periods at once by a recorder
            extra['constraint_rank'] = int(ex[14])
            wr = LazyWrenches(self._wrench_names, self._wrench_frames, _computed, _stacked,
                              (out[w:].reshape(nw, 6),), self._wrench_index)
        odom = {'position': out[o:o + 3], 'orientation': out[o + 3:o + 7], 'linear': out[o + 7:o + 10],
                'angular': out[o + 10:o + 13]}
        return SystemOutputs(joint_names=list(self.joint_names), position=out[:n], velocity=out[n:2 * n],
                             effort=out[2 * n:o], wrenches=wr, odom=odom,
                             energy=LazyValues(partial(self._report_energies, out[r:e])), extra=extra)

    def _report(self, y, uv):
        """:func:`robodyn_ros.kernels.diffdrive.dd_report` of state y under the kernels' input
        vector uv (compiled path)."""
        cs = self._cs
        out = np.empty(kernels.diffdrive.NDR)
        kernels.diffdrive.dd_report(cs.ip, cs.fp, cs.km.mi_r, cs.km.mf_r, uv, np.ascontiguousarray(y, dtype=np.float64),
                                      out)
        return out

    @staticmethod
    def _report_energies(report):
        c = kernels.diffdrive
        return {'kinetic': float(report[c.DR_KINETIC]), 'potential': float(report[c.DR_POTENTIAL]),
                'magnetic': float(report[c.DR_MAGNETIC])}

    # -- energy ------------------------------------------------------------------------------
    def energies(self, y):
        """``{'kinetic', 'potential', 'magnetic'}`` (J); kinetic includes the rotor inertia."""
        if self._compiled() is not None:   # (the energies do not depend on the inputs)
            return self._report_energies(self._report(y, self._zero_uv))
        q, v = self.split(y)
        M, _ = self.mass_and_bias(q, v, bias=False)
        ic = self.currents_state(y)
        mag = sum(0.5 * self.motors[k].inductance * ic[n] ** 2 for n, k in enumerate(self._cur))
        if not self.has_arm:
            pot = 0.0
        elif self._km is not None:
            pot = self._km.energies(q, v)[1]
        else:
            pot = dyn.potential_energy(self.model, q)
        return {'kinetic': 0.5 * float(v @ M @ v), 'potential': float(pot), 'magnetic': float(mag)}

    def total_energy(self, y):
        """Kinetic + gravitational (arm) + magnetic energy (J); the chassis height is constant."""
        return float(sum(self.energies(y).values()))

    def input_power(self, t, y, u):
        """``Σ (v i − R i² − friction loss)`` + arm effort power − arm damping (W)."""
        _, v = self.split(y)
        volts, i, _ = self.electrical(y, u)
        w = v[[_IL, _IR]]
        P = sum(mot.input_power(volts[k], i[k], w[k]) for k, mot in enumerate(self.motors))
        P += float(v @ dyn.passive_forces(self.model, v))
        if self.B.shape[1]:
            P += float(v @ (self.B @ u['effort']))
        return float(P)

    def fastest_time_constant(self, y):
        """Fastest time constant (s): the electrical ``L/R`` of motors with L > 0, the
        mechanical ones of the constrained motion under the back-EMF (L = 0), friction-slope and
        joint damping (generalised eigenvalues of the reduced damping and mass matrices), and
        ``1/α`` of a Baumgarte term."""
        q, v = self.split(y)
        taus = [mot.electrical_time_constant for mot in self.motors if mot.has_current_state]
        D = np.diag(self.model.damping.astype(float))
        for k, (mot, j) in enumerate(zip(self.motors, (_IL, _IR))):
            D[j, j] += mot.friction_slope(v[j]) + (0.0 if mot.has_current_state else mot.electrical_damping())
        K, _ = self.constraint_jacobian(q, v)
        C, _ = null_space_basis(K)
        M, _ = self.mass_and_bias(q, v, bias=False)
        L = np.linalg.cholesky(C.T @ M @ C)   # generalised eigenvalues of (CᵀDC, CᵀMC): those of
        Li = np.linalg.inv(L)                 # L⁻¹ CᵀDC L⁻ᵀ with CᵀMC = L Lᵀ
        mu = np.linalg.eigvalsh(Li @ (C.T @ D @ C) @ Li.T)
        if mu.max() > 0.0:
            taus.append(1.0 / mu.max())
        if self.params.baumgarte_alpha > 0.0:
            taus.append(1.0 / self.params.baumgarte_alpha)
        return float(min(taus)) if taus else float('inf')

    def passive_jacobian(self, t, y, u, h=None):
        """J (ny, ny) of the linearly implicit step at y (``System.passive_jacobian``; the compiled loop,
        ``kernels.diffdrive.dd_rosenbrock_step``, solves its stages as KKT systems instead): ``q̇ = v``; the
        passive damping D (joint damping, the motors' friction slopes, the back-EMF damping of L = 0
        motors) through the constrained mobility ``Y = M⁻¹ − M⁻¹Kᵀ (K M⁻¹ Kᵀ)⁺ K M⁻¹``, ``J_vv = −Y D``; and
        the L > 0 motors' electrics with their coupling, ``J_vi = Y N K e_ω``, ``J_iω = −N K/L``, ``J_ii = −R/L``."""
        q, v = self.split(np.asarray(y, dtype=float))
        nv = self.nv
        M, _ = self.mass_and_bias(q, v, bias=False)
        K, _ = self.constraint_jacobian(q, v)
        D = np.diag(self.model.damping.astype(float))
        for mot, j in zip(self.motors, (_IL, _IR)):
            D[j, j] += mot.friction_slope(v[j]) + (0.0 if mot.has_current_state else mot.electrical_damping())
        Minv = np.linalg.inv(M)
        Y = Minv - Minv @ K.T @ np.linalg.pinv(K @ Minv @ K.T) @ K @ Minv
        J = np.zeros((self.ny, self.ny))
        J[:nv, nv:2 * nv] = np.eye(nv)
        J[nv:2 * nv, nv:2 * nv] = -Y @ D
        for n, k in enumerate(self._cur):
            mot, j, c = self.motors[k], (_IL, _IR)[k], 2 * nv + n
            NK = mot.gear_ratio * mot.torque_constant
            J[nv:2 * nv, c] = Y[:, j] * NK
            J[c, nv + j] = -NK / mot.inductance
            J[c, c] = -mot.resistance / mot.inductance
        return J

    def explicit_time_constant(self, y):
        """``1/α`` of a Baumgarte term (not in :meth:`passive_jacobian`), else inf: the motors' L/R and the
        damping are passive."""
        a = self.params.baumgarte_alpha
        return 1.0 / a if a > 0.0 else float('inf')

    def urdf(self):
        """URDF rooted at base_link (chassis, payload, wheels, contact frames, arm)."""
        return to_urdf(self.urdf_model)
