"""/tf on a tree whose joints have oblique axes and rotated origins, against the dynamics' forward
kinematics (:func:`robodyn_ros.dynamics.body_poses`, Plücker transforms of ``jcalc``): every term
of the quaternion product is then non-zero (the bundled scenes' axes lie along their frames' axes,
where a wrong sign on a vanishing term goes unseen). The transforms are those of
:func:`robodyn_ros.kernels.records.tf_values_many`, the one implementation of /tf, for K
publications at once and for one (``TfTree.transforms``)."""
import numpy as np

from robodyn_ros import dynamics as dyn
from robodyn_ros.scene import parse_scene
from robodyn_ros.spatial import quat_to_R
from robodyn_ros.tf import TfTree

_OBLIQUE = """name: oblique
gravity: [0, 0, -9.81]
parts:
  - kind: arm
    name: arm
    links:
      - {name: l1, joint: j1, parent: base_link, type: revolute, origin: {xyz: [0.1, -0.2, 0.3], rpy: [0.4, -0.7, 1.1]},
         axis: [0.48, 0.6, 0.64], mass: 1.0, com: [0.2, 0.1, 0], inertia: [0.01, 0.02, 0.03, 0, 0, 0]}
      - {name: l2, joint: j2, parent: l1, type: prismatic, origin: {xyz: [0.5, 0.1, -0.1], rpy: [-0.9, 0.3, 0.2]},
         axis: [0.6, -0.8, 0.0], mass: 1.0, com: [0.1, 0, 0.1], inertia: [0.01, 0.02, 0.03, 0, 0, 0]}
      - {name: l3, joint: j3, parent: l2, type: revolute, origin: {xyz: [0.0, 0.4, 0.2], rpy: [1.3, 0.5, -2.0]},
         axis: [-0.36, 0.48, 0.8], mass: 1.0, com: [0.0, 0.2, 0], inertia: [0.01, 0.02, 0.03, 0, 0, 0]}
"""


def _world(rows, frames, root):
    """World pose (R, p) of every child frame, composing the transforms (x, y, z, qx, qy, qz, qw) from root."""
    poses = {root: (np.eye(3), np.zeros(3))}
    for (parent, child), v in zip(frames, rows):   # model order: parents first
        Rp, pp = poses[parent]
        poses[child] = (Rp @ quat_to_R(v[3:]), pp + Rp @ v[:3])
    return poses


def test_tf_on_oblique_joints_equals_the_dynamics_body_poses():
    sc = parse_scene(_OBLIQUE)
    tree = TfTree(sc.system)
    model = sc.system.model
    names = list(sc.system.joint_names)
    assert names == ['j1', 'j2', 'j3']
    rng = np.random.default_rng(29)
    pos = rng.uniform(-4.0, 4.0, size=(40, 3))
    got = tree.transform_values(names, pos)
    assert got.shape == (40, 3, 7)
    worst = 0.0
    for k in range(40):
        one = tree.transforms(names, pos[k])   # a single publication: the same numbers as row k
        assert np.array([(*p, *q) for _, _, p, q in one]).tobytes() == got[k].tobytes()
        poses = _world(got[k], tree.frames(False), model.root)
        R, p = dyn.body_poses(model, pos[k])
        for i, link in enumerate(model.link_names):
            worst = max(worst, np.abs(poses[link][0] - R[i]).max(), np.abs(poses[link][1] - p[i]).max())
        # the oblique case: each revolute transform's rotation part has all four components non-zero
        assert np.all(got[k][[0, 2], 3:] != 0.0)
    print(f'/tf vs dynamics.body_poses on oblique joints: {worst:.1e}')
    assert worst < 1e-12
