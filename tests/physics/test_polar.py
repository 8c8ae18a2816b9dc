"""The warm-started polar decomposition (rotations.polar_update_scalars) against the SVD: one
Newton step squares the rotation's error, it converges from any start (inverted tets included, to
the rotation with the smallest singular direction flipped), and degenerate tets stay finite."""
import numpy as np
import pytest

from tests.support.solver_fixtures import random_quat, svd_polar
from softhand_sim.physics.rotations import (matrix_to_quat, polar_rotation_update,
                                            polar_update_scalars, quat_exp, quat_mul, quat_to_matrix)


def angle(q, R):
    """[rad] between the quaternion q's rotation and the matrix R."""
    c = 0.5 * (np.trace(quat_to_matrix(np.asarray(q)).T @ R) - 1.0)
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


def strained(rng, strain):
    """F = R S: a random rotation times a symmetric stretch within `strain` of I."""
    S = np.eye(3) + strain * rng.uniform(-1.0, 1.0, (3, 3))
    return quat_to_matrix(random_quat(rng)) @ (0.5 * (S + S.T))


def off_by(rng, R, delta):
    """A quaternion `delta` [rad] from R about a random axis."""
    axis = rng.normal(size=3)
    return quat_mul(quat_exp(delta * axis / np.linalg.norm(axis)), matrix_to_quat(R))


@pytest.mark.parametrize("delta", [0.1, 0.03, 0.01])
def test_one_step_squares_the_error(delta):
    """From a start delta off the polar rotation one iteration leaves under delta^2 (Newton's
    step; Mueller's, delta / tr A, would leave about delta / 3), for tets stretched or compressed
    by up to 30 %."""
    rng = np.random.default_rng(3)
    worst = 0.0
    for _ in range(200):
        F = strained(rng, 0.3)
        R = svd_polar(F)
        q = polar_update_scalars(F, *off_by(rng, R, delta), 1)
        worst = max(worst, angle(q, R))
    assert worst < delta * delta
    assert worst < delta / 10.0


@pytest.mark.parametrize("strain,inverted,limit", [(0.1, False, 20), (0.5, False, 40), (0.3, True, 100)])
def test_converges_from_any_start(strain, inverted, limit):
    """From a random rotation (up to 180 degrees off) the iteration reaches the SVD's rotation to
    1e-7 rad within `limit` iterations, for inverted tets the one with the smallest singular
    direction flipped (never a reflection: a quaternion cannot hold one)."""
    rng = np.random.default_rng(5)
    for _ in range(100):
        F = strained(rng, strain)
        if inverted:
            F = F @ np.diag([1.0, 1.0, -0.4])
        q = polar_update_scalars(F, *random_quat(rng), limit)
        assert angle(q, svd_polar(F)) < 1e-7


def test_converged_rotation_stays_and_degenerate_tets_stay_finite():
    """At the polar rotation the update stops (no drift); a collapsed tet (F zero, rank 1 or 2)
    yields a finite unit quaternion; the array form equals the scalar one."""
    rng = np.random.default_rng(8)
    F = strained(rng, 0.2)
    q = matrix_to_quat(svd_polar(F))
    assert np.allclose(polar_update_scalars(F, *q, 5), q, atol=1e-12)
    for G in (np.zeros((3, 3)), np.outer(rng.normal(size=3), rng.normal(size=3)),
              F @ np.diag([1.0, 1.0, 0.0])):
        out = np.array(polar_update_scalars(G, *random_quat(rng), 10))
        assert np.all(np.isfinite(out)) and abs(np.linalg.norm(out) - 1.0) < 1e-12
    q0 = random_quat(rng)
    np.testing.assert_array_equal(polar_rotation_update(F, q0, 3), polar_update_scalars(F, *q0, 3))
