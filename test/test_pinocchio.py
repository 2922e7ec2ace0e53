"""robodyn_ros against Pinocchio (an independent implementation) on the same URDF.

The model is exported with :func:`robodyn_ros.model.to_urdf` and loaded with
``pin.buildModelFromXML``; joints are matched by name (Pinocchio orders them depth-first, and
merges FIXED joints into their parent). Conventions bridged here:

* Pinocchio motion/force vectors are (linear, angular), ours [angular; linear];
* a free joint's v is (linear, angular) body twist in Pinocchio, [angular; linear] here; its q is
  (p, quaternion x y z w) in both;
* ``pin.crba`` fills the upper triangle only;
* bodies welded to the root (FIXED joints all the way up) go into Pinocchio's universe inertia,
  which its centre of mass and potential energy leave out.
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from conftest import N_TREES
from robodyn_ros import dynamics as dyn
from robodyn_ros.model import FIXED, FREE, PRISMATIC, REVOLUTE, LinkSpec, Model, build_model, dh_links, to_urdf

TOL = 1e-12   # measured worst 1.8e-14 relative (README accuracy table)


class PinBridge:
    """A Pinocchio copy of a robodyn model and the index maps between the two.

    pm: a Pinocchio model of the same robot built elsewhere (e.g. from the original URDF file);
    default: ``pin.buildModelFromXML(to_urdf(m))``."""

    def __init__(self, m: Model, pm=None):
        self.m = m
        self.pm = pin.buildModelFromXML(to_urdf(m)) if pm is None else pm
        self.pm.gravity.linear = np.asarray(m.gravity, dtype=float)
        self.pd = self.pm.createData()
        assert (self.pm.nq, self.pm.nv) == (m.nq, m.nv)
        self.qmap = np.empty(m.nq, dtype=int)  # our q[k] is Pinocchio's q[qmap[k]]
        self.vmap = np.empty(m.nv, dtype=int)  # our v[k] is Pinocchio's v[vmap[k]]
        self.jid = {}  # body index -> Pinocchio joint id, for bodies with a moving joint
        for i in range(m.nb):
            if m.jtype[i] == FIXED:
                continue
            j = self.pm.getJointId(m.joint_names[i])
            assert j < self.pm.njoints, m.joint_names[i]
            self.jid[i] = j
            jm = self.pm.joints[j]
            q0, v0 = m.q_idx[i], m.v_idx[i]
            assert (jm.nq, jm.nv) == (m.nq_j[i], m.nv_j[i])
            self.qmap[q0:q0 + jm.nq] = jm.idx_q + np.arange(jm.nq)
            if m.jtype[i] == FREE:  # ours [w; v], theirs (v, w)
                self.vmap[v0:v0 + 6] = jm.idx_v + np.array([3, 4, 5, 0, 1, 2])
            else:
                self.vmap[v0] = jm.idx_v
        assert sorted(self.qmap) == list(range(m.nq)) and sorted(self.vmap) == list(range(m.nv))

    def q(self, q):
        out = np.empty(self.m.nq)
        out[self.qmap] = q
        return out

    def v(self, v):
        out = np.empty(self.m.nv)
        out[self.vmap] = v
        return out

    def back(self, x):
        """A Pinocchio v-space vector in our order."""
        return np.asarray(x)[self.vmap]

    def fext(self, fext):
        """Pinocchio's per-joint external forces from ours (nb, 6), [n; f] at body origins in
        body coordinates; a welded body's force is carried to its nearest moving ancestor."""
        m = self.m
        out = [np.zeros(6) for _ in range(self.pm.njoints)]  # our [n; f] order, per joint id
        for i in range(m.nb):
            X, k = np.eye(6), i
            while k >= 0 and m.jtype[k] == FIXED:
                X = X @ m.Xtree[k]
                k = m.parent[k]
            if k >= 0:  # bodies welded to the root feel nothing that moves
                out[self.jid[k]] += X.T @ fext[i]
        return pin.StdVec_Force([pin.Force(np.concatenate([w[3:], w[:3]])) for w in out])

    def universe(self):
        """``(mass, com in root coordinates)`` of the bodies welded to the root."""
        I0 = self.pm.inertias[0]
        return float(I0.mass), np.array(I0.lever)


def random_q(m, rng):
    """Random configuration, unit quaternions for free joints."""
    q = rng.uniform(-np.pi, np.pi, size=m.nq)
    for i in range(m.nb):
        if m.jtype[i] == FREE:
            s = m.q_idx[i]
            q[s:s + 3] = rng.normal(size=3)
            quat = rng.normal(size=4)
            q[s + 3:s + 7] = quat / np.linalg.norm(quat)
    return q


def rel(x, y, floor=1.0):
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    return float(np.max(np.abs(x - y), initial=0.0) / max(float(np.max(np.abs(y), initial=0.0)), floor))


def compare(m, rng, n_states=2, label='', pm=None):
    """Errors ``{quantity: [(err, where)]}`` of robodyn against Pinocchio at random states
    (pm: the Pinocchio model to compare with, see :class:`PinBridge`)."""
    b = PinBridge(m, pm)
    pm, pd = b.pm, b.pd
    errs = {k: [] for k in ('pose', 'M', 'rnea', 'aba', 'wrench', 'ke', 'pe', 'com')}
    for s in range(n_states):
        where = f'{label} state {s}'
        q = random_q(m, rng)
        v, a, tau = rng.normal(size=m.nv), rng.normal(size=m.nv), rng.normal(size=m.nv) * 3
        qp, vp, ap = b.q(q), b.v(v), b.v(a)
        # frames: our body frame i is Pinocchio's joint frame
        pin.forwardKinematics(pm, pd, qp)
        R, p = dyn.body_poses(m, q)
        for i, j in b.jid.items():
            errs['pose'].append((max(rel(R[i], pd.oMi[j].rotation), rel(p[i], pd.oMi[j].translation)), where))
        # joint-space inertia (upper triangle from Pinocchio)
        Mp = pin.crba(pm, pd, qp)
        Mp = np.triu(Mp) + np.triu(Mp, 1).T
        errs['M'].append((rel(dyn.crba(m, q), Mp[np.ix_(b.vmap, b.vmap)]), where))
        # inverse dynamics and the transmitted joint wrenches
        tau_ref = b.back(pin.rnea(pm, pd, qp, vp, ap))
        tau_ours, f = dyn.rnea_wrenches(m, q, v, a)
        errs['rnea'].append((rel(tau_ours, tau_ref), where))
        scale = max(1.0, max(np.abs(pd.f[j].vector).max() for j in b.jid.values()))
        for i, j in b.jid.items():
            fj = np.concatenate([pd.f[j].angular, pd.f[j].linear])
            errs['wrench'].append((np.abs(f[i] - fj).max() / scale, f'{where} joint {m.joint_names[i]}'))
        # forward dynamics
        errs['aba'].append((rel(dyn.aba(m, q, v, tau), b.back(pin.aba(pm, pd, qp, vp, b.v(tau)))), where))
        # the same with external forces on every body (welded bodies: moved to their joint's frame)
        fext = rng.normal(size=(m.nb, 6))
        fext_p = b.fext(fext)
        tau_ref = b.back(pin.rnea(pm, pd, qp, vp, ap, fext_p))
        tau_ours, f = dyn.rnea_wrenches(m, q, v, a, fext)
        errs['rnea'].append((rel(tau_ours, tau_ref), where + ' f_ext'))
        scale = max(1.0, max(np.abs(pd.f[j].vector).max() for j in b.jid.values()))
        for i, j in b.jid.items():
            fj = np.concatenate([pd.f[j].angular, pd.f[j].linear])
            errs['wrench'].append((np.abs(f[i] - fj).max() / scale, f'{where} f_ext joint {m.joint_names[i]}'))
        errs['aba'].append((rel(dyn.aba(m, q, v, tau, fext), b.back(pin.aba(pm, pd, qp, vp, b.v(tau), fext_p))),
                            where + ' f_ext'))
        # energies and centre of mass (adding back the mass welded to the root)
        m0, c0 = b.universe()
        ke_ref = pin.computeKineticEnergy(pm, pd, qp, vp)
        errs['ke'].append((rel(dyn.kinetic_energy(m, q, v), ke_ref), where))
        pe_ref = pin.computePotentialEnergy(pm, pd, qp) - m0 * float(np.dot(m.gravity, c0))
        errs['pe'].append((rel(dyn.potential_energy(m, q), pe_ref), where))
        com_p = pin.centerOfMass(pm, pd, qp)
        mass_p = pd.mass[0]
        com_ref = (mass_p * com_p + m0 * c0) / (mass_p + m0)
        com, mass = dyn.center_of_mass(m, q)
        errs['com'].append((max(rel(com, com_ref), rel(mass, mass_p + m0)), where))
    return errs


def assert_all(errs, expected_counts):
    for k, e in errs.items():
        assert len(e) == expected_counts[k], k
        worst = max(e, key=lambda x: x[0])
        assert worst[0] < TOL, f'{k}: {worst[0]:.3g} at {worst[1]}'


def test_random_trees_against_pinocchio(trees):
    rng = np.random.default_rng(41)
    allerrs = {}
    for label, m in trees:
        for k, e in compare(m, rng, 2, label).items():
            allerrs.setdefault(k, []).extend(e)
    n_moving = sum(int(((m.jtype == REVOLUTE) | (m.jtype == PRISMATIC)).sum()) for _, m in trees)
    per_state = {'pose': n_moving, 'wrench': 2 * n_moving, 'rnea': 2 * N_TREES, 'aba': 2 * N_TREES}
    assert_all(allerrs, {k: 2 * per_state.get(k, N_TREES) for k in allerrs})


def _inertia(rng):
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    a1, a2 = rng.uniform(0.02, 0.2, size=2)
    return Q @ np.diag([a1, a2, 0.9 * (a1 + a2)]) @ Q.T


def test_free_base_and_welds_against_pinocchio():
    """A free-floating base carrying a branched arm with a welded link, next to a body welded to
    the root: exercises the FREE joint and the universe-inertia bookkeeping."""
    rng = np.random.default_rng(43)

    def spec(name, joint, parent, kind, **kw):
        return LinkSpec(name=name, joint=joint, parent=parent, joint_type=kind,
                        origin_xyz=tuple(rng.uniform(-0.5, 0.5, size=3)),
                        origin_rpy=tuple(rng.uniform(-np.pi, np.pi, size=3)), mass=float(rng.uniform(0.5, 3)),
                        com=tuple(rng.uniform(-0.2, 0.2, size=3)), inertia=_inertia(rng), **kw)
    links = [spec('table', 'table_weld', None, 'fixed'),
             spec('base', 'base_free', None, 'free'),
             spec('upper', 'shoulder', 'base', 'revolute', axis=tuple(rng.normal(size=3))),
             spec('bracket', 'bracket_weld', 'upper', 'fixed'),
             spec('fore', 'elbow', 'bracket', 'revolute', axis=tuple(rng.normal(size=3))),
             spec('slide', 'rail', 'base', 'prismatic', axis=tuple(rng.normal(size=3)))]
    m = build_model(links, gravity=(0.3, -0.2, -9.81), name='free_base')
    assert m.nv == 9 and m.nq == 10
    errs = compare(m, rng, 5, 'free_base')
    per_state = {'pose': 4, 'wrench': 8, 'rnea': 2, 'aba': 2}
    assert_all(errs, {k: 5 * per_state.get(k, 1) for k in errs})


@pytest.mark.parametrize('convention', ['standard', 'modified'])
def test_dh_arms_against_pinocchio(convention):
    """Arms from DH tables (twists of ±90° put URDF origins exactly at the rpy gimbal lock),
    revolute and prismatic, exported through to_urdf."""
    rng = np.random.default_rng(44 if convention == 'standard' else 45)
    rows = []
    for k in range(6):
        rows.append(dict(type='prismatic' if k in (2, 4) else 'revolute', a=float(rng.choice([0.0, 0.3, -0.2])),
                         alpha=float(rng.choice([0.0, np.pi / 2, -np.pi / 2, 0.7])), d=float(rng.uniform(-0.3, 0.3)),
                         theta=float(rng.choice([0.0, np.pi / 2, -0.4])), mass=float(rng.uniform(0.5, 3)),
                         com=tuple(rng.uniform(-0.2, 0.2, size=3)), inertia=_inertia(rng)))
    m = build_model(dh_links(rows, convention=convention), name=f'dh_{convention}')
    errs = compare(m, rng, 4, f'dh {convention}')
    per_state = {'pose': 6, 'wrench': 12, 'rnea': 2, 'aba': 2}
    assert_all(errs, {k: 4 * per_state.get(k, 1) for k in errs})


def test_static_wrench_of_pinocchio_bridge_is_weight():
    """A guard on the bridge itself: a single hanging point mass gives the weight in both codes
    (so a convention slip in the comparison cannot cancel one in the code)."""
    m = build_model([LinkSpec(name='bob', joint='pivot', parent=None, axis=(0, 1, 0), mass=2.0,
                              com=(0.0, 0.0, -0.5))], gravity=(0.0, 0.0, -10.0))
    b = PinBridge(m)
    z = np.zeros(1)
    pin.rnea(b.pm, b.pd, z, z, z)
    fj = np.concatenate([b.pd.f[1].angular, b.pd.f[1].linear])
    _, f = dyn.rnea_wrenches(m, z, z, z)
    assert np.allclose(fj, [0, 0, 0, 0, 0, 20.0], atol=1e-12)
    assert np.allclose(f[0], [0, 0, 0, 0, 0, 20.0], atol=1e-12)


def _models_in(obj, depth=0, seen=None):
    """Every :class:`Model` reachable from a loaded scene through attributes, lists and dicts."""
    seen = set() if seen is None else seen
    if id(obj) in seen or depth > 4:
        return []
    seen.add(id(obj))
    if isinstance(obj, Model):
        return [obj]
    if isinstance(obj, (str, bytes, int, float, np.ndarray)) or obj is None:
        return []
    if isinstance(obj, dict):
        children = list(obj.values())
    elif isinstance(obj, (list, tuple)):
        children = list(obj)
    elif hasattr(obj, '__dict__'):
        children = list(vars(obj).values())
    else:
        return []
    out = []
    for c in children:
        out += _models_in(c, depth + 1, seen)
    return out


def test_bundled_scenes_against_pinocchio():
    """Every bundled scene's kinematic tree(s) agree with Pinocchio (M, RNEA, ABA, joint
    wrenches, energies, centre of mass)."""
    from robodyn_ros.scene import list_scenes, load_scene
    names = [n if isinstance(n, str) else n[0] for n in list_scenes()]  # names or (name, description)
    assert names, 'no bundled scenes'
    rng = np.random.default_rng(42)
    allerrs, n_models, n_moving = {}, 0, 0
    for name in names:
        models = {id(mm): mm for mm in _models_in(load_scene(name))}.values()
        for mm in models:
            if mm.nv == 0 or mm.has_spherical:   # spherical trees (huston_human17): kernels only, checked
                continue                         # against Pinocchio in test_spherical.py
            n_models += 1
            n_moving += int((mm.jtype != FIXED).sum())  # bodies with a Pinocchio joint
            for k, e in compare(mm, rng, 2, f'scene {name} model {mm.name}').items():
                allerrs.setdefault(k, []).extend(e)
    assert n_models >= 1, f'no kinematic tree found in scenes {names}'
    per_state = {'pose': n_moving, 'wrench': 2 * n_moving, 'rnea': 2 * n_models, 'aba': 2 * n_models}
    assert_all(allerrs, {k: 2 * per_state.get(k, n_models) for k in allerrs})


@pytest.mark.parametrize('name', ['huston_p19_4_1', 'betancur_dh_animation'])
def test_issue11_scenes_against_pinocchio(name):
    """The two scenes of issue 11 part B by name (so a missing or renamed scene fails here):
    M, RNEA, ABA, joint wrenches, energies and centre of mass at 4 random states each."""
    from robodyn_ros.scene import load_scene
    rng = np.random.default_rng(46)
    models = {id(mm): mm for mm in _models_in(load_scene(name))}.values()
    assert len(models) == 1, name
    m = next(iter(models))
    n_moving = int((m.jtype != FIXED).sum())
    assert n_moving == {'huston_p19_4_1': 7, 'betancur_dh_animation': 5}[name]
    errs = compare(m, rng, 4, name)
    per_state = {'pose': n_moving, 'wrench': 2 * n_moving, 'rnea': 2, 'aba': 2}
    assert_all(errs, {k: 4 * per_state.get(k, 1) for k in errs})
