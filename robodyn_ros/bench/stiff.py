"""``robodyn bench stiff``: stiff robots at a fixed step, what ``integrator: auto`` chooses and achieves.

Sections (each can be skipped with ``--skip``; ``robodyn bench speed`` runs them as its ``stiff``
section):

* ``robots``  every example-robot-data URDF that imports (``**/*.urdf`` under the installed data; a
  file that does not import is listed with the reason, so the table grows as the importer does): a
  1 s fall with the defaults of ``robodyn run FILE`` (fixed base, no command, dt = 1 ms, integrator
  auto): robot, DOF, the method auto chose, the real-time factor of ``Simulator.advance`` in 10 ms
  periods (wall, best of ``--repeat``), and the largest joint-position error over the run (sampled
  every 10 ms) against Pinocchio's ABA with the URDF's damping and the documented Coulomb law
  (``−f tanh(q̇/v_s)``, v_s = ``urdf.COULOMB_VELOCITY``) integrated by scipy's Radau at rtol 1e-10
  with Pinocchio's analytic derivatives (Pinocchio parses the URDF itself);
* ``mujoco``  xarm7 with damping only (friction attributes removed, no limits on either side), 1 s
  from q = 0 at 1 ms: rosenbrock2 against MuJoCo's implicitfast, implicit and Euler integrators
  stepped from Python (one ``mj_step`` per step, qpos read every 10 ms), errors against the same
  reference and real-time factors measured in this run;
* ``scenes``  huston_human17 (joint stops) and the inductive-motor platform of the extremes table
  (betancur_platform with L = 1e-5 H, L/R = 5.9 µs) run at 1 ms by rosenbrock2 over 1 s with their
  scripted commands, final-state error (``measures.state_error``) against Radau at rtol 1e-11 on
  the same equations.

Figures to read, never asserted by tests (test/test_rosenbrock*.py holds the asserted checks).
"""
from __future__ import annotations

import glob
import math
import os
import re
import time
import warnings

import numpy as np

from .timing import machine_line, table

HELP = 'stiff robots at 1 ms: auto\'s choice, RTF and error per example-robot-data URDF, xarm7 vs MuJoCo implicit'
SECTIONS = ('robots', 'mujoco', 'scenes')
#: step, publication rate and horizon of the runs
DT, RATE, HORIZON = 1e-3, 100.0, 1.0
#: tolerance of the Radau reference of the robot table
REF_RTOL = 1e-10
#: wall seconds after which a robot's run (or its reference) is given up
BUDGET = 300.0


def add_arguments(p):
    """Options of ``robodyn bench stiff``."""
    p.add_argument('--out', default=None, help='also write the markdown report to this file')
    p.add_argument('--robots', nargs='*', default=None,
                   help='URDF file names (stem) of the robots table (default: every example-robot-data URDF)')
    p.add_argument('--repeat', type=int, default=3, help='timed repeats per run (best kept; default 3)')
    p.add_argument('--skip', nargs='*', default=[], choices=SECTIONS, help='sections to leave out')


def main(args) -> int:
    """Run the sections and print (and optionally write) the markdown report."""
    text = report(args)
    print(text)
    if args.out:
        with open(args.out, 'w') as f:
            f.write(text + '\n')
    return 0


def report(args) -> str:
    """The markdown of the sections not skipped."""
    parts = [f'# Stiff robots at a fixed step\n\n{machine_line()}\n']
    if 'robots' not in args.skip:
        parts.append(section_robots(args))
    if 'mujoco' not in args.skip:
        parts.append(section_mujoco(args))
    if 'scenes' not in args.skip:
        parts.append(section_scenes(args))
    return '\n'.join(parts)


# ----------------------------------------------------------------------------------------------
# the reference: Pinocchio's own URDF parser and ABA, scipy's Radau
# ----------------------------------------------------------------------------------------------
def xml_mimics(urdf_text: str) -> dict:
    """``{joint: (independent joint, multiplier, offset)}`` read from the URDF with ElementTree alone (not
    our importer), chains of mimics composed."""
    import xml.etree.ElementTree as ET
    direct = {}
    for j in ET.fromstring(urdf_text.lstrip()).iter('joint'):
        m = j.find('mimic')
        if m is not None and j.get('type') != 'fixed':
            direct[j.get('name')] = (m.get('joint'), float(m.get('multiplier', 1)), float(m.get('offset', 0)))
    out = {}
    for j, (src, k, o) in direct.items():
        seen = {j}
        while src in direct and src not in seen:
            seen.add(src)
            s2, k2, o2 = direct[src]
            src, k, o = s2, k * k2, k * o2 + o
        out[j] = (src, k, o)
    return out


def pinocchio_fall(urdf_text: str, names, q0, v0, horizon=HORIZON, rate=RATE, rtol=REF_RTOL, friction=True):
    """Joint positions (n, len(names)) every 1/rate s over horizon of the URDF robot on a fixed base,
    unforced: ``M q̈ + C + g = −D q̇ − F tanh(q̇/v_s)`` with D, F as Pinocchio reads ``<dynamics>``, by
    Radau at rtol (atol = rtol/100). names: our joint order; q0, v0 in it. A continuous joint
    (Pinocchio's q = (cos θ, sin θ)) is integrated in θ. Joints of Pinocchio's model that are not in
    names (those our importer locks: no mass below them) are locked with ``buildReducedModel`` at 0, or
    where their mimic law puts them. ``<mimic>`` joints (coupling read from the XML with ElementTree):
    the motion is integrated in the independent joints r, ``θ = G r + θ₀``, ``r̈ = (Gᵀ M G)⁻¹ Gᵀ (τ − h)``
    from Pinocchio's CRBA and RNEA of the unreduced model, the Jacobian by differences; without mimic
    joints, ABA with the Jacobian from ``computeABADerivatives``."""
    import pinocchio as pin
    from scipy.integrate import solve_ivp

    from ..urdf import COULOMB_VELOCITY
    pm = pin.buildModelFromXML(urdf_text)
    every = xml_mimics(urdf_text)
    mimics = {k: c for k, c in every.items() if k in names and c[0] in names}   # else independent, as ours
    extra = [j for j in range(1, pm.njoints) if pm.joints[j].nv == 1 and pm.names[j] not in set(names)]
    if extra:   # locked by our importer: lock them here too
        qref = pin.neutral(pm)
        for j in extra:
            src = every.get(pm.names[j])
            if src is not None and pm.joints[j].nq == 1:
                qref[pm.joints[j].idx_q] = src[1] * 0.0 + src[2]
        pm = pin.buildReducedModel(pm, extra, qref)
    pd = pm.createData()
    nv = pm.nv
    idx = {pm.names[j]: j for j in range(1, pm.njoints)}
    jv = np.array([pm.joints[idx[n]].idx_v for n in names], dtype=int)    # our k -> Pinocchio's v index
    cont = [(pm.joints[j].idx_q, pm.joints[j].idx_v) for j in range(1, pm.njoints) if pm.joints[j].nq == 2]
    lin = [(pm.joints[j].idx_q, pm.joints[j].idx_v) for j in range(1, pm.njoints) if pm.joints[j].nq == 1]
    D = np.asarray(pm.damping, dtype=float).copy()
    F = np.asarray(pm.friction, dtype=float).copy() if friction else np.zeros(nv)
    vs = COULOMB_VELOCITY
    ts = np.arange(1, int(round(horizon * rate)) + 1) / rate
    if nv == 0:
        return np.zeros((len(ts), 0))

    def q_pin(th):
        q = pin.neutral(pm)
        for iq, iv in lin:
            q[iq] = th[iv]
        for iq, iv in cont:
            q[iq], q[iq + 1] = math.cos(th[iv]), math.sin(th[iv])
        return q

    def passive(v):
        return -D * v - F * np.tanh(v / vs)

    th0, w0 = np.zeros(nv), np.zeros(nv)
    th0[jv], w0[jv] = q0, v0
    if mimics:
        ind = [j for j in range(nv) if pm.names[next(k for k in range(1, pm.njoints)
                                                     if pm.joints[k].idx_v == j)] not in mimics]
        vname = {pm.joints[k].idx_v: pm.names[k] for k in range(1, pm.njoints)}
        G, off = np.zeros((nv, len(ind))), np.zeros(nv)
        for i in range(nv):
            src, mul, o = mimics.get(vname[i], (vname[i], 1.0, 0.0))
            G[i, ind.index(next(k for k in ind if vname[k] == src))] = mul
            off[i] = o

        def f(t, x):
            r, rd = x[:len(ind)], x[len(ind):]
            th, v = G @ r + off, G @ rd
            M = pin.crba(pm, pd, q_pin(th))
            M = np.triu(M) + np.triu(M, 1).T
            h = pin.rnea(pm, pd, q_pin(th), v, np.zeros(nv))
            return np.concatenate([rd, np.linalg.solve(G.T @ M @ G, G.T @ (passive(v) - h))])
        x0 = np.concatenate([th0[ind], w0[ind]])
        sol = solve_ivp(f, (0.0, ts[-1]), x0, method='Radau', rtol=rtol, atol=rtol * 1e-2, t_eval=ts,
                        max_step=1.0 / rate)   # (differenced Jacobian: long trial steps met singular states)
        if not sol.success:
            raise RuntimeError(f'Radau reference failed: {sol.message}')
        return (G @ sol.y[:len(ind)] + off[:, None])[jv].T

    def f(t, x):
        th, v = x[:nv], x[nv:]
        return np.concatenate([v, pin.aba(pm, pd, q_pin(th), v, passive(v))])

    def jac(t, x):
        th, v = x[:nv], x[nv:]
        pin.computeABADerivatives(pm, pd, q_pin(th), v, passive(v))
        Minv = np.triu(pd.Minv) + np.triu(pd.Minv, 1).T
        dtau = -D - F * (1.0 - np.tanh(v / vs) ** 2) / vs
        J = np.zeros((2 * nv, 2 * nv))
        J[:nv, nv:] = np.eye(nv)
        J[nv:, :nv] = pd.ddq_dq
        J[nv:, nv:] = pd.ddq_dv + Minv * dtau[None, :]
        return J
    sol = solve_ivp(f, (0.0, ts[-1]), np.concatenate([th0, w0]), method='Radau', rtol=rtol, atol=rtol * 1e-2,
                    jac=jac, t_eval=ts)
    if not sol.success:
        raise RuntimeError(f'Radau reference failed: {sol.message}')
    return sol.y[jv].T


def robodyn_fall(scene, integrator='auto', horizon=HORIZON, rate=RATE, repeat=3, budget=BUDGET, plan=None):
    """``(positions (n, nv), Simulator, best wall seconds)`` of the scene run from its initial state with
    no command, in periods of 1/rate s (the fused path, as ``robodyn run`` without a recorder); plan: the
    integrator plan (default: ``integrator`` at ``DT``, planned once for the repeats)."""
    from ..integrator_choice import plan_integrator
    from ..simulation import Simulator
    if plan is None:
        plan = plan_integrator(scene.system, scene.y0, integrator, DT)
    best, out, sim = math.inf, None, None
    for _ in range(max(1, repeat)):
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            sim = Simulator(scene.system, scene.y0, plan=plan)
        n = int(round(horizon * rate))
        q = np.empty((n, scene.system.nq))
        w0 = time.perf_counter()
        for k in range(n):
            q[k] = sim.advance((k + 1) / rate)[:scene.system.nq]
            if time.perf_counter() - w0 > budget:
                raise TimeoutError(f'stopped after {budget:g} s wall at t = {sim.t:.3g} s')
        wall = time.perf_counter() - w0
        if wall < best:
            best, out = wall, q
    return out, sim, best


def erd_urdfs(stems=None) -> list:
    """Every example-robot-data URDF path (sorted), or those whose file stem is in stems."""
    from ..urdf import example_robot_data_dir
    d = example_robot_data_dir()
    if d is None:
        return []
    files = sorted(glob.glob(os.path.join(str(d), '**', '*.urdf'), recursive=True))
    if stems:
        files = [f for f in files if os.path.splitext(os.path.basename(f))[0] in set(stems)]
    return files


def _load_urdf(path, text=None):
    """The scene of ``robodyn run FILE`` (fixed base, defaults) for a URDF path (or its edited text)."""
    from ..scene import load_scene, parse_scene, urdf_scene_text
    from ..systems.base import backend_scope, tools_backend
    with backend_scope(tools_backend()):
        if text is None:
            return load_scene(path)
        return parse_scene(urdf_scene_text(path, text=text), file=path, path=path)


def _fmt(x, spec='.2g'):
    return '—' if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, spec)


def robot_row(path, repeat=3) -> dict:
    """One row of the robots table (see the module docstring); never raises."""
    from ..integrator_choice import plan_integrator
    name = os.path.splitext(os.path.basename(path))[0]
    row = {'robot': name, 'dof': None, 'method': '', 'rtf': math.nan, 'error': math.nan, 'note': ''}
    try:
        scene = _load_urdf(path)
    except Exception as e:  # noqa: BLE001 - a URDF that does not import is a row with the reason
        row['note'] = 'does not import: ' + ' '.join(str(e).split())[:160]
        return row
    system = scene.system
    row['dof'] = system.nv
    try:
        plan = plan_integrator(system, scene.y0, dt=DT)
        row['method'] = plan.integrator
        q, sim, wall = robodyn_fall(scene, repeat=repeat, plan=plan)
        row['rtf'] = HORIZON / wall
        names = list(system.joint_names)
        with open(path) as f:
            text = f.read()
        if system.nv == 0:
            row['note'] = 'no moving joint: nothing to compare'
            return row
        try:
            ref = pinocchio_fall(text, names, scene.y0[:system.nq], scene.y0[system.nq:])
        except (ValueError, RuntimeError, np.linalg.LinAlgError) as e:
            row['note'] = f'the reference (Pinocchio + Radau) failed: {type(e).__name__}: ' + ' '.join(str(e).split())[:120]
            return row
        row['error'] = float(np.max(np.abs(q - ref)))
    except Exception as e:  # noqa: BLE001 - the row says what went wrong
        row['note'] = f'{type(e).__name__}: ' + ' '.join(str(e).split())[:160]
    return row


def section_robots(args) -> str:
    """The example-robot-data table."""
    files = erd_urdfs(args.robots)
    if not files:
        return '## Example-robot-data URDFs\n\nexample-robot-data is not installed (test extras).\n'
    rows = []
    for path in files:
        r = robot_row(path, repeat=args.repeat)
        rows.append([r['robot'], _fmt(r['dof'], 'd') if r['dof'] is not None else '—', r['method'] or '—',
                     _fmt(r['rtf'], '.0f'), _fmt(r['error']), r['note']])
        print(f'  {r["robot"]}: {r["method"]} RTF {_fmt(r["rtf"], ".0f")} error {_fmt(r["error"])} {r["note"]}',
              flush=True)
    ok = [r for r in rows if r[2] != '—']
    refused = [r for r in rows if 'refused' in r[5] or 'unstable' in r[5]]
    head = (f'## Example-robot-data URDFs: 1 s fall with the defaults (dt = {DT * 1e3:g} ms, integrator auto)\n\n'
            f'{len(files)} URDF files, {len(ok)} import; stiff refusals with the defaults: {len(refused)}. Error: the '
            f'largest joint-position error (rad or m) over the run against Pinocchio ABA + damping + Coulomb '
            f'friction integrated by Radau at rtol {REF_RTOL:g}; RTF: simulated / wall seconds of '
            f'Simulator.advance in 10 ms periods, best of {args.repeat}.\n\n')
    return head + table(['robot', 'DOF', 'auto chose', 'RTF', 'error', 'note'], rows) + '\n'


# ----------------------------------------------------------------------------------------------
# xarm7 against MuJoCo's implicit integrators
# ----------------------------------------------------------------------------------------------
def damping_only(urdf_text: str) -> str:
    """The URDF without Coulomb friction (friction attributes dropped) and without position limits
    (revolute joints written as continuous), as the issue's MuJoCo comparison has it."""
    text = re.sub(r'\s+friction="[^"]*"', '', urdf_text)
    return re.sub(r'type="revolute"', 'type="continuous"', text)


def mujoco_fall(urdf_text, names, integrator, q0, repeat=3, horizon=HORIZON, rate=RATE, dt=DT, cpu=False):
    """``(positions (n, len(names)), best wall seconds)`` of MuJoCo stepping the URDF at dt from q0 with
    the named integrator ('implicitfast', 'implicit', 'euler'), one mj_step per Python call, qpos read
    every 1/rate s; or ``(None, reason)``. cpu: return ``(positions, best wall seconds, CPU seconds of that
    run)`` (the stepping loop alone, as the wall figure; not the model's building)."""
    try:
        import mujoco
    except ImportError:
        return None, 'mujoco not installed'
    text = re.sub(r'<(visual|collision)\b.*?</\1>', '', urdf_text, flags=re.DOTALL)   # no meshes to load
    text = text.replace('<link ', '<mujoco><compiler boundinertia="1e-9"/></mujoco>\n  <link ', 1)
    m = mujoco.MjModel.from_xml_string(text)
    m.opt.timestep = dt
    m.opt.integrator = {'implicitfast': mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
                        'implicit': mujoco.mjtIntegrator.mjINT_IMPLICIT,
                        'euler': mujoco.mjtIntegrator.mjINT_EULER}[integrator]
    adr = np.array([m.joint(n).qposadr[0] for n in names])
    n = int(round(horizon * rate))
    per = int(round(1.0 / (rate * dt)))
    best, out, best_cpu = math.inf, None, math.inf
    for _ in range(max(1, repeat)):
        d = mujoco.MjData(m)
        d.qpos[adr] = q0
        q = np.empty((n, len(names)))
        step = mujoco.mj_step
        w0, c0 = time.perf_counter(), time.process_time()
        for k in range(n):
            for _ in range(per):
                step(m, d)
            q[k] = d.qpos[adr]
        wall, c = time.perf_counter() - w0, time.process_time() - c0
        if wall < best:
            best, out, best_cpu = wall, q, c
    return (out, best, best_cpu) if cpu else (out, best)


#: MuJoCo's runs of the xarm7 comparison: (integrator, step); the shorter steps show what its first-order
#: methods pay for robodyn's accuracy at 1 ms
MUJOCO_RUNS = (('implicitfast', DT), ('implicit', DT), ('euler', DT), ('implicitfast', 1e-4), ('implicitfast', 1e-5))


def xarm7_comparison(repeat=3) -> dict:
    """rosenbrock2 and MuJoCo's implicit integrators on xarm7 with damping only: ``{label: (error, rtf)}``."""
    files = erd_urdfs(['xarm7'])
    if not files:
        return {}
    with open(files[0]) as f:
        text = damping_only(f.read())
    scene = _load_urdf(files[0], text=text)
    system = scene.system
    names = list(system.joint_names)
    q0 = scene.y0[:system.nq]
    ref = pinocchio_fall(text, names, q0, scene.y0[system.nq:])
    out = {}
    q, sim, wall = robodyn_fall(scene, repeat=repeat)
    out[f'robodyn {sim.settings["integrator"]} (auto)'] = (float(np.max(np.abs(q - ref))), HORIZON / wall)
    for integ, dt in MUJOCO_RUNS:
        qm, wall = mujoco_fall(text, names, integ, q0, repeat=repeat, dt=dt)
        label = f'MuJoCo {integ}' + ('' if dt == DT else f' at {dt * 1e3:g} ms')
        if qm is None:
            out[label] = (math.nan, math.nan)
        else:
            out[label] = (float(np.max(np.abs(qm - ref))), HORIZON / wall)
    return out


def section_mujoco(args, figures=None) -> str:
    """xarm7 against MuJoCo (see the module docstring); figures (dict): filled with the results."""
    res = xarm7_comparison(args.repeat)
    if figures is not None:
        figures.update(res)
    if not res:
        return '## xarm7 against MuJoCo\n\nexample-robot-data is not installed.\n'
    rows = [[k, _fmt(e), _fmt(r, '.0f')] for k, (e, r) in res.items()]
    return ('## xarm7 with damping only, 1 s at 1 ms: robodyn against MuJoCo stepped from Python\n\n'
            'MuJoCo also at 0.1 and 0.01 ms: its implicit methods are first order in the step.\n\n'
            f'Error: largest joint-position error (rad) against Pinocchio ABA + damping by Radau at rtol {REF_RTOL:g}. '
            f'RTF: simulated / wall seconds, best of {args.repeat}, measured in this run.\n\n'
            + table(['integrator', 'error (rad)', 'RTF'], rows) + '\n')


# ----------------------------------------------------------------------------------------------
# bundled scenes with stiff passive forces
# ----------------------------------------------------------------------------------------------
def stiff_scenes() -> dict:
    """label -> Scene: huston_human17, and the platform with L/R = 5.9 µs motors (the extremes table's)."""
    from .extremes import _scene_variant
    from .precision import _load
    return {'huston_human17': _load('huston_human17'),
            'betancur_platform, L/R = 5.9 µs': _scene_variant('betancur_platform',
                                                             ('inductance: 0.0', 'inductance: 1.0e-5'))}


def section_scenes(args) -> str:
    """human17 and the inductive platform at 1 ms with rosenbrock2 against Radau at rtol 1e-11."""
    from ..measures import state_error
    from .precision import simulate
    rows = []
    for label, scene in stiff_scenes().items():
        ref = simulate(scene, 'radau', rtol=1e-11, atol=1e-13, horizon=HORIZON, sample=False)
        run = simulate(scene, 'rosenbrock2', dt=DT, horizon=HORIZON, sample=False)
        rk4 = simulate(scene, 'rk4', dt=DT, horizon=HORIZON, sample=False)
        err = state_error(run.y, ref.y) if run.y is not None and ref.y is not None else math.nan

        def rtf(r):
            return 1.0 / r.wall_per_sim_s if r.status == 'ok' and r.wall_per_sim_s > 0 else math.nan
        rk4_err = state_error(rk4.y, ref.y) if rk4.y is not None and ref.y is not None else math.nan
        rows.append([label, run.status, _fmt(err), _fmt(rtf(run), '.0f'),
                     f'{rk4.status}' + (f', error {_fmt(rk4_err)}, RTF {_fmt(rtf(rk4), ".0f")}' if rk4.status == 'ok'
                                        else f' ({" ".join(rk4.note.split())[:90]})')])
    return ('## Stiff passive forces in the bundled systems: rosenbrock2 at 1 ms over 1 s\n\n'
            'Error: final-state error (measures.state_error, relative per component) against Radau at rtol 1e-11 '
            'on the same equations, scripted commands applied.\n\n'
            + table(['scene', 'status', 'error', 'RTF', 'rk4 at 1 ms'], rows) + '\n')
