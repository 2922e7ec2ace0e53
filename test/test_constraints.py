"""Constraint solvers: KKT and orthogonal complement agree; closed forms; rank loss is reported."""
import numpy as np
import pytest

from robodyn_ros.constraints import (baumgarte_rhs, complement_solve, kkt_solve, null_space_basis,
                                     project_positions, project_velocities)


def _spd(n, rng):
    A = rng.normal(size=(n, n))
    return A @ A.T + n * np.eye(n)


def test_kkt_and_complement_agree_on_random_systems():
    rng = np.random.default_rng(7)
    errs = []
    for _ in range(20):
        n = int(rng.integers(3, 10))
        m = int(rng.integers(1, n))
        M, Q, K, k = _spd(n, rng), rng.normal(size=n), rng.normal(size=(m, n)), rng.normal(size=m)
        a1, l1, i1 = kkt_solve(M, Q, K, k)
        a2, l2, i2 = complement_solve(M, Q, K, k)
        # independent check: the dense KKT matrix [[M, -K^T], [K, 0]] [a; λ] = [Q; k]
        kkt = np.block([[M, -K.T], [K, np.zeros((m, m))]])
        x = np.linalg.solve(kkt, np.concatenate([Q, k]))
        errs += [np.abs(a1 - x[:n]).max(), np.abs(l1 - x[n:]).max(), np.abs(a2 - x[:n]).max(),
                 np.abs(l2 - x[n:]).max()]
        assert i1.rank == m and i2.rank == m
    assert len(errs) == 80 and max(errs) < 1e-9


def test_point_pendulum_tension_closed_form():
    """A point mass on a rod in Cartesian coordinates: the multiplier is the rod tension."""
    m, g, L, th, w = 2.0, 9.81, 1.5, 0.7, 1.3
    p = L * np.array([np.sin(th), -np.cos(th)])
    v = L * w * np.array([np.cos(th), np.sin(th)])
    M = m * np.eye(2)
    Q = np.array([0.0, -m * g])
    K = p[None, :] / L          # φ = (|p|² - L²)/(2L), K = pᵀ/L
    k = np.array([-(v @ v) / L])  # -K̇ v
    a, lam, _ = kkt_solve(M, Q, K, k)
    tension = m * g * np.cos(th) + m * L * w ** 2  # closed form, pulling toward the pivot
    assert lam[0] == pytest.approx(-tension, rel=1e-12)  # force Kᵀλ points along -p
    assert np.allclose(a, [-(g * np.sin(th)) * np.cos(th) * 1 - L * w ** 2 * np.sin(th),
                           -(g * np.sin(th)) * np.sin(th) + L * w ** 2 * np.cos(th)], atol=1e-12)


def test_redundant_rows_reported_and_solved_min_norm():
    rng = np.random.default_rng(3)
    n = 6
    M, Q = _spd(n, rng), rng.normal(size=n)
    K1 = rng.normal(size=(2, n))
    K = np.vstack([K1, K1[0] + 2 * K1[1]])  # third row redundant
    k1 = rng.normal(size=2)
    k = np.append(k1, k1[0] + 2 * k1[1])    # consistent
    a, lam, info = kkt_solve(M, Q, K, k)
    assert info.m == 3 and info.rank == 2 and info.rank_deficient
    a_ref, _, _ = kkt_solve(M, Q, K1, k1)
    assert np.allclose(a, a_ref, atol=1e-9)
    assert np.allclose(K.T @ lam, K1.T @ kkt_solve(M, Q, K1, k1)[1], atol=1e-8)  # same constraint force
    C, rank = null_space_basis(K)
    assert rank == 2 and C.shape == (n, n - 2) and np.abs(K @ C).max() < 1e-9
    a2, _, info2 = complement_solve(M, Q, K, k)
    assert info2.rank == 2 and np.allclose(a2, a_ref, atol=1e-8)


def test_damped_least_squares_stays_bounded_at_singularity():
    M = np.eye(2)
    K = np.array([[1.0, 0.0], [1.0, 1e-14]])  # nearly parallel rows
    k = np.array([0.0, 1.0])                   # inconsistent: undamped λ would be ~1e14
    _, lam_d, info = kkt_solve(M, np.zeros(2), K, k, damping=1e-4)
    assert np.all(np.isfinite(lam_d)) and np.abs(lam_d).max() < 1e5 and info.damping == 1e-4


def test_baumgarte_and_projection_reduce_violation():
    assert np.allclose(baumgarte_rhs([1.0], phi=[0.1], phidot=[0.2], alpha=3.0, beta=4.0), [1 - 1.2 - 1.6])
    assert np.allclose(baumgarte_rhs([1.0], phidot=[0.2], alpha=3.0), [1 - 0.6])
    L = 2.0
    phi = lambda q: np.array([0.5 * (q @ q - L * L)])
    Kf = lambda q: q[None, :]
    q, err, it = project_positions(np.eye(2), phi, Kf, np.array([1.5, 1.6]))
    assert err < 1e-12 and abs(np.linalg.norm(q) - L) < 1e-12 and it >= 1
    v = project_velocities(np.eye(2), Kf(q), np.array([1.0, 1.0]))
    assert abs(q @ v) < 1e-12
