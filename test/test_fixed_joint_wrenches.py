"""Wrenches through FIXED joints (``constraint_wrenches/tool_joint`` ...) against Pinocchio.

Pinocchio merges a URDF's fixed joints into their parent body, so it has no transmitted force
for them. The oracle here is the same URDF with every fixed joint turned into a revolute joint
(axis z, any axis would do) that is *held*: q = 0, q̇ = 0, q̈ = 0. A held joint is kinematically
a weld, so Pinocchio's RNEA force ``data.f[j]`` of that joint is the full 6D wrench the parent
exerts on the child through the weld, at the joint origin, in the child link frame — the
convention of README "Constraint wrenches" (ours is ordered [torque; force], Pinocchio's
(linear, angular)). The accelerations of the moving joints come from Pinocchio's own ABA on the
original URDF, so on the scenes the whole published path (ABA, then the wrench pass at the
simulated acceleration, with joint damping) is compared, not just our RNEA.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin

from robodyn_ros import dynamics as dyn
from robodyn_ros.model import FIXED, FREE, LinkSpec, build_model, to_urdf
from test_pinocchio import PinBridge, random_q

TOL = 1e-13   # measured worst 1.5e-15 relative


class HeldWeldBridge:
    """Pinocchio model of ``m`` in which every FIXED joint is a revolute joint held at zero."""

    def __init__(self, m):
        self.m = m
        root = ET.fromstring(to_urdf(m))
        fixed = {m.joint_names[i] for i in range(m.nb) if m.jtype[i] == FIXED}
        turned = 0
        for j in root.iter('joint'):
            if j.get('name') in fixed:
                assert j.get('type') == 'fixed', j.get('name')
                j.set('type', 'revolute')
                for tag in ('axis', 'limit'):
                    for old in j.findall(tag):
                        j.remove(old)
                ET.SubElement(j, 'axis', xyz='0 0 1')
                ET.SubElement(j, 'limit', lower='-1', upper='1', effort='0', velocity='0')
                turned += 1
        assert turned == len(fixed)
        self.pm = pin.buildModelFromXML(ET.tostring(root, encoding='unicode'))
        self.pm.gravity.linear = np.asarray(m.gravity, dtype=float)
        self.pd = self.pm.createData()
        assert self.pm.nv == m.nv + len(fixed)
        self.jid = {i: self.pm.getJointId(m.joint_names[i]) for i in range(m.nb)}
        assert all(j < self.pm.njoints for j in self.jid.values())

    def state(self, q, v, a):
        """Our (q, v, a) as the held model's, the held joints at rest."""
        m, pm = self.m, self.pm
        qp, vp, ap = np.zeros(pm.nq), np.zeros(pm.nv), np.zeros(pm.nv)
        for i in range(m.nb):
            if m.jtype[i] == FIXED:
                continue
            jm = pm.joints[self.jid[i]]
            q0, v0 = m.q_idx[i], m.v_idx[i]
            qp[jm.idx_q:jm.idx_q + jm.nq] = q[q0:q0 + jm.nq]
            order = [3, 4, 5, 0, 1, 2] if m.jtype[i] == FREE else [0]   # ours [w; v], Pinocchio (v, w)
            vp[jm.idx_v:jm.idx_v + jm.nv] = v[v0:v0 + jm.nv][order]
            ap[jm.idx_v:jm.idx_v + jm.nv] = a[v0:v0 + jm.nv][order]
        return qp, vp, ap

    def wrenches(self, q, v, a) -> dict:
        """body index -> Pinocchio's transmitted wrench [torque; force] at the simulated q, v, a."""
        pin.rnea(self.pm, self.pd, *self.state(q, v, a))
        return {i: np.concatenate([self.pd.f[j].angular, self.pd.f[j].linear]) for i, j in self.jid.items()}


def _errors(m, states, ours):
    """Largest relative 6D difference over the FIXED bodies (and the count compared)."""
    hb = HeldWeldBridge(m)
    worst, n = 0.0, 0
    for q, v, a in states:
        ref = hb.wrenches(q, v, a)
        f = ours(q, v, a)
        scale = max(1.0, max(np.abs(w).max() for w in ref.values()))
        for i in range(m.nb):
            worst = max(worst, float(np.abs(f[i] - ref[i]).max()) / scale)   # every body: a sanity anchor
            n += int(m.jtype[i] == FIXED)
    return worst, n


def test_held_weld_bridge_reproduces_pinocchio_on_moving_joints():
    """The bridge itself: turning welds into held joints changes nothing for the moving ones,
    and a hanging weld carries the weight of what hangs below it."""
    m = build_model([LinkSpec('arm', 'pivot', None, 'revolute', axis=(0, 1, 0), mass=1.0, com=(0.25, 0, 0)),
                     LinkSpec('tool', 'weld', 'arm', 'fixed', origin_xyz=(0.5, 0, 0), mass=2.0, com=(0.1, 0, 0))],
                    gravity=(0.0, 0.0, -10.0))
    z = np.zeros(1)
    w = HeldWeldBridge(m).wrenches(z, z, z)
    # statics: 20 N up, and the moment -(0.1 x̂ × -20 ẑ) = (0, -2, 0) N·m that holds the CoM 0.1 m out
    assert np.allclose(w[1], [0, -2.0, 0, 0, 0, 20.0], atol=1e-12)
    _, f = dyn.rnea_wrenches(m, z, z, z)
    assert np.allclose(f[1], w[1], atol=1e-12)
    b = PinBridge(m)
    pin.rnea(b.pm, b.pd, z, z, z)
    assert np.allclose(np.concatenate([b.pd.f[1].angular, b.pd.f[1].linear]), w[0], atol=1e-12)


def test_fixed_joint_wrenches_on_random_trees_against_pinocchio(trees):
    rng = np.random.default_rng(47)
    n_fixed, worst = 0, 0.0
    for label, m in trees:
        states = [(random_q(m, rng), rng.normal(size=m.nv), rng.normal(size=m.nv)) for _ in range(2)]
        e, n = _errors(m, states, lambda q, v, a, m=m: dyn.rnea_wrenches(m, q, v, a)[1])
        worst, n_fixed = max(worst, e), n_fixed + n
    assert n_fixed >= 10, f'only {n_fixed} fixed joints in the random trees'
    assert worst < TOL, worst


def test_published_fixed_joint_wrenches_of_the_scenes_against_pinocchio():
    """What the node publishes (``ArmSystem.outputs``, compiled kernels, with damping) for
    stanford_arm's tool_joint and every other scene's welds, at random states and commands."""
    from robodyn_ros.scene import load_scene
    rng = np.random.default_rng(48)
    checked = {}
    for name in ('stanford_arm', 'betancur_pendulum', 'huston_p19_2_3'):
        sc = load_scene(name)
        sy, m = sc.system, sc.system.model
        if not (m.jtype == FIXED).any():
            continue
        b = PinBridge(m)
        states = []
        for _ in range(3):
            q = sc.y0[:m.nq] + 0.3 * rng.normal(size=m.nq)
            v = rng.normal(size=m.nv)
            u = {'effort': rng.normal(size=len(sy.actuated)) * 5}
            y = np.concatenate([q, v])
            tau_net = sy.generalized_forces(y, u)                          # B u - D v
            np.testing.assert_allclose(tau_net, sy.B @ u['effort'] - m.damping * v, rtol=0, atol=1e-12)
            a = b.back(pin.aba(b.pm, b.pd, b.q(q), b.v(v), b.v(tau_net)))  # Pinocchio's acceleration
            out = sy.outputs(0.0, y, u, wrenches=True)
            states.append((q, v, a, out))
        hb = HeldWeldBridge(m)
        worst = 0.0
        for q, v, a, out in states:
            ref = hb.wrenches(q, v, a)
            scale = max(1.0, max(np.abs(w).max() for w in ref.values()))
            for i in range(m.nb):
                frame, w = out.wrenches[m.joint_names[i]]
                assert frame == m.link_names[i]
                worst = max(worst, float(np.abs(w - ref[i]).max()) / scale)
        checked[name] = (int((m.jtype == FIXED).sum()), worst)
    assert 'stanford_arm' in checked and checked['stanford_arm'][0] >= 1, checked
    assert all(e < TOL for _, e in checked.values()), checked
    print(f'\nfixed-joint wrenches vs Pinocchio (held welds): {checked}')
