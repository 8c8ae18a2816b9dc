"""Eq. 14 rigid coupling (energies/rigid_coupling.py, the one implementation the solver, the world
and the tracking loop use): gradient and Hessian against finite differences under q <- exp(delta) q,
and the solver's assembly of it."""
import numpy as np
import pytest

from softhand_sim.physics.energies import rigid_coupling as rc
from softhand_sim.physics.rotations import quat_exp, quat_mul, quat_normalize


def _perturb(x, q, i, h):
    """Perturb coordinate i of (x, theta) by h: translation, or q <- exp(h e_i) q."""
    x = x.copy()
    if i < 3:
        x[i] += h
        return x, q
    d = np.zeros(3)
    d[i - 3] = h
    return x, quat_normalize(quat_mul(quat_exp(d), q))


def _pair(rng, angle):
    """A body (x, q) and a target (x_t, q_t) rotated by `angle` [rad] from it."""
    x, xt = rng.normal(size=3) * 0.05, rng.normal(size=3) * 0.05
    q = quat_normalize(rng.normal(size=4))
    axis = rng.normal(size=3)
    qt = quat_mul(quat_exp(-angle * axis / np.linalg.norm(axis)), q)
    return x, q, xt, qt


def _energy(x, q, xt, qt, kx, kt):
    return rc.target_energy_gradient(x, q, xt, qt, kx, kt, np.zeros(6))


def _gradient(x, q, xt, qt, kx, kt):
    g = np.zeros(6)
    rc.target_energy_gradient(x, q, xt, qt, kx, kt, g)
    return g


@pytest.mark.parametrize("angle", [0.01, 0.5, 2.0, 3.0])
def test_gradient_matches_central_differences(angle):
    """The analytic Eq. 14 gradient w.r.t. the body's (x, theta) equals central differences of the
    energy for large and small relative rotations (relative error < 1e-6)."""
    rng = np.random.default_rng(1)
    x, q, xt, qt = _pair(rng, angle)
    kx, kt = 170.0, 70.0
    g = _gradient(x, q, xt, qt, kx, kt)
    h = 1e-6
    fd = np.array([(_energy(*_perturb(x, q, i, h), xt, qt, kx, kt)
                    - _energy(*_perturb(x, q, i, -h), xt, qt, kx, kt)) / (2 * h) for i in range(6)])
    assert np.linalg.norm(g) > 1.0
    assert np.linalg.norm(g - fd) <= 1e-6 * np.linalg.norm(g)


@pytest.mark.parametrize("angle", [1e-3, 0.3, 1.0])
def test_hessian_is_gauss_newton_of_gradient(angle):
    """The Hessian's translation block equals the FD derivative of the gradient; its rotation block
    equals the symmetric part of that derivative up to the stated t^2/12 gap and misses only the
    skew part (|.| <= t/2); it is symmetric positive definite."""
    rng = np.random.default_rng(2)
    x, q, xt, qt = _pair(rng, angle)
    kx, kt = 50.0, 200.0
    H = rc.hessian(kx, kt)
    h = 1e-6
    J = np.zeros((6, 6))
    for j in range(6):
        J[:, j] = (_gradient(*_perturb(x, q, j, h), xt, qt, kx, kt)
                   - _gradient(*_perturb(x, q, j, -h), xt, qt, kx, kt)) / (2 * h)
    assert np.allclose(H[:3, :3], J[:3, :3], rtol=1e-6, atol=1e-6 * kx)
    assert np.abs(J[:3, 3:]).max() <= 1e-6 * kx and np.abs(J[3:, :3]).max() <= 1e-6 * kt
    Jsym = 0.5 * (J + J.T)
    assert np.abs(H[3:, 3:] - Jsym[3:, 3:]).max() / kt <= angle ** 2 / 12 * 1.05 + 1e-6
    assert np.abs(0.5 * (J - J.T)[3:, 3:]).max() / kt <= angle / 2 * 1.05 + 1e-6
    assert np.allclose(H, H.T)
    assert np.linalg.eigvalsh(H).min() > 0.0


def test_pose_forms_are_the_stencil():
    """pose_energy / pose_gradient (the world's entry, COM poses (7,)) are the local stencil."""
    rng = np.random.default_rng(3)
    x, q, xt, qt = _pair(rng, 0.7)
    pose, target = np.r_[x, q], np.r_[xt, qt]
    assert rc.pose_energy(pose, target, 30.0, 9.0) == _energy(x, q, xt, qt, 30.0, 9.0)
    np.testing.assert_array_equal(rc.pose_gradient(pose, target, 30.0, 9.0),
                                  _gradient(x, q, xt, qt, 30.0, 9.0))


def test_solver_assembly_sums_the_stencil_per_body():
    """add_all (the solver's Eq. 14 term) = value + add_gradient + add_hessian = the per-body
    stencil written at body_dof0 + 6 b and the body's diagonal block."""
    rng = np.random.default_rng(4)
    B, dof0 = 3, 6
    pairs = [_pair(rng, a) for a in (0.2, 1.0, 2.5)]
    bx, bq, tx, tq = (np.array([p[i] for p in pairs]) for i in range(4))
    kx, kt = rng.uniform(10, 200, B), rng.uniform(1, 100, B)
    n = dof0 + 6 * B
    slots = np.array([(dof0 + 6 * b + np.arange(6))[:, None] * n + (dof0 + 6 * b + np.arange(6))[None, :]
                      for b in range(B)], np.int32)
    grad, vals = np.zeros(n), np.zeros(n * n)
    e = rc.add_all(bx, bq, tx, tq, kx, kt, dof0, grad, slots, vals)
    assert e == pytest.approx(rc.value(bx, bq, tx, tq, kx, kt), rel=1e-15)
    g_ref, H_ref = np.zeros(n), np.zeros((n, n))
    e_ref = 0.0
    for b in range(B):
        o = slice(dof0 + 6 * b, dof0 + 6 * b + 6)
        e_ref += _energy(bx[b], bq[b], tx[b], tq[b], kx[b], kt[b])
        g_ref[o] = _gradient(bx[b], bq[b], tx[b], tq[b], kx[b], kt[b])
        H_ref[o, o] = rc.hessian(kx[b], kt[b])
    assert e == pytest.approx(e_ref, rel=1e-15)
    np.testing.assert_array_equal(grad, g_ref)
    np.testing.assert_array_equal(vals.reshape(n, n), H_ref)
