"""Prescribed end-effector motion (Huston, *Dynamics of Mechanical Systems*, §19.16–19.18).

An arm with free (unactuated, or partly actuated) joints whose end point E is *driven* along a
prescribed planar path ``E(t) = (x(t), y(t))`` — problems P19.16.1–P19.18.2: three pin-connected
rods in a horizontal plane, the extremity E moved on a line or a circle. Kane's equations of the
arm plus the driving force at E (Huston eqs. 19.17.15–16)::

    A(q) q'' = f(q, q', t) + Bᵀ λ            (19.17.15; f = applied − Coriolis/centrifugal − gravity)
    B(q) q'  = g(t)                          (19.17.16; B = P J_E, g = P Ė_des)

where ``J_E`` (3, n) is the Jacobian of E's world position, ``P`` (2, 3) picks the two world
axes of the plane of motion (``plane: xy`` → x, y), and ``λ`` (2,) are the components of the
driving force that acts on the end-effector link at E along those axes (``F' = Bᵀ λ``,
eq. 19.17.4). Differentiating the constraint once gives the acceleration rows
``B q'' = g' − B' q'`` (eq. 19.18.2).

Two routes solve the same equations (``formulation``), and they must agree:

* ``complement`` — Huston §19.18: the orthogonal complement ``C`` of B (columns = eigenvectors
  of the zero eigenvalues of ``BᵀB``, Walton–Steeves, eqs. 19.18.7–11), the reduced system
  ``Q q'' = h`` with ``Q = [CᵀA; B]``, ``h = [Cᵀf; g' − B'q']`` (19.18.3–5) and the
  back-substitution ``λ = (BBᵀ)⁻¹B(Aq'' − f)`` (19.18.12): :func:`constraints.complement_solve`.
* ``kkt`` — the multiplier (Schur-complement) route ``(B A⁻¹ Bᵀ) λ = k − B A⁻¹ f``:
  :func:`constraints.kkt_solve`.

**Drift.** The acceleration-level equations only keep ``φ̈ = 0``; the position error
``φ = P E(q) − E_des(t)`` and the velocity error ``φ̇ = B q' − g`` are stabilised with
Baumgarte's ``φ̈ + 2α φ̇ + β² φ = 0`` (named gains, :func:`constraints.baumgarte_rhs`). A
position projection in :meth:`System.project` is not possible because ``project(y)`` carries
no time and the constraint moves with t; :meth:`PrescribedPathSystem.initial_state` projects
the initial state onto ``φ = 0``, ``φ̇ = 0`` instead.

**Singular (stretched) configurations.** When the arm stretches, the columns of ``J_E`` line up
and B loses rank: E can no longer move along the arm, and the exact driving force needed to
keep it on a path that demands such motion grows without bound. The measure is the ratio of
B's singular values ``s = σ_min(B)/σ_max(B)`` (dimensionless for revolute arms). Below
``SINGULAR_RATIO`` the constraint counts as rank deficient: a :class:`ConstraintWarning` is
issued once per episode, ``outputs.extra`` reports ``constraint_rank`` < 2 and ``singular``,
and *both* formulations switch to the damped least-squares multiplier solve (Nakamura &
Hanafusa 1986, with the variable damping of Maciejewski & Klein 1988 / Chiaverini 1997)::

    (B A⁻¹ Bᵀ + μ² I) λ = k − B A⁻¹ f,    μ² = DLS_DAMPING · w_max · (1 − (s / SINGULAR_RATIO)²)

(``w_max`` = largest eigenvalue of ``B A⁻¹ Bᵀ``, so μ² is scale free and vanishes continuously
at the threshold). The equations of motion ``A q'' = f + Bᵀλ`` still hold exactly, so the
energy balance still closes; only the constraint becomes compliant (``B q'' = k − μ² λ``) and
the path is followed approximately, with the error reported.

**Energy.** The driving force does work: ``dE/dt = q'ᵀ(τ + Bᵀλ) = q'ᵀτ + λ·(B q')``, which
:meth:`input_power` returns so that the simulator's ``E − E₀ − W`` closes.

State ``y = [q (n), q' (n)]`` (joint coordinates, revolute/prismatic only); inputs: ``effort``
for the actuated joints if any (default none: the pins are free, as in P19.16.1).
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from .. import dynamics as dyn
from .. import kernels
from ..constraints import (BAUMGARTE_ALPHA, BAUMGARTE_BETA, KKT_RCOND, NULLSPACE_TOL, ConstraintWarning, SolveInfo,
                           baumgarte_rhs, complement_solve, kkt_solve, project_positions, project_velocities)
from ..model import Model
from ..spatial import crm
from .arm import ArmSystem
from .base import InputPort, SystemOutputs, compiled_fused_advance, keeps_methods

__all__ = ['PrescribedPathSystem', 'CirclePath', 'LinePath', 'PathError', 'PATH_KINDS', 'PLANES',
           'FORMULATIONS', 'SINGULAR_RATIO', 'DLS_DAMPING', 'INITIAL_PROJECTION_TOL', 'DRIVE_WRENCH',
           'end_point_kinematics']

#: σ_min(B)/σ_max(B) below which the end-point constraint counts as rank deficient (singular):
#: the warning fires, ``constraint_rank`` drops and damped least squares takes over.
SINGULAR_RATIO = 0.1
#: largest damped-least-squares μ², as a fraction of the largest eigenvalue of B A⁻¹ Bᵀ
#: (reached at s = 0; scaled by 1 − (s/SINGULAR_RATIO)² between).
DLS_DAMPING = 0.2
#: the initial configuration must reach the path start to this accuracy (m) after projection
INITIAL_PROJECTION_TOL = 1e-10
#: name of the driving-force wrench in ``outputs.wrenches`` (topic constraint_wrenches/<name>)
DRIVE_WRENCH = 'end_effector_drive'
#: the two routes of Huston §19.18 that :class:`PrescribedPathSystem` offers
FORMULATIONS = ('complement', 'kkt')
#: plane of motion -> the two world axes that x(t), y(t) are measured along (rows of P)
PLANES = {'xy': ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
          'xz': ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
          'yz': ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0))}


class PathError(ValueError):
    """An invalid path parameter: ``param`` names it, the message says why."""

    def __init__(self, param: str, reason: str):
        super().__init__(f'{param}: {reason}')
        self.param = param
        self.reason = reason


# --------------------------------------------------------------------------------------------
# prescribed paths: path(t) -> (position (2,), velocity (2,), acceleration (2,)) in plane axes
# --------------------------------------------------------------------------------------------
class CirclePath:
    """E on a circle at constant speed (P19.16.2): ``c + r [cos θ, sin θ]``, ``θ = phase + ω t``.

    center: (2,) m; radius: m (> 0); angular_velocity: ω rad/s (sign = direction); phase: rad.
    """

    kind = 'circle'

    def __init__(self, center, radius, angular_velocity, phase=0.0):
        self.center = np.asarray(center, dtype=float).reshape(2)
        if not radius > 0.0:
            raise PathError('radius', f'must be > 0, got {radius!r}')
        self.radius, self.omega, self.phase = float(radius), float(angular_velocity), float(phase)

    def __call__(self, t):
        th = self.phase + self.omega * t
        c, s = math.cos(th), math.sin(th)
        r, w = self.radius, self.omega
        return (self.center + r * np.array([c, s]), r * w * np.array([-s, c]),
                -r * w * w * np.array([c, s]))


class LinePath:
    """Rest-to-rest straight segment with the quintic (minimum-jerk) time law (P19.16.1).

    start, end: (2,) m; duration: s (> 0) of the move; delay: s at ``start`` before it begins.
    ``E = start + (end − start) σ(τ)``, ``σ = 10τ³ − 15τ⁴ + 6τ⁵``, ``τ = (t − delay)/duration``
    clipped to [0, 1]: zero velocity and acceleration at both ends, held at ``end`` afterwards.
    """

    kind = 'line'

    def __init__(self, start, end, duration, delay=0.0):
        self.start = np.asarray(start, dtype=float).reshape(2)
        self.end = np.asarray(end, dtype=float).reshape(2)
        if not duration > 0.0:
            raise PathError('duration', f'must be > 0, got {duration!r}')
        if not delay >= 0.0:
            raise PathError('delay', f'must be >= 0, got {delay!r}')
        self.duration, self.delay = float(duration), float(delay)

    def __call__(self, t):
        tau = min(max((t - self.delay) / self.duration, 0.0), 1.0)
        s = tau ** 3 * (10.0 - 15.0 * tau + 6.0 * tau * tau)
        ds = 30.0 * tau * tau * (1.0 - tau) ** 2 / self.duration
        dds = 60.0 * tau * (1.0 - tau) * (1.0 - 2.0 * tau) / self.duration ** 2
        d = self.end - self.start
        return self.start + s * d, ds * d, dds * d


#: path kind -> (class, required parameters, optional parameters); each parameter maps to its
#: size (0 = a scalar). The scene loader validates these and calls ``class(**params)``.
PATH_KINDS = {
    'circle': (CirclePath, {'center': 2, 'radius': 0, 'angular_velocity': 0}, {'phase': 0}),
    'line': (LinePath, {'start': 2, 'end': 2, 'duration': 0}, {'delay': 0}),
}


# --------------------------------------------------------------------------------------------
# kinematics of the end point
# --------------------------------------------------------------------------------------------
def _cross(a, b):
    """``a × b`` for two 3-vectors (np.cross costs ~20 µs of dispatch on tiny arrays)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _origin(X):
    """World position (3,) of the origin of a frame whose root->frame motion transform is X."""
    P = -X[:3, :3].T @ X[3:, :3]               # X = [E 0; -E r× E] => r× = -Eᵀ X[3:, :3]
    return np.array([P[2, 1], P[0, 2], P[1, 0]])


def end_point_kinematics(model: Model, q, v, body: int):
    """World position, Jacobian and velocity-product acceleration of body ``body``'s origin.

    model: the tree (1-DOF and fixed joints); q, v: (n,) state; body: index of the
    end-effector body (E = the origin of its frame). Returns ``(E (3,), J (3, n), Jdv (3,),
    R (3, 3))``: E in the root frame; ``J`` with ``Ė = J v``; ``Jdv = J̇ v`` (E's classical
    acceleration at ``v̇ = 0``, without gravity); R the body's world orientation.

    The column of joint j on the path to ``body`` is its world motion subspace moved to E:
    ``R_j s_v + (R_j s_ω) × (E − p_j)`` for ``S_j = [s_ω; s_v]`` in body-j coordinates (so
    ``ω × (E − p_j)`` for a revolute and ``R_j s_v`` for a prismatic joint). J̇v comes from a
    velocity-product forward pass (``a_i = Xup_i a_p + v_i ×ₘ S_i q'_i``, Featherstone Table 5.1
    with q̈ = 0) and the classical acceleration of the body-fixed point at the body origin,
    ``a'_v + ω × v_v``.
    """
    Xup, S = dyn.joint_transforms(model, q)
    nb = model.nb
    X0 = np.empty_like(Xup)
    vb = np.empty((nb, 6))
    ab = np.empty((nb, 6))
    for i in range(nb):
        s0, s1 = model.v_idx[i], model.v_idx[i] + model.nv_j[i]
        vJ = S[:, s0:s1] @ v[s0:s1]
        p = model.parent[i]
        if p < 0:
            X0[i], vb[i], ab[i] = Xup[i], vJ, 0.0
        else:
            X0[i] = Xup[i] @ X0[p]
            vb[i] = Xup[i] @ vb[p] + vJ
            ab[i] = Xup[i] @ ab[p] + crm(vb[i]) @ vJ
    R = X0[body][:3, :3].T
    E = _origin(X0[body])
    J = np.zeros((3, model.nv))
    i = body
    while i >= 0:
        s0 = model.v_idx[i]
        if model.nv_j[i] == 1:
            Ri = X0[i][:3, :3].T
            J[:, s0] = Ri @ S[3:, s0] + _cross(Ri @ S[:3, s0], E - _origin(X0[i]))
        elif model.nv_j[i] != 0:
            raise ValueError(f'{model.name}: end_point_kinematics handles 1-DOF joints only')
        i = model.parent[i]
    Jdv = R @ (ab[body][3:] + _cross(vb[body][:3], vb[body][3:]))
    return E, J, Jdv, R


# --------------------------------------------------------------------------------------------
# the system
# --------------------------------------------------------------------------------------------
@dataclass
class PathSolve:
    """One constrained solve at (t, y): accelerations, multipliers and what was found about B.

    a: (n,) q''; lam: (2,) driving force components along the plane axes (N); B: (2, n)
    constraint matrix; phi: (2,) position error P E − E_des (m); phidot: (2,) velocity error
    B q' − g (m/s); E: (3,) end point in the world; R: (3, 3) end-effector orientation;
    ratio: σ_min(B)/σ_max(B); rank: singular values of B above SINGULAR_RATIO·σ_max;
    damping: μ² used (0 = exact); method: 'complement' | 'kkt' | 'kkt_damped'; info: the
    solver's SolveInfo; tau: (n,) applied generalised forces (efforts minus joint damping).
    """

    a: np.ndarray
    lam: np.ndarray
    B: np.ndarray
    phi: np.ndarray
    phidot: np.ndarray
    E: np.ndarray
    R: np.ndarray
    ratio: float
    rank: int
    damping: float
    method: str
    info: SolveInfo
    tau: np.ndarray

    @property
    def singular(self) -> bool:
        """True when B counts as rank deficient (near a stretched configuration)."""
        return self.rank < self.B.shape[0]


class PrescribedPathSystem(ArmSystem):
    """An arm whose end point E is driven along a prescribed planar path (Huston §19.16–19.18).

    model: the kinematic tree (1-DOF joints only); end_effector: name of the link whose frame
    origin is E (typically a massless fixed ``tool`` link at the tip); path: a path object
    (``path(t) -> (p, ṗ, p̈)``, each (2,), in the plane axes); plane: a key of :data:`PLANES`
    (the two world axes of x(t), y(t)); formulation: 'complement' or 'kkt'; actuated: joints
    with an ``effort`` input (default none); alpha, beta: Baumgarte gains (1/s); singular_ratio,
    dls_damping: see :data:`SINGULAR_RATIO`, :data:`DLS_DAMPING`; backend: as
    :class:`~robodyn_ros.systems.arm.ArmSystem`; on a compiled backend, with a
    :class:`CirclePath` or :class:`LinePath`, the whole solve (end-point kinematics, SVD of B,
    either formulation) is :func:`robodyn_ros.kernels.prescribed.pr_solve` (equal to 1e-12)
    and :meth:`fused_advance` runs whole periods of fixed steps in one call.
    """

    _COMPILED_METHODS = ('rhs', 'input_power', 'solve', 'constraint', 'generalized_forces', 'mass_matrix',
                         'inverse_dynamics', 'project', 'config_rate')

    def rebuilt(self, backend, **changes):
        """The same system built again on another ``backend``; ``changes`` override its options
        (plane, formulation, actuated, alpha, beta, singular_ratio, dls_damping, path)."""
        kw = dict(path=self.path, plane=self.plane, formulation=self.formulation, actuated=self.actuated,
                  alpha=self.alpha, beta=self.beta, singular_ratio=self.singular_ratio,
                  dls_damping=self.dls_damping)
        kw.update(changes)
        return PrescribedPathSystem(self.model, self.end_effector, kw.pop('path'), backend=backend, **kw)

    def __init__(self, model: Model, end_effector: str, path, plane='xy', formulation='complement',
                 actuated=(), alpha=BAUMGARTE_ALPHA, beta=BAUMGARTE_BETA, singular_ratio=SINGULAR_RATIO,
                 dls_damping=DLS_DAMPING, backend=None):
        if model.nq != model.nv:
            raise ValueError(f'{model.name}: prescribed end-point motion needs an arm of 1-DOF joints '
                             '(no free joint)')
        from .base import resolve_backend
        backend = resolve_backend(backend)
        # the constrained solve runs on kernels.prescribed: nothing to specialise
        super().__init__(model, actuated=list(actuated), backend='numba' if backend in ('generated', 'auto') else backend)
        if not self.actuated:
            self.inputs = {}
        else:
            self.inputs = {'effort': InputPort('effort', len(self.actuated), tuple(self.actuated),
                                               self.inputs['effort'].unit)}
        self.body = model.body(end_effector)
        self.end_effector = end_effector
        if formulation not in FORMULATIONS:
            raise ValueError(f'formulation must be one of {FORMULATIONS}, got {formulation!r}')
        if plane not in PLANES:
            raise ValueError(f'plane must be one of {tuple(PLANES)}, got {plane!r}')
        self.path, self.plane, self.formulation = path, plane, formulation
        self.P = np.array(PLANES[plane])                 # (2, 3) world axes of x(t), y(t)
        self.alpha, self.beta = float(alpha), float(beta)
        self.singular_ratio, self.dls_damping = float(singular_ratio), float(dls_damping)
        self._cache = None
        self._cs = self._pack() if self._km is not None else None
        self.reset_episode()

    def _pack(self):
        """The packed system for :mod:`robodyn_ros.kernels.prescribed` (``PRESCRIBED``), or None
        for a path the kernels do not know."""
        path = self.path
        if type(path) is CirclePath:
            kind, pp = 0, [*path.center, path.radius, path.omega, path.phase, 0.0]
        elif type(path) is LinePath:
            kind, pp = 1, [*path.start, *path.end, path.duration, path.delay]
        else:
            return None
        ip = [self.body, FORMULATIONS.index(self.formulation), kind, int(bool(self.actuated))]
        fp = [self.alpha, self.beta, self.singular_ratio, self.dls_damping, KKT_RCOND, NULLSPACE_TOL,
              *self.P.reshape(-1), *pp, *self.model.damping.astype(float)]
        return kernels.CompiledSystem(kernels.fixed_step.PRESCRIBED, ip, fp, self.model, self.nq)

    def _compiled(self):
        """The packed system when the compiled path stands in for this object's methods, else None."""
        if self._cs is None or not keeps_methods(self, PrescribedPathSystem, self._COMPILED_METHODS):
            return None
        return self._cs

    def _u_vec(self, u):
        """``B u_effort`` (n,), zeros for a free arm."""
        return self.B @ u['effort'] if self.actuated else np.zeros(self.nv)

    def fused_advance(self, integrator_name, dt, t0, z0, t1, u):
        """Integrate ``z = [y, W]`` from t0 to t1 in one compiled call, or None to decline.

        The Simulator's fast path (see ``ArmSystem.fused_advance``) with the solve of
        :meth:`solve` at every stage; the singular-configuration warning and counter are
        updated from the compiled loop's count afterwards.
        """
        cs = self._compiled()
        if cs is None:
            return None
        cs.stat[:] = 0.0
        try:
            return compiled_fused_advance(cs, self._grids, integrator_name, dt, t0, z0, t1, self._u_vec(u),
                                          self.ny)
        finally:
            self._note_singular(int(cs.stat[0]), cs.stat[1], cs.stat[2], cs.stat[3])

    def _note_singular(self, count, t, ratio, damping):
        """Count singular evaluations; warn once per episode (the first one's time and figures)."""
        if not count:
            return
        self.singular_evaluations += count
        if not self.warned:
            self.warned = True
            warnings.warn(ConstraintWarning(
                f'{self.model.name}: the end-point constraint matrix B lost rank at t={t:.4f} s '
                f'(σ_min/σ_max = {ratio:.3g} < SINGULAR_RATIO = {self.singular_ratio}): the arm is '
                f'near its stretched (singular) configuration; using damped least squares '
                f'(μ² = {damping:.3g}), so E follows its path only approximately'), stacklevel=3)

    # -- episode bookkeeping ---------------------------------------------------------------
    def reset_episode(self):
        """Start a new episode: the rank warning may fire again, the singular counters restart."""
        self.warned = False
        self.singular_evaluations = 0

    def zero_inputs(self):
        """``{}`` for a free arm, zero efforts otherwise."""
        return {k: np.zeros(p.size) for k, p in self.inputs.items()}

    def generalized_forces(self, y, u):
        """Applied plus passive generalised forces ``S u − D v`` (n,) (no efforts on free joints)."""
        _, v = self.split(y)
        tau = dyn.passive_forces(self.model, v)
        if self.actuated:
            tau = tau + self.B @ u['effort']
        return tau

    # -- constraint ----------------------------------------------------------------------
    def constraint(self, t, q, v):
        """``(φ (2,), φ̇ (2,), B (2, n), k (2,), E (3,), R (3, 3))`` at time t.

        φ = P E(q) − E_des(t), φ̇ = B q' − Ė_des(t), and the un-stabilised acceleration
        right-hand side ``k = g' − B' q'`` (eq. 19.18.2).
        """
        E, J, Jdv, R = end_point_kinematics(self.model, q, v, self.body)
        pd, vd, ad = self.path(t)
        B = self.P @ J
        return self.P @ E - pd, B @ v - vd, B, ad - self.P @ Jdv, E, R

    def solve(self, t, y, u) -> PathSolve:
        """The constrained accelerations and driving force at (t, y) (cached for the last call)."""
        key = (float(t), y.tobytes(), tuple(np.asarray(x).tobytes() for x in u.values()))
        if self._cache is not None and self._cache[0] == key:
            return self._cache[1]
        cs = self._compiled()
        if cs is not None:
            sol = self._solve_compiled(cs, t, y, u)
            self._note_singular(int(sol.singular), t, sol.ratio, sol.damping)
            self._cache = (key, sol)
            return sol
        q, v = self.split(y)
        A = self.mass_matrix(q)
        tau = self.generalized_forces(y, u)
        f = tau - self.inverse_dynamics(q, v, np.zeros(self.nv))   # Huston's f + F: all but Bᵀλ
        phi, phidot, B, k, E, R = self.constraint(t, q, v)
        k = baumgarte_rhs(k, phi, phidot, self.alpha, self.beta)
        sv = np.linalg.svd(B, compute_uv=False)
        ratio = float(sv[-1] / sv[0]) if sv[0] > 0.0 else 0.0
        rank = int(np.sum(sv > self.singular_ratio * sv[0])) if sv[0] > 0.0 else 0
        damping = 0.0
        if ratio < self.singular_ratio:
            # damped least squares, μ² scaled by the Schur complement's size and by closeness to
            # the singularity (zero at the threshold, so the switch is continuous)
            from scipy.linalg import cho_factor, cho_solve   # numpy backend only
            W = cho_solve(cho_factor(A), B.T)
            wmax = float(np.linalg.eigvalsh(B @ W)[-1])
            damping = self.dls_damping * wmax * (1.0 - (ratio / self.singular_ratio) ** 2)
            a, lam, info = kkt_solve(A, f, B, k, damping=damping)
            method = 'kkt_damped'
        elif self.formulation == 'complement':
            a, lam, info = complement_solve(A, f, B, k)
            method = 'complement'
        else:
            a, lam, info = kkt_solve(A, f, B, k)
            method = 'kkt'
        # (a non-finite solve can only come from a non-finite state; the integrator reports it)
        sol = PathSolve(a=a, lam=lam, B=B, phi=phi, phidot=phidot, E=E, R=R, ratio=ratio, rank=rank,
                        damping=damping, method=method, info=info, tau=tau)
        self._note_singular(int(sol.singular), t, ratio, damping)
        self._cache = (key, sol)
        return sol

    def _solve_compiled(self, cs, t, y, u) -> PathSolve:
        """:meth:`solve` by :func:`robodyn_ros.kernels.prescribed.pr_solve`."""
        n = self.nv
        a, lam, B, phi, phidot = np.empty(n), np.empty(2), np.empty((2, n)), np.empty(2), np.empty(2)
        E, R, tau, rec = np.empty(3), np.empty((3, 3)), np.empty(n), np.empty(kernels.prescribed.NPS)
        mi, mf, mi_r, mf_r = cs.tree
        if kernels.prescribed.pr_solve(cs.ip, cs.fp, mi, mf, mi_r, mf_r, self._u_vec(u), float(t),
                                        np.ascontiguousarray(y, dtype=float), a, lam, B, phi, phidot, E, R, tau, rec):
            raise np.linalg.LinAlgError('mass matrix is not positive definite')
        c = kernels.prescribed
        info = rec[c.PS_INFO:c.PS_INFO + c.NINFO]
        method = ('complement', 'kkt', 'kkt_damped')[int(rec[c.PS_METHOD])]
        return PathSolve(a=a, lam=lam, B=B, phi=phi, phidot=phidot, E=E, R=R, ratio=float(rec[c.PS_RATIO]),
                         rank=int(rec[c.PS_RANK]), damping=float(rec[c.PS_DAMPING]), method=method,
                         info=SolveInfo(m=2, rank=int(info[0]), sigma_min=float(info[1]), sigma_max=float(info[2]),
                                        damping=float(rec[c.PS_DAMPING]), residual=float(info[3])),
                         tau=tau)

    def mass_matrix(self, q):
        """Huston's generalised mass array ``A(q)`` (n, n) (CRBA, on this system's backend)."""
        if self._km is not None:
            return self._km.crba(np.ascontiguousarray(q, dtype=float))
        return dyn.crba(self.model, q)

    # -- System interface ------------------------------------------------------------------
    def rhs(self, t, y, u):
        """``[q'; q'']`` with q'' from the chosen formulation."""
        _, v = self.split(y)
        return np.concatenate([v, self.solve(t, y, u).a])

    def drive_force(self, sol: PathSolve) -> np.ndarray:
        """The driving force on the end-effector link at E (3,) in world coordinates: ``Pᵀ λ``."""
        return self.P.T @ sol.lam

    def outputs(self, t, y, u, wrenches=True):
        """Joint states, the driving wrench at E, joint wrenches, energies and constraint figures.

        ``wrenches['end_effector_drive'] = (end_effector, [0, 0, 0, F])`` with F the driving
        force in the end-effector frame (applied at its origin E, so no moment); the joint
        wrenches come from RNEA at the constrained acceleration with the driving force as an
        external force on the end-effector link.
        """
        q, v = self.split(y)
        sol = self.solve(t, y, u)
        F = self.drive_force(sol)
        w = {}
        extra = {'constraint_residual': float(np.abs(sol.phi).max()),
                 'constraint_velocity_residual': float(np.abs(sol.phidot).max()),
                 'constraint_rank': sol.rank, 'singular': sol.singular,
                 'constraint_sigma_ratio': sol.ratio, 'dls_damping': sol.damping,
                 'formulation': self.formulation, 'solver': sol.method, 'solver_rank': sol.info.rank,
                 'drive_power': float(sol.lam @ (sol.B @ v))}
        if wrenches:
            f_ext = np.zeros((self.model.nb, 6))
            f_ext[self.body, 3:] = sol.R.T @ F
            if self._km is not None:
                tau_id, fj = self._km.rnea_wrenches(q, v, sol.a, f_ext)
            else:
                tau_id, fj = dyn.rnea_wrenches(self.model, q, v, sol.a, f_ext)
            for i in range(self.model.nb):
                w[self.model.joint_names[i]] = (self.model.link_names[i], fj[i].copy())
            w[DRIVE_WRENCH] = (self.end_effector, f_ext[self.body].copy())
            extra['joint_torque_residual'] = float(np.abs(tau_id - sol.tau).max())
        effort = self.B @ u['effort'] if self.actuated else np.zeros(self.nv)
        kin, pot = self._energies(q, v)
        return SystemOutputs(joint_names=list(self.joint_names), position=q.copy(), velocity=v.copy(),
                             effort=effort, wrenches=w, energy={'kinetic': kin, 'potential': pot},
                             extra=extra)

    def input_power(self, t, y, u):
        """``q'ᵀτ + λ·(B q')``: efforts minus joint damping plus the driving force's power (W)."""
        _, v = self.split(y)
        sol = self.solve(t, y, u)
        return float(v @ sol.tau + sol.lam @ (sol.B @ v))

    def fastest_time_constant(self, y):
        """The Baumgarte error dynamics' time constant ``1/max(α, β)`` (s) (its double pole at −β)."""
        g = max(self.alpha, self.beta)
        return 1.0 / g if g > 0.0 else float('inf')

    def initial_state(self, q0=None, v0=None, t0=0.0):
        """A consistent state at ``t0``: q0 projected onto φ = 0, v0 onto B v = g.

        q0: (n,) guess (default zeros) — it picks the redundant (self-motion) branch; the
        projection is the smallest A(q0)-weighted change (Gauss–Newton); v0: (n,) guess
        (default zeros), corrected by the smallest kinetic-energy change. Raises ValueError when
        E cannot reach the path start from q0 within :data:`INITIAL_PROJECTION_TOL`.
        """
        self.reset_episode()
        q = np.zeros(self.nq) if q0 is None else np.array(q0, dtype=float)
        v = np.zeros(self.nv) if v0 is None else np.array(v0, dtype=float)
        zeros = np.zeros(self.nv)
        pd, vd, _ = self.path(t0)

        def phi_fn(qq):
            return self.constraint(t0, qq, zeros)[0]

        def K_fn(qq):
            return self.constraint(t0, qq, zeros)[2]

        A = self.mass_matrix(q)
        q, err, _ = project_positions(A, phi_fn, K_fn, q, tol=0.1 * INITIAL_PROJECTION_TOL, max_iter=50)
        if not err <= INITIAL_PROJECTION_TOL:
            raise ValueError(f'{self.model.name}: the end point cannot be put on the path start '
                             f'{pd.tolist()} (t = {t0} s) from the initial configuration: residual '
                             f'{err:.3g} m (is the start inside the workspace?)')
        B = K_fn(q)
        v = project_velocities(self.mass_matrix(q), B, v, vd)
        return np.concatenate([q, v])
