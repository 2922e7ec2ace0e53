"""A robodyn :class:`~robodyn_ros.model.Model` rebuilt joint by joint in Pinocchio (no URDF).

URDF has no ball joint (our export writes a spherical joint as three revolute joints), so trees
with spherical joints are built here directly: ``JointModelSpherical`` (q = quaternion x y z w,
v = angular velocity in the child frame, as ours), ``JointModelFreeFlyer`` for a FREE joint (q
identical, v = (linear, angular) in Pinocchio, [angular; linear] here) and unaligned revolute /
prismatic joints, from the same placements (``Xtree``) and inertias. Used by the speed benchmark
and by test/test_spherical.py (the Pinocchio oracle of the spherical joint).
"""
from __future__ import annotations

import numpy as np


def depth_first(model) -> list:
    """Body indices in depth-first order (Pinocchio's algorithms assume each subtree's v indices
    are contiguous)."""
    order, stack = [], [i for i in range(model.nb - 1, -1, -1) if model.parent[i] < 0]
    while stack:
        i = stack.pop()
        order.append(i)
        stack += [c for c in range(model.nb - 1, i, -1) if model.parent[c] == i]
    return order


def pin_model(model):
    """``(pin.Model, qmap, vmap, jid)``: our ``q[k]`` is Pinocchio's ``q[qmap[k]]`` (same for v),
    ``jid`` maps body index -> Pinocchio joint id. FIXED joints are not supported (ValueError)."""
    import pinocchio as pin

    from ..model import FREE, PRISMATIC, REVOLUTE, SPHERICAL
    from ..tf import _tree_pose   # the joint frame (R, p) in its parent, from Xtree
    pm = pin.Model()
    pm.gravity.linear = np.asarray(model.gravity, dtype=float)
    jid = {}
    qmap = np.empty(model.nq, dtype=int)
    vmap = np.empty(model.nv, dtype=int)
    for i in depth_first(model):
        placement = pin.SE3(*_tree_pose(model.Xtree[i]))
        parent = 0 if model.parent[i] < 0 else jid[int(model.parent[i])]
        jt = int(model.jtype[i])
        if jt == SPHERICAL:
            jm = pin.JointModelSpherical()
        elif jt == FREE:
            jm = pin.JointModelFreeFlyer()
        elif jt == REVOLUTE:
            jm = pin.JointModelRevoluteUnaligned(*model.axis[i])
        elif jt == PRISMATIC:
            jm = pin.JointModelPrismaticUnaligned(*model.axis[i])
        else:
            raise ValueError(f'{model.name}: joint {model.joint_names[i]!r}: FIXED joints are not rebuilt here')
        j = pm.addJoint(parent, jm, placement, model.joint_names[i])
        s = model.specs[i]
        pm.appendBodyToJoint(j, pin.Inertia(float(s.mass), np.asarray(s.com, float), np.asarray(s.inertia, float)),
                             pin.SE3.Identity())
        jid[i] = j
        jmod = pm.joints[j]
        q0, v0 = model.q_idx[i], model.v_idx[i]
        qmap[q0:q0 + jmod.nq] = jmod.idx_q + np.arange(jmod.nq)
        if jt == FREE:
            vmap[v0:v0 + 6] = jmod.idx_v + np.array([3, 4, 5, 0, 1, 2])
        else:
            vmap[v0:v0 + jmod.nv] = jmod.idx_v + np.arange(jmod.nv)
    return pm, qmap, vmap, jid
