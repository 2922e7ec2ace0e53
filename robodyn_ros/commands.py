"""Command ports: what a controller sends, checked, clamped and held (zero-order) until the next one.

Every command enters here, whether from a ROS subscription, a scripted profile, a re-simulated
recording or a live client: :meth:`CommandPorts.set` checks it against the port's size and
finiteness (a refused command is counted and changes nothing), clamps it to the port's effort
limits (counting the clamped components) and stamps it; :meth:`CommandPorts.held` gives the inputs
in force at a time, zero once a command is older than the timeout.

A port's kind (``InputPort.kind``) says how it holds: a ``vector`` (efforts, voltages, velocities) as it
came, zero after the timeout; a ``setpoint`` (position setpoints) as the system makes it
(``System.accept_input``: a servo's setpoint program), from the initial value the system gives
(``System.initial_input``: the initial posture), never timing out; a ``message`` (a trajectory) is
checked by the system and changes what its ``target`` port applies.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .systems.base import clamp_to_limit

__all__ = ['CommandError', 'CommandPort', 'CommandPorts']


class CommandError(ValueError):
    """A command that was refused; the message says what was expected. The state is unchanged."""


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

    def clamped_to_limit(self, value: np.ndarray) -> np.ndarray:
        """What the actuators apply of command value: clamped to the port's effort limits (value itself
        without limits)."""
        return clamp_to_limit(value, self.limit)


class CommandPorts:
    """The input ports of a system, each a :class:`CommandPort` at zero.

    system: the System whose ``inputs`` (name -> :class:`~robodyn_ros.systems.base.InputPort`: size,
    labels, unit, effort limits) these are; timeout: seconds of simulation time after which an
    unrefreshed command goes to zero (None = hold forever); y, t: the initial state and time, for the values
    the ports hold before any command (``System.initial_input``; zeros without y). ``ports`` maps each name to
    its CommandPort.
    """

    def __init__(self, system, timeout: float | None = None, y=None, t: float = 0.0):
        self.system = system
        self.inputs = inputs = system.inputs
        self.timeout = timeout
        init = getattr(system, 'initial_input', None) if y is not None else None
        self.ports = {}
        for k, p in inputs.items():
            value, applied = (np.zeros(p.size), None) if init is None else init(k, y, t)
            self.ports[k] = CommandPort(value, applied=applied,
                                        limit=None if p.limit is None else np.asarray(p.limit, dtype=float))

    def set(self, port: str, values, t: float):
        """Accept a command for ``port`` arriving at time t (s), held until the next one, or raise
        :class:`CommandError` naming what was expected (the refusal is counted; nothing else changes).

        values: sequence of floats of the port's size, in the port's unit; components beyond the
        port's effort limits are clamped (``applied``) and counted (``clamped``)."""
        if port not in self.ports:
            raise CommandError(f'unknown input {port!r}; this system takes {sorted(self.ports)}')
        spec = self.inputs[port]
        if spec.kind == 'message':   # a structured command (a trajectory) onto what its target port applies
            target = self.ports[spec.target]
            try:
                applied = self.system.accept_input(port, values, float(t), target.applied)
            except ValueError as e:
                self.ports[port].rejected += 1
                raise CommandError(f'{port}: {e}') from None
            p = self.ports[port]
            p.value = p.applied = values
            p.stamp = target.stamp = float(t)
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
            p.applied = self.system.accept_input(port, arr, float(t), p.applied)
            p.value = arr
            p.stamp = float(t)
            return
        p.value = arr
        p.applied = arr
        if spec.limit is not None:  # actuator effort limits: clamp, and count the clamped components
            lim = p.limit
            over = np.abs(arr) > lim
            if over.any():
                p.applied = np.clip(arr, -lim, lim)
                p.clamped += int(over.sum())
        p.stamp = float(t)
        p.timed_out = False

    def held(self, t: float) -> dict:
        """The inputs in force at time t (s): name -> (size,) applied command (zero-order hold), zeros
        once the command is older than the timeout (the port is then marked ``timed_out``)."""
        u = {}
        for k, p in self.ports.items():
            stale = (self.timeout is not None and p.stamp is not None
                     and t - p.stamp > self.timeout + 1e-12
                     and self.inputs[k].kind == 'vector')   # setpoints and trajectories hold
            if stale and not p.timed_out:
                p.timed_out = True
            u[k] = np.zeros_like(p.value) if p.timed_out else p.applied
        return u

    @property
    def rejected(self) -> int:
        """Total refused commands over all ports."""
        return sum(p.rejected for p in self.ports.values())
