"""Time integrators behind one interface: fixed step and error-controlled.

Every integrator advances a first-order system ``ydot = f(t, y)`` whose state ``y`` is a flat
float64 vector of shape (n,), from ``t0`` exactly to ``t1``::

    integ = make_integrator('rk4', dt=1e-3)
    y1, cost = integ.advance(f, t0, y0, t1, project=renormalise_quaternions)

* Fixed step (``euler``, ``semi_implicit_euler``, ``rk4``, ``rosenbrock2``): ``floor((t1 - t0)/dt)`` full steps
  and one final partial step when ``t1`` is not on the grid (round-off in ``t1 - t0`` is
  forgiven, so 1000 steps of 1e-3 reach 1.0 without a spurious extra step).  Step k starts at
  ``t0 + k*dt`` (no accumulated sum).  The step loop works in preallocated buffers.
* Linearly implicit (``rosenbrock2``): a Rosenbrock-W method of order 2 (ROS2, Verwer et al. 1999)
  for stiff *passive* forces: two evaluations of f and one linear solve with ``I − γhJ`` per step,
  J the passive part of ∂f/∂y (``jac``; J = 0 gives Heun's method), L-stable on it, explicit in
  the rest; order 2 whatever J is. The systems' compiled loops run it on the mass matrix
  (``M + γhD + γ²h²K``, :mod:`robodyn_ros.kernels.rosenbrock`, where the method, its stability and
  its cost are written out); :class:`Rosenbrock2` here is the generic form on ``ydot = f(t, y)``.
* Error-controlled (``rk45``, ``dop853``, ``radau``, ``bdf``, ``lsoda``): the scipy
  ``OdeSolver`` classes that ``scipy.integrate.solve_ivp`` drives, stepped here directly (the
  same loop as ``solve_ivp`` with ``dense_output=False`` and no events) so that the ``project``
  hook can act after every accepted step and the steps can be counted exactly.

Manifolds: ``project(y) -> y`` (e.g. renormalise a unit quaternion) is applied after every
accepted step; for ``bdf`` and ``lsoda``, whose multistep history cannot be projected
consistently, after the last step of each ``advance`` call (see ``IntegratorSpec.projection``).

Why the adaptive solver is restarted on every call instead of continued: the simulator holds
its commands constant over a call and changes them between calls, so ``f`` is discontinuous
at every call boundary.  A continued solver would reuse the derivative (FSAL stage, Radau's
``f``, BDF's difference table) of the *previous* right-hand side across the jump.  A restart
is the correct treatment of a discontinuity; it costs one evaluation of ``f`` (plus one
Jacobian for the implicit methods) per call.  The step size is not lost: the last step size
proposed by the error controller is passed as ``first_step`` to the next call (one-step
methods only: ``bdf`` and ``lsoda`` restart at order 1, where the step size of their previous
higher order would be too long; restarting also costs them accuracy, see
``IntegratorSpec.multistep``).

Rejected steps: for the explicit Runge-Kutta pairs every attempted step costs exactly
``n_stages`` evaluations of ``f`` (scipy's ``rk_step``: ``n_stages - 1`` stages plus the FSAL
evaluation at the new point), so the evaluations made inside one ``OdeSolver.step()`` call
give ``attempts = evals / n_stages`` and ``rejected = attempts - 1``, exactly.  For ``radau``,
``bdf`` and ``lsoda`` (Newton failures and error-test failures are not exposed by scipy) the
count is unknown and reported as ``None``.

Failure: a non-finite state, or an error-controlled solver that gives up (step size below
the spacing of floating-point numbers, Newton failure, ...) raises ``IntegrationError`` naming
the integrator, the time and the cause; a non-finite state is never returned. An
error-controlled call given ``max_steps`` raises ``StepBudgetError`` (an ``IntegrationError``)
instead of taking more accepted steps than that: a stiff system under an explicit pair would
otherwise creep on at its stability limit for hours (the Simulator's step budget).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Callable

import numpy as np

__all__ = [
    'INTEGRATORS',
    'AdaptiveIntegrator',
    'ClassicalRungeKutta4',
    'ExplicitEuler',
    'FixedStepIntegrator',
    'IntegrationError',
    'Integrator',
    'IntegratorSpec',
    'IntegratorStats',
    'Rosenbrock2',
    'SemiImplicitEuler',
    'StepBudgetError',
    'make_integrator',
]

Rhs = Callable[[float, np.ndarray], np.ndarray]
Projection = Callable[[np.ndarray], np.ndarray]

#: Defaults for the error-controlled integrators when the caller gives no tolerance.
DEFAULT_RTOL = 1e-6
DEFAULT_ATOL = 1e-9
_EPS = float(np.finfo(float).eps)
#: scipy raises ``rtol`` below this to it with a warning; we refuse it instead.
MIN_RTOL = 100.0 * _EPS
#: Round-off forgiven when deciding whether ``t1`` lies on the fixed-step grid, in units of
#: machine epsilon times the magnitude of the times involved.
GRID_ROUNDOFF_ULPS = 16.0


def step_start(t: float) -> float:
    """The time of a stage at the start of a step from t: ``GRID_ROUNDOFF_ULPS`` ulps after t, so that an input
    that jumps at t (a trajectory's knot on the step grid: a cubic's acceleration) is read as it acts over the
    step, from the right, even when round-off puts the grid point a few ulps before the knot."""
    return t + GRID_ROUNDOFF_ULPS * _EPS * abs(t)


def step_end(t: float, h: float) -> float:
    """The time of a stage at the end of the step from t of length h: ``GRID_ROUNDOFF_ULPS`` ulps before
    ``t + h``, so that an input jumping there enters the step from the left (as it acts over it). The compiled
    loops read the same sides with their stages at the grid times themselves (``kernels.servo``, ``OPT_SIDE``)."""
    te = t + h
    return te - GRID_ROUNDOFF_ULPS * _EPS * abs(te)


class IntegrationError(RuntimeError):
    """Raised when an integration cannot produce a finite state at the requested time.

    Args:
        integrator: registry name of the integrator that failed.
        t: simulation time (s) at which the failure was detected.
        cause: what went wrong, in words.
    """

    def __init__(self, integrator: str, t: float, cause: str):
        self.integrator = integrator
        self.t = t
        self.cause = cause
        super().__init__(f'{integrator}: integration failed at t={t:.12g} s: {cause}')


class StepBudgetError(IntegrationError):
    """An error-controlled call took the ``max_steps`` accepted steps it was allowed.

    Args:
        integrator: registry name; t: simulation time (s) reached; steps: accepted steps of the call.
    """

    def __init__(self, integrator: str, t: float, steps: int):
        self.steps = steps
        super().__init__(integrator, t, f'{steps} accepted steps, the most this call may take')


@dataclass
class IntegratorStats:
    """Cost counters of an integrator, additive over ``advance`` calls.

    Args:
        steps: accepted steps (fixed-step: every step, the partial one included).
        rejected_steps: steps rejected by the error controller; 0 for fixed-step methods,
            exact for the explicit Runge-Kutta pairs, ``None`` (unknown) for radau/bdf/lsoda.
        rhs_evals: calls of ``f``, counted by wrapping it; includes the evaluations that
            scipy spends on finite-difference Jacobians and on choosing the first step.
        njev: Jacobian evaluations (implicit methods).
        nlu: LU decompositions (implicit methods).
        advance_calls: number of ``advance`` calls.
        projections: calls of the ``project`` hook.
    """

    steps: int = 0
    rejected_steps: int | None = 0
    rhs_evals: int = 0
    njev: int = 0
    nlu: int = 0
    advance_calls: int = 0
    projections: int = 0

    def accumulate(self, other: IntegratorStats) -> None:
        """Add the counters of ``other`` to these, in place.

        Args:
            other: counters to add; an unknown ``rejected_steps`` makes the sum unknown.
        """
        self.steps += other.steps
        if self.rejected_steps is None or other.rejected_steps is None:
            self.rejected_steps = None
        else:
            self.rejected_steps += other.rejected_steps
        self.rhs_evals += other.rhs_evals
        self.njev += other.njev
        self.nlu += other.nlu
        self.advance_calls += other.advance_calls
        self.projections += other.projections

    def as_dict(self) -> dict:
        """Return the counters as a plain dict (for diagnostics and recording metadata)."""
        return asdict(self)

    @classmethod
    def of_fused_steps(cls, integrator_name: str, n_steps: int, advance_calls: int = 1) -> IntegratorStats:
        """The counters of ``n_steps`` steps of a fused compiled fixed-step loop (the systems'
        ``fused_advance``, the Simulator's block path): each step projected once, 4 evaluations of
        f per ``rk4`` step, 1 per ``euler`` / ``semi_implicit_euler`` step, 2 per ``rosenbrock2`` step
        with one Jacobian and one factorisation, as the Python loop counts."""
        evals = {'rk4': 4, 'rosenbrock2': 2}.get(integrator_name, 1)
        implicit = n_steps if integrator_name == 'rosenbrock2' else 0
        return cls(steps=n_steps, rhs_evals=evals * n_steps, njev=implicit, nlu=implicit,
                   advance_calls=advance_calls, projections=n_steps)


@dataclass(frozen=True)
class IntegratorSpec:
    """Registry entry: what an integrator is and how to build it.

    Args:
        name: registry name (lower case, as on the command line).
        kind: ``'fixed'`` (user picks ``dt``) or ``'adaptive'`` (user picks ``rtol``/``atol``).
        order: order of accuracy of the global error (for the variable-order multistep
            methods ``bdf`` and ``lsoda``: the highest order they use).
        symplectic: preserves the symplectic form of a Hamiltonian system in (q, v) split form.
        implicit: solves a system of equations per step: nonlinear (Newton with Jacobian and LU:
            radau, bdf, lsoda) or linear (rosenbrock2: one factorisation of I − γhJ).
        projection: ``'step'`` if ``project`` is applied after every accepted step,
            ``'call'`` if after the last step of each ``advance`` call only.
        multistep: variable-order multistep method (bdf, lsoda).  Restarted on every call,
            it starts again at order 1 with small steps, so its global error grows with the
            number of calls (about calls x tolerance); the step size is not carried over
            (it belonged to a higher order).  Prefer one-step methods for short calls.
        summary: one line for help texts.
        options: extra keyword arguments ``make_integrator`` accepts for it.
        factory: callable building the integrator from the validated arguments.
    """

    name: str
    kind: str
    order: int
    symplectic: bool
    implicit: bool
    projection: str
    multistep: bool
    summary: str
    options: tuple[str, ...] = ()
    factory: Callable[..., Integrator] = field(default=None, repr=False, compare=False)


class Integrator:
    """Common interface: ``advance(f, t0, y0, t1, project) -> (y1, stats_delta)``.

    Args:
        spec: the registry entry of this integrator.

    Attributes:
        stats: counters accumulated over every ``advance`` call since construction or
            ``reset()``.
    """

    def __init__(self, spec: IntegratorSpec):
        self.spec = spec
        self.name = spec.name
        self.stats = IntegratorStats()
        self._max_steps = None   # set per advance() call

    def reset(self) -> None:
        """Forget accumulated statistics and any step-size memory (e.g. after a scene reset)."""
        self.stats = IntegratorStats()

    def settings(self) -> dict:
        """Return the user-chosen settings, for recording metadata."""
        return {'integrator': self.name}

    def advance(self, f: Rhs, t0: float, y0, t1: float, project: Projection | None = None,
                max_steps: int | None = None) -> tuple[np.ndarray, IntegratorStats]:
        """Integrate ``ydot = f(t, y)`` from ``(t0, y0)`` to exactly ``t1``.

        Args:
            f: right-hand side ``f(t, y) -> ydot``, y and ydot of shape (n,).  It may be
                called with internal work arrays: it must not keep or modify its argument.
            t0: start time (s).
            y0: state at t0, shape (n,); not modified.
            t1: end time (s), ``t1 >= t0``.
            project: optional ``project(y) -> y`` mapping a state back onto the
                configuration manifold (e.g. normalising a quaternion), applied after every
                accepted step (see ``spec.projection``).  It may work in place (and then
                return y or None).
            max_steps: error-controlled integrators only: the most accepted steps this call
                may take (None: no limit); fixed-step ones take their grid's steps regardless.

        Returns:
            ``(y1, stats_delta)``: a new float64 array of shape (n,) holding the state at
            ``t1``, and the cost of this call (also added to ``self.stats``).

        Raises:
            IntegrationError: the state became non-finite or the solver failed
                (``StepBudgetError``: ``max_steps`` accepted steps did not reach ``t1``).
            ValueError: malformed times or state.
        """
        t0 = float(t0)
        t1 = float(t1)
        if not (math.isfinite(t0) and math.isfinite(t1)):
            raise ValueError(f'{self.name}: times must be finite, got t0={t0}, t1={t1}')
        if t1 < t0:
            raise ValueError(f'{self.name}: integrates forward only, got t1={t1!r} < t0={t0!r}')
        y = np.array(y0, dtype=np.float64)  # a copy: the caller's y0 is never touched
        if y.ndim != 1:
            raise ValueError(f'{self.name}: the state must be a flat vector, got shape {y.shape}')
        if not np.isfinite(y).all():
            raise IntegrationError(self.name, t0, 'initial state is non-finite at components '
                                   f'{_nonfinite_indices(y)}')
        delta = IntegratorStats(advance_calls=1)
        self._max_steps = max_steps
        try:
            if t1 > t0:
                y = self._advance(f, t0, y, t1, project, delta)
        finally:  # a failed call still cost something: count it
            self.stats.accumulate(delta)
        return y, delta

    def step_grids(self, t0, t1) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`step_grid` of many intervals at once: ``(n_full (K,) int64, h_last (K,))`` for
        arrays t0, t1 (K,), element by element the same float operations and numbers."""
        t0 = np.asarray(t0, dtype=float)
        t1 = np.asarray(t1, dtype=float)
        dt = self.dt
        ratio = (t1 - t0) / dt
        n_near = np.round(ratio)   # half to even, as round()
        tol = GRID_ROUNDOFF_ULPS * _EPS * (np.maximum(np.abs(t0), np.abs(t1)) / dt + ratio + 1.0)
        near = np.abs(ratio - n_near) <= tol
        n_full = np.where(near, n_near, np.floor(ratio)).astype(np.int64)
        h_last = t1 - (t0 + n_full * dt)
        return n_full, np.where(near | ~(h_last > 0.0), 0.0, h_last)

    def _advance(self, f, t0, y, t1, project, delta):  # pragma: no cover - abstract
        raise NotImplementedError


def _nonfinite_indices(y: np.ndarray, limit: int = 8) -> list[int]:
    """Return up to ``limit`` indices of non-finite entries of ``y``."""
    return np.flatnonzero(~np.isfinite(y))[:limit].tolist()


def _apply_projection(project: Projection, y: np.ndarray) -> np.ndarray:
    """Apply ``project`` to ``y``, returning an array of the same shape (may be ``y`` itself)."""
    p = project(y)
    if p is None:  # projected in place
        return y
    if p is not y:
        p = np.asarray(p, dtype=np.float64)
        if p.shape != y.shape:
            raise ValueError(f'project(y) returned shape {p.shape}, expected {y.shape}')
    return p


# ----------------------------------------------------------------------------------------
# Fixed step
# ----------------------------------------------------------------------------------------

class FixedStepIntegrator(Integrator):
    """Base of the fixed-step methods: step grid, projection, non-finite guard.

    Args:
        spec: registry entry.
        dt: step size h (s), > 0.

    Subclasses implement ``_step(f, t, y, h)`` updating ``y`` in place and returning the
    number of evaluations of ``f`` it made.
    """

    def __init__(self, spec: IntegratorSpec, dt: float):
        super().__init__(spec)
        self.dt = float(dt)
        self._n = -1  # state size the work buffers are allocated for

    def settings(self) -> dict:
        """Return the user-chosen settings, for recording metadata."""
        return {'integrator': self.name, 'dt': self.dt}

    def _allocate(self, n: int) -> None:
        """(Re)allocate the work buffers for a state of size n."""
        self._n = n
        self._finite = np.empty(n, dtype=bool)

    def step_grid(self, t0: float, t1: float) -> tuple[int, float]:
        """Return ``(n_full, h_last)``: full steps of ``dt`` and the final partial step.

        Args:
            t0: start time.
            t1: end time, ``t1 > t0``.

        ``t1 - t0`` within round-off (``GRID_ROUNDOFF_ULPS`` ulps of the largest time
        involved) of a multiple of ``dt`` counts as that multiple, with ``h_last = 0``.
        """
        dt = self.dt
        ratio = (t1 - t0) / dt
        n_near = round(ratio)
        tol = GRID_ROUNDOFF_ULPS * _EPS * (max(abs(t0), abs(t1)) / dt + ratio + 1.0)
        if abs(ratio - n_near) <= tol:
            return int(n_near), 0.0
        n_full = int(math.floor(ratio))
        h_last = t1 - (t0 + n_full * dt)
        return n_full, (h_last if h_last > 0.0 else 0.0)

    def _advance(self, f, t0, y, t1, project, delta):
        if y.shape[0] != self._n:
            self._allocate(y.shape[0])
        n_full, h_last = self.step_grid(t0, t1)
        dt = self.dt
        step = self._step
        isfinite = np.isfinite
        finite = self._finite
        nfev = 0
        n_steps = n_full + (1 if h_last > 0.0 else 0)
        for k in range(n_steps):
            t = t0 + k * dt
            h = dt if k < n_full else h_last
            nfev += step(f, t, y, h)
            if project is not None:
                p = _apply_projection(project, y)
                if p is not y:
                    y[:] = p
            if not isfinite(y, out=finite).all():
                delta.steps += k + 1
                delta.rhs_evals += nfev
                delta.projections += k + 1 if project is not None else 0
                raise IntegrationError(
                    self.name, t + h,
                    f'state became non-finite (components {_nonfinite_indices(y)}) in the '
                    f'step from t={t:.12g} s with h={h:.6g} s; reduce dt or check the model')
        delta.steps += n_steps
        delta.rhs_evals += nfev
        if project is not None:
            delta.projections += n_steps
        self._count_linear_algebra(delta, n_steps)
        return y

    def _count_linear_algebra(self, delta, n_steps):
        """Add the Jacobians and factorisations of n_steps steps to delta (none for explicit methods)."""

    def _step(self, f, t, y, h):  # pragma: no cover - abstract
        raise NotImplementedError


class ExplicitEuler(FixedStepIntegrator):
    """Explicit (forward) Euler, order 1: ``y += h f(t, y)`` (Hairer-Norsett-Wanner I.1).

    Args:
        spec: registry entry.
        dt: step size h (s), > 0.
    """

    def _allocate(self, n):
        super()._allocate(n)
        self._dy = np.empty(n)

    def _step(self, f, t, y, h):
        # f's result is copied into _dy before y changes, so f may return (a view of) y.
        np.multiply(f(step_start(t), y), h, out=self._dy)
        y += self._dy
        return 1


class SemiImplicitEuler(FixedStepIntegrator):
    """Symplectic (semi-implicit) Euler for mechanical systems, order 1.

    With ``y = [q (nq), v (nv)]`` and ``a = f(t, y)[nq:]`` (Hairer-Lubich-Wanner, GNI VI.3)::

        v_{k+1} = v_k + h a(t_k, q_k, v_k)
        q_{k+1} = q_k + h qdot(q_k, v_{k+1})

    The position half of ``f`` is not used.  The map is symplectic for ``qdot(q, v) = v``
    and separable Hamiltonians; with velocity-dependent forces it is still a first-order,
    well-behaved method.

    Args:
        spec: registry entry.
        dt: step size h (s), > 0.
        nq: number of position coordinates, stored first in y (velocities follow).
        qdot: optional map ``qdot(q, v) -> dq/dt`` of shape (nq,) (e.g. the quaternion
            kinematics of a free-flying base); default the identity ``qdot = v``, which
            requires ``nv == nq``.  It receives views into the state and must not modify them.
    """

    def __init__(self, spec: IntegratorSpec, dt: float, nq: int,
                 qdot: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None):
        super().__init__(spec, dt)
        self.nq = nq
        self.qdot = qdot

    def settings(self) -> dict:
        """Return the user-chosen settings, for recording metadata."""
        return {**super().settings(), 'nq': self.nq}

    def _allocate(self, n):
        nq = self.nq
        if not 0 < nq < n:
            raise ValueError(f'{self.name}: nq={nq} must lie in (0, {n}) for a state of size {n}')
        if self.qdot is None and n != 2 * nq:
            raise ValueError(
                f'{self.name}: with the identity qdot(q, v) = v the state must be [q, v] with '
                f'nv == nq, but n={n} and nq={nq}; pass qdot=... for nv != nq')
        super()._allocate(n)
        self._dq = np.empty(nq)
        self._dv = np.empty(n - nq)

    def _step(self, f, t, y, h):
        nq = self.nq
        q = y[:nq]
        v = y[nq:]
        ydot = f(step_start(t), y)
        np.multiply(ydot[nq:], h, out=self._dv)  # copy first: ydot may alias y
        v += self._dv
        qd = v if self.qdot is None else self.qdot(q, v)
        np.multiply(qd, h, out=self._dq)
        q += self._dq
        return 1


class ClassicalRungeKutta4(FixedStepIntegrator):
    """Classical fourth-order Runge-Kutta (Hairer-Norsett-Wanner I, Table II.1.2).

    ``k1 = f(t, y)``, ``k2 = f(t + h/2, y + h/2 k1)``, ``k3 = f(t + h/2, y + h/2 k2)``,
    ``k4 = f(t + h, y + h k3)``, ``y += h/6 (k1 + 2 k2 + 2 k3 + k4)`` (k1 and k4 read time-dependent inputs on
    the step's side of the grid: :func:`step_start`, :func:`step_end`).

    Args:
        spec: registry entry.
        dt: step size h (s), > 0.
    """

    def _allocate(self, n):
        super()._allocate(n)
        self._Y = np.empty(n)    # stage value
        self._acc = np.empty(n)  # k1 + 2 k2 + 2 k3 + k4

    def _step(self, f, t, y, h):
        # Each k is folded into _acc before the stage buffer _Y is overwritten, so f may
        # return (a view of) its argument.
        Y = self._Y
        acc = self._acc
        half = 0.5 * h
        k = f(step_start(t), y)
        acc[:] = k
        np.multiply(k, half, out=Y)
        Y += y
        k = f(t + half, Y)
        np.add(acc, k, out=acc)
        np.add(acc, k, out=acc)
        np.multiply(k, half, out=Y)
        Y += y
        k = f(t + half, Y)
        np.add(acc, k, out=acc)
        np.add(acc, k, out=acc)
        np.multiply(k, h, out=Y)
        Y += y
        k = f(step_end(t, h), Y)
        np.add(acc, k, out=acc)
        acc *= h / 6.0
        y += acc
        return 4


class Rosenbrock2(FixedStepIntegrator):
    """Linearly implicit Rosenbrock-W method of order 2 (ROS2, Verwer, Spee, Blom & Hundsdorfer 1999)::

        (I − γhJ) k1 = f(t, y)
        (I − γhJ) k2 = f(t + h, y + h k1) − 2 k1
        y += h (3/2 k1 + 1/2 k2),        γ = 1 − 1/√2

    Order 2 for any J (a W-method), L-stable on the part of f that J holds exactly; J = 0 gives
    Heun's method. The method, its stability function and its cost on a mechanical system are in
    :mod:`robodyn_ros.kernels.rosenbrock`; the systems' compiled loops run it there. Here it is the
    generic form, one LU factorisation of ``I − γhJ`` per step (none when ``jac`` is None). Where f
    moves with time stiffly (a stiff servo on a moving setpoint), ``dfdt`` gives the time term of the
    method's non-autonomous form (Verwer et al. 1999, eq. 2.4)::

        (I − γhJ) k1 = f(t, y) + γh f_t,     (I − γhJ) k2 = f(t + h, y + h k1) − 2 k1 − γh f_t

    (any f_t keeps order 2, as any J does; the exact one keeps a stiff mode on its moving equilibrium).

    Args:
        spec: registry entry.
        dt: step size h (s), > 0.
        jac: optional ``jac(t, y) -> J (n, n)``, evaluated once per step at its start: the stiff
            (passive) part of ∂f/∂y; None: J = 0.
        gamma: γ, default :data:`GAMMA` (1 − 1/√2); the other L-stable root 1 + 1/√2 is the one the
            compiled loops take in steps with a joint stop in J or a ground contact touching
            (``kernels.rosenbrock.GAMMA_STOP``; ``kernels.arm.arm_implicit_matrix``).
        dfdt: optional ``dfdt(t, y) -> f_t (n,)``, evaluated once per step at its start; None: 0.
        rtol, atol: None (fixed steps of dt), or the tolerances of error control, dt then the largest step
            (:meth:`_advance_controlled`; ``make_integrator`` sets atol = rtol when not given).
        controlled: how many leading components of y the error control measures (None: all).
    """

    def __init__(self, spec: IntegratorSpec, dt: float, jac=None, gamma=None, dfdt=None, rtol=None, atol=None,
                 controlled=None):
        super().__init__(spec, dt)
        self.jac = jac
        self.dfdt = dfdt
        self.gamma = GAMMA if gamma is None else float(gamma)
        self.rtol = rtol
        self.atol = atol
        #: how many leading components of the state the error control measures (None: all); the Simulator
        #: sets it to the system's state, leaving out the work quadrature it appends
        self.controlled = controlled

    def settings(self) -> dict:
        out = super().settings()
        if self.rtol is not None:
            out.update(rtol=self.rtol, atol=self.atol)
        return out

    @property
    def tolerance(self):
        """``(rtol, atol)`` under error control, else None (fixed steps of dt)."""
        return None if self.rtol is None else (self.rtol, self.atol)

    def _advance(self, f, t0, y, t1, project, delta):
        if self.rtol is None:
            return super()._advance(f, t0, y, t1, project, delta)
        return self._advance_controlled(f, t0, y, t1, project, delta)

    def _advance_controlled(self, f, t0, y, t1, project, delta):
        """Error-controlled steps from t0 to t1, dt the largest and the first one tried, the last ending on
        t1 (nothing carried over from the call before). The error of a step is that of the embedded
        first-order solution ``y + h k1`` (Verwer et al. 1999): ``e = y_new − y − h k1``, measured as the root
        mean square of ``e_i / (atol + rtol max(|y_i|, |y_new,i|))`` over the controlled components; a step
        with a measure ≤ 1 is kept and projected, the next one ``h min(5, max(0.2, 0.9/√err))``, at most
        dt. The systems' compiled loops have their own (``kernels.arm.arm_controlled_steps``, positions in
        tangent coordinates)."""
        if y.shape[0] != self._n:
            self._allocate(y.shape[0])
        m = y.shape[0] if self.controlled is None else self.controlled
        rtol, atol, dt = self.rtol, self.atol, self.dt
        span = t1 - t0
        done, h = 0.0, dt
        y0 = np.empty_like(y)
        accepted = rejected = nfev = 0
        while done < span:
            rest = span - done
            hs = min(h, rest)
            y0[:] = y
            nfev += self._step(f, t0 + done, y, hs)
            e = (y[:m] - y0[:m]) - hs * self._k1[:m]
            sc = atol + rtol * np.maximum(np.abs(y0[:m]), np.abs(y[:m]))
            err = float(np.sqrt(np.mean((e / sc) ** 2))) if m else 0.0
            if err <= 1.0:
                accepted += 1
                if project is not None:
                    p = _apply_projection(project, y)
                    if p is not y:
                        y[:] = p
                if not np.isfinite(y).all():
                    break
                if hs >= rest:
                    done = span
                    break
                done += hs
                if self._max_steps is not None and accepted >= self._max_steps:
                    break
                h = min(dt, hs * min(GROW_MAX, max(SHRINK_MAX, SAFETY / math.sqrt(max(err, 1e-12)))))
            else:
                rejected += 1
                y[:] = y0
                h = hs * (max(SHRINK_MAX, SAFETY / math.sqrt(err)) if math.isfinite(err) else SHRINK_MAX)
                if h < H_MIN * dt:
                    break
        delta.steps += accepted
        delta.rejected_steps = (delta.rejected_steps or 0) + rejected
        delta.rhs_evals += nfev
        self._count_linear_algebra(delta, accepted + rejected)
        if project is not None:
            delta.projections += accepted
        if done < span:
            t = t0 + done
            if self._max_steps is not None and accepted >= self._max_steps:
                raise StepBudgetError(self.name, t, accepted)
            if not np.isfinite(y).all():
                raise IntegrationError(self.name, t, f'state became non-finite (components '
                                       f'{_nonfinite_indices(y)}) in a step from t={t:.12g} s')
            raise IntegrationError(self.name, t, tolerance_failure(t, h, rtol, atol, dt))
        return y

    def _allocate(self, n):
        super()._allocate(n)
        self._Y = np.empty(n)
        self._k1 = np.empty(n)
        self._eye = np.eye(n)

    def _step(self, f, t, y, h):
        from scipy.linalg import lu_factor, lu_solve
        lu = None
        ts = step_start(t)   # stage 1 and its J, f_t: inputs on the step's side of the grid (see step_start)
        if self.jac is not None:
            J = np.asarray(self.jac(ts, y), dtype=np.float64)
            lu = lu_factor(self._eye - (self.gamma * h) * J, check_finite=False)
        ft = None if self.dfdt is None else (self.gamma * h) * np.asarray(self.dfdt(ts, y), dtype=np.float64)
        k1 = self._k1
        k1[:] = f(ts, y)
        if ft is not None:
            k1 += ft
        if lu is not None:
            k1[:] = lu_solve(lu, k1, check_finite=False)
        np.multiply(k1, h, out=self._Y)
        self._Y += y
        k2 = np.asarray(f(step_end(t, h), self._Y), dtype=np.float64) - 2.0 * k1
        if ft is not None:
            k2 -= ft
        if lu is not None:
            k2 = lu_solve(lu, k2, check_finite=False)
        y += h * (1.5 * k1 + 0.5 * k2)
        return 2

    def _count_linear_algebra(self, delta, n_steps):
        if self.jac is not None:
            delta.njev += n_steps
            delta.nlu += n_steps


def tolerance_failure(t: float, h: float, rtol: float, atol: float, dt: float) -> str:
    """The message of an error-controlled rosenbrock2 run whose step fell below its floor."""
    return (f'rosenbrock2 could not meet rtol={rtol:g}, atol={atol:g} at t={t:.12g} s: its step fell to '
            f'{h:.3g} s, below 1e-9 of dt={dt:g} s; loosen the tolerances or check the model')


#: γ of :class:`Rosenbrock2` (the L-stable root of 2γ² − 4γ + 1 = 0; kernels.rosenbrock.GAMMA)
GAMMA = 1.0 - 1.0 / math.sqrt(2.0)


# ----------------------------------------------------------------------------------------
# Error-controlled (scipy OdeSolver)
# ----------------------------------------------------------------------------------------

class _CountedRhs:
    """Wrap ``f`` to count its calls, remember the first non-finite result and mark errors.

    ``raised`` tells an exception raised by ``f`` itself (a model error, propagated as is)
    from one raised by the solver's linear algebra (an integration failure).
    """

    __slots__ = ('f', 'n', 'nonfinite_t', 'raised')

    def __init__(self, f: Rhs):
        self.f = f
        self.n = 0
        self.nonfinite_t = None
        self.raised = False

    def __call__(self, t, y):
        self.n += 1
        try:
            ydot = self.f(t, y)
        except BaseException:
            self.raised = True
            raise
        if self.nonfinite_t is None and not np.isfinite(ydot).all():
            self.nonfinite_t = t
        return ydot


class AdaptiveIntegrator(Integrator):
    """Error-controlled integration with a scipy ``OdeSolver`` (the engine of ``solve_ivp``).

    Args:
        spec: registry entry.
        solver_class: ``scipy.integrate`` solver class (RK45, DOP853, Radau, BDF, LSODA).
        rtol: relative tolerance, > 0.
        atol: absolute tolerance, > 0, scalar or shape (n,).
        max_step: largest step allowed (s), default unbounded.
        first_step: first step size of the first call (s); default chosen by scipy.
        jac: optional Jacobian ``jac(t, y) -> (n, n)`` (implicit methods only); default
            finite differences.

    The step size proposed by the error controller at the end of each call is used as
    ``first_step`` of the next call (see the module docstring for why the solver is
    restarted per call).
    """

    def __init__(self, spec: IntegratorSpec, solver_class, rtol, atol,
                 max_step: float = math.inf, first_step: float | None = None, jac=None):
        super().__init__(spec)
        self.solver_class = solver_class
        self.rtol = rtol
        self.atol = atol
        self.max_step = max_step
        self.first_step = first_step
        self.jac = jac
        self._stages = getattr(solver_class, 'n_stages', None)  # explicit RK pairs only
        self._h_next = first_step

    def reset(self) -> None:
        """Forget statistics and the remembered step size."""
        super().reset()
        self._h_next = self.first_step

    def settings(self) -> dict:
        """Return the user-chosen settings, for recording metadata."""
        atol = self.atol if np.ndim(self.atol) == 0 else np.asarray(self.atol).tolist()
        return {'integrator': self.name, 'rtol': self.rtol, 'atol': atol,
                'max_step': self.max_step}

    def _advance(self, f, t0, y, t1, project, delta):
        rhs = _CountedRhs(f)
        kwargs = {'rtol': self.rtol, 'atol': self.atol, 'max_step': self.max_step}
        if self.jac is not None:
            kwargs['jac'] = self.jac
        h0 = self.first_step if self.spec.multistep else self._h_next
        if h0 is not None:
            kwargs['first_step'] = min(h0, t1 - t0)
        solver = self.solver_class(rhs, t0, y, t1, **kwargs)
        per_step_projection = project is not None and self.spec.projection == 'step'
        stages = self._stages
        rejected = 0 if stages is not None else None
        h_next = None
        while solver.status == 'running':
            h_proposed = getattr(solver, 'h_abs', None)
            n_before = rhs.n
            try:
                message = solver.step()
            except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
                if rhs.raised:
                    raise
                # e.g. lu_factor on a Jacobian with NaN/inf entries (BDF, Radau)
                self._fail(rhs, solver, delta, rejected, f'{type(exc).__name__}: {exc}', exc)
            if solver.status == 'failed':
                self._fail(rhs, solver, delta, rejected, message)
            delta.steps += 1
            if stages is not None:
                attempts = (rhs.n - n_before) // stages
                rejected += attempts - 1
            h_taken = solver.t - solver.t_old
            h_after = getattr(solver, 'h_abs', h_taken)
            # A final step clipped at t1 is shorter than what the controller wanted: keep
            # the pre-clip proposal for the next call if the step was accepted at once
            # (known for the explicit pairs only; otherwise take the controller's new value).
            if (solver.status == 'finished' and h_proposed is not None
                    and h_taken < h_proposed and stages is not None and attempts == 1):
                h_next = max(h_proposed, h_after)
            else:
                h_next = h_after
            if per_step_projection:
                self._project_solver_state(solver, project, delta)
            if not np.isfinite(solver.y).all():
                self._record(rhs, solver, delta, rejected)
                raise IntegrationError(
                    self.name, solver.t,
                    f'state became non-finite (components {_nonfinite_indices(solver.y)})')
            if self._max_steps is not None and delta.steps >= self._max_steps and solver.status == 'running':
                self._record(rhs, solver, delta, rejected)
                raise StepBudgetError(self.name, solver.t, delta.steps)
        self._record(rhs, solver, delta, rejected)
        if h_next is not None and h_next > 0.0 and math.isfinite(h_next):
            self._h_next = h_next
        y1 = np.array(solver.y, dtype=np.float64)
        if project is not None and not per_step_projection:
            y1 = np.array(_apply_projection(project, y1), dtype=np.float64)
            delta.projections += 1
            if not np.isfinite(y1).all():
                raise IntegrationError(self.name, t1, 'project(y) returned a non-finite state')
        return y1

    @staticmethod
    def _project_solver_state(solver, project, delta):
        """Project the solver's state in place and keep its stored derivative consistent."""
        p = _apply_projection(project, solver.y.copy())  # a copy: project may work in place
        delta.projections += 1
        if np.array_equal(p, solver.y):
            return
        solver.y = p
        # RK45/DOP853 reuse f(t, y) as the first stage of the next step (FSAL) and Radau
        # uses it in its error estimate: re-evaluate it at the projected state.
        solver.f = solver.fun(solver.t, solver.y)

    def _record(self, rhs, solver, delta, rejected):
        """Copy the cost of this call from the counter and the solver into ``delta``."""
        delta.rhs_evals += rhs.n
        delta.njev += int(getattr(solver, 'njev', 0))
        delta.nlu += int(getattr(solver, 'nlu', 0))
        delta.rejected_steps = rejected

    def _fail(self, rhs, solver, delta, rejected, message, exc=None):
        """Raise IntegrationError for a solver that gave up, with the likely cause."""
        self._record(rhs, solver, delta, rejected)
        cause = f'scipy {self.solver_class.__name__} failed: {message}'
        if rhs.nonfinite_t is not None:
            cause += f'; f(t, y) returned non-finite values first at t={rhs.nonfinite_t:.12g} s'
        raise IntegrationError(self.name, solver.t, cause) from exc


# ----------------------------------------------------------------------------------------
# Registry
# ----------------------------------------------------------------------------------------

def _fixed(cls):
    """Return a factory for a fixed-step integrator class."""
    def build(spec, dt, **kw):
        return cls(spec, dt, **kw)
    return build


def _adaptive(solver_name):
    """Return a factory for an error-controlled integrator on the ``scipy.integrate`` solver class
    of that name (imported when the first such integrator is built: a fixed-step run never loads
    scipy)."""
    def build(spec, rtol, atol, **kw):
        import scipy.integrate
        return AdaptiveIntegrator(spec, getattr(scipy.integrate, solver_name), rtol, atol, **kw)
    return build


_ADAPTIVE_OPTIONS = ('max_step', 'first_step')

INTEGRATORS: dict[str, IntegratorSpec] = {s.name: s for s in (
    IntegratorSpec(name='euler', kind='fixed', order=1, symplectic=False, implicit=False,
                   projection='step', multistep=False,
                   summary='explicit (forward) Euler',
                   factory=_fixed(ExplicitEuler)),
    IntegratorSpec(name='semi_implicit_euler', kind='fixed', order=1, symplectic=True,
                   implicit=False, projection='step', multistep=False,
                   summary='symplectic Euler: v from the acceleration at (q, v), then q from '
                           'the new v',
                   options=('nq', 'qdot'), factory=_fixed(SemiImplicitEuler)),
    IntegratorSpec(name='rk4', kind='fixed', order=4, symplectic=False, implicit=False,
                   projection='step', multistep=False,
                   summary='classical fourth-order Runge-Kutta',
                   factory=_fixed(ClassicalRungeKutta4)),
    IntegratorSpec(name='rosenbrock2', kind='fixed', order=2, symplectic=False, implicit=True,
                   projection='step', multistep=False,
                   summary='linearly implicit Rosenbrock-W, order 2, L-stable on the stiff passive forces '
                           '(damping, friction, joint limits, ground contact, motor electrics, joint servos), explicit '
                           'in the rest; with rtol (atol: rtol) error-controlled, dt its largest step',
                   options=('jac', 'gamma', 'dfdt'), factory=_fixed(Rosenbrock2)),
    IntegratorSpec(name='rk45', kind='adaptive', order=5, symplectic=False, implicit=False,
                   projection='step', multistep=False,
                   summary='Dormand-Prince 5(4) explicit Runge-Kutta (scipy RK45)',
                   options=_ADAPTIVE_OPTIONS, factory=_adaptive('RK45')),
    IntegratorSpec(name='dop853', kind='adaptive', order=8, symplectic=False, implicit=False,
                   projection='step', multistep=False,
                   summary='Dormand-Prince 8(5,3) explicit Runge-Kutta (scipy DOP853)',
                   options=_ADAPTIVE_OPTIONS, factory=_adaptive('DOP853')),
    IntegratorSpec(name='radau', kind='adaptive', order=5, symplectic=False, implicit=True,
                   projection='step', multistep=False,
                   summary='Radau IIA implicit Runge-Kutta, order 5, L-stable (scipy Radau)',
                   options=_ADAPTIVE_OPTIONS + ('jac',), factory=_adaptive('Radau')),
    IntegratorSpec(name='bdf', kind='adaptive', order=5, symplectic=False, implicit=True,
                   projection='call', multistep=True,
                   summary='variable-order BDF/NDF 1-5 for stiff systems (scipy BDF)',
                   options=_ADAPTIVE_OPTIONS + ('jac',), factory=_adaptive('BDF')),
    IntegratorSpec(name='lsoda', kind='adaptive', order=12, symplectic=False, implicit=True,
                   projection='call', multistep=True,
                   summary='Adams 1-12 / BDF 1-5 with automatic stiffness switching '
                           '(scipy LSODA)',
                   options=_ADAPTIVE_OPTIONS + ('jac',), factory=_adaptive('LSODA')),
)}


def _positive_finite(label: str, name: str, value) -> float:
    """Return ``float(value)`` or raise ValueError unless it is a finite number > 0."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f'{name}: {label} must be a number > 0, got {value!r}') from None
    if not (math.isfinite(x) and x > 0.0):
        raise ValueError(f'{name}: {label} must be finite and > 0, got {value!r}')
    return x


def make_integrator(name: str, dt: float | None = None, rtol: float | None = None,
                    atol=None, **kw) -> Integrator:
    """Build a registered integrator from user settings, validating them.

    Args:
        name: registry name, one of ``INTEGRATORS`` (case-insensitive).
        dt: step size (s) of a fixed-step integrator; required and > 0 for those, not
            accepted by the error-controlled ones.
        rtol: relative tolerance of an error-controlled integrator, >= 100 machine epsilon
            (default ``DEFAULT_RTOL``); not accepted by fixed-step ones.
        atol: absolute tolerance, > 0, scalar or one per state component (default
            ``DEFAULT_ATOL``); not accepted by fixed-step ones.
        **kw: integrator options listed in ``INTEGRATORS[name].options``:
            ``nq`` (int, required) and ``qdot`` for ``semi_implicit_euler``;
            ``max_step``, ``first_step`` (s, > 0) for the error-controlled ones and ``jac``
            for the implicit ones.

    Returns:
        A fresh ``Integrator`` (it holds step-size memory and statistics: one per system).

    Raises:
        ValueError: unknown name, or a missing, inapplicable or out-of-range argument.
    """
    key = name.strip().lower() if isinstance(name, str) else name
    spec = INTEGRATORS.get(key)
    if spec is None:
        raise ValueError(f'unknown integrator {name!r}; valid names: {", ".join(INTEGRATORS)}')
    unknown = sorted(set(kw) - set(spec.options))
    if unknown:
        accepted = ', '.join(spec.options) if spec.options else 'none'
        raise ValueError(f'{spec.name}: unexpected option(s) {", ".join(unknown)}; '
                         f'accepted options: {accepted}')
    if spec.kind == 'fixed':
        if (rtol is not None or atol is not None) and spec.name not in CONTROLLABLE:
            raise tolerance_refused(spec.name, 'rtol/atol')
        if dt is None:
            raise ValueError(f'{spec.name} is a fixed-step integrator: dt (s) is required')
        dt = _positive_finite('dt', spec.name, dt)
        if rtol is not None or atol is not None:   # rosenbrock2 under error control, dt its largest step
            if rtol is None:
                raise ValueError(f'{spec.name}: atol needs rtol (error control, dt the largest step)')
            rtol = _positive_finite('rtol', spec.name, rtol)
            if rtol < MIN_RTOL:
                raise ValueError(f'{spec.name}: rtol={rtol:g} is below 100 machine epsilon '
                                 f'({MIN_RTOL:.3g}) and cannot be met')
            if atol is not None and np.ndim(atol) != 0:
                raise ValueError(f'{spec.name}: atol must be one number (m, rad, m/s, rad/s), got {atol!r}')
            atol = rtol if atol is None else _positive_finite('atol', spec.name, atol)
            kw.update(rtol=rtol, atol=atol)
        if spec.name == 'semi_implicit_euler':
            nq = kw.get('nq')
            if isinstance(nq, bool) or not isinstance(nq, (int, np.integer)) or nq <= 0:
                raise ValueError(f'{spec.name}: nq (number of position coordinates, stored '
                                 f'first in y) must be a positive int, got {nq!r}')
            kw['nq'] = int(nq)
            if kw.get('qdot') is not None and not callable(kw['qdot']):
                raise ValueError(f'{spec.name}: qdot must be callable qdot(q, v) -> dq/dt')
        if kw.get('jac') is not None and not callable(kw['jac']):
            raise ValueError(f'{spec.name}: jac must be callable jac(t, y) -> (n, n) array')
        return spec.factory(spec, dt, **kw)

    if dt is not None:
        raise ValueError(f'{spec.name} is error-controlled: give rtol/atol, not dt '
                         f'(max_step=... caps its step; fixed-step ones: '
                         f'{", ".join(_names("fixed"))})')
    rtol = DEFAULT_RTOL if rtol is None else _positive_finite('rtol', spec.name, rtol)
    if rtol < MIN_RTOL:
        raise ValueError(f'{spec.name}: rtol={rtol:g} is below 100 machine epsilon '
                         f'({MIN_RTOL:.3g}) and cannot be met')
    if atol is None:
        atol = DEFAULT_ATOL
    elif np.ndim(atol) == 0:
        atol = _positive_finite('atol', spec.name, atol)
    else:
        atol = np.asarray(atol, dtype=np.float64)
        if atol.ndim != 1 or not (np.isfinite(atol).all() and (atol > 0).all()):
            raise ValueError(f'{spec.name}: atol must be > 0 (a scalar or one finite value '
                             f'per state component), got {atol!r}')
    for option in ('max_step', 'first_step'):
        if option in kw and kw[option] is not None:
            value = kw[option]
            if option == 'max_step' and value == math.inf:
                continue
            kw[option] = _positive_finite(option, spec.name, value)
    if kw.get('jac') is not None and not callable(kw['jac']):
        raise ValueError(f'{spec.name}: jac must be callable jac(t, y) -> (n, n) array')
    kw = {k: v for k, v in kw.items() if v is not None}
    return spec.factory(spec, rtol, atol, **kw)


#: the step controller of rosenbrock2 under error control, here and in the trees' compiled loop
#: (``kernels.arm.arm_controlled_steps``, whose cache fingerprint holds them): safety factor, the largest growth
#: and shrinking of the step, and the smallest step, relative to dt, before the run fails
SAFETY, GROW_MAX, SHRINK_MAX, H_MIN = 0.9, 5.0, 0.2, 1e-9

#: fixed-step methods that also run under error control when given rtol (dt then their largest step)
CONTROLLABLE = ('rosenbrock2',)


def tolerance_refused(name: str, given: str, auto: bool = False) -> ValueError:
    """The error for tolerances (``given``: 'rtol', 'atol' or 'rtol/atol') asked of the fixed-step method ``name``
    (not rosenbrock2), naming the methods that take them (and auto, where a run may choose it)."""
    takes = list(CONTROLLABLE) + _names('adaptive') + (['or auto'] if auto else [])
    return ValueError(f'{name} is a fixed-step integrator: give dt, not {given} (error-controlled ones: '
                      f'{", ".join(takes)})')


def _names(kind: str) -> list[str]:
    """Return the registry names of one kind ('fixed' or 'adaptive')."""
    return [n for n, s in INTEGRATORS.items() if s.kind == kind]
