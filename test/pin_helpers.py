"""Pinocchio readings of recorded messages, shared by the tests that rebuild a robot's state from a recording
alone (Pinocchio is the oracle: it reads the recording's own ``/robot_description``)."""
from __future__ import annotations

import math

import numpy as np
import pinocchio as pin


def centroidal_momenta(pm, msgs):
    """Pinocchio's centroidal momentum ``(p (n, 3), L (n, 3), positions [dict])`` at every ``/joint_states``
    of a recording of a free-rooted tree of spherical joints written as Bryan-angle triples (``<joint>_x``,
    ``_y``, ``_z``: the human's URDF export), its root from ``/odom`` at the same stamp. pm: the Pinocchio
    model of the recorded ``/robot_description`` on a free flyer; msgs: topic -> [(t_ns, message)].

    Each triple's rates come from the child-frame angular velocity ω of the recorded velocities:
    ``α̇ = (cos γ ω_x − sin γ ω_y) / cos β``, ``β̇ = sin γ ω_x + cos γ ω_y``, ``γ̇ = ω_z − sin β α̇``."""
    pd = pm.createData()
    odom = dict(msgs['/odom'])
    ps, Ls, positions = [], [], []
    for t_ns, js in msgs['/joint_states']:
        o = odom[t_ns]
        q, v = pin.neutral(pm), np.zeros(pm.nv)
        P, Q = o.pose.pose.position, o.pose.pose.orientation
        q[:7] = [P.x, P.y, P.z, Q.x, Q.y, Q.z, Q.w]
        lin, ang = o.twist.twist.linear, o.twist.twist.angular
        v[:6] = [lin.x, lin.y, lin.z, ang.x, ang.y, ang.z]
        pos, vel = dict(zip(js.name, js.position)), dict(zip(js.name, js.velocity))
        for j in {n[:-2] for n in js.name}:
            a, b, g = (pos[j + s] for s in ('_x', '_y', '_z'))
            w = [vel[j + s] for s in ('_x', '_y', '_z')]          # child-frame angular velocity
            ad = (math.cos(g) * w[0] - math.sin(g) * w[1]) / math.cos(b)
            rates = (ad, math.sin(g) * w[0] + math.cos(g) * w[1], w[2] - math.sin(b) * ad)
            for s, x, xd in zip(('_x', '_y', '_z'), (a, b, g), rates):
                jm = pm.joints[pm.getJointId(j + s)]
                q[jm.idx_q], v[jm.idx_v] = x, xd
        hg = pin.computeCentroidalMomentum(pm, pd, q, v)
        ps.append(np.array(hg.linear))
        Ls.append(np.array(hg.angular))
        positions.append(pos)
    return np.array(ps), np.array(Ls), positions
