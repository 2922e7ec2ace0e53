"""Passive joint elements beyond viscous damping, compiled (numba): Coulomb joint friction and its slope.

Coulomb friction ``f`` (N·m or N) at a joint of velocity ``q̇`` is regularised as the DC motor's
(:mod:`robodyn_ros.systems.motor`): ``τ = −f tanh(q̇ / v_s)`` with the regularisation speed
``v_s`` (:data:`robodyn_ros.urdf.COULOMB_VELOCITY`): a smooth right-hand side, no stick-slip
events; below ``|q̇| ~ v_s`` it acts as a viscous damper of slope ``f / v_s``, so a load under
the friction level creeps at ``~ v_s artanh(τ/f)`` instead of sticking.
"""
from __future__ import annotations

import math

from .jit import njit


@njit(cache=True, nogil=True, error_model='numpy', _nrt=False)
def add_coulomb_friction(friction, v_s, v, tau):
    """``tau[k] -= friction[k] tanh(v[k] / v_s)`` for every joint k (in place; all arrays (nv,))."""
    for k in range(v.shape[0]):
        if friction[k] != 0.0:
            tau[k] -= friction[k] * math.tanh(v[k] / v_s)


@njit(cache=True, nogil=True, error_model='numpy', _nrt=False)
def friction_jacobian_add(friction, v_s, v, Dm):
    """``Dm[k, k] += f_k sech²(v_k / v_s) / v_s``: minus the derivative of :func:`add_coulomb_friction`'s
    torque with respect to v_k, the friction's share of the passive damping of the linearly implicit
    step (:mod:`robodyn_ros.kernels.rosenbrock`); Dm (nv, nv)."""
    for k in range(v.shape[0]):
        if friction[k] != 0.0:
            th = math.tanh(v[k] / v_s)
            Dm[k, k] += friction[k] * (1.0 - th * th) / v_s
