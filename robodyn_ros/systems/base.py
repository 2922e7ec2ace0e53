"""The interface every system implements, and the containers it returns."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class InputPort:
    """A named command input: its size, the names of its elements and their unit.

    name: port name ('effort', 'wheel_voltage', 'base_wrench'); size: vector length;
    labels: element names (joint names, 'left'/'right', ...); unit: SI unit text for messages.
    """

    name: str
    size: int
    labels: tuple
    unit: str


@dataclass
class SystemOutputs:
    """What a system reports at one instant (all arrays finite, SI units).

    joint_names, position, velocity, effort: every joint in ``joint_states`` order;
    wrenches: joint or contact name -> (child frame, (6,) [torque; force] on the child at the
    joint origin in child coordinates); odom: optional dict with 'position' (3,),
    'orientation' (x, y, z, w), 'linear' (3,) and 'angular' (3,) in base_link;
    energy: dict of named energies (J); extra: other diagnostics values.
    """

    joint_names: list
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray
    wrenches: dict = field(default_factory=dict)
    odom: dict | None = None
    energy: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)


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

    def urdf(self) -> str:
        """URDF of the system for ``robot_description`` (names equal those in joint_states)."""
        from ..model import to_urdf
        return to_urdf(self.model)
