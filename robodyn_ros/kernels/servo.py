"""The joint servo of position- and velocity-commanded joints, compiled (numba): its one implementation.

A joint commanded by position (a held ``position_commands`` setpoint or a ``joint_trajectory``) or by
velocity (``velocity_commands``) is driven by a PD law evaluated at every stage of the integrator, at
the stage's time and state::

    τ_j = sat_j( kp_j (q*_j(t) − q_j) + kd_j (q̇*_j(t) − q̇_j) + τ_ff,j )                       (S1)

with ``sat_j`` the clamp to ``±u_max,j`` (the URDF's effort limit; inf = none). A velocity-commanded
joint has no position term (``q*`` is not defined: ``kp`` is not used) and ``q̇*`` is its held setpoint.
The feed-forward ``τ_ff`` (switchable) is the inverse dynamics of the desired motion: the RNEA of the
tree at the configuration ``q̃`` (the servo joints at ``q*``, the others where they are), velocities
``ṽ`` (``q̇*``, the others' own) and accelerations ``ã`` (``q̈*``, zero elsewhere), plus the joint's own
damping and Coulomb friction at ``q̇*`` (:mod:`.passive`), so that a robot on its desired motion needs no
error to stay on it. Its power ``Σ q̇_j τ_j`` is part of the arm's input power (the work quadrature).

**The setpoint program** of the position-commanded joints (:mod:`robodyn_ros.setpoints` builds it from
commands and trajectories) is piecewise polynomial in time: segments ``k`` starting at ``T[k]``
(increasing), and per segment and joint column the origin ``t₀`` and the coefficients of
``q*(t) = Σᵢ cᵢ (t − t₀)ⁱ`` (degree <= 5: a held position is ``c₀``; joint_trajectory_controller's
linear, cubic and quintic segments are degrees 1, 3, 5). The segment in force at t is the last with
``T[k] <= t``.

**In the linearly implicit step** (:mod:`.rosenbrock`) the servo is a passive element while it is not
saturated: ``K += kp``, ``D += kd`` on its joint's diagonal (:func:`servo_jacobian_add`), so stiff gains
(kp ~ 1e4-1e6) run at the step of the rest of the robot. Its setpoint moves with time, and a stiff
spring on a moving setpoint needs the time derivative of the method (Rosenbrock methods for
non-autonomous systems, ROS2 of Verwer et al. 1999 eq. 2.4: ``+γh f_t`` in stage 1, ``−γh f_t`` in
stage 2): ``F_t = kp q̇* + kd q̈*`` (:func:`servo_time_rate`). Without it a stiff servo on a moving
setpoint overshoots each step by ``(1/(2γ) − 1) Δq*`` (0.71 Δq* with γ = 1 − 1/√2); with it the step
follows ``Δq*``. Any ``F_t`` keeps order 2 (a W-method treats time as a state whose Jacobian column
may be approximated), so the feed-forward's own time rate, which is not stiff, is left out.

Layout of ``srv`` (a tuple; None: no servo, which prunes the servo code at compile time)::

    si   int64 (ns, 4): SI_V (v index), SI_Q (q index), SI_MODE (SERVO_POSITION, SERVO_VELOCITY),
                        SI_COL (column of the program C, or of vset)
    sf   float64 (ns, 3): SF_KP (N·m/rad or N/m), SF_KD (N·m·s/rad or N·s/m), SF_UMAX (N·m or N; inf: none)
    T    float64 (K,) segment start times (s)
    C    float64 (K, npos, 7): per segment and column ``[t₀, c₀, ..., c₅]``
    vset float64 (nvel,) velocity setpoints (rad/s or m/s)
    sw   float64 (NSW, max(nq, nv, 1)) work rows (see SW_*): the last evaluation's desired values,
         torques and saturation flags are left there for the outputs and the implicit step
    opt  float64 (NOPT,): OPT_FF (1: feed-forward on), OPT_SIDE (the stage's side of the step grid, see
         below), OPT_FIXED (1: every joint is a servo joint, so the feed-forward depends on the time alone),
         OPT_CT, OPT_CK (the time and segment of the feed-forward in ``sw[SW_FF]``; NaN: none)

**Knots on the step grid.** A trajectory's knot (a cubic's acceleration jumps there) that falls on a
step boundary belongs to the step that ends there for that step's last stage and to the next step for
its first: the loops set ``OPT_SIDE`` to +1 for a stage at a step's start, −1 at its end and 0 in between
(:func:`servo_side`), and the segment is looked up ``SIDE_ULPS`` ulps of t to that side (the step grid's
own round-off, ``integrators.GRID_ROUNDOFF_ULPS``), the polynomial evaluated at t itself. Without it a
cubic trajectory's knots each put an acceleration jump into the step that ends there (xArm7, cubic
segments at 1 ms: 1.5e-5 rad of tracking error instead of 1.3e-7). The reference path's integrators read
the same sides from their stage times (``integrators.step_start``, ``step_end``).

**The feed-forward's cache.** When every joint is a servo joint the feed-forward is a function of the time
and the segment alone: a stage at the time and segment of the last evaluation (RK4's two mid-step stages,
a step's last stage and the next step's first away from knots) reuses it, so a step costs one RNEA of
feed-forward under rosenbrock2 and two under RK4 instead of two and four.
"""
from __future__ import annotations

import numpy as np

from .jit import njit
from .passive import add_coulomb_friction
from .tree import _JIT, _LEAF
from .treefn import id_at

#: columns of si
SI_V, SI_Q, SI_MODE, SI_COL = 0, 1, 2, 3
#: columns of sf
SF_KP, SF_KD, SF_UMAX = 0, 1, 2
#: servo modes (si[:, SI_MODE])
SERVO_POSITION, SERVO_VELOCITY = 0, 1
#: rows of sw: the feed-forward's configuration, velocity, acceleration, torques and passive scratch
#: (nq or nv entries), then per servo joint: q*, q̇*, q̈*, the applied torque, the saturation flag (1.0:
#: clamped at this evaluation) and the feed-forward torque
SW_Q, SW_V, SW_A, SW_FF, SW_P, SW_QS, SW_QDS, SW_QDDS, SW_U, SW_SAT, SW_FFJ = range(11)
NSW = 11
#: entries of opt
OPT_FF, OPT_SIDE, OPT_FIXED, OPT_CT, OPT_CK = 0, 1, 2, 3, 4
NOPT = 5
#: ulps of a stage's time within which a knot counts as on the step grid (module docstring)
SIDE_ULPS = 16.0
#: machine epsilon of float64
EPS = 2.220446049250313e-16
#: columns of the program rows C[k, j]: the origin, then c0..c5
C_T0 = 0
NC = 7


@njit(**_LEAF)
def segment_at(T, t):
    """Index of the program segment in force at time t: the last k with ``T[k] <= t`` (0 before T[0])."""
    lo = 0
    hi = T.shape[0] - 1
    if t < T[0]:
        return 0
    while lo < hi:               # invariant: T[lo] <= t; the answer is in [lo, hi]
        mid = (lo + hi + 1) // 2
        if T[mid] <= t:
            lo = mid
        else:
            hi = mid - 1
    return lo


@njit(**_LEAF)
def setpoint_eval(C, k, col, t, out, j):
    """``out[SW_QS, j], out[SW_QDS, j], out[SW_QDDS, j] = q*(t), q̇*(t), q̈*(t)`` of column col of
    segment k of a program C (module docstring), by Horner's rule in ``τ = t − t₀``."""
    tau = t - C[k, col, C_T0]
    c0, c1, c2 = C[k, col, 1], C[k, col, 2], C[k, col, 3]
    c3, c4, c5 = C[k, col, 4], C[k, col, 5], C[k, col, 6]
    out[SW_QS, j] = c0 + tau * (c1 + tau * (c2 + tau * (c3 + tau * (c4 + tau * c5))))
    out[SW_QDS, j] = c1 + tau * (2.0 * c2 + tau * (3.0 * c3 + tau * (4.0 * c4 + tau * 5.0 * c5)))
    out[SW_QDDS, j] = 2.0 * c2 + tau * (6.0 * c3 + tau * (12.0 * c4 + tau * 20.0 * c5))


@njit(**_LEAF)
def servo_side(srv, side):
    """Say which side of the step grid the next stages are on (``OPT_SIDE``: +1 a step's start, −1 its end,
    0 within); nothing without a servo (srv None)."""
    if srv is not None:
        srv[6][OPT_SIDE] = side


@njit(**_LEAF)
def servo_desired(srv, t, q):
    """The desired values of every servo joint at time t into ``sw[SW_QS:SW_QDDS + 1]`` (a velocity
    joint: ``q* = q`` (no position term), ``q̇*`` its setpoint, ``q̈* = 0``); returns the program's segment
    (looked up on the stage's side of the step grid, ``OPT_SIDE``)."""
    si, T, C, vset, sw = srv[0], srv[2], srv[3], srv[4], srv[5]
    side = srv[6][OPT_SIDE]
    k = segment_at(T, t + side * (SIDE_ULPS * EPS * abs(t)) if side != 0.0 else t)
    for j in range(si.shape[0]):
        col = si[j, SI_COL]
        if si[j, SI_MODE] == SERVO_POSITION:
            setpoint_eval(C, k, col, t, sw, j)
        else:
            sw[SW_QS, j] = q[si[j, SI_Q]]
            sw[SW_QDS, j] = vset[col]
            sw[SW_QDDS, j] = 0.0
    return k


@njit(**_LEAF)
def servo_feedforward(mi, mf, damping, friction, v_s, srv, q, v, W, dyn):
    """The feed-forward torques of (S1) into ``sw[SW_FF]`` (nv,): RNEA at the desired motion (the servo
    joints at ``sw[SW_QS:SW_QDDS + 1]``, the others at their own q, v and zero acceleration: the ``id`` at
    the address ``dyn[2]``, :mod:`.treefn`, the generic one or the model's generated code) plus the damping
    ``d q̇*`` and Coulomb friction ``f tanh(q̇*/v_s)`` the desired velocity meets, each torque then added to
    +0.0 (the two implementations agree but for the sign of a zero, :mod:`.codegen`: a −0 becomes +0, so a
    recording holds the same bits whichever ran). Uses W (the caller transforms it again for its own state
    afterwards)."""
    si, sw = srv[0], srv[5]
    nq = q.shape[0]
    nv = v.shape[0]
    qd, vd, ad, ff, pp = sw[SW_Q, :nq], sw[SW_V, :nv], sw[SW_A, :nv], sw[SW_FF, :nv], sw[SW_P, :nv]
    for a in range(nq):
        qd[a] = q[a]
    for a in range(nv):
        vd[a] = v[a]
        ad[a] = 0.0
        pp[a] = 0.0
    for j in range(si.shape[0]):
        vi = si[j, SI_V]
        if si[j, SI_MODE] == SERVO_POSITION:
            qd[si[j, SI_Q]] = sw[SW_QS, j]
        vd[vi] = sw[SW_QDS, j]
        ad[vi] = sw[SW_QDDS, j]
    id_at(dyn[2])(mi, mf, qd, vd, ad, ff, W)
    add_coulomb_friction(friction, v_s, vd, pp)     # pp = −f tanh(ṽ / v_s)
    for a in range(nv):
        ff[a] = (ff[a] + (damping[a] * vd[a] - pp[a])) + 0.0


@njit(**_LEAF)
def servo_forces_add(mi, mf, damping, friction, v_s, srv, t, q, v, tauv, W, dyn):
    """``tauv += τ`` of (S1) at time t (s) and state (q (nq,), v (nv,)); returns the servo's power
    ``Σ q̇_j τ_j`` (W). Leaves in sw the desired values, the applied torques ``SW_U``, the saturation
    flags ``SW_SAT`` and the feed-forward ``SW_FFJ`` of each servo joint. W: a work array
    (:func:`~robodyn_ros.kernels.tree.workspace`) it may overwrite (the feed-forward's RNEA); dyn: the
    dynamics' addresses (:mod:`.treefn`; the feed-forward takes ``dyn[2]``)."""
    si, sf, sw, opt = srv[0], srv[1], srv[5], srv[6]
    k = servo_desired(srv, t, q)
    ff_on = opt[OPT_FF] != 0.0
    if ff_on and not (opt[OPT_FIXED] != 0.0 and opt[OPT_CT] == t and opt[OPT_CK] == k):
        servo_feedforward(mi, mf, damping, friction, v_s, srv, q, v, W, dyn)
        opt[OPT_CT] = t
        opt[OPT_CK] = k
    P = 0.0
    for j in range(si.shape[0]):
        vi = si[j, SI_V]
        ff = sw[SW_FF, vi] if ff_on else 0.0
        u = sf[j, SF_KD] * (sw[SW_QDS, j] - v[vi]) + ff
        if si[j, SI_MODE] == SERVO_POSITION:
            u += sf[j, SF_KP] * (sw[SW_QS, j] - q[si[j, SI_Q]])
        umax = sf[j, SF_UMAX]
        sat = 0.0
        if u > umax:
            u, sat = umax, 1.0
        elif u < -umax:
            u, sat = -umax, 1.0
        sw[SW_U, j] = u
        sw[SW_SAT, j] = sat
        sw[SW_FFJ, j] = ff
        tauv[vi] += u
        P += v[vi] * u
    return P


@njit(**_LEAF)
def servo_jacobian_add(srv, sat, Dm, Km):
    """The servo's share of the implicit step's passive Jacobian (module docstring): ``Dm[v, v] += kd``
    and, for a position joint, ``Km[v, v] += kp`` on every joint whose flag in sat (ns,) is 0 (not
    saturated at the step's start: a clamped torque does not depend on the state)."""
    si, sf = srv[0], srv[1]
    for j in range(si.shape[0]):
        if sat[j] != 0.0:
            continue
        vi = si[j, SI_V]
        Dm[vi, vi] += sf[j, SF_KD]
        if si[j, SI_MODE] == SERVO_POSITION:
            Km[vi, vi] += sf[j, SF_KP]


@njit(**_LEAF)
def servo_time_rate(srv, Ft):
    """``Ft (nv,) = ∂τ/∂t`` of the servo's stiff part at its last evaluation: ``kp q̇* + kd q̈*`` on the
    unsaturated position joints, 0 elsewhere (the time term of the linearly implicit step)."""
    si, sf, sw = srv[0], srv[1], srv[5]
    for a in range(Ft.shape[0]):
        Ft[a] = 0.0
    for j in range(si.shape[0]):
        if si[j, SI_MODE] == SERVO_POSITION and sw[SW_SAT, j] == 0.0:
            Ft[si[j, SI_V]] = sf[j, SF_KP] * sw[SW_QDS, j] + sf[j, SF_KD] * sw[SW_QDDS, j]


@njit(**_JIT)
def servo_state(mi, mf, damping, friction, v_s, srv, t, q, v, W, out, dyn):
    """One evaluation of (S1) at (t, q, v) for the outputs: ``out (ns, 6)`` = per servo joint q*, q̇*,
    q̈*, the feed-forward torque, the applied torque and the saturation flag; returns the servo power.
    dyn: the dynamics' addresses (:func:`servo_forces_add`)."""
    tauv = np.zeros(v.shape[0])
    P = servo_forces_add(mi, mf, damping, friction, v_s, srv, t, q, v, tauv, W, dyn)
    sw = srv[5]
    for j in range(out.shape[0]):
        out[j, 0] = sw[SW_QS, j]
        out[j, 1] = sw[SW_QDS, j]
        out[j, 2] = sw[SW_QDDS, j]
        out[j, 3] = sw[SW_FFJ, j]
        out[j, 4] = sw[SW_U, j]
        out[j, 5] = sw[SW_SAT, j]
    return P


@njit(**_JIT)
def setpoints_many(T, C, cols, times, out):
    """``out (n, len(cols), 3)`` = q*, q̇*, q̈* of program columns cols at each of times (n,): the
    desired motion a trajectory commands, sampled (its check against the polynomials, the recorder)."""
    tmp = np.zeros((SW_QDDS + 1, max(cols.shape[0], 1)))
    for i in range(times.shape[0]):
        k = segment_at(T, times[i])
        for j in range(cols.shape[0]):
            setpoint_eval(C, k, cols[j], times[i], tmp, j)
            out[i, j, 0] = tmp[SW_QS, j]
            out[i, j, 1] = tmp[SW_QDS, j]
            out[i, j, 2] = tmp[SW_QDDS, j]
