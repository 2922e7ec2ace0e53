"""6D spatial algebra (Featherstone, *Rigid Body Dynamics Algorithms*, 2008, ch. 2).

Conventions, used everywhere in robodyn_ros:

* spatial motion and force vectors are ``[angular; linear]`` (6,), as in the book;
* a Plücker transform ``X`` (6, 6) from frame A to frame B maps motion vectors in A
  coordinates to B coordinates; forces map with ``X^-T`` (``X^*``);
* ``E`` (3, 3) is the coordinate rotation from A to B (``E = R^T`` where ``R`` has B's axes as
  columns in A), ``r`` (3,) is B's origin expressed in A (book eq. 2.24: ``X = [E 0; -E r× E]``);
* poses returned to users are ``(R, p)``: ``R`` rotates child coordinates into parent ones and
  ``p`` is the child origin in parent coordinates.
"""
from __future__ import annotations

import numpy as np

__all__ = [
    'skew', 'rotx', 'roty', 'rotz', 'rot_axis', 'plux', 'pose_of', 'xinv', 'xtrans', 'xrot',
    'crm', 'crf', 'mcI', 'inertia_parts', 'rpy_to_R', 'R_to_rpy', 'quat_to_R', 'R_to_quat',
    'quat_mul', 'quat_exp',
]


def skew(v):
    """Return the 3x3 cross-product matrix ``v×``.

    v: (3,) vector.
    """
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def rot_axis(axis, angle):
    """Rotation matrix R (3, 3) turning by ``angle`` (rad) about unit ``axis`` (Rodrigues).

    axis: (3,) unit vector; angle: radians, right-hand rule.
    """
    k = skew(axis)
    return np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)


def rotx(a):
    """Rotation matrix R about x by angle ``a`` (rad)."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def roty(a):
    """Rotation matrix R about y by angle ``a`` (rad)."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rotz(a):
    """Rotation matrix R about z by angle ``a`` (rad)."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def plux(E, r):
    """Plücker transform from coordinate rotation ``E`` and translation ``r`` (book eq. 2.24).

    E: (3, 3) rotation from A to B coordinates; r: (3,) origin of B expressed in A.
    """
    X = np.zeros((6, 6))
    X[:3, :3] = E
    X[3:, 3:] = E
    X[3:, :3] = -E @ skew(r)
    return X


def pose_of(R, p):
    """Plücker transform A->B for a child frame B with pose ``(R, p)`` in A.

    R: (3, 3) child axes in parent coordinates; p: (3,) child origin in parent coordinates.
    """
    return plux(R.T, p)


def xinv(X):
    """Inverse of a Plücker transform without a general matrix inverse.

    X: (6, 6) motion transform.
    """
    E = X[:3, :3]
    Er = X[3:, :3]  # = -E r×
    Xi = np.zeros((6, 6))
    Xi[:3, :3] = E.T
    Xi[3:, 3:] = E.T
    Xi[3:, :3] = Er.T
    return Xi


def xtrans(r):
    """Pure translation transform (origin of B at ``r`` in A)."""
    return plux(np.eye(3), r)


def xrot(R):
    """Pure rotation transform for a child frame with axes ``R`` (columns) in the parent."""
    return plux(R.T, np.zeros(3))


def crm(v):
    """Motion cross-product matrix ``v×`` (book eq. 2.31).

    v: (6,) spatial motion [w; v].
    """
    w, u = v[:3], v[3:]
    M = np.zeros((6, 6))
    M[:3, :3] = skew(w)
    M[3:, 3:] = skew(w)
    M[3:, :3] = skew(u)
    return M


def crf(v):
    """Force cross-product matrix ``v×* = -(v×)^T`` (book eq. 2.32).

    v: (6,) spatial motion.
    """
    return -crm(v).T


def mcI(m, c, Ic):
    """Spatial inertia at a body-frame origin from mass, centre of mass and rotational inertia.

    m: mass (kg); c: (3,) centre of mass in body coordinates; Ic: (3, 3) inertia about the
    centre of mass in body axes (book eq. 2.63).
    """
    C = skew(c)
    I = np.zeros((6, 6))
    I[:3, :3] = Ic + m * C @ C.T
    I[:3, 3:] = m * C
    I[3:, :3] = m * C.T
    I[3:, 3:] = m * np.eye(3)
    return I


def inertia_parts(I):
    """Inverse of :func:`mcI`: ``(m, c, Ic)`` from a spatial inertia (6, 6)."""
    m = I[5, 5]
    if m <= 0.0:
        return 0.0, np.zeros(3), I[:3, :3].copy()
    C = I[:3, 3:] / m
    c = np.array([C[2, 1], C[0, 2], C[1, 0]])
    Ic = I[:3, :3] - m * C @ C.T
    return m, c, Ic


def rpy_to_R(rpy):
    """URDF roll-pitch-yaw (fixed axes x, y, z) to a rotation matrix ``Rz(y) Ry(p) Rx(r)``."""
    r, p, y = rpy
    return rotz(y) @ roty(p) @ rotx(r)


def R_to_rpy(R):
    """Rotation matrix to URDF roll-pitch-yaw; the exact inverse of :func:`rpy_to_R`.

    Every angle comes from an ``arctan2`` (no ``arcsin``), so it stays accurate next to pitch
    ±90°; exactly at gimbal lock, yaw is set to 0 and the rotation is carried by roll.
    """
    cp = np.hypot(R[0, 0], R[1, 0])
    y = np.arctan2(R[1, 0], R[0, 0]) if cp > 1e-12 else 0.0
    cy, sy = np.cos(y), np.sin(y)  # Rz(-y) R = Ry(p) Rx(r)
    p = np.arctan2(-R[2, 0], cy * R[0, 0] + sy * R[1, 0])
    r = np.arctan2(sy * R[0, 2] - cy * R[1, 2], cy * R[1, 1] - sy * R[0, 1])
    return np.array([r, p, y])


def quat_to_R(q):
    """Unit quaternion ``(x, y, z, w)`` (ROS order) to rotation matrix R (3, 3)."""
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def R_to_quat(R):
    """Rotation matrix to unit quaternion ``(x, y, z, w)`` with ``w >= 0`` (Shepperd's method)."""
    t = np.trace(R)
    if t > 0.0:
        s = 2.0 * np.sqrt(1.0 + t)
        q = np.array([(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s])
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = np.array([0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s, (R[2, 1] - R[1, 2]) / s])
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = np.array([(R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s, (R[0, 2] - R[2, 0]) / s])
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = np.array([(R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s, (R[1, 0] - R[0, 1]) / s])
    q /= np.linalg.norm(q)
    return q if q[3] >= 0.0 else -q


def quat_mul(a, b):
    """Hamilton product ``a ⊗ b`` of quaternions in ``(x, y, z, w)`` order."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ])


def quat_exp(phi):
    """Unit quaternion ``(x, y, z, w)`` of the rotation vector ``phi`` (3,) (axis × angle)."""
    th = np.linalg.norm(phi)
    if th < 1e-8:
        half = 0.5 * np.asarray(phi, dtype=float)
        q = np.array([half[0], half[1], half[2], 1.0 - th * th / 8.0])
        return q / np.linalg.norm(q)
    s = np.sin(0.5 * th) / th
    return np.array([phi[0] * s, phi[1] * s, phi[2] * s, np.cos(0.5 * th)])
