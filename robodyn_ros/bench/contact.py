"""``robodyn bench contact``: the standing quadruped (``a1_stand``) against MuJoCo on the same URDF.

Two parts, each printed as a table (``--out FILE`` writes them as markdown; ``make bench`` writes
``docs/bench_contact.md``):

* **comparison** — the drop and stand of ``a1_stand`` run by robodyn and by MuJoCo on the same URDF
  (MuJoCo reads its collision primitives; the robot on a free joint, a plane at height 0, the same μ,
  the same PD law at the same rate, effort limits and no joint-limit constraints on both sides):
  time of first impact, base height at rest, total vertical ground force at rest, the feet's
  penetration. MuJoCo's compliance is matched at rest: its ``solref`` time constant is calibrated
  (two short runs) so that its feet sink as deep as ours (its penetration at rest grows as the
  square of the time constant); its damping ratio is 1, its ``solimp`` the default.
* **speed** — real-time factor of ``a1_stand`` at its step (1 ms), fully recorded (every topic, as
  ``robodyn run --record``), beside MuJoCo (implicitfast, 1 ms) stepped from Python with the PD
  computed in Python at the same rate and its state copied out every period, measured in the
  same run (CPU time, median of ``--repeat`` runs).

* **steps** (``--steps``, instead of the two above) — the integrator and step of each bundled ground
  scene (``a1_stand``, ``solo12_drop``, ``huston_human17_fall``) against rk4 at 25 µs over the scene's
  duration: the largest joint-position difference at the publications and the one at the end (at
  rest), the base height at the end, the energy balance ``E − E0 − W`` beside the work W, and the
  CPU time per simulated second; then A1 at 1 ms on the generic rosenbrock2 step (the Python path:
  ``integrators.Rosenbrock2`` with the system's passive Jacobian) with either root of γ held for the
  whole run, the choice docs/contact.md explains. The table of docs/contact.md, "Integrator and step".

Figures are printed, never asserted here; ``test/test_contact_mujoco.py`` asserts the comparison's
tolerances and ``test/test_contact_implicit.py`` the steps' bounds.
"""
from __future__ import annotations

import math
import os
import tempfile
import time
import warnings

import numpy as np

HELP = 'the standing quadruped (a1_stand) against MuJoCo on the same URDF: drop, rest, real-time factor'
#: the scene compared and timed
SCENE = 'a1_stand'
#: MuJoCo's joint-space PD uses the scene's pd_hold parameters; its first guess of the time constant
MUJOCO_TIMECONST0 = 0.02


def add_arguments(p):
    """Options of the contact benchmark."""
    p.add_argument('--out', default=None, help='also write the tables (markdown) to this file')
    p.add_argument('--duration', type=float, default=3.0, help='simulated seconds of each run (default 3)')
    p.add_argument('--integrator', default=None, help='our integrator (default: the scene\'s)')
    p.add_argument('--dt', type=float, default=None, help='our step (default: the scene\'s)')
    p.add_argument('--repeat', type=int, default=3, help='timed runs of each (median; default 3)')
    p.add_argument('--skip-speed', action='store_true', help='the comparison only')
    p.add_argument('--steps', action='store_true',
                   help='instead: the integrator and step of each bundled ground scene against rk4 at 25 us, '
                        'and A1 on the generic rosenbrock2 step with either root of gamma')
    return p


# ------------------------------------------------------------------------------------------------
# ours
# ------------------------------------------------------------------------------------------------
def load(scene=SCENE):
    """The loaded scene (its URDF's warnings silenced)."""
    from ..scene import load_scene
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        return load_scene(scene)


def urdf_path(sc) -> str:
    """The file of the scene's URDF part (its ``package://`` path resolved)."""
    from ..meshes import resolve_uri
    return str(resolve_uri(str(sc.data['parts'][0]['file'])))


def pd_params(sc) -> dict:
    """The scene's pd_hold keys and rate: ``{posture: {joint: q}, kp, kd, rate}``."""
    c = sc.data['commands']['effort']
    names = list(sc.system.actuated)

    def per_joint(v):
        return dict(zip(names, v)) if isinstance(v, list) else {n: float(v) for n in names}
    return {'posture': dict(c['posture']), 'kp': per_joint(c['kp']), 'kd': per_joint(c['kd']),
            'rate': float(sc.settings['publish_rate'])}


def ours(sc, duration, integrator=None, dt=None, impact_step=1e-3):
    """Drop and stand of scene sc: ``{'impact': first time a point touches (s, to impact_step), 't', 'z'
    (base height per period), 'fz' (Σ vertical ground force per period), 'depth' (feet at the end)}``."""
    from ..kernels.contact import PACTIVE, PDEPTH, PF
    from ..simulation import Simulator
    s = sc.system
    integrator = integrator or sc.settings['integrator']
    dt = dt or sc.settings['dt']
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        sim = Simulator(s, sc.y0, integrator=integrator, dt=dt)
    rate = float(sc.settings['publish_rate'])
    n = int(round(duration * rate))
    sub = max(1, int(round(1.0 / (rate * impact_step))))
    impact, ts, zs, fz = None, [], [], []
    for k in range(n):
        for port, val in sc.script(sim.t, sim.y).items():
            sim.set_command(port, val)
        t0 = k / rate
        for j in range(1, sub + 1):
            sim.advance(t0 + j / (rate * sub))
            if impact is None:
                P = s.contact.point_outputs(s._km, sim.y[:s.nq], sim.y[s.nq:])
                if (P[:, PACTIVE] > 0).any():
                    impact = sim.t
        P = s.contact.point_outputs(s._km, sim.y[:s.nq], sim.y[s.nq:])
        ts.append(sim.t)
        zs.append(sim.y[2])
        fz.append(float(P[P[:, PACTIVE] > 0, PF + 2].sum()))
    on = P[:, PACTIVE] > 0
    return {'impact': impact, 't': np.array(ts), 'z': np.array(zs), 'fz': np.array(fz),
            'depth': P[on, PDEPTH], 'sim': sim}


# ------------------------------------------------------------------------------------------------
# MuJoCo
# ------------------------------------------------------------------------------------------------
def mujoco_ground_model(urdf_path, mu, timeconst, dampratio=1.0, dt=1e-3, height=0.0):
    """MuJoCo model of a URDF on a free joint above a plane, or ``(None, reason)``.

    Every geom of the robot collides with the plane only (contype 1, conaffinity 0; the plane 0, 1), with
    sliding friction mu (torsional and rolling 0); contact ``solref (timeconst, dampratio)``, default
    ``solimp``; joint limits off (ours are reported, not enforced, on a floating URDF); integrator
    implicitfast at step dt."""
    try:
        import mujoco
    except ImportError:
        return None, 'mujoco not installed'
    try:
        spec = mujoco.MjSpec.from_file(str(urdf_path))
    except Exception as e:   # MuJoCo's URDF importer refuses some files: say why
        return None, f'MuJoCo cannot load the URDF ({" ".join(str(e).split())})'
    spec.compiler.boundinertia = 1e-9
    root = spec.worldbody.first_body()
    root.add_freejoint()
    for g in spec.geoms:
        g.contype, g.conaffinity = 1, 0
        g.friction = [mu, 0.0, 0.0]
        g.solref = [timeconst, dampratio]
        g.condim = 3
    floor = spec.worldbody.add_geom()
    floor.type = mujoco.mjtGeom.mjGEOM_PLANE
    floor.size = [0.0, 0.0, 1.0]
    floor.pos = [0.0, 0.0, height]
    floor.contype, floor.conaffinity = 0, 1
    floor.friction = [mu, 0.0, 0.0]
    floor.solref = [timeconst, dampratio]
    floor.condim = 3
    m = spec.compile()
    m.jnt_limited[:] = 0
    m.opt.timestep = dt
    m.opt.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    return m, ''


class MujocoPD:
    """The scene's drop and stand in MuJoCo: state mapped from ours, the PD computed in Python at the
    scene's rate (clamped to the URDF's effort limits) and applied as generalised forces."""

    def __init__(self, m, sc):
        import mujoco
        self.m = m
        s = sc.system
        model = s.model
        self.names = list(s.actuated)
        self.qadr = np.array([m.jnt_qposadr[m.joint(n).id] for n in self.names])
        self.vadr = np.array([m.jnt_dofadr[m.joint(n).id] for n in self.names])
        p = pd_params(sc)
        self.posture = np.array([p['posture'].get(n, 0.0) for n in self.names])
        self.kp = np.array([p['kp'][n] for n in self.names])
        self.kd = np.array([p['kd'][n] for n in self.names])
        self.rate = p['rate']
        specs = {sp.joint: sp for sp in model.specs}
        self.limit = np.array([specs[n].effort_limit or np.inf for n in self.names])
        q0 = sc.y0[:s.nq]
        d = mujoco.MjData(m)
        d.qpos[0:3] = q0[0:3]
        d.qpos[3:7] = [q0[6], q0[3], q0[4], q0[5]]          # MuJoCo: w x y z
        for n, a in zip(self.names, self.qadr):
            d.qpos[a] = q0[model.q_idx[model.joint_names.index(n)]]
        mujoco.mj_forward(m, d)
        self.d0 = d

    def run(self, duration, copy_state=False):
        """``{'impact', 't', 'z', 'fz', 'depth'}`` as :func:`ours` (impact to the step)."""
        import mujoco
        m = self.m
        d = mujoco.MjData(m)
        d.qpos[:] = self.d0.qpos
        d.qvel[:] = 0.0
        mujoco.mj_forward(m, d)
        nstep = max(1, int(round(1.0 / (self.rate * m.opt.timestep))))
        n = int(round(duration * self.rate))
        impact, ts, zs, fz = None, np.empty(n), np.empty(n), np.empty(n)
        Q = np.empty((n, m.nq)) if copy_state else None
        V = np.empty((n, m.nv)) if copy_state else None
        F = np.empty(6)
        step = mujoco.mj_step
        for k in range(n):
            tau = self.kp * (self.posture - d.qpos[self.qadr]) - self.kd * d.qvel[self.vadr]
            d.qfrc_applied[self.vadr] = np.clip(tau, -self.limit, self.limit)
            if impact is None:
                for _ in range(nstep):
                    step(m, d)
                    if impact is None and d.ncon > 0:
                        impact = d.time
            else:
                step(m, d, nstep)
            ts[k], zs[k] = d.time, d.qpos[2]
            if copy_state:
                Q[k], V[k] = d.qpos, d.qvel
            else:
                f = 0.0
                for c in range(d.ncon):
                    mujoco.mj_contactForce(m, d, c, F)
                    f += (d.contact[c].frame[:3] * F[0])[2]   # the normal force along world z
                fz[k] = f
        depth = np.array([-d.contact[c].dist for c in range(d.ncon)])
        return {'impact': impact, 't': ts, 'z': zs, 'fz': fz, 'depth': depth}


def calibrated_mujoco(sc, target_depth, duration=2.0, mu=None):
    """MuJoCo model whose feet sink ``target_depth`` at rest (the time constant scaled twice by
    ``sqrt(target/measured)``: penetration at rest grows as its square), and its last run."""
    path = urdf_path(sc)
    mu = sc.system.contact.ground.friction if mu is None else mu
    tc = MUJOCO_TIMECONST0
    for _ in range(3):
        m, why = mujoco_ground_model(path, mu, tc)
        if m is None:
            return None, why, None
        r = MujocoPD(m, sc).run(duration)
        depth = float(np.mean(r['depth'])) if len(r['depth']) else 0.0
        if depth <= 0.0 or abs(depth / target_depth - 1.0) < 0.02:
            break
        tc *= math.sqrt(target_depth / depth)
    return m, f'solref ({tc:.4g} s, 1)', r


def compare(duration=3.0, integrator=None, dt=None):
    """The comparison's figures: ``{'ours': ..., 'mujoco': ..., 'solref': str, 'mass': kg}``."""
    sc = load()
    a = ours(sc, duration, integrator, dt)
    depth = float(np.mean(a['depth']))
    m, solref, b = calibrated_mujoco(sc, depth)
    if m is None:
        return {'ours': a, 'mujoco': None, 'why': solref, 'mass': _mass(sc)}
    b = MujocoPD(m, sc).run(duration)
    return {'ours': a, 'mujoco': b, 'solref': solref, 'mass': _mass(sc), 'mujoco_model': m, 'scene': sc}


def _mass(sc) -> float:
    return float(sum(sp.mass for sp in sc.system.model.specs))


def rest(r, last=0.5):
    """Mean base height and vertical ground force over the last ``last`` seconds of a run."""
    sel = r['t'] >= r['t'][-1] - last
    return float(np.mean(r['z'][sel])), float(np.mean(r['fz'][sel]))


# ------------------------------------------------------------------------------------------------
# speed
# ------------------------------------------------------------------------------------------------
def our_recorded_run(sc, duration, integrator, dt):
    """CPU seconds of ``robodyn run SCENE --record`` (in process): the Simulator, every topic recorded."""
    from ..recording.run_sink import HEADLESS_BATCH, McapRunSink
    from ..runs import DIAGNOSTICS_PERIOD, resolve_settings
    from ..simulation import Simulator, run_headless
    st = resolve_settings(sc, integrator, dt, None, None, None, duration)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        sim = Simulator(sc.system, sc.y0, integrator=st['integrator'], dt=st['dt'])
    with tempfile.TemporaryDirectory() as tmp:
        sink = McapRunSink(os.path.join(tmp, 'run.mcap'), sc, {**st, 'mode': 'headless'},
                           diagnostics_period=DIAGNOSTICS_PERIOD, batch=HEADLESS_BATCH)
        c0 = time.process_time()
        run_headless(sim, st['duration'], st['rate'], sc.script, [sink])
        sink.close()
        return time.process_time() - c0


def speed(duration, integrator, dt, repeat):
    """``{'ours': median CPU s, 'mujoco': median CPU s, 'duration': s}`` of the timed runs."""
    sc = load()
    our_recorded_run(sc, 0.2, integrator, dt)   # compiled code loaded
    t_ours = sorted(our_recorded_run(sc, duration, integrator, dt) for _ in range(repeat))[repeat // 2]
    m, _ = mujoco_ground_model(urdf_path(sc), sc.system.contact.ground.friction, MUJOCO_TIMECONST0)
    t_mj = None
    if m is not None:
        pd = MujocoPD(m, sc)
        times = []
        for _ in range(repeat):
            c0 = time.process_time()
            pd.run(duration, copy_state=True)
            times.append(time.process_time() - c0)
        t_mj = sorted(times)[repeat // 2]
    return {'ours': t_ours, 'mujoco': t_mj, 'duration': duration}


# ------------------------------------------------------------------------------------------------
# steps: the integrator and step of the ground scenes
# ------------------------------------------------------------------------------------------------
#: the reference of the steps table: rk4 at this step (s)
REFERENCE_DT = 2.5e-5
#: per ground scene, its reference ``(integrator, dt, rtol)``: rk4 at 25 µs, or where the friction slope is stiff
#: for rk4 (its error falls slowly with the step), rk4 at 5 µs (solo12_drop: 5 µs and 10 µs 1.1e-4 rad apart) or
#: rosenbrock2 under error control at rtol 1e-6 (huston_human17_fall, whose fall is sensitive: rk4 down to
#: 2.5 µs ends it in another rest posture)
REFERENCES = {'a1_stand': ('rk4', REFERENCE_DT, None), 'solo12_drop': ('rk4', 5e-6, None),
              'huston_human17_fall': ('rosenbrock2', 1e-3, 1e-6)}
#: per ground scene, the ``(integrator, step, rtol)`` rows of the steps table (rtol: rosenbrock2 under error
#: control, the step its largest)
STEP_ROWS = {'a1_stand': [('rosenbrock2', 1e-3, None), ('rosenbrock2', 5e-4, None), ('rosenbrock2', 1e-3, 1e-5),
                          ('rk4', 1e-3, None), ('rk4', 5e-5, None)],
             'solo12_drop': [('rosenbrock2', 1e-3, 1e-5), ('rosenbrock2', 1e-3, 1e-4), ('rosenbrock2', 1e-3, 1e-6),
                             ('rosenbrock2', 1e-3, None), ('rosenbrock2', 5e-4, None), ('rk4', 5e-4, None),
                             ('rk4', 1e-4, None), ('rk4', 5e-5, None), ('rk4', 2.5e-5, None)],
             'huston_human17_fall': [('rosenbrock2', 1e-3, 1e-4), ('rosenbrock2', 1e-3, 1e-5),
                                     ('rosenbrock2', 1e-3, None), ('rosenbrock2', 5e-4, None), ('rk4', 5e-4, None),
                                     ('rk4', 5e-5, None), ('rk4', 2.5e-5, None), ('rk4', 5e-6, None)]}


def method_label(integ, dt, rtol=None) -> str:
    """``rk4, 0.05 ms`` or ``rosenbrock2, rtol 1e-05, ≤ 1 ms``."""
    return f'{integ}, {dt * 1e3:g} ms' if rtol is None else f'{integ}, rtol {rtol:g}, ≤ {dt * 1e3:g} ms'


def scene_run(name, integrator=None, dt=None, generic_gamma=None, text=None, rtol=None, step_budget=None):
    """Scene ``name`` over its duration with its settings (or integrator, dt), its scripted commands
    held per publication period: ``{'q': joint positions per publication (n+1, nq − 7), 'z': base
    height per publication, 'first': the first publication where a point touches, 'energy':
    Simulator.energy_report(), 'cpu': CPU s, 'sim', 'scene'}``. generic_gamma: run rosenbrock2 on the
    Simulator's Python path (``integrators.Rosenbrock2`` on the system's right-hand side and passive
    Jacobian) with this γ in every step, instead of the compiled loop (which takes 1 + 1/√2 while a
    point touches, 1 − 1/√2 otherwise). text: a variant of the scene, its YAML edited, instead of the
    bundled file. rtol: rosenbrock2 under error control, dt its largest step; step_budget: the Simulator's
    (inf: none, for a tight reference)."""
    from ..kernels.contact import PACTIVE
    from ..scene import load_scene, parse_scene
    from ..simulation import Simulator, run_headless
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        sc = load_scene(name) if text is None else parse_scene(text, file=f'{name}.yaml')
        s = sc.system
        sim = Simulator(s, sc.y0, integrator=integrator or sc.settings['integrator'], dt=dt or sc.settings['dt'],
                        rtol=rtol if integrator else sc.settings.get('rtol'),
                        atol=None if integrator else sc.settings.get('atol'), step_budget=step_budget)
    if generic_gamma is not None:
        assert sim.settings['integrator'] == 'rosenbrock2', sim.settings
        s.fused_advance = lambda *a, **k: None      # this instance only: the Simulator's Python path
        s.fused_periods = None
        sim.integrator.gamma = float(generic_gamma)
    rows = []

    class Sink:
        def on_start(self, sim):
            pass

        def on_command(self, t, port, values):
            pass

        def on_output(self, t, out, sim):
            on = (s.contact.point_outputs(s._km, sim.y[:s.nq], sim.y[s.nq:])[:, PACTIVE] > 0).any()
            rows.append((sim.y[7:s.nq].copy(), sim.y[2], on))

        def close(self):
            pass
    c0 = time.process_time()
    run_headless(sim, sc.settings['duration'], sc.settings['publish_rate'], sc.script, sinks=[Sink()])
    cpu = time.process_time() - c0
    return {'q': np.array([r[0] for r in rows]), 'z': np.array([r[1] for r in rows]),
            'first': int(np.flatnonzero([r[2] for r in rows])[0]), 'energy': sim.energy_report(), 'cpu': cpu,
            'sim': sim, 'scene': sc}


def step_row(run, ref) -> dict:
    """One row of the steps table: ``run`` (:func:`scene_run`) against the reference run ``ref``."""
    e = run['energy']
    return {'q_max': float(np.abs(run['q'] - ref['q']).max()), 'q_rest': float(np.abs(run['q'][-1] - ref['q'][-1]).max()),
            'z_rest': float(run['z'][-1] - ref['z'][-1]), 'balance': float(e['drift']), 'work': float(e['work']),
            'same_impact': run['first'] == ref['first'],
            'cpu_per_s': run['cpu'] / float(run['scene'].settings['duration']),
            'steps_per_s': run['sim'].integrator.stats.steps / float(run['scene'].settings['duration'])}


def steps(progress=print) -> dict:
    """The steps table: ``{scene: [(integrator, dt, rtol, row)]}`` (its reference first, :data:`REFERENCES`, then
    :data:`STEP_ROWS` against it) and ``'gamma'``: A1 at 1 ms on the generic step with γ = 1 − 1/√2 and 1 + 1/√2."""
    from ..kernels.rosenbrock import GAMMA, GAMMA_STOP
    out = {}
    for name, rows in STEP_ROWS.items():
        r_integ, r_dt, r_tol = REFERENCES[name]
        ref = scene_run(name, r_integ, r_dt, rtol=r_tol, step_budget=math.inf)
        out[name] = [(r_integ, r_dt, r_tol, step_row(ref, ref))]   # the reference's own balance and cost
        for integ, dt, rtol in rows:
            out[name].append((integ, dt, rtol, step_row(scene_run(name, integ, dt, rtol=rtol, step_budget=math.inf),
                                                        ref)))
            progress(f'{name} {method_label(integ, dt, rtol)}: {out[name][-1][3]}')
        if name == 'a1_stand':
            out['gamma'] = [(g, step_row(scene_run(name, 'rosenbrock2', 1e-3, generic_gamma=g), ref))
                            for g in (GAMMA, GAMMA_STOP)]
            progress(f'gamma: {out["gamma"]}')
    return out


def steps_report(t: dict) -> str:
    """Markdown of :func:`steps`."""
    lines = ['Each bundled ground scene against its reference over its duration (joint positions at every '
             'publication; accepted steps and CPU time per simulated second, this machine, this run). The '
             'references: rk4 at 25 µs (a1_stand), rk4 at 5 µs (solo12_drop, whose friction slope is stiff for '
             'rk4), rosenbrock2 under error control at rtol 1e-6 (huston_human17_fall, whose fall is sensitive: '
             'rk4 down to 2.5 µs ends it in another rest posture). "rtol r, ≤ h": rosenbrock2 under error control '
             '(atol = rtol), steps of at most h.', '',
             '| scene | method | joint positions (max) | at rest | base height at rest | E − E0 − W | W | same first '
             'contact | steps per simulated s | CPU per simulated s |', '|---|---|---|---|---|---|---|---|---|---|']
    for name in STEP_ROWS:
        for k, (integ, dt, rtol, r) in enumerate(t[name]):
            label = method_label(integ, dt, rtol)
            if k == 0:
                lines.append(f'| `{name}` | {label} (the reference) | | | | {r["balance"]:+.2g} J | '
                             f'{r["work"]:+.4g} J | | {r["steps_per_s"]:.0f} | {1e3 * r["cpu_per_s"]:.0f} ms |')
                continue
            lines.append(f'| `{name}` | {label} | {r["q_max"]:.2g} rad | {r["q_rest"]:.2g} rad | '
                         f'{r["z_rest"]:+.2g} m | {r["balance"]:+.2g} J | {r["work"]:+.4g} J | '
                         f'{"yes" if r["same_impact"] else "no"} | {r["steps_per_s"]:.0f} | '
                         f'{1e3 * r["cpu_per_s"]:.0f} ms |')
    lines += ['', 'A1 (`a1_stand`) at 1 ms on the generic rosenbrock2 step (the Python path) with one root of γ in '
                  'every step, against the same reference:', '',
              '| γ | joint positions (max) | at rest | E − E0 − W |', '|---|---|---|---|']
    for g, r in t['gamma']:
        lines.append(f'| {g:.4f} | {r["q_max"]:.2g} rad | {r["q_rest"]:.2g} rad | {r["balance"]:+.2g} J |')
    return '\n'.join(lines) + '\n'


def main(args) -> int:
    """Print the comparison and the speed tables, or with --steps the steps table (and write it with --out)."""
    if args.steps:
        text = ('# Ground scenes: integrator and step\n\n`robodyn bench contact --steps` (read in '
                '[contact.md](contact.md#integrator-and-step-of-the-bundled-scenes)).\n\n'
                + steps_report(steps(progress=lambda m: None)))
        print(text)
        if args.out:
            with open(args.out, 'w', encoding='utf-8') as f:
                f.write(text)
        return 0
    sc = load()
    integ = args.integrator or sc.settings['integrator']
    dt = args.dt or sc.settings['dt']
    c = compare(args.duration, integ, dt)
    a, b = c['ours'], c['mujoco']
    lines = [f'# {SCENE}: robodyn against MuJoCo', '',
             f'Drop from 0.1 m and stand, {args.duration:g} s; ours {integ} at {dt:g} s; MuJoCo implicitfast at 1 ms, '
             f'{c.get("solref", c.get("why"))}. Rest: the last 0.5 s. Weight m g = {c["mass"] * 9.81:.2f} N.', '',
             '| figure | robodyn | MuJoCo |', '|---|---|---|']
    za, fa = rest(a)
    if b is not None:
        zb, fb = rest(b)
        lines += [f'| first impact (s) | {a["impact"]:.4f} | {b["impact"]:.4f} |',
                  f'| base height at rest (m) | {za:.5f} | {zb:.5f} |',
                  f'| vertical ground force at rest (N) | {fa:.3f} | {fb:.3f} |',
                  f'| feet penetration at rest (mm) | {1e3 * np.mean(a["depth"]):.3f} | '
                  f'{1e3 * np.mean(b["depth"]):.3f} |']
    else:
        lines += [f'| first impact (s) | {a["impact"]:.4f} | {c["why"]} |', f'| base height at rest (m) | {za:.5f} | |']
    if not args.skip_speed:
        sp = speed(args.duration, integ, dt, args.repeat)
        lines += ['', f'Real-time factor, ours {integ} at {dt:g} s, MuJoCo at 1 ms ({args.duration:g} s simulated, CPU '
                      f'time, median of {args.repeat}):', '',
                  '| run | CPU s | real-time factor |', '|---|---|---|',
                  f'| robodyn, {integ}, every topic recorded | {sp["ours"]:.3f} | {sp["duration"] / sp["ours"]:.0f} |']
        if sp['mujoco'] is not None:
            lines.append(f'| MuJoCo implicitfast from Python, PD in Python, state copied out | {sp["mujoco"]:.3f} | '
                         f'{sp["duration"] / sp["mujoco"]:.0f} |')
    text = '\n'.join(lines) + '\n'
    print(text)
    if args.out:
        with open(args.out, 'w', encoding='utf-8') as f:
            f.write(text)
    return 0
