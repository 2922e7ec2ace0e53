"""Scene huston_p19_4_1 against hand-derived answers of Huston's problems P19.4.1, P19.4.5,
P19.8.3 and P19.8.7 (seed 000, chapter 19).

The hand derivation below is written from the scene file's documented reading, directly as
Huston's transformation-matrix products (S_0K = Rz(alpha_B) Rx(90 deg + alpha_1) Rz(gamma_1)
Rx(alpha_2) Rz(gamma_2) ..., joint origins O_{K+1} = O_K + L_K S_0K n_1), with plain numpy and no
robodyn code; the model side goes through the scene loader, the URDF-style origins, the tree
transforms and the forward kinematics of robodyn_ros.dynamics. The book's answers are not in the
seed (it holds the problems only), so the figures are ours; the test prints them.
"""
from __future__ import annotations

import numpy as np
import pytest

from robodyn_ros import dynamics as dyn
from robodyn_ros.scene import load_scene

IN = 0.0254
DEG = np.pi / 180.0
ALPHA = np.array([0.0, 90.0, 0.0, -90.0, 0.0, 90.0]) * DEG   # P19.4.2 pin inclinations
GAMMA = np.array([30.0, 45.0, 60.0, 45.0, 30.0, 45.0]) * DEG  # P19.4.2 articulation angles
ALPHA_B = 30.0 * DEG
LENGTH = np.array([6.0, 6.0, 8.0, 8.0, 12.0, 12.0]) * IN       # P19.8.3
H_O1 = 6.0 * IN                                                 # O_1 above O


def Rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def Rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def hand(alpha_b=ALPHA_B, gamma=GAMMA):
    """``(S (6, 3, 3), O (7, 3))``: link orientations S_0K in R and joint origins O_1..O_6, E."""
    S, O = [], [np.array([0.0, 0.0, H_O1])]
    R = Rz(alpha_b) @ Rx(np.pi / 2)  # B, then the horizontal 'pin 0' reference
    for k in range(6):
        R = R @ Rx(ALPHA[k]) @ Rz(gamma[k])
        S.append(R)
        O.append(O[-1] + LENGTH[k] * R[:, 0])
    return np.array(S), np.array(O)


def _model_state():
    sc = load_scene('huston_p19_4_1')
    m = sc.system.model
    q = np.concatenate([[ALPHA_B], GAMMA])
    return sc, m, q


def test_degrees_of_freedom_and_initial_posture_p19_4_1():
    """P19.4.1: 'How many degrees of freedom?' -- 7 (the base and six pins); the scene starts at P19.4.2."""
    sc, m, q = _model_state()
    assert m.nv == 7 and sc.system.joint_names == ['alpha_B'] + [f'gamma_{k}' for k in range(1, 7)]
    assert np.allclose(sc.y0[:7], q, rtol=0, atol=1e-15) and np.all(sc.y0[7:] == 0.0)


def test_end_effector_position_p19_8_3():
    """P19.8.3: P_E relative to O at the P19.4.2 angles equals the hand-derived product."""
    _, m, q = _model_state()
    R, p = dyn.body_poses(m, q)
    iE = m.link_names.index('E')
    _, O = hand()
    print('P19.8.3 P_E (m):', p[iE].tolist(), '(in):', (p[iE] / IN).tolist())
    assert np.abs(p[iE] - O[6]).max() < 1e-14
    # the link origins O_1..O_6 as well (each joint frame sits on its pin)
    for k in range(6):
        assert np.abs(p[m.link_names.index(f'L{k + 1}')] - O[k]).max() < 1e-14, k
    # and the pin axes: link k's z axis is pin k
    S, _ = hand()
    for k in range(6):
        assert np.abs(R[m.link_names.index(f'L{k + 1}')] - S[k]).max() < 1e-14, k
    # a planted error must show: pin 1 read as vertical (the P19.2.3 convention) moves E by cm
    R0 = Rz(ALPHA_B)
    O_alt = np.array([0.0, 0.0, H_O1])
    for k in range(6):
        R0 = R0 @ Rx(ALPHA[k]) @ Rz(GAMMA[k])
        O_alt = O_alt + LENGTH[k] * R0[:, 0]
    assert np.linalg.norm(O_alt - p[iE]) > 0.05


def test_mass_centres_p19_8_7():
    """P19.8.7: uniform links, mass centres at mid-link: G_K = O_K + (L_K / 2) S_0K n_1."""
    _, m, q = _model_state()
    R, p = dyn.body_poses(m, q)
    S, O = hand()
    for k in range(6):
        i = m.link_names.index(f'L{k + 1}')
        G = p[i] + R[i] @ np.asarray(m.specs[i].com)
        assert np.abs(G - (O[k] + 0.5 * LENGTH[k] * S[k][:, 0])).max() < 1e-14, k


def test_link_angular_velocities_p19_4_5():
    """P19.4.5: all articulation rates 30 rpm = pi rad/s: omega_K = pi (n_03 + sum_{j<=K} pin_j)."""
    _, m, q = _model_state()
    v = np.full(7, np.pi)
    R, _ = dyn.body_poses(m, q)
    vb = dyn.body_velocities(m, q, v)
    S, _ = hand()
    w = np.pi * np.array([0.0, 0.0, 1.0])  # the base B turns about the vertical n_03
    assert np.abs(R[m.link_names.index('B')] @ vb[m.link_names.index('B')][:3] - w).max() < 1e-14
    for k in range(6):
        w = w + np.pi * S[k][:, 2]
        i = m.link_names.index(f'L{k + 1}')
        wk = R[i] @ vb[i][:3]
        print(f'P19.4.5 omega_L{k + 1} (rad/s, in R):', np.round(wk, 6).tolist())
        assert np.abs(wk - w).max() < 1e-13, k


def _partial_velocities(S, O, G):
    """Huston's partial velocities (sections 19.5, 19.10) by hand: ``omega_r[k]`` (7, 6, 3), the
    partial angular velocity of link k for coordinate r, and ``v_r[k]`` of its mass centre G_k."""
    axes = [np.array([0.0, 0.0, 1.0])] + [S[j][:, 2] for j in range(6)]      # n_03 (base), pins 1..6
    points = [np.zeros(3)] + [O[j] for j in range(6)]                        # a point of each axis
    w = np.zeros((7, 6, 3))
    v = np.zeros((7, 6, 3))
    for r in range(7):
        for k in range(6):
            if r <= k + 1:  # coordinate r moves link k (r = 0: the base; r = j + 1: pin j)
                w[r, k] = axes[r]
                v[r, k] = np.cross(axes[r], G[k] - points[r])
    return w, v


def test_kinetic_energy_and_gravity_forces_by_partial_velocities():
    """At P19.4.2 with the P19.4.5 rates (pi rad/s): the kinetic energy from Huston's partial
    velocities (1/2 m v_G^2 + 1/2 w.I w per bar, 1/2 I_B w_B^2 for the base), and the generalised
    gravity forces F_r = sum_k m_k g . v_r(G_k) (section 19.13), against the model's kinetic energy
    and -RNEA(q, 0, 0)."""
    sc, m, q = _model_state()
    S, O = hand()
    G = np.array([O[k] + 0.5 * LENGTH[k] * S[k][:, 0] for k in range(6)])
    w_r, v_r = _partial_velocities(S, O, G)
    mass = 2.0 * LENGTH  # the scene's 2 kg/m bars
    qd = np.full(7, np.pi)
    ke = 0.5 * 0.0025 * np.pi ** 2  # the base: solid cylinder, m r^2 / 2 = 0.0025 kg m^2 about its axis
    for k in range(6):
        wk = np.einsum('r,ri->i', qd, w_r[:, k])
        vk = np.einsum('r,ri->i', qd, v_r[:, k])
        I = S[k] @ np.diag([0.0, 1.0, 1.0]) @ S[k].T * mass[k] * LENGTH[k] ** 2 / 12.0
        ke += 0.5 * mass[k] * vk @ vk + 0.5 * wk @ I @ wk
    ke_model = dyn.kinetic_energy(m, q, qd)
    print(f'P19.4.5 state: kinetic energy {ke_model:.12g} J (partial velocities {ke:.12g} J)')
    assert abs(ke_model - ke) <= 4e-14 * ke   # measured 6e-16
    g = np.array([0.0, 0.0, -9.81])
    F = np.array([sum(mass[k] * g @ v_r[r, k] for k in range(6)) for r in range(7)])
    gravity = dyn.rnea(m, q, np.zeros(7), np.zeros(7))
    print('P19.4.2 generalised gravity forces (N m):', np.round(F, 9).tolist())
    assert F[0] == pytest.approx(0.0, abs=1e-15)  # gravity has no moment about the vertical base axis
    assert np.abs(-gravity - F).max() <= 4e-14 * np.abs(F).max()   # measured 4e-16
    # a planted error must show: the mass centres at the pins' far ends instead of mid-link
    F_bad = np.array([sum(mass[k] * g @ np.cross(w_r[r, k], O[k + 1] - ([np.zeros(3)] + list(O[:6]))[r])
                          for k in range(6) if r <= k + 1) for r in range(7)])
    assert np.abs(-gravity - F_bad).max() > 0.1 * np.abs(F).max()
