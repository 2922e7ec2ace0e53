"""The block path of :func:`robodyn_ros.simulation.run_headless`: many publication periods per compiled call.

A headless run of an arm with compiled scripted commands does not need to return to Python at every
period: :class:`BlockRunner` asks the system to run up to :data:`BLOCK_PERIODS` periods in one
compiled call (``system.fused_periods``), which evaluates the scripted commands, integrates and
computes the outputs of each period, and hands the sinks the periods as a :class:`PeriodBlock`. The
numbers are those of the per-period path (the same compiled functions, the same arithmetic): the
recording and the final Simulator equal it byte for byte (``test/test_block_path.py``). The
Simulator is put at the end of each piece handed to the sinks (:meth:`Simulator.arrive
<robodyn_ros.simulation.Simulator.arrive>`), as per-period calls leave it.

Computing ahead (:data:`PIPELINE`): while the sinks take a block, a second thread computes the
blocks after it (:class:`_Ahead`; the compiled loop releases the GIL), each from the state, command
and time the one before ends with. A block so computed is used only when the Simulator is then
found exactly there (the same bits of state, work, command and time) and the sinks take it; else it
and those after it are dropped and the block is computed again as without. The numbers are thus the
same, and a recording the same bytes (``test/test_block_path.py``); a recorded run's wall time comes
near the larger of integrating and recording instead of their sum.
"""
from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass

import numpy as np

from .integrators import IntegratorStats
from .systems.base import SystemOutputs

__all__ = ['BLOCK_PERIODS', 'PeriodBlock', 'BlockRunner']

#: publication periods per compiled call of the block path (fewer where a sink needs the
#: Simulator's state, e.g. at a diagnostics message)
BLOCK_PERIODS = 64
#: compute the next blocks while the sinks take one (module docstring), where there are sinks, the kernels
#: are machine code and this process has more than one CPU; ``$ROBODYN_PIPELINE=0`` turns it off
PIPELINE = os.environ.get('ROBODYN_PIPELINE', '1') != '0'
#: blocks computed ahead at most before the sinks take them (two recorder batches of 1024 periods: a recorder
#: encodes and compresses a batch at once, while the loop goes on)
AHEAD = 32


def _block_port(system) -> tuple:
    """``(port, others)``: the input port whose command the compiled loop applies (the only one, or the effort port
    of an arm with a joint servo, whose setpoint ports are held over a block), or ``(None, ())``."""
    ports = list(system.inputs)
    if len(ports) == 1:
        return ports[0], ()
    if 'effort' in ports and getattr(system, 'servo', None) is not None:
        return 'effort', tuple(p for p in ports if p != 'effort')
    return None, ()


def _held(sim, others) -> dict:
    """``fused_periods``' keyword for a system with other ports or sensors (whose readings depend on every input):
    ``{'held': the inputs held now}``, else none."""
    return {'held': sim.held_inputs()} if others or getattr(sim.system, 'sensors', None) is not None else {}


def _pipelines() -> bool:
    """True when the block path computes ahead (:data:`PIPELINE`): the loop is machine code then (numba
    loaded; interpreted kernels hold the GIL) and a second CPU can run it."""
    from .kernels import jit
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:   # (not on Linux)
        cpus = os.cpu_count() or 1
    return PIPELINE and jit.LOADED and cpus > 1


@dataclass
class PeriodBlock:
    """K consecutive publication periods run in one compiled call (:class:`BlockRunner`).

    Period k starts at ``t_cmd[k]`` (its scripted commands, ``commands[port][k]``, are applied
    then) and ends at ``t_out[k]``, where the system's outputs are ``position``, ``velocity``,
    ``effort`` (K, ·) and, when computed, the joint wrenches ``wrenches`` (K, n, 6) in the order
    of ``template.wrenches``; ``odom`` (K, 13: position, orientation, linear, angular) of a system
    that publishes one, and the ground's ``contacts`` (K, nl, 6) in the order of ``template.contacts``
    and every contact point's outputs ``points`` (K, np, NP) (``ArmSystem.contact_point_outputs`` of each
    period's end) (else None); ``control``: per period the servo's and sensors' ``(messages, imu_poses, ft_wrenches)``
    (``ArmSystem.control_outputs``; else None). template: the SystemOutputs of one such period (names, frames, how wrenches are
    computed), the same for all K. z: (K, ny + 1 + parts) the Simulator's state and work quadrature
    ``[y, W, W_parts]`` at each period's end. The Simulator is at the end of the last one, or, with
    ``arrive`` (a callable, :meth:`BlockRunner.run`'s lone sink), ``arrive(j)`` puts it at the end of
    period j (forward only; at the end of the last one after ``on_block``).
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
    arrive: object = None
    control: list | None = None
    points: np.ndarray | None = None


class BlockRunner:
    """Runs periods of :func:`~robodyn_ros.simulation.run_headless` in compiled blocks.

    Taken when the system runs periods in compiled code (``system.fused_periods``: the arms),
    the integrator is fixed-step, the scripted commands have compiled forms (``script.programs``,
    :mod:`robodyn_ros.profiles`) and every sink takes blocks (``sink.takes_blocks``: it has
    ``block_periods`` and ``on_block``, see ``McapRunSink``); not with a ``stop`` condition or a
    command timeout, nor with effort limits unless the system clamps in its loop
    (``system.clamps_in_blocks``; the clamps are counted there, the velocity-limit samples here). A
    period the compiled loop refuses (a non-finite command or state) is redone on the per-period
    path, which raises as it always has.

    sim: the Simulator; port: its one input port; program: the compiled form of that port's scripted
    command (None: the command held as it is); sinks: the run's sinks; wrenches: compute joint wrenches;
    halt: optional ``halt() -> bool`` asked after each piece the sinks took (the run ends there: a Ctrl-C).
    """

    def __init__(self, sim, port, program, sinks, wrenches, pipeline=True, halt=None):
        self.sim, self.port, self.program, self.sinks, self.wrenches = sim, port, program, sinks, wrenches
        self.pipeline = pipeline   # may compute ahead (:data:`PIPELINE`)
        self.halt = halt
        self.template = None
        self.others, self.due, self.held_kw = (), {}, {}   # ports besides ``port``, their messages' next times (plan)
        self.used = [0]      # blocks computed ahead (:class:`_Ahead`) and taken (tests, benchmarks)
        self.dropped = [0]   # blocks computed ahead and dropped

    @classmethod
    def plan(cls, sim, script, sinks, stop, wrenches, pipeline=True, halt=None):
        """A BlockRunner for this run, or None when the block path does not apply (class docstring);
        pipeline: it may compute blocks ahead (:data:`PIPELINE`; a sweep's runs fill the cores already);
        halt: as the class's."""
        sys_ = sim.system
        if getattr(sys_, 'fused_periods', None) is None or stop is not None or sim.command_timeout is not None \
                or sim.integrator.spec.kind != 'fixed' or getattr(sim.integrator, 'tolerance', None) is not None \
                or not all(getattr(s, 'takes_blocks', False) for s in sinks):
            return None
        port, others = _block_port(sys_)
        if port is None:
            return None
        if sys_.inputs[port].limit is not None and not getattr(sys_, 'clamps_in_blocks', False):
            return None
        program, due = None, {}
        if script is not None:
            programs = getattr(script, 'programs', None) or {}
            sends = getattr(script, 'next_send', None) or {}
            for p in programs:
                if p == port and programs[p] is not None:
                    program = programs[p]
                elif p in others and p in sends:   # messages at given times: blocks end before each
                    due[p] = sends[p]
                else:
                    return None
            if not programs:
                return None
        # the system may still decline (e.g. joint_states that are not its state as it is): ask with no period
        none = np.zeros(0)
        from .kernels import jit
        with jit.quiet():   # (interpreted, this probe asks for no machine code: the first block asks)
            declined = sys_.fused_periods(sim.settings['integrator'], sim.integrator.dt, sim.work_state(), none, none,
                                          np.array(sim.ports[port].applied, dtype=float), program, wrenches,
                                          **_held(sim, others)) is None
        if declined:
            return None
        runner = cls(sim, port, program, sinks, wrenches, pipeline, halt)
        runner.others, runner.due = others, due
        return runner

    def run(self, k: int, n: int, t_start: float, rate: float) -> int:
        """Run periods k.. in blocks; returns the first period not run (n when all are).

        One compiled call runs up to :data:`BLOCK_PERIODS` periods; the sinks then get them in
        pieces that end where one wants the Simulator's state (a diagnostics message), the
        Simulator being put at the end of each piece first, as per-period calls leave it. A lone
        sink that says ``arrives_in_blocks`` takes the periods in one piece instead and puts the
        Simulator at the end of the periods where it wants its state itself (``PeriodBlock.arrive``:
        the same Simulator there, without a piece per diagnostics message)."""
        sim, sys_ = self.sim, self.sim.system
        n = self._before_message(k, n, t_start, rate)
        if n <= k:
            return k   # a message is due at the start of period k: sent on the per-period path
        self.held_kw = _held(sim, self.others)   # the other ports' inputs, fixed until that message
        if self.template is None:
            self.template = sim.outputs(wrenches=self.wrenches)   # names and frames of every period's outputs
        cmd_kind = () if self.program is None else ((self.port, sim.ports[self.port].value.shape[0]),)
        whole = (True,) if len(self.sinks) == 1 and getattr(self.sinks[0], 'arrives_in_blocks', False) else ()
        ahead = None   # the thread computing the next blocks (_Ahead)
        try:
            while k < n:
                K = min(BLOCK_PERIODS, n - k)
                t_out = t_start + (np.arange(k, k + K) + 1) / rate   # the per-period path's t_start + (k + 1) / rate
                if any(s.block_periods(t_out, self.template, cmd_kind, *whole) <= 0 for s in self.sinks):
                    return k   # a sink wants this period on the per-period path
                t_cmd = np.empty(K)
                t_cmd[0] = sim.t
                t_cmd[1:] = t_out[:-1]
                u = np.array(sim.ports[self.port].applied, dtype=float)
                u0 = u.copy()   # (the loop changes u in place)
                z = sim.work_state()
                res = None
                if ahead is not None:
                    res = ahead.take((z, t_cmd, t_out, u))
                    if res is None:   # not from here: dropped with what it computed after it
                        ahead.stop(self.dropped)
                        ahead = None
                if res is None:
                    w0 = time.perf_counter()
                    res = self._periods(z, t_cmd, t_out, u)
                    sim.diag.wall += time.perf_counter() - w0
                if res is None:
                    return k
                done, code = res[0], res[1]
                if ahead is None and self.pipeline and self.sinks and done == K and code == 0 and k + K < n \
                        and _pipelines():   # (without sinks there is nothing to do meanwhile)
                    ahead = _Ahead(self, res, k + K, n, t_start, rate, t_out[-1], u0)
                a = 0
                while a < done:
                    b = done
                    for s in self.sinks:
                        b = min(b, a + s.block_periods(t_out[a:done], self.template, cmd_kind, *whole))
                    if b <= a:   # the rest of the block is dropped: the Simulator is at the end of period k + a - 1
                        return k + a
                    self._commit(a, b, t_cmd, t_out, res, bool(whole))
                    a = b
                    if self.halt is not None and self.halt():   # the Simulator is at the end of period k + b - 1
                        return k + b
                k += done
                if code:
                    return k
            return n
        finally:
            if ahead is not None:   # (its thread uses the loop's work arrays: stopped before anything else runs)
                ahead.stop(self.dropped)

    def _periods(self, z, t_cmd, t_out, u):
        """``system.fused_periods`` of these periods from state z and command u (both changed in place)."""
        sim = self.sim
        return sim.system.fused_periods(sim.settings['integrator'], sim.integrator.dt, z, t_cmd, t_out, u,
                                        self.program, self.wrenches, **self.held_kw)

    def _before_message(self, k, n, t_start, rate) -> int:
        """The first period from k on at whose start a scripted message is due on another port (the per-period
        path sends it: ``feed`` at that period's start ``t_start + j / rate``, within the scripts' 1e-12 s),
        or n."""
        for next_send in self.due.values():
            t_due = next_send()
            if not math.isfinite(t_due):
                continue
            if t_due <= self.sim.t + 1e-12:
                return k
            j = max(k + 1, int(math.floor((t_due - t_start) * rate)) - 2)
            while j < n and not t_due <= t_start + j / rate + 1e-12:
                j += 1
            n = min(n, j)
        return n

    def _next_command(self, res, u):
        """The command the port holds after block res, as :meth:`_arrive` leaves it (u: the one it started with)."""
        if self.program is None:
            return u.copy()
        return np.array(self.sim.ports[self.port].clamped_to_limit(res[3][res[0] - 1]), dtype=float)

    def _commit(self, a, b, t_cmd, t_out, res, whole=False):
        """The Simulator at the end of period b - 1 of the block, as advance() calls leave it;
        the sinks get periods a..b-1 (whole: the lone sink may put the Simulator at the end of
        an earlier one of them first, ``PeriodBlock.arrive``)."""
        _, _, Zs, Us, outs, Fs, steps = res[:7]
        more = res[7] if len(res) > 7 else {}
        at = [a]   # the first period of the piece the Simulator is not yet past
        counts = steps.tolist()   # the steps of each period (ints: their sums are steps[a:b].sum())

        def arrive(j):
            """The Simulator at the end of period a + j of the block (j counted in the piece; forward only)."""
            if a + j + 1 > at[0]:
                self._arrive(at[0], a + j + 1, t_cmd, t_out, res, sum(counts[at[0]:a + j + 1]))
                at[0] = a + j + 1
            elif a + j + 1 < at[0]:
                raise RuntimeError(f'the Simulator is past period {a + j} of the block')
        if not whole:
            arrive(b - a - 1)
        commands = {} if self.program is None else {self.port: Us[a:b]}
        position, velocity, effort = outs
        odom, contacts, control = more.get('odom'), more.get('contacts'), more.get('control')
        points = more.get('points')
        block = PeriodBlock(t_cmd=t_cmd[a:b], t_out=t_out[a:b], commands=commands, position=position[a:b],
                            velocity=velocity[a:b], effort=effort[a:b], wrenches=None if Fs is None else Fs[a:b],
                            template=self.template, z=Zs[a:b], odom=None if odom is None else odom[a:b],
                            contacts=None if contacts is None else contacts[a:b], arrive=arrive if whole else None,
                            control=None if control is None else control[a:b],
                            points=None if points is None else points[a:b])
        for s in self.sinks:
            s.on_block(block, self.sim)
        arrive(b - a - 1)

    def _arrive(self, a, b, t_cmd, t_out, res, n_steps):
        """The Simulator at the end of period b - 1 of the block, coming from the end of period a - 1:
        the counters of periods a..b-1 (n_steps steps) added, the port holding period b - 1's command."""
        sim, sys_ = self.sim, self.sim.system
        _, _, Zs, Us, outs = res[:5]
        ny = sys_.ny
        z = Zs[b - 1]
        st = IntegratorStats.of_fused_steps(sim.settings['integrator'], n_steps, b - a)
        sim.integrator.stats.accumulate(st)
        sim.diag.count(st)
        sim.diag.block_periods += b - a
        sim.arrive(float(t_out[b - 1]), z[:ny].copy(), z)
        if self.program is not None:
            p = sim.ports[self.port]
            p.value = Us[b - 1].copy()
            p.applied = p.clamped_to_limit(p.value)
            p.stamp = float(t_cmd[b - 1])
            p.timed_out = False
            if p.limit is not None:   # the clamped components of these periods' commands, as set_command counts them
                p.clamped += int(np.count_nonzero(np.abs(Us[a:b]) > p.limit))
        # each published state's velocities against their limits, as Simulator.outputs counts them
        sim.diag.velocity_limit_exceeded += sim.velocity_limits.count(sim.t, self.template.joint_names,
                                                                      outs[1][a:b])
        extra = getattr(sys_, 'state_extra', None)
        if extra is not None:   # what outputs() would have put in diag.extra at the last state
            points = res[7].get('points') if len(res) > 7 else None
            sim.diag.extra.update(extra(sim.y) if points is None else extra(sim.y, points[b - 1]))


class _Ahead:
    """A thread computing the blocks that follow a block (:meth:`BlockRunner.run`), one after the other from
    where the last one ended, up to :data:`AHEAD` blocks before the sinks take them; it stops after a block the
    loop ended short (a refused period), at the run's end, or when told (:meth:`stop`)."""

    def __init__(self, runner, res, k, n, t_start, rate, t_end, u):
        import queue
        import threading
        self.runner, self.n, self.t_start, self.rate = runner, n, t_start, rate
        self.done = queue.Queue(AHEAD)   # (inputs, res, wall, error) per block, in order
        self.computed = 0   # blocks computed (taken or not)
        self.taken = 0
        self.halt = threading.Event()
        z = res[2][res[0] - 1].copy()
        self.thread = threading.Thread(target=self._work, args=(k, z, float(t_end), runner._next_command(res, u)),
                                       name='robodyn-blocks', daemon=True)
        self.thread.start()

    def _work(self, k, z, t_end, u):
        try:
            self._blocks(k, z, t_end, u)
        finally:
            self._put(None)   # the end: take() says None from here on

    def _put(self, item):
        import queue
        while not self.halt.is_set():
            try:
                self.done.put(item, timeout=0.05)
                return
            except queue.Full:
                pass

    def _blocks(self, k, z, t_end, u):
        runner = self.runner
        while k < self.n and not self.halt.is_set():
            K = min(BLOCK_PERIODS, self.n - k)
            t_out = self.t_start + (np.arange(k, k + K) + 1) / self.rate
            t_cmd = np.empty(K)
            t_cmd[0] = t_end
            t_cmd[1:] = t_out[:-1]
            inputs = (z.copy(), t_cmd, t_out, u.copy())
            res, error = None, None
            w0 = time.perf_counter()
            try:
                res = runner._periods(z, t_cmd, t_out, u)
            except BaseException as e:   # raised where the sinks take this block
                error = e
            self.computed += 1
            self._put((inputs, res, time.perf_counter() - w0, error))
            if res is None or res[0] < K or res[1] != 0:
                return
            k += K
            z, t_end, u = res[2][K - 1].copy(), float(t_out[-1]), runner._next_command(res, inputs[3])

    def take(self, now):
        """The next block's result when it was computed from ``now`` (state and work, command times and ends,
        command; bit for bit), else None. Raises what computing it raised."""
        item = self.done.get()
        if item is None:
            self.done.put(None)
            return None
        inputs, res, wall, error = item
        if not all(a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()
                   for a, b in zip(inputs, now)):
            return None
        self.runner.sim.diag.wall += wall
        self.runner.used[0] += 1
        self.taken += 1
        if error is not None:
            raise error
        return res

    def stop(self, dropped):
        """Stop computing, wait for the thread, count the blocks it computed that were not taken."""
        import queue
        self.halt.set()
        while self.thread.is_alive():
            try:
                self.done.get(timeout=0.01)   # (a full queue lets the thread see the halt)
            except queue.Empty:
                pass
        dropped[0] += self.computed - self.taken
