"""Permanent-magnet DC motor with gearbox, friction and supply saturation (seed 001, §3.3.3).

Electrical side (armature circuit, seed eq. 54 with the back-EMF written out)::

    L di/dt = v − R i − K ω_m          ω_m = N ω_out   (motor shaft, rad/s)       (M1)

Mechanical side, on the output (wheel) shaft::

    τ_out = N (K i − b ω_m − τ_c tanh(ω_m / ω_s))                                  (M2)

* ``K`` is the torque constant (N·m/A), equal to the back-EMF constant (V·s/rad) in SI units
  (seed eq. 55: ``T = K i``); ``R`` the armature resistance (the seed calls it "rolling
  resistance"; it is the winding resistance), ``L`` the inductance, ``N`` the gear ratio (motor
  turns per output turn, ideal lossless gear), ``b`` viscous and ``τ_c`` Coulomb friction at the
  motor shaft.
* **Coulomb regularisation.** The sign function of dry friction is replaced by
  ``tanh(ω_m / ω_s)`` with the named regularisation speed ``ω_s`` (``coulomb_velocity``, rad/s
  at the motor shaft): a smooth right-hand side that every integrator can step (no event
  detection, no stick-slip switching). Below ``|ω_m| ~ ω_s`` the friction acts as a stiff
  viscous damper of slope ``τ_c / ω_s``, which :meth:`DCMotor.friction_slope` reports so that
  step-size checks can account for it; holding torques below ``τ_c`` therefore creep at a speed
  ``~ ω_s artanh(τ/τ_c)`` instead of sticking exactly.
* **Supply saturation.** The applied voltage is ``clip(v_cmd, −V_s, V_s)`` (an ideal H-bridge
  on a supply of ``V_s`` volts); the clipped value is what the motor sees and what the power
  bookkeeping uses.
* ``L = 0`` (the seed's model): (M1) is algebraic, ``i = (v − K ω_m)/R``, and the current is
  not a state. ``L > 0``: the current is a state and the electrical time constant ``L/R`` is
  usually the fastest one of the whole system (a 1e-4 H, 1.7 Ω motor: 59 µs).

Power (W), used by the energy-balance bookkeeping::

    v i = R i² + L i di/dt + K ω_m i                      (electrical)
    K ω_m i = τ_out ω_out + b ω_m² + τ_c tanh(ω_m/ω_s) ω_m   (mechanical)

so ``d/dt(kinetic + ½ L i²) = v i − R i² − b ω_m² − τ_c tanh(ω_m/ω_s) ω_m``.

The rotor inertia ``J_m`` appears on the output shaft as ``N² J_m`` (reflected inertia); the
system that owns the shaft adds it to its mass matrix.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..model import COULOMB_VELOCITY  # default regularisation speed of the Coulomb friction tanh


@dataclass(frozen=True)
class DCMotor:
    """Parameters of one DC motor and its gear (SI units; see the module docstring).

    torque_constant K (N·m/A, >= 0; 0 = a free, unpowered shaft), resistance R (Ω, > 0),
    inductance L (H, >= 0), gear_ratio N (> 0), rotor_inertia J_m (kg·m², >= 0, motor side),
    viscous_friction b (N·m·s/rad, motor side), coulomb_friction τ_c (N·m, motor side),
    coulomb_velocity ω_s (rad/s, motor side, > 0), supply_voltage V_s (V, > 0, inf = no limit).
    """

    torque_constant: float = 0.061
    resistance: float = 1.7
    inductance: float = 0.0
    gear_ratio: float = 1.0
    rotor_inertia: float = 0.0
    viscous_friction: float = 0.0
    coulomb_friction: float = 0.0
    coulomb_velocity: float = COULOMB_VELOCITY
    supply_voltage: float = math.inf

    def __post_init__(self):
        checks = (('torque_constant', 0.0, False), ('resistance', 0.0, True), ('inductance', 0.0, False),
                  ('gear_ratio', 0.0, True), ('rotor_inertia', 0.0, False), ('viscous_friction', 0.0, False),
                  ('coulomb_friction', 0.0, False), ('coulomb_velocity', 0.0, True),
                  ('supply_voltage', 0.0, True))
        for name, lo, strict in checks:
            x = getattr(self, name)
            if isinstance(x, bool) or not isinstance(x, (int, float)) or math.isnan(x):
                raise ValueError(f'{name}: expected a number, got {x!r}')
            if (x <= lo if strict else x < lo) or (math.isinf(x) and name != 'supply_voltage'):
                raise ValueError(f'{name}: must be {"> " if strict else ">= "}{lo} and finite, got {x!r}')

    @property
    def has_current_state(self) -> bool:
        """True when L > 0: the current is integrated as a state."""
        return self.inductance > 0.0

    @property
    def electrical_time_constant(self) -> float:
        """``L / R`` (s); 0 for the algebraic (L = 0) model."""
        return self.inductance / self.resistance

    @property
    def reflected_inertia(self) -> float:
        """Rotor inertia seen at the output shaft, ``N² J_m`` (kg·m²)."""
        return self.gear_ratio ** 2 * self.rotor_inertia

    def applied_voltage(self, v_cmd):
        """The voltage the motor sees: the command clipped to ``±supply_voltage`` (V)."""
        return np.clip(v_cmd, -self.supply_voltage, self.supply_voltage)

    def current(self, v, w_out):
        """Algebraic current (A) of the L = 0 model, ``(v − K N ω_out) / R``; v already clipped."""
        return (v - self.torque_constant * self.gear_ratio * w_out) / self.resistance

    def current_rate(self, v, i, w_out):
        """``di/dt`` (A/s) of the L > 0 model, eq. (M1); v already clipped."""
        return (v - self.resistance * i - self.torque_constant * self.gear_ratio * w_out) / self.inductance

    def friction_torque(self, w_out):
        """Friction torque at the motor shaft (N·m, opposing motion): ``b ω_m + τ_c tanh(ω_m/ω_s)``."""
        wm = self.gear_ratio * w_out
        return self.viscous_friction * wm + self.coulomb_friction * np.tanh(wm / self.coulomb_velocity)

    def output_torque(self, i, w_out):
        """Torque on the output shaft (N·m), eq. (M2): ``N (K i − friction)``."""
        return self.gear_ratio * (self.torque_constant * i - self.friction_torque(w_out))

    def friction_loss(self, w_out):
        """Power dissipated by friction (W, >= 0): ``friction_torque · ω_m``."""
        return self.friction_torque(w_out) * (self.gear_ratio * w_out)

    def friction_slope(self, w_out):
        """``d τ_out / d ω_out`` of friction alone at the output (N·m·s/rad, >= 0): local damping."""
        wm = self.gear_ratio * w_out
        sech2 = 1.0 / np.cosh(np.clip(wm / self.coulomb_velocity, -350.0, 350.0)) ** 2
        return self.gear_ratio ** 2 * (self.viscous_friction + self.coulomb_friction * sech2 / self.coulomb_velocity)

    def electrical_damping(self) -> float:
        """Back-EMF damping at the output of the L = 0 model, ``N² K² / R`` (N·m·s/rad)."""
        return (self.gear_ratio * self.torque_constant) ** 2 / self.resistance

    def input_power(self, v, i, w_out):
        """``v i − R i² − friction losses`` (W): rate of change of kinetic + magnetic energy."""
        return v * i - self.resistance * i * i - self.friction_loss(w_out)
