"""Run-time stability analysis: a fixed step analysed before the run starts, and failures that name their cause.

GUIDE §3: at every extreme the simulator stays within its stated error, adapts, or stops with a
message naming the cause, and never publishes a non-finite value. This module is the analysis behind
that: the linearisation, its modes, the methods' stability functions, the preflight of the initial
state and the diagnosis of a failure. It decides nothing: :mod:`robodyn_ros.integrator_choice` (which
integrator, which step, and why) calls it once per run, and ``Simulator.advance`` calls
:func:`diagnose` and :func:`stiff_mode` when a run fails. It sits low in the house (it imports only
``model`` and ``dynamics``); the scenarios that push the simulator to its extremes and write the
README table are a benchmark, :mod:`robodyn_ros.bench.extremes`:

**Step stability (before a fixed-step run).** A fixed explicit step ``h`` is stable on a mode
``ẏ = λ y`` when the method's amplification ``|R(hλ)| <= 1`` (Hairer–Wanner II, §IV.2). The
modes of a mechanical system are estimated from its linearisation at the initial state::

    J = ∂f/∂y  (central finite differences, 2 ny evaluations of f)            (S1)
    modes = eig(J), each λ with Re λ > 0 replaced by ±i|λ|,
            plus -1/τ_sys and ±i ω_spin/2                                        (S2)

A growing eigenvalue is a saddle of the configuration the run starts in (a pendulum released
off its equilibrium); elsewhere on the path the same curvature is an oscillation of about the
same frequency, which is what a fixed step has to survive. ``τ_sys`` is the system's declared
``fastest_time_constant`` (motor electrics ``L/R``, Baumgarte gains), and a free base spinning
at ``ω_spin`` turns its quaternion at ``ω_spin/2`` (``q̇ = ½ q ⊗ ω``); both are in J already and
are added explicitly so that finite differences cannot blur them. The scalar stability functions::

    euler                R(z) = 1 + z
    rk4                  R(z) = 1 + z + z²/2 + z³/6 + z⁴/24
    semi_implicit_euler  largest root of μ² − (2 + 2 Re z − |z|²) μ + (1 + 2 Re z) = 0
                         (the damped oscillator q̇ = v, v̇ = −ω²q − 2ζω v with z = hλ; explicit
                         Euler on a real, first-order mode)

give the largest growth per step ``ρ = max |R(hλ)|`` over the modes and the spurious growth::

    g = ln ρ                                          (per step)                     (S3)

``g > REFUSE_GROWTH`` (a mode that grows by more than 1 % per step doubles within 70 steps)
refuses the step; a smaller ``g > 0`` whose doubling time ``h ln 2 / g`` is shorter than
``WARN_DOUBLING_TIME`` of simulated time warns (explicit Euler on any undamped oscillation: its
energy grows without bound, slowly for small steps). The message names the dominant mode (its
|λ|, the time constant 1/|λ|, and whether it is the declared time constant or the spin), the
largest stable step for the method on it, and the alternatives (a smaller ``dt``, an
error-controlled or a stiff integrator). Error-controlled integrators are not checked: they
adapt (and report rejected steps) or are stable (radau, bdf). This is an estimate from one
state: a run that moves into faster modes (a command that spins a joint up) is caught by the
non-finite guard, and :func:`diagnose` then explains it.

**Preflight.** ``preflight(system, y)`` evaluates ``f`` once at the initial state; a singular
mass matrix (a moving joint that carries no inertia about its axis) or a non-finite derivative
is refused with the joint named, instead of surfacing later as ``LinAlgError`` or NaN.

**Diagnosis.** ``diagnose(...)`` explains a failed run from its last good state (the same
linearisation, plus the largest command), so the ``SimulationError`` names the likely cause.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ['REFUSE_GROWTH', 'WARN_DOUBLING_TIME', 'FD_REL_STEP', 'STOP_RESOLUTION', 'StepWarning', 'StepAnalysis',
           'linearisation', 'candidate_modes', 'spin_rate', 'analyse_step',
           'preflight', 'diagnose', 'stable_step_limit', 'rosenbrock2_amplification', 'rosenbrock2_step_matrix',
           'passive_jacobian', 'step_alternatives', 'stiff_mode', 'start_inputs']

#: spurious amplification per step (eq. S3, as ln ρ) above which a fixed step is refused
REFUSE_GROWTH = 1e-2
#: simulated seconds: a slower spurious growth than this doubling time passes silently
WARN_DOUBLING_TIME = 1e5
#: relative finite-difference step of the linearisation (central differences: ~eps^(1/3))
FD_REL_STEP = 6e-6
#: fixed explicit methods this module analyses
FIXED_EXPLICIT = ('euler', 'semi_implicit_euler', 'rk4')
#: the longest explicit step on a joint stop, as a multiple of its time constant τ (``stop_time_constant``,
#: 1/ω for an underdamped stop): the stop's law switches within its bounce (its spring and damper on at
#: contact, the damper off when the joint turns back), which linear stability (S3) does not see. Measured on a
#: hinge coasting into its stop (every phase of the step at contact; test_joint_limits): rk4 at h/τ = 2.5
#: throws a damped joint (ζ = 0.5) back 1.8 times as fast as it came, symplectic Euler 2.7 times at 1.5;
#: within these limits a damped stop (ζ >= 0.05) sends it back slower than it came, an undamped one within
#: 2.5 % of its speed. Explicit Euler gains on any oscillation: at 0.1 an undamped stop returns the joint
#: 17 % faster, a damped one (ζ = 0.5) slower.
STOP_RESOLUTION = {'euler': 0.1, 'semi_implicit_euler': 1.0, 'rk4': 1.5}
#: fixed-step methods implicit in the system's passive forces (``System.passive_jacobian``), explicit in the rest
LINEARLY_IMPLICIT = ('rosenbrock2',)
#: every fixed-step method this module analyses
FIXED_STEP = FIXED_EXPLICIT + LINEARLY_IMPLICIT
#: γ of rosenbrock2 (kernels.rosenbrock.GAMMA, integrators.GAMMA): the analysis takes this root. The
#: compiled loops take the other, 1 + 1/√2 (kernels.rosenbrock.GAMMA_STOP), in steps with a joint stop in
#: J or a ground contact touching; both are L-stable on what J holds, and outside J the method is Heun's
#: whatever γ is, so the verdicts hold for either
_GAMMA = 1.0 - 1.0 / math.sqrt(2.0)


class StepWarning(UserWarning):
    """A fixed step that is stable enough to run but amplifies some mode spuriously."""


@dataclass
class StepAnalysis:
    """What :func:`analyse_step` found about a fixed step on a system at a state.

    integrator, dt: the method and step (s); eigenvalues: (k,) complex modes λ (1/s) checked
    (S1–S2); lam_max: largest |λ| (1/s); tau: 1/lam_max (s); spin: angular speed of
    a free base (rad/s, 0 without one); system_tau: the system's declared fastest time constant
    (s); rho: largest amplification per step over the modes; growth: g = ln rho (S3); doubling_time:
    simulated seconds for the spurious mode to double (inf when g <= 0); dt_limit: the largest
    step for which the dominant mode passes (s); verdict: 'ok' | 'warn' | 'refuse'; message:
    the text of a warning or refusal ('' when ok).
    """

    integrator: str
    dt: float
    eigenvalues: np.ndarray
    lam_max: float
    tau: float
    spin: float
    system_tau: float
    rho: float
    growth: float
    doubling_time: float
    dt_limit: float
    verdict: str = 'ok'
    message: str = ''
    worst: complex = 0j
    extra: dict = field(default_factory=dict)


def start_inputs(system, y=None, t: float = 0.0) -> dict:
    """The inputs in force before any command, at state y and time t: what ``System.initial_input`` applies
    (zeros, but a servo's hold of the initial posture), zeros where the system does not say."""
    init = getattr(system, 'initial_input', None)
    if init is None or y is None:
        return {k: np.zeros(p.size) for k, p in getattr(system, 'inputs', {}).items()}
    return {k: init(k, np.asarray(y, dtype=float), t)[1] for k in getattr(system, 'inputs', {})}


def linearisation(system, y, u=None, t: float = 0.0, rel_step: float = FD_REL_STEP) -> np.ndarray:
    """``J = ∂f/∂y`` (ny, ny) of ``f = system.rhs(t, ·, u)`` at y, by central differences (S1).

    system: the System; y: (ny,) state; u: inputs (default zeros); t: time (s); rel_step:
    perturbation of component j is ``rel_step * max(1, |y_j|)``. Costs 2 ny evaluations of f.
    """
    u = start_inputs(system, y, t) if u is None else u
    y = np.array(y, dtype=float)
    n = y.size
    J = np.empty((n, n))
    for j in range(n):
        h = rel_step * max(1.0, abs(y[j]))
        yp = y.copy()
        ym = y.copy()
        yp[j] += h
        ym[j] -= h
        fp = np.asarray(system.rhs(t, yp, u), dtype=float)
        fm = np.asarray(system.rhs(t, ym, u), dtype=float)
        J[:, j] = (fp - fm) / (2.0 * h)
    return J


def rosenbrock2_amplification(z: complex, w: complex | None = None) -> complex:
    """R(z, w) of rosenbrock2 on ``y' = λy`` with J = μ (z = hλ, w = hμ; kernels.rosenbrock eq. R4):
    ``1 + 3a/2 + (z + z a − 2a)/(2 (1 − γw))`` with ``a = z/(1 − γw)``. w = None: J exact (w = z), the
    L-stable ``(1 + (1 − 2γ) z)/(1 − γz)²``; w = 0: Heun's ``1 + z + z²/2``."""
    z = complex(z)
    w = z if w is None else complex(w)
    d = 1.0 - _GAMMA * w
    a = z / d
    return 1.0 + 1.5 * a + (z + z * a - 2.0 * a) / (2.0 * d)


def rosenbrock2_step_matrix(J: np.ndarray, Jp: np.ndarray, h: float) -> np.ndarray:
    """G (n, n): one rosenbrock2 step on the linear system ``y' = J y`` with the passive part Jp in its
    W-matrix ``W = I − γh Jp``: ``G = I + 3h/2 W⁻¹J + h/2 W⁻¹(J + h J W⁻¹J − 2 W⁻¹J)`` (R1-R3)."""
    n = J.shape[0]
    I = np.eye(n)
    W = I - (_GAMMA * h) * Jp
    K1 = np.linalg.solve(W, J)            # k1 = K1 y
    K2 = np.linalg.solve(W, J + h * J @ K1 - 2.0 * K1)
    return I + h * (1.5 * K1 + 0.5 * K2)


def _scalar_amplification(integrator: str, z: complex) -> float:
    """``|R(z)|`` of a method on the scalar test equation (semi-implicit Euler: on the
    oscillator/decay pair it is exact for, approximated by its largest root; rosenbrock2: on a mode
    outside its passive Jacobian, where it is Heun's method)."""
    if integrator == 'euler':
        return abs(1 + z)
    if integrator == 'rosenbrock2':
        return abs(1 + z + z * z / 2)
    if integrator == 'rk4':
        return abs(1 + z + z * z / 2 + z ** 3 / 6 + z ** 4 / 24)
    if abs(z.imag) <= 1e-12 * abs(z):  # a first-order decay (a motor current): explicit Euler on it
        return abs(1 + z)
    # semi-implicit Euler on q' = v, v' = -2ζω v - ω² q (modes λ = z/h): characteristic
    # polynomial of G is μ² - (2 - 2ζωh - ω²h²) μ + (1 - 2ζωh) = 0
    w2h2 = abs(z) ** 2
    two_zeta_wh = -2.0 * z.real
    b = 2.0 - two_zeta_wh - w2h2
    c = 1.0 - two_zeta_wh
    roots = np.roots([1.0, -b, c])
    return float(np.max(np.abs(roots)))


def stable_step_limit(integrator: str, lam: complex, hmax: float = 1e6) -> float:
    """The largest h (s) with ``|R(hλ)| <= 1 + 1e-9`` on the ray through λ (bisection).

    For a mode on the imaginary axis explicit Euler has no stable step (returns 0).
    """
    if lam == 0:
        return math.inf
    def ok(h):
        return _scalar_amplification(integrator, h * lam) <= 1.0 + 1e-9
    lo, hi = 0.0, 1.0 / abs(lam)
    if not ok(hi * 1e-6):
        return 0.0
    while ok(hi):
        lo, hi = hi, 2.0 * hi
        if hi > hmax:
            return math.inf
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if ok(mid):
            lo = mid
        else:
            hi = mid
    return lo


def candidate_modes(lam, spin: float = 0.0) -> np.ndarray:
    """The modes a fixed step must be stable on (S2): the eigenvalues ``lam`` of the linearisation
    with each growing one (Re λ > 0, a saddle such as a pendulum released off its equilibrium)
    replaced by the oscillation ±i|λ| it becomes elsewhere on the path, plus ±i spin/2."""
    lam = np.asarray(lam, dtype=complex)
    out = [l for l in lam if l.real <= 0.0]
    for l in lam:
        if l.real > 0.0:
            out += [1j * abs(l), -1j * abs(l)]
    if spin > 0:
        out += [0.5j * spin, -0.5j * spin]
    return np.array(out, dtype=complex)


def spin_rate(system, y) -> float:
    """Angular speed (rad/s) of a free-flying base at state y (0 for fixed-base systems)."""
    model = getattr(system, 'model', None)
    minimal = getattr(system, 'minimal', None)
    if model is None or minimal is None or model.nb == 0:
        return 0.0
    from .model import FREE
    if model.jtype[0] != FREE:
        return 0.0
    _, v = minimal(np.asarray(y, dtype=float))
    return float(np.linalg.norm(v[0:3]))


def passive_jacobian(system, y, u=None, t: float = 0.0, h: float | None = None) -> np.ndarray:
    """The system's implicit Jacobian (ny, ny) at y for step h (``System.passive_jacobian``), zeros when it
    has none."""
    u = start_inputs(system, y, t) if u is None else u
    fn = getattr(system, 'passive_jacobian', None)
    Jp = fn(t, np.asarray(y, dtype=float), u, h) if fn is not None else None
    n = np.asarray(y).size
    return np.zeros((n, n)) if Jp is None else np.asarray(Jp, dtype=float)


def analyse_step(system, integrator: str, dt: float, y, u=None, t: float = 0.0, J=None) -> StepAnalysis:
    """Analyse a fixed step on ``system`` at state y (module docstring, S1–S3; S4 for rosenbrock2).

    system: the System; integrator: 'euler' | 'semi_implicit_euler' | 'rk4' | 'rosenbrock2'; dt: step
    (s); y: (ny,) state; u: inputs (default zeros); t: time; J: a precomputed Jacobian (optional).
    Returns a :class:`StepAnalysis` whose ``verdict`` is 'ok', 'warn' or 'refuse'.
    """
    name = str(integrator).lower()
    if name not in FIXED_STEP:
        raise ValueError(f'analyse_step is for fixed-step methods {FIXED_STEP}, got {integrator!r}')
    h = float(dt)
    y = np.asarray(y, dtype=float)
    if J is None:
        J = linearisation(system, y, u, t)
    if not np.all(np.isfinite(J)):
        raise ValueError(f'the linearisation of {type(system).__name__} at the initial state is not finite: '
                         f'{_not_finite_cause(system, y, J)}')
    if name in LINEARLY_IMPLICIT:
        return _analyse_linearly_implicit(system, name, h, y, u, t, J)
    lam = np.linalg.eigvals(J) if J.size else np.zeros(0, dtype=complex)
    modes = candidate_modes(lam, spin := spin_rate(system, y))
    sys_tau = float(system.fastest_time_constant(y)) if hasattr(system, 'fastest_time_constant') else math.inf
    if math.isfinite(sys_tau) and sys_tau > 0:
        modes = np.concatenate([modes, [-1.0 / sys_tau]])
    amp = np.array([_scalar_amplification(name, complex(h * m)) for m in modes]) if modes.size else np.ones(0)
    k = int(np.argmax(amp)) if amp.size else -1
    rho = float(amp[k]) if k >= 0 else 1.0
    worst = complex(modes[k]) if k >= 0 else 0j
    growth = math.log(rho) if rho > 0 else 0.0
    lam_max = float(np.max(np.abs(modes))) if modes.size else 0.0
    dt_limit = stable_step_limit(name, worst) if worst != 0 else math.inf
    doubling = h * math.log(2.0) / growth if growth > 0 else math.inf
    a = StepAnalysis(integrator=name, dt=h, eigenvalues=modes, lam_max=lam_max,
                     tau=1.0 / lam_max if lam_max > 0 else math.inf, spin=spin, system_tau=sys_tau, rho=rho,
                     growth=growth, doubling_time=doubling, dt_limit=dt_limit, worst=worst)
    source = _mode_source(worst, sys_tau, spin, getattr(system, 'time_constant_words', ''))
    mode = (f'its fastest mode at the initial state has |λ| = {abs(worst):.3g} 1/s '
            f'(λ = {worst.real:.3g}{worst.imag:+.3g}i, time constant {1.0 / abs(worst) if worst else math.inf:.3g} s'
            f'{source})')
    if growth > REFUSE_GROWTH:
        limit = (f'a stable {name} step on that mode is at most {dt_limit:.3g} s'
                 if dt_limit * abs(worst) > 1e-3 else
                 f'{name} has no stable step on that (undamped) mode')
        a.verdict = 'refuse'
        a.message = (f'{name} with dt={h:g} s is unstable for this system ({type(system).__name__}): {mode}; '
                     f'h·|λ| = {h * abs(worst):.3g} amplifies it by {rho:.3g} per step; {limit}. '
                     f'{step_alternatives(system, h, y, u, t, J)}')
    elif growth > 0 and doubling < WARN_DOUBLING_TIME:
        a.verdict = 'warn'
        a.message = (f'{name} with dt={h:g} s amplifies a mode of {type(system).__name__} spuriously: {mode}; '
                     f'numerical growth {growth:.2e} per step doubles it every {doubling:.3g} s of simulated '
                     f'time (energy drifts upward); use semi_implicit_euler, rk4 or an error-controlled integrator '
                     f'for long runs')
    tau_stop = float(system.stop_time_constant(y)) if hasattr(system, 'stop_time_constant') else math.inf
    if a.verdict != 'refuse' and h > STOP_RESOLUTION[name] * tau_stop:
        a.verdict = 'refuse'
        a.extra['stop'] = True
        a.message = (f'{name} with dt={h:g} s does not resolve a joint stop of {type(system).__name__}'
                     f'{getattr(system, "time_constant_words", "")}: h/τ = {h / tau_stop:.3g}; an explicit step '
                     f'through a stop\'s bounce must keep h/τ <= {STOP_RESOLUTION[name]:g} (dt <= '
                     f'{STOP_RESOLUTION[name] * tau_stop:.3g} s), or it can throw the joint back faster than it came. '
                     f'{step_alternatives(system, h, y, u, t, J)}')
    return a


def step_alternatives(system, h, y, u=None, t: float = 0.0, J=None) -> str:
    """What to use instead of a refused explicit step of h (s) at y, as a sentence: rosenbrock2 first
    when it is stable there (the stiffness is passive), then a smaller dt and the error-controlled methods."""
    if J is None:
        J = linearisation(system, np.asarray(y, dtype=float), u, t)
    tail = 'or an error-controlled integrator (dop853, rk45) or a stiff one (radau, bdf, lsoda)'
    try:
        ok = _analyse_linearly_implicit(system, 'rosenbrock2', h, y, u, t, J).verdict != 'refuse'
    except (ValueError, np.linalg.LinAlgError):
        ok = False
    if ok:
        return (f'Use rosenbrock2 (linearly implicit in the passive forces, stable at this step; integrator: auto '
                f'picks it), a smaller dt, {tail}')
    return f'Use a smaller dt, {tail} (rosenbrock2 is not stable here either: the stiffness is not passive)'


def _analyse_linearly_implicit(system, name, h, y, u, t, J) -> StepAnalysis:
    """rosenbrock2 at step h (S4): the step matrix G of the linearisation J with the passive part
    ``Jp = system.passive_jacobian`` in its W-matrix (:func:`rosenbrock2_step_matrix`); each eigenvalue ν of
    G is paired with the mode λ of J whose true growth e^{hλ} it is nearest, and its spurious growth
    ``ln|ν| − h max(0, Re λ)`` (less the true growth of a saddle the run starts on) refuses.
    What stays explicit is Heun's method on the modes of J without the passive forces (``J − Jp`` on the
    rows after the configuration, whose Jp rows are the kinematics; S2's candidates), on a free base's
    spin ``±i ω/2`` and on the declared time constant the passive part does not hold
    (``System.explicit_time_constant``), which J may blur: those refuse too. A slow growth warns when
    both G on the modes that do not grow and Heun's on the explicit modes show it (G's eigenvalues near
    1 carry the round-off of J's finite differences amplified by near-defective zero modes, ~1e-7 per
    step; the explicit modes alone leave out the damping that holds them)."""
    Jp = passive_jacobian(system, y, u, t, h)
    lam = np.linalg.eigvals(J) if J.size else np.zeros(0, dtype=complex)
    nu = np.linalg.eigvals(rosenbrock2_step_matrix(J, Jp, h)) if J.size else np.zeros(0, dtype=complex)
    # each eigenvalue ν of G against the true growth e^{hλ} of the mode it approximates (the nearest)
    exact = np.exp(h * lam)
    paired = lam[np.argmin(np.abs(nu[:, None] - exact[None, :]), axis=1)] if nu.size else lam
    log_nu = np.log(np.maximum(np.abs(nu), 1e-300))
    g_matrix = float(np.max(log_nu - h * np.maximum(paired.real, 0.0))) if nu.size else -math.inf
    settled = paired.real <= 0.0    # modes that do not grow: any growth of theirs is the method's
    g_settled = float(np.max(log_nu[settled])) if np.any(settled) else -math.inf
    spin = spin_rate(system, y)
    Je = J.copy()   # the linearisation without the passive forces (Jp's configuration rows are kinematics)
    nq = int(getattr(system, 'nq', 0))
    Je[nq:] -= Jp[nq:]
    explicit = candidate_modes(np.linalg.eigvals(Je) if J.size else np.zeros(0, dtype=complex), spin)
    tau_e = float(system.explicit_time_constant(y)) if hasattr(system, 'explicit_time_constant') else math.inf
    declared = [0.5j * spin, -0.5j * spin] if spin > 0 else []
    if math.isfinite(tau_e) and tau_e > 0:
        declared.append(-1.0 / tau_e)
    explicit = np.concatenate([explicit, np.array(declared, dtype=complex)])

    def heun_growth(ms):
        return max((math.log(max(_scalar_amplification(name, h * m), 1e-300)) for m in ms), default=-math.inf)
    g_declared = heun_growth(declared)
    refuse_growth = max(g_matrix, g_declared)
    growth = max(min(g_settled, heun_growth(explicit)), g_declared)
    k = int(np.argmax(np.abs(explicit))) if explicit.size else -1
    worst = complex(explicit[k]) if k >= 0 else 0j
    modes = candidate_modes(lam, spin)
    lam_max = float(np.max(np.abs(modes))) if modes.size else 0.0
    sys_tau = float(system.fastest_time_constant(y)) if hasattr(system, 'fastest_time_constant') else math.inf
    dt_limit = stable_step_limit(name, worst) if worst != 0 else math.inf
    shown = refuse_growth if refuse_growth > REFUSE_GROWTH else growth
    doubling = h * math.log(2.0) / shown if shown > 0 else math.inf
    a = StepAnalysis(integrator=name, dt=h, eigenvalues=modes, lam_max=lam_max,
                     tau=1.0 / lam_max if lam_max > 0 else math.inf, spin=spin, system_tau=sys_tau,
                     rho=math.exp(shown), growth=shown, doubling_time=doubling, dt_limit=dt_limit, worst=worst,
                     extra={'passive_lam_max': float(np.max(np.abs(np.linalg.eigvals(Jp)))) if Jp.size else 0.0,
                            'explicit_lam_max': abs(worst), 'step_matrix_growth': g_matrix,
                            'settled_growth': g_settled})
    mode = (f'its fastest mode outside the passive forces has |λ| = {abs(worst):.3g} 1/s '
            f'(λ = {worst.real:.3g}{worst.imag:+.3g}i)')
    if refuse_growth > REFUSE_GROWTH:
        a.verdict = 'refuse'
        a.message = (f'{name} with dt={h:g} s is unstable for this system ({type(system).__name__}): it is implicit '
                     f'only in the passive forces (damping, friction, joint limits, ground contact, motor electrics) and {mode}; '
                     f'a mode grows by {math.exp(refuse_growth):.3g} per step; a stable step on that mode is at most '
                     f'{dt_limit:.3g} s. Use a smaller dt or a stiff error-controlled integrator (radau, bdf, lsoda)')
    elif growth > 0 and doubling < WARN_DOUBLING_TIME:
        a.verdict = 'warn'
        a.message = (f'{name} with dt={h:g} s amplifies a mode of {type(system).__name__} spuriously: outside the '
                     f'passive forces it is Heun\'s method, which lets an undamped oscillation of frequency ω grow '
                     f'by (ωh)⁴/8 per step; numerical growth {growth:.2e} per step doubles it every {doubling:.3g} s '
                     f'of simulated time; use rk4 or a smaller dt for long undamped runs')
    return a


def _mode_source(lam: complex, sys_tau: float, spin: float, sys_words: str = '') -> str:
    """Words saying where a mode comes from, when it can be told (sys_words: the system's own words
    for its declared time constant, e.g. which joint limit it is)."""
    if spin > 0 and abs(lam.real) < 0.05 * abs(lam) and any(abs(abs(lam) - f * spin) <= 0.05 * spin
                                                           for f in (0.5, 1.0)):
        return f'; the free base spins at {spin:.3g} rad/s'
    if math.isfinite(sys_tau) and sys_tau > 0 and abs(abs(lam) * sys_tau - 1.0) < 0.05:
        return sys_words or '; the system\'s declared fastest time constant, e.g. motor electrics L/R or Baumgarte gains'
    return ''


#: smallest eigenvalue of the mass matrix, relative to its largest, below which the preflight calls
#: it singular: accelerations along that eigenvector would be round-off amplified 1e15-fold
SINGULAR_RATIO = 1e-15


def _singular_joint(system, y) -> str:
    """Words naming the joint whose subtree has no inertia about its axis, or ''."""
    model = getattr(system, 'model', None)
    if model is None:
        return ''
    from . import dynamics as dyn
    try:
        q = system.minimal(y)[0] if hasattr(system, 'minimal') else np.asarray(y)[:model.nq]
        M = dyn.crba(model, q)
    except Exception:  # noqa: BLE001 - best effort: the caller reports the original error anyway
        return ''
    if M.size == 0:   # nothing moves (a fixed-base robot of fixed joints): nothing to be singular
        return ''
    if not np.all(np.isfinite(M)):
        return 'the mass matrix is not finite (a length, mass or inertia too large to compute with)' + _not_finite_where(model, M)
    d = np.diag(M)
    scale = max(float(np.max(np.abs(d))), 1e-300)
    names = [model.joint_names[i] for i in range(model.nb) for _ in range(int(model.nv_j[i]))]
    bad = [names[k] for k in range(len(d)) if d[k] <= 1e-15 * scale]
    if bad:
        return (f'joint(s) {", ".join(bad)} move a subtree with no mass or inertia about their axis, so the mass '
                f'matrix is singular; give the links beyond them a mass and inertia, or make the joint fixed')
    w, V = np.linalg.eigh(0.5 * (M + M.T))
    if w[0] <= SINGULAR_RATIO * max(w[-1], 1e-300):
        k = np.argsort(-np.abs(V[:, 0]))
        moving = [names[i] for i in k if abs(V[i, 0]) >= 0.1 * abs(V[k[0], 0])][:4]
        return (f'the mass matrix is singular (eigenvalues {w[0]:.3g} .. {w[-1]:.3g}): a motion of joints '
                f'{", ".join(moving)} meets no inertia (their axes line up here and the links between them '
                f'carry none about it); start from another configuration, or lock one of them')
    return ''


def preflight(system, y, t: float = 0.0) -> None:
    """Evaluate ``f`` once at the initial state; refuse (ValueError) what cannot be integrated.

    A singular mass matrix (a moving joint without inertia about its axis), a constraint system
    the system's solver refuses, or a non-finite derivative are reported with their cause.
    """
    u = start_inputs(system, y, t)
    try:
        f = np.asarray(system.rhs(t, np.array(y, dtype=float), u), dtype=float)
    except (np.linalg.LinAlgError, FloatingPointError, ZeroDivisionError) as e:
        cause = _singular_joint(system, y) or f'{type(e).__name__}: {e}'
        raise ValueError(f'{type(system).__name__}: the equations of motion cannot be solved at the initial '
                         f'state: {cause}') from e
    if not np.all(np.isfinite(f)):
        bad = np.flatnonzero(~np.isfinite(f))[:8].tolist()
        cause = _singular_joint(system, y) or f'components {bad} of dy/dt are non-finite'
        raise ValueError(f'{type(system).__name__}: the state derivative at the initial state is not finite: {cause}')
    cause = _singular_joint(system, y)   # finite but meaningless: accelerations of a singular M are round-off
    if cause:
        raise ValueError(f'{type(system).__name__}: the equations of motion cannot be solved at the initial '
                         f'state: {cause}')


def _not_finite_where(model, M) -> str:
    """Words naming where a non-finite mass matrix comes from: the links whose spatial inertia (mass,
    m·c, inertia about the origin) or joint placement is not finite, else the joints of its non-finite
    diagonal entries."""
    links = [f'{model.link_names[i]} (its {"spatial inertia" if not np.all(np.isfinite(model.I[i])) else "joint origin"})'
             for i in range(model.nb) if not (np.all(np.isfinite(model.I[i])) and np.all(np.isfinite(model.Xtree[i])))]
    if links:
        return ': link ' + ', '.join(links[:4])
    names = [model.joint_names[i] for i in range(model.nb) for _ in range(int(model.nv_j[i]))]
    bad = list(dict.fromkeys(names[k] for k in np.flatnonzero(~np.isfinite(np.diag(M)))))
    return f': at joint{"s" if len(bad) > 1 else ""} {", ".join(bad[:4])}' if bad else ''


def _not_finite_cause(system, y, J) -> str:
    """Why a linearisation J (ny, ny) is not finite: the joint the mass matrix cannot accelerate
    (:func:`_singular_joint`), else the state components whose rate derivatives are not finite."""
    cause = _singular_joint(system, y)
    if cause:
        return cause
    bad = np.flatnonzero(~np.all(np.isfinite(J), axis=0))[:4]
    return ('the derivative of dy/dt is not finite with respect to ' +
            ', '.join(_state_words(system, int(k)) for k in bad) if bad.size else 'non-finite entries')


def _state_words(system, k: int) -> str:
    """``y[k]``, with the joint it belongs to when the state is ``[q, v, ...]`` of 1-DOF joints."""
    names = list(getattr(system, 'joint_names', None) or ())
    nq, nv = getattr(system, 'nq', None), getattr(system, 'nv', None)
    if names and nq == nv == len(names) and k < 2 * nq:
        return f'y[{k}], the {"position" if k < nq else "velocity"} of joint {names[k % nq]!r}'
    return f'y[{k}]'


def stiff_mode(system, y, u=None, t: float = 0.0) -> str:
    """Words on the fastest mode of the linearisation at (t, y) with inputs u (S1): its |λ|, time
    constant, where it comes from when the system says (declared time constant, base spin), and
    the state component its eigenvector lies mostly on; '' when the linearisation fails."""
    try:
        J = linearisation(system, y, u, t)
        if not np.all(np.isfinite(J)) or not J.size:
            return ''
        lam, vec = np.linalg.eig(J)
    except Exception:  # noqa: BLE001 - words for a message: never hide the failure they explain
        return ''
    k = int(np.argmax(np.abs(lam)))
    lk = complex(lam[k])
    if lk == 0:
        return ''
    sys_tau = float(system.fastest_time_constant(y)) if hasattr(system, 'fastest_time_constant') else math.inf
    source = _mode_source(lk, sys_tau, spin_rate(system, y), getattr(system, 'time_constant_words', ''))
    where = _state_words(system, int(np.argmax(np.abs(vec[:, k]))))
    return (f'the fastest mode at t={t:.6g} s has |λ| = {abs(lk):.3g} 1/s (λ = {lk.real:.3g}{lk.imag:+.3g}i, '
            f'time constant {1.0 / abs(lk):.3g} s{source}), mostly {where}')


def diagnose(system, y, u, integrator: str, dt=None, t: float = 0.0) -> str:
    """A sentence on the likely cause of a failed run, from its last good state (or '').

    Linearises at y with the inputs u that were held, reports the fastest mode against the step
    (fixed-step methods) or its stiffness (error-controlled ones) and the largest command.
    """
    parts = []
    try:
        big = {k: float(np.max(np.abs(np.asarray(x, dtype=float)))) for k, x in (u or {}).items() if np.size(x)}
        if big:
            k = max(big, key=big.get)
            parts.append(f'largest command {k} = {big[k]:.3g} {getattr(system.inputs.get(k), "unit", "")}'.rstrip())
        spin = spin_rate(system, y)
        if spin > 0:
            parts.append(f'base spin {spin:.3g} rad/s')
        f = np.asarray(system.rhs(t, np.asarray(y, dtype=float), u), dtype=float)
        if f.size and np.all(np.isfinite(f)):
            k = int(np.argmax(np.abs(f)))
            parts.append(f'largest state rate |dy/dt| = {abs(f[k]):.3g} (y[{k}])')
        J = linearisation(system, y, u, t)
        if np.all(np.isfinite(J)):
            lam = np.linalg.eigvals(J)
            k = int(np.argmax(np.abs(lam)))
            text = f'fastest mode |λ| = {abs(lam[k]):.3g} 1/s (time constant {1.0 / max(abs(lam[k]), 1e-300):.3g} s)'
            name = str(integrator).lower()
            if name in FIXED_EXPLICIT and dt and abs(lam[k]) > 0.0:  # (a still system has no step limit)
                text += (f', h·|λ| = {dt * abs(lam[k]):.3g} for {name} dt={dt:g} s '
                         f'(stable up to {stable_step_limit(name, complex(lam[k])) * abs(lam[k]):.3g})')
            parts.append(text)
        else:
            parts.append('the linearisation is already non-finite there')
    except Exception as e:  # noqa: BLE001 - a diagnosis must never hide the original failure
        parts.append(f'(no diagnosis: {type(e).__name__})')
    return ('at the last good state: ' + '; '.join(parts)) if parts else ''
