"""What a run reports about itself: its running figures, its energy balance and its diagnostics values.

The :class:`~robodyn_ros.simulation.Simulator` keeps one :class:`Diagnostics` per episode and updates
it as it integrates; every sink that publishes diagnostics (the recorder, the node, the summary of
``robodyn run``) reads the same numbers from it, through :meth:`Diagnostics.energy_report` and
:meth:`Diagnostics.values`. :class:`VelocityLimits` counts the published joint velocities above their
joints' velocity limits (URDF ``<limit velocity>``: reported, not enforced).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ['Diagnostics', 'VelocityLimits']


@dataclass
class Diagnostics:
    """Running figures of a simulation, published on ``diagnostics`` and printed in summaries.

    energy0: total energy at start (J); work: ∫ (input power − dissipation) dt (J), integrated
    with the state; work_parts: name -> the part of ``work`` done by one element, integrated
    with the state by the same quadrature (the system's ``work_components``, e.g. ``limit``:
    the joint-limit moments); steps, rhs_evals, rejected_steps: integrator statistics (rejected_steps
    None once a method that does not count them ran); wall: wall time spent in advance() (s; on
    run_headless's block path, in its compiled calls, which also evaluate the scripted commands and
    compute the outputs); sim_time: simulated time (s); velocity_limit_exceeded: published
    joint-velocity samples above their joint's velocity limit (URDF ``<limit velocity>``);
    block_periods: periods run by the block path (many per compiled call; not published: a figure for
    benchmarks and tests); extra: the system's own values (motor currents, constraint residuals, ...)
    at the last published state.
    """

    energy0: float = 0.0
    work: float = 0.0
    work_parts: dict = field(default_factory=dict)
    steps: int = 0
    rhs_evals: int = 0
    rejected_steps: int | None = 0
    wall: float = 0.0
    sim_time: float = 0.0
    velocity_limit_exceeded: int = 0
    block_periods: int = 0
    extra: dict = field(default_factory=dict)

    def count(self, st):
        """Add the cost of one integrator call (an :class:`~robodyn_ros.integrators.IntegratorStats`)."""
        self.steps += st.steps
        self.rhs_evals += st.rhs_evals
        if st.rejected_steps is None or self.rejected_steps is None:
            self.rejected_steps = None  # implicit scipy solvers do not report rejections
        else:
            self.rejected_steps += st.rejected_steps

    def energy_report(self, energy: float, work: float) -> dict:
        """The energy balance at a state of total energy ``energy`` (J) reached with ``work`` (J) done on
        the system: ``energy``, ``energy0``, ``work``, the drift ``E − E0 − W`` and its relative value
        (over the largest of |E0|, |E|, |W|), and each work part as ``<name>_work`` (the current ones)."""
        drift = energy - self.energy0 - work
        scale = max(abs(self.energy0), abs(energy), abs(work), 1e-12)
        out = {'energy': energy, 'energy0': self.energy0, 'work': work, 'drift': drift,
               'relative_drift': drift / scale}
        for name, w in self.work_parts.items():   # e.g. limit_work: the joint-limit moments' part of work
            out[f'{name}_work'] = w
        return out

    def values(self, t: float, energy: dict, ports, integrator: str, wall_clock: bool = False,
               velocity_limited: bool = False) -> dict:
        """Flat name -> value map for the ``diagnostics`` topic.

        t: simulation time (s); energy: :meth:`energy_report` now; ports: the
        :class:`~robodyn_ros.commands.CommandPorts` (timeouts, clamps, refusals); integrator: the method's
        name; wall_clock: include figures that depend on the machine's speed (compute real-time factor),
        off for headless recordings so that equal runs give byte-identical files; velocity_limited: some
        joint has a velocity limit (then ``velocity_limit_exceeded`` is reported).
        """
        vals = {'sim_time': t, 'energy': energy['energy'], 'energy_drift': energy['drift'],
                'energy_drift_relative': energy['relative_drift'], 'work_in': energy['work'],
                **{f'{name}_work': w for name, w in self.work_parts.items()},
                'steps': self.steps, 'rhs_evals': self.rhs_evals,
                'rejected_steps': 'unknown' if self.rejected_steps is None else self.rejected_steps,
                'rejected_commands': ports.rejected, 'integrator': integrator}
        if wall_clock:
            vals['real_time_factor_compute'] = self.sim_time / self.wall if self.wall > 0 else float('nan')
        for k, p in ports.ports.items():
            vals[f'{k}_timed_out'] = p.timed_out
            if ports.inputs[k].limit is not None:
                vals[f'{k}_clamped'] = p.clamped
        if velocity_limited:
            vals['velocity_limit_exceeded'] = self.velocity_limit_exceeded
        vals.update(self.extra)
        return vals


class VelocityLimits:
    """The joints' velocity limits (``LinkSpec.velocity_limit``, from URDF ``<limit velocity>``) and the
    count of published velocities above them, each published state counted once.

    system: its ``model.specs`` give the limits (rad/s or m/s); a system without any has none
    (``bool(limits)`` is False).
    """

    def __init__(self, system):
        specs = getattr(getattr(system, 'model', None), 'specs', ())
        self.of = {s.joint: s.velocity_limit for s in specs
                   if getattr(s, 'velocity_limit', None) is not None}   # joint -> rad/s or m/s
        self._cache = (None, None)
        self.checked_at = None

    def __bool__(self) -> bool:
        return bool(self.of)

    def reset(self):
        """A new episode: no state counted yet."""
        self.checked_at = None

    def of_names(self, names) -> np.ndarray | None:
        """``(len(names),)`` velocity limits of the joint_states entries (inf where none), or None
        when no joint of the system has one."""
        if not self.of:
            return None
        key = tuple(names)
        if self._cache[0] != key:
            self._cache = (key, np.array([self.of.get(n, np.inf) for n in key]))
        return self._cache[1]

    def count(self, t: float, names, velocity) -> int:
        """Velocity samples above their limits in the state published at time t, (k, n) or (n,)
        ``velocity`` in ``names`` order; 0 for a state already counted at t (or no limits). Rows of
        a block of periods ending at t are counted together."""
        lim = self.of_names(names)
        if lim is None or t == self.checked_at:
            return 0
        self.checked_at = t
        return int(np.count_nonzero(np.abs(velocity) > lim))
