"""Joint armature (rotor inertia, ``M + diag(a)``) against Pinocchio's ``model.armature`` and MuJoCo's
joint ``armature``; the importer's automatic armature on icub's neck; energy conserved with it.

The kernels (generic and generated) and the numpy reference add the armature to CRBA, ABA's ``D``,
RNEA's ``τ`` and the kinetic energy; the joint wrenches stay the links' (Pinocchio's ``data.f``).
"""
from __future__ import annotations

import re
import subprocess
import sys
import warnings
from dataclasses import replace

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from robodyn_ros import dynamics, kernels
from robodyn_ros.armature import LADDER, REGULAR_RATIO, regularising_armature
from robodyn_ros.bench.pinbridge import pin_model
from robodyn_ros.model import FREE, SPHERICAL, build_model, random_tree
from robodyn_ros.scene import SceneError, load_scene, parse_scene
from robodyn_ros.simulation import Simulator, run_headless
from robodyn_ros.systems.base import backend_scope
from robodyn_ros.urdf import UrdfWarning, example_robot_data_dir, read_urdf

ERD = example_robot_data_dir()
#: worst relative difference allowed against Pinocchio (measured 5.8e-15: docs/urdf.md)
TOL = 1e-12


def rel(a, b):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return float(np.abs(a - b).max() / max(1.0, np.abs(b).max()))


def with_armature(m, rng):
    """The model with a random armature (0.01 .. 0.5) on every joint that takes one (not FREE)."""
    specs = [replace(s, armature=float(rng.uniform(0.01, 0.5))) if s.joint_type in ('revolute', 'prismatic',
                                                                                      'spherical') else s
             for s in m.specs]
    return build_model(specs, gravity=m.gravity, name=m.name, root=m.root)


def random_state(m, rng):
    q = rng.normal(size=m.nq)
    for i in range(m.nb):
        s = m.q_idx[i]
        if m.jtype[i] == FREE:
            s += 3
        if m.jtype[i] in (FREE, SPHERICAL):
            quat = rng.normal(size=4)
            q[s:s + 4] = quat / np.linalg.norm(quat)
    return q, rng.normal(size=m.nv), rng.normal(size=m.nv), rng.normal(size=m.nv) * 3


def test_armature_in_the_kernels_and_the_reference_agrees_with_pinocchio():
    """On 10 seeded trees (1-DOF, spherical and free-root ones) with armature on every joint, at 3 states
    each: M (CRBA), τ (RNEA), q̈ (ABA; generic and generated kernels, numpy reference), the kinetic energy
    ``½ vᵀ M v`` and the joint wrenches, against Pinocchio with the same ``model.armature`` (worst 5.8e-15,
    the generic ABA's; the generated ABA on the trees of up to 4 bodies)."""
    rng = np.random.default_rng(3030)
    errs = {k: [] for k in ('M', 'rnea', 'aba', 'aba_gen', 'ref', 'ke', 'wrench')}
    shift = []
    for k in range(10):
        m0 = random_tree(2 + k % 7, rng, chain=k % 2 == 0, spherical_fraction=0.4 if k % 3 == 1 else 0.0,
                         free_root=k % 4 == 3)
        m = with_armature(m0, rng)
        km = kernels.CompiledModel(m)
        # generated code on the trees of up to 4 bodies (5 of them): random trees trace to dense code (no axis
        # along a frame's), whose compile grows with the tree (random8: 14 000 lines, a minute of the suite's CPU)
        gen = kernels.CompiledModel(m, specialize=True) \
            if m.nb <= 4 and not (m.has_spherical or (m.jtype == FREE).any()) else None
        pm, qmap, vmap, jid = pin_model(m)
        pm.armature[vmap] = m.armature
        pd = pm.createData()
        for s in range(3):
            q, v, a, tau = random_state(m, rng)
            qp, vp, ap, taup = np.empty(m.nq), np.empty(m.nv), np.empty(m.nv), np.empty(m.nv)
            qp[qmap], vp[vmap], ap[vmap], taup[vmap] = q, v, a, tau
            Mp = pin.crba(pm, pd, qp)
            Mp = (np.triu(Mp) + np.triu(Mp, 1).T)[np.ix_(vmap, vmap)]
            M = km.crba(q)
            errs['M'].append(rel(M, Mp))
            shift.append(rel(M - kernels.CompiledModel(m0).crba(q), np.diag(m.armature)))
            tau_k, f = km.rnea_wrenches(q, v, a)
            errs['rnea'].append(rel(tau_k, pin.rnea(pm, pd, qp, vp, ap)[vmap]))
            for i, j in jid.items():   # the wrench through joint i is the links', without the rotor's a q̈
                fj = np.concatenate([pd.f[j].angular, pd.f[j].linear])
                errs['wrench'].append(float(np.abs(f[i] - fj).max() / max(1.0, np.abs(fj).max())))
            qdd_p = pin.aba(pm, pd, qp, vp, taup)[vmap]
            errs['aba'].append(rel(km.aba(q, v, tau), qdd_p))
            if gen is not None:
                assert gen.gen is not None
                errs['aba_gen'].append(rel(gen.forward(q, v, tau), qdd_p))
            if not m.has_spherical:
                errs['ref'].append(max(rel(dynamics.crba(m, q), Mp), rel(dynamics.aba(m, q, v, tau), qdd_p),
                                       rel(dynamics.rnea(m, q, v, a), tau_k),
                                       rel(dynamics.kinetic_energy(m, q, v), 0.5 * v @ Mp @ v)))
            errs['ke'].append(rel(km.energies(q, v)[0], 0.5 * v @ Mp @ v))
    print('worst vs Pinocchio with armature:', {k: f'{max(e):.1e}' for k, e in errs.items()})
    assert len(errs['M']) == 30 and len(errs['aba_gen']) >= 6 and len(errs['ref']) >= 12, {k: len(e) for k, e in
                                                                                           errs.items()}
    for k, e in errs.items():
        assert max(e) < TOL, (k, max(e))
    assert max(shift) < TOL   # the armature is on the diagonal only


def _mujoco_pendulum():
    """example-robot-data's double pendulum read by MuJoCo and by us, with armature 0.2 and 0.05 kg·m²."""
    path = ERD / 'double_pendulum_description/urdf/double_pendulum_simple.urdf'
    # its <limit lower="0" upper="0"> (no limits given) would make MuJoCo warn into ./MUJOCO_LOG.TXT: left out
    mj = mujoco.MjModel.from_xml_string(re.sub(r'<limit[^>]*/>', '', path.read_text()))
    mj.dof_armature[:] = (0.2, 0.05)
    mj.dof_damping[:] = 0.0        # ABA alone: no passive forces, no friction loss, no contacts or limits
    mj.dof_frictionloss[:] = 0.0
    mj.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
    mj.opt.gravity[:] = (0.0, 0.0, -9.81)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', UrdfWarning)
        robot = read_urdf(path, armature={'joint1': 0.2, 'joint2': 0.05})
    m = build_model(robot.specs, root=robot.root, name=robot.name)
    names = [mj.joint(k).name for k in range(mj.njnt)]
    assert names == m.dof_joint_names == ['joint1', 'joint2'], names
    return mj, m


def test_armature_agrees_with_mujoco_joint_armature():
    """MuJoCo's joint armature on the same URDF: ``M`` (mj_fullM) and the free acceleration (mj_forward)
    at seeded states, 4.4e-16 relative (bound 1e-13); without the armature they differ by it."""
    mj, m = _mujoco_pendulum()
    d = mujoco.MjData(mj)
    km = kernels.CompiledModel(m)
    rng = np.random.default_rng(5)
    errs, without = [], []
    for _ in range(5):
        q, v = rng.uniform(-2, 2, size=2), rng.normal(size=2)
        d.qpos[:], d.qvel[:], d.ctrl[:] = q, v, 0.0
        d.qfrc_applied[:] = tau = rng.normal(size=2)
        mujoco.mj_forward(mj, d)
        Mm = np.zeros((2, 2))
        mujoco.mj_fullM(mj, d, Mm)
        errs.append(max(rel(km.crba(q), Mm), rel(km.aba(q, v, tau), d.qacc)))
        without.append(rel(kernels.CompiledModel(build_model([replace(s, armature=0.0) for s in m.specs],
                                                             root=m.root)).crba(q), Mm))
    print('vs MuJoCo armature:', max(errs))
    assert len(errs) == 5 and max(errs) < 1e-13, errs
    assert min(without) > 0.01   # the comparison sees the armature


#: relative energy drift allowed over the 1 s swing (docs/urdf.md quotes the measured one)
DRIFT = 1e-12


def test_energy_is_conserved_with_armature_and_counts_the_rotors():
    """A frictionless double pendulum with armature swings 1 s under RK4 at 0.1 ms: the energy the
    simulator reports (the rotors' ½ a q̇² included) stays constant to 1e-9 relative; leaving the rotors
    out of it would break that by their share (> 1 % here)."""
    _, m = _mujoco_pendulum()
    m = build_model([replace(s, damping=0.0, friction=0.0) for s in m.specs], root=m.root, name=m.name)
    from robodyn_ros.systems.arm import ArmSystem
    sys_ = ArmSystem(m)
    y0 = np.concatenate([[1.0, -0.5], [0.0, 0.0]])
    sim = Simulator(sys_, y0, integrator='rk4', dt=1e-4)
    E0 = sys_.total_energy(y0)
    run_headless(sim, 1.0, 100.0, None)
    y = sim.y
    E1 = sys_.total_energy(y)
    rotors = 0.5 * float(m.armature @ (y[2:] ** 2))
    drift = abs(E1 - E0) / abs(E0)
    print(f'energy {E0:.9g} -> {E1:.9g} J (relative drift {drift:.1e}), rotors {rotors:.3g} J')
    assert drift < DRIFT and rotors > 0.01 * abs(E0)


ICUB = 'icub_description/robots/icub.urdf'


def test_icub_gets_the_smallest_armature_that_makes_its_mass_matrix_regular():
    """icub's neck_yaw and neck_roll line up at q = 0 with a point mass between them: M is singular.
    The importer adds the smallest value of the ladder to those two joints only, with one warning naming
    them and the value; M is then regular (checked with Pinocchio's CRBA and the same armature), and the
    next smaller value would not be enough."""
    with pytest.warns(UrdfWarning) as rec:
        robot = read_urdf(ERD / ICUB)
    msgs = [str(w.message) for w in rec if 'armature' in str(w.message)]
    assert len(msgs) == 1 and 'neck_yaw' in msgs[0] and 'neck_roll' in msgs[0], msgs
    given = {s.joint: s.armature for s in robot.specs if s.armature}
    assert set(given) == {'neck_yaw', 'neck_roll'} and len(set(given.values())) == 1, given
    a = given['neck_yaw']
    assert a in LADDER and f'armature {a:g} kg·m²' in msgs[0]
    pm = pin.buildModelFromUrdf(str(ERD / ICUB))
    for j, x in given.items():
        pm.armature[pm.joints[pm.getJointId(j)].idx_v] = x
    Mp = pin.crba(pm, pm.createData(), pin.neutral(pm))
    Mp = np.triu(Mp) + np.triu(Mp, 1).T
    w = np.linalg.eigvalsh(Mp)
    assert w[0] >= REGULAR_RATIO * w[-1], w[[0, -1]]
    k = LADDER.index(a)
    if k > 0:
        for j in given:
            pm.armature[pm.joints[pm.getJointId(j)].idx_v] = LADDER[k - 1]
        Mp = pin.crba(pm, pm.createData(), pin.neutral(pm))
        w = np.linalg.eigvalsh(np.triu(Mp) + np.triu(Mp, 1).T)
        assert w[0] < REGULAR_RATIO * w[-1]   # the value chosen is the smallest that is enough
    m = build_model(robot.specs, root=robot.root, name=robot.name)
    assert regularising_armature(m) is None   # regular now: nothing more to add


def test_icub_runs_with_its_armature_and_is_refused_in_one_line_without(tmp_path):
    p = subprocess.run([sys.executable, '-m', 'robodyn_ros.cli', 'run', str(ERD / ICUB), '--duration', '0.02'],
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    warned = [ln for ln in p.stderr.splitlines() if 'armature' in ln]
    assert len(warned) == 1 and warned[0].startswith('robodyn: warning: ') and 'neck_yaw' in warned[0], p.stderr
    scene = tmp_path / 'icub.yaml'
    scene.write_text(f'name: icub\nparts:\n  - {{kind: urdf, name: icub, file: {ERD / ICUB}, armature: 0}}\n')
    with backend_scope('numba'), warnings.catch_warnings():
        warnings.simplefilter('ignore', UrdfWarning)
        sc = load_scene(scene)
        assert not sc.system.model.armature.any()
        with pytest.raises(ValueError, match=r'mass matrix is singular .*neck_yaw, neck_roll|neck_roll, neck_yaw') as e:
            Simulator(sc.system, sc.y0, integrator='rk4', dt=1e-3)
    assert '\n' not in str(e.value)


def test_scene_armature_key_sets_it_by_joint_or_for_all_and_refuses_bad_values():
    urdf = (ERD / 'double_pendulum_description/urdf/double_pendulum_simple.urdf').read_text()
    text = 'name: dp\nparts:\n  - kind: urdf\n    name: dp\n    armature: {}\n    urdf: |\n' + \
        ''.join(f'      {ln}\n' for ln in urdf.splitlines())
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', UrdfWarning)
        assert list(parse_scene(text.replace('{}', '0.3', 1)).system.model.armature) == [0.3, 0.3]
        assert list(parse_scene(text.replace('{}', '{joint2: 0.1}', 1)).system.model.armature) == [0.0, 0.1]
        assert list(parse_scene(text.replace('{}', 'auto', 1)).system.model.armature) == [0.0, 0.0]
        for bad, words in (('-1', r'parts\[0\]\.armature: expected a number >= 0'),
                           ('{ghost: 1}', r'parts\[0\]\.armature\.ghost: not a moving'),
                           ('[1]', r"parts\[0\]\.armature: expected 'auto', a number"),
                           ('{joint1: .nan}', r'armature\.joint1: expected a finite number')):
            with pytest.raises(SceneError, match=words):
                parse_scene(text.replace('{}', bad, 1))
