"""The arm's compiled loops (:mod:`robodyn_ros.systems.arm`): its right-hand side with the work
quadrature (:func:`arm_rhs`), the fused fixed-step integration (:func:`arm_steps`) and publication
periods with their scripted commands and outputs (:func:`run_arm_periods`, the one entry from Python:
one period for the per-period path, many for the block path), on the tree algorithms of
:mod:`robodyn_ros.kernels.tree`.

The forward dynamics and the bias/mass pass of a tree without mimic joints or ground contacts, and a joint
servo's feed-forward inverse dynamics, are reached through the function addresses ``dyn = (fd, bm, id)`` of
:mod:`robodyn_ros.kernels.treefn`: the generic kernels or a model's generated code
(:mod:`robodyn_ros.kernels.codegen`), the same operations, behind one compiled loop.
"""
from __future__ import annotations

import math

import numpy as np
from .jit import njit

from .contact import (contact_jacobian_add, contact_points, ground_fext_ws, link_wrenches, point_body_forces,
                      touching_points)
from .coupled import couple_into, coupled_fd_ws, reduce_into
from .fixed_step import M_RK4, M_ROSENBROCK2, M_SEMI_IMPLICIT_EULER
from .linalg import chol_solve, cholesky
from .passive import add_coulomb_friction, friction_jacobian_add
from .profiles import CMD_GRAVITY_SINE, CMD_NONE, CMD_PD_HOLD, command_eval
from .rosenbrock import B1, B2, C21, GAMMA, GAMMA_STOP, factor_iteration_matrix, mat_vec, stage_rhs, stage_velocity
from .servo import SW_SAT, servo_forces_add, servo_jacobian_add, servo_side, servo_state, servo_time_rate
from ..integrators import GROW_MAX, H_MIN, SAFETY, SHRINK_MAX   # the controller's constants (in the fingerprint)
from ..model import SPHERICAL
from .tree import (_JIT, _LEAF, _limit_frame, joint_wrenches, limit_forces_add, limit_jacobian_add, normalize_into,
                   qdot_into, retract_into, rnea_into, tangent_rate_into, tangent_velocity_into, transforms, workspace)
from .treefn import bm_at, bmx_at, fd_at, fdx_at, kin_at


# ----------------------------------------------------------------------------------------------
# fused fixed-step integration of an arm with its work quadrature
# ----------------------------------------------------------------------------------------------
@njit(**_LEAF)
def arm_forces(damping, friction, v_s, lim, tau_app, nq, nv, z, dz, tauv):
    """``tauv = B u − D v − F tanh(v / v_s) + τ_lim`` at ``z = [q, v, W(, W_lim)]``; returns the power
    ``vᵀ tauv``. F: Coulomb joint friction (``passive.add_coulomb_friction``; zeros = none).
    With W_lim in z, ``dz[nq + nv + 1] = vᵀ τ_lim`` (the limit forces are formed alone in
    ``dz[nq:nq + nv]``, which the caller's ABA overwrites; one row per joint, so tauv gets the
    same sums as :func:`limit_forces_add` on it). The sums are those of ``ArmSystem.generalized_forces``
    in its order. Shared by :func:`arm_rhs` and the generated one."""
    q = z[:nq]
    v = z[nq:nq + nv]
    for k in range(nv):
        tauv[k] = tau_app[k] - damping[k] * v[k]
    add_coulomb_friction(friction, v_s, v, tauv)
    if z.shape[0] > nq + nv + 1:
        tl = dz[nq:nq + nv]
        for k in range(nv):
            tl[k] = 0.0
        if lim.shape[0]:
            limit_forces_add(lim, q, v, tl)
        P = 0.0
        for k in range(nv):
            P += v[k] * tl[k]
            tauv[k] += tl[k]
        dz[nq + nv + 1] = P
    elif lim.shape[0]:
        limit_forces_add(lim, q, v, tauv)
    P = 0.0
    for k in range(nv):
        P += v[k] * tauv[k]
    return P


@njit(**_LEAF)
def arm_rhs(mi, mf, damping, friction, v_s, lim, tau_app, nq, nv, z, dz, tauv, W, cpl, cs, con, fx, t, srv, dyn):
    """``dz/dt`` for ``z = [q, v, W]``: ``[q̇; ABA(q, v, τ); vᵀ τ]`` with ``τ = B u − D v − F tanh(v/v_s) +
    τ_lim``;
    for ``z = [q, v, W, W_lim]`` also ``vᵀ τ_lim`` (the joint-limit work on its own).

    tau_app (nv,) = B u held over the call; damping (nv,) = D; friction (nv,) = F, v_s its
    regularisation speed; lim: the joint-limit table
    (:func:`limit_forces_add`, 0 rows = none); tauv (nv,) scratch; cpl: None, or ``(mimic table,
    col, mul)`` of a tree with mimic joints (:mod:`.coupled`), whose v̇ is then the coupled
    dynamics (:func:`.coupled.coupled_fd_ws`, scratch cs) instead of ABA. con: None, or the packed
    ground contacts (:mod:`.contact`) whose body forces (into the scratch fx (nb, 6)) enter ABA; then
    ``z`` ends with the contact work ``W_c`` (``[q, v, W(, W_lim), W_c]``), whose rate is their power
    (also part of W's). srv: None, or the joint servo (:mod:`.servo`), whose torques at time t (s) join
    τ and whose power joins W's. Without cpl and con, ABA is the ``fd`` at the address ``dyn[0]``
    (:mod:`.treefn`); with con, the kinematics the contacts read are ``kin`` (``dyn[3]``) and ABA under their
    forces ``fdx`` (``dyn[4]``). (ArmSystem.rhs, .input_power and .work_component_powers of the reference path.)
    """
    q = z[:nq]
    v = z[nq:nq + nv]
    qdot_into(mi, q, v, dz[:nq])
    if con is None:   # a None argument prunes the contact code at compile time
        P = arm_forces(damping, friction, v_s, lim, tau_app, nq, nv, z, dz, tauv)
    else:
        P = arm_forces(damping, friction, v_s, lim, tau_app, nq, nv, z[:z.shape[0] - 1], dz, tauv)
    if srv is not None:   # before W holds q's transforms: the feed-forward's RNEA uses W
        P += servo_forces_add(mi, mf, damping, friction, v_s, srv, t, q, v, tauv, W, dyn)
    if cpl is not None:   # a None argument prunes this branch at compile time: no coupled code for other trees
        transforms(mi, mf, q, W)
        coupled_fd_ws(mi, mf, cpl[1], cpl[2], q, v, tauv, dz[nq:nq + nv], W, cs[0], cs[1], cs[2], cs[3], cs[4], cs[5])
        dz[nq + nv] = P
    elif con is not None:
        kin_at(dyn[3])(mi, mf, q, v, W)
        Pc = ground_fext_ws(con, W, fx)
        fdx_at(dyn[4])(mi, mf, q, v, tauv, fx, dz[nq:nq + nv], W)
        dz[nq + nv] = P + Pc
        dz[z.shape[0] - 1] = Pc
    else:
        fd_at(dyn[0])(mi, mf, q, v, tauv, dz[nq:nq + nv], W)
        dz[nq + nv] = P


@njit(**_JIT)
def coupled_scratch(cpl, nv):
    """The work arrays of the coupled dynamics (:func:`.coupled.coupled_fd_ws`) of a tree with mimic joints
    (cpl, :func:`arm_rhs`), nv velocities; empty ones for cpl None (which prunes the rest at compile time)."""
    if cpl is None:
        e = np.zeros(0)
        e2 = np.zeros((0, 0))
        return e2, e, e2, e2, e, e
    nr = nv - cpl[0].shape[0]
    return np.zeros((nv, nv)), np.zeros(nv), np.zeros((nr, nr)), np.zeros((nr, nr)), np.zeros(nr), np.zeros(nr)


@njit(**_JIT)
def arm_steps(mi, mf, damping, friction, v_s, lim, tau_app, nq, method, z, dt, n_full, h_last, cpl, con, t0, srv, ros,
              dyn):
    """Integrate ``z = [q, v, W]`` (or ``[q, v, W, W_lim]``, see :func:`arm_rhs`) in place over
    ``n_full`` steps of dt and one of h_last (if > 0).

    method: ``M_EULER``, ``M_SEMI_IMPLICIT_EULER``, ``M_RK4`` or ``M_ROSENBROCK2`` (the linearly implicit
    step :func:`arm_rosenbrock_step`), with the arithmetic of
    :mod:`robodyn_ros.integrators` (RK4: ``acc = k1 + 2 k2 + 2 k3 + k4`` folded stage by
    stage, ``y += h/6 acc``; symplectic Euler: ``[v, W] += h f[nq:]``, then ``q += h q̇(q,
    v_new)``); free-joint quaternions are renormalised and mimic joints set from their sources
    (cpl: None, or see :func:`arm_rhs`) after every step, as the Simulator's projection does.
    con: None, or the ground contacts of :func:`arm_rhs`. t0: the time (s) of the first step (step k starts
    at ``t0 + k dt``); srv: None, or the joint servo of :func:`arm_rhs`, evaluated at each stage's time.
    ros: the linearly implicit step's work arrays
    ``(vec (ROS_VECTORS, nv), mat (ROS_MATRICES, nv, nv), (red (2, nr, nr), red (2, nr)), (cj (3, nv),
    cj (nv,) int64), ctl (CTL_SIZE,))`` (:func:`rosenbrock_work`; a tolerance in ctl: the span under error
    control, :func:`arm_controlled_steps`), or None for the other methods (a None argument prunes the
    implicit step's code at compile time: an rk4 run compiles none of it). dyn: the dynamics' addresses
    (:mod:`.treefn`). Returns the index of the first step whose result is non-finite (z then holds that
    result), or -1.
    """
    if ros is not None:   # rosenbrock2 under error control (a tolerance in its control row): its own loop
        if method == M_ROSENBROCK2 and ros[4][CTL_RTOL] > 0.0:
            return arm_controlled_steps(mi, mf, damping, friction, v_s, lim, tau_app, nq, z, dt, n_full, h_last, cpl,
                                        con, t0, srv, ros, dyn)
    nb = mi.shape[0]
    fx = np.zeros((nb, 6))
    n = z.shape[0]
    nv = damping.shape[0]
    W = workspace(nb)
    buf = np.empty(3 * n + nv + nq)
    K = buf[:n]
    Y = buf[n:2 * n]
    acc = buf[2 * n:3 * n]
    tauv = buf[3 * n:3 * n + nv]
    qd = buf[3 * n + nv:]
    cs = coupled_scratch(cpl, nv)
    n_steps = n_full + (1 if h_last > 0.0 else 0)
    for k in range(n_steps):
        h = dt if k < n_full else h_last
        t = t0 + k * dt   # the reference integrator's step times (integrators.FixedStepIntegrator._advance)
        servo_side(srv, 1.0)   # a servo's setpoints: a knot on the step grid is read from this step's side
        if method == M_RK4:
            half = 0.5 * h
            arm_rhs(mi, mf, damping, friction, v_s, lim, tau_app, nq, nv, z, K, tauv, W, cpl, cs, con, fx, t, srv, dyn)
            servo_side(srv, 0.0)
            for a in range(n):
                acc[a] = K[a]
                Y[a] = K[a] * half + z[a]
            arm_rhs(mi, mf, damping, friction, v_s, lim, tau_app, nq, nv, Y, K, tauv, W, cpl, cs, con, fx, t + half,
                    srv, dyn)
            for a in range(n):
                acc[a] = (acc[a] + K[a]) + K[a]
                Y[a] = K[a] * half + z[a]
            arm_rhs(mi, mf, damping, friction, v_s, lim, tau_app, nq, nv, Y, K, tauv, W, cpl, cs, con, fx, t + half,
                    srv, dyn)
            for a in range(n):
                acc[a] = (acc[a] + K[a]) + K[a]
                Y[a] = K[a] * h + z[a]
            servo_side(srv, -1.0)
            arm_rhs(mi, mf, damping, friction, v_s, lim, tau_app, nq, nv, Y, K, tauv, W, cpl, cs, con, fx, t + h, srv, dyn)
            h6 = h / 6.0
            for a in range(n):
                z[a] += (acc[a] + K[a]) * h6
        elif method == M_ROSENBROCK2:
            if ros is None:
                z[nq] = math.nan   # called without the implicit step's work arrays: a failed step
            else:
                rest = h            # one step, or several where it enters a stiff stop (limit_event)
                splits = 0
                while rest > 0.0:
                    hs = rest
                    taken = -1.0
                    while taken < 0.0:
                        taken = arm_rosenbrock_step(mi, mf, damping, friction, v_s, lim, tau_app, nq, nv, z, hs,
                                                    splits < MAX_SPLITS, W, K, Y, acc, tauv, ros[0], ros[1], cpl, cs,
                                                    ros[2], con, fx, ros[3], t + (h - rest), srv,
                                                    dyn)
                        if taken == -math.inf:
                            break
                        if taken < 0.0:
                            hs = -taken
                            splits += 1
                    if taken == -math.inf:
                        z[nq] = math.nan   # the iteration matrix was not positive definite: a failed step
                        break
                    rest = 0.0 if hs >= rest else rest - hs
        elif method == M_SEMI_IMPLICIT_EULER:
            arm_rhs(mi, mf, damping, friction, v_s, lim, tau_app, nq, nv, z, K, tauv, W, cpl, cs, con, fx, t, srv, dyn)
            for a in range(nq, n):
                z[a] += K[a] * h
            qdot_into(mi, z[:nq], z[nq:nq + nv], qd)
            for a in range(nq):
                z[a] += qd[a] * h
        else:
            arm_rhs(mi, mf, damping, friction, v_s, lim, tau_app, nq, nv, z, K, tauv, W, cpl, cs, con, fx, t, srv, dyn)
            for a in range(n):
                z[a] += K[a] * h
        servo_side(srv, 0.0)
        normalize_into(mi, z[:nq])
        if cpl is not None:
            couple_into(cpl[0], z[:nq], z[nq:nq + nv])
        for a in range(n):
            if not math.isfinite(z[a]):
                return k
    return -1


#: the control row ``ros[4]`` of :func:`rosenbrock_work`: the tolerances and the most steps the call may accept
#: (set by the caller; rtol 0: fixed steps; steps 0: no limit), and what the controlled loop adds up (accepted
#: and rejected steps, the smallest accepted step, 1 where the step fell below :data:`H_MIN` of dt, 1 where it
#: stopped at its most steps, and how far it got, s)
CTL_RTOL, CTL_ATOL, CTL_MAX_STEPS, CTL_ACCEPTED, CTL_REJECTED, CTL_H_MIN, CTL_UNDERFLOW, CTL_BUDGET, CTL_DONE = range(9)
CTL_SIZE = 9


@njit(**_JIT)
def arm_controlled_steps(mi, mf, damping, friction, v_s, lim, tau_app, nq, z, dt, n_full, h_last, cpl, con, t0, srv,
                         ros, dyn):
    """rosenbrock2 under error control over the span ``n_full dt + h_last`` from t0 (what :func:`arm_steps`
    would take in fixed steps), in place; dt is the largest step, the first one tried, and the last step
    ends on the span's end.

    Each step is :func:`arm_rosenbrock_step` (events at stiff stops, touch-downs in J, as in fixed steps).
    Its local error is that of the embedded first-order solution ``zₙ ⊕ h k1`` (Verwer, Spee, Blom &
    Hundsdorfer 1999), ``e = h (k1 + k2) / 2`` in the tangent coordinates of q and in v, measured as the
    root mean square of ``e_q / atol`` and ``e_v / (atol + rtol max(|vₙ|, |vₙ₊₁|))`` over the 2 nv
    components. A step with a measure ≤ 1 is taken, then projected (quaternions, mimic joints) as a fixed
    step is; a larger one is undone. The next step is ``h min(GROW_MAX, max(SHRINK_MAX, SAFETY / √err))``
    (order 2: the error of the embedded pair goes as h²), at most dt. Nothing is carried from one call
    to the next: each publication period starts again at dt, so a run is the same whichever path (per
    period or blocks of periods) takes it.

    ros[4] (:data:`CTL_SIZE`): the tolerances and the most steps, read; the counters, added to. Returns -1,
    or (a step non-finite, the step below ``H_MIN dt``, or the most steps taken short of the span; the latter
    two flagged in ros[4]) the index of the fixed step of dt the failure falls in, z holding the failed result
    (non-finite; at the most steps: the last step's state)."""
    ctl = ros[4]
    rtol = ctl[CTL_RTOL]
    atol = ctl[CTL_ATOL]
    vec = ros[0]
    kq1, kv1, kq2, kv2 = vec[2], vec[3], vec[4], vec[5]
    nb = mi.shape[0]
    fx = np.zeros((nb, 6))
    n = z.shape[0]
    nv = damping.shape[0]
    W = workspace(nb)
    buf = np.empty(4 * n + nv)
    K = buf[:n]
    Y = buf[n:2 * n]
    acc = buf[2 * n:3 * n]
    z0 = buf[3 * n:4 * n]
    tauv = buf[4 * n:]
    cs = coupled_scratch(cpl, nv)
    span = n_full * dt + h_last
    done = 0.0
    h = dt
    splits = 0
    while done < span:
        rest = span - done
        hs = h
        last = hs >= rest
        if last:
            hs = rest
        for a in range(n):
            z0[a] = z[a]
        servo_side(srv, 1.0)
        taken = arm_rosenbrock_step(mi, mf, damping, friction, v_s, lim, tau_app, nq, nv, z, hs, splits < MAX_SPLITS,
                                    W, K, Y, acc, tauv, ros[0], ros[1], cpl, cs, ros[2], con, fx, ros[3], t0 + done,
                                    srv, dyn)
        servo_side(srv, 0.0)
        if taken == -math.inf:
            z[nq] = math.nan   # the iteration matrix was not positive definite: a failed step
            return int(done / dt)
        if taken < 0.0:        # a stiff stop met within the step: take the part up to it (z untouched)
            h = -taken
            splits += 1
            continue
        s = 0.0
        half = 0.5 * hs
        for a in range(nv):
            eq = half * (kq1[a] + kq2[a]) / atol
            ev = half * (kv1[a] + kv2[a]) / (atol + rtol * max(abs(z0[nq + a]), abs(z[nq + a])))
            s += eq * eq + ev * ev
        err = math.sqrt(s / (2 * nv))
        if err <= 1.0:
            ctl[CTL_ACCEPTED] += 1.0
            if hs < ctl[CTL_H_MIN]:
                ctl[CTL_H_MIN] = hs
            splits = 0
            normalize_into(mi, z[:nq])
            if cpl is not None:
                couple_into(cpl[0], z[:nq], z[nq:nq + nv])
            for a in range(n):
                if not math.isfinite(z[a]):
                    return int(done / dt)
            if last:
                break
            done += hs
            ctl[CTL_DONE] = done
            if ctl[CTL_MAX_STEPS] > 0.0 and ctl[CTL_ACCEPTED] >= ctl[CTL_MAX_STEPS]:
                ctl[CTL_BUDGET] = 1.0   # the step budget spent: z is the last step's state, ``done`` in
                return int(done / dt)
            h = min(dt, hs * min(GROW_MAX, max(SHRINK_MAX, SAFETY / math.sqrt(max(err, 1e-12)))))
        else:
            ctl[CTL_REJECTED] += 1.0
            for a in range(n):
                z[a] = z0[a]
            h = hs * (max(SHRINK_MAX, SAFETY / math.sqrt(err)) if math.isfinite(err) else SHRINK_MAX)
            if h < H_MIN * dt:
                ctl[CTL_UNDERFLOW] = 1.0
                z[nq] = math.nan
                return int(done / dt)
    return -1


@njit(**_LEAF)
def passive_jacobian(damping, friction, v_s, lim, q, v, qs, use_qs, Dm, Km):
    """The passive Jacobian of a tree at (q, v) added to Dm, Km: ``Dm += −∂τ_p/∂v``, ``Km += −∂τ_p/∂q``
    (nv, nv, tangent coordinates; the caller starts them at zero, or K at the gravity stiffness), as the
    sum of named contributions (:mod:`robodyn_ros.kernels.rosenbrock`):
    joint damping ``diag(d)``, the Coulomb friction's slope (``passive.friction_jacobian_add``,
    regularisation speed v_s), the joint-limit moments' spring and damper on their branches at (q, v)
    (returns how many stop terms it added)
    (:func:`~robodyn_ros.kernels.tree.limit_jacobian_add`; with use_qs also the stops the stage configuration qs is beyond).
    A new passive element (a compliant contact: ``Jᶜᵀ K_c Jᶜ``, ``Jᶜᵀ D_c Jᶜ``) adds its own term here."""
    for i in range(Dm.shape[0]):
        Dm[i, i] += damping[i]
    friction_jacobian_add(friction, v_s, v, Dm)
    if lim.shape[0]:
        return limit_jacobian_add(lim, q, v, qs, use_qs, Dm, Km)
    return 0


#: a stop is resolved explicitly over a time t when ``γ² t² k <= LIMIT_EXPLICIT · M_jj`` (its mode
#: ω t <~ 0.2: the stage point may then meet it without J); stiffer stops entered within a step are events
LIMIT_EXPLICIT = 0.05
#: time to contact below which (as a fraction of the step) a stop counts as met: it joins J at once
LIMIT_CONTACT = 1e-6


@njit(**_LEAF)
def _first_root(x0, x1, x2):
    """The smallest t > 0 with ``x0 + x1 t + x2 t² = 0`` (x0 < 0: inside), or inf."""
    if x2 == 0.0:
        return -x0 / x1 if x1 > 0.0 else math.inf
    disc = x1 * x1 - 4.0 * x2 * x0
    if disc < 0.0:
        return math.inf
    sq = math.sqrt(disc)
    # roots (-x1 ± sq) / (2 x2), written to avoid cancellation: t = 2 x0 / (-x1 ∓ sq)
    best = math.inf
    for den in (-x1 - sq, -x1 + sq):
        if den != 0.0:
            t = 2.0 * x0 / den
            if t > 0.0 and t < best:
                best = t
    return best


@njit(**_LEAF)
def _entry_step(x0, xd, xs, h, k, m):
    """Sub-step of a step h that meets a stop (stiffness k, inertia m) whose signed penetration is
    x0 <= 0 at its start, xd its rate, xs > 0 at the stage point ``h kq1`` (= ``h xd + γh² xa``): h when
    the stop is explicit over h; 0 when the joint is at contact (the stop joins J); else the time to
    contact t_c (``x0 + xd t + ½ xa t² = 0``) when the stop is explicit over t_c, or the longest step
    whose stage point stays short of the stop (``x0 + xd t + γ xa t² = 0``), which the next one resumes from.

    x0 = 0 (a joint exactly on its stop, where a step that met it at t_c leaves it) is at contact: the
    roots of the quadratics are then t = 0 and one behind or far ahead, and without this the stop would
    be neither cut nor in J -- the stage point's stiff force explicit (a hinge coasting in at 1 rad/s
    with ωh = 10 was thrown back at 54 rad/s)."""
    gk = GAMMA * GAMMA * k
    if gk * h * h <= LIMIT_EXPLICIT * m:
        return h
    if x0 >= 0.0:
        return 0.0
    xa = (xs - x0 - h * xd) / (GAMMA * h * h)
    tc = _first_root(x0, xd, 0.5 * xa)
    if tc <= LIMIT_CONTACT * h:
        return 0.0
    if tc < h and gk * tc * tc <= LIMIT_EXPLICIT * m:
        return tc
    return min(_first_root(x0, xd, GAMMA * xa), h)


@njit(**_LEAF)
def limit_event(lim, q, v, h, qs, H):
    """The step to take when the stage point qs (nq,) of a step h from (q, v) is beyond a stop the branch
    at q left out of J: h (no such stop, or every one explicit over h: :data:`LIMIT_EXPLICIT`), 0 (at
    contact: the stops join J, ``use_qs`` of :func:`~robodyn_ros.kernels.tree.limit_jacobian_add`), or a shorter step that lands the
    joint on the stop, or short of it with its stage point outside (:func:`_entry_step`; the smallest
    over the stops met; a spherical row's three components: :func:`_spherical_limit_event`). H (nv, nv):
    the mass matrix, whose diagonal is the inertia each stop acts on. (Called at every step: it allocates
    nothing for 1-DOF rows.)"""
    step = h
    for r in range(lim.shape[0]):
        if int(lim[r, 0]) == SPHERICAL:
            s = _spherical_limit_event(lim, r, q, v, h, qs, H)
            if s < step:
                step = s
            continue
        qi = int(lim[r, 1])
        vi = int(lim[r, 2])
        s = _stop_entry(q[qi], v[vi], qs[qi], lim[r, 4], lim[r, 5], h, lim[r, 10], H[vi, vi])
        if s < step:
            step = s
    return step


@njit(**_LEAF)
def _stop_entry(th, thd, ths, lo, hi, h, k, m):
    """One component's entry step (:func:`limit_event`, :func:`_entry_step`) at angle th, rate thd, stage value
    ths, limits lo, hi, stiffness k and inertia m; inf when it is beyond a limit already (its branch is in J)
    or its stage value stays inside."""
    if th > hi or th < lo:
        return math.inf
    if ths > hi:
        return _entry_step(th - hi, thd, ths - hi, h, k, m)
    if ths < lo:
        return _entry_step(lo - th, -thd, lo - ths, h, k, m)
    return math.inf


@njit(**_LEAF)
def _spherical_limit_event(lim, r, q, v, h, qs, H):
    """:func:`limit_event` of the spherical row r: the smallest entry step over its rotation vector's three
    components (:func:`~robodyn_ros.kernels.tree._limit_frame` at q and at qs), inf when none enters."""
    vi = int(lim[r, 2])
    k = lim[r, 10]
    step = math.inf
    phi, _, d = _limit_frame(lim, r, q, v)
    phs, _, _ = _limit_frame(lim, r, qs, v)
    for e in range(3):
        s = _stop_entry(phi[e], d[e], phs[e], lim[r, 4 + 2 * e], lim[r, 5 + 2 * e], h, k, H[vi + e, vi + e])
        if s < step:
            step = s
    return step


@njit(**_LEAF)
def contact_bias_mass(mi, mf, con, q, v, zero, bias, H, G, Dc, Kc, fx, cj, W, dyn):
    """The bias/mass pass (:func:`.treefn.generic_bm`) on a ground (con: :func:`arm_rhs`): ``bias = C + g − τ_c`` with the contacts'
    generalised force ``τ_c = Σ J_iᵀ F_i`` (their body forces fx (nb, 6), :func:`.contact.ground_fext_ws`,
    given to :func:`rnea_ws`), H, G as there, and the contacts' damping and stiffness ``Dc, Kc`` (nv, nv) =
    ``Σ J_iᵀ D_i J_i``, ``Σ J_iᵀ K_i J_i`` (:func:`.contact.contact_jacobian_add`, (C4)-(C5); cj: its
    scratch) at one transform and world-kinematics pass (``kin``, then ``bmx``: the addresses ``dyn[3]``, ``dyn[5]``
    of :mod:`.treefn`). Returns the contacts' power ``Σ F_i·u_i`` (W) and the number of touching points."""
    kin_at(dyn[3])(mi, mf, q, v, W)
    Pc = ground_fext_ws(con, W, fx)
    nv = H.shape[0]
    for a in range(nv):
        for b in range(nv):
            Dc[a, b] = 0.0
            Kc[a, b] = 0.0
    touching = contact_jacobian_add(con, mi, mf, W, Dc, Kc, cj[0], cj[1])
    bmx_at(dyn[5])(mi, mf, q, v, zero, fx, bias, H, G, W)
    return Pc, touching


@njit(**_LEAF)
def contact_stage_jacobian(mi, mf, con, touching, Dc, K2, cj, W):
    """Touch-down within a step: when more points touch at the stage point Y (whose poses and velocities
    W holds: :func:`arm_rhs` at Y) than the ``touching`` at zₙ -- a point's friction slope ``μ f_n / v_s``
    acts within the step but was not in J at zₙ, where f_n = 0: over a step with ``h μ f_n / (v_s m) >> 1``
    it would be explicit -- J's contact damping Dc is taken at Y instead (the slopes the step meets; any
    J keeps the W-method's order 2). The stiffness stays zₙ's: a new point's spring in K would act on the
    whole step's displacement (``−γh K bq``) as if it touched at zₙ, pushing from above the plane (A1 at
    1 ms: the step that crosses the plane ends its feet 0.5 mm short of rk4's, 0.2 mm with D alone).
    Returns how many points touch at Y (Dc unchanged when not more than ``touching``). K2 (nv, nv), cj:
    scratch."""
    ty = touching_points(con, W)
    if ty <= touching:
        return ty
    nv = Dc.shape[0]
    for a in range(nv):
        for b in range(nv):
            Dc[a, b] = 0.0
            K2[a, b] = 0.0
    return contact_jacobian_add(con, mi, mf, W, Dc, K2, cj[0], cj[1])


@njit(**_LEAF)
def arm_implicit_matrix(mi, mf, damping, friction, v_s, lim, q, v, h, qs, use_qs, W, mat, cpl, red, touching, srv,
                        sat):
    """The iteration matrix ``A = M + γh D + γ²h² K`` (R5) of :func:`arm_rosenbrock_step` and its Cholesky
    factor, into ``mat = [H (= M, given), D, K, A, L, G (given)]``: D, K from :func:`passive_jacobian`
    (stops at the stage configuration qs too with use_qs), when ``touching`` > 0 points touch a ground the
    contacts' ``D_c, K_c`` (``mat[6], mat[7]``: :func:`contact_bias_mass`, :func:`contact_stage_jacobian`),
    plus the gravity stiffness G = ∂g/∂q of the 1-DOF joints (the bias/mass pass ``bm``), which is dropped
    when A is not positive definite with it (a load above its axis stiff enough to matter at this step),
    and the joint servo's kp, kd on the joints not saturated at the step's start (srv: None, or
    :mod:`.servo`; sat (ns,) their flags, :func:`.servo.servo_jacobian_add`).
    Returns the γ of the step: ``GAMMA`` (1 − 1/√2), or ``GAMMA_STOP`` (1 + 1/√2) when a joint stop is in J
    or a contact touches (docs/contact.md: the friction's sign flips with the small root), whose law switches
    its damper within a step (:mod:`robodyn_ros.kernels.rosenbrock`); 0.0 when A is not positive definite
    without the gravity part either.

    Why gravity is in J: with the passive forces alone a stiffly damped joint under gravity converges at
    order 1 (its velocity is the balance ``D v = τ − g(q)`` at a lagging q), and an undamped swinging
    link gets Heun's error constant 1/6 instead of the method's 0.040 (a pendulum swinging from 1 rad,
    1 s at 1 ms: 1.8e-6 rad with it, 6.7e-6 rad without; test_rosenbrock)."""
    H, Dm, Km, A, L, G = mat[0], mat[1], mat[2], mat[3], mat[4], mat[5]
    nv = Km.shape[0]
    if touching <= 0:
        for a in range(nv):
            for b in range(nv):
                Dm[a, b] = 0.0
                Km[a, b] = G[a, b]
    else:   # the ground's D_c, K_c (contact_bias_mass) are passive terms as the joints' are
        for a in range(nv):
            for b in range(nv):
                Dm[a, b] = mat[6][a, b]
                Km[a, b] = G[a, b] + mat[7][a, b]
    stops = passive_jacobian(damping, friction, v_s, lim, q, v, qs, use_qs, Dm, Km)
    if srv is not None:
        servo_jacobian_add(srv, sat, Dm, Km)
    gamma = GAMMA_STOP if stops or touching > 0 else GAMMA
    if factor_stage_matrix(H, Dm, Km, gamma * h, A, L, cpl, red):
        return gamma
    for a in range(nv):   # without the gravity part
        for b in range(nv):
            Km[a, b] -= G[a, b]
    return gamma if factor_stage_matrix(H, Dm, Km, gamma * h, A, L, cpl, red) else 0.0


@njit(**_LEAF)
def factor_stage_matrix(H, Dm, Km, gh, A, L, cpl, red):
    """Factor the iteration matrix (:func:`robodyn_ros.kernels.rosenbrock.factor_iteration_matrix`); for a
    tree with mimic joints (cpl, :mod:`.coupled`) its reduction to the independent joints,
    ``A_r = Gᵀ A G`` (:func:`.coupled.reduce_into`), into ``red[0] = [A_r, L_r]``. False if not positive
    definite."""
    if cpl is None:
        return factor_iteration_matrix(H, Dm, Km, gh, A, L)
    nv = H.shape[0]
    gh2 = gh * gh
    for i in range(nv):
        for j in range(nv):
            A[i, j] = H[i, j] + gh * Dm[i, j] + gh2 * Km[i, j]
    Ar, Lr = red[0][0], red[0][1]
    reduce_into(A, H[0], cpl[1], cpl[2], Ar, red[1][0])
    return cholesky(Ar, Ar.shape[0], Lr)


@njit(**_LEAF)
def solve_stage(L, Km, gh, force, bq, kv, tmp, cpl, red):
    """kv (nv,) of one stage (R6): :func:`robodyn_ros.kernels.rosenbrock.stage_velocity`; with mimic joints
    in the independent ones, ``A_r kv_r = Gᵀ (force − γh K bq)``, ``kv = G kv_r``."""
    if cpl is None:
        stage_velocity(L, Km, gh, force, bq, kv, tmp)
        return
    nv = kv.shape[0]
    stage_rhs(Km, gh, force, bq, tmp)
    col, mul = cpl[1], cpl[2]
    fr, xr = red[1][0], red[1][1]
    for a in range(fr.shape[0]):
        fr[a] = 0.0
    for k in range(nv):
        fr[col[k]] += mul[k] * tmp[k]
    chol_solve(red[0][1], fr.shape[0], fr, xr)
    for k in range(nv):
        kv[k] = mul[k] * xr[col[k]]


#: sub-steps a step may be cut into where it enters stiff stops (then the stops join J at once)
MAX_SPLITS = 16
#: rows of the vector (nv,) and matrix (nv, nv) work arrays of :func:`arm_rosenbrock_step`
ROS_VECTORS, ROS_MATRICES = 13, 9


def rosenbrock_work(nv: int, nr: int):
    """The work arrays ``ros`` of :func:`arm_steps` for the linearly implicit step of a tree with nv
    velocities, nr of them independent (nv without mimic joints): vectors, matrices, the iteration matrix
    in the independent joints, a contact point's Jacobian and its columns, and the error control's row
    (:data:`CTL_SIZE`; rtol 0: fixed steps, :func:`arm_controlled_steps`)."""
    return (np.empty((ROS_VECTORS, nv)), np.empty((ROS_MATRICES, nv, nv)),
            (np.empty((2, nr, nr)), np.empty((2, nr))), (np.empty((3, nv)), np.empty(nv, dtype=np.int64)),
            np.zeros(CTL_SIZE))


@njit(**_LEAF)
def tangent_rate(mi, simple, q, v, out):
    """:func:`~robodyn_ros.kernels.tree.tangent_rate_into`, or ``out = v`` when ``simple`` (1-DOF joints only)."""
    if simple:
        for a in range(v.shape[0]):
            out[a] = v[a]
    else:
        tangent_rate_into(mi, q, v, out)


@njit(**_LEAF)
def stiffness_rate(mi, simple, con, q, bq, out):
    """The stage rate bq (tangent coordinates) in the coordinates K acts on: bq itself, but on a ground
    (con) of a tree with a free root ``Φ bq`` (:func:`~robodyn_ros.kernels.tree.tangent_velocity_into`):
    the contacts' K_c is ``−∂τ_c/∂q`` for q-increments in velocity coordinates (body-frame linear part),
    while the stage algebra's tangent increments have the free root's position in the world frame
    (``K_tan = K_c Φ``; in A, ``K_tan T = K_c``, so the iteration matrix keeps K_c). Returns the array
    to use."""
    if con is None or simple:
        return bq
    tangent_velocity_into(mi, q, bq, out)
    return out


@njit(**_LEAF)
def retract(mi, simple, q, dq, h, out):
    """:func:`~robodyn_ros.kernels.tree.retract_into`, or ``out = q + h dq`` when ``simple`` (1-DOF joints only)."""
    if simple:
        for a in range(q.shape[0]):
            out[a] = q[a] + h * dq[a]
    else:
        retract_into(mi, q, dq, h, out)


@njit(**_LEAF)
def arm_rosenbrock_step(mi, mf, damping, friction, v_s, lim, tau_app, nq, nv, z, h, split, W, dz, Y, k1, tauv, vec,
                        mat, cpl, cs, red, con, fx, cj, t, srv, dyn):
    """One linearly implicit step (:mod:`robodyn_ros.kernels.rosenbrock`, (R1)-(R6)) of an arm,
    ``z = [q, v, W(, W_lim)]`` in place. Returns h when taken; ``−s`` (z untouched) when the step meets a
    stiff stop it should enter as a shorter step s (with split; :func:`limit_event`: the caller takes s,
    then the rest); ``−inf`` (z untouched) when the iteration matrix is not positive definite.

    J (:func:`arm_implicit_matrix`) holds the passive forces at zₙ (damping, friction slope, the
    joint-limit spring and damper of the branches at zₙ) and the gravity stiffness of the 1-DOF joints.
    A stage point beyond a stiff stop that J left out is an event: the step is cut where the joint meets
    the stop (or short of it), and at contact the stop joins J and stage 1 is redone. Coriolis forces,
    the gravity of free and spherical joints and the commands are explicit. Stage 1 solves
    ``A kv1 = r(zₙ) − γh K fq`` with the force residual ``r = τ − RNEA(q, v, 0)`` (no M⁻¹); stage 2
    evaluates :func:`arm_rhs` (ABA) at ``Y = zₙ ⊕ h k1`` and solves ``A kv2 = M (f_v(Y) − 2 kv1) −
    γh K (fq(Y) − 2 kq1)``. Increments of q are tangent vectors (:func:`~robodyn_ros.kernels.tree.tangent_rate_into`, applied by
    :func:`~robodyn_ros.kernels.tree.retract_into`); the work entries W (no J rows) take ``k = P`` (the power) and
    ``k2 = P(Y) − 2 k1``. With mimic joints (cpl, cs: see :func:`arm_rhs`) the stages are solved in the
    independent joints (:func:`factor_stage_matrix`, :func:`solve_stage`; red: their work arrays) and
    f(Y) is the coupled dynamics. On a ground (con, fx: see :func:`arm_rhs`; ``z`` ends with W_c) the
    contacts' forces are in the residual r and their ``D_c, K_c`` in J (:func:`contact_bias_mass`; cj: its
    scratch). The step starts at time t (s); a joint servo (srv, :mod:`.servo`) is in the residual at t and
    in the stage-2 forces at t + h, its kp, kd in J while not saturated at zₙ, and its time rate ``F_t`` in the
    stages (``+γh F_t`` in stage 1, ``−γh F_t`` in stage 2: ROS2's non-autonomous form). dz, Y, k1 (n,),
    tauv (nv,): scratch; vec (ROS_VECTORS, nv), mat (ROS_MATRICES, nv, nv): work arrays; dyn: the
    dynamics' addresses (:mod:`.treefn`: the bias/mass pass ``bm`` off the ground, ABA).
    """
    n = z.shape[0]
    q = z[:nq]
    v = z[nq:nq + nv]
    H, Dm, Km, A, L = mat[0], mat[1], mat[2], mat[3], mat[4]
    r, fq, kq1, kv1, kq2, kv2, x, y, zero = vec[0], vec[1], vec[2], vec[3], vec[4], vec[5], vec[6], vec[7], vec[8]
    # stage 1 at z_n: τ and the powers (W, W_lim), the bias C + g, M, the passive Jacobian, A = L Lᵀ
    if con is None:   # a None argument prunes the contact code at compile time
        P = arm_forces(damping, friction, v_s, lim, tau_app, nq, nv, z, dz, tauv)
    else:
        P = arm_forces(damping, friction, v_s, lim, tau_app, nq, nv, z[:n - 1], dz, tauv)
    sat, Ft, rr = vec[10], vec[11], vec[12]
    if srv is not None:   # the servo at (t, zₙ): its torques, its saturation flags and time rate for J and the stages
        servo_side(srv, 1.0)
        P += servo_forces_add(mi, mf, damping, friction, v_s, srv, t, q, v, tauv, W, dyn)
        ns = srv[0].shape[0]
        for a in range(ns):
            sat[a] = srv[5][SW_SAT, a]
        servo_time_rate(srv, Ft)
    for a in range(nq + nv, n):
        k1[a] = dz[a]
    k1[nq + nv] = P
    for a in range(nv):
        zero[a] = 0.0
    touching = -1
    if con is None:
        bm_at(dyn[1])(mi, mf, q, v, zero, y, H, mat[5], W)
    else:
        Pc, touching = contact_bias_mass(mi, mf, con, q, v, zero, y, H, mat[5], mat[6], mat[7], fx, cj, W, dyn)
        k1[nq + nv] = P + Pc
        k1[n - 1] = Pc
    for a in range(nv):
        r[a] = tauv[a] - y[a]
    simple = nq == nv   # only 1-DOF joints: tangent coordinates are q itself
    tangent_rate(mi, simple, q, v, fq)
    use_qs = False
    stops_checked = False
    for attempt in range(3):   # again with the stops the stage point met (limit_event), the contacts it touches
        gh = h * arm_implicit_matrix(mi, mf, damping, friction, v_s, lim, q, v, h, Y[:nq], use_qs, W, mat, cpl, red,
                                     touching, srv, sat)
        if gh == 0.0:
            return -math.inf
        if srv is None:
            solve_stage(L, Km, gh, r, stiffness_rate(mi, simple, con, q, fq, vec[9]), kv1, x, cpl, red)
        else:
            for a in range(nv):
                rr[a] = r[a] + gh * Ft[a]
            solve_stage(L, Km, gh, rr, stiffness_rate(mi, simple, con, q, fq, vec[9]), kv1, x, cpl, red)
        tangent_rate(mi, simple, q, kv1, kq1)
        for a in range(nv):
            kq1[a] = fq[a] + gh * kq1[a]
        retract(mi, simple, q, kq1, h, Y[:nq])   # stage 2 at Y = z_n ⊕ h k1
        if not stops_checked and lim.shape[0]:
            stops_checked = True
            s = limit_event(lim, q, v, h, Y[:nq], H)
            if s < h:
                if s > 0.0 and split:
                    return -s           # retake the step as a shorter one (z untouched)
                use_qs = True
                continue
        for a in range(nv):
            Y[nq + a] = v[a] + h * kv1[a]
        for a in range(nq + nv, n):
            Y[a] = z[a] + h * k1[a]
        servo_side(srv, -1.0)   # stage 2 at the step's end
        arm_rhs(mi, mf, damping, friction, v_s, lim, tau_app, nq, nv, Y, dz, tauv, W, cpl, cs, con, fx, t + h, srv, dyn)
        servo_side(srv, 0.0)
        if con is None or attempt == 2:
            break
        ty = contact_stage_jacobian(mi, mf, con, touching, mat[6], mat[8], cj, W)
        if ty <= touching:
            break
        touching = ty           # a touch-down within the step: stage 1 again with J's contact part from Y
    tangent_rate(mi, simple, Y[:nq], Y[nq:nq + nv], fq)
    for a in range(nv):
        fq[a] += C21 * kq1[a]                       # bq of stage 2
        x[a] = dz[nq + a] + C21 * kv1[a]            # bv of stage 2
    mat_vec(H, x, r)                                # M bv
    if srv is not None:
        for a in range(nv):
            r[a] -= gh * Ft[a]
    solve_stage(L, Km, gh, r, stiffness_rate(mi, simple, con, q, fq, vec[9]), kv2, x, cpl, red)
    tangent_rate(mi, simple, q, kv2, kq2)
    for a in range(nv):
        kq2[a] = fq[a] + gh * kq2[a]
    # z_{n+1} = z_n ⊕ h (3/2 k1 + 1/2 k2)
    for a in range(nv):
        x[a] = B1 * kq1[a] + B2 * kq2[a]
        v[a] += h * (B1 * kv1[a] + B2 * kv2[a])
    retract(mi, simple, q, x, h, q)
    for a in range(nq + nv, n):
        z[a] += h * (B1 * k1[a] + B2 * (dz[a] + C21 * k1[a]))
    return h


@njit(**_JIT)
def run_arm_periods(mi, mf, mi_r, mf_r, damping, friction, v_s, lim, B, nq, method, z, dt, t_start, n_full, h_last,
                    kind, P, times, values, BT, Bq, u, Zs, Us, TAUs, Fs, want_f, ulim, con, cpo, Cs, CPs, t_end, srv,
                    SVs, cpl, ros, dyn):
    """K publication periods of an arm in one call: per period k the scripted command at its
    start ``t_start[k]`` (:func:`command_eval`, kind ``CMD_NONE``: u held as given), clamped to the
    effort limits ulim (nu,) (inf: none) as the Simulator clamps it (np.clip), ``τ_app = B u_clamped``
    (B with no rows: ``τ_app = u``, the per-period path's applied forces as they are),
    :func:`arm_steps` over its step grid ``(n_full[k], h_last[k])``, then the outputs at its end:
    ``Zs[k] = z``, ``Us[k] = u`` (as commanded), ``TAUs[k] = τ_app`` and, with want_f, the joint
    wrenches ``Fs[k]`` (:func:`joint_wrenches` under ``τ = B u − D v − F tanh(v/v_s) + τ_lim``,
    :func:`arm_forces`, and on a ground the contacts' forces on their own links,
    :func:`.contact.point_body_forces`) -- the numbers the Simulator's per-period path computes with
    the same functions. con: None, or the ground contacts (:func:`arm_rhs`; z then ends with W_c), with
    cpo = ``(body_of, link_of)`` (each point's body of the full tree and its link's row in Cs) and the
    links' contact wrenches ``Cs[k]`` (nl, 6) (:func:`.contact.link_wrenches`; Cs with no links: not
    computed) and every point's outputs ``CPs[k]`` (np, NP) (:func:`.contact.contact_points`, which both come
    from; CPs with no points: not kept). srv: None, or a joint servo (:mod:`.servo`) held over the K periods (its setpoint program
    fixed), evaluated at each stage; with SVs (K, ns, 6) (SVs with no rows: not computed) its torques at each
    period's end ``t_end[k]`` join ``TAUs[k]`` (its joints take no B u) and the wrenches' τ, with its desired
    values in ``SVs[k]`` (:func:`.servo.servo_state`). cpl: None, or the mimic coupling (:func:`arm_rhs`; the block path declines such trees, the
    per-period path runs them here); ros, dyn: see :func:`arm_steps`.

    z: ``[q, v, W(, W_lim)(, W_c)]`` in place; u (n,) the command held before period 0. Returns
    ``(k, code, step)``: code 0 after all K periods; 1: the command of period k is non-finite (not
    applied: u and z are those of the end of period k − 1); 2: the state became non-finite in
    step ``step`` of period k (z as the failed integration left it; ``Zs[k − 1]`` is the end of period
    k − 1). The block path redoes period k on the per-period path, which raises with the diagnosis.
    """
    K = t_start.shape[0]
    nv = damping.shape[0]
    n = z.shape[0]
    nw = n - 1 if con is not None else n   # z without W_c: what arm_forces reads
    nu = u.shape[0]
    g = np.zeros(nv)
    zeros = np.zeros(nv)
    un = np.empty(nu)
    ua = np.empty(nu)
    tau_app = np.empty(nv)
    dz = np.empty(n)
    tauv = np.empty(nv)
    zf = np.zeros((mi.shape[0], 6))
    Wr = workspace(mi_r.shape[0])
    for k in range(K):
        if kind != CMD_NONE:
            if kind == CMD_GRAVITY_SINE or (kind == CMD_PD_HOLD and P[3, 0] != 0.0):
                rnea_into(mi_r, mf_r, z[:nq], zeros, zeros, g)   # gravity torques RNEA(q, 0, 0) (CompiledModel.rnea)
            command_eval(kind, P, times, values, BT, Bq, z[:nq], z[nq:nq + nv], g, t_start[k], un)
            for i in range(nu):
                if not math.isfinite(un[i]):
                    return k, 1, -1
            for i in range(nu):
                u[i] = un[i]
        for i in range(nu):
            ua[i] = (ulim[i] if u[i] > 0.0 else -ulim[i]) if abs(u[i]) > ulim[i] else u[i]
        if B.shape[0] == 0:
            for r in range(nv):
                tau_app[r] = ua[r]
        else:
            for r in range(nv):
                acc = 0.0
                for i in range(nu):
                    acc += B[r, i] * ua[i]
                tau_app[r] = acc
        step = arm_steps(mi_r, mf_r, damping, friction, v_s, lim, tau_app, nq, method, z, dt, n_full[k], h_last[k],
                         cpl, con, t_start[k], srv, ros, dyn)
        if step >= 0:
            return k, 2, step
        for a in range(n):
            Zs[k, a] = z[a]
        for i in range(nu):
            Us[k, i] = u[i]
        for r in range(nv):
            TAUs[k, r] = tau_app[r]
        if srv is not None and SVs.shape[1] > 0:   # the servo's torques at the period's end: its joints' effort
            servo_state(mi_r, mf_r, damping, friction, v_s, srv, t_end[k], z[:nq], z[nq:nq + nv], Wr, SVs[k], dyn)
            for j in range(srv[0].shape[0]):
                TAUs[k, srv[0][j, 0]] += SVs[k, j, 4]
        if con is not None and (Cs.shape[1] > 0 or CPs.shape[1] > 0):   # the contacts at the period's end
            Pc = contact_points(con, mi_r, mf_r, z[:nq], z[nq:nq + nv])
            if Cs.shape[1] > 0:   # per link
                link_wrenches(con[0], Pc, cpo[1], Cs[k])
            if CPs.shape[1] > 0:   # per point (the block path's markers)
                for p in range(Pc.shape[0]):
                    for c in range(Pc.shape[1]):
                        CPs[k, p, c] = Pc[p, c]
            if want_f:   # per body
                point_body_forces(mi, mf, z[:nq], Pc, cpo[0], zf)
        if want_f:
            arm_forces(damping, friction, v_s, lim, tau_app, nq, nv, z[:nw], dz, tauv)
            if srv is not None and SVs.shape[1] > 0:
                for j in range(srv[0].shape[0]):
                    tauv[srv[0][j, 0]] += SVs[k, j, 4]
            _, f = joint_wrenches(mi, mf, z[:nq], z[nq:nq + nv], tauv, zf, con is not None)
            for b in range(f.shape[0]):
                for c in range(6):
                    Fs[k, b, c] = f[b, c]
    return K, 0, -1
