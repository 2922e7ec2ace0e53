"""The Simulator: advance(t) as a short pipeline of stages, with invariants and diagnostics.

One control period is::

    u  = held_inputs()                       # commands.CommandPorts: zero-order hold, timeout to zero
    y  = integrate(system, y, u, t -> t1)    # the plan's integrator, energy-work quadrature
    guard_finite(y)                          # never keep a non-finite state
    out = system.outputs(t1, y, u)           # joint states, wrenches, odometry, energies
    sinks(out, diagnostics)                  # recorder, ROS publishers (reporting.Diagnostics)

Which integrator, which step and why is decided once, before the first period, by
:func:`robodyn_ros.integrator_choice.plan_integrator` (the Simulator asks it, or is handed the plan
its caller made). :func:`run_headless` runs periods with scripted commands, many per compiled call
where it can (:mod:`robodyn_ros.blocks`).

No ROS here: nodes and the recorder are sinks the simulator calls, stamped with simulation time.
"""
from __future__ import annotations

import math
import time
import warnings

import numpy as np

from .blocks import BlockRunner
from .commands import CommandError, CommandPort, CommandPorts
from .integrator_choice import AUTO, DEFAULT_DT, IntegratorPlan, StepBudget, plan_integrator
from .integrators import IntegrationError, StepBudgetError
from .reporting import Diagnostics, VelocityLimits
from .stability import StepWarning, diagnose
from .systems.base import System, SystemOutputs

__all__ = ['Simulator', 'SimulationError', 'CommandError', 'CommandPort', 'run_headless']


class SimulationError(RuntimeError):
    """The simulation cannot continue (non-finite state, failed integrator); the last good state is kept."""


class Simulator:
    """Integrates a :class:`System` in control periods, holding commands between them.

    system: what to simulate; y0: initial state (ny,); integrator: name ('rk4', 'dop853', ...) or
    ``'auto'`` (rk4, rosenbrock2 or radau from the step analysis at y0); dt, rtol, atol: step or
    tolerances for that integrator; command_timeout: seconds of simulation time after which an
    unrefreshed command goes to zero (None = hold forever); t0: start time (s); step_budget: accepted
    steps per simulated second an error-controlled integrator may take (None: the default
    ``integrator_choice.STEP_BUDGET``; inf: no budget): a run that spends it stops with the stiff mode
    named (:meth:`advance`) instead of creeping on at an explicit method's stability limit for hours;
    plan: the :class:`~robodyn_ros.integrator_choice.IntegratorPlan` its caller made for this system at
    y0 and t0 (then integrator, dt, rtol, atol and step_budget are not read); without one the Simulator
    asks :func:`~robodyn_ros.integrator_choice.plan_integrator` itself, at its initial state.

    ``plan`` holds the decision (method, step, budget, and why); ``settings`` the method's settings
    (with ``auto``: the reason, when auto chose); ``choice`` the plan when auto chose, else None.
    """

    def __init__(self, system: System, y0, integrator=AUTO, dt=DEFAULT_DT, rtol=None, atol=None,
                 command_timeout=None, t0=0.0, step_budget=None, plan: IntegratorPlan | None = None):
        self.system = system
        self._command_timeout = command_timeout
        self._y0 = np.array(y0, dtype=float)
        self._t0 = float(t0)
        self.velocity_limits = VelocityLimits(system)
        self._budget = None
        self.reset()
        if plan is None:
            plan = plan_integrator(system, self.y, integrator, dt, rtol, atol, step_budget, self.t)
        self.plan = plan
        for text in plan.warnings:
            warnings.warn(StepWarning(text), stacklevel=2)
        self.step_budget = plan.step_budget
        self._budget = StepBudget(plan.step_budget)
        self.settings = {**plan.settings(), 'command_timeout': command_timeout}
        self.integrator = plan.build(system)

    @property
    def choice(self) -> IntegratorPlan | None:
        """The plan when ``auto`` chose the integrator (its ``reason`` says why), else None."""
        return self.plan if self.plan.auto else None

    # -- state ---------------------------------------------------------------------------
    def reset(self):
        """Back to the initial state and time; commands cleared, diagnostics restarted."""
        if self._y0.shape != (self.system.ny,) or not np.all(np.isfinite(self._y0)):
            raise SimulationError(f'initial state must be {self.system.ny} finite numbers, got {self._y0!r}')
        self.t = self._t0
        self.system.reset_episode()
        self.y = self.system.project(self._y0.copy())
        self.commands = CommandPorts(self.system, self._command_timeout, self.y, self.t)
        self.diag = Diagnostics(energy0=self.system.total_energy(self.y))
        self._work_parts = tuple(getattr(self.system, 'work_components', ()))
        self.diag.work_parts = {k: 0.0 for k in self._work_parts}
        self.velocity_limits.reset()
        if self._budget is not None:
            self._budget.reset()
        self.failed: str | None = None

    def work_state(self) -> np.ndarray:
        """``[y, W, W_parts]`` (ny + 1 + parts,): the state with the work quadrature, as the integrators
        advance it."""
        ny = self.system.ny
        z = np.empty(ny + 1 + len(self._work_parts))
        z[:ny] = self.y
        z[ny] = self.diag.work
        for k, name in enumerate(self._work_parts):
            z[ny + 1 + k] = self.diag.work_parts[name]
        return z

    def arrive(self, t1: float, y1: np.ndarray, z1: np.ndarray):
        """The Simulator at time t1 (s) in state y1 (ny,), with the work and its parts of the work state
        z1 (:meth:`work_state`'s layout; y1 is its first ny values)."""
        ny = self.system.ny
        self.t, self.y, self.diag.work = float(t1), y1, float(z1[ny])
        for k, name in enumerate(self._work_parts):
            self.diag.work_parts[name] = float(z1[ny + 1 + k])
        self.diag.sim_time = self.t - self._t0

    # -- commands ------------------------------------------------------------------------
    @property
    def command_timeout(self) -> float | None:
        """Seconds of simulation time after which an unrefreshed command goes to zero (None: never)."""
        return self._command_timeout

    @command_timeout.setter
    def command_timeout(self, value):
        self._command_timeout = value
        self.commands.timeout = value

    @property
    def ports(self) -> dict:
        """Input name -> its :class:`~robodyn_ros.commands.CommandPort` (held command, counts)."""
        return self.commands.ports

    def set_command(self, port: str, values, t: float | None = None):
        """Accept a command for ``port`` (held until the next one) or raise :class:`CommandError`.

        port: input name; values: sequence of floats of the port's size; t: arrival time
        (simulation seconds, default now). A refused command is counted and changes nothing
        (:meth:`robodyn_ros.commands.CommandPorts.set`).
        """
        self.commands.set(port, values, self.t if t is None else t)

    def held_inputs(self) -> dict:
        """Stage 1: the inputs in force now (zero-order hold; zero after the timeout)."""
        return self.commands.held(self.t)

    @property
    def rejected_commands(self) -> int:
        """Total refused commands over all ports."""
        return self.commands.rejected

    # -- stepping ------------------------------------------------------------------------
    def _integrate(self, u, t1):
        """Stage 2: integrate ``z = [y; W; W_parts]`` from self.t to t1 with u held (W = work done on the
        system, W_parts: the parts of it listed in ``system.work_components``, kept in diag.work_parts).

        Returns ``(z1, stats, verified)``; verified: the fused path checked z1's finiteness itself (it
        raises otherwise), so that :meth:`advance` need not check again.
        """
        sys_ = self.system
        ny = sys_.ny
        integ = self.integrator
        parts = self._work_parts
        z0 = self.work_state()
        fused = getattr(sys_, 'fused_advance', None)
        tol = getattr(integ, 'tolerance', None)   # rosenbrock2 under error control: (rtol, atol)
        if tol is not None and not getattr(sys_, 'fused_tolerance', False):
            fused = None
        if fused is not None and integ.spec.kind == 'fixed':
            # fast path: the system runs the same method, grid and projection in compiled code
            if tol is None:
                res = fused(integ.name, integ.dt, self.t, z0, t1, u)
            else:   # under error control, within the step budget
                limit = self._budget.limit(t1 - self.t)
                res = fused(integ.name, integ.dt, self.t, z0, t1, u, tol=tol + (limit,))
                if res is not None and limit is not None:
                    self._budget.spend(limit, res[1].steps)
            if res is not None:
                z1, st = res
                integ.stats.accumulate(st)
                return z1, st, True

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
            integ.controlled = ny   # its error control (under a tolerance) measures y, not the work
            integ.jac = self._passive_jacobian(u, ny, z0.shape[0])
            integ.dfdt = self._time_derivative(u, ny, z0.shape[0])
        limit = self._budget.limit(t1 - self.t) if integ.spec.kind == 'adaptive' or tol is not None else None
        z1, st = integ.advance(f, self.t, z0, t1, project=project, max_steps=limit)
        if limit is not None:
            self._budget.spend(limit, st.steps)
        return z1, st, False

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
            z1, st, verified = self._integrate(u, t1)
        except StepBudgetError as e:
            self.failed = self.plan.over_budget(self.system, self.y, u, self.t, self.diag.steps + e.steps,
                                                e.t - self._t0)
            raise SimulationError(self.failed) from e
        except (IntegrationError, np.linalg.LinAlgError, FloatingPointError, ZeroDivisionError) as e:
            # LinAlgError/FloatingPointError come from the system's own solves (a mass matrix or
            # constraint system that became singular); all of them stop the run with the cause
            what = 'integration failed' if isinstance(e, IntegrationError) else \
                f'the equations of motion could not be solved ({type(e).__name__})'
            self.failed = f'{what} at t={self.t:.6f} s: {e}{self._diagnosis(u)}'
            raise SimulationError(self.failed) from e
        self.diag.wall += time.perf_counter() - w0
        ny = self.system.ny
        y1 = z1[:ny]
        if not ((verified or np.all(np.isfinite(y1))) and math.isfinite(z1[ny])):   # stage 3: the guard
            self.failed = (f'state became non-finite between t={self.t:.6f} and {t1:.6f} s with '
                           f'{self.settings["integrator"]} (dt={self.settings["dt"]}); last good state kept'
                           f'{self._diagnosis(u)}')
            raise SimulationError(self.failed)
        self.diag.count(st)
        self.arrive(t1, y1, z1)
        return self.y

    def _diagnosis(self, u) -> str:
        """``'; <likely cause>'`` of a failure, from the last good state (stability.diagnose)."""
        text = diagnose(self.system, self.y, u, self.settings['integrator'], self.settings['dt'], self.t)
        return f'; {text}' if text else ''

    # -- outputs and reports -------------------------------------------------------------
    def outputs(self, wrenches: bool = True) -> SystemOutputs:
        """Stage 4: what the system reports at the current state (wrench solve optional).

        The system's ``extra`` values (motor currents, constraint residuals, ...) are kept in
        ``diag.extra`` so that every diagnostics sink (recorder, node) publishes them; the published
        velocities above their limits are counted once per state.
        """
        out = self.system.outputs(self.t, self.y, self.held_inputs(), wrenches=wrenches)
        self.diag.extra.update(out.extra)
        self.diag.velocity_limit_exceeded += self.velocity_limits.count(self.t, out.joint_names, out.velocity)
        return out

    def energy_report(self, y=None, work=None) -> dict:
        """Total energy, work done by inputs/dissipation and the drift ``E − E0 − W`` (J), now or
        at another state y with its work (a period of a block, :class:`~robodyn_ros.blocks.PeriodBlock`;
        the work parts reported are the current ones): :meth:`robodyn_ros.reporting.Diagnostics.energy_report`."""
        if y is None:
            y, work = self.y, self.diag.work
        return self.diag.energy_report(self.system.total_energy(y), work)

    def diagnostics_values(self, wall_clock: bool = False) -> dict:
        """Flat name -> value map for the ``diagnostics`` topic (:meth:`robodyn_ros.reporting.Diagnostics.values`).

        wall_clock: include figures that depend on the machine's speed (compute real-time
        factor). Off for headless recordings, so that equal runs give byte-identical files.
        """
        return self.diag.values(self.t, self.energy_report(), self.commands, self.settings['integrator'],
                                wall_clock, bool(self.velocity_limits))


def run_headless(sim: Simulator, duration: float, rate: float, script=None, sinks=(), wrenches=None, stop=None,
                 pipeline=True, halt=None):
    """Run ``duration`` s at ``rate`` Hz publications, feeding scripted commands, calling sinks.

    sim: the simulator; duration: seconds of simulation time; rate: publication (and scripted
    command) rate in Hz; script: optional ``script(t, y) -> {port: values}`` evaluated at the
    start of each period and held (zero-order); sinks: objects with ``on_start(sim)``,
    ``on_command(t, port, values)``, ``on_output(t, outputs, sim)`` (a sink asks ``sim`` for
    diagnostics only when it publishes them), ``close()``; a sink whose ``takes_blocks`` is true
    may get many periods at once instead (``block_periods``, ``on_block``: :class:`~robodyn_ros.blocks.BlockRunner`);
    wrenches: compute joint wrenches (default: when some sink wants them, ``sink.wants_wrenches``);
    stop: optional ``stop(t, y) -> bool`` checked after every period's outputs (a scene's
    ``stop_when``): the run ends at the first period where it holds; pipeline: the block path may compute
    its next blocks on a second thread while the sinks take one (:data:`~robodyn_ros.blocks.PIPELINE`; the
    same numbers either way); halt: optional ``halt() -> bool``, asked where the sinks have every period
    up to the Simulator's state (after each period, or each piece of a block): the run ends there when it
    holds (a Ctrl-C's flag: the recording then ends exactly at ``sim.t``).
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
    blocks = BlockRunner.plan(sim, script, sinks, stop, wrenches, pipeline, halt)
    k = 0
    while k < n:
        if halt is not None and halt():
            return k
        if blocks is not None and k > 0:   # periods 1.. in compiled blocks; period k on this path
            k = blocks.run(k, n, t_start, rate)   # when a block stops short (or a sink wants it)
            if k >= n or (halt is not None and halt()):
                return k
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
