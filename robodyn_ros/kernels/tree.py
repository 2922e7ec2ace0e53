"""numba-compiled rigid-body kernels on packed model arrays (see :mod:`robodyn_ros.kernels`).

The algorithms are those of :mod:`robodyn_ros.dynamics` (Featherstone 2008, book notation
``Xup, S, vJ, c, IA, pA, U, d, u``), rewritten for speed without changing what they compute:

* a Plücker transform ``X = [E 0; -E r× E]`` is stored as ``(E (3, 3), r (3,))`` (book §2.8),
  never as a 6x6 matrix; ``X m``, ``Xᵀ f`` and ``Xᵀ I X`` are written out on 3-vectors
  (:func:`xmot`, :func:`xforce_T_add`, :func:`xinertia_T_add`), about a quarter of the flops
  of the 6x6 products;
* a 1-DOF joint's motion subspace is ``S = [k; 0]`` (revolute) or ``[0; k]`` (prismatic) in its
  own body frame, so ``U = IA S``, ``d = Sᵀ U`` and ``Sᵀ f`` are 3-term dot products, and a
  revolute ``XJ(q)`` is Rodrigues' formula folded into ``Xtree`` (book Table 4.1);
* a FREE joint (6 DOF, ``S = 1``) solves its 6x6 articulated inertia by Cholesky;
* a SPHERICAL joint (3 DOF, ``S = [1; 0]``, q a unit quaternion (x, y, z, w), v the child's
  angular velocity relative to the parent in child coordinates) keeps ``U = IA S`` (6x3) and
  ``D⁻¹`` (3x3, explicit inverse of the symmetric positive definite ``Sᵀ IA S``) per body;
* all per-body work quantities live in one work array ``W`` (:func:`workspace`), addressed by
  (row = body, named column offset) — no per-body array views, which numba would have to
  reference-count — and the fused integrators (:func:`robodyn_ros.kernels.arm.integrate_arm`)
  allocate once per call and then run whole stretches of fixed steps without returning to Python.

Packed model (built by :func:`robodyn_ros.kernels.pack_model`):

* ``mi`` int64 (nb, 5): columns ``PARENT`` (-1 = root), ``JTYPE`` (model codes), ``QIDX``, ``VIDX``,
  ``AXK`` (1 when a 1-DOF joint's axis is exactly +z, as in every DH joint: the cheaper forms
  ``Rz(q)``, ``U = IA[:, 2]``, ``Sᵀ f = f_z`` are used; 0 otherwise);
* ``mf`` float64 (nb + 1, NF): per body ``AX`` axis (3), ``ET`` Xtree's E (9, row major),
  ``RT`` Xtree's r (3), ``MASS``, ``HV`` = m c (3), ``IB`` rotational inertia about the body
  origin (9, row major), ``ARM`` the joint's armature (rotor inertia reflected to the joint, kg·m² or
  kg, on each of its velocity coordinates: ``M + diag(a)``, MuJoCo's and Pinocchio's ``armature``); the extra last row
  holds gravity (3,) in columns ``0:3``.

Work array ``W`` (nb + 1, NW): row i < nb holds body i's ``E_`` (9, Xup's E row major), ``R_``
(3, Xup's r), ``V_`` velocity, ``C_`` = v × vJ, ``P_`` bias force pA (RNEA: the joint wrench f),
``U_`` = IA S, ``UV_`` = u (1 or 6 entries), ``A_`` acceleration, ``IA_`` (36, articulated or
composite inertia, row major), ``D_`` = Sᵀ IA S, ``E0_``/``R0_`` root-to-body transform; the
last row is scratch (``T_``, ``TMP_``, ``L_``, ``S1_``..``S4_``, ``FC_``). Spatial vectors are
``[angular; linear]`` in body coordinates.

Gravity enters as the fictitious base acceleration ``a0 = -[0; g]`` (book §5.3), as in the
reference.
"""
from __future__ import annotations

import math

import numpy as np

from ..model import FIXED, FREE, PRISMATIC, REVOLUTE, SPHERICAL
from .jit import njit

# columns of mi
PARENT, JTYPE, QIDX, VIDX, AXK = 0, 1, 2, 3, 4
# columns of mf
AX, ET, RT, MASS, HV, IB, ARM, NF = 0, 3, 12, 15, 16, 19, 28, 29
# columns of a body row of W
E_, R_, V_, C_, P_, U_, UV_, A_, IA_, D_, E0_, R0_ = 0, 9, 12, 18, 24, 30, 36, 42, 48, 84, 85, 94
# columns of the scratch row of W
T_, TMP_, L_, S1_, S2_, S3_, S4_, FC_ = 0, 36, 45, 81, 87, 93, 99, 105
# spherical joints (body rows): U = IA S (6x3, row major) and D⁻¹ = (Sᵀ IA S)⁻¹ (3x3)
U3_, DI3_ = 141, 159
NW = 168

_JIT = dict(cache=True, nogil=True, error_model='numpy', _nrt=True)
#: options of a kernel that allocates no array: without numba's reference counting (``_nrt=False``), so
#: a call does not count a reference to each array argument up and down again (about 3 ns per array
#: argument per call; docs/speed.md). A kernel that does not say ``_nrt`` takes its caller's setting, so
#: :data:`_JIT` says True: an allocating kernel called from one of these counts its own arrays. numba refuses
#: to compile such a kernel if it allocates. One returning an array (a view of an argument) must only be
#: called from kernels with these options (its callers count no reference either).
_LEAF = dict(_JIT, _nrt=False)


@njit(**_JIT)
def workspace(nb):
    """The work array W (nb + 1, NW) of the algorithms (see the module docstring)."""
    return np.empty((nb + 1, NW))


# ----------------------------------------------------------------------------------------------
# spatial arithmetic on (E, r) transforms and 6-vectors stored in W
# ----------------------------------------------------------------------------------------------
@njit(**_LEAF)
def xmot(W, i, sr, sc, dr, dc):
    """``W[dr, dc:dc+6] = X_i W[sr, sc:sc+6]`` (motion): ``[E w; E (u - r × w)]``; may alias."""
    w0, w1, w2 = W[sr, sc], W[sr, sc + 1], W[sr, sc + 2]
    r0, r1, r2 = W[i, R_], W[i, R_ + 1], W[i, R_ + 2]
    u0 = W[sr, sc + 3] - (r1 * w2 - r2 * w1)
    u1 = W[sr, sc + 4] - (r2 * w0 - r0 * w2)
    u2 = W[sr, sc + 5] - (r0 * w1 - r1 * w0)
    for a in range(3):
        e0, e1, e2 = W[i, E_ + 3 * a], W[i, E_ + 3 * a + 1], W[i, E_ + 3 * a + 2]
        W[dr, dc + a] = e0 * w0 + e1 * w1 + e2 * w2
        W[dr, dc + 3 + a] = e0 * u0 + e1 * u1 + e2 * u2


@njit(**_LEAF)
def xforce_T_add(W, i, sr, sc, dr, dc):
    """``W[dr, dc:dc+6] += X_iᵀ W[sr, sc:sc+6]`` (force, child -> parent): ``[Eᵀ n + r × Eᵀ f; Eᵀ f]``."""
    n0, n1, n2 = W[sr, sc], W[sr, sc + 1], W[sr, sc + 2]
    f0, f1, f2 = W[sr, sc + 3], W[sr, sc + 4], W[sr, sc + 5]
    g0 = W[i, E_] * f0 + W[i, E_ + 3] * f1 + W[i, E_ + 6] * f2
    g1 = W[i, E_ + 1] * f0 + W[i, E_ + 4] * f1 + W[i, E_ + 7] * f2
    g2 = W[i, E_ + 2] * f0 + W[i, E_ + 5] * f1 + W[i, E_ + 8] * f2
    r0, r1, r2 = W[i, R_], W[i, R_ + 1], W[i, R_ + 2]
    W[dr, dc] += W[i, E_] * n0 + W[i, E_ + 3] * n1 + W[i, E_ + 6] * n2 + (r1 * g2 - r2 * g1)
    W[dr, dc + 1] += W[i, E_ + 1] * n0 + W[i, E_ + 4] * n1 + W[i, E_ + 7] * n2 + (r2 * g0 - r0 * g2)
    W[dr, dc + 2] += W[i, E_ + 2] * n0 + W[i, E_ + 5] * n1 + W[i, E_ + 8] * n2 + (r0 * g1 - r1 * g0)
    W[dr, dc + 3] += g0
    W[dr, dc + 4] += g1
    W[dr, dc + 5] += g2


@njit(**_LEAF)
def etxe(e, x):
    """``Eᵀ X E`` for 3x3 matrices given as row-major 9-tuples (returns a 9-tuple)."""
    m0 = x[0] * e[0] + x[1] * e[3] + x[2] * e[6]
    m1 = x[0] * e[1] + x[1] * e[4] + x[2] * e[7]
    m2 = x[0] * e[2] + x[1] * e[5] + x[2] * e[8]
    m3 = x[3] * e[0] + x[4] * e[3] + x[5] * e[6]
    m4 = x[3] * e[1] + x[4] * e[4] + x[5] * e[7]
    m5 = x[3] * e[2] + x[4] * e[5] + x[5] * e[8]
    m6 = x[6] * e[0] + x[7] * e[3] + x[8] * e[6]
    m7 = x[6] * e[1] + x[7] * e[4] + x[8] * e[7]
    m8 = x[6] * e[2] + x[7] * e[5] + x[8] * e[8]
    return (e[0] * m0 + e[3] * m3 + e[6] * m6, e[0] * m1 + e[3] * m4 + e[6] * m7, e[0] * m2 + e[3] * m5 + e[6] * m8,
            e[1] * m0 + e[4] * m3 + e[7] * m6, e[1] * m1 + e[4] * m4 + e[7] * m7, e[1] * m2 + e[4] * m5 + e[7] * m8,
            e[2] * m0 + e[5] * m3 + e[8] * m6, e[2] * m1 + e[5] * m4 + e[8] * m7, e[2] * m2 + e[5] * m5 + e[8] * m8)


@njit(**_LEAF)
def xinertia_T_add(W, i, sr, sc, dr, dc, ur, uc, dinv):
    """``W[dr, dc:dc+36] += X_iᵀ (A - U Uᵀ dinv) X_i`` for a symmetric 6x6 A at ``W[sr, sc:sc+36]``.

    A is row major; ``U = W[ur, uc:uc+6]`` with ``dinv = 1/d`` gives the articulated inertia
    ``Ia = IA - U d⁻¹ Uᵀ`` of a 1-DOF joint without storing it (``dinv = 0``: plain A, U unread).
    With ``X = Rot(E) Trans(r)``: first the blocks of ``Rot(E)ᵀ A Rot(E)``, ``P = Eᵀ A11 E``,
    ``Q = Eᵀ A12 E``, ``R = Eᵀ A22 E``; then, with ``Y = Q r×`` and ``Z = r× R``::

        Trans(r)ᵀ [P Q; Qᵀ R] Trans(r) = [P - Y - Yᵀ - Z r×,  Q + Z;  (Q + Z)ᵀ,  R]

    (``Trans(r) = [1 0; -r× 1]``), all in scalars (no stores between the stages).
    """
    if dinv != 0.0:
        u0, u1, u2 = W[ur, uc], W[ur, uc + 1], W[ur, uc + 2]
        u3, u4, u5 = W[ur, uc + 3], W[ur, uc + 4], W[ur, uc + 5]
    else:
        u0 = u1 = u2 = u3 = u4 = u5 = 0.0
    a00 = W[sr, sc] - u0 * u0 * dinv
    a01 = W[sr, sc + 1] - u0 * u1 * dinv
    a02 = W[sr, sc + 2] - u0 * u2 * dinv
    a11 = W[sr, sc + 7] - u1 * u1 * dinv
    a12 = W[sr, sc + 8] - u1 * u2 * dinv
    a22 = W[sr, sc + 14] - u2 * u2 * dinv
    b00 = W[sr, sc + 3] - u0 * u3 * dinv
    b01 = W[sr, sc + 4] - u0 * u4 * dinv
    b02 = W[sr, sc + 5] - u0 * u5 * dinv
    b10 = W[sr, sc + 9] - u1 * u3 * dinv
    b11 = W[sr, sc + 10] - u1 * u4 * dinv
    b12 = W[sr, sc + 11] - u1 * u5 * dinv
    b20 = W[sr, sc + 15] - u2 * u3 * dinv
    b21 = W[sr, sc + 16] - u2 * u4 * dinv
    b22 = W[sr, sc + 17] - u2 * u5 * dinv
    c00 = W[sr, sc + 21] - u3 * u3 * dinv
    c01 = W[sr, sc + 22] - u3 * u4 * dinv
    c02 = W[sr, sc + 23] - u3 * u5 * dinv
    c11 = W[sr, sc + 28] - u4 * u4 * dinv
    c12 = W[sr, sc + 29] - u4 * u5 * dinv
    c22 = W[sr, sc + 35] - u5 * u5 * dinv
    e = (W[i, E_], W[i, E_ + 1], W[i, E_ + 2], W[i, E_ + 3], W[i, E_ + 4], W[i, E_ + 5],
         W[i, E_ + 6], W[i, E_ + 7], W[i, E_ + 8])
    P = etxe(e, (a00, a01, a02, a01, a11, a12, a02, a12, a22))
    Q = etxe(e, (b00, b01, b02, b10, b11, b12, b20, b21, b22))
    R = etxe(e, (c00, c01, c02, c01, c11, c12, c02, c12, c22))
    r0, r1, r2 = W[i, R_], W[i, R_ + 1], W[i, R_ + 2]
    # Z = r× R: column b is r × R[:, b]; H = Q + Z
    z0, z3, z6 = r1 * R[6] - r2 * R[3], r2 * R[0] - r0 * R[6], r0 * R[3] - r1 * R[0]
    z1, z4, z7 = r1 * R[7] - r2 * R[4], r2 * R[1] - r0 * R[7], r0 * R[4] - r1 * R[1]
    z2, z5, z8 = r1 * R[8] - r2 * R[5], r2 * R[2] - r0 * R[8], r0 * R[5] - r1 * R[2]
    # Y rows: Q[a] × r; (Z r×) rows: Z[a] × r
    y0, y1, y2 = Q[1] * r2 - Q[2] * r1, Q[2] * r0 - Q[0] * r2, Q[0] * r1 - Q[1] * r0
    y3, y4, y5 = Q[4] * r2 - Q[5] * r1, Q[5] * r0 - Q[3] * r2, Q[3] * r1 - Q[4] * r0
    y6, y7, y8 = Q[7] * r2 - Q[8] * r1, Q[8] * r0 - Q[6] * r2, Q[6] * r1 - Q[7] * r0
    w0, w1, w2 = z1 * r2 - z2 * r1, z2 * r0 - z0 * r2, z0 * r1 - z1 * r0
    w4, w5 = z5 * r0 - z3 * r2, z3 * r1 - z4 * r0
    w8 = z6 * r1 - z7 * r0
    i00 = P[0] - 2.0 * y0 - w0
    i01 = P[1] - y1 - y3 - w1
    i02 = P[2] - y2 - y6 - w2
    i11 = P[4] - 2.0 * y4 - w4
    i12 = P[5] - y5 - y7 - w5
    i22 = P[8] - 2.0 * y8 - w8
    h = (Q[0] + z0, Q[1] + z1, Q[2] + z2, Q[3] + z3, Q[4] + z4, Q[5] + z5, Q[6] + z6, Q[7] + z7, Q[8] + z8)
    W[dr, dc] += i00
    W[dr, dc + 1] += i01
    W[dr, dc + 2] += i02
    W[dr, dc + 6] += i01
    W[dr, dc + 7] += i11
    W[dr, dc + 8] += i12
    W[dr, dc + 12] += i02
    W[dr, dc + 13] += i12
    W[dr, dc + 14] += i22
    for a in range(3):
        for b in range(3):
            W[dr, dc + 6 * a + 3 + b] += h[3 * a + b]
            W[dr, dc + 6 * (3 + b) + a] += h[3 * a + b]
            W[dr, dc + 6 * (3 + a) + 3 + b] += R[3 * a + b]


@njit(**_LEAF)
def rigid_inertia(mf, i, W, dr, dc):
    """Body i's spatial inertia ``[Ī h×; h×ᵀ m1]`` (book eq. 2.63) into ``W[dr, dc:dc+36]``."""
    h0, h1, h2 = mf[i, HV], mf[i, HV + 1], mf[i, HV + 2]
    m = mf[i, MASS]
    for a in range(3):
        for b in range(3):
            W[dr, dc + 6 * a + b] = mf[i, IB + 3 * a + b]
            W[dr, dc + 6 * (3 + a) + 3 + b] = m if a == b else 0.0
    W[dr, dc + 3], W[dr, dc + 4], W[dr, dc + 5] = 0.0, -h2, h1
    W[dr, dc + 9], W[dr, dc + 10], W[dr, dc + 11] = h2, 0.0, -h0
    W[dr, dc + 15], W[dr, dc + 16], W[dr, dc + 17] = -h1, h0, 0.0
    for a in range(3):
        for b in range(3):
            W[dr, dc + 6 * (3 + b) + a] = W[dr, dc + 6 * a + 3 + b]


@njit(**_LEAF)
def rigid_inertia_times(mf, i, W, sr, sc, dr, dc):
    """``W[dr, dc:dc+6] = I_i W[sr, sc:sc+6]``: ``[Ī w + h × u; m u - h × w]``."""
    w0, w1, w2 = W[sr, sc], W[sr, sc + 1], W[sr, sc + 2]
    u0, u1, u2 = W[sr, sc + 3], W[sr, sc + 4], W[sr, sc + 5]
    h0, h1, h2 = mf[i, HV], mf[i, HV + 1], mf[i, HV + 2]
    m = mf[i, MASS]
    W[dr, dc] = mf[i, IB] * w0 + mf[i, IB + 1] * w1 + mf[i, IB + 2] * w2 + (h1 * u2 - h2 * u1)
    W[dr, dc + 1] = mf[i, IB + 3] * w0 + mf[i, IB + 4] * w1 + mf[i, IB + 5] * w2 + (h2 * u0 - h0 * u2)
    W[dr, dc + 2] = mf[i, IB + 6] * w0 + mf[i, IB + 7] * w1 + mf[i, IB + 8] * w2 + (h0 * u1 - h1 * u0)
    W[dr, dc + 3] = m * u0 - (h1 * w2 - h2 * w1)
    W[dr, dc + 4] = m * u1 - (h2 * w0 - h0 * w2)
    W[dr, dc + 5] = m * u2 - (h0 * w1 - h1 * w0)


@njit(**_LEAF)
def cross_force_add(W, vr, vc, fr, fc, dr, dc):
    """``W[dr, dc:dc+6] += v ×* f`` (book eq. 2.32): ``[w × n + u × f; w × f]``."""
    w0, w1, w2 = W[vr, vc], W[vr, vc + 1], W[vr, vc + 2]
    u0, u1, u2 = W[vr, vc + 3], W[vr, vc + 4], W[vr, vc + 5]
    n0, n1, n2 = W[fr, fc], W[fr, fc + 1], W[fr, fc + 2]
    f0, f1, f2 = W[fr, fc + 3], W[fr, fc + 4], W[fr, fc + 5]
    W[dr, dc] += w1 * n2 - w2 * n1 + u1 * f2 - u2 * f1
    W[dr, dc + 1] += w2 * n0 - w0 * n2 + u2 * f0 - u0 * f2
    W[dr, dc + 2] += w0 * n1 - w1 * n0 + u0 * f1 - u1 * f0
    W[dr, dc + 3] += w1 * f2 - w2 * f1
    W[dr, dc + 4] += w2 * f0 - w0 * f2
    W[dr, dc + 5] += w0 * f1 - w1 * f0


@njit(**_LEAF)
def cross_motion_add(W, vr, vc, mr, mc, dr, dc):
    """``W[dr, dc:dc+6] += v × m`` (book eq. 2.31): ``[w × mw; w × mu + u × mw]``."""
    w0, w1, w2 = W[vr, vc], W[vr, vc + 1], W[vr, vc + 2]
    u0, u1, u2 = W[vr, vc + 3], W[vr, vc + 4], W[vr, vc + 5]
    a0, a1, a2 = W[mr, mc], W[mr, mc + 1], W[mr, mc + 2]
    b0, b1, b2 = W[mr, mc + 3], W[mr, mc + 4], W[mr, mc + 5]
    W[dr, dc] += w1 * a2 - w2 * a1
    W[dr, dc + 1] += w2 * a0 - w0 * a2
    W[dr, dc + 2] += w0 * a1 - w1 * a0
    W[dr, dc + 3] += w1 * b2 - w2 * b1 + u1 * a2 - u2 * a1
    W[dr, dc + 4] += w2 * b0 - w0 * b2 + u2 * a0 - u0 * a2
    W[dr, dc + 5] += w0 * b1 - w1 * b0 + u0 * a1 - u1 * a0


# ----------------------------------------------------------------------------------------------
# joints
# ----------------------------------------------------------------------------------------------
@njit(**_LEAF)
def joint_transform(mi, mf, q, i, W):
    """``Xup[i] = XJ(q_i) Xtree[i]`` as ``(E, r)`` into ``W[i, E_]``, ``W[i, R_]``.

    Composition ``(E2, r2)(E1, r1) = (E2 E1, r1 + E1ᵀ r2)``; revolute ``XJ = (Rᵀ(k, q), 0)``
    with Rodrigues ``Rᵀ = c 1 - s k× + (1 - c) k kᵀ``; prismatic ``XJ = (1, k q)``; free
    ``XJ = (Rᵀ(quat), p)`` (``spatial.quat_to_R``); spherical ``XJ = (Rᵀ(quat), 0)``; fixed ``XJ = 1``.
    """
    jt = mi[i, JTYPE]
    qi = mi[i, QIDX]
    if mi[i, AXK] == 1:
        if jt == REVOLUTE:  # E = Rz(q)ᵀ Et: rows c Et0 + s Et1, -s Et0 + c Et1, Et2
            c = math.cos(q[qi])
            s = math.sin(q[qi])
            for b in range(3):
                e0, e1 = mf[i, ET + b], mf[i, ET + 3 + b]
                W[i, E_ + b] = c * e0 + s * e1
                W[i, E_ + 3 + b] = c * e1 - s * e0
                W[i, E_ + 6 + b] = mf[i, ET + 6 + b]
                W[i, R_ + b] = mf[i, RT + b]
        else:  # prismatic along z: r = rt + q Et[2, :]
            qq = q[qi]
            for b in range(3):
                W[i, E_ + b] = mf[i, ET + b]
                W[i, E_ + 3 + b] = mf[i, ET + 3 + b]
                W[i, E_ + 6 + b] = mf[i, ET + 6 + b]
                W[i, R_ + b] = mf[i, RT + b] + mf[i, ET + 6 + b] * qq
        return
    if jt == REVOLUTE or jt == FREE or jt == SPHERICAL:
        if jt == REVOLUTE:
            th = q[qi]
            c = math.cos(th)
            s = math.sin(th)
            t = 1.0 - c
            kx, ky, kz = mf[i, AX], mf[i, AX + 1], mf[i, AX + 2]
            J00, J01, J02 = c + t * kx * kx, s * kz + t * kx * ky, -s * ky + t * kx * kz
            J10, J11, J12 = -s * kz + t * ky * kx, c + t * ky * ky, s * kx + t * ky * kz
            J20, J21, J22 = s * ky + t * kz * kx, -s * kx + t * kz * ky, c + t * kz * kz
            for a in range(3):
                W[i, R_ + a] = mf[i, RT + a]
        else:
            o = 3 if jt == FREE else 0
            x, y, z, w = q[qi + o], q[qi + o + 1], q[qi + o + 2], q[qi + o + 3]
            J00, J10, J20 = 1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)
            J01, J11, J21 = 2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)
            J02, J12, J22 = 2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)
            if jt == FREE:
                p0, p1, p2 = q[qi], q[qi + 1], q[qi + 2]
                for a in range(3):
                    W[i, R_ + a] = (mf[i, RT + a] + mf[i, ET + a] * p0 + mf[i, ET + 3 + a] * p1
                                    + mf[i, ET + 6 + a] * p2)
            else:
                for a in range(3):
                    W[i, R_ + a] = mf[i, RT + a]
        for b in range(3):
            e0, e1, e2 = mf[i, ET + b], mf[i, ET + 3 + b], mf[i, ET + 6 + b]
            W[i, E_ + b] = J00 * e0 + J01 * e1 + J02 * e2
            W[i, E_ + 3 + b] = J10 * e0 + J11 * e1 + J12 * e2
            W[i, E_ + 6 + b] = J20 * e0 + J21 * e1 + J22 * e2
        return
    for a in range(9):
        W[i, E_ + a] = mf[i, ET + a]
    if jt == PRISMATIC:
        qq = q[qi]
        d0, d1, d2 = mf[i, AX] * qq, mf[i, AX + 1] * qq, mf[i, AX + 2] * qq
        for a in range(3):
            W[i, R_ + a] = mf[i, RT + a] + mf[i, ET + a] * d0 + mf[i, ET + 3 + a] * d1 + mf[i, ET + 6 + a] * d2
    else:
        for a in range(3):
            W[i, R_ + a] = mf[i, RT + a]


@njit(**_LEAF)
def transforms(mi, mf, q, W):
    """Every body's ``Xup`` into W."""
    for i in range(mi.shape[0]):
        joint_transform(mi, mf, q, i, W)


@njit(**_LEAF)
def joint_motion(mi, mf, x, i, W, dr, dc):
    """``W[dr, dc:dc+6] = S_i x_i`` (joint velocity vJ, or S a)."""
    jt = mi[i, JTYPE]
    s = mi[i, VIDX]
    for a in range(6):
        W[dr, dc + a] = 0.0
    if mi[i, AXK] == 1:
        W[dr, dc + (2 if jt == REVOLUTE else 5)] = x[s]
    elif jt == REVOLUTE:
        for a in range(3):
            W[dr, dc + a] = mf[i, AX + a] * x[s]
    elif jt == PRISMATIC:
        for a in range(3):
            W[dr, dc + 3 + a] = mf[i, AX + a] * x[s]
    elif jt == FREE:
        for a in range(6):
            W[dr, dc + a] = x[s + a]
    elif jt == SPHERICAL:
        for a in range(3):
            W[dr, dc + a] = x[s + a]


@njit(**_LEAF)
def joint_nv(jt):
    """Number of velocity coordinates of a joint type."""
    if jt == FREE:
        return 6
    if jt == SPHERICAL:
        return 3
    if jt == FIXED:
        return 0
    return 1


@njit(**_LEAF)
def project_force(mi, mf, W, sr, sc, j, out, off):
    """``out[off + v_j : off + v_j + nv_j] = S_jᵀ W[sr, sc:sc+6]`` (a joint's share of a body force)."""
    jt = mi[j, JTYPE]
    t = off + mi[j, VIDX]
    if mi[j, AXK] == 1:
        out[t] = W[sr, sc + (2 if jt == REVOLUTE else 5)]
    elif jt == REVOLUTE:
        out[t] = mf[j, AX] * W[sr, sc] + mf[j, AX + 1] * W[sr, sc + 1] + mf[j, AX + 2] * W[sr, sc + 2]
    elif jt == PRISMATIC:
        out[t] = mf[j, AX] * W[sr, sc + 3] + mf[j, AX + 1] * W[sr, sc + 4] + mf[j, AX + 2] * W[sr, sc + 5]
    elif jt == FREE:
        for a in range(6):
            out[t + a] = W[sr, sc + a]
    elif jt == SPHERICAL:
        for a in range(3):
            out[t + a] = W[sr, sc + a]


@njit(**_LEAF)
def base_acceleration(mf, W, dr, dc):
    """``a0 = -[0; g]`` into ``W[dr, dc:dc+6]``, gravity from the last row of mf."""
    g = mf.shape[0] - 1
    W[dr, dc] = 0.0
    W[dr, dc + 1] = 0.0
    W[dr, dc + 2] = 0.0
    W[dr, dc + 3] = -mf[g, 0]
    W[dr, dc + 4] = -mf[g, 1]
    W[dr, dc + 5] = -mf[g, 2]


@njit(**_LEAF)
def pivot_sqrt(s):
    """``√s`` of a Cholesky pivot s, NaN when s is not positive (the matrix is not positive definite). The
    generated code (:mod:`.codegen`) writes it as this expression: the one branch on the state it keeps."""
    return math.sqrt(s) if s > 0.0 else math.nan


@njit(**_LEAF)
def chol6_solve(W, ar, ac, br, bc, xr, xc):
    """Solve ``A x = b`` for a symmetric positive definite A (6, 6) at ``W[ar, ac:ac+36]`` by Cholesky.

    b at ``W[br, bc:bc+6]``, x into ``W[xr, xc:xc+6]``; L in the scratch row.
    """
    s_ = W.shape[0] - 1
    for j in range(6):
        s = W[ar, ac + 7 * j]
        for k in range(j):
            ljk = W[s_, L_ + 6 * j + k]
            s -= ljk * ljk
        d = pivot_sqrt(s)
        W[s_, L_ + 7 * j] = d
        for i in range(j + 1, 6):
            s = W[ar, ac + 6 * i + j]
            for k in range(j):
                s -= W[s_, L_ + 6 * i + k] * W[s_, L_ + 6 * j + k]
            W[s_, L_ + 6 * i + j] = s / d
    for i in range(6):
        s = W[br, bc + i]
        for k in range(i):
            s -= W[s_, L_ + 6 * i + k] * W[xr, xc + k]
        W[xr, xc + i] = s / W[s_, L_ + 7 * i]
    for i in range(5, -1, -1):
        s = W[xr, xc + i]
        for k in range(i + 1, 6):
            s -= W[s_, L_ + 6 * k + i] * W[xr, xc + k]
        W[xr, xc + i] = s / W[s_, L_ + 7 * i]


@njit(**_LEAF)
def spherical_articulated(W, i, tau, s, propagate, arm):
    """ABA pass 2 at a spherical joint i (``S = [1; 0]``, book Table 7.1 with a 3-column S).

    ``U = IA S`` = the first three columns of IA (into ``W[i, U3_]``, 6x3 row major),
    ``D = Sᵀ IA S + arm 1`` = IA's upper-left 3x3 block plus the armature, inverted explicitly (cofactors; it is
    symmetric positive definite for a body with mass) into ``W[i, DI3_]``, ``u = τ - Sᵀ pA``
    into ``W[i, UV_:UV_+3]``. With propagate: ``Ia = IA - U D⁻¹ Uᵀ`` overwrites ``W[i, IA_]``
    and ``pa = pA + Ia c + U D⁻¹ u`` goes to ``W[s_, S2_]``.
    """
    s_ = W.shape[0] - 1
    for a in range(6):
        for k in range(3):
            W[i, U3_ + 3 * a + k] = W[i, IA_ + 6 * a + k]
    d00, d01, d02 = W[i, IA_] + arm, W[i, IA_ + 1], W[i, IA_ + 2]
    d11, d12, d22 = W[i, IA_ + 7] + arm, W[i, IA_ + 8], W[i, IA_ + 14] + arm
    c00 = d11 * d22 - d12 * d12
    c01 = d02 * d12 - d01 * d22
    c02 = d01 * d12 - d02 * d11
    c11 = d00 * d22 - d02 * d02
    c12 = d01 * d02 - d00 * d12
    c22 = d00 * d11 - d01 * d01
    det = d00 * c00 + d01 * c01 + d02 * c02
    inv = 1.0 / det if det > 0.0 else math.nan
    W[i, DI3_], W[i, DI3_ + 1], W[i, DI3_ + 2] = c00 * inv, c01 * inv, c02 * inv
    W[i, DI3_ + 3], W[i, DI3_ + 4], W[i, DI3_ + 5] = c01 * inv, c11 * inv, c12 * inv
    W[i, DI3_ + 6], W[i, DI3_ + 7], W[i, DI3_ + 8] = c02 * inv, c12 * inv, c22 * inv
    for k in range(3):
        W[i, UV_ + k] = tau[s + k] - W[i, P_ + k]
    if not propagate:
        return
    # G = U D⁻¹ (6x3) into the scratch T_ block; then Ia = IA - G Uᵀ, pa = pA + Ia c + G u
    for a in range(6):
        for k in range(3):
            W[s_, T_ + 3 * a + k] = (W[i, U3_ + 3 * a] * W[i, DI3_ + k] + W[i, U3_ + 3 * a + 1] * W[i, DI3_ + 3 + k]
                                     + W[i, U3_ + 3 * a + 2] * W[i, DI3_ + 6 + k])
    for a in range(6):
        for b in range(6):
            W[i, IA_ + 6 * a + b] -= (W[s_, T_ + 3 * a] * W[i, U3_ + 3 * b] + W[s_, T_ + 3 * a + 1] * W[i, U3_ + 3 * b + 1]
                                      + W[s_, T_ + 3 * a + 2] * W[i, U3_ + 3 * b + 2])
    for a in range(6):
        acc = W[i, P_ + a] + (W[s_, T_ + 3 * a] * W[i, UV_] + W[s_, T_ + 3 * a + 1] * W[i, UV_ + 1]
                              + W[s_, T_ + 3 * a + 2] * W[i, UV_ + 2])
        for b in range(6):
            acc += W[i, IA_ + 6 * a + b] * W[i, C_ + b]
        W[s_, S2_ + a] = acc


# ----------------------------------------------------------------------------------------------
# algorithms (Xup already in W: call transforms first)
# ----------------------------------------------------------------------------------------------
@njit(**_LEAF)
def aba_ws(mi, mf, q, v, tau, fext, has_fext, qdd, W):
    """Articulated-body forward dynamics (book Table 7.1) into qdd (nv,).

    tau (nv,) generalised forces; fext (nb, 6) external body forces (used if has_fext). A joint's
    armature a (``mf[:, ARM]``) adds to its ``D = Sᵀ IA S`` only: the rotor turns with the joint
    rate but passes no inertia on to the parent.
    """
    nb = mi.shape[0]
    s_ = nb  # scratch row
    for i in range(nb):                     # pass 1: velocities, bias terms
        p = mi[i, PARENT]
        joint_motion(mi, mf, v, i, W, s_, S1_)           # vJ
        if p < 0:
            for a in range(6):
                W[i, V_ + a] = W[s_, S1_ + a]
                W[i, C_ + a] = 0.0
        else:
            xmot(W, i, p, V_, i, V_)
            for a in range(6):
                W[i, V_ + a] += W[s_, S1_ + a]
                W[i, C_ + a] = 0.0
            cross_motion_add(W, i, V_, s_, S1_, i, C_)    # c = v × vJ
        rigid_inertia(mf, i, W, i, IA_)
        rigid_inertia_times(mf, i, W, i, V_, s_, S2_)    # I v
        for a in range(6):
            W[i, P_ + a] = -fext[i, a] if has_fext else 0.0
        cross_force_add(W, i, V_, s_, S2_, i, P_)        # pA = v ×* I v - f_ext
    for i in range(nb - 1, -1, -1):         # pass 2: articulated inertias
        p = mi[i, PARENT]
        jt = mi[i, JTYPE]
        s = mi[i, VIDX]
        if jt == REVOLUTE or jt == PRISMATIC:
            o = 0 if jt == REVOLUTE else 3
            if mi[i, AXK] == 1:             # U = IA S = column o + 2
                for a in range(6):
                    W[i, U_ + a] = W[i, IA_ + 6 * a + o + 2]
                di = W[i, U_ + o + 2]
                ui = tau[s] - W[i, P_ + o + 2]
            else:
                k0, k1, k2 = mf[i, AX], mf[i, AX + 1], mf[i, AX + 2]
                for a in range(6):
                    b = IA_ + 6 * a + o
                    W[i, U_ + a] = W[i, b] * k0 + W[i, b + 1] * k1 + W[i, b + 2] * k2
                di = k0 * W[i, U_ + o] + k1 * W[i, U_ + o + 1] + k2 * W[i, U_ + o + 2]
                ui = tau[s] - (k0 * W[i, P_ + o] + k1 * W[i, P_ + o + 1] + k2 * W[i, P_ + o + 2])
            di += mf[i, ARM]                # D = Sᵀ IA S + armature (the rotor's inertia)
            W[i, D_] = di
            W[i, UV_] = ui
            if p >= 0:
                # Ia = IA - U Uᵀ/d (applied inside xinertia_T_add);
                # pa = pA + Ia c + U u/d = pA + IA c + U (u - Uᵀc)/d
                Uc = 0.0
                for a in range(6):
                    Uc += W[i, U_ + a] * W[i, C_ + a]
                coef = (ui - Uc) / di
                for a in range(6):
                    acc = W[i, P_ + a] + W[i, U_ + a] * coef
                    for b in range(6):
                        acc += W[i, IA_ + 6 * a + b] * W[i, C_ + b]
                    W[s_, S2_ + a] = acc
                xinertia_T_add(W, i, i, IA_, p, IA_, i, U_, 1.0 / di)
                xforce_T_add(W, i, s_, S2_, p, P_)
        elif jt == FREE:
            # S = 1: U = D = IA, so Ia = 0 and pa = pA + u (the joint force)
            for a in range(6):
                W[i, UV_ + a] = tau[s + a] - W[i, P_ + a]
            if p >= 0:
                for a in range(6):
                    W[s_, S2_ + a] = W[i, P_ + a] + W[i, UV_ + a]
                xforce_T_add(W, i, s_, S2_, p, P_)
        elif jt == SPHERICAL:
            spherical_articulated(W, i, tau, s, p >= 0, mf[i, ARM])
            if p >= 0:  # W[i, IA_] now holds Ia, W[s_, S2_] pa
                xinertia_T_add(W, i, i, IA_, p, IA_, i, U_, 0.0)
                xforce_T_add(W, i, s_, S2_, p, P_)
        elif p >= 0:  # FIXED (c = 0): the welded body's IA and pA pass on unchanged
            xinertia_T_add(W, i, i, IA_, p, IA_, i, U_, 0.0)
            xforce_T_add(W, i, i, P_, p, P_)
    for i in range(nb):                     # pass 3: accelerations
        p = mi[i, PARENT]
        jt = mi[i, JTYPE]
        s = mi[i, VIDX]
        if p < 0:
            base_acceleration(mf, W, s_, S3_)
            xmot(W, i, s_, S3_, i, A_)
        else:
            xmot(W, i, p, A_, i, A_)
        for a in range(6):
            W[i, A_ + a] += W[i, C_ + a]
        if jt == REVOLUTE or jt == PRISMATIC:
            o = 0 if jt == REVOLUTE else 3
            Ua = 0.0
            for a in range(6):
                Ua += W[i, U_ + a] * W[i, A_ + a]
            qi = (W[i, UV_] - Ua) / W[i, D_]
            qdd[s] = qi
            if mi[i, AXK] == 1:
                W[i, A_ + o + 2] += qi
            else:
                for a in range(3):
                    W[i, A_ + o + a] += mf[i, AX + a] * qi
        elif jt == SPHERICAL:   # qdd = D⁻¹ (u - Uᵀ a'), a = a' + S qdd
            for k in range(3):
                W[s_, S4_ + k] = W[i, UV_ + k]
                for a in range(6):
                    W[s_, S4_ + k] -= W[i, U3_ + 3 * a + k] * W[i, A_ + a]
            for k in range(3):
                qk = (W[i, DI3_ + 3 * k] * W[s_, S4_] + W[i, DI3_ + 3 * k + 1] * W[s_, S4_ + 1]
                      + W[i, DI3_ + 3 * k + 2] * W[s_, S4_ + 2])
                qdd[s + k] = qk
                W[i, A_ + k] += qk
        elif jt == FREE:
            # qdd = IA⁻¹ (u - IA ap) = IA⁻¹ u - ap, and a = ap + qdd = IA⁻¹ u
            chol6_solve(W, i, IA_, i, UV_, s_, S4_)
            for a in range(6):
                qdd[s + a] = W[s_, S4_ + a] - W[i, A_ + a]
                W[i, A_ + a] = W[s_, S4_ + a]


@njit(**_LEAF)
def rnea_ws(mi, mf, q, v, acc, fext, has_fext, tau, W):
    """Recursive Newton–Euler (book Table 5.1) into tau (nv,); joint wrenches left in ``W[:, P_]``.

    ``W[i, P_:P_+6]`` is the force the parent exerts on body i through joint i, in body i
    coordinates at its origin (see :func:`robodyn_ros.dynamics.rnea_wrenches`). A joint's armature
    a adds ``a q̈`` to its tau, not to the wrench: the rotor's torque never passes through the link.
    """
    nb = mi.shape[0]
    s_ = nb
    for i in range(nb):
        p = mi[i, PARENT]
        joint_motion(mi, mf, v, i, W, s_, S1_)     # vJ
        joint_motion(mi, mf, acc, i, W, s_, S2_)   # S qdd
        if p < 0:
            base_acceleration(mf, W, s_, S3_)
            xmot(W, i, s_, S3_, i, A_)
            for a in range(6):
                W[i, V_ + a] = W[s_, S1_ + a]
                W[i, A_ + a] += W[s_, S2_ + a]
        else:
            xmot(W, i, p, V_, i, V_)
            xmot(W, i, p, A_, i, A_)
            for a in range(6):
                W[i, V_ + a] += W[s_, S1_ + a]
                W[i, A_ + a] += W[s_, S2_ + a]
            cross_motion_add(W, i, V_, s_, S1_, i, A_)
        rigid_inertia_times(mf, i, W, i, A_, i, P_)
        rigid_inertia_times(mf, i, W, i, V_, s_, S4_)
        cross_force_add(W, i, V_, s_, S4_, i, P_)
        if has_fext:
            for a in range(6):
                W[i, P_ + a] -= fext[i, a]
    for i in range(nb - 1, -1, -1):
        project_force(mi, mf, W, i, P_, i, tau, 0)
        if mf[i, ARM] != 0.0:
            s = mi[i, VIDX]
            for k in range(joint_nv(mi[i, JTYPE])):
                tau[s + k] += mf[i, ARM] * acc[s + k]
        p = mi[i, PARENT]
        if p >= 0:
            xforce_T_add(W, i, i, P_, p, P_)


@njit(**_LEAF)
def rbi_T_add(W, i, sr, sc, dr, dc):
    """Composite rigid-body inertia ``+= X_iᵀ I X_i`` in 10-number form ``[m, h (3), Ī (6: 00 01 02 11 12 22)]``.

    A rigid (composite) inertia stays rigid, so instead of the 6x6 sandwich: with ``g = Eᵀ h``,
    ``m' = m``, ``h' = g + m r`` and ``Ī' = Eᵀ Ī E - (r gᵀ + g rᵀ) - m r rᵀ + (2 g·r + m |r|²) 1``
    (from ``a× b× = b aᵀ - (a·b) 1`` in the general formula of :func:`xinertia_T_add`).
    """
    m = W[sr, sc]
    h0, h1, h2 = W[sr, sc + 1], W[sr, sc + 2], W[sr, sc + 3]
    i00, i01, i02 = W[sr, sc + 4], W[sr, sc + 5], W[sr, sc + 6]
    i11, i12, i22 = W[sr, sc + 7], W[sr, sc + 8], W[sr, sc + 9]
    e = (W[i, E_], W[i, E_ + 1], W[i, E_ + 2], W[i, E_ + 3], W[i, E_ + 4], W[i, E_ + 5],
         W[i, E_ + 6], W[i, E_ + 7], W[i, E_ + 8])
    P = etxe(e, (i00, i01, i02, i01, i11, i12, i02, i12, i22))
    g0 = e[0] * h0 + e[3] * h1 + e[6] * h2
    g1 = e[1] * h0 + e[4] * h1 + e[7] * h2
    g2 = e[2] * h0 + e[5] * h1 + e[8] * h2
    r0, r1, r2 = W[i, R_], W[i, R_ + 1], W[i, R_ + 2]
    d = 2.0 * (g0 * r0 + g1 * r1 + g2 * r2) + m * (r0 * r0 + r1 * r1 + r2 * r2)
    W[dr, dc] += m
    W[dr, dc + 1] += g0 + m * r0
    W[dr, dc + 2] += g1 + m * r1
    W[dr, dc + 3] += g2 + m * r2
    W[dr, dc + 4] += P[0] - 2.0 * r0 * g0 - m * r0 * r0 + d
    W[dr, dc + 5] += P[1] - (r0 * g1 + g0 * r1) - m * r0 * r1
    W[dr, dc + 6] += P[2] - (r0 * g2 + g0 * r2) - m * r0 * r2
    W[dr, dc + 7] += P[4] - 2.0 * r1 * g1 - m * r1 * r1 + d
    W[dr, dc + 8] += P[5] - (r1 * g2 + g1 * r2) - m * r1 * r2
    W[dr, dc + 9] += P[8] - 2.0 * r2 * g2 - m * r2 * r2 + d


@njit(**_LEAF)
def crba_ws(mi, mf, H, W):
    """Composite-rigid-body joint-space inertia (book Table 6.2) into H (nv, nv) (C order), zeroed by caller;
    a joint's armature is added to its diagonal entries (``M + diag(a)``).

    Composite inertias ``IC`` are kept in the 10-number rigid form at ``W[i, IA_:IA_+10]``
    (:func:`rbi_T_add`); ``F = IC S`` per joint column, carried to the root by ``Xupᵀ``.
    """
    nb = mi.shape[0]
    nv = H.shape[0]
    Hf = H.reshape(nv * nv)
    s_ = nb
    for i in range(nb):
        W[i, IA_] = mf[i, MASS]
        for a in range(3):
            W[i, IA_ + 1 + a] = mf[i, HV + a]
        W[i, IA_ + 4], W[i, IA_ + 5], W[i, IA_ + 6] = mf[i, IB], mf[i, IB + 1], mf[i, IB + 2]
        W[i, IA_ + 7], W[i, IA_ + 8], W[i, IA_ + 9] = mf[i, IB + 4], mf[i, IB + 5], mf[i, IB + 8]
    for i in range(nb - 1, -1, -1):
        p = mi[i, PARENT]
        if p >= 0:
            rbi_T_add(W, i, i, IA_, p, IA_)
    for i in range(nb):
        jt = mi[i, JTYPE]
        ni = joint_nv(jt)
        if ni == 0:
            continue
        s = mi[i, VIDX]
        m = W[i, IA_]
        h0, h1, h2 = W[i, IA_ + 1], W[i, IA_ + 2], W[i, IA_ + 3]
        I00, I01, I02 = W[i, IA_ + 4], W[i, IA_ + 5], W[i, IA_ + 6]
        I11, I12, I22 = W[i, IA_ + 7], W[i, IA_ + 8], W[i, IA_ + 9]
        for k in range(ni):                 # F = IC S, column k at W[s_, FC_ + 6k]
            if jt == FREE or jt == SPHERICAL:
                w0, w1, w2 = (1.0 if k == 0 else 0.0), (1.0 if k == 1 else 0.0), (1.0 if k == 2 else 0.0)
                u0, u1, u2 = (1.0 if k == 3 else 0.0), (1.0 if k == 4 else 0.0), (1.0 if k == 5 else 0.0)
            elif mi[i, AXK] == 1:
                w0, w1, w2, u0, u1 = 0.0, 0.0, 0.0, 0.0, 0.0
                if jt == REVOLUTE:
                    w2, u2 = 1.0, 0.0
                else:
                    w2, u2 = 0.0, 1.0
            elif jt == REVOLUTE:
                w0, w1, w2, u0, u1, u2 = mf[i, AX], mf[i, AX + 1], mf[i, AX + 2], 0.0, 0.0, 0.0
            else:
                w0, w1, w2, u0, u1, u2 = 0.0, 0.0, 0.0, mf[i, AX], mf[i, AX + 1], mf[i, AX + 2]
            # IC [w; u] = [Ī w + h × u; m u - h × w]
            o = FC_ + 6 * k
            W[s_, o] = I00 * w0 + I01 * w1 + I02 * w2 + (h1 * u2 - h2 * u1)
            W[s_, o + 1] = I01 * w0 + I11 * w1 + I12 * w2 + (h2 * u0 - h0 * u2)
            W[s_, o + 2] = I02 * w0 + I12 * w1 + I22 * w2 + (h0 * u1 - h1 * u0)
            W[s_, o + 3] = m * u0 - (h1 * w2 - h2 * w1)
            W[s_, o + 4] = m * u1 - (h2 * w0 - h0 * w2)
            W[s_, o + 5] = m * u2 - (h0 * w1 - h1 * w0)
        for k in range(ni):                 # diagonal block S_iᵀ F, plus the armature
            project_force(mi, mf, W, s_, FC_ + 6 * k, i, Hf, (s + k) * nv)
            H[s + k, s + k] += mf[i, ARM]
        j = i
        while mi[j, PARENT] >= 0:
            for k in range(ni):             # F = Xup[j]ᵀ F
                for a in range(6):
                    W[s_, S1_ + a] = 0.0
                xforce_T_add(W, j, s_, FC_ + 6 * k, s_, S1_)
                for a in range(6):
                    W[s_, FC_ + 6 * k + a] = W[s_, S1_ + a]
            j = mi[j, PARENT]
            t = mi[j, VIDX]
            nj = joint_nv(mi[j, JTYPE])
            for k in range(ni):
                project_force(mi, mf, W, s_, FC_ + 6 * k, j, Hf, (s + k) * nv)
                for m2 in range(nj):
                    H[t + m2, s + k] = H[s + k, t + m2]


@njit(**_LEAF)
def bias_mass_ws(mi, mf, q, v, zero, fext, has_fext, bias, H, G, W):
    """The bias/mass pass on the ``Xup`` in W: ``bias (nv,) = RNEA(q, v, 0)`` under the external body forces fext
    (used if has_fext), ``H (nv, nv) = M(q)`` (:func:`crba_ws`) and the gravity stiffness ``G = ∂g/∂q``
    (:func:`gravity_stiffness_ws`, from the CRBA's composite inertias); zero (nv,): zeros."""
    rnea_ws(mi, mf, q, v, zero, fext, has_fext, bias, W)
    nv = H.shape[0]
    for a in range(nv):
        for b in range(nv):
            H[a, b] = 0.0
    crba_ws(mi, mf, H, W)
    gravity_stiffness_ws(mi, mf, W, G)


@njit(**_LEAF)
def world_kinematics_ws(mi, mf, v, W):
    """Every body's root-to-body transform and velocity into W (Xup already there: :func:`transforms`).

    ``X0_i = Xup_i X0_p``: ``E0_i = E_i E0_p`` (``W[i, E0_]``, row major: world -> body axes) and
    ``r0_i = r0_p + E0_pᵀ r_i`` (``W[i, R0_]``: the body origin in the root frame); the body velocity
    ``v_i = X_i v_p + S_i q̇_i`` (``W[i, V_]``, ``[ω; v_O]`` in body coordinates, book eq. 5.7).
    """
    nb = mi.shape[0]
    s_ = nb
    for i in range(nb):
        p = mi[i, PARENT]
        joint_motion(mi, mf, v, i, W, s_, S1_)
        if p < 0:
            for a in range(6):
                W[i, V_ + a] = W[s_, S1_ + a]
            for a in range(9):
                W[i, E0_ + a] = W[i, E_ + a]
            for a in range(3):
                W[i, R0_ + a] = W[i, R_ + a]
        else:
            xmot(W, i, p, V_, i, V_)
            for a in range(6):
                W[i, V_ + a] += W[s_, S1_ + a]
            r0, r1, r2 = W[i, R_], W[i, R_ + 1], W[i, R_ + 2]
            for a in range(3):
                W[i, R0_ + a] = W[p, R0_ + a] + W[p, E0_ + a] * r0 + W[p, E0_ + 3 + a] * r1 + W[p, E0_ + 6 + a] * r2
                for b in range(3):
                    W[i, E0_ + 3 * a + b] = (W[i, E_ + 3 * a] * W[p, E0_ + b] + W[i, E_ + 3 * a + 1] * W[p, E0_ + 3 + b]
                                             + W[i, E_ + 3 * a + 2] * W[p, E0_ + 6 + b])


@njit(**_LEAF)
def energies_ws(mi, mf, q, v, W):
    """``(kinetic, potential)`` (J): ``½ Σ vᵢᵀ Iᵢ vᵢ + ½ Σ a q̇²`` (the rotors' share, armature a) and
    ``-gᵀ Σ mᵢ cᵢ`` (world coms).

    The world poses and body velocities come from :func:`world_kinematics_ws`.
    """
    nb = mi.shape[0]
    s_ = nb
    kin = 0.0
    mc0, mc1, mc2 = 0.0, 0.0, 0.0
    world_kinematics_ws(mi, mf, v, W)
    for i in range(nb):
        rigid_inertia_times(mf, i, W, i, V_, s_, S2_)
        for a in range(6):
            kin += W[i, V_ + a] * W[s_, S2_ + a]
        s = mi[i, VIDX]
        for k in range(joint_nv(mi[i, JTYPE])):
            kin += mf[i, ARM] * v[s + k] * v[s + k]
        m = mf[i, MASS]
        h0, h1, h2 = mf[i, HV], mf[i, HV + 1], mf[i, HV + 2]
        # m (p + R c) = m r0 + E0ᵀ h
        mc0 += m * W[i, R0_] + W[i, E0_] * h0 + W[i, E0_ + 3] * h1 + W[i, E0_ + 6] * h2
        mc1 += m * W[i, R0_ + 1] + W[i, E0_ + 1] * h0 + W[i, E0_ + 4] * h1 + W[i, E0_ + 7] * h2
        mc2 += m * W[i, R0_ + 2] + W[i, E0_ + 2] * h0 + W[i, E0_ + 5] * h1 + W[i, E0_ + 8] * h2
    g = mf.shape[0] - 1
    return 0.5 * kin, -(mf[g, 0] * mc0 + mf[g, 1] * mc1 + mf[g, 2] * mc2)


@njit(**_LEAF)
def qdot_into(mi, q, v, out):
    """``dq/dt`` (nq,) into out: v for 1-DOF joints; ``[R v_lin, ½ quat ⊗ [w; 0]]`` for free ones,
    ``½ quat ⊗ [w; 0]`` for spherical ones."""
    for i in range(mi.shape[0]):
        jt = mi[i, JTYPE]
        q0 = mi[i, QIDX]
        v0 = mi[i, VIDX]
        if jt == FREE:
            x, y, z, w = q[q0 + 3], q[q0 + 4], q[q0 + 5], q[q0 + 6]
            R00, R01, R02 = 1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)
            R10, R11, R12 = 2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)
            R20, R21, R22 = 2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)
            l0, l1, l2 = v[v0 + 3], v[v0 + 4], v[v0 + 5]
            out[q0] = R00 * l0 + R01 * l1 + R02 * l2
            out[q0 + 1] = R10 * l0 + R11 * l1 + R12 * l2
            out[q0 + 2] = R20 * l0 + R21 * l1 + R22 * l2
            bx, by, bz = v[v0], v[v0 + 1], v[v0 + 2]
            # ½ quat ⊗ (bx, by, bz, 0), as spatial.quat_mul
            out[q0 + 3] = 0.5 * (w * bx + y * bz - z * by)
            out[q0 + 4] = 0.5 * (w * by - x * bz + z * bx)
            out[q0 + 5] = 0.5 * (w * bz + x * by - y * bx)
            out[q0 + 6] = 0.5 * (-x * bx - y * by - z * bz)
        elif jt == SPHERICAL:   # ½ quat ⊗ (ω, 0), ω in child coordinates
            x, y, z, w = q[q0], q[q0 + 1], q[q0 + 2], q[q0 + 3]
            bx, by, bz = v[v0], v[v0 + 1], v[v0 + 2]
            out[q0] = 0.5 * (w * bx + y * bz - z * by)
            out[q0 + 1] = 0.5 * (w * by - x * bz + z * bx)
            out[q0 + 2] = 0.5 * (w * bz + x * by - y * bx)
            out[q0 + 3] = 0.5 * (-x * bx - y * by - z * bz)
        elif jt != FIXED:
            out[q0] = v[v0]


@njit(**_LEAF)
def normalize_into(mi, q):
    """Renormalise free- and spherical-joint quaternions of q in place (the projection onto the manifold)."""
    for i in range(mi.shape[0]):
        jt = mi[i, JTYPE]
        if jt == FREE or jt == SPHERICAL:
            s = mi[i, QIDX] + (3 if jt == FREE else 0)
            n = math.sqrt(q[s] * q[s] + q[s + 1] * q[s + 1] + q[s + 2] * q[s + 2] + q[s + 3] * q[s + 3])
            for a in range(4):
                q[s + a] /= n


@njit(**_LEAF)
def tangent_rate_into(mi, q, v, out):
    """The configuration rate of (q, v) in tangent coordinates, out (nv,): v for 1-DOF joints, the
    body angular velocity ω for spherical joints, ``[ω; R(q) v_lin]`` for a free joint (its position
    rate in the world frame). Linear in v: with v = x it is the map T of
    :mod:`robodyn_ros.kernels.rosenbrock` (R6) at q."""
    for i in range(mi.shape[0]):
        jt = mi[i, JTYPE]
        s = mi[i, VIDX]
        if jt == FREE:
            q0 = mi[i, QIDX]
            x, y, z, w = q[q0 + 3], q[q0 + 4], q[q0 + 5], q[q0 + 6]
            l0, l1, l2 = v[s + 3], v[s + 4], v[s + 5]
            out[s], out[s + 1], out[s + 2] = v[s], v[s + 1], v[s + 2]
            out[s + 3] = (1 - 2 * (y * y + z * z)) * l0 + 2 * (x * y - z * w) * l1 + 2 * (x * z + y * w) * l2
            out[s + 4] = 2 * (x * y + z * w) * l0 + (1 - 2 * (x * x + z * z)) * l1 + 2 * (y * z - x * w) * l2
            out[s + 5] = 2 * (x * z - y * w) * l0 + 2 * (y * z + x * w) * l1 + (1 - 2 * (x * x + y * y)) * l2
        elif jt == SPHERICAL:
            out[s], out[s + 1], out[s + 2] = v[s], v[s + 1], v[s + 2]
        elif jt != FIXED:
            out[s] = v[s]


@njit(**_LEAF)
def tangent_velocity_into(mi, q, t, out):
    """The inverse of :func:`tangent_rate_into` at q: the velocity coordinates out (nv,) of a tangent
    vector t (nv,): t itself but for a free joint's linear part, ``R(q)ᵀ t_lin`` (world frame -> body)."""
    for i in range(mi.shape[0]):
        jt = mi[i, JTYPE]
        s = mi[i, VIDX]
        if jt == FREE:
            q0 = mi[i, QIDX]
            x, y, z, w = q[q0 + 3], q[q0 + 4], q[q0 + 5], q[q0 + 6]
            l0, l1, l2 = t[s + 3], t[s + 4], t[s + 5]
            out[s], out[s + 1], out[s + 2] = t[s], t[s + 1], t[s + 2]
            out[s + 3] = (1 - 2 * (y * y + z * z)) * l0 + 2 * (x * y + z * w) * l1 + 2 * (x * z - y * w) * l2
            out[s + 4] = 2 * (x * y - z * w) * l0 + (1 - 2 * (x * x + z * z)) * l1 + 2 * (y * z + x * w) * l2
            out[s + 5] = 2 * (x * z + y * w) * l0 + 2 * (y * z - x * w) * l1 + (1 - 2 * (x * x + y * y)) * l2
        elif jt == SPHERICAL:
            out[s], out[s + 1], out[s + 2] = t[s], t[s + 1], t[s + 2]
        elif jt != FIXED:
            out[s] = t[s]


@njit(**_LEAF)
def retract_into(mi, q, dq, h, out):
    """``out (nq,) = q ⊕ h dq`` for a tangent increment dq (nv,) (:func:`tangent_rate_into`'s
    coordinates): ``q + h dq`` for 1-DOF joints and a free joint's position; ``quat ⊗ exp(h ω/2)`` for
    quaternions (ω in the child frame, as ``q̇ = ½ quat ⊗ [ω; 0]``), unit length to round-off.
    out may be q itself."""
    for i in range(mi.shape[0]):
        jt = mi[i, JTYPE]
        q0 = mi[i, QIDX]
        s = mi[i, VIDX]
        if jt == FREE or jt == SPHERICAL:
            o = 0
            if jt == FREE:
                for a in range(3):
                    out[q0 + a] = q[q0 + a] + h * dq[s + 3 + a]
                o = 3
            x, y, z, w = q[q0 + o], q[q0 + o + 1], q[q0 + o + 2], q[q0 + o + 3]
            b0, b1, b2 = 0.5 * h * dq[s], 0.5 * h * dq[s + 1], 0.5 * h * dq[s + 2]
            th = math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
            c = math.cos(th)
            f = math.sin(th) / th if th > 1e-8 else 1.0 - th * th / 6.0
            a0, a1, a2 = f * b0, f * b1, f * b2
            # quat ⊗ (a0, a1, a2, c)
            out[q0 + o] = w * a0 + x * c + y * a2 - z * a1
            out[q0 + o + 1] = w * a1 - x * a2 + y * c + z * a0
            out[q0 + o + 2] = w * a2 + x * a1 - y * a0 + z * c
            out[q0 + o + 3] = w * c - x * a0 - y * a1 - z * a2
        elif jt != FIXED:
            out[q0] = q[q0] + h * dq[s]


# ----------------------------------------------------------------------------------------------
# joint-limit moments (Huston eq. 20.2.1)
# ----------------------------------------------------------------------------------------------
@njit(**_LEAF)
def limit_moment(th, thd, lo, hi, k, c, mode):
    """The joint-limit moment of Huston eq. (20.2.1) at angle th, rate thd (range [lo, hi]).

    Inside the range M = 0. Beyond the upper limit, moving on outward (``θ̇ >= 0``),
    ``M = -k (θ - θmax) - c θ̇``; moving back (``θ̇ < 0``) the "restoring aspect" is off:
    mode 1 (``'none'``, the equation as printed) ``M = 0``; mode 2 (``'spring'``) ``M = -k (θ -
    θmax)``, the spring without its damper. Mirror image below the lower limit. (The printed
    cases leave ``θ̇ = 0`` open; it counts as moving outward, so a joint can rest on its stop.)
    Its power ``M θ̇`` is never positive in mode 1: the stop only takes energy out.
    """
    if th > hi:
        if thd >= 0.0:
            return -k * (th - hi) - c * thd
        return -k * (th - hi) if mode == 2 else 0.0
    if th < lo:
        if thd <= 0.0:
            return -k * (th - lo) - c * thd
        return -k * (th - lo) if mode == 2 else 0.0
    return 0.0


@njit(**_LEAF)
def rotation_vector(x, y, z, w):
    """``(b, φ0, φ1, φ2)``: the rotation vector φ of the unit quaternion (x, y, z, w), |φ| <= π, and the
    coefficient b of ``J_r⁻¹(φ) = 1 + ½ φ× + b φ×²`` (right Jacobian: ``φ̇ = J_r⁻¹(φ) ω``, ω in the
    rotated frame), ``b = 1/θ² - (1 + cos θ)/(2 θ sin θ)``, series ``1/12 + θ²/720`` near 0."""
    if w < 0.0:
        x, y, z, w = -x, -y, -z, -w
    sn = math.sqrt(x * x + y * y + z * z)
    th = 2.0 * math.atan2(sn, w)
    f = th / sn if sn > 1e-12 else 2.0 / w
    p0, p1, p2 = f * x, f * y, f * z
    if th < 1e-3:
        return 1.0 / 12.0 + th * th / 720.0, p0, p1, p2
    return 1.0 / (th * th) - (1.0 + math.cos(th)) / (2.0 * th * math.sin(th)), p0, p1, p2


@njit(**_LEAF)
def limit_forces_add(lim, q, v, tau):
    """``tau += `` the joint-limit moments of every row of ``lim`` (:func:`robodyn_ros.model.limit_table`).

    A 1-DOF joint: :func:`limit_moment` of ``(q, v)``. A spherical joint: :func:`_spherical_limit_forces_add`.
    (Called at every stage of every step: it allocates nothing.)
    """
    for r in range(lim.shape[0]):
        if int(lim[r, 0]) != SPHERICAL:
            qi = int(lim[r, 1])
            vi = int(lim[r, 2])
            tau[vi] += limit_moment(q[qi], v[vi], lim[r, 4], lim[r, 5], lim[r, 10], lim[r, 11], int(lim[r, 3]))
        else:
            _spherical_limit_forces_add(lim, r, q, v, tau)


@njit(**_LEAF)
def _spherical_limit_forces_add(lim, r, q, v, tau):
    """:func:`limit_forces_add` of the spherical row r: per component of its rotation vector φ (joint
    frame) with ``φ̇ = J_r⁻¹(φ) ω``; the moments M (conjugate to φ) act on ω as ``J_r⁻ᵀ M`` (same power
    ``M·φ̇``). Allocates nothing (every stage of every step calls it)."""
    vi = int(lim[r, 2])
    mode = int(lim[r, 3])
    k = lim[r, 10]
    c = lim[r, 11]
    (p0, p1, p2), (J00, J01, J02, J10, J11, J12, J20, J21, J22), (d0, d1, d2) = _limit_frame(lim, r, q, v)
    m0 = limit_moment(p0, d0, lim[r, 4], lim[r, 5], k, c, mode)
    m1 = limit_moment(p1, d1, lim[r, 6], lim[r, 7], k, c, mode)
    m2 = limit_moment(p2, d2, lim[r, 8], lim[r, 9], k, c, mode)
    tau[vi] += J00 * m0 + J10 * m1 + J20 * m2
    tau[vi + 1] += J01 * m0 + J11 * m1 + J21 * m2
    tau[vi + 2] += J02 * m0 + J12 * m1 + J22 * m2


@njit(**_LEAF)
def limit_slopes(th, thd, lo, hi, k, c, mode):
    """``(k_a, c_a)``: the stop's share of the stiffness and damping of the linearly implicit step
    (:mod:`robodyn_ros.kernels.rosenbrock`), ``−∂M/∂θ`` and ``−∂M/∂θ̇`` of :func:`limit_moment` on the branch
    at angle th, rate thd: beyond a limit k and c, or k alone when the joint moves back under the return
    spring (mode 2: M is continuous through θ̇ = 0 there); mode 1 moving back has M = 0 but jumps to
    ``−k Δ`` the moment the joint turns outward again, so it gets k and c ahead of the jump (where the
    force is in fact zero the extra J only slows that DOF's response within the step; the method stays
    order 2 for any J). Inside the range: nothing (a stop entered within a step is an event,
    :func:`robodyn_ros.kernels.arm.limit_event`)."""
    if th > hi:
        return (k, 0.0) if (thd < 0.0 and mode == 2) else (k, c)
    if th < lo:
        return (k, 0.0) if (thd > 0.0 and mode == 2) else (k, c)
    return 0.0, 0.0


@njit(**_LEAF)
def _limit_frame(lim, r, q, v):
    """``(φ, J, d)`` of a spherical limit row r at q, as tuples: its rotation vector φ (3), ``J = J_r⁻¹(φ) =
    1 + ½ φ× + b (φ φᵀ − |φ|² 1)`` row-major (9) and ``φ̇ = J ω`` (3) (see :func:`limit_forces_add`)."""
    qi = int(lim[r, 1])
    vi = int(lim[r, 2])
    bb, p0, p1, p2 = rotation_vector(q[qi], q[qi + 1], q[qi + 2], q[qi + 3])
    pp = p0 * p0 + p1 * p1 + p2 * p2
    J00, J01, J02 = 1.0 + bb * (p0 * p0 - pp), -0.5 * p2 + bb * p0 * p1, 0.5 * p1 + bb * p0 * p2
    J10, J11, J12 = 0.5 * p2 + bb * p1 * p0, 1.0 + bb * (p1 * p1 - pp), -0.5 * p0 + bb * p1 * p2
    J20, J21, J22 = -0.5 * p1 + bb * p2 * p0, 0.5 * p0 + bb * p2 * p1, 1.0 + bb * (p2 * p2 - pp)
    w0, w1, w2 = v[vi], v[vi + 1], v[vi + 2]
    return ((p0, p1, p2), (J00, J01, J02, J10, J11, J12, J20, J21, J22),
            (J00 * w0 + J01 * w1 + J02 * w2, J10 * w0 + J11 * w1 + J12 * w2, J20 * w0 + J21 * w1 + J22 * w2))


@njit(**_LEAF)
def limit_jacobian_add(lim, q, v, qs, use_qs, Dm, Km):
    """``Km += −∂τ_lim/∂q``, ``Dm += −∂τ_lim/∂v`` (nv, nv) of :func:`limit_forces_add` on the branches at
    (q, v) (:func:`limit_slopes`) -- with use_qs also the outward branch of every stop the configuration
    qs (nq,) is beyond (the stage point of a step that enters it) -- in tangent coordinates; a spherical
    row: :func:`_spherical_limit_jacobian_add`. Returns the number of stop terms added. (Called at every
    step: it allocates nothing for 1-DOF rows.)"""
    active = 0
    for r in range(lim.shape[0]):
        if int(lim[r, 0]) == SPHERICAL:
            active += _spherical_limit_jacobian_add(lim, r, q, v, qs, use_qs, Dm, Km)
            continue
        qi = int(lim[r, 1])
        vi = int(lim[r, 2])
        k = lim[r, 10]
        c = lim[r, 11]
        a, b = limit_slopes(q[qi], v[vi], lim[r, 4], lim[r, 5], k, c, int(lim[r, 3]))
        if use_qs and a == 0.0 and (qs[qi] > lim[r, 5] or qs[qi] < lim[r, 4]):
            a, b = k, c
        Km[vi, vi] += a
        Dm[vi, vi] += b
        active += a != 0.0 or b != 0.0
    return active


@njit(**_LEAF)
def _spherical_limit_jacobian_add(lim, r, q, v, qs, use_qs, Dm, Km):
    """:func:`limit_jacobian_add` of the spherical row r: its moments act through the rotation vector φ
    with ``φ̇ = J_r⁻¹(φ) ω`` (and ``δφ = J_r⁻¹ δ`` for a tangent increment δ), so it adds
    ``J_r⁻ᵀ diag(k_a) J_r⁻¹`` and ``J_r⁻ᵀ diag(c_a) J_r⁻¹`` (the change of J_r⁻¹ itself is left out: any J
    keeps the method's order). Returns its number of stop terms. Allocates nothing."""
    vi = int(lim[r, 2])
    mode = int(lim[r, 3])
    k = lim[r, 10]
    c = lim[r, 11]
    phi, Jm, d = _limit_frame(lim, r, q, v)
    phs = phi
    if use_qs:
        phs, _, _ = _limit_frame(lim, r, qs, v)
    ka0, ca0 = _stop_slopes(lim, r, 0, phi[0], d[0], phs[0], use_qs, k, c, mode)
    ka1, ca1 = _stop_slopes(lim, r, 1, phi[1], d[1], phs[1], use_qs, k, c, mode)
    ka2, ca2 = _stop_slopes(lim, r, 2, phi[2], d[2], phs[2], use_qs, k, c, mode)
    ka, ca = (ka0, ka1, ka2), (ca0, ca1, ca2)
    active = 0
    for e in range(3):
        active += ka[e] != 0.0 or ca[e] != 0.0
    for a in range(3):
        for b in range(3):
            sk = 0.0
            sc = 0.0
            for e in range(3):
                sk += Jm[3 * e + a] * ka[e] * Jm[3 * e + b]
                sc += Jm[3 * e + a] * ca[e] * Jm[3 * e + b]
            Km[vi + a, vi + b] += sk
            Dm[vi + a, vi + b] += sc
    return active


@njit(**_LEAF)
def _stop_slopes(lim, r, e, p, dp, ps, use_qs, k, c, mode):
    """``(k_e, c_e)`` of component e of the spherical row r (:func:`limit_slopes` at its angle p and rate
    dp), with use_qs the outward branch when its stage value ps is beyond a limit and the branch at p is not
    in."""
    lo, hi = lim[r, 4 + 2 * e], lim[r, 5 + 2 * e]
    ke, ce = limit_slopes(p, dp, lo, hi, k, c, mode)
    if use_qs and ke == 0.0 and (ps > hi or ps < lo):
        ke, ce = k, c
    return ke, ce


@njit(**_LEAF)
def gravity_stiffness_ws(mi, mf, W, G):
    """``G = ∂g/∂q`` (nv, nv, overwritten) over the 1-DOF joints, from the composite inertias that
    :func:`crba_ws` leaves in W (call it first): the Hessian of the gravitational potential V, with
    g = ∂V/∂q the gravity part of the bias (:func:`rnea_ws` at v = 0, a = 0). Symmetric, not definite
    (negative where a joint holds a load above its axis).

    With joint i's axis ``a_i`` through its body's origin, the subtree's mass ``m_i`` and first moment
    ``h_i = m_i (c_i − p_i)`` about that origin (the composite inertia's, body coordinates) and gravity γ
    (body coordinates), ``g_i = −γᵀ (a_i × h_i)`` (revolute) or ``−γᵀ m_i a_i`` (prismatic). Turning a
    joint j ⪯ i (an ancestor, or i itself) turns ``x_i = a_i × h_i`` (or ``m_i a_i``) rigidly, so for a
    revolute j::

        G_ij = G_ji = −γ_jᵀ (a_j × x_i)        (x_i and γ in body j's coordinates)

    and turning a descendant moves ``h_i`` by what the same formula gives with i and j swapped; a
    prismatic j translates the subtree rigidly (G_ij = 0 for j ⪯ i), separate branches do not couple.
    FREE and SPHERICAL joints get no rows (their gravity stays explicit) but carry their subtrees'
    frames. O(nb · depth). Scratch: ``W[:, A_:A_+6]`` (γ per body, then x carried up the tree)."""
    nb = mi.shape[0]
    nv = G.shape[0]
    for a in range(nv):
        for b in range(nv):
            G[a, b] = 0.0
    gi = mf.shape[0] - 1
    for i in range(nb):          # gravity in body coordinates: γ_i = E_i γ_parent
        p = mi[i, PARENT]
        if p < 0:
            g0, g1, g2 = mf[gi, 0], mf[gi, 1], mf[gi, 2]
        else:
            g0, g1, g2 = W[p, A_], W[p, A_ + 1], W[p, A_ + 2]
        for a in range(3):
            W[i, A_ + a] = W[i, E_ + 3 * a] * g0 + W[i, E_ + 3 * a + 1] * g1 + W[i, E_ + 3 * a + 2] * g2
    for i in range(nb):
        jt = mi[i, JTYPE]
        if jt != REVOLUTE and jt != PRISMATIC:
            continue
        si = mi[i, VIDX]
        k0, k1, k2 = mf[i, AX], mf[i, AX + 1], mf[i, AX + 2]
        m = W[i, IA_]
        if jt == REVOLUTE:
            h0, h1, h2 = W[i, IA_ + 1], W[i, IA_ + 2], W[i, IA_ + 3]
            x0, x1, x2 = k1 * h2 - k2 * h1, k2 * h0 - k0 * h2, k0 * h1 - k1 * h0
        else:
            x0, x1, x2 = m * k0, m * k1, m * k2
        j = i
        while j >= 0:            # j ⪯ i: i itself, then its ancestors; x in body j's coordinates
            if mi[j, JTYPE] == REVOLUTE:
                sj = mi[j, VIDX]
                a0, a1, a2 = mf[j, AX], mf[j, AX + 1], mf[j, AX + 2]
                gg = -(W[j, A_] * (a1 * x2 - a2 * x1) + W[j, A_ + 1] * (a2 * x0 - a0 * x2)
                       + W[j, A_ + 2] * (a0 * x1 - a1 * x0))
                G[si, sj] += gg
                if sj != si:
                    G[sj, si] += gg
            p = mi[j, PARENT]
            if p >= 0:           # to the parent's coordinates: Eᵀ x
                y0 = W[j, E_] * x0 + W[j, E_ + 3] * x1 + W[j, E_ + 6] * x2
                y1 = W[j, E_ + 1] * x0 + W[j, E_ + 4] * x1 + W[j, E_ + 7] * x2
                y2 = W[j, E_ + 2] * x0 + W[j, E_ + 5] * x1 + W[j, E_ + 8] * x2
                x0, x1, x2 = y0, y1, y2
            j = p


@njit(**_JIT)
def gravity_stiffness_into(mi, mf, q, G):
    """``G = ∂g/∂q`` (nv, nv) at q (:func:`gravity_stiffness_ws` after :func:`crba_ws`), one call."""
    nv = G.shape[0]
    W = workspace(mi.shape[0])
    transforms(mi, mf, q, W)
    H = np.zeros((nv, nv))
    crba_ws(mi, mf, H, W)
    gravity_stiffness_ws(mi, mf, W, G)


@njit(**_JIT)
def limit_forces(lim, q, v, nv):
    """The joint-limit generalised forces (nv,) alone (:func:`limit_forces_add` on zeros)."""
    tau = np.zeros(nv)
    limit_forces_add(lim, q, v, tau)
    return tau


# ----------------------------------------------------------------------------------------------
# one-call entry points (called from Python)
# ----------------------------------------------------------------------------------------------
@njit(**_JIT)
def aba_into(mi, mf, q, v, tau, qdd):
    """Forward dynamics into qdd (nv,), without external forces (the caller allocates qdd:
    returning a numba-allocated array costs more than the algorithm on a small arm)."""
    W = workspace(mi.shape[0])
    transforms(mi, mf, q, W)
    aba_ws(mi, mf, q, v, tau, W, False, qdd, W)


@njit(**_JIT)
def aba_fext_into(mi, mf, q, v, tau, fext, qdd):
    """Forward dynamics into qdd (nv,) with external body forces fext (nb, 6)."""
    W = workspace(mi.shape[0])
    transforms(mi, mf, q, W)
    aba_ws(mi, mf, q, v, tau, fext, True, qdd, W)


@njit(**_JIT)
def rnea(mi, mf, q, v, acc, fext, has_fext):
    """Inverse dynamics with joint wrenches: ``(tau (nv,), f (nb, 6))``."""
    nb = mi.shape[0]
    W = workspace(nb)
    transforms(mi, mf, q, W)
    tau = np.empty(acc.shape[0])
    rnea_ws(mi, mf, q, v, acc, fext, has_fext, tau, W)
    return tau, W[:nb, P_:P_ + 6].copy()


@njit(**_JIT)
def rnea_into(mi, mf, q, v, acc, tau):
    """Inverse dynamics into tau (nv,), without external forces."""
    W = workspace(mi.shape[0])
    transforms(mi, mf, q, W)
    rnea_ws(mi, mf, q, v, acc, W, False, tau, W)


@njit(**_JIT)
def crba_into(mi, mf, q, H):
    """Joint-space inertia matrix into H (nv, nv), C order, zeroed by the caller."""
    W = workspace(mi.shape[0])
    transforms(mi, mf, q, W)
    crba_ws(mi, mf, H, W)


@njit(**_JIT)
def joint_wrenches(mi, mf, q, v, tau, fext, has_fext):
    """``(qdd (nv,), f (nb, 6))``: ABA, then the RNEA wrenches at that acceleration."""
    nb = mi.shape[0]
    W = workspace(nb)
    transforms(mi, mf, q, W)
    qdd = np.empty(tau.shape[0])
    aba_ws(mi, mf, q, v, tau, fext, has_fext, qdd, W)
    tau2 = np.empty(tau.shape[0])
    rnea_ws(mi, mf, q, v, qdd, fext, has_fext, tau2, W)
    return qdd, W[:nb, P_:P_ + 6].copy()


@njit(**_JIT)
def energies(mi, mf, q, v):
    """``(kinetic, potential)`` energy (J)."""
    W = workspace(mi.shape[0])
    transforms(mi, mf, q, W)
    return energies_ws(mi, mf, q, v, W)


@njit(**_JIT)
def qdot(mi, q, v):
    """``dq/dt`` (nq,)."""
    out = np.empty(q.shape[0])
    qdot_into(mi, q, v, out)
    return out
