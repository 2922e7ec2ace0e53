"""Compliant point contact of a tree's bodies with a ground plane, compiled (numba): the law, its
external body forces for the forward dynamics, and its per-point outputs (one implementation,
used by :mod:`robodyn_ros.systems.contact` and the arm's compiled loops, :mod:`.arm`).

**The law**, per contact point, with ``n`` the plane's unit normal and the plane ``{x : n·x = h}``::

    δ   = h − n·x_c                                   penetration of the contact point x_c      (C1)
    δ̇   = −n·u                                        u: velocity of the body's material point at x_c
    f_n = max(0, k δ (1 + d δ̇))       (δ > 0; else no force)                                    (C2)
    u_t = u − (n·u) n,   F_t = −μ f_n tanh(|u_t| / v_s) u_t / |u_t|                              (C3)
    F   = f_n n + F_t                 acting on the body at x_c (world coordinates)

A point is a body-fixed point (x_c itself) or a sphere of centre c and radius r, whose contact point
is its lowest point along the normal, ``x_c = c − r n``. (C2) is Hunt & Crossley's damping (J. Appl.
Mech. 42, 1975) on a linear spring, as Drake's point contact writes it: the damping force
``k d δ δ̇`` vanishes with δ, so the force is continuous at touch-down (zero at δ = 0 whatever the
speed), and the clamp at 0 keeps it from pulling while the body leaves. k (N/m) is the stiffness per
point, d (s/m) the dissipation. Without gravity a point of mass m that arrives at speed v_in leaves at
``v_out`` with ``v_out − ln(1 + d v_out)/d = v_in − ln(1 + d v_in)/d`` (v = δ̇, so v_out < 0;
``m v dv/dδ = −k δ (1 + d v)`` separates), whatever k and m: the coefficient of restitution of the law.
(C3) is Coulomb friction regularised as the joints' (:mod:`.passive`): below the slip speed
``|u_t| ~ v_s`` it is a viscous damper of slope ``μ f_n / v_s``, so a body held by friction creeps at
``v_s artanh(F_t / (μ f_n))`` instead of sticking; above it, ``|F_t| → μ f_n``.

Power of the contact forces on the tree: ``P = Σ F·u`` (≤ 0 for the damping and the friction; the
spring's part is the rate of its stored energy ``−d/dt (½ k δ²)``): the simulator integrates it as
the contact work.

**Jacobian** (:func:`contact_jacobian_add`, for a linearly implicit step): with ``J_i`` (3 × nv) the
world velocity Jacobian of contact point i (``u_i = J_i v``), the contacts' generalised force is
``τ_c = Σ J_iᵀ F_i`` and its stiff part is ``−∂τ_c/∂v ≈ D_c = Σ J_iᵀ D_i J_i``,
``−∂τ_c/∂q ≈ K_c = Σ J_iᵀ K_i J_i`` (q-increments in velocity coordinates) with the 3 × 3,
symmetric positive semi-definite::

    K_i = k (1 + d δ̇) n nᵀ                                         (normal spring, f_n > 0)      (C4)
    D_i = k d δ n nᵀ + μ f_n [ tanh(s/v_s)/s (P − t tᵀ) + sech²(s/v_s)/v_s t tᵀ ]                 (C5)

(s = |u_t|, t = u_t/s, P = 1 − n nᵀ; ``1/v_s P`` as s → 0): the exact derivatives of (C2) and of
(C3) at fixed f_n. Left out, as a W-method allows: the friction's dependence on f_n (a
non-symmetric coupling), the rotation of J_i with q (the geometric stiffness ``∂J_iᵀ/∂q F_i``).

**Packed contacts** ``con = (gp, cg, cgf, cf)`` (:func:`robodyn_ros.systems.contact.pack_contacts`):

* ``gp`` float64 (NG,): the ground: normal ``GN`` (3, unit), height ``GH``, stiffness ``GK`` (N/m),
  dissipation ``GD`` (s/m), friction coefficient ``GMU``, slip speed ``GVS`` (m/s);
* ``cg`` int64 (ng, 3): per group of points on one body: the body (of the tree the kernels get:
  the merged one in the arm's loops), the first point, one past the last;
* ``cgf`` float64 (ng, 4): per group a bounding sphere in body coordinates (centre, radius): a group
  whose sphere is above the plane is skipped (no point of it can touch);
* ``cf`` float64 (nc, 4): per point its position in its body's coordinates and its radius (0: a point).
"""
from __future__ import annotations

import math

import numpy as np

from ..model import FREE, PRISMATIC, REVOLUTE, SPHERICAL
from .jit import njit
from .tree import _JIT, _LEAF, AX, AXK, E0_, E_, JTYPE, PARENT, R0_, R_, V_, VIDX, transforms, workspace, world_kinematics_ws

#: columns of gp
GN, GH, GK, GD, GMU, GVS, NG = 0, 3, 4, 5, 6, 7, 8
#: columns of a point's outputs (contact_points): contact point x_c (3), force F (3) on the body,
#: world coordinates; penetration δ (m, > 0 in contact), slip speed |u_t| (m/s), power F·u (W), active (0/1)
PX, PF, PDEPTH, PSLIP, PPOWER, PACTIVE, NP = 0, 3, 6, 7, 8, 9, 10


@njit(**_LEAF)
def point_depth(gp, cf, c, b, W):
    """``(x0, x1, x2, δ)``: the contact point x_c of point c (a row of cf) of body b (world coordinates)
    and its penetration (C1), from the body poses in W (``W[b, R0_]``, ``W[b, E0_]``)."""
    n0, n1, n2 = gp[GN], gp[GN + 1], gp[GN + 2]
    p0, p1, p2 = cf[c, 0], cf[c, 1], cf[c, 2]
    # world position of the point (a sphere: its centre): x = r0 + E0ᵀ p
    x0 = W[b, R0_] + W[b, E0_] * p0 + W[b, E0_ + 3] * p1 + W[b, E0_ + 6] * p2
    x1 = W[b, R0_ + 1] + W[b, E0_ + 1] * p0 + W[b, E0_ + 4] * p1 + W[b, E0_ + 7] * p2
    x2 = W[b, R0_ + 2] + W[b, E0_ + 2] * p0 + W[b, E0_ + 5] * p1 + W[b, E0_ + 8] * p2
    r = cf[c, 3]
    if r > 0.0:                    # the sphere's lowest point along the normal
        x0 -= r * n0
        x1 -= r * n1
        x2 -= r * n2
    return x0, x1, x2, gp[GH] - (n0 * x0 + n1 * x1 + n2 * x2)          # (C1)


@njit(**_LEAF)
def touching_points(con, W):
    """How many points penetrate the plane (δ > 0) at the configuration whose body poses are in W
    (``W[:, R0_]``, ``W[:, E0_]``: :func:`~robodyn_ros.kernels.tree.world_kinematics_ws` done): the
    count :func:`contact_jacobian_add` returns, from the poses alone."""
    gp, cg, cgf, cf = con
    n = 0
    for g in range(cg.shape[0]):
        if _group_clear(gp, cg, cgf, g, W):
            continue
        b = cg[g, 0]
        for c in range(cg[g, 1], cg[g, 2]):
            if point_depth(gp, cf, c, b, W)[3] > 0.0:
                n += 1
    return n


@njit(**_LEAF)
def point_force(gp, cf, c, b, W):
    """Force of the ground on point c (a row of cf) of body b, from W (transforms and
    :func:`~robodyn_ros.kernels.tree.world_kinematics_ws` done).

    Returns ``(active, x0, x1, x2, F0, F1, F2, δ, |u_t|, F·u)``: whether it penetrates, the contact
    point x_c and the force F (world coordinates, law (C1)-(C3)), the penetration, slip speed and
    power. The body's origin is ``r0 = W[b, R0_]``, its axes ``E0 = W[b, E0_]`` (world -> body) and
    its velocity ``[ω; v_O] = W[b, V_]`` in body coordinates.
    """
    n0, n1, n2 = gp[GN], gp[GN + 1], gp[GN + 2]
    x0, x1, x2, depth = point_depth(gp, cf, c, b, W)
    if depth <= 0.0:
        return False, x0, x1, x2, 0.0, 0.0, 0.0, depth, 0.0, 0.0
    u0, u1, u2 = point_velocity(b, W, x0, x1, x2)
    un = n0 * u0 + n1 * u1 + n2 * u2
    fn = gp[GK] * depth * (1.0 + gp[GD] * (-un))              # (C2)
    if fn < 0.0:
        fn = 0.0
    t0, t1, t2 = u0 - un * n0, u1 - un * n1, u2 - un * n2     # (C3)
    slip = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
    vs = gp[GVS]
    if slip > 1e-8 * vs:
        cft = gp[GMU] * fn * math.tanh(slip / vs) / slip
    else:                          # tanh(s/v_s)/s -> 1/v_s
        cft = gp[GMU] * fn / vs
    F0 = fn * n0 - cft * t0
    F1 = fn * n1 - cft * t1
    F2 = fn * n2 - cft * t2
    return True, x0, x1, x2, F0, F1, F2, depth, slip, F0 * u0 + F1 * u1 + F2 * u2


@njit(**_LEAF)
def _group_clear(gp, cg, cgf, g, W):
    """True when group g's bounding sphere is wholly above the plane (none of its points can touch)."""
    b = cg[g, 0]
    c0, c1, c2 = cgf[g, 0], cgf[g, 1], cgf[g, 2]
    x0 = W[b, R0_] + W[b, E0_] * c0 + W[b, E0_ + 3] * c1 + W[b, E0_ + 6] * c2
    x1 = W[b, R0_ + 1] + W[b, E0_ + 1] * c0 + W[b, E0_ + 4] * c1 + W[b, E0_ + 7] * c2
    x2 = W[b, R0_ + 2] + W[b, E0_ + 2] * c0 + W[b, E0_ + 5] * c1 + W[b, E0_ + 8] * c2
    return gp[GN] * x0 + gp[GN + 1] * x1 + gp[GN + 2] * x2 - gp[GH] > cgf[g, 3]


@njit(**_LEAF)
def ground_fext_ws(con, W, fext):
    """External body forces of the ground into fext (nb, 6), ``[n; f]`` in body coordinates about the
    body origin (as :func:`~robodyn_ros.kernels.tree.aba_ws` takes them; rows of bodies without a
    touching point are zeroed); returns their power ``Σ F·u`` (W). W: transforms and
    :func:`~robodyn_ros.kernels.tree.world_kinematics_ws` done."""
    gp, cg, cgf, cf = con
    for i in range(fext.shape[0]):
        for a in range(6):
            fext[i, a] = 0.0
    P = 0.0
    for g in range(cg.shape[0]):
        if _group_clear(gp, cg, cgf, g, W):
            continue
        b = cg[g, 0]
        for c in range(cg[g, 1], cg[g, 2]):
            on, x0, x1, x2, F0, F1, F2, _, _, pw = point_force(gp, cf, c, b, W)
            if not on:
                continue
            P += pw
            # f_b = E0 F; n_b = s × f_b with s = E0 (x − r0) the point in body coordinates
            s0, s1, s2 = body_point(b, W, x0, x1, x2)
            f0 = W[b, E0_] * F0 + W[b, E0_ + 1] * F1 + W[b, E0_ + 2] * F2
            f1 = W[b, E0_ + 3] * F0 + W[b, E0_ + 4] * F1 + W[b, E0_ + 5] * F2
            f2 = W[b, E0_ + 6] * F0 + W[b, E0_ + 7] * F1 + W[b, E0_ + 8] * F2
            fext[b, 0] += s1 * f2 - s2 * f1
            fext[b, 1] += s2 * f0 - s0 * f2
            fext[b, 2] += s0 * f1 - s1 * f0
            fext[b, 3] += f0
            fext[b, 4] += f1
            fext[b, 5] += f2
    return P


@njit(**_LEAF)
def contact_points_ws(con, W, out):
    """Every point's outputs into out (nc, NP) (columns ``PX, PF, PDEPTH, PSLIP, PPOWER, PACTIVE``):
    the contact point and the force on the body (world), the penetration (signed: < 0 above the
    plane), slip speed and power; points of a group clear of the plane get their depth only as
    ``−inf`` and zeros. W as for :func:`ground_fext_ws`."""
    gp, cg, cgf, cf = con
    for g in range(cg.shape[0]):
        b = cg[g, 0]
        clear = _group_clear(gp, cg, cgf, g, W)
        for c in range(cg[g, 1], cg[g, 2]):
            for a in range(NP):
                out[c, a] = 0.0
            if clear:
                out[c, PDEPTH] = -math.inf
                continue
            on, x0, x1, x2, F0, F1, F2, depth, slip, pw = point_force(gp, cf, c, b, W)
            out[c, PX], out[c, PX + 1], out[c, PX + 2] = x0, x1, x2
            out[c, PDEPTH] = depth
            if on:
                out[c, PF], out[c, PF + 1], out[c, PF + 2] = F0, F1, F2
                out[c, PSLIP] = slip
                out[c, PPOWER] = pw
                out[c, PACTIVE] = 1.0


@njit(**_JIT)
def contact_points(con, mi, mf, q, v):
    """The points' outputs (nc, NP) at state (q, v) of the tree (mi, mf) (:func:`contact_points_ws`)."""
    W = workspace(mi.shape[0])
    transforms(mi, mf, q, W)
    world_kinematics_ws(mi, mf, v, W)
    out = np.empty((con[3].shape[0], NP))
    contact_points_ws(con, W, out)
    return out


@njit(**_JIT)
def ground_fext(con, mi, mf, q, v):
    """``(fext (nb, 6), power)``: the ground's body forces at state (q, v) (:func:`ground_fext_ws`)."""
    W = workspace(mi.shape[0])
    transforms(mi, mf, q, W)
    world_kinematics_ws(mi, mf, v, W)
    fext = np.empty((mi.shape[0], 6))
    P = ground_fext_ws(con, W, fext)
    return fext, P


@njit(**_LEAF)
def point_jacobian(mi, mf, W, b, x0, x1, x2, J, cols):
    """World velocity Jacobian (3, nv) of the point x of body b into J (its nonzero columns only: the
    velocity coordinates of b's joint and its ancestors, listed in cols; returns their count). W:
    transforms and world kinematics done. A joint j's motion column ``[ω; v_O]`` (body j coordinates)
    moves x at ``E0_jᵀ v_O + (E0_jᵀ ω) × (x − r0_j)``."""
    nc = 0
    j = b
    while j >= 0:
        jt = mi[j, JTYPE]
        s = mi[j, VIDX]
        nd = 6 if jt == FREE else 3 if jt == SPHERICAL else 1 if (jt == REVOLUTE or jt == PRISMATIC) else 0
        r0, r1, r2 = x0 - W[j, R0_], x1 - W[j, R0_ + 1], x2 - W[j, R0_ + 2]
        for k in range(nd):
            w0 = w1 = w2 = u0 = u1 = u2 = 0.0   # the motion column in body j coordinates
            if jt == FREE or jt == SPHERICAL:
                if k == 0:
                    w0 = 1.0
                elif k == 1:
                    w1 = 1.0
                elif k == 2:
                    w2 = 1.0
                elif k == 3:
                    u0 = 1.0
                elif k == 4:
                    u1 = 1.0
                else:
                    u2 = 1.0
            elif mi[j, AXK] == 1:
                if jt == REVOLUTE:
                    w2 = 1.0
                else:
                    u2 = 1.0
            elif jt == REVOLUTE:
                w0, w1, w2 = mf[j, AX], mf[j, AX + 1], mf[j, AX + 2]
            else:
                u0, u1, u2 = mf[j, AX], mf[j, AX + 1], mf[j, AX + 2]
            # world: ω_w = E0ᵀ ω, v_w = E0ᵀ v_O
            a0 = W[j, E0_] * w0 + W[j, E0_ + 3] * w1 + W[j, E0_ + 6] * w2
            a1 = W[j, E0_ + 1] * w0 + W[j, E0_ + 4] * w1 + W[j, E0_ + 7] * w2
            a2 = W[j, E0_ + 2] * w0 + W[j, E0_ + 5] * w1 + W[j, E0_ + 8] * w2
            c = s + k
            J[0, c] = W[j, E0_] * u0 + W[j, E0_ + 3] * u1 + W[j, E0_ + 6] * u2 + (a1 * r2 - a2 * r1)
            J[1, c] = W[j, E0_ + 1] * u0 + W[j, E0_ + 4] * u1 + W[j, E0_ + 7] * u2 + (a2 * r0 - a0 * r2)
            J[2, c] = W[j, E0_ + 2] * u0 + W[j, E0_ + 5] * u1 + W[j, E0_ + 8] * u2 + (a0 * r1 - a1 * r0)
            cols[nc] = c
            nc += 1
        j = mi[j, PARENT]
    return nc


@njit(**_JIT)
def contact_jacobian_add(con, mi, mf, W, Dm, Km, J, cols):
    """``Dm += Σ J_iᵀ D_i J_i``, ``Km += Σ J_iᵀ K_i J_i`` over the touching points ((C4), (C5); Dm, Km (nv,
    nv) in velocity coordinates), from W (transforms and world kinematics done, as for
    :func:`ground_fext_ws`); J (3, nv) and cols (nv,) int64 scratch. Returns the number of touching points."""
    gp, cg, cgf, cf = con
    n0, n1, n2 = gp[GN], gp[GN + 1], gp[GN + 2]
    k, dis, mu, vs = gp[GK], gp[GD], gp[GMU], gp[GVS]
    A = np.empty((3, 3))
    B = np.empty((3, 3))
    touching = 0
    for g in range(cg.shape[0]):
        if _group_clear(gp, cg, cgf, g, W):
            continue
        b = cg[g, 0]
        for c in range(cg[g, 1], cg[g, 2]):
            on, x0, x1, x2, F0, F1, F2, depth, slip, _ = point_force(gp, cf, c, b, W)
            if not on:
                continue
            touching += 1
            fn = F0 * n0 + F1 * n1 + F2 * n2
            nc = point_jacobian(mi, mf, W, b, x0, x1, x2, J, cols)
            # u = J v: its normal speed gives 1 + d δ̇ = fn / (k δ)
            kn = fn / depth if fn > 0.0 else 0.0          # k (1 + d δ̇)_+
            dn = k * dis * depth if fn > 0.0 else 0.0
            nv3 = (n0, n1, n2)
            for a in range(3):
                for e in range(3):
                    A[a, e] = kn * nv3[a] * nv3[e]
                    B[a, e] = dn * nv3[a] * nv3[e]
            if fn > 0.0 and mu > 0.0:
                t0, t1, t2 = _slip(gp, cf, c, b, W, x0, x1, x2)   # u_t, as point_force forms it
                if slip > 1e-8 * vs:
                    a_ = mu * fn * math.tanh(slip / vs) / slip
                    ch = math.cosh(slip / vs)
                    b_ = mu * fn / (vs * ch * ch)
                    t0, t1, t2 = t0 / slip, t1 / slip, t2 / slip
                else:
                    a_ = b_ = mu * fn / vs
                    t0 = t1 = t2 = 0.0
                tv = (t0, t1, t2)
                for a in range(3):
                    for e in range(3):
                        P = (1.0 if a == e else 0.0) - nv3[a] * nv3[e]
                        B[a, e] += a_ * (P - tv[a] * tv[e]) + b_ * tv[a] * tv[e]
            for m in range(nc):           # Jᵀ A J and Jᵀ B J on the nonzero columns
                ci = cols[m]
                y0 = A[0, 0] * J[0, ci] + A[0, 1] * J[1, ci] + A[0, 2] * J[2, ci]
                y1 = A[1, 0] * J[0, ci] + A[1, 1] * J[1, ci] + A[1, 2] * J[2, ci]
                y2 = A[2, 0] * J[0, ci] + A[2, 1] * J[1, ci] + A[2, 2] * J[2, ci]
                z0 = B[0, 0] * J[0, ci] + B[0, 1] * J[1, ci] + B[0, 2] * J[2, ci]
                z1 = B[1, 0] * J[0, ci] + B[1, 1] * J[1, ci] + B[1, 2] * J[2, ci]
                z2 = B[2, 0] * J[0, ci] + B[2, 1] * J[1, ci] + B[2, 2] * J[2, ci]
                for l in range(nc):
                    cj = cols[l]
                    Km[cj, ci] += J[0, cj] * y0 + J[1, cj] * y1 + J[2, cj] * y2
                    Dm[cj, ci] += J[0, cj] * z0 + J[1, cj] * z1 + J[2, cj] * z2
    return touching


@njit(**_LEAF)
def body_point(b, W, x0, x1, x2):
    """The world point x in body b's coordinates, s = E0 (x − r0) (3 floats)."""
    d0, d1, d2 = x0 - W[b, R0_], x1 - W[b, R0_ + 1], x2 - W[b, R0_ + 2]
    return (W[b, E0_] * d0 + W[b, E0_ + 1] * d1 + W[b, E0_ + 2] * d2,
            W[b, E0_ + 3] * d0 + W[b, E0_ + 4] * d1 + W[b, E0_ + 5] * d2,
            W[b, E0_ + 6] * d0 + W[b, E0_ + 7] * d1 + W[b, E0_ + 8] * d2)


@njit(**_LEAF)
def point_velocity(b, W, x0, x1, x2):
    """The velocity (world, 3 floats) of the material point of body b at world position x: the point in
    body coordinates, s = E0 (x − r0), its velocity v_O + ω × s (body), then world axes."""
    s0, s1, s2 = body_point(b, W, x0, x1, x2)
    w0, w1, w2 = W[b, V_], W[b, V_ + 1], W[b, V_ + 2]
    b0 = W[b, V_ + 3] + (w1 * s2 - w2 * s1)
    b1 = W[b, V_ + 4] + (w2 * s0 - w0 * s2)
    b2 = W[b, V_ + 5] + (w0 * s1 - w1 * s0)
    u0 = W[b, E0_] * b0 + W[b, E0_ + 3] * b1 + W[b, E0_ + 6] * b2
    u1 = W[b, E0_ + 1] * b0 + W[b, E0_ + 4] * b1 + W[b, E0_ + 7] * b2
    u2 = W[b, E0_ + 2] * b0 + W[b, E0_ + 5] * b1 + W[b, E0_ + 8] * b2
    return u0, u1, u2


@njit(**_LEAF)
def _slip(gp, cf, c, b, W, x0, x1, x2):
    """The tangential velocity u_t (world, 3 floats) of point c of body b at its contact point x."""
    n0, n1, n2 = gp[GN], gp[GN + 1], gp[GN + 2]
    u0, u1, u2 = point_velocity(b, W, x0, x1, x2)
    un = n0 * u0 + n1 * u1 + n2 * u2
    return u0 - un * n0, u1 - un * n1, u2 - un * n2


@njit(**_JIT)
def contact_jacobian(con, mi, mf, q, v):
    """``(D_c, K_c)`` (nv, nv) of the contacts at state (q, v) (:func:`contact_jacobian_add` on zeros)."""
    nv = v.shape[0]
    W = workspace(mi.shape[0])
    transforms(mi, mf, q, W)
    world_kinematics_ws(mi, mf, v, W)
    Dm = np.zeros((nv, nv))
    Km = np.zeros((nv, nv))
    contact_jacobian_add(con, mi, mf, W, Dm, Km, np.zeros((3, nv)), np.zeros(nv, dtype=np.int64))
    return Dm, Km


@njit(**_JIT)
def link_wrenches(gp, P, link_of, out):
    """Per link ``[moment; force]`` into out (nl, 6), world axes, from the points' outputs P (nc, NP) (link_of
    (nc,): each point's link): the resultant of its touching points' forces and the moment about their
    centre of pressure ``Σ f_n x / Σ f_n`` (f_n = F·n; their mean where every f_n is 0); zeros where none touches."""
    nl = out.shape[0]
    n0, n1, n2 = gp[GN], gp[GN + 1], gp[GN + 2]
    acc = np.zeros((nl, 8))     # Σ f_n x (3), Σ f_n, Σ x (3), count
    for i in range(nl):
        for a in range(6):
            out[i, a] = 0.0
    for c in range(P.shape[0]):
        if P[c, PACTIVE] <= 0.0:
            continue
        j = link_of[c]
        fn = P[c, PF] * n0 + P[c, PF + 1] * n1 + P[c, PF + 2] * n2
        for a in range(3):
            acc[j, a] += fn * P[c, PX + a]
            acc[j, 4 + a] += P[c, PX + a]
            out[j, 3 + a] += P[c, PF + a]
        acc[j, 3] += fn
        acc[j, 7] += 1.0
    for c in range(P.shape[0]):
        if P[c, PACTIVE] <= 0.0:
            continue
        j = link_of[c]
        if acc[j, 3] > 0.0:
            p0, p1, p2 = acc[j, 0] / acc[j, 3], acc[j, 1] / acc[j, 3], acc[j, 2] / acc[j, 3]
        else:
            p0, p1, p2 = acc[j, 4] / acc[j, 7], acc[j, 5] / acc[j, 7], acc[j, 6] / acc[j, 7]
        r0, r1, r2 = P[c, PX] - p0, P[c, PX + 1] - p1, P[c, PX + 2] - p2
        F0, F1, F2 = P[c, PF], P[c, PF + 1], P[c, PF + 2]
        out[j, 0] += r1 * F2 - r2 * F1
        out[j, 1] += r2 * F0 - r0 * F2
        out[j, 2] += r0 * F1 - r1 * F0


@njit(**_JIT)
def point_body_forces(mi, mf, q, P, body_of, fext):
    """The points' forces (outputs P, world) on the bodies they belong to (body_of (nc,): bodies of the
    tree (mi, mf), e.g. the full tree whose welded links are bodies of their own) into fext (nb, 6),
    ``[n; f]`` in body coordinates about the body origin, zeroed first."""
    W = workspace(mi.shape[0])
    transforms(mi, mf, q, W)
    _poses_ws(mi, W)
    for i in range(fext.shape[0]):
        for a in range(6):
            fext[i, a] = 0.0
    for c in range(P.shape[0]):
        if P[c, PACTIVE] <= 0.0:
            continue
        b = body_of[c]
        d0, d1, d2 = P[c, PX] - W[b, R0_], P[c, PX + 1] - W[b, R0_ + 1], P[c, PX + 2] - W[b, R0_ + 2]
        s0 = W[b, E0_] * d0 + W[b, E0_ + 1] * d1 + W[b, E0_ + 2] * d2
        s1 = W[b, E0_ + 3] * d0 + W[b, E0_ + 4] * d1 + W[b, E0_ + 5] * d2
        s2 = W[b, E0_ + 6] * d0 + W[b, E0_ + 7] * d1 + W[b, E0_ + 8] * d2
        F0, F1, F2 = P[c, PF], P[c, PF + 1], P[c, PF + 2]
        f0 = W[b, E0_] * F0 + W[b, E0_ + 1] * F1 + W[b, E0_ + 2] * F2
        f1 = W[b, E0_ + 3] * F0 + W[b, E0_ + 4] * F1 + W[b, E0_ + 5] * F2
        f2 = W[b, E0_ + 6] * F0 + W[b, E0_ + 7] * F1 + W[b, E0_ + 8] * F2
        fext[b, 0] += s1 * f2 - s2 * f1
        fext[b, 1] += s2 * f0 - s0 * f2
        fext[b, 2] += s0 * f1 - s1 * f0
        fext[b, 3] += f0
        fext[b, 4] += f1
        fext[b, 5] += f2


@njit(**_LEAF)
def _poses_ws(mi, W):
    """Root-to-body transforms ``W[:, E0_]``, ``W[:, R0_]`` from the Xup in W (the pose half of
    :func:`~robodyn_ros.kernels.tree.world_kinematics_ws`)."""
    for i in range(mi.shape[0]):
        p = mi[i, PARENT]
        if p < 0:
            for a in range(9):
                W[i, E0_ + a] = W[i, E_ + a]
            for a in range(3):
                W[i, R0_ + a] = W[i, R_ + a]
        else:
            r0, r1, r2 = W[i, R_], W[i, R_ + 1], W[i, R_ + 2]
            for a in range(3):
                W[i, R0_ + a] = W[p, R0_ + a] + W[p, E0_ + a] * r0 + W[p, E0_ + 3 + a] * r1 + W[p, E0_ + 6 + a] * r2
                for b in range(3):
                    W[i, E0_ + 3 * a + b] = (W[i, E_ + 3 * a] * W[p, E0_ + b] + W[i, E_ + 3 * a + 1] * W[p, E0_ + 3 + b]
                                             + W[i, E_ + 3 * a + 2] * W[p, E0_ + 6 + b])
