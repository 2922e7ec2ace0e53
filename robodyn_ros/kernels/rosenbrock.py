"""The linearly implicit (Rosenbrock-W) step for stiff passive forces: coefficients and stage algebra.

**Method** (``rosenbrock2``; ROS2 of Verwer, Spee, Blom & Hundsdorfer, SIAM J. Sci. Comput. 20(4),
1999, eq. 2.4; Hairer & Wanner II, §IV.7 for Rosenbrock/W-methods)::

    (I − γhJ) k1 = f(yₙ)                                                        (R1)
    (I − γhJ) k2 = f(yₙ + h k1) − 2 k1                                          (R2)
    yₙ₊₁ = yₙ + h (3/2 k1 + 1/2 k2),        γ = 1 − 1/√2                       (R3)

* **Order 2 for any J** (a W-method): the terms in J cancel to O(h³) in the local error whatever
  J is, so J may be frozen at yₙ, approximate, and hold only the stiff *passive* part of ∂f/∂y.
  With J = 0 the method is Heun's second-order Runge–Kutta method.
* **Stability.** With J exact (the scalar test equation y' = λy, z = hλ) the stability function is
  ``R(z) = (1 + (1 − 2γ) z) / (1 − γz)²``: A-stable, and L-stable (R(∞) = 0) because
  ``2γ² − 4γ + 1 = 0``. Of its two roots the paper takes γ = 1 + 1/√2, for which R(z) > 0 on the
  negative real axis (no overshoot); we take γ = 1 − 1/√2: the local error constant ``3γ² − 2γ³ − 1/6``
  of the implicit part is 0.040 instead of −1.37, and on a robot whose stiffly damped joints creep
  under gravity that is the error that counts (xarm7 falling 1 s at 1 ms: 2.7e-7 rad against 8.2e-6;
  test_rosenbrock_robots).
  The price: for z < −1/(1 − 2γ) = −2.41, R(z) < 0 with ``|R| <= (√2 − 1)/2 = 0.21``: a stiff mode's
  remainder changes sign from step to step while it shrinks at least 4.8-fold per step. That is
  harmless on smooth forces but not on a joint stop, whose law switches its damper off when the joint
  turns back, nor on a ground contact, whose friction changes its slope from stick to slip: within one
  step the stage point then meets another force than J holds, and with the small γ a stop could do work
  and a contact's friction flips its sign from step to step (docs/contact.md). A step with a stop in J,
  or with a contact touching (:func:`.arm.arm_implicit_matrix`), therefore takes ``GAMMA_STOP`` =
  1 + 1/√2, the paper's root, whose positive R does not overshoot (both roots are order 2 and L-stable;
  the choice is per step). With the passive part μ of a mode in J and the rest explicit (z = hλ, w = hμ)::

      R(z, w) = 1 + 3a/2 + (z + z a − 2a) / (2 (1 − γw)),    a = z / (1 − γw)        (R4)

  (``stability.rosenbrock2_amplification``). The explicit rest is Heun's: an undamped oscillation of
  frequency ω grows by ``|R(iωh)|² = 1 + (ωh)⁴/4`` per step, i.e. its energy doubles after
  ``≈ 2.8/(ω⁴h³)`` seconds (ω = 10 rad/s at 1 ms: 2.8e5 s), and the step is stable up to
  ``ωh = 2`` only for damped modes: stiffness that is not in J (gravity on a near-massless link,
  a constraint) stays explicit and limits the step as for RK2.

**Mechanical systems.** For ``y = [q, v]`` with ``M(q) v̇ = r(q, v)`` (r = τ − C − g + passive
forces) and its stiff part ``∂r/∂q ≈ −K``, ``∂r/∂v ≈ −D`` (K, D (nv, nv), symmetric; see below), ``J = [[0, T], [−M⁻¹K, −M⁻¹D]]`` with ``T`` the map from v to the tangent rate of
q (identity for 1-DOF joints). Eliminating the q-row of (R1)/(R2) (``kq = bq + γh T kv``) leaves
one symmetric positive definite system per stage with the *iteration matrix*::

    A = M + γh D + γ²h² K                                                        (R5)
    A kv = M bv − γh K bq,        kq = bq + γh T kv                                (R6)

where ``M bv`` is the force residual ``r(yₙ)`` at stage 1 (no M⁻¹ is formed) and
``M(qₙ)(f_v(Y₂) − 2 kv1)`` at stage 2. A is factorised once per step (Cholesky). Cost per step:
one CRBA, one Cholesky (n³/6 flops), one RNEA (stage 1), one ABA (stage 2), two triangular
solves and two products with M (2 n² flops each) and the passive Jacobian — about the cost of two
RK4 stages plus ``n³/6``, against four ABA for RK4.

**J is a sum of named contributions** (assembled per system in its kernel, ``arm.arm_implicit_matrix``
for trees, the differential drive's for its motors): joint damping ``D += diag(d)``; the regularised
Coulomb friction ``D += diag(f sech²(v/v_s)/v_s)`` (:func:`robodyn_ros.kernels.passive.friction_jacobian_add`);
the joint-limit moments of Huston eq. (20.2.1) on the branch active at yₙ, ``K += k``, ``D += c``, with
the spherical joints' ``J_r⁻ᵀ diag(k) J_r⁻¹`` (``tree.limit_jacobian_add``); a ground's compliant
contacts, with contact Jacobian ``Jᶜ`` (3 × nv per touching point), ``K += Σ Jᶜᵀ K_c Jᶜ`` and
``D += Σ Jᶜᵀ D_c Jᶜ`` (normal stiffness and damping, friction slope; ``arm.contact_bias_mass`` at yₙ,
``arm.contact_stage_jacobian`` at a touch-down within the step; ``contact.contact_jacobian_add``); the
DC motors' electrics, eliminated from the current rows so that A stays symmetric positive definite; and
the gravity stiffness ``∂g/∂q`` of the 1-DOF joints (``tree.gravity_stiffness_ws``, O(n·depth)): with
the passive part alone a stiffly damped joint under gravity converges at order 1 (its velocity is the
balance ``D v = τ − g(q)`` at a lagging q), and a swinging link gets Heun's error constant 1/6 instead
of the method's 0.040 (an undamped pendulum swinging from 1 rad, 1 s at 1 ms: 1.8e-6 rad with it,
6.7e-6 rad without; test_rosenbrock). If A is not positive definite with it (a load above its axis,
stiff enough to matter), the step drops the gravity part. A constant joint coupling ``q = G q_r + q₀``
(URDF mimic joints) is integrated in reduced coordinates with ``A_r = Gᵀ A G`` and right-hand side
``Gᵀ (M bv − γh K bq)`` (M, D and K assembled in the full coordinates, then reduced;
``arm.factor_stage_matrix``).

**Quaternion coordinates** (free roots, spherical joints): stage increments are nv-vectors in the
tangent space (the body angular velocity), applied by ``q ⊗ exp(h k_ω / 2)``
(``tree.retract_into``); the free root's position increment is its world-frame velocity
(``T = R(q)`` on the linear block). The dexp⁻¹ correction of Runge–Kutta–Munthe-Kaas methods is
dropped: its first term ``½ [h k1, k2]`` is O(h²) in a stage value, O(h³) in the step, which order
2 allows (measured in test_rosenbrock).
"""
from __future__ import annotations

import math

from .jit import njit

from .linalg import chol_solve, cholesky
from .tree import _JIT, _LEAF

#: γ of (R1)-(R3): the root of 2γ² − 4γ + 1 = 0 (L-stable) with the smaller error constant (see above)
GAMMA = 1.0 - 1.0 / math.sqrt(2.0)
#: the other root, R(z) > 0 on the negative real axis: the γ of a step with a joint stop in J or a ground
#: contact touching (see above)
GAMMA_STOP = 1.0 + 1.0 / math.sqrt(2.0)
#: weights of the stages in (R3), and the factor of k1 in (R2)
B1, B2, C21 = 1.5, 0.5, -2.0


@njit(**_LEAF)
def factor_iteration_matrix(H, Dm, Km, gh, A, L):
    """``A = H + γh Dm + (γh)² Km`` (R5) and its Cholesky factor into L; False if not positive definite.

    H (nv, nv) the mass matrix; Dm, Km (nv, nv) the passive damping and stiffness; gh = γh (s).
    """
    nv = H.shape[0]
    gh2 = gh * gh
    for i in range(nv):
        for j in range(i + 1):   # the lower triangle: cholesky reads no more
            A[i, j] = H[i, j] + gh * Dm[i, j] + gh2 * Km[i, j]
    return cholesky(A, nv, L)


@njit(**_LEAF)
def stage_rhs(Km, gh, force, bq, tmp):
    """tmp (nv,) = ``force − γh Km bq``, the right-hand side of (R6) in the full coordinates."""
    nv = tmp.shape[0]
    for i in range(nv):
        s = 0.0
        for j in range(nv):
            s += Km[i, j] * bq[j]
        tmp[i] = force[i] - gh * s


@njit(**_LEAF)
def stage_velocity(L, Km, gh, force, bq, kv, tmp):
    """kv (nv,) of (R6): ``A kv = force − γh Km bq`` with A = L Lᵀ; force = M bv (nv,), bq (nv,) the
    stage's tangent rate; tmp (nv,) scratch."""
    stage_rhs(Km, gh, force, bq, tmp)
    chol_solve(L, kv.shape[0], tmp, kv)


@njit(**_LEAF)
def mat_vec(H, x, out):
    """``out = H x`` for a dense H (n, n)."""
    n = H.shape[0]
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += H[i, j] * x[j]
        out[i] = s
