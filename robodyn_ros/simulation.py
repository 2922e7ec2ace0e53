"""The Simulator: advance(t) as a short pipeline of stages, with invariants and diagnostics.

One control period is::

    u  = held_inputs(commands, t)            # zero-order hold, timeout to zero
    y  = integrate(system, y, u, t -> t1)    # the chosen integrator, energy-work quadrature
    guard_finite(y)                          # never keep a non-finite state
    out = system.outputs(t1, y, u)           # joint states, wrenches, odometry, energies
    sinks(out, diagnostics)                  # recorder, ROS publishers

No ROS here: nodes and the recorder are sinks the simulator calls, stamped with simulation time.
"""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from .integrators import INTEGRATORS, IntegrationError, IntegratorStats, StepBudgetError, make_integrator
from .integrator_choice import AUTO, choose_integrator, is_auto
from .stability import FIXED_STEP, StepWarning, check_fixed_step, diagnose, preflight, step_alternatives, stiff_mode
from .systems.base import System, SystemOutputs


class CommandError(ValueError):
    """A command that was refused; the message says what was expected. The state is unchanged."""


class SimulationError(RuntimeError):
    """The simulation cannot continue (non-finite state, failed integrator); the last good state is kept."""


@dataclass
class CommandPort:
    """Zero-order-hold storage of one input port.

    value: (size,) last accepted command (as received); applied: (size,) what the actuators
    apply, the command clamped to the port's effort limits (``InputPort.limit``); stamp:
    simulation time (s) it arrived (None = never); rejected: count of refused commands;
    clamped: count of command components clamped so far; timed_out: True while the timeout
    holds it at zero; limit: the port's effort limits as an array (None = none).
    """

    value: np.ndarray
    stamp: float | None = None
    rejected: int = 0
    timed_out: bool = False
    applied: np.ndarray | None = None
    clamped: int = 0
    limit: np.ndarray | None = None

    def __post_init__(self):
        if self.applied is None:   # nothing clamped yet: the actuators apply the command as held
            self.applied = self.value


@dataclass
class Diagnostics:
    """Running figures of a simulation, published on ``diagnostics`` and printed in summaries.

    energy0: total energy at start (J); work: ∫ (input power − dissipation) dt (J), integrated
    with the state; work_parts: name -> the part of ``work`` done by one element, integrated
    with the state by the same quadrature (the system's ``work_components``, e.g. ``limit``:
    the joint-limit moments); steps, rhs_evals, rejected_steps: integrator statistics; wall: wall time
    spent in advance() (s; on run_headless's block path, in its compiled calls, which also evaluate
    the scripted commands and compute the outputs); sim_time: simulated time (s);
    velocity_limit_exceeded: published joint-velocity samples above their joint's velocity limit
    (URDF ``<limit velocity>``);
    block_periods: periods run by :func:`run_headless`'s block path (many per compiled call;
    not published: a figure for benchmarks and tests).
    """

    energy0: float = 0.0
    work: float = 0.0
    work_parts: dict = field(default_factory=dict)
    steps: int = 0
    rhs_evals: int = 0
    rejected_steps: int = 0
    wall: float = 0.0
    sim_time: float = 0.0
    velocity_limit_exceeded: int = 0
    block_periods: int = 0
    extra: dict = field(default_factory=dict)


def build_integrator(system: System, name: str, dt=None, rtol=None, atol=None):
    """An integrator for ``system``: dt for fixed-step methods, rtol/atol for adaptive ones.

    system: supplies ``nq`` and ``config_rate`` for the symplectic Euler split; name: registry
    name; the arguments that do not apply to the chosen kind are ignored (scene defaults may
    carry both).
    """
    spec = INTEGRATORS.get(str(name).lower())
    if spec is None:
        raise ValueError(f'unknown integrator {name!r}; valid names: {", ".join(INTEGRATORS)}')
    if spec.kind == 'fixed':
        kw = {'dt': dt}
        if spec.name == 'semi_implicit_euler':
            kw.update(nq=system.nq, qdot=system.config_rate)
        return make_integrator(spec.name, **kw)
    return make_integrator(spec.name, rtol=rtol, atol=atol)


#: largest stable ``h/τ`` of the fixed-step explicit methods on a decaying mode ``ẏ = −y/τ`` (the
#: real-axis extent of their stability regions: Euler 2, classical RK4 2.785)
STABILITY_LIMIT = {'euler': 2.0, 'semi_implicit_euler': 2.0, 'rk4': 2.785}


def check_step(system: System, integrator: str, dt, y, u=None):
    """Refuse a fixed explicit step that the system's fastest time constant makes unstable.

    system: supplies ``fastest_time_constant(y)`` (s); integrator: registry name; dt: its step
    (s); y: the state it starts from; u: the inputs (default zeros). Error-controlled integrators always pass (they adapt or are
    stable); rosenbrock2 is checked on what it leaves explicit (``stability.analyse_step``). Policy: refuse, do not sub-step silently — raises ValueError
    naming the time constant, the largest stable step and the alternatives. Beyond the declared
    time constant, :func:`robodyn_ros.stability.check_fixed_step` checks the modes of the
    linearisation at y (finite differences) and the spin of a free base: it refuses a step that
    amplifies one of them by more than ``stability.REFUSE_GROWTH`` per step and warns
    (``stability.StepWarning``) on a slow spurious growth (explicit Euler on an oscillation).
    """
    name = str(integrator).lower()
    if dt is None or name not in FIXED_STEP:
        return
    limit = STABILITY_LIMIT.get(name)   # explicit methods: the declared time constant first
    tau = float(system.fastest_time_constant(y)) if limit is not None else math.inf
    if limit is not None and dt > limit * tau:
        raise ValueError(f'{name} with dt={dt:g} s is unstable for this system: its fastest time constant is '
                         f'{tau:.3g} s ({type(system).__name__}'
                         f'{getattr(system, "time_constant_words", "") or "; e.g. motor electrics L/R"}), '
                         f'so a stable {name} step is at most {limit * tau:.3g} s. '
                         f'{step_alternatives(system, dt, y, u)}')
    check_fixed_step(system, name, dt, y, u)


#: default step budget of the error-controlled integrators: accepted steps per simulated second.
#: The bundled scenes take at most 1.4e3 under rk45 or dop853 at the default tolerances
#: (huston_human17), the stiffest runs of the tests 1.7e4 (dop853 on a 1e-9 kg·m² link, rk45 on
#: 5.9 µs motor electrics: the numerical-extremes table): 12x below this
STEP_BUDGET = 2e5
#: simulated seconds of budget a run may spend at once (its bursts: a first step found by trial,
#: an impact): over any stretch of W seconds a run takes at most ``budget * (W + STEP_BURST)`` steps
STEP_BURST = 0.05


def check_step_budget(value, what='step_budget') -> float | None:
    """A step budget as given (steps per simulated second, > 0; ``inf`` = none; None = the default)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0 or math.isnan(value):
        raise ValueError(f'{what} must be a number of steps per simulated second > 0 (inf: no budget), got {value!r}')
    return float(value)


class Simulator:
    """Integrates a :class:`System` in control periods, holding commands between them.

    system: what to simulate; y0: initial state (ny,); integrator: name ('rk4', 'dop853', ...) or
    ``'auto'`` (:mod:`robodyn_ros.integrator_choice`: rk4, rosenbrock2 or radau from the step analysis at
    y0; ``choice`` holds what it chose and why, ``settings`` the chosen method); dt, rtol, atol: step or
    tolerances for that integrator; command_timeout: seconds of simulation time after which an
    unrefreshed command goes to zero (None = hold forever); t0: start time (s); step_budget: accepted
    steps per simulated second an error-controlled integrator may take (None: :data:`STEP_BUDGET`;
    inf: no budget), counted as a token bucket that holds ``STEP_BURST`` seconds' worth: a run that
    spends it stops with the stiff mode named (:meth:`advance`) instead of creeping on at an explicit
    method's stability limit for hours.
    """

    def __init__(self, system: System, y0, integrator=AUTO, dt=1e-3, rtol=None, atol=None,
                 command_timeout=None, t0=0.0, step_budget=None):
        self.system = system
        budget = check_step_budget(step_budget)
        self.step_budget = STEP_BUDGET if budget is None else budget
        self.command_timeout = command_timeout
        self._y0 = np.array(y0, dtype=float)
        self._t0 = float(t0)
        specs = getattr(getattr(system, 'model', None), 'specs', ())
        self._velocity_limit_of = {s.joint: s.velocity_limit for s in specs
                                   if getattr(s, 'velocity_limit', None) is not None}   # joint -> rad/s or m/s
        self._vlim_cache = (None, None)
        self.reset()
        preflight(system, self.y, self.t)  # a singular mass matrix or non-finite dy/dt: refused, cause named
        self.choice = None
        u0 = self.held_inputs()   # the inputs in force at the start (a servo's hold of the initial posture)
        if is_auto(integrator):
            self.choice = choose_integrator(system, self.y, dt, rtol, atol, self.t, u=u0)
            integrator, dt, rtol, atol = self.choice.integrator, self.choice.dt, self.choice.rtol, self.choice.atol
            if self.choice.analysis is not None and self.choice.analysis.verdict == 'warn':
                warnings.warn(StepWarning(self.choice.analysis.message), stacklevel=2)
        else:
            check_step(system, integrator, dt, self.y, u0)
        self.settings = {'integrator': integrator, 'dt': dt, 'rtol': rtol, 'atol': atol,
                         'command_timeout': command_timeout}
        if self.choice is not None:
            self.settings['auto'] = self.choice.reason
        self.integrator = build_integrator(system, integrator, dt=dt, rtol=rtol, atol=atol)

    # -- state ---------------------------------------------------------------------------
    def reset(self):
        """Back to the initial state and time; commands cleared, diagnostics restarted."""
        if self._y0.shape != (self.system.ny,) or not np.all(np.isfinite(self._y0)):
            raise SimulationError(f'initial state must be {self.system.ny} finite numbers, got {self._y0!r}')
        self.t = self._t0
        self.system.reset_episode()
        self.y = self.system.project(self._y0.copy())
        self.ports = {}
        for k, p in self.system.inputs.items():
            value, applied = self.system.initial_input(k, self.y, self.t)   # zeros but for a servo's setpoints
            self.ports[k] = CommandPort(value, applied=applied,
                                        limit=None if p.limit is None else np.asarray(p.limit, dtype=float))
        self.diag = Diagnostics(energy0=self.system.total_energy(self.y))
        self._work_parts = tuple(getattr(self.system, 'work_components', ()))
        self.diag.work_parts = {k: 0.0 for k in self._work_parts}
        self._velocity_checked_at = None
        self._step_tokens = self.step_budget * STEP_BURST   # the step budget's bucket (see the class)
        self.failed: str | None = None

    # -- commands ------------------------------------------------------------------------
    def set_command(self, port: str, values, t: float | None = None):
        """Accept a command for ``port`` (held until the next one) or raise :class:`CommandError`.

        port: input name; values: sequence of floats of the port's size; t: arrival time
        (simulation seconds, default now). A refused command is counted and changes nothing.
        """
        if port not in self.ports:
            raise CommandError(f'unknown input {port!r}; this system takes {sorted(self.ports)}')
        spec = self.system.inputs[port]
        now = self.t if t is None else float(t)
        if spec.kind == 'message':   # a structured command (a trajectory) onto what its target port applies
            target = self.ports[spec.target]
            try:
                applied = self.system.accept_input(port, values, now, target.applied)
            except ValueError as e:
                self.ports[port].rejected += 1
                raise CommandError(f'{port}: {e}') from None
            p = self.ports[port]
            p.value = p.applied = values
            p.stamp = target.stamp = now
            target.applied = applied
            return
        try:
            arr = np.asarray(values, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            self.ports[port].rejected += 1
            raise CommandError(f'{port}: expected {spec.size} numbers ({", ".join(spec.labels)}) in '
                               f'{spec.unit}, got {values!r}') from None
        if arr.shape != (spec.size,):
            self.ports[port].rejected += 1
            raise CommandError(f'{port}: expected {spec.size} values ({", ".join(spec.labels)}) in {spec.unit}, '
                               f'got {arr.size}')
        if not all(map(math.isfinite, arr.tolist())):   # (a tenth of np.isfinite's cost on a few values)
            self.ports[port].rejected += 1
            bad = [spec.labels[k] for k in np.flatnonzero(~np.isfinite(arr))]
            raise CommandError(f'{port}: non-finite value for {bad}; expected {spec.size} finite values '
                               f'({", ".join(spec.labels)}) in {spec.unit}')
        p = self.ports[port]
        if spec.kind == 'setpoint':   # what the system makes of it (a servo's setpoint program), held
            p.applied = self.system.accept_input(port, arr, now, p.applied)
            p.value = arr
            p.stamp = now
            return
        p.value = arr
        p.applied = arr
        if spec.limit is not None:  # actuator effort limits: clamp, and count the clamped components
            lim = p.limit
            over = np.abs(arr) > lim
            if over.any():
                p.applied = np.clip(arr, -lim, lim)
                p.clamped += int(over.sum())
        p.stamp = self.t if t is None else float(t)
        p.timed_out = False

    def held_inputs(self) -> dict:
        """Stage 1: the inputs in force now (zero-order hold; zero after the timeout)."""
        u = {}
        for k, p in self.ports.items():
            stale = (self.command_timeout is not None and p.stamp is not None
                     and self.t - p.stamp > self.command_timeout + 1e-12
                     and self.system.inputs[k].kind == 'vector')   # setpoints and trajectories hold
            if stale and not p.timed_out:
                p.timed_out = True
            u[k] = np.zeros_like(p.value) if p.timed_out else p.applied
        return u

    @property
    def rejected_commands(self) -> int:
        """Total refused commands over all ports."""
        return sum(p.rejected for p in self.ports.values())

    # -- stepping ------------------------------------------------------------------------
    def _work_state(self) -> np.ndarray:
        """``[y, W, W_parts]``: the state with the work quadrature, as the integrators advance it."""
        ny = self.system.ny
        z = np.empty(ny + 1 + len(self._work_parts))
        z[:ny] = self.y
        z[ny] = self.diag.work
        for k, name in enumerate(self._work_parts):
            z[ny + 1 + k] = self.diag.work_parts[name]
        return z

    def _integrate(self, u, t1):
        """Stage 2: integrate ``[y; W; W_parts]`` from self.t to t1 with u held (W = work done on the
        system, W_parts: the parts of it listed in ``system.work_components``, kept in diag.work_parts).

        Returns ``(y1, W1, stats)``. The fused path checks finiteness itself (it raises otherwise):
        the array it returns is noted in ``_verified`` so that :meth:`advance` need not check again.
        """
        sys_ = self.system
        ny = sys_.ny
        integ = self.integrator
        parts = self._work_parts
        z0 = self._work_state()
        fused = getattr(sys_, 'fused_advance', None)
        if fused is not None and integ.spec.kind == 'fixed':
            # fast path: the system runs the same method, grid and projection in compiled code
            res = fused(integ.name, integ.dt, self.t, z0, t1, u)
            if res is not None:
                z1, st = res
                integ.stats.accumulate(st)
                self._verified = z1
                self._parts_z = z1[ny + 1:]
                return z1[:ny], z1[ny], st

        def f(t, z):
            y = z[:ny]
            dz = np.empty(z.shape[0])
            dz[:ny] = sys_.rhs(t, y, u)
            dz[ny] = sys_.input_power(t, y, u)
            if parts:
                dz[ny + 1:] = sys_.work_component_powers(t, y, u)
            return dz

        def project(z):
            z[:ny] = sys_.project(z[:ny])
            return z

        if integ.name == 'rosenbrock2':   # its W-matrix: the system's passive Jacobian, inputs held over the call
            integ.jac = self._passive_jacobian(u, ny, z0.shape[0])
            integ.dfdt = self._time_derivative(u, ny, z0.shape[0])
        limit = None
        if integ.spec.kind == 'adaptive' and math.isfinite(self.step_budget):
            limit = max(1, int(self._step_tokens + self.step_budget * (t1 - self.t)))
        z1, st = integ.advance(f, self.t, z0, t1, project=project, max_steps=limit)
        if limit is not None:
            self._step_tokens = min(self.step_budget * STEP_BURST, limit - st.steps)
        self._parts_z = z1[ny + 1:]
        return z1[:ny], z1[ny], st

    def _passive_jacobian(self, u, ny, n):
        """``jac(t, z)`` (n, n) for rosenbrock2 on ``z = [y, W, W_parts]``: the system's passive Jacobian
        in the y block (``System.passive_jacobian`` at the inputs u), zeros elsewhere; None without one."""
        sys_ = self.system
        h = self.integrator.dt
        if sys_.passive_jacobian(self.t, self.y, u, h) is None:
            return None

        def jac(t, z):
            out = np.zeros((n, n))
            out[:ny, :ny] = sys_.passive_jacobian(t, z[:ny], u, h)
            return out
        return jac

    def _time_derivative(self, u, ny, n):
        """``dfdt(t, z)`` (n,) for rosenbrock2's time term: the system's ``time_derivative`` in the y block
        (a servo on a moving setpoint), zeros elsewhere; None when the system has none."""
        sys_ = self.system
        if sys_.time_derivative(self.t, self.y, u) is None:
            return None

        def dfdt(t, z):
            out = np.zeros(n)
            out[:ny] = sys_.time_derivative(t, z[:ny], u)
            return out
        return dfdt

    def advance(self, t1: float):
        """Advance to simulation time ``t1`` (s) holding the current inputs; returns the state.

        Raises :class:`SimulationError` (and keeps the last good state) if the integrator fails
        or the state becomes non-finite; afterwards the simulator refuses to advance until reset.
        """
        if self.failed:
            raise SimulationError(self.failed)
        if t1 < self.t - 1e-12:
            raise ValueError(f'cannot advance backwards from t={self.t} to t={t1}')
        if t1 <= self.t:
            return self.y
        u = self.held_inputs()
        w0 = time.perf_counter()
        try:
            self._verified = None
            y1, work, st = self._integrate(u, t1)
        except StepBudgetError as e:
            self.failed = self._over_budget(e, u)
            raise SimulationError(self.failed) from e
        except (IntegrationError, np.linalg.LinAlgError, FloatingPointError, ZeroDivisionError) as e:
            # LinAlgError/FloatingPointError come from the system's own solves (a mass matrix or
            # constraint system that became singular); all of them stop the run with the cause
            what = 'integration failed' if isinstance(e, IntegrationError) else \
                f'the equations of motion could not be solved ({type(e).__name__})'
            self.failed = f'{what} at t={self.t:.6f} s: {e}{self._diagnosis(u)}'
            raise SimulationError(self.failed) from e
        self.diag.wall += time.perf_counter() - w0
        verified = self._verified is not None and y1.base is self._verified  # untouched output of the fused path
        self._verified = None
        if not ((verified or np.all(np.isfinite(y1))) and math.isfinite(work)):
            self.failed = (f'state became non-finite between t={self.t:.6f} and {t1:.6f} s with '
                           f'{self.settings["integrator"]} (dt={self.settings["dt"]}); last good state kept'
                           f'{self._diagnosis(u)}')
            raise SimulationError(self.failed)
        self.diag.steps += st.steps
        self.diag.rhs_evals += st.rhs_evals
        if st.rejected_steps is None or self.diag.rejected_steps is None:
            self.diag.rejected_steps = None  # implicit scipy solvers do not report rejections
        else:
            self.diag.rejected_steps += st.rejected_steps
        self.t, self.y, self.diag.work = float(t1), y1, float(work)
        for k, name in enumerate(self._work_parts):
            self.diag.work_parts[name] = float(self._parts_z[k])
        self.diag.sim_time = self.t - self._t0
        return self.y

    def _over_budget(self, e: StepBudgetError, u) -> str:
        """The message of a run stopped by its step budget: the integrator, the steps it took, the
        stiff mode at the last good state (:func:`robodyn_ros.stability.stiff_mode`) and what to do."""
        name = self.integrator.name
        steps = self.diag.steps + e.steps
        text = (f'{name} spent its step budget: {steps} steps for {e.t - self._t0:.3g} s of simulated time '
                f'(budget {self.step_budget:.3g} steps per simulated second); ')
        mode = stiff_mode(self.system, self.y, u, self.t)
        text += (f'{mode}; ' if mode else '')
        if self.integrator.spec.implicit:
            text += (f'{name} is stable on it, so its error control needs these steps: loosen rtol/atol '
                     'or raise the budget')
        else:
            stiff = ['radau', 'bdf'] + [n for n, s in INTEGRATORS.items() if s.kind == 'fixed' and s.implicit]
            text += (f'an explicit method ({name}) must take steps about as short as that time constant, for '
                     f'as long as the mode lasts: use an implicit integrator ({", ".join(stiff)}), '
                     'or raise the budget')
        return (text + ' (simulation: step_budget in the scene, robodyn run --step-budget, the node\'s '
                'step_budget parameter; inf = none). Last good state kept')

    def _diagnosis(self, u) -> str:
        """``'; <likely cause>'`` of a failure, from the last good state (stability.diagnose)."""
        text = diagnose(self.system, self.y, u, self.settings['integrator'], self.settings['dt'], self.t)
        return f'; {text}' if text else ''

    def outputs(self, wrenches: bool = True) -> SystemOutputs:
        """Stage 4: what the system reports at the current state (wrench solve optional).

        The system's ``extra`` values (motor currents, constraint residuals, ...) are kept in
        ``diag.extra`` so that every diagnostics sink (recorder, node) publishes them.
        """
        out = self.system.outputs(self.t, self.y, self.held_inputs(), wrenches=wrenches)
        self.diag.extra.update(out.extra)
        lim = self._velocity_limits(out.joint_names)
        if lim is not None and self.t != self._velocity_checked_at:  # each published state counted once
            self._velocity_checked_at = self.t
            self.diag.velocity_limit_exceeded += int(np.count_nonzero(np.abs(out.velocity) > lim))
        return out

    def _velocity_limits(self, names):
        """``(len(names),)`` velocity limits of the joint_states entries (inf where none), or None
        when no joint of the system has one (LinkSpec.velocity_limit, from URDF ``<limit velocity>``)."""
        if not self._velocity_limit_of:
            return None
        key = tuple(names)
        if self._vlim_cache[0] != key:
            self._vlim_cache = (key, np.array([self._velocity_limit_of.get(n, np.inf) for n in key]))
        return self._vlim_cache[1]

    def energy_report(self, y=None, work=None) -> dict:
        """Total energy, work done by inputs/dissipation and the drift ``E − E0 − W`` (J), now or
        at another state y with its work (a period of a block, :class:`PeriodBlock`; the work parts
        reported are the current ones)."""
        if y is None:
            y, work = self.y, self.diag.work
        E = self.system.total_energy(y)
        drift = E - self.diag.energy0 - work
        scale = max(abs(self.diag.energy0), abs(E), abs(work), 1e-12)
        out = {'energy': E, 'energy0': self.diag.energy0, 'work': work, 'drift': drift,
               'relative_drift': drift / scale}
        for name, w in self.diag.work_parts.items():   # e.g. limit_work: the joint-limit moments' part of work
            out[f'{name}_work'] = w
        return out

    def diagnostics_values(self, wall_clock: bool = False) -> dict:
        """Flat name -> value map for the ``diagnostics`` topic.

        wall_clock: include figures that depend on the machine's speed (compute real-time
        factor). Off for headless recordings, so that equal runs give byte-identical files.
        """
        e = self.energy_report()
        d = self.diag
        vals = {'sim_time': self.t, 'energy': e['energy'], 'energy_drift': e['drift'],
                'energy_drift_relative': e['relative_drift'], 'work_in': e['work'],
                **{f'{name}_work': w for name, w in d.work_parts.items()},
                'steps': d.steps, 'rhs_evals': d.rhs_evals,
                'rejected_steps': 'unknown' if d.rejected_steps is None else d.rejected_steps,
                'rejected_commands': self.rejected_commands, 'integrator': self.settings['integrator']}
        if wall_clock:
            vals['real_time_factor_compute'] = d.sim_time / d.wall if d.wall > 0 else float('nan')
        for k, p in self.ports.items():
            vals[f'{k}_timed_out'] = p.timed_out
            if self.system.inputs[k].limit is not None:
                vals[f'{k}_clamped'] = p.clamped
        if self._velocity_limit_of:
            vals['velocity_limit_exceeded'] = d.velocity_limit_exceeded
        vals.update(d.extra)
        return vals


def run_headless(sim: Simulator, duration: float, rate: float, script=None, sinks=(), wrenches=None, stop=None):
    """Run ``duration`` s at ``rate`` Hz publications, feeding scripted commands, calling sinks.

    sim: the simulator; duration: seconds of simulation time; rate: publication (and scripted
    command) rate in Hz; script: optional ``script(t, y) -> {port: values}`` evaluated at the
    start of each period and held (zero-order); sinks: objects with ``on_start(sim)``,
    ``on_command(t, port, values)``, ``on_output(t, outputs, sim)`` (a sink asks ``sim`` for
    diagnostics only when it publishes them), ``close()``; a sink whose ``takes_blocks`` is true
    may get many periods at once instead (``block_periods``, ``on_block``: :class:`_BlockRunner`);
    wrenches: compute joint wrenches (default: when some sink wants them, ``sink.wants_wrenches``);
    stop: optional ``stop(t, y) -> bool`` checked after every period's outputs (a scene's
    ``stop_when``): the run ends at the first period where it holds.
    Returns the number of periods run. The final state stays in ``sim``.

    Which command an output carries: the output at the end of a period carries the command held
    over that period. The first period's scripted command is set before the initial state at t0
    is published, so that output carries the command applied from t0 on (README, "The node").
    """
    if rate <= 0 or not math.isfinite(rate):
        raise ValueError(f'rate must be a positive number of Hz, got {rate!r}')
    if wrenches is None:
        wrenches = any(getattr(s, 'wants_wrenches', False) for s in sinks)
    n = int(round(duration * rate))
    for s in sinks:
        s.on_start(sim)

    def feed():  # the scripted command of the period starting now, held over it
        if script is not None:
            for port, values in script(sim.t, sim.y).items():
                sim.set_command(port, values)
                for s in sinks:
                    s.on_command(sim.t, port, sim.ports[port].value)
    # publish the initial state at t0 so a recording starts where the run starts, with the
    # command that is applied from t0 on
    if n > 0:
        feed()
    out = sim.outputs(wrenches=wrenches)
    for s in sinks:
        s.on_output(sim.t, out, sim)
    t_start = sim.t
    blocks = _BlockRunner.plan(sim, script, sinks, stop, wrenches)
    k = 0
    while k < n:
        if blocks is not None and k > 0:   # periods 1.. in compiled blocks; period k on this path
            k = blocks.run(k, n, t_start, rate)   # when a block stops short (or a sink wants it)
            if k >= n:
                break
        if k > 0:
            feed()
        sim.advance(t_start + (k + 1) / rate)
        out = sim.outputs(wrenches=wrenches)
        for s in sinks:
            s.on_output(sim.t, out, sim)
        if stop is not None and stop(sim.t, sim.y):
            return k + 1
        k += 1
    return n


#: publication periods per compiled call of the block path (fewer where a sink needs the
#: Simulator's state, e.g. at a diagnostics message)
BLOCK_PERIODS = 64


@dataclass
class PeriodBlock:
    """K consecutive publication periods run in one compiled call (:class:`_BlockRunner`).

    Period k starts at ``t_cmd[k]`` (its scripted commands, ``commands[port][k]``, are applied
    then) and ends at ``t_out[k]``, where the system's outputs are ``position``, ``velocity``,
    ``effort`` (K, ·) and, when computed, the joint wrenches ``wrenches`` (K, n, 6) in the order
    of ``template.wrenches``; ``odom`` (K, 13: position, orientation, linear, angular) of a system
    that publishes one, and the ground's ``contacts`` (K, nl, 6) in the order of ``template.contacts``
    (else None). template: the SystemOutputs of one such period (names, frames, how wrenches are
    computed), the same for all K. z: (K, ny + 1 + parts) the Simulator's state and work quadrature
    ``[y, W, W_parts]`` at each period's end. The Simulator is at the end of the last one.
    """
    t_cmd: np.ndarray
    t_out: np.ndarray
    commands: dict
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray
    wrenches: np.ndarray | None
    template: SystemOutputs
    z: np.ndarray
    odom: np.ndarray | None = None
    contacts: np.ndarray | None = None


class _BlockRunner:
    """The block path of :func:`run_headless`: many periods per compiled call.

    Taken when the system runs periods in compiled code (``system.fused_periods``: the arms),
    the integrator is fixed-step, the scripted commands have compiled forms (``script.programs``,
    :mod:`robodyn_ros.profiles`) and every sink takes blocks (``sink.takes_blocks``: it has
    ``block_periods`` and ``on_block``, see ``McapRunSink``); not with a ``stop`` condition or a
    command timeout, nor with effort limits unless the system clamps in its loop
    (``system.clamps_in_blocks``; the clamps are counted there, the velocity-limit samples here). The
    numbers are those of the per-period path (same compiled functions, same arithmetic; the
    recordings test compares files byte for byte); a period the compiled loop refuses (a
    non-finite command or state) is redone on the per-period path, which raises as it always has.
    """

    def __init__(self, sim, port, program, sinks, wrenches):
        self.sim, self.port, self.program, self.sinks, self.wrenches = sim, port, program, sinks, wrenches
        self.template = None

    @classmethod
    def plan(cls, sim, script, sinks, stop, wrenches):
        sys_ = sim.system
        if getattr(sys_, 'fused_periods', None) is None or stop is not None or sim.command_timeout is not None \
                or sim.integrator.spec.kind != 'fixed' or len(sys_.inputs) != 1 \
                or not all(getattr(s, 'takes_blocks', False) for s in sinks):
            return None
        (port, spec), = sys_.inputs.items()
        if spec.limit is not None and not getattr(sys_, 'clamps_in_blocks', False):
            return None
        program = None
        if script is not None:
            programs = getattr(script, 'programs', None) or {}
            if set(programs) != {port} or programs[port] is None:
                return None
            program = programs[port]
        # the system may still decline (e.g. joint_states that are not its state as it is): ask with no period
        none = np.zeros(0)
        if sys_.fused_periods(sim.settings['integrator'], sim.integrator.dt, sim._work_state(), none, none,
                              np.array(sim.ports[port].applied, dtype=float), program, wrenches) is None:
            return None
        return cls(sim, port, program, sinks, wrenches)

    def run(self, k: int, n: int, t_start: float, rate: float) -> int:
        """Run periods k.. in blocks; returns the first period not run (n when all are).

        One compiled call runs up to :data:`BLOCK_PERIODS` periods; the sinks then get them in
        pieces that end where one wants the Simulator's state (a diagnostics message), the
        Simulator being put at the end of each piece first, as per-period calls leave it."""
        sim, sys_ = self.sim, self.sim.system
        if self.template is None:
            self.template = sim.outputs(wrenches=self.wrenches)   # names and frames of every period's outputs
        cmd_kind = () if self.program is None else ((self.port, sim.ports[self.port].value.shape[0]),)
        while k < n:
            K = min(BLOCK_PERIODS, n - k)
            t_out = t_start + (np.arange(k, k + K) + 1) / rate    # the per-period path's t_start + (k + 1) / rate
            if any(s.block_periods(t_out, self.template, cmd_kind) <= 0 for s in self.sinks):
                return k   # a sink wants this period on the per-period path
            t_cmd = np.empty(K)
            t_cmd[0] = sim.t
            t_cmd[1:] = t_out[:-1]
            u = np.array(sim.ports[self.port].applied, dtype=float)
            z = sim._work_state()
            w0 = time.perf_counter()
            res = sys_.fused_periods(sim.settings['integrator'], sim.integrator.dt, z, t_cmd, t_out, u,
                                     self.program, self.wrenches)
            sim.diag.wall += time.perf_counter() - w0
            if res is None:
                return k
            done, code = res[0], res[1]
            a = 0
            while a < done:
                b = done
                for s in self.sinks:
                    b = min(b, a + s.block_periods(t_out[a:done], self.template, cmd_kind))
                if b <= a:   # the rest of the block is dropped: the Simulator is at the end of period k + a - 1
                    return k + a
                self._commit(a, b, t_cmd, t_out, res)
                a = b
            k += done
            if code:
                return k
        return n

    def _commit(self, a, b, t_cmd, t_out, res):
        """The Simulator at the end of period b - 1 of the block, as advance() calls leave it;
        the sinks get periods a..b-1."""
        sim, sys_ = self.sim, self.sim.system
        _, _, Zs, Us, outs, Fs, steps = res[:7]
        more = res[7] if len(res) > 7 else {}
        ny = sys_.ny
        z = Zs[b - 1]
        st = IntegratorStats.of_fused_steps(sim.settings['integrator'], int(steps[a:b].sum()), b - a)
        sim.integrator.stats.accumulate(st)
        sim.diag.steps += st.steps
        sim.diag.rhs_evals += st.rhs_evals
        sim.diag.block_periods += b - a
        sim.t, sim.y, sim.diag.work = float(t_out[b - 1]), z[:ny].copy(), float(z[ny])
        for j, name in enumerate(sim._work_parts):
            sim.diag.work_parts[name] = float(z[ny + 1 + j])
        sim.diag.sim_time = sim.t - sim._t0
        commands = {}
        if self.program is not None:
            p = sim.ports[self.port]
            p.value = Us[b - 1].copy()
            p.applied = p.value if p.limit is None else np.clip(p.value, -p.limit, p.limit)
            p.stamp = float(t_cmd[b - 1])
            p.timed_out = False
            if p.limit is not None:   # the clamped components of these periods' commands, as set_command counts them
                p.clamped += int(np.count_nonzero(np.abs(Us[a:b]) > p.limit))
            commands[self.port] = Us[a:b]
        position, velocity, effort = outs
        lim = sim._velocity_limits(self.template.joint_names)
        if lim is not None:   # each published state's velocities against their limits, as Simulator.outputs counts them
            sim.diag.velocity_limit_exceeded += int(np.count_nonzero(np.abs(velocity[a:b]) > lim))
            sim._velocity_checked_at = sim.t
        extra = getattr(sys_, 'state_extra', None)
        if extra is not None:   # what outputs() would have put in diag.extra at the last state
            sim.diag.extra.update(extra(sim.y))
        odom, contacts = more.get('odom'), more.get('contacts')
        block = PeriodBlock(t_cmd=t_cmd[a:b], t_out=t_out[a:b], commands=commands, position=position[a:b],
                            velocity=velocity[a:b], effort=effort[a:b], wrenches=None if Fs is None else Fs[a:b],
                            template=self.template, z=Zs[a:b], odom=None if odom is None else odom[a:b],
                            contacts=None if contacts is None else contacts[a:b])
        for s in self.sinks:
            s.on_block(block, sim)