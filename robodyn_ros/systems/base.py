"""The interface every system implements, and the containers it returns."""
from __future__ import annotations

import functools
import operator
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

BACKENDS = ('numpy', 'numba', 'generated', 'auto')


def default_backend() -> str:
    """``'numba'`` when the compiled kernels are importable, else ``'numpy'`` (env ``ROBODYN_BACKEND``)."""
    import os

    from .. import kernels
    env = os.environ.get('ROBODYN_BACKEND', '').lower()
    if env in BACKENDS:
        return env if env == 'numpy' or kernels.AVAILABLE else 'numpy'
    return 'numba' if kernels.AVAILABLE else 'numpy'


#: backend of ``robodyn run``, the sim node and sweeps when neither their option nor
#: ``ROBODYN_BACKEND`` chooses one: an arm starts on the generic compiled kernels (compiled once per
#: install, cached on disk, for every robot: a new robot starts without compiling) and takes up its
#: own generated code (:mod:`robodyn_ros.kernels.codegen`: the same operations without the generic
#: loops, 2-3x faster per call) once a child process has compiled it, which it starts after
#: ``kernels.GENERATE_AFTER`` seconds of integration; the bytes of a run do not depend on when.
#: Other systems take 'auto' as 'numba'.
TOOLS_BACKEND = 'auto'


def tools_backend(requested=None) -> str:
    """The backend of the command-line tools and the node: ``requested`` if given, else
    ``ROBODYN_BACKEND``, else :data:`TOOLS_BACKEND`; ValueError for an unknown name."""
    import os
    name = requested or os.environ.get('ROBODYN_BACKEND') or TOOLS_BACKEND
    name = str(name).lower()
    if name not in BACKENDS:
        raise ValueError(f'unknown backend {name!r}; valid: {", ".join(BACKENDS)}')
    return name


def recorded_backend(name: str) -> str:
    """The backend a recording's settings name (what ``robodyn resim`` rebuilds on): ``'numpy'`` for the
    reference, ``'numba'`` for every compiled backend (numba, generated and auto compute the same bits,
    so a recording does not depend on which ran)."""
    return 'numpy' if name == 'numpy' else 'numba'


class backend_scope:
    """Context manager: systems built inside it default to backend ``name`` (``ROBODYN_BACKEND``)."""

    def __init__(self, name):
        self.name = name

    def __enter__(self):
        import os
        self.old = os.environ.get('ROBODYN_BACKEND')
        if self.name:
            os.environ['ROBODYN_BACKEND'] = self.name
        return self

    def __exit__(self, *exc):
        import os
        if self.old is None:
            os.environ.pop('ROBODYN_BACKEND', None)
        else:
            os.environ['ROBODYN_BACKEND'] = self.old


def resolve_backend(backend) -> str:
    """A validated backend name: None -> :func:`default_backend`; raises ValueError for an unknown
    name or a compiled backend without numba."""
    from .. import kernels
    backend = default_backend() if backend is None else str(backend).lower()
    if backend not in BACKENDS:
        raise ValueError(f'unknown backend {backend!r}; valid: {", ".join(BACKENDS)}')
    if backend != 'numpy' and not kernels.AVAILABLE:
        raise ValueError(f'backend {backend} unavailable (no numba): {kernels.UNAVAILABLE_REASON}')
    return backend


def keeps_methods(obj, base: type, names) -> bool:
    """True when ``obj`` computes ``names`` exactly as class ``base`` does: no subclass override,
    no method replaced on the instance (the condition for a compiled path to stand in for them).

    Checked at every call (systems ask once or more per publication period), in C loops: an
    instance of ``base`` itself has its methods by definition, a subclass's are compared one by
    one (``attrgetter``, ``operator.is_``), and the instance dictionary must hold none of them.
    """
    cls = type(obj)
    if cls is not base:
        get = _attr_tuple(tuple(names))
        if not all(map(operator.is_, get(cls), get(base))):
            return False
    return obj.__dict__.keys().isdisjoint(names)


@functools.lru_cache(maxsize=None)
def _attr_tuple(names: tuple):
    """``obj -> tuple of obj.<name>`` for each of names (a tuple even for one name)."""
    if len(names) < 2:
        return lambda obj: tuple(getattr(obj, n) for n in names)
    return operator.attrgetter(*names)


#: what :func:`compiled_fused_advance` uses of modules that import this one, once imported
_FUSED_DEPS = None


def _fused_deps():
    global _FUSED_DEPS
    from .. import kernels
    from ..integrators import IntegrationError, IntegratorStats, make_integrator
    _FUSED_DEPS = (kernels, IntegrationError, IntegratorStats, make_integrator)
    return _FUSED_DEPS


def compiled_fused_advance(cs, grids: dict, integrator_name, dt, t0, z0, t1, u_vec, ny):
    """Integrate ``z = [y, W]`` from t0 to t1 in one call of the compiled loop, or None to decline.

    The shared fast path of the systems on :class:`robodyn_ros.kernels.CompiledSystem` (the
    Simulator's ``fused_advance`` protocol, see ``ArmSystem.fused_advance``): same method, step
    grid (``FixedStepIntegrator.step_grid``), projection after every step and work quadrature as
    ``Simulator._integrate`` with the system's own methods. cs: the packed system; grids: a
    per-system cache dt -> grid integrator; u_vec: the system's input vector for the call.
    Returns ``(z1 (ny + 1,), IntegratorStats)``; raises ``IntegrationError`` like the reference
    when the state becomes non-finite, ``numpy.linalg.LinAlgError`` for a singular mass matrix.
    """
    kernels, IntegrationError, IntegratorStats, make_integrator = _FUSED_DEPS or _fused_deps()
    if integrator_name not in cs.methods:
        return None
    z = np.array(z0, dtype=np.float64)
    if z.shape != (ny + 1,):
        return None
    grid = grids.get(dt)
    if grid is None:
        grid = grids[dt] = make_integrator('rk4', dt=dt)
    n_full, h_last = grid.step_grid(float(t0), float(t1)) if t1 > t0 else (0, 0.0)
    n_steps = n_full + (1 if h_last > 0.0 else 0)
    k = cs.integrate(integrator_name, z, u_vec, t0, dt, n_full, h_last)
    if k in (0, -2) and not np.isfinite(z0).all():  # checked after the fact: the loop reports step 0
        raise IntegrationError(integrator_name, t0, 'initial state is non-finite at components '
                               f'{np.flatnonzero(~np.isfinite(np.asarray(z0)))[:8].tolist()}')
    if k != -1:
        step = k if k >= 0 else -2 - k
        t = t0 + step * dt
        h = dt if step < n_full else h_last
        if k <= -2:
            raise np.linalg.LinAlgError(f'mass matrix not positive definite in the step from t={t:.12g} s')
        raise IntegrationError(
            integrator_name, t + h,
            f'state became non-finite (components {np.flatnonzero(~np.isfinite(z))[:8].tolist()}) in the '
            f'step from t={t:.12g} s with h={h:.6g} s; reduce dt or check the model')
    return z, IntegratorStats.of_fused_steps(integrator_name, n_steps)


def clamp_to_limit(value: np.ndarray, limit) -> np.ndarray:
    """What the actuators apply of command value under effort limits (None: value itself): the one clamp of
    the per-period path (:meth:`robodyn_ros.commands.CommandPort.clamped_to_limit`) and of the block path's
    sensor inputs (``ArmSystem.fused_periods``)."""
    return value if limit is None else np.clip(value, -limit, limit)


@dataclass(frozen=True)
class InputPort:
    """A named command input: its size, the names of its elements and their unit.

    name: port name ('effort', 'wheel_voltage', 'base_wrench', 'position', 'velocity', 'trajectory');
    size: vector length; labels: element names (joint names, 'left'/'right', ...); unit: SI unit text
    for messages; limit: optional (size,) tuple, the largest |value| per element (inf = none): the
    Simulator clamps commands to it and counts the clamped components.
    kind: ``'vector'`` (held values; zero after the command timeout), ``'setpoint'`` (a vector the system
    turns into what it applies, :meth:`System.accept_input`, held with no timeout: position setpoints)
    or ``'message'`` (a structured command, e.g. a trajectory, validated by :meth:`System.accept_input`,
    which yields what port ``target`` applies from then on).
    """

    name: str
    size: int
    labels: tuple
    unit: str
    limit: tuple | None = None
    kind: str = 'vector'
    target: str = ''


class LazyValues(Mapping):
    """A read-only mapping computed on first access by ``fn() -> dict``: output values (energies)
    that most publications never read are only computed when someone does."""

    __slots__ = ('_fn', '_d')

    def __init__(self, fn):
        self._fn = fn
        self._d = None

    def _data(self) -> dict:
        if self._d is None:
            self._d = self._fn()
            self._fn = None
        return self._d

    def __getitem__(self, key):
        return self._data()[key]

    def __iter__(self):
        return iter(self._data())

    def __len__(self):
        return len(self._data())

    def __repr__(self):
        return repr(self._data())


class LazyWrenches(Mapping):
    """``outputs.wrenches`` computed on first read of a value: joint name -> (child frame,
    (6,) [torque; force]), names and frames known up front.

    one: ``one(*args) -> (n, 6)`` wrenches of this publication; many: ``many([args, ...]) ->
    (K, n, 6)``, the same numbers for K publications in one call. A recorder that batches
    publications keeps ``args`` and calls ``many`` once (``batch_key`` tells which publications
    it may batch together); everyone else reads the mapping as a dict.
    """

    __slots__ = ('names', 'frames', 'args', '_one', 'many', '_f', '_index')

    def __init__(self, names: tuple, frames: tuple, one, many, args, index: dict):
        self.names, self.frames, self.args = names, frames, args
        self._one, self.many, self._index = one, many, index
        self._f = None

    @property
    def batch_key(self):
        """Publications with the same key share names, frames and ``many``."""
        return (self.names, self.frames, self.many)

    def array(self) -> np.ndarray:
        """``(n, 6)`` wrenches in name order (read-only: the mapping's values are views of it)."""
        if self._f is None:
            f = np.asarray(self._one(*self.args))
            f.flags.writeable = False
            self._f = f
        return self._f

    def __getitem__(self, key):
        return self.frames[self._index[key]], self.array()[self._index[key]]

    def __iter__(self):
        return iter(self.names)

    def __len__(self):
        return len(self.names)

    def __repr__(self):
        return repr(dict(self.items()))


@dataclass
class SystemOutputs:
    """What a system reports at one instant (all arrays finite, SI units).

    joint_names, position, velocity, effort: every joint in ``joint_states`` order;
    wrenches: joint or contact name -> (child frame, (6,) [torque; force] on the child at the
    joint origin in child coordinates); odom: optional dict with 'position' (3,),
    'orientation' (x, y, z, w), 'linear' (3,) and 'angular' (3,) in base_link (the link named by
    ``odom_child``);
    energy: mapping of named energies (J; may be a :class:`LazyValues`, computed when read);
    extra: other diagnostics values; contacts: link -> (world frame, (6,) [moment; force]) of the
    ground on that link, world axes, about its centre of pressure (``contact_wrenches/<link>``,
    :mod:`robodyn_ros.systems.contact`), empty off the ground; contact_points: (n, 6) ``[x; F]`` of the
    points touching the ground (world frame; m, N), None off the ground (drawn as markers); messages:
    further messages of this instant, ``[(topic, type, message dict)]`` (sensors, a servo's desired and
    error states); imu_poses: (ni, 12) ``[p; R]`` of each IMU's link in the world (root) frame (origin, m;
    rotation row major, the link's axes as columns), ft_wrenches: (nf, 9) ``[p; f; n]`` of each force-torque
    sensor: its frame's origin and its published reading in world axes (m, N, N·m), both None without
    sensors (drawn as markers; :meth:`robodyn_ros.systems.sensors.SensorSet.world_frames`).
    """

    joint_names: list
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray
    wrenches: dict = field(default_factory=dict)
    odom: dict | None = None
    energy: dict = field(default_factory=dict)
    odom_child: str = 'base_link'   # child_frame_id of odom (the free root's link for a floating tree)
    extra: dict = field(default_factory=dict)
    contacts: dict = field(default_factory=dict)
    contact_points: np.ndarray | None = None
    messages: list = field(default_factory=list)
    imu_poses: np.ndarray | None = None
    ft_wrenches: np.ndarray | None = None


class System:
    """Base class: state layout, inputs, right-hand side and outputs of a simulated system.

    Subclasses set ``ny`` (state size), ``nq`` (configuration part, first in y; velocities
    follow, then any extra states such as motor currents), ``inputs`` (name -> InputPort).
    """

    ny: int = 0
    nq: int = 0
    inputs: dict = {}

    def zero_inputs(self) -> dict:
        """Input values that mean 'no command' (zeros) for every port."""
        return {k: np.zeros(p.size) for k, p in self.inputs.items()}

    def initial_input(self, port: str, y: np.ndarray, t: float):
        """``(value, applied)`` of a port before any command, at the initial state y and time t (s):
        zeros by default (a position setpoint port holds the initial positions)."""
        z = np.zeros(self.inputs[port].size)
        return z, z

    def accept_input(self, port: str, value, t: float, applied):
        """What a ``setpoint`` or ``message`` port's command ``value`` arriving at time t (s) makes the
        system apply from then on, given what it applies now (``applied``; for a message port, its target
        port's); raises ValueError (the reason) to refuse it. Only systems with such ports implement it."""
        raise ValueError(f'port {port!r} takes no structured commands')

    def time_derivative(self, t: float, y: np.ndarray, u: dict):
        """``∂(dy/dt)/∂t`` (ny,) of the stiff part of f that moves with time (a servo on a moving setpoint),
        for the linearly implicit step's time term; None (the default): none."""
        return None

    def rhs(self, t: float, y: np.ndarray, u: dict) -> np.ndarray:
        """State derivative ``dy/dt`` (ny,) at time t (s) with inputs u held constant."""
        raise NotImplementedError

    def config_rate(self, q: np.ndarray, w: np.ndarray) -> np.ndarray:
        """``dq/dt`` (nq,) from the part of the state after q (velocities first); for symplectic Euler."""
        return w[:self.nq]

    def project(self, y: np.ndarray) -> np.ndarray:
        """Project y back onto its manifold (renormalise quaternions); identity by default."""
        return y

    def reset_episode(self) -> None:
        """A new episode starts (Simulator construction and reset): clear once-per-episode state
        such as warnings already issued; nothing by default."""

    def outputs(self, t: float, y: np.ndarray, u: dict, wrenches: bool = True) -> SystemOutputs:
        """Everything published about state y; ``wrenches=False`` skips the wrench solve."""
        raise NotImplementedError

    def total_energy(self, y: np.ndarray) -> float:
        """Mechanical (plus stored electrical) energy of state y (J)."""
        raise NotImplementedError

    def input_power(self, t: float, y: np.ndarray, u: dict) -> float:
        """Power (W) the inputs put into the system minus dissipation at state y; d(E)/dt."""
        raise NotImplementedError

    def fastest_time_constant(self, y: np.ndarray) -> float:
        """An estimate (s) of the fastest time constant at state y, for step-size checks."""
        return float('inf')

    def stop_time_constant(self, y: np.ndarray) -> float:
        """The fastest time constant (s) at state y of a joint stop, whose law switches within a bounce: an
        explicit step must resolve it (``stability.STOP_RESOLUTION``); inf when there is none."""
        return float('inf')

    def passive_jacobian(self, t: float, y: np.ndarray, u: dict, h: float | None = None):
        """The stiff part J (ny, ny) of ``∂(dy/dt)/∂y`` at (t, y) that the linearly implicit ``rosenbrock2``
        treats implicitly at step h (s): the passive forces (damping, friction slope, joint-limit springs
        and dampers, a ground's contact stiffness, damping and friction slope, motor electrics) and the parts
        of the rest it can afford (the gravity stiffness); or None:
        J = 0 (the method is then Heun's). Also used by the step preflight (:mod:`robodyn_ros.stability`)."""
        return None

    def analysis_states(self, y: np.ndarray) -> list:
        """States besides y at which ``integrator: auto`` analyses the step (:mod:`robodyn_ros.integrator_choice`):
        those whose stiffness y does not show yet (a body above a ground it will land on). None by default."""
        return []

    def explicit_time_constant(self, y: np.ndarray) -> float:
        """The part of :meth:`fastest_time_constant` (s) that :meth:`passive_jacobian` does not hold
        (``rosenbrock2`` must resolve it explicitly): all of it by default."""
        return self.fastest_time_constant(y)

    def urdf(self) -> str:
        """URDF of the system for ``robot_description`` (names equal those in joint_states)."""
        from ..model import to_urdf
        return to_urdf(self.model)


def effort_actuation(model, candidates, actuated=None, what='joints'):
    """Validated actuated joints, actuation matrix and ``effort`` input port of a tree model.

    model: the kinematic tree (its ``v_idx`` places each joint in v); candidates: the joints
    that may be driven; actuated: the driven ones (None = all candidates); what: how the
    candidates are named in the error message. Returns ``(actuated, B (nv, m), port)`` with
    ``tau = B u``; raises ValueError naming unknown joints. The port's ``limit`` holds the
    joints' ``effort_limit`` (LinkSpec; URDF ``<limit effort>``), None when no joint has one.
    """
    from ..model import PRISMATIC
    candidates = list(candidates)
    actuated = list(candidates if actuated is None else actuated)
    unknown = [j for j in actuated if j not in candidates]
    if unknown:
        raise ValueError(f'actuated joints {unknown} are not {what} of {model.name}; {what} are {candidates}')
    where = [model.state_index(n) for n in actuated]   # (body, v index) of each driven component
    B = np.zeros((model.nv, len(actuated)))
    for k, (_, vi) in enumerate(where):
        B[vi, k] = 1.0   # a spherical joint's '<joint>_x/_y/_z': its torque components
    lim = np.array([model.specs[i].effort_limit or np.inf for i, _ in where], dtype=float)
    units = sorted({'N' if model.jtype[i] == PRISMATIC else 'N·m' for i, _ in where})
    return actuated, B, InputPort('effort', len(actuated), tuple(actuated), '/'.join(units) or '-',
                                  tuple(lim.tolist()) if np.isfinite(lim).any() else None)
