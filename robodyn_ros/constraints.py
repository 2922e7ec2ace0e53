"""Constrained dynamics: Lagrange multipliers (KKT), orthogonal complement, Baumgarte, projection.

Every formulation here solves the same problem. Unconstrained equations of motion in some
coordinates (minimal, or extended such as the free-flying seed's 26 coordinates)::

    M(q) a = Q(q, v, t) + Kᵀ λ                                   (1)

with ``m`` constraints on the acceleration, obtained by differentiating holonomic position
constraints ``φ(q, t) = 0`` twice or nonholonomic velocity constraints ``K(q) v = g(t)`` once::

    K a = k,     k = ġ − K̇ v   (− Baumgarte terms, eq. 4)            (2)

The sign convention makes ``Kᵀ λ`` the generalised constraint force (Huston's ``F' = Bᵀ λ``):
``λ`` is the reaction (force, torque) the constraint applies, not its negative.

**KKT / multiplier route.** Eliminating ``a`` from (1)–(2) with ``a_u = M⁻¹ Q`` (the
unconstrained acceleration) gives the Schur complement ("operational-space inertia inverse")::

    (K M⁻¹ Kᵀ) λ = k − K a_u,     a = a_u + M⁻¹ Kᵀ λ                  (3)

``M`` is symmetric positive definite (Cholesky); ``K M⁻¹ Kᵀ`` is only positive
*semi*-definite when constraints are redundant or the mechanism is singular (a stretched arm
under end-point constraints). It is therefore solved as a least-squares problem through its
eigen-decomposition, discarding eigenvalues below ``KKT_RCOND`` times the largest (named
tolerance, reported rank), or with Tikhonov damping ``(A + μ² I) λ = b`` (damped least
squares, Nakamura & Hanafusa 1986) when the caller asks for graceful degradation. This is
the solve RigidBodyDynamics.jl's ``dynamics_solve!`` performs, written out.

**Orthogonal complement (Huston §19.x, Walton–Steeves).** With ``C`` (n × (n−m)) spanning
the null space of ``B = K`` (``B C = 0``; columns = eigenvectors of the zero eigenvalues of
``BᵀB``), premultiplying (1) by ``Cᵀ`` removes ``λ``; stacking the constraint rows gives
the square reduced system::

    [Cᵀ A; B] a = [Cᵀ f; k]       (Huston's ``Q q'' = h``)
    λ = (B Bᵀ)⁻¹ B (A a − f)        (back-substitution)

**Baumgarte stabilisation** (J. Baumgarte, *Stabilization of constraints and integrals of
motion in dynamical systems*, Comput. Methods Appl. Mech. Eng. 1 (1972) 1–16): replace
``φ̈ = 0`` by ``φ̈ + 2 α φ̇ + β² φ = 0`` (and ``ė + α e = 0`` for a velocity-level error
``e = K v − g``), so drift decays instead of growing::

    k = ġ − K̇ v − 2 α φ̇ − β² φ                                        (4)

**Projection** (e.g. Bayo & Ledesma 1996, mass-orthogonal): after a step, move ``q`` by the
smallest ``M``-weighted correction onto ``φ = 0`` (Gauss–Newton) and ``v`` onto ``K v = g``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Relative eigenvalue threshold below which K M⁻¹ Kᵀ is treated as singular (rank-deficient).
KKT_RCOND = 1e-10
# Relative eigenvalue threshold of BᵀB that counts as zero when building the complement C.
NULLSPACE_TOL = 1e-10
# Default Baumgarte gains (1/s and 1/s): critically damped constraint error, time constant 0.05 s.
BAUMGARTE_ALPHA = 20.0
BAUMGARTE_BETA = 20.0


class ConstraintWarning(UserWarning):
    """Issued when a constraint matrix loses rank (redundant constraints, singular configuration)."""


@dataclass
class SolveInfo:
    """What a constrained solve found out about its constraint matrix.

    m: number of constraint rows; rank: numerical rank used; sigma_min, sigma_max: smallest and
    largest eigenvalue of the (scaled) Schur complement (or singular values of B); damping: the
    μ² used (0 = none); residual: ‖K a − k‖∞ after the solve.
    """

    m: int
    rank: int
    sigma_min: float
    sigma_max: float
    damping: float = 0.0
    residual: float = 0.0

    @property
    def rank_deficient(self) -> bool:
        """True when some constraint rows are redundant or singular."""
        return self.rank < self.m


def kkt_solve(M, Q, K, k, rcond=KKT_RCOND, damping=0.0):
    """Accelerations and multipliers of ``M a = Q + Kᵀ λ``, ``K a = k`` by eq. (3).

    M: (n, n) symmetric positive definite; Q: (n,) applied and velocity-product forces;
    K: (m, n) constraint Jacobian; k: (m,) acceleration-level right-hand side; rcond: relative
    eigenvalue cut-off of ``K M⁻¹ Kᵀ``; damping: μ² of damped least squares (0 = none).
    Returns ``(a (n,), λ (m,), SolveInfo)``. Redundant rows get the minimum-norm λ.
    """
    from scipy.linalg import cho_factor, cho_solve   # the numpy backend's solver, loaded when used
    n = M.shape[0]
    m = K.shape[0]
    c = cho_factor(M)
    a_u = cho_solve(c, Q)
    if m == 0:
        return a_u, np.zeros(0), SolveInfo(0, 0, np.inf, np.inf)
    MinvKt = cho_solve(c, K.T)
    A = K @ MinvKt
    A = 0.5 * (A + A.T)
    b = k - K @ a_u
    w, V = np.linalg.eigh(A)
    wmax = max(float(w[-1]), 0.0)
    if damping > 0.0:
        lam = V @ ((V.T @ b) / (w + damping))
        rank = int(np.sum(w > rcond * wmax)) if wmax > 0 else 0
    else:
        keep = w > rcond * wmax if wmax > 0 else np.zeros(m, dtype=bool)
        rank = int(keep.sum())
        lam = V[:, keep] @ ((V[:, keep].T @ b) / w[keep])
    a = a_u + MinvKt @ lam
    info = SolveInfo(m=m, rank=rank, sigma_min=float(max(w[0], 0.0)), sigma_max=wmax, damping=float(damping),
                     residual=float(np.abs(K @ a - k).max()))
    return a, lam, info


def null_space_basis(B, tol=NULLSPACE_TOL):
    """Orthonormal basis ``C`` (n, n − rank) of the null space of B (Walton–Steeves).

    B: (m, n) constraint matrix. The columns are the eigenvectors of ``BᵀB`` whose
    eigenvalues are at most ``tol`` times the largest, so ``B C ≈ 0``.
    Returns ``(C, rank)``.
    """
    n = B.shape[1]
    if B.shape[0] == 0:
        return np.eye(n), 0
    w, V = np.linalg.eigh(B.T @ B)
    wmax = max(float(w[-1]), 0.0)
    zero = w <= tol * wmax if wmax > 0 else np.ones(n, dtype=bool)
    return V[:, zero], int(n - zero.sum())


def complement_solve(A, f, B, k, tol=NULLSPACE_TOL):
    """Huston's orthogonal-complement route: reduced system ``[CᵀA; B] a = [Cᵀf; k]``, then λ.

    A: (n, n) mass matrix; f: (n,) applied forces; B: (m, n) constraint matrix; k: (m,)
    acceleration right-hand side (``g' − B' q'`` plus stabilisation). Returns
    ``(a, λ, SolveInfo)``; with rank-deficient B the redundant rows are dropped (least
    squares on the stacked system) and λ is the minimum-norm back-substitution.
    """
    C, rank = null_space_basis(B, tol)
    m = B.shape[0]
    Qr = np.vstack([C.T @ A, B])
    h = np.concatenate([C.T @ f, k])
    if rank == m:
        a = np.linalg.solve(Qr, h)
    else:
        a = np.linalg.lstsq(Qr, h, rcond=None)[0]
    BBt = B @ B.T
    lam = np.linalg.lstsq(BBt, B @ (A @ a - f), rcond=tol)[0]
    sv = np.linalg.svd(B, compute_uv=False) if m else np.zeros(0)
    info = SolveInfo(m=m, rank=rank, sigma_min=float(sv.min()) if m else np.inf,
                     sigma_max=float(sv.max()) if m else np.inf, residual=float(np.abs(B @ a - k).max()) if m else 0.0)
    return a, lam, info


def baumgarte_rhs(k, phi=None, phidot=None, alpha=BAUMGARTE_ALPHA, beta=BAUMGARTE_BETA):
    """Stabilised acceleration right-hand side, eq. (4): ``k − 2 α φ̇ − β² φ``.

    k: (m,) ``ġ − K̇ v``; phi: (m,) position-level violation (None for velocity-level
    constraints); phidot: (m,) velocity-level violation ``K v − g``; alpha, beta: gains (1/s).
    For velocity-level (nonholonomic) rows pass ``phi=None`` and the damping becomes ``α e``.
    """
    out = np.array(k, dtype=float)
    if phidot is not None:
        out -= (2.0 * alpha if phi is not None else alpha) * np.asarray(phidot)
    if phi is not None:
        out -= beta * beta * np.asarray(phi)
    return out


def project_velocities(M, K, v, g=None):
    """Smallest M-weighted change of v (n,) that satisfies ``K v = g`` (default 0).

    Returns the corrected velocity: ``v − M⁻¹Kᵀ (K M⁻¹ Kᵀ)⁺ (K v − g)``.
    """
    from scipy.linalg import cho_factor, cho_solve
    e = K @ v - (0.0 if g is None else g)
    c = cho_factor(M)
    MinvKt = cho_solve(c, K.T)
    dl = np.linalg.lstsq(K @ MinvKt, e, rcond=KKT_RCOND)[0]
    return v - MinvKt @ dl


def project_positions(M, phi_fn, K_fn, q, tol=1e-12, max_iter=10):
    """Gauss–Newton projection of q onto ``φ(q) = 0`` with M-weighted minimal corrections.

    M: (n, n) metric; phi_fn(q) -> (m,); K_fn(q) -> (m, n) = ∂φ/∂q; q: (n,) start.
    Returns ``(q, ‖φ‖∞, iterations)``.
    """
    from scipy.linalg import cho_factor, cho_solve
    c = cho_factor(M)
    q = np.array(q, dtype=float)
    for it in range(max_iter):
        phi = phi_fn(q)
        err = float(np.abs(phi).max()) if phi.size else 0.0
        if err <= tol:
            return q, err, it
        K = K_fn(q)
        MinvKt = cho_solve(c, K.T)
        q = q - MinvKt @ np.linalg.lstsq(K @ MinvKt, phi, rcond=KKT_RCOND)[0]
    phi = phi_fn(q)
    return q, float(np.abs(phi).max()) if phi.size else 0.0, max_iter
