"""Simulated IMU and force-torque sensors, compiled (numba): their one implementation.

Both read the tree's motion at one state ``(q, v)`` with the joint accelerations ``q̈`` the dynamics
gives there (the right-hand side at the output state): one RNEA pass (book Table 5.1) at ``(q, v, q̈)``
with the fictitious base acceleration ``a₀ = −[0; g]`` (book §5.3), which leaves in every body's
spatial acceleration ``a_i − g`` (body coordinates) and in every joint the wrench the parent transmits
(``constraint_wrenches/<joint>``, fixed joints included), then the world poses.

**IMU** on body b (a URDF link; body coordinates, ``[ω; v_O]`` spatial vectors):

* orientation: the body's rotation relative to the root frame (world, or the fixed base's root);
* angular velocity ``ω_b``;
* linear acceleration = specific force: the classical acceleration of the body origin minus gravity,
  ``f = a_lin + ω × v_O`` (the spatial acceleration's linear part is ``a_O − ω × v_O``, book §2.11),
  already minus g through a₀: at rest it reads +g upward (``+9.81`` along the world's up axis,
  expressed in the body), in free fall 0.

**Force-torque sensor** on joint j, read in frame s (a URDF link): the joint wrench ``[n; f]`` at the
child's origin c, child coordinates, moved to s's origin and turned into s's axes:
``f_s = R_sc f``, ``n_s = R_sc (n − p × f)`` with ``p`` the origin of s in c's coordinates and
``R_sc = E0_s E0_cᵀ`` (E0: root-to-body rotation, world axes to body axes).
"""
from __future__ import annotations

import numpy as np

from .jit import njit
from .tree import _JIT, A_, E0_, P_, R0_, V_, rnea_ws, transforms, workspace, world_kinematics_ws

#: columns of an IMU reading row: E0 (9, row major: world axes -> body axes), ω (3), specific force (3)
IMU_E, IMU_W, IMU_F, NIMU = 0, 9, 12, 15


@njit(**_JIT)
def sensor_readings(mi, mf, q, v, qdd, fext, has_fext, imu, ft, out_imu, out_ft):
    """Readings of the IMUs on bodies ``imu`` (ni,) into ``out_imu (ni, NIMU)`` and of the force-torque
    sensors ``ft (nf, 2)`` = [joint's body, frame body] into ``out_ft (nf, 6)`` = ``[n; f]`` in the
    frame's axes about its origin (module docstring). q (nq,), v, qdd (nv,): the state and its
    accelerations; fext (nb, 6): external body forces (has_fext) as the dynamics applied them; all on
    the full tree (fixed bodies kept)."""
    nb = mi.shape[0]
    W = workspace(nb)
    transforms(mi, mf, q, W)
    tau = np.empty(qdd.shape[0])
    rnea_ws(mi, mf, q, v, qdd, fext, has_fext, tau, W)
    world_kinematics_ws(mi, mf, v, W)
    for s in range(imu.shape[0]):
        b = imu[s]
        for a in range(9):
            out_imu[s, IMU_E + a] = W[b, E0_ + a]
        w0, w1, w2 = W[b, V_], W[b, V_ + 1], W[b, V_ + 2]
        u0, u1, u2 = W[b, V_ + 3], W[b, V_ + 4], W[b, V_ + 5]
        out_imu[s, IMU_W] = w0
        out_imu[s, IMU_W + 1] = w1
        out_imu[s, IMU_W + 2] = w2
        out_imu[s, IMU_F] = W[b, A_ + 3] + (w1 * u2 - w2 * u1)
        out_imu[s, IMU_F + 1] = W[b, A_ + 4] + (w2 * u0 - w0 * u2)
        out_imu[s, IMU_F + 2] = W[b, A_ + 5] + (w0 * u1 - w1 * u0)
    for s in range(ft.shape[0]):
        c = ft[s, 0]
        o = ft[s, 1]
        n0, n1, n2 = W[c, P_], W[c, P_ + 1], W[c, P_ + 2]
        f0, f1, f2 = W[c, P_ + 3], W[c, P_ + 4], W[c, P_ + 5]
        # p = E0_c (r0_o − r0_c): the frame's origin in c's coordinates
        d0 = W[o, R0_] - W[c, R0_]
        d1 = W[o, R0_ + 1] - W[c, R0_ + 1]
        d2 = W[o, R0_ + 2] - W[c, R0_ + 2]
        p0 = W[c, E0_] * d0 + W[c, E0_ + 1] * d1 + W[c, E0_ + 2] * d2
        p1 = W[c, E0_ + 3] * d0 + W[c, E0_ + 4] * d1 + W[c, E0_ + 5] * d2
        p2 = W[c, E0_ + 6] * d0 + W[c, E0_ + 7] * d1 + W[c, E0_ + 8] * d2
        m0 = n0 - (p1 * f2 - p2 * f1)
        m1 = n1 - (p2 * f0 - p0 * f2)
        m2 = n2 - (p0 * f1 - p1 * f0)
        # R_oc = E0_o E0_cᵀ: c's axes -> world -> o's axes
        for a in range(3):
            r0 = W[o, E0_ + 3 * a] * W[c, E0_] + W[o, E0_ + 3 * a + 1] * W[c, E0_ + 1] \
                + W[o, E0_ + 3 * a + 2] * W[c, E0_ + 2]
            r1 = W[o, E0_ + 3 * a] * W[c, E0_ + 3] + W[o, E0_ + 3 * a + 1] * W[c, E0_ + 4] \
                + W[o, E0_ + 3 * a + 2] * W[c, E0_ + 5]
            r2 = W[o, E0_ + 3 * a] * W[c, E0_ + 6] + W[o, E0_ + 3 * a + 1] * W[c, E0_ + 7] \
                + W[o, E0_ + 3 * a + 2] * W[c, E0_ + 8]
            out_ft[s, a] = r0 * m0 + r1 * m1 + r2 * m2
            out_ft[s, 3 + a] = r0 * f0 + r1 * f1 + r2 * f2
