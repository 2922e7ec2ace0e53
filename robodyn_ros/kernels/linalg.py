"""Small dense linear algebra for the constrained systems' kernels, compiled (numba).

**KKT solve** (:func:`kkt_solve`, eq. (3) of :mod:`robodyn_ros.constraints`): Cholesky of ``M``
(block-diagonal beyond its first ``nd`` rows, as in the augmented formulation, where the CoM
block is ``m_i 1``: the factor is then computed blockwise — the same numbers a dense factor
gives, since the off-diagonal entries are exact zeros), the Schur complement ``A = K M⁻¹ Kᵀ``
(skipping the zeros of the constraint rows), then the eigen-decomposition with the ``rcond``
cut-off of the reference. When the caller does not ask for the rank figures, a Cholesky factor
of ``A`` is tried first and used when it *certifies* that no eigenvalue would be cut:
``λ_min ≥ 1/tr(A⁻¹) > rcond · tr(A) ≥ rcond · λ_max`` (``tr(A⁻¹) = ‖L⁻¹‖_F²``). The
pseudo-inverse of the reference is then the inverse, so the multipliers are the same numbers
up to rounding, for a fraction of the cost of an eigen-decomposition.

**Small dense linear algebra without LAPACK.** The matrices here have a few rows (4 rolling
constraints, 3 table rows, 15 joint connections, a 2-row end-point constraint), where a call
into LAPACK costs more than the arithmetic and its numba bindings take seconds to compile.
Eigenproblems use cyclic Jacobi (:func:`sym_eig`), least squares on the symmetric positive
semi-definite Schur complements the eigen pseudo-inverse (:func:`pinv_solve`, what ``lstsq``
computes for such matrices), square systems LU with partial pivoting (:func:`lu_solve`), and
the singular values of the 2-row end-point Jacobian one-sided Jacobi (:func:`singular_values_2`).
All are backward stable like the reference's LAPACK routines; the tests compare to 1e-12.
"""
from __future__ import annotations

import math

import numpy as np
from .jit import njit

from .tree import _JIT, _LEAF


OK, SINGULAR = 0, 1
#: length of the ``info`` array of :func:`kkt_solve`: rank, sigma_min, sigma_max, residual
NINFO = 4

# ----------------------------------------------------------------------------------------------
# small dense linear algebra
# ----------------------------------------------------------------------------------------------


@njit(**_LEAF)
def flag(b):
    """``b`` as a plain (non-constant) bool. numba compiles a jitted callee once per *constant*
    argument it is called with; passing flags through this keeps a single compiled version of the
    large solvers below (and of ``tree.rnea_ws``), which matters for the first-run compile time."""
    return b != 0


@njit(**_LEAF)
def cholesky(A, nd, L):
    """Lower Cholesky factor of the symmetric positive definite A (n, n) into L; False if not PD.

    Rows and columns from ``nd`` on must be diagonal (A block-diagonal with a diagonal second
    block); only the first ``nd`` rows are factorised densely.
    """
    n = A.shape[0]
    for i in range(n):
        for j in range(n):
            L[i, j] = 0.0
    for j in range(nd):
        s = A[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > 0.0:
            return False
        d = math.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, nd):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / d
    for j in range(nd, n):
        if not A[j, j] > 0.0:
            return False
        L[j, j] = math.sqrt(A[j, j])
    return True


@njit(**_LEAF)
def chol_solve(L, nd, b, x):
    """Solve ``L Lᵀ x = b`` (L from :func:`cholesky` with the same nd)."""
    n = L.shape[0]
    for i in range(nd):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * x[k]
        x[i] = s / L[i, i]
    for i in range(nd - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, nd):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]
    for i in range(nd, n):
        x[i] = b[i] / L[i, i] / L[i, i] if b[i] != 0.0 else 0.0


EPS = float(np.finfo(np.float64).eps)
#: cyclic Jacobi sweeps before giving up (convergence is quadratic: 5–8 sweeps for the sizes here)
JACOBI_SWEEPS = 60


@njit(**_JIT)
def sym_eig(A, w, V):
    """Eigenvalues w (m,) and orthonormal eigenvectors V (m, m) (columns) of the symmetric A (m, m).

    Cyclic Jacobi (Golub & Van Loan, Algorithm 8.5.3, with the rotation of 8.5.1): plane rotations
    ``Jᵀ S J`` annihilate each off-diagonal entry in turn until none is above ``eps √|s_pp s_qq|``
    (Demmel–Veselić: the eigenvalues are then accurate to that relative level). Backward stable
    like LAPACK's ``syevd`` (the reference's ``numpy.linalg.eigh``) and, for the matrices of a few
    rows met here, cheaper than the call into LAPACK. Eigenvalues are not sorted.
    """
    m = A.shape[0]
    S = np.empty((m, m))
    for i in range(m):
        for j in range(m):
            S[i, j] = A[i, j]
            V[i, j] = 1.0 if i == j else 0.0
    for sweep in range(JACOBI_SWEEPS):
        rotated = False
        for p in range(m - 1):
            for q in range(p + 1, m):
                apq = S[p, q]
                app, aqq = S[p, p], S[q, q]
                if abs(apq) <= EPS * math.sqrt(abs(app * aqq)) or abs(apq) < 1e-300:
                    continue
                rotated = True
                tau = (aqq - app) / (2.0 * apq)
                if tau >= 0.0:
                    t = 1.0 / (tau + math.sqrt(1.0 + tau * tau))
                else:
                    t = -1.0 / (-tau + math.sqrt(1.0 + tau * tau))
                c = 1.0 / math.sqrt(1.0 + t * t)
                sn = t * c
                for k in range(m):
                    skp, skq = S[k, p], S[k, q]
                    S[k, p] = c * skp - sn * skq
                    S[k, q] = sn * skp + c * skq
                for k in range(m):
                    spk, sqk = S[p, k], S[q, k]
                    S[p, k] = c * spk - sn * sqk
                    S[q, k] = sn * spk + c * sqk
                S[p, q] = 0.0
                S[q, p] = 0.0
                for k in range(m):
                    vkp, vkq = V[k, p], V[k, q]
                    V[k, p] = c * vkp - sn * vkq
                    V[k, q] = sn * vkp + c * vkq
        if not rotated:
            break
    for i in range(m):
        w[i] = S[i, i]


@njit(**_JIT)
def pinv_solve(A, b, cut, x):
    """Minimum-norm least-squares solution x of ``A x = b`` for a symmetric positive semi-definite
    A (m, m): the eigen-decomposition with eigenvalues ``|λ| <= cut · max |λ|`` discarded (what
    ``numpy.linalg.lstsq(A, b, rcond=cut)`` computes for such A, whose singular values are |λ|).
    Returns the rank used."""
    m = A.shape[0]
    w = np.empty(m)
    V = np.empty((m, m))
    sym_eig(A, w, V)
    smax = 0.0
    for j in range(m):
        smax = max(smax, abs(w[j]))
    for i in range(m):
        x[i] = 0.0
    rank = 0
    for j in range(m):
        if smax > 0.0 and abs(w[j]) > cut * smax:
            rank += 1
            s = 0.0
            for i in range(m):
                s += V[i, j] * b[i]
            s /= w[j]
            for i in range(m):
                x[i] += V[i, j] * s
    return rank


@njit(**_JIT)
def lu_solve(A, b, x):
    """Solve the square system ``A x = b`` by Gaussian elimination with partial pivoting (the
    algorithm of LAPACK ``getrf``/``getrs``, the reference's ``numpy.linalg.solve``); A, b unchanged."""
    n = A.shape[0]
    U = A.copy()
    for i in range(n):
        x[i] = b[i]
    for k in range(n):
        piv = k
        for i in range(k + 1, n):
            if abs(U[i, k]) > abs(U[piv, k]):
                piv = i
        if piv != k:
            for j in range(n):
                U[k, j], U[piv, j] = U[piv, j], U[k, j]
            x[k], x[piv] = x[piv], x[k]
        for i in range(k + 1, n):
            f = U[i, k] / U[k, k]
            for j in range(k + 1, n):
                U[i, j] -= f * U[k, j]
            x[i] -= f * x[k]
    for i in range(n - 1, -1, -1):
        s = x[i]
        for j in range(i + 1, n):
            s -= U[i, j] * x[j]
        x[i] = s / U[i, i]


@njit(**_JIT)
def singular_values_2(B, sv):
    """Singular values ``sv[0] >= sv[1]`` of a 2-row matrix B (2, n): one-sided Jacobi (Hestenes)
    rotates the two rows until they are orthogonal; the singular values are then their norms, to
    high relative accuracy (as LAPACK's ``gesdd`` in the reference's ``numpy.linalg.svd``)."""
    n = B.shape[1]
    r0 = B[0].copy()
    r1 = B[1].copy()
    for sweep in range(8):
        a = 0.0
        b = 0.0
        c = 0.0
        for j in range(n):
            a += r0[j] * r0[j]
            b += r1[j] * r1[j]
            c += r0[j] * r1[j]
        if abs(c) <= EPS * math.sqrt(a * b) or c == 0.0:
            break
        tau = (b - a) / (2.0 * c)
        if tau >= 0.0:
            t = 1.0 / (tau + math.sqrt(1.0 + tau * tau))
        else:
            t = -1.0 / (-tau + math.sqrt(1.0 + tau * tau))
        cs = 1.0 / math.sqrt(1.0 + t * t)
        sn = t * cs
        for j in range(n):
            x0, x1 = r0[j], r1[j]
            r0[j] = cs * x0 - sn * x1
            r1[j] = sn * x0 + cs * x1
    s0 = 0.0
    s1 = 0.0
    for j in range(n):
        s0 += r0[j] * r0[j]
        s1 += r1[j] * r1[j]
    s0, s1 = math.sqrt(s0), math.sqrt(s1)
    sv[0] = max(s0, s1)
    sv[1] = min(s0, s1)


@njit(**_LEAF)
def chol_solve_cols(L, nd, X):
    """Solve ``L Lᵀ Y = X`` in place for every column of X (n, m): the operations of
    :func:`chol_solve` column by column, in the same order, with the columns updated together
    (row axpys that vectorise instead of one dependent chain per column)."""
    n, m = X.shape
    for i in range(nd):
        for c in range(i):
            lic = L[i, c]
            for j in range(m):
                X[i, j] -= lic * X[c, j]
        d = L[i, i]
        for j in range(m):
            X[i, j] /= d
    for i in range(nd - 1, -1, -1):
        for c in range(i + 1, nd):
            lci = L[c, i]
            for j in range(m):
                X[i, j] -= lci * X[c, j]
        d = L[i, i]
        for j in range(m):
            X[i, j] /= d
    for i in range(nd, n):
        d = L[i, i]
        for j in range(m):
            if X[i, j] != 0.0:
                X[i, j] = X[i, j] / d / d


@njit(**_JIT)
def trace_inverse(L):
    """``tr(A⁻¹) = ‖L⁻¹‖_F²`` for ``A = L Lᵀ``: the columns of L⁻¹ by column-oriented forward
    substitution (axpy updates on the rows of Lᵀ, which vectorise)."""
    m = L.shape[0]
    LT = L.T.copy()
    dinv = np.empty(m)
    for c in range(m):
        dinv[c] = 1.0 / LT[c, c]
    x = np.empty(m)
    t = 0.0
    for j in range(m):
        for i in range(j, m):
            x[i] = 0.0
        x[j] = 1.0
        for c in range(j, m):
            xc = x[c] * dinv[c]
            t += xc * xc
            for i in range(c + 1, m):
                x[i] -= xc * LT[c, i]
    return t


@njit(**_JIT)
def all_finite(A):
    for x in A.ravel():
        if not math.isfinite(x):
            return False
    return True


@njit(**_JIT)
def kkt_solve(M, nd, Q, K, k, rcond, damping, exact_info, a, lam, info):
    """Accelerations a (n,) and multipliers lam (m,) of ``M a = Q + Kᵀ λ``, ``K a = k``.

    :func:`robodyn_ros.constraints.kkt_solve` (eq. (3)) with the same ``rcond`` cut-off and
    damped least squares (``damping`` = μ² > 0). nd: M's dense block (see :func:`cholesky`);
    exact_info: fill ``info = [rank, sigma_min, sigma_max, residual]`` from the
    eigen-decomposition (else the certified Cholesky shortcut of the module docstring may be
    taken and info holds ``[m, nan, nan, nan]``). Returns OK, or SINGULAR when M is not
    positive definite (a non-finite M gives non-finite results instead).
    """
    n = M.shape[0]
    m = K.shape[0]
    L = np.empty((n, n))
    if not cholesky(M, nd, L):
        if all_finite(M):
            return SINGULAR
        a[:] = np.nan
        lam[:] = np.nan
        return OK
    au = np.empty(n)
    chol_solve(L, nd, Q, au)
    if m == 0:
        a[:] = au
        info[0] = 0.0
        info[1] = np.inf
        info[2] = np.inf
        info[3] = 0.0
        return OK
    XT = K.T.copy()  # columns: M⁻¹ K_jᵀ
    chol_solve_cols(L, nd, XT)
    A = np.zeros((m, m))
    for i in range(m):  # A[i, :i+1] += K[i, c] X[:i+1, c] (rows of K are sparse in the augmented formulation)
        for c in range(n):
            kic = K[i, c]
            if kic != 0.0:
                for j in range(i + 1):
                    A[i, j] += kic * XT[c, j]
    for i in range(m):  # the lower triangle (the reference symmetrises K M⁻¹ Kᵀ; this computes one half)
        for j in range(i):
            A[j, i] = A[i, j]
    b = np.empty(m)
    for i in range(m):
        s = 0.0
        for c in range(n):
            s += K[i, c] * au[c]
        b[i] = k[i] - s
    solved = False
    if damping == 0.0 and not exact_info:
        LA = np.empty((m, m))
        if cholesky(A, m, LA):
            tinv = trace_inverse(LA)
            tr = 0.0
            for i in range(m):
                tr += A[i, i]
            if tinv > 0.0 and 1.0 / tinv > rcond * tr * (1.0 + 1e-8):  # margin for the rounding of the bound
                chol_solve(LA, m, b, lam)
                info[0] = m
                info[1] = np.nan
                info[2] = np.nan
                info[3] = np.nan
                solved = True
    if not solved:
        if not all_finite(A) or not all_finite(b):
            a[:] = np.nan
            lam[:] = np.nan
            return OK
        w = np.empty(m)
        V = np.empty((m, m))
        sym_eig(A, w, V)
        wmax = 0.0
        wmin = np.inf
        for j in range(m):
            wmax = max(wmax, w[j])
            wmin = min(wmin, w[j])
        rank = 0
        for i in range(m):
            lam[i] = 0.0
        for j in range(m):
            keep = wmax > 0.0 and w[j] > rcond * wmax
            if keep:
                rank += 1
            if damping > 0.0 or keep:
                s = 0.0
                for i in range(m):
                    s += V[i, j] * b[i]
                s /= (w[j] + damping) if damping > 0.0 else w[j]
                for i in range(m):
                    lam[i] += V[i, j] * s
        info[0] = rank
        info[1] = max(wmin, 0.0)
        info[2] = wmax
    for c in range(n):
        s = au[c]
        for j in range(m):
            s += XT[c, j] * lam[j]
        a[c] = s
    if exact_info:
        r = 0.0
        for i in range(m):
            s = 0.0
            for c in range(n):
                s += K[i, c] * a[c]
            r = max(r, abs(s - k[i]))
        info[3] = r
    return OK


@njit(**_JIT)
def project_velocities(M, nd, K, v, g, rcond):
    """``v − M⁻¹Kᵀ (K M⁻¹ Kᵀ)⁺ (K v − g)`` in place (:func:`robodyn_ros.constraints.project_velocities`,
    least squares with ``rcond``); returns OK or SINGULAR."""
    n = M.shape[0]
    m = K.shape[0]
    L = np.empty((n, n))
    if not cholesky(M, nd, L):
        return SINGULAR if all_finite(M) else OK
    XT = K.T.copy()
    chol_solve_cols(L, nd, XT)
    A = np.zeros((m, m))
    e = np.empty(m)
    for i in range(m):
        s = 0.0
        for c in range(n):
            s += K[i, c] * v[c]
        e[i] = s - g[i]
        for c in range(n):
            kic = K[i, c]
            if kic != 0.0:
                for j in range(m):
                    A[i, j] += kic * XT[c, j]
    for i in range(m):
        for j in range(i):
            s = 0.5 * (A[i, j] + A[j, i])
            A[i, j] = s
            A[j, i] = s
    if not (all_finite(A) and all_finite(e)):
        v[:] = np.nan
        return OK
    dl = np.empty(m)
    pinv_solve(A, e, rcond, dl)
    for c in range(n):
        s = 0.0
        for j in range(m):
            s += XT[c, j] * dl[j]
        v[c] -= s
    return OK


@njit(**_LEAF)
def quat_to_R(q0, q1, q2, q3, R):
    """:func:`robodyn_ros.spatial.quat_to_R` of ``(x, y, z, w)`` into R (3, 3)."""
    x, y, z, w = q0, q1, q2, q3
    R[0, 0] = 1 - 2 * (y * y + z * z)
    R[0, 1] = 2 * (x * y - z * w)
    R[0, 2] = 2 * (x * z + y * w)
    R[1, 0] = 2 * (x * y + z * w)
    R[1, 1] = 1 - 2 * (x * x + z * z)
    R[1, 2] = 2 * (y * z - x * w)
    R[2, 0] = 2 * (x * z - y * w)
    R[2, 1] = 2 * (y * z + x * w)
    R[2, 2] = 1 - 2 * (x * x + y * y)


@njit(**_LEAF)
def cross(a, b, out):
    """``out = a × b`` (3-vectors; out must not alias a or b)."""
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]
