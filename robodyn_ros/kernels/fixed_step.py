"""The fused fixed-step loop of the constrained and floating-base systems, one compiled unit per kind.

The reference implementations are the numpy methods of the system classes
(:mod:`robodyn_ros.systems.diffdrive`, ``freeflyer``, ``augmented``, ``prescribed``) and the
solvers of :mod:`robodyn_ros.constraints`; the kernels (:mod:`.diffdrive`, :mod:`.freeflyer`, :mod:`.augmented`,
:mod:`.prescribed`, on :mod:`.linalg` and :mod:`.frames`) compute the same quantities with the same
algorithms in numba (tested equal to 1e-12 relative), so that a system can evaluate its
right-hand side in a few microseconds and run a whole publication period of fixed steps in one
call (``integrate_<kind>`` here), like the arm's :func:`robodyn_ros.kernels.arm.integrate_arm`.

One calling convention for every system::

    (kind, ip, fp, mi, mf, mi_r, mf_r, u)

* ``kind``: :data:`DIFFDRIVE`, :data:`FREEFLYER`, :data:`AUGMENTED` or :data:`PRESCRIBED`;
* ``ip`` int64 / ``fp`` float64: the system's parameters, packed by the system class in the
  layouts documented at each section below (``*_I`` / ``*_F`` column constants);
* ``mi, mf`` / ``mi_r, mf_r``: the packed tree, full and with FIXED bodies merged
  (:func:`robodyn_ros.kernels.pack_model`); the augmented formulation has its own kinematics
  and passes 1-row dummies;
* ``u`` float64: the inputs held over the call (layout per system).

Status codes: the solvers return :data:`OK`, or :data:`SINGULAR` when a mass matrix is not
positive definite (the caller raises ``numpy.linalg.LinAlgError`` as the reference's
``cho_factor`` would). A non-finite state gives a non-finite derivative, which the integrators
report.

**Compile units.** Each system kind has its own entry points here (``evaluate_*``, ``project_*``,
``integrate_*``): the first run of a scene compiles only what its system uses. Flags are passed
to the large solvers through :func:`robodyn_ros.kernels.linalg.flag` (numba compiles a callee once per constant argument).
"""
from __future__ import annotations

import math

import numpy as np
from .jit import njit

from .augmented import au_config_rate, au_evaluate, au_project
from .diffdrive import dd_evaluate, dd_project, dd_rosenbrock_step
from .freeflyer import ff_evaluate, ff_project
from .linalg import OK
from .prescribed import pr_evaluate
from .tree import _JIT, qdot_into


# fused-integrator method codes (see integrate_arm; kernels.FUSED_METHODS maps names to them)
M_EULER, M_SEMI_IMPLICIT_EULER, M_RK4, M_ROSENBROCK2 = 0, 1, 2, 3

DIFFDRIVE, FREEFLYER, AUGMENTED, PRESCRIBED = 1, 2, 3, 4


# ----------------------------------------------------------------------------------------------
# the fused fixed-step loop, one compiled unit per system kind
# ----------------------------------------------------------------------------------------------
# Each kind has its own entry points (evaluate_*, project_*, integrate_*) with the common signature
# below, chosen in Python (kernels.CompiledSystem): a first run compiles only the kind it uses.
# The integrators' arithmetic is shared (_stage_update); only the calls into the kind differ.

@njit(**_JIT)
def _stage_update(method, s, h, z, K, Y, acc, nq):
    """Fold stage s's derivative K into the step (the arithmetic of :mod:`robodyn_ros.integrators`).

    RK4: ``acc = k1 + 2 k2 + 2 k3 + k4`` folded stage by stage, the next stage point into Y,
    ``z += h/6 acc`` after the fourth; symplectic Euler: ``[v, W] += h f[nq:]`` (q follows with
    q̇(q, v_new), done by the caller); Euler: ``z += h f``.
    """
    n = z.shape[0]
    if method == M_RK4:
        if s == 0:
            half = 0.5 * h
            for a in range(n):
                acc[a] = K[a]
                Y[a] = K[a] * half + z[a]
        elif s < 3:
            c = 0.5 * h if s == 1 else h
            for a in range(n):
                acc[a] = (acc[a] + K[a]) + K[a]
                Y[a] = K[a] * c + z[a]
        else:
            h6 = h / 6.0
            for a in range(n):
                z[a] += (acc[a] + K[a]) * h6
    elif method == M_SEMI_IMPLICIT_EULER:
        for a in range(nq, n):
            z[a] += K[a] * h
    else:
        for a in range(n):
            z[a] += K[a] * h


@njit(**_JIT)
def _stage_time(method, s, t, h):
    """Time of stage s: t, t + h/2, t + h/2, t + h (RK4); t otherwise."""
    if method != M_RK4 or s == 0:
        return t
    return t + 0.5 * h if s < 3 else t + h


@njit(**_JIT)
def _all_finite_1d(z):
    for a in range(z.shape[0]):
        if not math.isfinite(z[a]):
            return False
    return True


@njit(**_JIT)
def evaluate_dd(ip, fp, mi, mf, mi_r, mf_r, u, nq, t, z, dz, stat):
    """``dz (ny + 1,) = [dy/dt; input power]`` at (t, z[:ny]) (differential drive)."""
    return dd_evaluate(ip, fp, mi_r, mf_r, u, z[:z.shape[0] - 1], dz)


@njit(**_JIT)
def evaluate_ff(ip, fp, mi, mf, mi_r, mf_r, u, nq, t, z, dz, stat):
    """As :func:`evaluate_dd` (free base, minimal coordinates)."""
    return ff_evaluate(ip, fp, mi, mf, mi_r, mf_r, u, nq, z, dz)


@njit(**_JIT)
def evaluate_au(ip, fp, mi, mf, mi_r, mf_r, u, nq, t, z, dz, stat):
    """As :func:`evaluate_dd` (free base, augmented formulation)."""
    return au_evaluate(ip, fp, u, z, dz)


@njit(**_JIT)
def evaluate_pr(ip, fp, mi, mf, mi_r, mf_r, u, nq, t, z, dz, stat):
    """As :func:`evaluate_dd` (prescribed path; stat counts singular evaluations)."""
    return pr_evaluate(ip, fp, mi, mf, mi_r, mf_r, u, t, z, dz, stat)


@njit(**_JIT)
def project_dd(ip, fp, mi, mf, mi_r, mf_r, nq, y):
    """The system's ``project(y)`` in place (y without the work entry); differential drive."""
    return dd_project(ip, fp, mi_r, mf_r, y)


@njit(**_JIT)
def project_ff(ip, fp, mi, mf, mi_r, mf_r, nq, y):
    """As :func:`project_dd` (free base, minimal coordinates)."""
    return ff_project(ip, fp, mi, mf, mi_r, mf_r, nq, y)


@njit(**_JIT)
def project_au(ip, fp, mi, mf, mi_r, mf_r, nq, y):
    """As :func:`project_dd` (augmented: the quaternion)."""
    return au_project(ip, y)


@njit(**_JIT)
def project_pr(ip, fp, mi, mf, mi_r, mf_r, nq, y):
    """As :func:`project_dd` (prescribed path: nothing to project)."""
    return OK


# The four loops below are the same but for the evaluate/project/q̇ calls of their kind
# (numba cannot cache a loop that takes those functions as arguments).
# integrate_*(ip, fp, mi, mf, mi_r, mf_r, u, nq, method, z, t0, dt, n_full, h_last, stat) integrates
# z = [y, W] in place over n_full steps of dt and one of h_last (if > 0), with the step times of
# FixedStepIntegrator (t = t0 + k dt) and the projection after every step. Returns -1, the index
# k of the first step whose result is non-finite, or -2 - k when a mass matrix was not positive
# definite in step k.

@njit(**_JIT)
def integrate_dd(ip, fp, mi, mf, mi_r, mf_r, u, nq, method, z, t0, dt, n_full, h_last, stat):
    """Fused fixed-step loop of the differential drive (see the comment above)."""
    n = z.shape[0]
    K, Y, acc = np.empty(n), np.empty(n), np.empty(n)
    for k in range(n_full + (1 if h_last > 0.0 else 0)):
        t = t0 + k * dt
        h = dt if k < n_full else h_last
        if method == M_ROSENBROCK2 and dd_rosenbrock_step(ip, fp, mi_r, mf_r, u, z, h, K, Y, acc) != OK:
            return -2 - k
        for s in range(4 if method == M_RK4 else (0 if method == M_ROSENBROCK2 else 1)):
            if evaluate_dd(ip, fp, mi, mf, mi_r, mf_r, u, nq, _stage_time(method, s, t, h),
                           z if s == 0 else Y, K, stat) != OK:
                return -2 - k
            _stage_update(method, s, h, z, K, Y, acc, nq)
        if method == M_SEMI_IMPLICIT_EULER:  # q̇ = v
            for a in range(nq):
                z[a] += z[nq + a] * h
        if project_dd(ip, fp, mi, mf, mi_r, mf_r, nq, z[:n - 1]) != OK:
            return -2 - k
        if not _all_finite_1d(z):
            return k
    return -1


@njit(**_JIT)
def integrate_ff(ip, fp, mi, mf, mi_r, mf_r, u, nq, method, z, t0, dt, n_full, h_last, stat):
    """Fused fixed-step loop of the free base in minimal coordinates."""
    n = z.shape[0]
    K, Y, acc, qd = np.empty(n), np.empty(n), np.empty(n), np.empty(nq)
    for k in range(n_full + (1 if h_last > 0.0 else 0)):
        t = t0 + k * dt
        h = dt if k < n_full else h_last
        for s in range(4 if method == M_RK4 else 1):
            if evaluate_ff(ip, fp, mi, mf, mi_r, mf_r, u, nq, _stage_time(method, s, t, h),
                           z if s == 0 else Y, K, stat) != OK:
                return -2 - k
            _stage_update(method, s, h, z, K, Y, acc, nq)
        if method == M_SEMI_IMPLICIT_EULER:
            qdot_into(mi, z[:nq], z[nq:], qd)
            for a in range(nq):
                z[a] += qd[a] * h
        if project_ff(ip, fp, mi, mf, mi_r, mf_r, nq, z[:n - 1]) != OK:
            return -2 - k
        if not _all_finite_1d(z):
            return k
    return -1


@njit(**_JIT)
def integrate_au(ip, fp, mi, mf, mi_r, mf_r, u, nq, method, z, t0, dt, n_full, h_last, stat):
    """Fused fixed-step loop of the augmented free base."""
    n = z.shape[0]
    K, Y, acc, qd = np.empty(n), np.empty(n), np.empty(n), np.empty(nq)
    for k in range(n_full + (1 if h_last > 0.0 else 0)):
        t = t0 + k * dt
        h = dt if k < n_full else h_last
        for s in range(4 if method == M_RK4 else 1):
            if evaluate_au(ip, fp, mi, mf, mi_r, mf_r, u, nq, _stage_time(method, s, t, h),
                           z if s == 0 else Y, K, stat) != OK:
                return -2 - k
            _stage_update(method, s, h, z, K, Y, acc, nq)
        if method == M_SEMI_IMPLICIT_EULER:
            au_config_rate(nq, n - nq, z[:nq], z[nq:], qd)
            for a in range(nq):
                z[a] += qd[a] * h
        if project_au(ip, fp, mi, mf, mi_r, mf_r, nq, z[:n - 1]) != OK:
            return -2 - k
        if not _all_finite_1d(z):
            return k
    return -1


@njit(**_JIT)
def integrate_pr(ip, fp, mi, mf, mi_r, mf_r, u, nq, method, z, t0, dt, n_full, h_last, stat):
    """Fused fixed-step loop of the prescribed-path arm."""
    n = z.shape[0]
    K, Y, acc = np.empty(n), np.empty(n), np.empty(n)
    for k in range(n_full + (1 if h_last > 0.0 else 0)):
        t = t0 + k * dt
        h = dt if k < n_full else h_last
        for s in range(4 if method == M_RK4 else 1):
            if evaluate_pr(ip, fp, mi, mf, mi_r, mf_r, u, nq, _stage_time(method, s, t, h),
                           z if s == 0 else Y, K, stat) != OK:
                return -2 - k
            _stage_update(method, s, h, z, K, Y, acc, nq)
        if method == M_SEMI_IMPLICIT_EULER:  # q̇ = v
            for a in range(nq):
                z[a] += z[nq + a] * h
        if not _all_finite_1d(z):
            return k
    return -1


#: kind -> (evaluate, project, integrate)
ENTRY_POINTS = {DIFFDRIVE: (evaluate_dd, project_dd, integrate_dd), FREEFLYER: (evaluate_ff, project_ff, integrate_ff),
                AUGMENTED: (evaluate_au, project_au, integrate_au), PRESCRIBED: (evaluate_pr, project_pr, integrate_pr)}
