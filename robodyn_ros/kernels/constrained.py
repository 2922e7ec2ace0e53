"""Compiled right-hand sides of the constrained and floating-base systems, and their fused loop.

The reference implementations are the numpy methods of the system classes
(:mod:`robodyn_ros.systems.diffdrive`, ``freeflyer``, ``augmented``, ``prescribed``) and the
solvers of :mod:`robodyn_ros.constraints`; this module computes the same quantities with the same
algorithms in numba (tested equal to 1e-12 relative), so that a system can evaluate its
right-hand side in a few microseconds and run a whole publication period of fixed steps in one
call (:func:`integrate`), like the arm's :func:`robodyn_ros.kernels.tree.integrate_arm`.

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

**Compile units.** Each system kind has its own entry points (``evaluate_*``, ``project_*``,
``integrate_*``): the first run of a scene compiles only what its system uses. Flags are passed
to the large solvers through :func:`flag` (numba compiles a callee once per constant argument).
"""
from __future__ import annotations

import math

import numpy as np
from llvmlite import ir as llvm_ir
from numba import njit, types
from numba.extending import intrinsic

from ..model import FREE, PRISMATIC, REVOLUTE, SPHERICAL
from .tree import (_JIT, E_, M_RK4, M_SEMI_IMPLICIT_EULER, P_, R_, AX, HV, IB, JTYPE, MASS, PARENT, VIDX,
                   aba_fext_into, crba_into, crba_ws, energies, normalize_into, qdot_into, rnea_ws, transforms,
                   workspace)

DIFFDRIVE, FREEFLYER, AUGMENTED, PRESCRIBED = 1, 2, 3, 4
OK, SINGULAR = 0, 1
#: length of the ``info`` array of :func:`kkt_solve`: rank, sigma_min, sigma_max, residual
NINFO = 4

# ----------------------------------------------------------------------------------------------
# small dense linear algebra
# ----------------------------------------------------------------------------------------------


@intrinsic
def fma(typingctx, a, b, c):
    """``a * b + c`` rounded once (IEEE 754 fused multiply-add, ``llvm.fma.f64``: the instruction
    where the processor has it, else the C library's ``fma``; the same bits everywhere). A chain of
    them from +0.0 is how OpenBLAS's SkylakeX kernels (the ones this machine's OpenBLAS picks)
    compute numpy's ``@`` of small vectors; its Haswell, Zen and older kernels round the products
    separately (test_compiled_systems checks both, with ``OPENBLAS_CORETYPE``)."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        d = llvm_ir.DoubleType()
        fn = builder.module.declare_intrinsic('llvm.fma', [d], llvm_ir.FunctionType(d, [d, d, d]))
        return builder.call(fn, args)
    return sig, codegen


@njit(**_JIT)
def flag(b):
    """``b`` as a plain (non-constant) bool. numba compiles a jitted callee once per *constant*
    argument it is called with; passing flags through this keeps a single compiled version of the
    large solvers below (and of ``tree.rnea_ws``), which matters for the first-run compile time."""
    return b != 0


@njit(**_JIT)
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


@njit(**_JIT)
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


_EPS = float(np.finfo(np.float64).eps)
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
                if abs(apq) <= _EPS * math.sqrt(abs(app * aqq)) or abs(apq) < 1e-300:
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
        if abs(c) <= _EPS * math.sqrt(a * b) or c == 0.0:
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


@njit(**_JIT)
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
def _all_finite(A):
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
        if _all_finite(M):
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
        if not _all_finite(A) or not _all_finite(b):
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
        return SINGULAR if _all_finite(M) else OK
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
    if not (_all_finite(A) and _all_finite(e)):
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


@njit(**_JIT)
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


@njit(**_JIT)
def cross(a, b, out):
    """``out = a × b`` (3-vectors; out must not alias a or b)."""
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


@njit(**_JIT)
def body_frames(mi, mf, q, W, R, p):
    """World orientation R (nb, 3, 3) and origin p (nb, 3) of every body (``dynamics.body_poses``);
    W must hold the transforms (:func:`robodyn_ros.kernels.tree.transforms`)."""
    nb = mi.shape[0]
    E0 = np.empty((nb, 9))
    for i in range(nb):
        par = mi[i, PARENT]
        if par < 0:
            for a in range(9):
                E0[i, a] = W[i, E_ + a]
            for a in range(3):
                p[i, a] = W[i, R_ + a]
        else:
            r0, r1, r2 = W[i, R_], W[i, R_ + 1], W[i, R_ + 2]
            for a in range(3):
                p[i, a] = p[par, a] + E0[par, a] * r0 + E0[par, 3 + a] * r1 + E0[par, 6 + a] * r2
                for b in range(3):
                    E0[i, 3 * a + b] = (W[i, E_ + 3 * a] * E0[par, b] + W[i, E_ + 3 * a + 1] * E0[par, 3 + b]
                                        + W[i, E_ + 3 * a + 2] * E0[par, 6 + b])
        for a in range(3):
            for b in range(3):
                R[i, a, b] = E0[i, 3 * b + a]


@njit(**_JIT)
def _xmot(W, i, src, dst):
    """``dst = X_i src`` for a motion vector (Xup_i in W): ``[E w; E (u − r × w)]``."""
    w0, w1, w2 = src[0], src[1], src[2]
    r0, r1, r2 = W[i, R_], W[i, R_ + 1], W[i, R_ + 2]
    u0 = src[3] - (r1 * w2 - r2 * w1)
    u1 = src[4] - (r2 * w0 - r0 * w2)
    u2 = src[5] - (r0 * w1 - r1 * w0)
    for a in range(3):
        e0, e1, e2 = W[i, E_ + 3 * a], W[i, E_ + 3 * a + 1], W[i, E_ + 3 * a + 2]
        dst[a] = e0 * w0 + e1 * w1 + e2 * w2
        dst[3 + a] = e0 * u0 + e1 * u1 + e2 * u2


@njit(**_JIT)
def _joint_motion(mi, mf, x, i, out):
    """``out = S_i x_i`` (6,) in body i coordinates."""
    jt = mi[i, JTYPE]
    s = mi[i, VIDX]
    for a in range(6):
        out[a] = 0.0
    if jt == REVOLUTE:
        for a in range(3):
            out[a] = mf[i, AX + a] * x[s]
    elif jt == PRISMATIC:
        for a in range(3):
            out[3 + a] = mf[i, AX + a] * x[s]
    elif jt == FREE:
        for a in range(6):
            out[a] = x[s + a]
    elif jt == SPHERICAL:
        for a in range(3):
            out[a] = x[s + a]


@njit(**_JIT)
def body_velocities(mi, mf, q, v, W, vb):
    """Body spatial velocities vb (nb, 6) ``[ω; v_O]`` in body coordinates (``dynamics.body_velocities``)."""
    vJ = np.empty(6)
    for i in range(mi.shape[0]):
        par = mi[i, PARENT]
        _joint_motion(mi, mf, v, i, vJ)
        if par < 0:
            for a in range(6):
                vb[i, a] = vJ[a]
        else:
            _xmot(W, i, vb[par], vb[i])
            for a in range(6):
                vb[i, a] += vJ[a]


@njit(**_JIT)
def momentum(mi, mf, q, v):
    """``(p (3,), L (3,), c (3,))``: linear momentum, angular momentum about the CoM and the CoM,
    world coordinates (``freeflyer.momentum_about_com`` of ``FreeFlyerSystem.body_coms``)."""
    nb = mi.shape[0]
    W, R, p = frames_ws(mi, mf, q)
    vb = np.empty((nb, 6))
    body_velocities(mi, mf, q, v, W, vb)
    ms = np.empty(nb)
    c = np.empty((nb, 3))
    cd = np.empty((nb, 3))
    Ls = np.empty((nb, 3))
    ci = np.empty(3)
    t = np.empty(3)
    Ic = np.empty((3, 3))
    for i in range(nb):
        m = mf[i, MASS]
        for a in range(3):
            for b in range(3):
                Ic[a, b] = mf[i, IB + 3 * a + b]
        if m <= 0.0:
            m = 0.0
            ci[:] = 0.0
        else:
            for a in range(3):
                ci[a] = mf[i, HV + a] / m
            # Ic = I_O − m c× c×ᵀ = I_O − m (|c|² 1 − c cᵀ)
            cc = ci[0] * ci[0] + ci[1] * ci[1] + ci[2] * ci[2]
            for a in range(3):
                for b in range(3):
                    Ic[a, b] -= m * ((cc if a == b else 0.0) - ci[a] * ci[b])
        ms[i] = m
        cross(vb[i, :3], ci, t)
        for a in range(3):
            t[a] += vb[i, 3 + a]
        for a in range(3):
            c[i, a] = p[i, a] + R[i, a, 0] * ci[0] + R[i, a, 1] * ci[1] + R[i, a, 2] * ci[2]
            cd[i, a] = R[i, a, 0] * t[0] + R[i, a, 1] * t[1] + R[i, a, 2] * t[2]
        for a in range(3):
            ci[a] = Ic[a, 0] * vb[i, 0] + Ic[a, 1] * vb[i, 1] + Ic[a, 2] * vb[i, 2]
        for a in range(3):
            Ls[i, a] = R[i, a, 0] * ci[0] + R[i, a, 1] * ci[1] + R[i, a, 2] * ci[2]
    mt = 0.0
    for i in range(nb):
        mt += ms[i]
    com = np.zeros(3)
    lin = np.zeros(3)
    ang = np.zeros(3)
    for i in range(nb):
        for a in range(3):
            com[a] += ms[i] * c[i, a]
            lin[a] += ms[i] * cd[i, a]
            ang[a] += Ls[i, a]
    for a in range(3):
        com[a] /= mt
    for i in range(nb):
        for a in range(3):
            ci[a] = c[i, a] - com[a]
        cross(ci, cd[i], t)
        for a in range(3):
            ang[a] += ms[i] * t[a]
    return lin, ang, com


@njit(**_JIT)
def frames_ws(mi, mf, q):
    """``(W, R (nb, 3, 3), p (nb, 3))``: a workspace holding the transforms at q, and the world
    poses of the body frames."""
    nb = mi.shape[0]
    W = workspace(nb)
    transforms(mi, mf, q, W)
    R = np.empty((nb, 3, 3))
    p = np.empty((nb, 3))
    body_frames(mi, mf, q, W, R, p)
    return W, R, p


@njit(**_JIT)
def poses(mi, mf, q):
    """``(R (nb, 3, 3), p (nb, 3))`` world poses of the body frames."""
    _, R, p = frames_ws(mi, mf, q)
    return R, p


# ----------------------------------------------------------------------------------------------
# differential drive (systems/diffdrive.py), alone or with an arm
#   ip: [nv, has_arm, cur_left, cur_right, has_effort]  (cur_*: index of the current state or -1)
#   fp: [r_w, r_c, alpha, m, S0, S1, J, Is_l, Is_r, rcond, motor left (8), motor right (8),
#        armature (nv), damping (nv)]; motor: [K, R, L, N, b, tau_c, omega_s, V_s]
#   u:  [V_left, V_right, B u_effort (nv)]
#   y = [q (nv), v (nv), currents]; q = [x, y, yaw, phi_l, phi_r, arm...]
# ----------------------------------------------------------------------------------------------
DD_NV, DD_HAS_ARM, DD_CUR, DD_HAS_EFFORT = 0, 1, 2, 4
DD_RW, DD_RC, DD_ALPHA, DD_M, DD_S, DD_J, DD_IS, DD_RCOND, DD_MOTOR = 0, 1, 2, 3, 4, 6, 7, 9, 10
MOT_K, MOT_R, MOT_L, MOT_N, MOT_B, MOT_TC, MOT_WS, MOT_VS, MOT_SIZE = 0, 1, 2, 3, 4, 5, 6, 7, 8
DD_ARMATURE = DD_MOTOR + 2 * MOT_SIZE
_IX, _IY, _ITH, _IL, _IR = 0, 1, 2, 3, 4


@njit(**_JIT)
def dd_electrical(ip, fp, u, y, el):
    """``el = [volts (2), currents (2), wheel torques (2)]`` (``DiffDriveSystem.electrical``)."""
    nv = ip[DD_NV]
    for k in range(2):
        o = DD_MOTOR + MOT_SIZE * k
        Vs = fp[o + MOT_VS]
        volts = min(max(u[k], -Vs), Vs)
        w = y[nv + _IL + k]
        Kt, Nn = fp[o + MOT_K], fp[o + MOT_N]
        cur = ip[DD_CUR + k]
        if cur >= 0:
            i = y[2 * nv + cur]
        else:
            i = (volts - Kt * Nn * w) / fp[o + MOT_R]
        wm = Nn * w
        fr = fp[o + MOT_B] * wm + fp[o + MOT_TC] * math.tanh(wm / fp[o + MOT_WS])
        el[k] = volts
        el[2 + k] = i
        el[4 + k] = Nn * (Kt * i - fr)


@njit(**_JIT)
def dd_constraints(fp, nv, q, v, K, kdv):
    """``K (4, nv)`` and ``K̇ v (4,)`` of the rolling constraints (D4)."""
    rw, rc = fp[DD_RW], fp[DD_RC]
    c, s = math.cos(q[_ITH]), math.sin(q[_ITH])
    for i in range(4):
        for j in range(nv):
            K[i, j] = 0.0
    K[0, _IX], K[0, _IY], K[0, _ITH], K[0, _IL] = c, s, -rc, -rw
    K[1, _IX], K[1, _IY] = -s, c
    K[2, _IX], K[2, _IY], K[2, _ITH], K[2, _IR] = c, s, rc, -rw
    K[3, _IX], K[3, _IY] = -s, c
    vf = c * v[_IX] + s * v[_IY]
    vy = -s * v[_IX] + c * v[_IY]
    w = v[_ITH]
    kdv[0] = w * vy
    kdv[1] = -w * vf
    kdv[2] = w * vy
    kdv[3] = -w * vf


@njit(**_JIT)
def dd_mass(ip, fp, mi_r, mf_r, q, v, M, h, bias):
    """``M`` (+ rotor inertia) and, if bias, ``h`` (``DiffDriveSystem.mass_and_bias``)."""
    nv = ip[DD_NV]
    if ip[DD_HAS_ARM] == 0:
        c, s = math.cos(q[_ITH]), math.sin(q[_ITH])
        S0, S1 = fp[DD_S], fp[DD_S + 1]
        for i in range(5):
            for j in range(5):
                M[i, j] = 0.0
        M[0, 0] = fp[DD_M]
        M[1, 1] = fp[DD_M]
        M[0, 2] = M[2, 0] = c * -S1 - s * S0
        M[1, 2] = M[2, 1] = s * -S1 + c * S0
        M[2, 2] = fp[DD_J]
        M[3, 3] = fp[DD_IS]
        M[4, 4] = fp[DD_IS + 1]
        if bias:
            w2 = -v[_ITH] ** 2
            h[0] = w2 * (c * S0 - s * S1)
            h[1] = w2 * (s * S0 + c * S1)
            for j in range(2, 5):
                h[j] = 0.0
        return
    for i in range(nv):
        for j in range(nv):
            M[i, j] = 0.0
    W = workspace(mi_r.shape[0])
    transforms(mi_r, mf_r, q, W)
    if bias:  # RNEA leaves the transforms in W for the CRBA
        rnea_ws(mi_r, mf_r, q, v, np.zeros(nv), W, flag(0), h, W)
    crba_ws(mi_r, mf_r, M, W)
    for i in range(nv):
        M[i, i] += fp[DD_ARMATURE + i]


@njit(**_JIT)
def dd_solve(ip, fp, mi_r, mf_r, u, y, exact_info, a, lam, info, el):
    """Constrained accelerations a and ground forces lam (4,) (``DiffDriveSystem.solve``); el
    receives the electrical quantities of :func:`dd_electrical`. Returns OK or SINGULAR."""
    nv = ip[DD_NV]
    q = y[:nv]
    v = y[nv:2 * nv]
    dd_electrical(ip, fp, u, y, el)
    M = np.empty((nv, nv))
    h = np.empty(nv)
    dd_mass(ip, fp, mi_r, mf_r, q, v, M, h, flag(1))
    K = np.empty((4, nv))
    kdv = np.empty(4)
    dd_constraints(fp, nv, q, v, K, kdv)
    alpha = fp[DD_ALPHA]
    k = np.empty(4)
    for i in range(4):
        s = 0.0
        for j in range(nv):
            s += K[i, j] * v[j]
        k[i] = -kdv[i] - alpha * s
    Q = np.empty(nv)
    for j in range(nv):
        Q[j] = -fp[DD_ARMATURE + nv + j] * v[j]
    Q[_IL] += el[4]
    Q[_IR] += el[5]
    if ip[DD_HAS_EFFORT]:
        for j in range(nv):
            Q[j] += u[2 + j]
    for j in range(nv):
        Q[j] -= h[j]
    return kkt_solve(M, nv, Q, K, k, fp[DD_RCOND], 0.0, exact_info, a, lam, info)


@njit(**_JIT)
def dd_evaluate(ip, fp, mi_r, mf_r, u, y, dz):
    """``dz = [q̇; v̇; di/dt; power]`` (``DiffDriveSystem.rhs`` and ``.input_power``)."""
    nv = ip[DD_NV]
    ny = y.shape[0]
    for x in y:
        if not math.isfinite(x):
            dz[:] = np.nan
            return OK
    el = np.empty(6)
    lam = np.empty(4)
    info = np.empty(NINFO)
    st = dd_solve(ip, fp, mi_r, mf_r, u, y, flag(0), dz[nv:2 * nv], lam, info, el)
    if st != OK:
        return st
    for j in range(nv):
        dz[j] = y[nv + j]
    P = 0.0
    for k in range(2):
        o = DD_MOTOR + MOT_SIZE * k
        volts, i, w = el[k], el[2 + k], y[nv + _IL + k]
        cur = ip[DD_CUR + k]
        Kt, Nn, Rr = fp[o + MOT_K], fp[o + MOT_N], fp[o + MOT_R]
        if cur >= 0:
            dz[2 * nv + cur] = (volts - Rr * i - Kt * Nn * w) / fp[o + MOT_L]
        wm = Nn * w
        fr = fp[o + MOT_B] * wm + fp[o + MOT_TC] * math.tanh(wm / fp[o + MOT_WS])
        P += volts * i - Rr * i * i - fr * (Nn * w)
    s = 0.0
    for j in range(nv):
        s += y[nv + j] * (-fp[DD_ARMATURE + nv + j] * y[nv + j])
    P += s
    if ip[DD_HAS_EFFORT]:
        s = 0.0
        for j in range(nv):
            s += y[nv + j] * u[2 + j]
        P += s
    dz[ny] = P
    return OK


#: entries of :func:`dd_report`'s output
DR_EL, DR_FRICTION, DR_RESIDUAL, DR_KINETIC, DR_POTENTIAL, DR_MAGNETIC, NDR = 0, 6, 8, 9, 10, 11, 12


@njit(**_JIT)
def dd_report(ip, fp, mi_r, mf_r, u, y, out):
    """What ``DiffDriveSystem.outputs`` reports besides the wrenches, into out (NDR,):
    electrical quantities (6, :func:`dd_electrical`), friction loss per motor (2), ``max |K v|``,
    kinetic (with rotor inertia), potential (arm) and magnetic energy."""
    nv = ip[DD_NV]
    q = y[:nv]
    v = y[nv:2 * nv]
    dd_electrical(ip, fp, u, y, out[DR_EL:DR_EL + 6])
    for k in range(2):
        o = DD_MOTOR + MOT_SIZE * k
        w = v[_IL + k]
        Nn = fp[o + MOT_N]
        wm = Nn * w
        fr = fp[o + MOT_B] * wm + fp[o + MOT_TC] * math.tanh(wm / fp[o + MOT_WS])
        out[DR_FRICTION + k] = fr * (Nn * w)
    K = np.empty((4, nv))
    kdv = np.empty(4)
    dd_constraints(fp, nv, q, v, K, kdv)
    r = 0.0
    for i in range(4):
        s = 0.0
        for j in range(nv):
            s += K[i, j] * v[j]
        r = max(r, abs(s))
    out[DR_RESIDUAL] = r
    M = np.empty((nv, nv))
    h = np.empty(nv)
    dd_mass(ip, fp, mi_r, mf_r, q, v, M, h, flag(0))
    kin = 0.0
    for i in range(nv):
        s = 0.0
        for j in range(nv):
            s += M[i, j] * v[j]
        kin += v[i] * s
    out[DR_KINETIC] = 0.5 * kin
    out[DR_POTENTIAL] = energies(mi_r, mf_r, q, v)[1] if ip[DD_HAS_ARM] else 0.0
    mag = 0.0
    for k in range(2):
        cur = ip[DD_CUR + k]
        if cur >= 0:
            mag += 0.5 * fp[DD_MOTOR + MOT_SIZE * k + MOT_L] * y[2 * nv + cur] ** 2
    out[DR_MAGNETIC] = mag


@njit(**_JIT)
def dd_project(ip, fp, mi_r, mf_r, y):
    """Mass-orthogonal projection of v onto ``K v = 0`` in place (``DiffDriveSystem.project``)."""
    nv = ip[DD_NV]
    q = y[:nv]
    v = y[nv:2 * nv]
    K = np.empty((4, nv))
    kdv = np.empty(4)
    dd_constraints(fp, nv, q, v, K, kdv)
    e = 0.0
    for i in range(4):
        s = 0.0
        for j in range(nv):
            s += K[i, j] * v[j]
        e = max(e, abs(s))
    if not e > 0.0:
        return OK
    M = np.empty((nv, nv))
    h = np.empty(nv)
    dd_mass(ip, fp, mi_r, mf_r, q, v, M, h, flag(0))
    return project_velocities(M, nv, K, v, np.zeros(4), fp[DD_RCOND])


#: blocks of :func:`dd_outputs`'s output after the joint states (3 n_pub: positions, velocities,
#: efforts): odometry (13: position, orientation x y z w, linear, angular), the report (NDR, as
#: :func:`dd_report`), then DO_NEXTRA diagnostics values in ``DiffDriveSystem.outputs``' order
#: [per motor: voltage, current, power, torque, friction loss; electrical power, copper loss,
#: voltage saturated (0/1), constraint residual, constraint rank], then, with wrenches, the
#: (2 + n_bodies, 6) wrenches (contacts, then the bodies given)
DO_ODOM, DO_NEXTRA = 13, 15


@njit(**_JIT)
def dd_contact_wrenches(fp, mi, mf, q, v, a, lam, bodies, wheels, f):
    """Contact and joint wrenches (``DiffDriveSystem.contact_wrenches``) into f (2 + len(bodies), 6):
    rows 0, 1 the left and right contacts ``[0, 0, 0, F_long, F_lat, 0]``, then the RNEA joint
    wrench (parent on child, child coordinates) of each body in ``bodies``, with the contact
    forces acting on the wheel bodies ``wheels`` (2,) as external forces.

    The force at a contact, ``F = F_long heading + F_lat left``, and ``r × F`` (r = contact point
    minus wheel centre) are taken to the wheel frame with ``Rᵀ x`` as a chain of fused
    multiply-adds from +0.0 (:func:`fma`; signed zeros included): numpy's ``R.T @ x`` as OpenBLAS's
    SkylakeX kernels compute it, which the compiled path called before issue 15, so the recordings
    made then keep their bytes. The numbers no longer depend on the BLAS; they equal the numpy
    method's (``dynamics`` poses and RNEA, not these kernels) to round-off (tested to 1e-11), not
    to the bit.
    """
    nb = mi.shape[0]
    W, R, p = frames_ws(mi, mf, q)
    th = q[_ITH]
    c, s = math.cos(th), math.sin(th)
    fext = np.zeros((nb, 6))
    F = np.empty(3)
    rxF = np.empty(3)
    r0, r1, r2 = 0.0, 0.0, -fp[DD_RW]
    for k in range(2):
        F_long, F_lat = lam[2 * k], lam[2 * k + 1]
        F[0] = F_long * c + F_lat * -s
        F[1] = F_long * s + F_lat * c
        F[2] = F_long * 0.0 + F_lat * 0.0
        rxF[0] = r1 * F[2] - r2 * F[1]
        rxF[1] = r2 * F[0] - r0 * F[2]
        rxF[2] = r0 * F[1] - r1 * F[0]
        b = wheels[k]
        for j in range(3):
            fext[b, j] = fma(R[b, 2, j], rxF[2], fma(R[b, 1, j], rxF[1], fma(R[b, 0, j], rxF[0], 0.0)))
            fext[b, 3 + j] = fma(R[b, 2, j], F[2], fma(R[b, 1, j], F[1], fma(R[b, 0, j], F[0], 0.0)))
        for j in range(6):
            f[k, j] = 0.0
        f[k, 3] = F_long
        f[k, 4] = F_lat
    tau = np.empty(v.shape[0])
    rnea_ws(mi, mf, q, v, a, fext, True, tau, W)
    for n in range(bodies.shape[0]):
        for j in range(6):
            f[2 + n, j] = W[bodies[n], P_ + j]


@njit(**_JIT)
def dd_outputs(ip, fp, mi, mf, mi_r, mf_r, u, y, pub, wrenches, bodies, wheels, out):
    """Everything ``DiffDriveSystem.outputs`` publishes, in one call, into out (layout at
    :data:`DO_ODOM`): pub the published coordinates (wheels, then the arm joints); wrenches:
    also solve for the ground forces (:func:`dd_solve` with the exact rank) and compute the
    wrenches of :func:`dd_contact_wrenches` for ``bodies``. Returns OK or SINGULAR.

    The values are those the compiled path published before issue 15 (the kernels' report, then
    the numpy method's operations in its order; its two-term ``volts @ i`` as OpenBLAS's SkylakeX
    ddot computes it, an fma chain, see :func:`dd_contact_wrenches`): equal to the numpy method's
    to round-off, and independent of the BLAS.
    """
    nv = ip[DD_NV]
    npub = pub.shape[0]
    o = 3 * npub
    rep = out[o + DO_ODOM:o + DO_ODOM + NDR]
    dd_report(ip, fp, mi_r, mf_r, u, y, rep)
    for n in range(npub):
        out[n] = y[pub[n]]
        out[npub + n] = y[nv + pub[n]]
        out[2 * npub + n] = u[2 + pub[n]]
    out[2 * npub] = rep[DR_EL + 4]
    out[2 * npub + 1] = rep[DR_EL + 5]
    th = y[_ITH]
    c, s = math.cos(th), math.sin(th)
    vx, vy = y[nv + _IX], y[nv + _IY]
    od = out[o:o + DO_ODOM]
    od[0], od[1], od[2] = y[_IX], y[_IY], 0.0
    od[3], od[4], od[5], od[6] = 0.0, 0.0, math.sin(0.5 * th), math.cos(0.5 * th)
    od[7], od[8], od[9] = c * vx + s * vy, -s * vx + c * vy, 0.0
    od[10], od[11], od[12] = 0.0, 0.0, y[nv + _ITH]
    ex = out[o + DO_ODOM + NDR:o + DO_ODOM + NDR + DO_NEXTRA]
    volts, cur = rep[DR_EL:DR_EL + 2], rep[DR_EL + 2:DR_EL + 4]
    for k in range(2):
        ex[5 * k] = volts[k]
        ex[5 * k + 1] = cur[k]
        ex[5 * k + 2] = volts[k] * cur[k]
        ex[5 * k + 3] = rep[DR_EL + 4 + k]
        ex[5 * k + 4] = rep[DR_FRICTION + k]
    ex[10] = fma(volts[1], cur[1], fma(volts[0], cur[0], 0.0))
    R0, R1 = fp[DD_MOTOR + MOT_R], fp[DD_MOTOR + MOT_SIZE + MOT_R]
    ex[11] = R0 * cur[0] * cur[0] + R1 * cur[1] * cur[1]
    ex[12] = 1.0 if volts[0] != u[0] or volts[1] != u[1] else 0.0
    ex[13] = rep[DR_RESIDUAL]
    ex[14] = 0.0
    if not wrenches:
        return OK
    a = np.empty(nv)
    lam = np.empty(4)
    info = np.empty(NINFO)
    el = np.empty(6)
    st = dd_solve(ip, fp, mi_r, mf_r, u, y, flag(1), a, lam, info, el)
    if st != OK:
        return st
    ex[14] = info[0]
    w0 = o + DO_ODOM + NDR + DO_NEXTRA
    f = out[w0:w0 + 6 * (2 + bodies.shape[0])].reshape((2 + bodies.shape[0], 6))
    dd_contact_wrenches(fp, mi, mf, y[:nv], y[nv:2 * nv], a, lam, bodies, wheels, f)
    return OK


# ----------------------------------------------------------------------------------------------
# free-flying base, minimal coordinates (systems/freeflyer.py)
#   ip: [table, stabilisation (0 baumgarte, 1 projection, 2 none)]
#   fp: [alpha, beta, table height, rcond, damping (nv)]
#   u:  [B u_effort (nv), base wrench (6) = fx fy fz tx ty tz in base_link]
# ----------------------------------------------------------------------------------------------
FF_TABLE, FF_STAB = 0, 1
FF_ALPHA, FF_BETA, FF_HEIGHT, FF_RCOND, FF_DAMPING = 0, 1, 2, 3, 4
STAB_BAUMGARTE, STAB_PROJECTION, STAB_NONE = 0, 1, 2


@njit(**_JIT)
def ff_table(fp, nv, q, v, phi, K, k):
    """Table constraints in minimal coordinates: φ (3,), K (3, nv), k (3,) (``FreeFlyerSystem._table``
    with :func:`robodyn_ros.systems.freeflyer.table_rows` for s = 0)."""
    R = np.empty((3, 3))
    quat_to_R(q[3], q[4], q[5], q[6], R)
    n0, n1, n2 = R[0, 2], R[1, 2], R[2, 2]
    phi[0] = q[2] - fp[FF_HEIGHT]
    phi[1] = -n1
    phi[2] = n0
    for i in range(3):
        for j in range(nv):
            K[i, j] = 0.0
    for j in range(3):
        K[1, j] = n2 * R[0, j] - n0 * R[2, j]
        K[2, j] = n2 * R[1, j] - n1 * R[2, j]
        K[0, 3 + j] = R[2, j]
    w = v[0:3]
    wv = np.empty(3)
    cross(w, v[3:6], wv)
    k[0] = -(R[2, 0] * wv[0] + R[2, 1] * wv[1] + R[2, 2] * wv[2])
    ww = np.empty(3)
    for a in range(3):
        ww[a] = R[a, 0] * w[0] + R[a, 1] * w[1] + R[a, 2] * w[2]
    nn = np.empty(3)
    nn[0], nn[1], nn[2] = n0, n1, n2
    t1 = np.empty(3)
    t2 = np.empty(3)
    cross(ww, nn, t1)
    cross(ww, t1, t2)
    k[1] = t2[1]
    k[2] = -t2[0]


@njit(**_JIT)
def ff_solve(ip, fp, mi, mf, mi_r, mf_r, q, v, tau, fext, exact_info, a, lam, info):
    """Accelerations and table multipliers (``FreeFlyerSystem.solve``); lam has 3 or 0 entries."""
    nv = v.shape[0]
    if ip[FF_TABLE] == 0:
        aba_fext_into(mi, mf, q, v, tau, fext, a)
        info[0] = 0.0
        info[1] = np.inf
        info[2] = np.inf
        info[3] = 0.0
        return OK
    M = np.zeros((nv, nv))
    h = np.empty(nv)
    W = workspace(mi.shape[0])
    transforms(mi, mf, q, W)
    rnea_ws(mi, mf, q, v, np.zeros(nv), fext, flag(1), h, W)
    crba_ws(mi, mf, M, W)  # the transforms are still in W
    phi = np.empty(3)
    K = np.empty((3, nv))
    k = np.empty(3)
    ff_table(fp, nv, q, v, phi, K, k)
    two_alpha = 2.0 * fp[FF_ALPHA]
    b2 = fp[FF_BETA] * fp[FF_BETA]
    for i in range(3):
        s = 0.0
        for j in range(nv):
            s += K[i, j] * v[j]
        k[i] = k[i] - two_alpha * s - b2 * phi[i]
    rhs = np.empty(nv)
    for j in range(nv):
        rhs[j] = tau[j] - h[j]
    return kkt_solve(M, nv, rhs, K, k, fp[FF_RCOND], 0.0, exact_info, a, lam, info)


@njit(**_JIT)
def ff_forces(fp, u, v, tau, fext):
    """Joint-space forces ``B u − D v`` into tau and the base wrench as f_ext on body 0."""
    nv = v.shape[0]
    for j in range(nv):
        tau[j] = u[j] + (-fp[FF_DAMPING + j] * v[j])
    for i in range(fext.shape[0]):
        for a in range(6):
            fext[i, a] = 0.0
    for a in range(3):
        fext[0, a] = u[nv + 3 + a]
        fext[0, 3 + a] = u[nv + a]


@njit(**_JIT)
def ff_evaluate(ip, fp, mi, mf, mi_r, mf_r, u, nq, z, dz):
    """``dz = [q̇; v̇; power]`` (``FreeFlyerSystem.rhs`` and ``.input_power``)."""
    nv = z.shape[0] - 1 - nq
    q = z[:nq]
    v = z[nq:nq + nv]
    qdot_into(mi, q, v, dz[:nq])
    tau = np.empty(nv)
    fext = np.empty((mi.shape[0], 6))
    ff_forces(fp, u, v, tau, fext)
    lam = np.empty(3)
    info = np.empty(NINFO)
    st = ff_solve(ip, fp, mi, mf, mi_r, mf_r, q, v, tau, fext, flag(0), dz[nq:nq + nv], lam, info)
    P = 0.0
    for j in range(nv):
        P += v[j] * tau[j]
    P += v[0] * u[nv + 3] + v[1] * u[nv + 4] + v[2] * u[nv + 5]
    P += v[3] * u[nv] + v[4] * u[nv + 1] + v[5] * u[nv + 2]
    dz[nq + nv] = P
    return st


@njit(**_JIT)
def ff_project(ip, fp, mi, mf, mi_r, mf_r, nq, y):
    """Renormalise the quaternion; with projection on the table also q, v (``FreeFlyerSystem.project``)."""
    q = y[:nq]
    normalize_into(mi, q)
    if ip[FF_TABLE] == 0 or ip[FF_STAB] != STAB_PROJECTION:
        return OK
    nv = y.shape[0] - nq
    v = y[nq:]
    z, w = q[5], q[6]
    n = math.hypot(z, w)
    if n < 1e-12:
        q[3], q[4], q[5], q[6] = 0.0, 0.0, 0.0, 1.0
    else:
        q[3], q[4], q[5], q[6] = 0.0, 0.0, z / n, w / n
    q[2] = fp[FF_HEIGHT]
    M = np.zeros((nv, nv))
    crba_into(mi_r, mf_r, q, M)
    phi = np.empty(3)
    K = np.empty((3, nv))
    k = np.empty(3)
    ff_table(fp, nv, q, v, phi, K, k)
    return project_velocities(M, nv, K, v, np.zeros(3), fp[FF_RCOND])


# ----------------------------------------------------------------------------------------------
# free-flying base, augmented formulation (systems/augmented.py)
#   ip: [nb, nj, table, stabilisation, n_constraints, -, -, -, parent (nb), dof (nb)]
#   fp: [alpha, beta, table height, rcond, gravity (3), -, m (nb), com (3 nb), Ic (9 nb),
#        Etree (9 nb), r (3 nb), axis (3 nb), arm damping (nj)]
#   u:  [(B u_effort)[6:] (nj), base wrench (6)]
#   x = [quat (4), θ (nj), c (3 nb)], w = [ω (3), θ̇ (nj), ċ (3 nb)]
# ----------------------------------------------------------------------------------------------
AU_NB, AU_NJ, AU_TABLE, AU_STAB, AU_NC, AU_PARENT = 0, 1, 2, 3, 4, 8
AU_ALPHA, AU_BETA, AU_HEIGHT, AU_RCOND, AU_G, AU_M = 0, 1, 2, 3, 4, 8


@njit(**_JIT)
def au_offsets(nb):
    """fp offsets ``(com, Ic, Etree, r, axis, damping)`` of the augmented layout."""
    o_com = AU_M + nb
    o_ic = o_com + 3 * nb
    o_et = o_ic + 9 * nb
    o_r = o_et + 9 * nb
    o_ax = o_r + 3 * nb
    o_d = o_ax + 3 * nb
    return o_com, o_ic, o_et, o_r, o_ax, o_d


@njit(**_JIT)
def au_kinematics(ip, fp, x, w, R, E, om, J, beta):
    """Rotations R, E, angular velocities om, partial angular velocities J, β (``_kinematics``)."""
    nb, nj = ip[AU_NB], ip[AU_NJ]
    nr = 3 + nj
    o_com, o_ic, o_et, o_r, o_ax, o_d = au_offsets(nb)
    quat_to_R(x[0], x[1], x[2], x[3], R[0])
    for a in range(3):
        for b in range(3):
            E[0, a, b] = R[0, b, a]
        om[0, a] = w[a]
        beta[0, a] = 0.0
        for c in range(nr):
            J[0, a, c] = 1.0 if c == a else 0.0
    Rt = np.empty((3, 3))
    K0 = np.zeros((3, 3))
    t = np.empty(3)
    for i in range(1, nb):
        p = ip[AU_PARENT + i]
        k = ip[AU_PARENT + nb + i]
        ax0, ax1, ax2 = fp[o_ax + 3 * i], fp[o_ax + 3 * i + 1], fp[o_ax + 3 * i + 2]
        if k >= 0:
            # rot_axis(a, θ) = 1 + sin θ k× + (1 − cos θ) k× k×, then E = rot_axisᵀ Etree
            th = x[4 + k]
            s, c1 = math.sin(th), 1.0 - math.cos(th)
            K0[0, 1], K0[0, 2], K0[1, 0], K0[1, 2], K0[2, 0], K0[2, 1] = -ax2, ax1, ax2, -ax0, -ax1, ax0
            for a in range(3):
                for b in range(3):
                    kk = K0[a, 0] * K0[0, b] + K0[a, 1] * K0[1, b] + K0[a, 2] * K0[2, b]
                    Rt[b, a] = (1.0 if a == b else 0.0) + s * K0[a, b] + c1 * kk
            for a in range(3):
                for b in range(3):
                    E[i, a, b] = (Rt[a, 0] * fp[o_et + 9 * i + b] + Rt[a, 1] * fp[o_et + 9 * i + 3 + b]
                                  + Rt[a, 2] * fp[o_et + 9 * i + 6 + b])
        else:
            for a in range(3):
                for b in range(3):
                    E[i, a, b] = fp[o_et + 9 * i + 3 * a + b]
        for a in range(3):
            for b in range(3):
                R[i, a, b] = R[p, a, 0] * E[i, b, 0] + R[p, a, 1] * E[i, b, 1] + R[p, a, 2] * E[i, b, 2]
        for a in range(3):
            om[i, a] = E[i, a, 0] * om[p, 0] + E[i, a, 1] * om[p, 1] + E[i, a, 2] * om[p, 2]
            beta[i, a] = E[i, a, 0] * beta[p, 0] + E[i, a, 1] * beta[p, 1] + E[i, a, 2] * beta[p, 2]
            for c in range(nr):
                J[i, a, c] = E[i, a, 0] * J[p, 0, c] + E[i, a, 1] * J[p, 1, c] + E[i, a, 2] * J[p, 2, c]
        if k >= 0:
            thd = w[3 + k]
            at0, at1, at2 = ax0 * thd, ax1 * thd, ax2 * thd
            # β += (E ω_p) × (a θ̇) with E ω_p = om[i] before the joint rate is added
            t[0] = om[i, 1] * at2 - om[i, 2] * at1
            t[1] = om[i, 2] * at0 - om[i, 0] * at2
            t[2] = om[i, 0] * at1 - om[i, 1] * at0
            om[i, 0] += at0
            om[i, 1] += at1
            om[i, 2] += at2
            J[i, 0, 3 + k] += ax0
            J[i, 1, 3 + k] += ax1
            J[i, 2, 3 + k] += ax2
            for a in range(3):
                beta[i, a] += t[a]


@njit(**_JIT)
def _au_joint_end(R, om, J, beta, body, s, sign, nr, r0, Cq, Qd, Ms, acc, t1, t2):
    """One end (child: sign −1, parent: +1) of a joint's rows: ``sign R [s]× J`` into C_q and
    ``sign R (β × s + ω × (ω × s))`` into Q_d."""
    for a in range(3):
        Ms[a, 0] = R[body, a, 1] * s[2] - R[body, a, 2] * s[1]
        Ms[a, 1] = -R[body, a, 0] * s[2] + R[body, a, 2] * s[0]
        Ms[a, 2] = R[body, a, 0] * s[1] - R[body, a, 1] * s[0]
    for a in range(3):
        for c in range(nr):
            Cq[r0 + a, c] += sign * (Ms[a, 0] * J[body, 0, c] + Ms[a, 1] * J[body, 1, c] + Ms[a, 2] * J[body, 2, c])
    cross(beta[body], s, acc)
    cross(om[body], s, t1)
    cross(om[body], t1, t2)
    for a in range(3):
        acc[a] += t2[a]
    for a in range(3):
        Qd[r0 + a] += sign * (R[body, a, 0] * acc[0] + R[body, a, 1] * acc[1] + R[body, a, 2] * acc[2])


@njit(**_JIT)
def au_constraints(ip, fp, x, w, R, om, J, beta, C, Cq, Qd):
    """Joint-connection (and table) constraints ``C, C_q, Q_d`` (``AugmentedFreeFlyerSystem._constraints``)."""
    nb, nj = ip[AU_NB], ip[AU_NJ]
    nr = 3 + nj
    nv = nr + 3 * nb
    nc = ip[AU_NC]
    o_com, o_ic, o_et, o_r, o_ax, o_d = au_offsets(nb)
    co = 4 + nj  # c in x
    for i in range(nc):
        for j in range(nv):
            Cq[i, j] = 0.0
    sc = np.empty(3)
    sp = np.empty(3)
    Ms = np.empty((3, 3))
    t1 = np.empty(3)
    t2 = np.empty(3)
    acc = np.empty(3)
    for i in range(1, nb):
        p = ip[AU_PARENT + i]
        r0 = 3 * (i - 1)
        for a in range(3):
            sc[a] = -fp[o_com + 3 * i + a]
            sp[a] = fp[o_r + 3 * i + a] - fp[o_com + 3 * p + a]
        for a in range(3):
            C[r0 + a] = (x[co + 3 * i + a] + (R[i, a, 0] * sc[0] + R[i, a, 1] * sc[1] + R[i, a, 2] * sc[2])
                         - x[co + 3 * p + a] - (R[p, a, 0] * sp[0] + R[p, a, 1] * sp[1] + R[p, a, 2] * sp[2]))
            Cq[r0 + a, nr + 3 * i + a] = 1.0
            Cq[r0 + a, nr + 3 * p + a] = -1.0
        # C_q += −R_i [s_c]× J_i + R_p [s_p]× J_p;
        # Q_d = −(R_i (β_i × s_c + ω_i × (ω_i × s_c)) − R_p (β_p × s_p + ω_p × (ω_p × s_p)))
        for a in range(3):
            Qd[r0 + a] = 0.0
        _au_joint_end(R, om, J, beta, i, sc, -1.0, nr, r0, Cq, Qd, Ms, acc, t1, t2)
        _au_joint_end(R, om, J, beta, p, sp, 1.0, nr, r0, Cq, Qd, Ms, acc, t1, t2)
    if ip[AU_TABLE]:
        r0 = 3 * (nb - 1)
        for a in range(3):
            sc[a] = -fp[o_com + a]
        pb = np.empty(3)
        for a in range(3):
            pb[a] = x[co + a] + R[0, a, 0] * sc[0] + R[0, a, 1] * sc[1] + R[0, a, 2] * sc[2]
        n0, n1, n2 = R[0, 0, 2], R[0, 1, 2], R[0, 2, 2]
        C[r0] = pb[2] - fp[AU_HEIGHT]
        C[r0 + 1] = -n1
        C[r0 + 2] = n0
        # Kw[0] = −(R [s]×)[2], Kw[1:] = (−[e_z]× [n]× R)[:2], Kc[0, 2] = 1
        Cq[r0, 0] = -(R[0, 2, 1] * sc[2] - R[0, 2, 2] * sc[1])
        Cq[r0, 1] = -(-R[0, 2, 0] * sc[2] + R[0, 2, 2] * sc[0])
        Cq[r0, 2] = -(R[0, 2, 0] * sc[1] - R[0, 2, 1] * sc[0])
        for j in range(3):
            Cq[r0 + 1, j] = n2 * R[0, 0, j] - n0 * R[0, 2, j]
            Cq[r0 + 2, j] = n2 * R[0, 1, j] - n1 * R[0, 2, j]
        Cq[r0, nr + 2] = 1.0
        # k[0] = −(R (ω × (ω × s)))_z, k[1:] = −(e_z × (ω_w × (ω_w × n)))[:2]
        cross(om[0], sc, t1)
        cross(om[0], t1, t2)
        Qd[r0] = -(R[0, 2, 0] * t2[0] + R[0, 2, 1] * t2[1] + R[0, 2, 2] * t2[2])
        ww = np.empty(3)
        for a in range(3):
            ww[a] = R[0, a, 0] * om[0, 0] + R[0, a, 1] * om[0, 1] + R[0, a, 2] * om[0, 2]
        acc[0], acc[1], acc[2] = n0, n1, n2
        cross(ww, acc, t1)
        cross(ww, t1, t2)
        Qd[r0 + 1] = t2[1]
        Qd[r0 + 2] = -t2[0]


@njit(**_JIT)
def au_solve(ip, fp, u, y, exact_info, wd, lam, info, R, E, om, J, beta, C, Cq, M):
    """The augmented system at state y (``AugmentedFreeFlyerSystem.solve``): ẇ into wd, λ into lam,
    the kinematics into R, E, om, J, beta and C, C_q, M. Returns OK or SINGULAR."""
    nb, nj = ip[AU_NB], ip[AU_NJ]
    nr = 3 + nj
    nq = 4 + nj + 3 * nb
    nv = nr + 3 * nb
    nc = ip[AU_NC]
    x = y[:nq]
    w = y[nq:nq + nv]
    o_com, o_ic, o_et, o_r, o_ax, o_d = au_offsets(nb)
    au_kinematics(ip, fp, x, w, R, E, om, J, beta)
    for i in range(nv):
        for j in range(nv):
            M[i, j] = 0.0
    Q = np.zeros(nv)
    Ic = np.empty((3, 3))
    IJ = np.empty((3, nr))
    t = np.empty(3)
    Iw = np.empty(3)
    for i in range(nb):
        for a in range(3):
            for b in range(3):
                Ic[a, b] = fp[o_ic + 9 * i + 3 * a + b]
        for a in range(3):
            for c in range(nr):
                IJ[a, c] = Ic[a, 0] * J[i, 0, c] + Ic[a, 1] * J[i, 1, c] + Ic[a, 2] * J[i, 2, c]
        for r in range(nr):
            for c in range(nr):
                M[r, c] += J[i, 0, r] * IJ[0, c] + J[i, 1, r] * IJ[1, c] + J[i, 2, r] * IJ[2, c]
        for a in range(3):
            Iw[a] = Ic[a, 0] * om[i, 0] + Ic[a, 1] * om[i, 1] + Ic[a, 2] * om[i, 2]
        cross(om[i], Iw, t)
        for a in range(3):
            t[a] += Ic[a, 0] * beta[i, 0] + Ic[a, 1] * beta[i, 1] + Ic[a, 2] * beta[i, 2]
        for r in range(nr):
            Q[r] -= J[i, 0, r] * t[0] + J[i, 1, r] * t[1] + J[i, 2, r] * t[2]
        mi_ = fp[AU_M + i]
        for a in range(3):
            M[nr + 3 * i + a, nr + 3 * i + a] = mi_
            Q[nr + 3 * i + a] += mi_ * fp[AU_G + a]
    # thrusters: τ_c = τ_b − com_0 × f_b about the platform CoM, R_0 f_b on ċ_0
    fb = u[nj:nj + 3]
    c0 = np.empty(3)
    for a in range(3):
        c0[a] = fp[o_com + a]
    cross(c0, fb, t)
    for a in range(3):
        Q[a] += u[nj + 3 + a] - t[a]
    for a in range(3):
        Q[nr + a] += R[0, a, 0] * fb[0] + R[0, a, 1] * fb[1] + R[0, a, 2] * fb[2]
    for k in range(nj):
        Q[3 + k] += u[k] - fp[o_d + k] * w[3 + k]
    if nc == 0:
        return kkt_solve(M, nr, Q, Cq, np.zeros(0), fp[AU_RCOND], 0.0, exact_info, wd, lam, info)
    Qd = np.empty(nc)
    au_constraints(ip, fp, x, w, R, om, J, beta, C, Cq, Qd)
    two_alpha = 2.0 * fp[AU_ALPHA]
    b2 = fp[AU_BETA] * fp[AU_BETA]
    for i in range(nc):
        s = 0.0
        for j in range(nv):
            s += Cq[i, j] * w[j]
        Qd[i] = Qd[i] - two_alpha * s - b2 * C[i]
    return kkt_solve(M, nr, Q, Cq, Qd, fp[AU_RCOND], 0.0, exact_info, wd, lam, info)


@njit(**_JIT)
def au_config_rate(nq, nv, x, w, out):
    """``[½ quat ⊗ (ω, 0); θ̇; ċ]`` (``AugmentedFreeFlyerSystem.config_rate``)."""
    ax, ay, az, aw = x[0], x[1], x[2], x[3]
    bx, by, bz, bw = w[0], w[1], w[2], 0.0
    out[0] = 0.5 * (aw * bx + ax * bw + ay * bz - az * by)
    out[1] = 0.5 * (aw * by - ax * bz + ay * bw + az * bx)
    out[2] = 0.5 * (aw * bz + ax * by - ay * bx + az * bw)
    out[3] = 0.5 * (aw * bw - ax * bx - ay * by - az * bz)
    for j in range(4, nq):
        out[j] = w[j - 1]


@njit(**_JIT)
def au_evaluate(ip, fp, u, z, dz):
    """``dz = [ẋ; ẇ; power]`` (``AugmentedFreeFlyerSystem.rhs`` and ``.input_power``)."""
    nb, nj = ip[AU_NB], ip[AU_NJ]
    nr = 3 + nj
    nq = 4 + nj + 3 * nb
    nv = nr + 3 * nb
    nc = ip[AU_NC]
    x = z[:nq]
    w = z[nq:nq + nv]
    R = np.empty((nb, 3, 3))
    E = np.empty((nb, 3, 3))
    om = np.empty((nb, 3))
    J = np.empty((nb, 3, nr))
    beta = np.empty((nb, 3))
    C = np.empty(nc)
    Cq = np.empty((nc, nv))
    M = np.empty((nv, nv))
    lam = np.empty(nc)
    info = np.empty(NINFO)
    st = au_solve(ip, fp, u, z[:nq + nv], flag(0), dz[nq:nq + nv], lam, info, R, E, om, J, beta, C, Cq, M)
    au_config_rate(nq, nv, x, w, dz[:nq])
    # power: θ̇ · (τ_arm − D θ̇) + ω · τ_b + v_O · f_b, v_O = R_0ᵀ ċ_0 − ω × com_0
    o_com, o_ic, o_et, o_r, o_ax, o_d = au_offsets(nb)
    P = 0.0
    for k in range(nj):
        P += w[3 + k] * (u[k] - fp[o_d + k] * w[3 + k])
    P += w[0] * u[nj + 3] + w[1] * u[nj + 4] + w[2] * u[nj + 5]
    c0 = np.empty(3)
    t = np.empty(3)
    for a in range(3):
        c0[a] = fp[o_com + a]
    cross(w[0:3], c0, t)
    Rq = np.empty((3, 3))
    quat_to_R(x[0], x[1], x[2], x[3], Rq)
    for a in range(3):
        vo = Rq[0, a] * w[nr] + Rq[1, a] * w[nr + 1] + Rq[2, a] * w[nr + 2] - t[a]
        P += vo * u[nj + a]
    dz[nq + nv] = P
    return st


@njit(**_JIT)
def au_report(ip, fp, y, R, om, out):
    """Momentum and energies of the augmented state y (``AugmentedFreeFlyerSystem._momentum`` and
    ``._energies``) into out: ``[p (3), L about the CoM (3), CoM (3), kinetic, potential]``; R, om
    from :func:`au_kinematics`."""
    nb, nj = ip[AU_NB], ip[AU_NJ]
    nr = 3 + nj
    nq = 4 + nj + 3 * nb
    o_com, o_ic, o_et, o_r, o_ax, o_d = au_offsets(nb)
    co, cdo = 4 + nj, nq + nr
    mt = 0.0
    for i in range(nb):
        mt += fp[AU_M + i]
    for a in range(11):
        out[a] = 0.0
    Iw = np.empty(3)
    ke_t = 0.0
    ke_r = 0.0
    pe = 0.0
    for i in range(nb):
        m = fp[AU_M + i]
        for a in range(3):
            Iw[a] = (fp[o_ic + 9 * i + 3 * a] * om[i, 0] + fp[o_ic + 9 * i + 3 * a + 1] * om[i, 1]
                     + fp[o_ic + 9 * i + 3 * a + 2] * om[i, 2])
        for a in range(3):
            out[3 + a] += R[i, a, 0] * Iw[0] + R[i, a, 1] * Iw[1] + R[i, a, 2] * Iw[2]  # spin momenta
            out[a] += m * y[cdo + 3 * i + a]
            out[6 + a] += m * y[co + 3 * i + a]
        ke_t += m * (y[cdo + 3 * i] ** 2 + y[cdo + 3 * i + 1] ** 2 + y[cdo + 3 * i + 2] ** 2)
        ke_r += om[i, 0] * Iw[0] + om[i, 1] * Iw[1] + om[i, 2] * Iw[2]
        pe += m * (y[co + 3 * i] * fp[AU_G] + y[co + 3 * i + 1] * fp[AU_G + 1] + y[co + 3 * i + 2] * fp[AU_G + 2])
    for a in range(3):
        out[6 + a] /= mt
    for i in range(nb):  # + Σ m_i (c_i − c) × ċ_i
        m = fp[AU_M + i]
        r0 = y[co + 3 * i] - out[6]
        r1 = y[co + 3 * i + 1] - out[7]
        r2 = y[co + 3 * i + 2] - out[8]
        d0, d1, d2 = y[cdo + 3 * i], y[cdo + 3 * i + 1], y[cdo + 3 * i + 2]
        out[3] += m * (r1 * d2 - r2 * d1)
        out[4] += m * (r2 * d0 - r0 * d2)
        out[5] += m * (r0 * d1 - r1 * d0)
    out[9] = 0.5 * ke_t + 0.5 * ke_r
    out[10] = -pe


@njit(**_JIT)
def au_project(ip, y):
    """Renormalise the quaternion in place (the Baumgarte / unstabilised projection)."""
    n = math.sqrt(y[0] * y[0] + y[1] * y[1] + y[2] * y[2] + y[3] * y[3])
    for a in range(4):
        y[a] /= n
    return OK


# ----------------------------------------------------------------------------------------------
# prescribed end-point path (systems/prescribed.py)
#   ip: [body, formulation (0 complement, 1 kkt), path kind (0 circle, 1 line), has_effort]
#   fp: [alpha, beta, singular_ratio, dls_damping, rcond (KKT), nullspace tol, P (6, row major),
#        path (6): circle [cx, cy, radius, omega, phase, -] | line [x0, y0, x1, y1, duration, delay],
#        damping (nv)]
#   u:  [B u_effort (nv)]
# Solve record (PR_*): ratio, rank, damping, method (0 complement, 1 kkt, 2 kkt_damped), info (4)
# ----------------------------------------------------------------------------------------------
PR_BODY, PR_FORM, PR_PATH, PR_HAS_EFFORT = 0, 1, 2, 3
PF_ALPHA, PF_BETA, PF_SR, PF_DLS, PF_RCOND, PF_TOL, PF_P, PF_PATH, PF_DAMPING = 0, 1, 2, 3, 4, 5, 6, 12, 18
PATH_CIRCLE, PATH_LINE = 0, 1
METHOD_COMPLEMENT, METHOD_KKT, METHOD_KKT_DAMPED = 0, 1, 2
PS_RATIO, PS_RANK, PS_DAMPING, PS_METHOD, PS_INFO, NPS = 0, 1, 2, 3, 4, 8


@njit(**_JIT)
def path_eval(ip, fp, t, pd, vd, ad):
    """Position, velocity, acceleration (2,) of the prescribed path at t (``CirclePath``/``LinePath``)."""
    o = PF_PATH
    if ip[PR_PATH] == PATH_CIRCLE:
        r, w = fp[o + 2], fp[o + 3]
        th = fp[o + 4] + w * t
        c, s = math.cos(th), math.sin(th)
        rw = r * w
        rww = -r * w * w
        pd[0], pd[1] = fp[o] + r * c, fp[o + 1] + r * s
        vd[0], vd[1] = rw * -s, rw * c
        ad[0], ad[1] = rww * c, rww * s
    else:
        dur, delay = fp[o + 4], fp[o + 5]
        tau = min(max((t - delay) / dur, 0.0), 1.0)
        s = math.pow(tau, 3.0) * (10.0 - 15.0 * tau + 6.0 * tau * tau)
        ds = 30.0 * tau * tau * math.pow(1.0 - tau, 2.0) / dur
        dds = 60.0 * tau * (1.0 - tau) * (1.0 - 2.0 * tau) / math.pow(dur, 2.0)
        for a in range(2):
            d = fp[o + 2 + a] - fp[o + a]
            pd[a] = fp[o + a] + s * d
            vd[a] = ds * d
            ad[a] = dds * d


@njit(**_JIT)
def end_point_kinematics(mi, mf, q, v, body, E, J, Jdv, R):
    """World position E (3,), Jacobian J (3, nv), ``J̇ v`` (3,) and orientation R (3, 3) of a body's
    origin (:func:`robodyn_ros.systems.prescribed.end_point_kinematics`; 1-DOF joints)."""
    W = workspace(mi.shape[0])
    transforms(mi, mf, q, W)
    end_point_kinematics_ws(mi, mf, q, v, body, W, E, J, Jdv, R)


@njit(**_JIT)
def end_point_kinematics_ws(mi, mf, q, v, body, W, E, J, Jdv, R):
    """:func:`end_point_kinematics` with the transforms already in W (only their columns are read)."""
    nb = mi.shape[0]
    Rb = np.empty((nb, 3, 3))
    pb = np.empty((nb, 3))
    body_frames(mi, mf, q, W, Rb, pb)
    vb = np.empty((nb, 6))
    ab = np.empty((nb, 6))
    vJ = np.empty(6)
    for i in range(nb):
        par = mi[i, PARENT]
        _joint_motion(mi, mf, v, i, vJ)
        if par < 0:
            for a in range(6):
                vb[i, a] = vJ[a]
                ab[i, a] = 0.0
        else:
            _xmot(W, i, vb[par], vb[i])
            _xmot(W, i, ab[par], ab[i])
            for a in range(6):
                vb[i, a] += vJ[a]
            # + crm(v_i) vJ = [ω × vJ_ω; ω × vJ_v + v_v × vJ_ω]
            w0, w1, w2 = vb[i, 0], vb[i, 1], vb[i, 2]
            u0, u1, u2 = vb[i, 3], vb[i, 4], vb[i, 5]
            a0, a1, a2 = vJ[0], vJ[1], vJ[2]
            b0, b1, b2 = vJ[3], vJ[4], vJ[5]
            ab[i, 0] += w1 * a2 - w2 * a1
            ab[i, 1] += w2 * a0 - w0 * a2
            ab[i, 2] += w0 * a1 - w1 * a0
            ab[i, 3] += (w1 * b2 - w2 * b1) + (u1 * a2 - u2 * a1)
            ab[i, 4] += (w2 * b0 - w0 * b2) + (u2 * a0 - u0 * a2)
            ab[i, 5] += (w0 * b1 - w1 * b0) + (u0 * a1 - u1 * a0)
    for a in range(3):
        E[a] = pb[body, a]
        for b in range(3):
            R[a, b] = Rb[body, a, b]
    for a in range(3):
        for c in range(J.shape[1]):
            J[a, c] = 0.0
    d = np.empty(3)
    ra = np.empty(3)
    t = np.empty(3)
    i = body
    while i >= 0:
        jt = mi[i, JTYPE]
        if jt == REVOLUTE or jt == PRISMATIC:
            s0 = mi[i, VIDX]
            for a in range(3):
                ra[a] = Rb[i, a, 0] * mf[i, AX] + Rb[i, a, 1] * mf[i, AX + 1] + Rb[i, a, 2] * mf[i, AX + 2]
            if jt == PRISMATIC:
                for a in range(3):
                    J[a, s0] = ra[a]
            else:
                for a in range(3):
                    d[a] = E[a] - pb[i, a]
                cross(ra, d, t)
                for a in range(3):
                    J[a, s0] = t[a]
        i = mi[i, PARENT]
    for a in range(3):
        t[a] = ab[body, 3 + a]
    t[0] += vb[body, 1] * vb[body, 5] - vb[body, 2] * vb[body, 4]
    t[1] += vb[body, 2] * vb[body, 3] - vb[body, 0] * vb[body, 5]
    t[2] += vb[body, 0] * vb[body, 4] - vb[body, 1] * vb[body, 3]
    for a in range(3):
        Jdv[a] = R[a, 0] * t[0] + R[a, 1] * t[1] + R[a, 2] * t[2]


@njit(**_JIT)
def complement_solve(A, f, B, k, tol, a, lam, info):
    """Huston's orthogonal-complement route (:func:`robodyn_ros.constraints.complement_solve`).

    C = eigenvectors of the (relatively) zero eigenvalues of ``BᵀB``; ``[CᵀA; B] a = [Cᵀf; k]``
    (LU with partial pivoting when square, else the minimum-norm least-squares solution through
    the normal equations — the rank-deficient case, which the prescribed-path system never
    reaches: it switches to damped least squares first); ``λ = (BBᵀ)⁺ B (A a − f)`` with the
    ``tol`` cut-off; singular values of B (two rows) for the info.
    """
    n = A.shape[0]
    m = B.shape[0]
    BtB = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            s = 0.0
            for r in range(m):
                s += B[r, i] * B[r, j]
            BtB[i, j] = s
    w = np.empty(n)
    V = np.empty((n, n))
    sym_eig(BtB, w, V)
    wmax = 0.0
    for j in range(n):
        wmax = max(wmax, w[j])
    nz = 0
    for j in range(n):
        if not (wmax > 0.0) or w[j] <= tol * wmax:
            nz += 1
    rank = n - nz
    Qr = np.empty((nz + m, n))
    h = np.empty(nz + m)
    r = 0
    for j in range(n):
        if not (wmax > 0.0) or w[j] <= tol * wmax:
            for c in range(n):
                s = 0.0
                for e in range(n):
                    s += V[e, j] * A[e, c]
                Qr[r, c] = s
            s = 0.0
            for e in range(n):
                s += V[e, j] * f[e]
            h[r] = s
            r += 1
    for i in range(m):
        for c in range(n):
            Qr[nz + i, c] = B[i, c]
        h[nz + i] = k[i]
    if rank == m:
        lu_solve(Qr, h, a)
    else:
        N = np.empty((n, n))
        g = np.empty(n)
        for i in range(n):
            s = 0.0
            for e in range(nz + m):
                s += Qr[e, i] * h[e]
            g[i] = s
            for j in range(n):
                s = 0.0
                for e in range(nz + m):
                    s += Qr[e, i] * Qr[e, j]
                N[i, j] = s
        pinv_solve(N, g, _EPS * max(nz + m, n), a)
    BBt = np.empty((m, m))
    rhs = np.empty(m)
    res = np.empty(n)
    for c in range(n):
        s = 0.0
        for e in range(n):
            s += A[c, e] * a[e]
        res[c] = s - f[c]
    for i in range(m):
        s = 0.0
        for c in range(n):
            s += B[i, c] * res[c]
        rhs[i] = s
        for j in range(m):
            s = 0.0
            for c in range(n):
                s += B[i, c] * B[j, c]
            BBt[i, j] = s
    pinv_solve(BBt, rhs, tol, lam)
    sv = np.empty(2)
    singular_values_2(B, sv)
    info[0] = rank
    info[1] = sv[1]
    info[2] = sv[0]
    r2 = 0.0
    for i in range(m):
        s = 0.0
        for c in range(n):
            s += B[i, c] * a[c]
        r2 = max(r2, abs(s - k[i]))
    info[3] = r2


@njit(**_JIT)
def pr_solve(ip, fp, mi, mf, mi_r, mf_r, u, t, y, a, lam, Bm, phi, phidot, E, R, tau, rec):
    """The constrained accelerations and driving force at (t, y) (``PrescribedPathSystem.solve``).

    Fills a (n,), lam (2,), Bm (2, n), phi, phidot (2,), E (3,), R (3, 3), tau (n,) and the
    record rec (NPS,) (module layout). Returns OK or SINGULAR.
    """
    n = a.shape[0]
    q = y[:n]
    v = y[n:2 * n]
    for j in range(n):
        tau[j] = -fp[PF_DAMPING + j] * v[j]
    if ip[PR_HAS_EFFORT]:
        for j in range(n):
            tau[j] = tau[j] + u[j]
    W = workspace(mi.shape[0])  # one set of transforms (full tree) for RNEA, CRBA and the end point
    transforms(mi, mf, q, W)
    hb = np.empty(n)
    rnea_ws(mi, mf, q, v, np.zeros(n), W, flag(0), hb, W)
    A = np.zeros((n, n))
    crba_ws(mi, mf, A, W)
    f = np.empty(n)
    for j in range(n):
        f[j] = tau[j] - hb[j]
    J = np.empty((3, n))
    Jdv = np.empty(3)
    end_point_kinematics_ws(mi, mf, q, v, ip[PR_BODY], W, E, J, Jdv, R)
    pd = np.empty(2)
    vd = np.empty(2)
    ad = np.empty(2)
    path_eval(ip, fp, t, pd, vd, ad)
    k = np.empty(2)
    two_alpha = 2.0 * fp[PF_ALPHA]
    b2 = fp[PF_BETA] * fp[PF_BETA]
    for r in range(2):
        p0, p1, p2 = fp[PF_P + 3 * r], fp[PF_P + 3 * r + 1], fp[PF_P + 3 * r + 2]
        for c in range(n):
            Bm[r, c] = p0 * J[0, c] + p1 * J[1, c] + p2 * J[2, c]
        phi[r] = (p0 * E[0] + p1 * E[1] + p2 * E[2]) - pd[r]
        s = 0.0
        for c in range(n):
            s += Bm[r, c] * v[c]
        phidot[r] = s - vd[r]
        k[r] = ad[r] - (p0 * Jdv[0] + p1 * Jdv[1] + p2 * Jdv[2])
        k[r] = k[r] - two_alpha * phidot[r] - b2 * phi[r]
    sv = np.empty(2)
    singular_values_2(Bm, sv)
    sr = fp[PF_SR]
    ratio = sv[1] / sv[0] if sv[0] > 0.0 else 0.0
    rank = 0
    if sv[0] > 0.0:
        for s in sv:
            if s > sr * sv[0]:
                rank += 1
    damping = 0.0
    info = rec[PS_INFO:PS_INFO + NINFO]
    if ratio < sr:
        L = np.empty((n, n))
        if not cholesky(A, n, L):
            return SINGULAR if _all_finite(A) else OK
        X = np.empty((2, n))
        for r in range(2):
            chol_solve(L, n, Bm[r], X[r])
        S = np.empty((2, 2))
        for r in range(2):
            for c in range(2):
                acc = 0.0
                for e in range(n):
                    acc += Bm[r, e] * X[c, e]
                S[r, c] = acc
        # eigvalsh reads the lower triangle
        S[0, 1] = S[1, 0]
        ws = np.empty(2)
        Vs = np.empty((2, 2))
        sym_eig(S, ws, Vs)
        wmax = max(ws[0], ws[1])
        damping = fp[PF_DLS] * wmax * (1.0 - math.pow(ratio / sr, 2.0))
        st = kkt_solve(A, n, f, Bm, k, fp[PF_RCOND], damping, flag(1), a, lam, info)
        method = METHOD_KKT_DAMPED
    elif ip[PR_FORM] == METHOD_COMPLEMENT:
        complement_solve(A, f, Bm, k, fp[PF_TOL], a, lam, info)
        st = OK
        method = METHOD_COMPLEMENT
    else:
        st = kkt_solve(A, n, f, Bm, k, fp[PF_RCOND], 0.0, flag(1), a, lam, info)
        method = METHOD_KKT
    rec[PS_RATIO] = ratio
    rec[PS_RANK] = rank
    rec[PS_DAMPING] = damping
    rec[PS_METHOD] = method
    return st


@njit(**_JIT)
def pr_evaluate(ip, fp, mi, mf, mi_r, mf_r, u, t, z, dz, stat):
    """``dz = [q̇; q̈; power]`` (``PrescribedPathSystem.rhs`` and ``.input_power``); counts
    singular evaluations in stat ``[count, t of the first, its ratio, its damping]``."""
    n = (z.shape[0] - 1) // 2
    y = z[:2 * n]
    for x in y:
        if not math.isfinite(x):
            dz[:] = np.nan
            return OK
    lam = np.empty(2)
    Bm = np.empty((2, n))
    phi = np.empty(2)
    phidot = np.empty(2)
    E = np.empty(3)
    R = np.empty((3, 3))
    tau = np.empty(n)
    rec = np.empty(NPS)
    st = pr_solve(ip, fp, mi, mf, mi_r, mf_r, u, t, y, dz[n:2 * n], lam, Bm, phi, phidot, E, R, tau, rec)
    if rec[PS_RANK] < 2:
        if stat[0] == 0:
            stat[1] = t
            stat[2] = rec[PS_RATIO]
            stat[3] = rec[PS_DAMPING]
        stat[0] += 1
    P = 0.0
    for j in range(n):
        dz[j] = z[n + j]
        P += z[n + j] * tau[j]
    for r in range(2):
        s = 0.0
        for c in range(n):
            s += Bm[r, c] * z[n + c]
        P += lam[r] * s
    dz[2 * n] = P
    return st


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
        for s in range(4 if method == M_RK4 else 1):
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
