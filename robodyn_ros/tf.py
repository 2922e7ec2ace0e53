"""TF of the robot (``tf2_msgs/msg/TFMessage`` dicts) from published outputs; no rclpy.

Foxglove's 3D panel, RViz and every tf2 listener place the links of ``robot_description`` at the
poses that ``/tf`` and ``/tf_static`` give; none of them does forward kinematics from
``joint_states``. :class:`TfTree` is that forward kinematics, done the way
``robot_state_publisher`` does it: from the URDF's joints and the positions in ``joint_states``,
plus ``odom -> base_link`` from the ``odom`` output of platforms and free bases.

The tree is the model the system exports as its URDF (``system.urdf_model`` when the system has
one, as the differential drive does — its dynamics tree has virtual planar joints that the URDF
replaces by the ``odom`` pose — else ``system.model``). For every joint of that model:

- fixed joints give a constant ``parent_link -> child_link`` transform, published once on
  ``/tf_static`` (:meth:`TfTree.static_message`);
- revolute and prismatic joints give ``parent_link -> child_link`` at the joint's position in
  ``joint_states`` (looked up by joint name), published on ``/tf`` (:meth:`TfTree.message`);
- a spherical joint is in the URDF as three revolute joints ``<joint>_x``, ``_y``, ``_z`` about x,
  y', z'' joined by two massless links (:func:`robodyn_ros.model.to_urdf`); ``joint_states`` carries
  their angles (the Bryan angles of the joint's quaternion), so it gives three transforms;
- a free (floating) joint is not in the URDF: its child link (``base_link``) gets
  ``odom -> base_link`` from the ``odom`` output instead, as does the URDF root of a platform.

So the frame ids are the URDF's link names, each non-root URDF link is the child of exactly one
transform, and the tree has one root: ``odom`` for systems that publish ``odom``, the URDF root
(``base_link``) for fixed-base arms. Stamps are simulation time.

Transforms are computed from the model's tree transforms ``Xtree`` and joint axes (the frames of
:func:`robodyn_ros.dynamics.joint_transforms` and of the exported URDF): a revolute joint at
angle θ is ``(R_tree Rot(a, θ), p_tree)``, a prismatic joint at d is ``(R_tree, p_tree + R_tree a d)``.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np

from .model import FIXED, FREE, PRISMATIC, REVOLUTE, SPHERICAL, SPHERICAL_AXES, spherical_link_names

TF_TYPE = 'tf2_msgs/msg/TFMessage'
TF_TOPIC = '/tf'
TF_STATIC_TOPIC = '/tf_static'
ODOM_FRAME = 'odom'

__all__ = ['TfTree', 'TF_TYPE', 'TF_TOPIC', 'TF_STATIC_TOPIC', 'ODOM_FRAME', 'tf_model', 'urdf_joints']


def tf_model(system):
    """The model whose URDF ``system.urdf()`` exports: ``system.urdf_model`` if any, else ``system.model``."""
    model = getattr(system, 'urdf_model', None)
    return model if model is not None else system.model


def urdf_joints(urdf: str) -> dict:
    """``child link -> (joint name, joint type, parent link)`` of every joint of a URDF text."""
    root = ET.fromstring(urdf)
    return {j.find('child').get('link'): (j.get('name'), j.get('type'), j.find('parent').get('link'))
            for j in root.findall('joint')}


def _tree_pose(Xtree):
    """``(R (3, 3), p (3,))``: the joint frame at q = 0 in its parent (child axes, origin)."""
    R = Xtree[:3, :3].T
    P = -R @ Xtree[3:, :3]  # X[3:, :3] = -E r×  =>  r× = -E^T X[3:, :3]
    return R, np.array([P[2, 1], P[0, 2], P[1, 0]])


def _quat(R):
    """Unit quaternion ``(x, y, z, w)`` of a rotation matrix, ``w >= 0``."""
    from .spatial import R_to_quat
    return R_to_quat(R)


def _transform(t_ns: int, parent: str, child: str, p, q) -> dict:
    """``geometry_msgs/TransformStamped`` dict."""
    return {'header': {'stamp': {'sec': int(t_ns // 1_000_000_000), 'nanosec': int(t_ns % 1_000_000_000)},
                       'frame_id': parent},
            'child_frame_id': child,
            'transform': {'translation': {'x': float(p[0]), 'y': float(p[1]), 'z': float(p[2])},
                          'rotation': {'x': float(q[0]), 'y': float(q[1]), 'z': float(q[2]), 'w': float(q[3])}}}


class TfTree:
    """The transform tree of a system's ``robot_description``; build once, call per publication.

    system: a System with ``model`` (and ``urdf_model`` when its URDF is not ``model``'s) and
    ``urdf()``. check_urdf: verify once that the tree's (parent, child) pairs are exactly the
    URDF's joints (raises ValueError naming the difference).

    Attributes: ``root`` (the URDF root link), ``odom_child`` (the link ``odom`` poses: the free
    joint's child, else the URDF root), ``static`` and ``moving`` (lists of ``(parent, child)``).
    """

    def __init__(self, system, check_urdf: bool = True):
        m = tf_model(system)
        names = m.link_names
        free = [i for i in range(m.nb) if m.jtype[i] == FREE]
        if len(free) > 1 or (free and m.parent[free[0]] >= 0):
            raise ValueError(f'{m.name}: at most one free joint, attached to the root, is supported by TF')
        self.root = names[free[0]] if free else m.root
        self.odom_child = self.root
        self.static, self.moving = [], []
        self._static_poses = []
        self._rows = []   # per moving joint: (revolute, joint name, p_tree, q_tree, axis, R_tree rows)
        for i in range(m.nb):
            jt = int(m.jtype[i])
            if jt == FREE:
                continue
            parent = m.root if m.parent[i] < 0 else names[m.parent[i]]
            R, p = _tree_pose(m.Xtree[i])
            if jt == FIXED:
                self.static.append((parent, names[i]))
                self._static_poses.append((tuple(p.tolist()), tuple(_quat(R).tolist())))
            elif jt in (REVOLUTE, PRISMATIC):
                self.moving.append((parent, names[i]))
                self._rows.append((jt == REVOLUTE, m.joint_names[i], tuple(p.tolist()), tuple(_quat(R).tolist()),
                                   tuple(float(a) for a in m.axis[i]), tuple(tuple(r) for r in R.tolist())))
            elif jt == SPHERICAL:   # three revolute joints (x, y', z''), as in the URDF export
                lx, ly = spherical_link_names(m.specs[i])
                eye = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
                for k, (pa, ch) in enumerate(((parent, lx), (lx, ly), (ly, names[i]))):
                    self.moving.append((pa, ch))
                    first = k == 0
                    self._rows.append((True, m.joint_names[i] + SPHERICAL_AXES[k],
                                       tuple(p.tolist()) if first else (0.0, 0.0, 0.0),
                                       tuple(_quat(R).tolist()) if first else (0.0, 0.0, 0.0, 1.0), eye[k],
                                       tuple(tuple(r) for r in R.tolist()) if first else eye))
            else:
                raise ValueError(f'{m.name}: joint {m.joint_names[i]!r} of type {jt} has no TF')
        self._joints = [r[1] for r in self._rows]
        self._names_key = None
        self._src = None
        self._groups = None   # transform_values' constants
        if check_urdf:
            self._check(system.urdf())

    def _check(self, urdf: str):
        """Raise ValueError unless the tree's transforms are exactly the URDF's joints."""
        want = {child: parent for child, (_, _, parent) in urdf_joints(urdf).items()}
        have = {child: parent for parent, child in self.static + self.moving}
        if have != want:
            extra = sorted(set(have.items()) - set(want.items()))
            missing = sorted(set(want.items()) - set(have.items()))
            raise ValueError(f'TF tree differs from robot_description: (child, parent) not in the URDF '
                             f'{extra}, URDF joints without a transform {missing}')

    def _source(self, joint_names):
        """Indices in ``joint_states`` of the moving joints (cached per list of names)."""
        key = tuple(joint_names)
        if key != self._names_key:
            index = {n: k for k, n in enumerate(key)}
            missing = [j for j in self._joints if j not in index]
            if missing:
                raise ValueError(f'joints {missing} of robot_description are not in joint_states {list(key)}')
            self._src = [index[j] for j in self._joints]
            self._names_key = key
        return self._src

    def transforms(self, joint_names, position, odom=None):
        """``[(parent, child, p (x, y, z), quat (x, y, z, w))]`` of one publication, floats:
        ``odom -> odom_child`` first (when ``odom`` is given), then every moving joint in model order.

        joint_names, position: as in ``joint_states``; odom: the outputs' odom dict or None.
        The numbers are :meth:`transform_values` of this one publication.
        """
        pose = None if odom is None else np.concatenate([odom['position'], odom['orientation']])[None]
        values = self.transform_values(joint_names, np.asarray(position, dtype=np.float64)[None], pose)[0]
        return [(parent, child, tuple(v[:3].tolist()), tuple(v[3:].tolist()))
                for (parent, child), v in zip(self.frames(odom is not None), values)]

    def frames(self, odom: bool) -> list:
        """``[(parent, child)]`` of the transforms :meth:`transforms` gives (with or without odom)."""
        return ([(ODOM_FRAME, self.odom_child)] if odom else []) + list(self.moving)

    def transform_values(self, joint_names, positions, odom_pose=None) -> np.ndarray:
        """The transforms of many publications at once: ``(K, n_transforms, 7)`` array of
        ``(x, y, z, qx, qy, qz, qw)`` in the order of :meth:`frames`, computed by
        :func:`robodyn_ros.kernels.records.tf_values_many` (compiled; plain Python without numba):
        a revolute joint ``q_tree ⊗ (a sin θ/2, cos θ/2)`` at ``p_tree``, a prismatic one
        ``p_tree + R_tree a d`` with ``q_tree``.

        positions: (K, n) joint_states positions; odom_pose: (K, 7) odom position and
        orientation, or None when there is no odom entry.
        """
        positions = np.ascontiguousarray(positions, dtype=np.float64)
        K = positions.shape[0]
        first = 0 if odom_pose is None else 1
        out = np.empty((K, first + len(self._rows), 7))
        if first:
            out[:, 0, :] = odom_pose
        if not self._rows:
            return out
        src = np.asarray(self._source(joint_names), dtype=np.int64)
        if self._groups is None:   # the rows' constants as arrays, once
            from .kernels.records import tf_values_many
            r = self._rows
            self._groups = (tf_values_many, np.array([x[0] for x in r]), np.array([x[4] for x in r], dtype=float),
                            np.array([x[2] for x in r], dtype=float), np.array([x[3] for x in r], dtype=float),
                            np.array([x[5] for x in r], dtype=float))
        run, rev, axis, p, q, R = self._groups
        run(rev, src, axis, p, q, R, positions, out, first)
        return out

    def message(self, t_ns: int, out) -> dict:
        """The ``/tf`` message of one publication from :class:`SystemOutputs` ``out`` (stamped t_ns)."""
        return {'transforms': [_transform(t_ns, *tr) for tr in
                               self.transforms(out.joint_names, out.position, out.odom)]}

    def static_message(self, t_ns: int) -> dict:
        """The ``/tf_static`` message: every fixed joint's constant transform (stamped t_ns)."""
        return {'transforms': [_transform(t_ns, parent, child, p, q)
                               for (parent, child), (p, q) in zip(self.static, self._static_poses)]}
