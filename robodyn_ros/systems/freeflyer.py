"""A free-flying base carrying an arm (seed 003, Unfried, da Fonseca & Goes 2016), minimal coordinates.

The platform is body 0 of a :class:`~robodyn_ros.model.Model` whose root joint is FREE
(``q = [p (3) in odom, quaternion (x, y, z, w)]``, ``v = [ω; v_O]`` body twist in base_link
coordinates); the arm hangs from it. The recursive algorithms of :mod:`robodyn_ros.dynamics`
handle the 6-DOF joint generically, so in orbit the minimal formulation is just ABA with the
thruster wrench as ``f_ext`` on the base.

Environments (``ENVIRONMENTS``):

* ``orbit`` — zero gravity, no constraint: 6 + n degrees of freedom.
* ``free_fall`` — as orbit, but under the scene's gravity (no ground contact: the robot falls);
  an imported floating-base URDF (``kind: urdf, floating: true``) runs in it.
* ``air_bearing_table`` — gravity on, the platform floats on a horizontal table. We impose
  **three** holonomic constraints on the free joint (:func:`table_rows`): the height of the
  base_link origin, and roll = pitch = 0 (the platform's z axis stays vertical), leaving
  x, y, yaw + n DOF. The seed counts one constraint (the height) and 10 DOF; but a platform
  held only at one height can tip about any horizontal axis, and with gravity on and the arm's
  centre of mass off the platform's centre it would topple. Air-bearing pads resist tilting
  with a pressure distribution whose resultant is the normal force *and* two tilting moments;
  those are the three multipliers, published as ``constraint_wrenches/base_plane``.

The table constraints are solved with :func:`robodyn_ros.constraints.kkt_solve` and held with
Baumgarte stabilisation (gains ``alpha``, ``beta``, defaults
``constraints.BAUMGARTE_ALPHA/BETA``), optionally followed after every accepted step by a
projection (``stabilisation='projection'``): the exact position correction of the table
constraints plus the mass-weighted velocity projection of
:func:`robodyn_ros.constraints.project_velocities`.

Outputs follow GUIDE §2: ``odom`` (pose of base_link in odom; twist = base_link's linear and
angular velocity in base_link), ``joint_states`` (arm joints), ``constraint_wrenches/<joint>``
(the wrench the parent exerts on the child at the joint origin in child coordinates,
[torque; force]) and, on the table, ``base_plane`` (the table's wrench on base_link at the
base_link origin, in base_link coordinates). ``extra`` holds the momentum about the centre of
mass, the centre of mass and the constraint residuals. The augmented (extended-coordinate)
formulation of the same system is :mod:`robodyn_ros.systems.augmented`.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np

from .. import constraints as con
from .. import dynamics as dyn
from .. import kernels
from ..model import FREE, LinkSpec, Model, ModelError, build_model, to_urdf
from ..spatial import quat_to_R, skew
from .base import (InputPort, System, SystemOutputs, compiled_fused_advance, effort_actuation, keeps_methods,
                   resolve_backend)

__all__ = ['ENVIRONMENTS', 'STABILISATIONS', 'FORMULATIONS', 'FreeFlyerSystem', 'free_flyer_model',
           'table_rows', 'level_quaternion', 'free_base_urdf', 'momentum_about_com', 'BASE_WRENCH_LABELS']

ENVIRONMENTS = ('orbit', 'air_bearing_table', 'free_fall')
STABILISATIONS = ('baumgarte', 'projection', 'none')
FORMULATIONS = ('minimal', 'augmented')
#: element order of the ``base_wrench`` port (messages.PORT_TOPICS: base_wrench_command), base_link axes
BASE_WRENCH_LABELS = ('fx', 'fy', 'fz', 'tx', 'ty', 'tz')
_EZ = np.array([0.0, 0.0, 1.0])


def _cross(a, b):
    """``a × b`` of two 3-vectors (numpy.cross costs ~50 µs per call on small vectors)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def free_flyer_model(base: LinkSpec, arm_specs, gravity=(0.0, 0.0, 0.0), name='free_flyer', world='odom',
                     mounted_visuals=()) -> Model:
    """A model whose body 0 is the platform on a FREE joint from ``world`` and the arm hangs from it.

    base: the platform's LinkSpec (name = base link, joint = the free joint's name, mass, com,
    inertia; its joint_type is forced to 'free'); arm_specs: LinkSpecs of the arm whose root
    parent is ``base.name`` (or None); gravity: (3,) in the world frame; world: name of the
    fixed world frame (``odom``); mounted_visuals: drawn besides a link's own (``Model.mounted_visuals``).
    """
    from dataclasses import replace
    specs = [replace(base, joint_type='free', parent=None, origin_xyz=(0.0, 0.0, 0.0), origin_rpy=(0.0, 0.0, 0.0),
                     origin_R=None)]
    for s in arm_specs:
        specs.append(replace(s, parent=base.name if s.parent in (None, base.name) else s.parent))
    model = build_model(specs, gravity=gravity, name=name, root=world, mounted_visuals=mounted_visuals)
    if model.jtype[0] != FREE or any(model.jtype[i] == FREE for i in range(1, model.nb)):
        raise ModelError(f'{name}: exactly one free joint, at the platform, is allowed')
    return model


def free_base_urdf(model: Model) -> str:
    """URDF of a free-flyer model with the platform link as the root (carrying its inertia).

    The floating joint and the world link are left out: the platform's pose is published on
    ``odom`` (REP 105), and a tool that wants a floating root adds it itself (Pinocchio:
    ``buildModelFromXML(urdf, JointModelFreeFlyer())``).
    """
    root = ET.fromstring(to_urdf(model))
    world = model.root
    for el in list(root):
        if el.tag == 'link' and el.get('name') == world:
            root.remove(el)
        elif el.tag == 'joint' and el.get('type') == 'floating':
            root.remove(el)
    ET.indent(root, space='  ')
    return '<?xml version="1.0"?>\n' + ET.tostring(root, encoding='unicode') + '\n'


def level_quaternion(quat):
    """The yaw-only quaternion nearest to ``quat`` (x, y, z, w): its twist about world z.

    Swing–twist decomposition about z: ``(0, 0, z, w) / ‖(z, w)‖``. Undefined when the body is
    upside down (z = w = 0); then the identity is returned.
    """
    z, w = float(quat[2]), float(quat[3])
    n = np.hypot(z, w)
    if n < 1e-12:
        return np.array([0.0, 0.0, 0.0, 1.0])
    return np.array([0.0, 0.0, z / n, w / n])


def table_rows(R, omega, p, height, s=np.zeros(3), ref_bias=np.zeros(3)):
    """The three air-bearing-table constraints on the platform: height, roll, pitch.

    R: (3, 3) platform orientation (body axes in world); omega: (3,) platform angular velocity
    in body coordinates; p: (3,) world position of the held point (the base_link origin);
    height: its prescribed height (m); s: (3,) the held point relative to a *reference point*
    of the platform, in body coordinates; ref_bias: (3,) the part of the reference point's
    world acceleration that is not an acceleration coordinate. The rows thus serve both
    formulations: minimal (reference = base_link origin, s = 0, ``c̈ = R (v̇_O + ω × v_O)`` so
    ``ref_bias = R (ω × v_O)``) and augmented (reference = the platform's CoM, whose world
    acceleration is a coordinate: ``ref_bias = 0``, ``s = −com``).

    Position constraints ``φ = [e_zᵀ p − h; (e_z × n)_x; (e_z × n)_y]`` with ``n = R e_z`` the
    platform's z axis in world: for a small tilt by a horizontal rotation vector θ,
    ``e_z × n ≈ θ``, so the last two rows are the roll and pitch angles (about world x, y) and
    their multipliers the tilting moments; the first multiplier is the normal force (N).
    With ``p = c + R s``, ``ω_w = R ω`` and ``ṅ = ω_w × n``::

        φ̇_z  = e_zᵀ (ċ − R [s]× ω)
        φ̈_z  = e_zᵀ (c̈ − R [s]× ω̇ + R (ω × (ω × s)))
        d/dt (e_z × n)   = −[e_z]× [n]× R ω
        d²/dt² (e_z × n) = −[e_z]× [n]× R ω̇ + [e_z]× (ω_w × (ω_w × n))

    Returns ``(phi (3,), Kw (3, 3), Kc (3, 3), k (3,))`` with ``φ̇ = Kw ω + Kc ċ`` (ċ: the
    reference point's world velocity) and ``φ̈ = Kw ω̇ + Kc c̈_coord − k`` i.e. ``K a = k`` is
    ``φ̈ = 0`` without stabilisation.
    """
    n = R @ _EZ
    ez = skew(_EZ)
    phi = np.array([p[2] - height, *(ez @ n)[:2]])
    Kw = np.zeros((3, 3))
    Kc = np.zeros((3, 3))
    Kw[0] = -(R @ skew(s))[2]
    Kc[0, 2] = 1.0
    Kw[1:] = (-ez @ skew(n) @ R)[:2]
    ww = R @ omega
    k = np.empty(3)
    k[0] = -(ref_bias[2] + (R @ _cross(omega, _cross(omega, s)))[2])
    k[1:] = -(ez @ _cross(ww, _cross(ww, n)))[:2]
    return phi, Kw, Kc, k


def momentum_about_com(m_i, c_i, cdot_i, L_i):
    """Linear momentum (3,), angular momentum about the system CoM (3,) and the CoM (3,), world.

    m_i: (nb,) masses; c_i, cdot_i: (nb, 3) body CoM positions and velocities (world);
    L_i: (nb, 3) spin angular momenta ``R_i I_ci ω_i`` of the bodies about their own CoMs (world).
    """
    mt = float(np.sum(m_i))
    c = (m_i[:, None] * c_i).sum(0) / mt
    p = (m_i[:, None] * cdot_i).sum(0)
    r, d = c_i - c, cdot_i
    rxd = np.stack([r[:, 1] * d[:, 2] - r[:, 2] * d[:, 1], r[:, 2] * d[:, 0] - r[:, 0] * d[:, 2],
                    r[:, 0] * d[:, 1] - r[:, 1] * d[:, 0]], axis=1)  # np.cross, without its ~30 µs of dispatch
    L = L_i.sum(0) + (m_i[:, None] * rxd).sum(0)
    return p, L, c


class _FreeBaseCommon(System):
    """Inputs, command handling and output bookkeeping shared by both formulations.

    model: the free-flyer tree (body 0 on a FREE joint); actuated: driven arm joints (default
    every 1-DOF joint); environment: 'orbit' | 'air_bearing_table' | 'free_fall'; table_height: height (m)
    of the base_link origin on the table (default: the initial height given to
    :meth:`initial_state`, else 0); stabilisation: 'baumgarte' | 'projection' | 'none';
    alpha, beta: Baumgarte gains (1/s); backend: ``'numpy'`` (the methods of the classes, the
    reference) or ``'numba'`` (``'generated'`` is taken as numba): right-hand side, projection and
    solves by :mod:`robodyn_ros.kernels.freeflyer` (equal to 1e-12) and :meth:`fused_advance`;
    default :func:`robodyn_ros.systems.base.default_backend`.
    """

    formulation = ''
    #: the methods of the class whose results the compiled kernels reproduce
    _COMPILED_METHODS = ()

    def __init__(self, model: Model, actuated=None, environment='orbit', table_height=None,
                 stabilisation='baumgarte', alpha=con.BAUMGARTE_ALPHA, beta=con.BAUMGARTE_BETA, backend=None):
        self.backend = resolve_backend(backend)
        self._cs = None
        self._grids = {}
        if model.nb == 0 or model.jtype[0] != FREE or model.parent[0] != -1:
            raise ModelError(f'{model.name}: a free-flyer model needs body 0 on a FREE joint from the root')
        if environment not in ENVIRONMENTS:
            raise ValueError(f'environment must be one of {ENVIRONMENTS}, got {environment!r}')
        if stabilisation not in STABILISATIONS:
            raise ValueError(f'stabilisation must be one of {STABILISATIONS}, got {stabilisation!r}')
        if not (np.isfinite(alpha) and np.isfinite(beta) and alpha >= 0 and beta >= 0):
            raise ValueError(f'Baumgarte gains must be finite and >= 0, got alpha={alpha!r}, beta={beta!r}')
        if environment == 'orbit' and np.any(model.gravity != 0.0):
            raise ValueError(f'environment orbit needs zero gravity, the model has {model.gravity.tolist()}')
        if environment == 'air_bearing_table' and not (model.gravity[2] < 0 and np.allclose(model.gravity[:2], 0)):
            raise ValueError('the air-bearing table is horizontal: gravity must point along -z, got '
                             f'{model.gravity.tolist()}')
        self.model = model
        self.environment = environment
        self.table = environment == 'air_bearing_table'
        self.table_height = None if table_height is None else float(table_height)
        self._height0 = self.table_height
        self._gains = (alpha, beta)
        self.stabilisation = stabilisation
        self.alpha, self.beta = (float(alpha), float(beta)) if stabilisation != 'none' else (0.0, 0.0)
        self.base_link = model.link_names[0]
        self.joint_names = model.dof_joint_names
        self.actuated, self.B, port = effort_actuation(model, self.joint_names, actuated, 'arm joints')
        self.n_arm = len(self.joint_names)
        # tau = B u on the minimal v (6 base + arm); actuated joint positions = Bq q (minimal q)
        self.Bq = np.zeros((len(self.actuated), model.nq))
        for k, n in enumerate(self.actuated):
            self.Bq[k, model.q_idx[model.joint_names.index(n)]] = 1.0
        self.inputs = {'effort': port, 'base_wrench': InputPort('base_wrench', 6, BASE_WRENCH_LABELS, 'N/N·m')}
        self.mass = model.total_mass()
        self.weight = self.mass * float(np.linalg.norm(model.gravity))

    # -- shared helpers ------------------------------------------------------------------
    @property
    def options(self) -> dict:
        """The constructor options of this system (environment, table height, stabilisation, gains)."""
        return {'environment': self.environment, 'table_height': self._height0, 'stabilisation': self.stabilisation,
                'alpha': self._gains[0], 'beta': self._gains[1]}

    def with_arm(self, arm_specs, actuated=None, name=None, mounted_visuals=()):
        """The same free base (class, environment, options) carrying the arm ``arm_specs``.

        arm_specs: LinkSpecs whose root parent is this system's base link (or None); actuated:
        driven joints (default all); name: model name (default this model's); mounted_visuals:
        ``((link, visuals), ...)``, an imported arm's root-link visuals drawn on the base link
        (``Model.mounted_visuals``).
        """
        model = free_flyer_model(self.model.specs[0], arm_specs, gravity=self.model.gravity,
                                 name=name or self.model.name, world=self.model.root,
                                 mounted_visuals=mounted_visuals)
        return type(self)(model, actuated=actuated, backend=self.backend, **self.options)

    def rebuilt(self, backend, cls=None, **changes):
        """The same system built again on another ``backend`` (and, optionally, formulation).

        cls: FreeFlyerSystem or AugmentedFreeFlyerSystem (default: this system's class);
        changes: constructor options overriding this system's (e.g. stabilisation).
        """
        return (cls or type(self))(self.model, actuated=self.actuated, backend=backend,
                                   **{**self.options, **changes})

    def arm_torques(self, u, thetadot):
        """Applied plus passive arm joint forces ``B_arm u − D θ̇`` (n_arm,)."""
        return (self.B @ u['effort'])[6:] - self.model.damping[6:] * thetadot

    def _table_height(self, p):
        if self.table_height is None:
            self.table_height = float(p[2])
        return self.table_height

    def _compiled(self):
        """The packed system when the compiled path stands in for this object's methods, else None."""
        cs = self._cs
        if cs is None or not keeps_methods(self, self._compiled_class, self._COMPILED_METHODS):
            return None
        return cs

    def _u_vec(self, u):
        """Input vector of the kernels (layout of the formulation's section in ``kernels.freeflyer`` / ``kernels.augmented``)."""
        raise NotImplementedError

    def _sync_height(self, cs, y):
        """Fix the table height (the first state seen, when none was given) in the packed parameters."""
        if self.table and self.table_height is None:
            self._table_height(self._base_origin(y))
        if self.table:
            cs.fp[2] = self.table_height  # FF_HEIGHT == AU_HEIGHT

    def fused_advance(self, integrator_name, dt, t0, z0, t1, u):
        """Integrate ``z = [y, W]`` from t0 to t1 in one compiled call, or None to decline.

        The Simulator's fast path (see ``ArmSystem.fused_advance``): the same fixed-step method,
        step grid, projection after every step and work quadrature as the reference path with
        :meth:`rhs`, :meth:`input_power` and :meth:`project`. Declines on the numpy backend, for
        error-controlled integrators and when a method was overridden.
        """
        cs = self._compiled()
        if cs is None or not self._fused_supported():
            return None
        self._sync_height(cs, np.asarray(z0, dtype=float))
        return compiled_fused_advance(cs, self._grids, integrator_name, dt, t0, z0, t1, self._u_vec(u), self.ny)

    def _fused_supported(self) -> bool:
        return True

    def fastest_time_constant(self, y):
        """``1/max(alpha, beta)`` when Baumgarte-stabilised constraints are present, else inf."""
        g = max(self.alpha, self.beta)
        return 1.0 / g if (self.has_constraints and g > 0) else float('inf')

    def urdf(self) -> str:
        """URDF of the robot with base_link as its root (see :func:`free_base_urdf`)."""
        return free_base_urdf(self.model)

    def _extra(self, p, L, c, residual, vresidual, info):
        e = {'formulation': self.formulation, 'environment': self.environment,
             'momentum_linear_x': p[0], 'momentum_linear_y': p[1], 'momentum_linear_z': p[2],
             'momentum_angular_com_x': L[0], 'momentum_angular_com_y': L[1], 'momentum_angular_com_z': L[2],
             'com_x': c[0], 'com_y': c[1], 'com_z': c[2],
             'constraint_residual': residual, 'constraint_velocity_residual': vresidual,
             'constraint_rows': info.m, 'constraint_rank': info.rank,
             'constraint_rank_deficient': bool(info.rank_deficient)}
        return e


class FreeFlyerSystem(_FreeBaseCommon):
    """Free-flying base + arm in minimal coordinates: state ``y = [q (nq), v (nv)]``.

    q = [p (3) base_link origin in odom, quaternion (x, y, z, w), θ (n_arm)]; v = [ω (3), v_O
    (3) base twist in base_link coordinates, θ̇ (n_arm)]. Inputs: ``effort`` (actuated arm
    joints, N·m) and ``base_wrench`` ([fx, fy, fz, tx, ty, tz] on base_link at its origin, in
    base_link axes). See the module docstring for the environments and outputs.
    """

    formulation = 'minimal'
    _COMPILED_METHODS = ('rhs', 'input_power', 'project', 'config_rate', 'generalized_forces', 'solve', '_f_ext',
                         '_table', 'body_coms', 'total_energy')

    def __init__(self, model: Model, **kw):
        super().__init__(model, **kw)
        self.nq, self.nv = model.nq, model.nv
        self.ny = self.nq + self.nv
        self.initial_state_sizes = (model.nq, model.nv)
        self.has_constraints = self.table
        self.n_constraints = 3 if self.table else 0
        self._compiled_class = FreeFlyerSystem
        self._km = None
        if self.backend != 'numpy':
            stab = {'baumgarte': 0, 'projection': 1, 'none': 2}[self.stabilisation]
            fp = [self.alpha, self.beta, 0.0 if self.table_height is None else self.table_height, con.KKT_RCOND]
            self._cs = kernels.CompiledSystem(kernels.fixed_step.FREEFLYER, [int(self.table), stab],
                                              fp + list(model.damping.astype(float)), model, self.nq)
            self._km = self._cs.km

    def _u_vec(self, u):
        """``[B u_effort (nv), base wrench (6)]``."""
        uv = np.empty(self.nv + 6)
        uv[:self.nv] = self.B @ u['effort']
        uv[self.nv:] = u['base_wrench']
        return uv

    def _base_origin(self, y):
        return y[:3]

    # -- state ---------------------------------------------------------------------------
    def split(self, y):
        """Views ``(q, v)`` of the state vector (minimal coordinates)."""
        return y[:self.nq], y[self.nq:self.nq + self.nv]

    def minimal(self, y):
        """``(q, v)`` copies in minimal coordinates (the common interface of both formulations)."""
        q, v = self.split(y)
        return q.copy(), v.copy()

    def initial_state(self, q0=None, v0=None):
        """State from q0 (nq,) and v0 (nv,) in minimal coordinates (neutral / zero by default).

        On the table the height of the initial base_link origin becomes the table height
        unless one was given.
        """
        y = np.zeros(self.ny)
        y[:self.nq] = self.model.neutral() if q0 is None else q0
        y[:self.nq] = dyn.normalize_configuration(self.model, y[:self.nq])
        if v0 is not None:
            y[self.nq:] = v0
        if self.table:
            self._table_height(y[:3])
        return y

    def config_rate(self, q, w):
        """``dq/dt`` from the velocities at the start of ``w`` (quaternion-aware)."""
        return dyn.qdot(self.model, q, w[:self.nv])

    def project(self, y):
        """Renormalise the quaternion; with ``projection`` also put q, v back on the table."""
        cs = self._compiled()
        if cs is not None:
            self._sync_height(cs, y)
            return cs.project(y) if y.flags.c_contiguous and y.dtype == np.float64 else \
                cs.project(np.ascontiguousarray(y, dtype=np.float64))
        y[:self.nq] = dyn.normalize_configuration(self.model, y[:self.nq])
        if self.table and self.stabilisation == 'projection':
            q, v = y[:self.nq], y[self.nq:]
            q[3:7] = level_quaternion(q[3:7])
            q[2] = self._table_height(q[:3])
            M = dyn.crba(self.model, q)
            K = self._table(q, v)[1]
            y[self.nq:] = con.project_velocities(M, K, v)
        return y

    # -- dynamics ------------------------------------------------------------------------
    def _f_ext(self, u):
        """External forces (nb, 6) in body coordinates: the base wrench on body 0."""
        f = np.zeros((self.model.nb, 6))
        w = u['base_wrench']
        f[0, :3] = w[3:6]
        f[0, 3:] = w[0:3]
        return f

    def generalized_forces(self, y, u):
        """Joint-space applied plus passive forces ``B u − D v`` (nv,) (base wrench via f_ext)."""
        _, v = self.split(y)
        return self.B @ u['effort'] + dyn.passive_forces(self.model, v)

    def _table(self, q, v):
        """Table constraints in minimal coordinates: ``(φ (3,), K (3, nv), k (3,))``.

        The held point is the base_link origin itself (s = 0) with world velocity
        ``ṗ = R v_O``; its acceleration is ``R (v̇_O + ω × v_O)`` (the FREE joint's v̇ is the
        derivative of the body-coordinate twist), so ``K`` acts on v̇_O through ``e_zᵀ R`` and
        the bias is ``−e_zᵀ R (ω × v_O)``.
        """
        cs = self._compiled()
        if cs is not None:
            self._sync_height(cs, q)
            phi, K, k = np.empty(3), np.empty((3, self.nv)), np.empty(3)
            kernels.freeflyer.ff_table(cs.fp, self.nv, np.ascontiguousarray(q, dtype=float),
                                         np.ascontiguousarray(v, dtype=float), phi, K, k)
            return phi, K, k
        R = quat_to_R(q[3:7])
        w, vo = v[0:3], v[3:6]
        phi, Kw, Kc, k = table_rows(R, w, q[:3], self._table_height(q[:3]), ref_bias=R @ _cross(w, vo))
        K = np.zeros((3, self.nv))
        K[:, 0:3] = Kw
        K[:, 3:6] = Kc @ R
        return phi, K, k

    def solve(self, q, v, tau, f_ext):
        """Accelerations (nv,), table multipliers (3,) or (0,) and the SolveInfo at (q, v).

        Orbit: ABA. Table: ``M a = τ − h + Kᵀλ``, ``K a = k − 2α φ̇ − β² φ`` by
        :func:`robodyn_ros.constraints.kkt_solve`; λ = [normal force, moment about x, moment about
        y] (world axes, for a level platform).
        """
        cs = self._compiled()
        if cs is not None:
            self._sync_height(cs, q)
            a, lam, info = np.empty(self.nv), np.empty(self.n_constraints), np.empty(kernels.linalg.NINFO)
            c = np.ascontiguousarray
            if kernels.freeflyer.ff_solve(cs.ip, cs.fp, *cs.tree, c(q, dtype=float), c(v, dtype=float),
                                            c(tau, dtype=float), c(f_ext, dtype=float), True, a, lam, info):
                raise np.linalg.LinAlgError('mass matrix is not positive definite')
            return a, lam, con.SolveInfo(m=self.n_constraints, rank=int(info[0]), sigma_min=float(info[1]),
                                         sigma_max=float(info[2]), residual=float(info[3]))
        if not self.table:
            return dyn.aba(self.model, q, v, tau, f_ext), np.zeros(0), con.SolveInfo(0, 0, np.inf, np.inf)
        M = dyn.crba(self.model, q)
        h = dyn.bias_forces(self.model, q, v, f_ext)
        phi, K, k = self._table(q, v)
        k = con.baumgarte_rhs(k, phi, K @ v, self.alpha, self.beta)
        a, lam, info = con.kkt_solve(M, tau - h, K, k)
        return a, lam, info

    def rhs(self, t, y, u):
        """``[q̇; v̇]``."""
        cs = self._compiled()
        if cs is not None:
            self._sync_height(cs, y)
            return cs.evaluate(t, y, self._u_vec(u))[:self.ny]
        q, v = self.split(y)
        out = np.empty(self.ny)
        out[:self.nq] = dyn.qdot(self.model, q, v)
        out[self.nq:] = self.solve(q, v, self.generalized_forces(y, u), self._f_ext(u))[0]
        return out

    def table_wrench(self, q, v, lam):
        """The table's wrench [torque; force] on base_link at its origin, base_link coordinates (6,)."""
        if not self.table:
            return np.zeros(6)
        _, K, _ = self._table(q, v)
        return (K.T @ lam)[:6]

    # -- outputs -------------------------------------------------------------------------
    def body_coms(self, q, v):
        """Per-body masses (nb,), CoMs (nb, 3), CoM velocities (nb, 3), spin momenta (nb, 3), world."""
        m = self.model
        R, p = dyn.body_poses(m, q)
        vb = dyn.body_velocities(m, q, v)
        ms = np.empty(m.nb)
        c = np.empty((m.nb, 3))
        cd = np.empty((m.nb, 3))
        Ls = np.empty((m.nb, 3))
        for i in range(m.nb):
            mi, ci, Ic = dyn.inertia_parts(m.I[i])
            ms[i] = mi
            c[i] = p[i] + R[i] @ ci
            cd[i] = R[i] @ (vb[i, 3:] + _cross(vb[i, :3], ci))
            Ls[i] = R[i] @ (Ic @ vb[i, :3])
        return ms, c, cd, Ls

    def outputs(self, t, y, u, wrenches=True):
        """Joint states, odometry, joint and table wrenches, energies and momentum diagnostics."""
        q, v = self.split(y)
        m = self.model
        tau = self.generalized_forces(y, u)
        f_ext = self._f_ext(u)
        a, lam, info = self.solve(q, v, tau, f_ext)
        w = {}
        tab = self._table(q, v) if self.table else None
        table_w = (tab[1].T @ lam)[:6] if self.table else np.zeros(6)  # table_wrench, with the rows at hand
        fast = self._compiled() is not None
        if wrenches:
            fe = f_ext.copy()
            fe[0] += table_w
            if fast:
                _, f = self._km.rnea_wrenches(np.ascontiguousarray(q), np.ascontiguousarray(v), a, fe)
            else:
                _, f = dyn.rnea_wrenches(m, q, v, a, fe)
            for i in range(1, m.nb):
                w[m.joint_names[i]] = (m.link_names[i], f[i].copy())
            if self.table:
                w['base_plane'] = (self.base_link, table_w)
        if fast:
            p, L, com = self._km.momentum(q, v)
            kin, pot = self._km.energies(np.ascontiguousarray(q), np.ascontiguousarray(v))
        else:
            ms, c, cd, Ls = self.body_coms(q, v)
            p, L, com = momentum_about_com(ms, c, cd, Ls)
            kin, pot = dyn.kinetic_energy(m, q, v), dyn.potential_energy(m, q)
        res, vres = 0.0, 0.0
        if self.table:
            phi, K, _ = tab
            res, vres = float(np.abs(phi).max()), float(np.abs(K @ v).max())
        odom = {'position': q[0:3].copy(), 'orientation': q[3:7].copy(), 'linear': v[3:6].copy(),
                'angular': v[0:3].copy()}
        return SystemOutputs(joint_names=list(self.joint_names), position=q[7:].copy(), velocity=v[6:].copy(),
                             effort=(self.B @ u['effort'])[6:], wrenches=w, odom=odom,
                             energy={'kinetic': kin, 'potential': pot},
                             extra=self._extra(p, L, com, res, vres, info))

    def total_energy(self, y):
        """Kinetic plus gravitational potential energy (J)."""
        q, v = self.split(y)
        if self._compiled() is not None:
            kin, pot = self._km.energies(np.ascontiguousarray(q), np.ascontiguousarray(v))
            return kin + pot
        return dyn.kinetic_energy(self.model, q, v) + dyn.potential_energy(self.model, q)

    def input_power(self, t, y, u):
        """Power of the joint efforts and the base wrench minus joint damping (W)."""
        _, v = self.split(y)
        wr = u['base_wrench']
        return float(v @ self.generalized_forces(y, u) + v[0:3] @ wr[3:6] + v[3:6] @ wr[0:3])
