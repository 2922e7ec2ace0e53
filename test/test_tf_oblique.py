"""TfTree.transform_values (the recorder's batched /tf, kernels/records.tf_values_many) against
TfTree.transforms (one publication at a time) on a tree whose joints have oblique axes and
rotated origins: every term of the quaternion product is then non-zero (the bundled scenes'
axes lie along their frames' axes, where a wrong sign on a vanishing term goes unseen)."""
import numpy as np

from robodyn_ros.scene import parse_scene
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


def test_batched_tf_equals_per_publication_tf_on_oblique_joints():
    sc = parse_scene(_OBLIQUE)
    tree = TfTree(sc.system)
    names = list(sc.system.joint_names)
    assert names == ['j1', 'j2', 'j3']
    rng = np.random.default_rng(29)
    pos = rng.uniform(-4.0, 4.0, size=(40, 3))
    got = tree.transform_values(names, pos)
    assert got.shape == (40, 3, 7)
    for k in range(40):
        want = np.array([(*p, *q) for _, _, p, q in tree.transforms(names, pos[k])])
        assert want.tobytes() == got[k].tobytes()   # bit for bit
        # the oblique case: each moving transform's rotation part has all four components non-zero
        assert np.all(want[[0, 2], 3:] != 0.0)
