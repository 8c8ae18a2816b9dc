"""Eq. 14 rigid coupling: gradient and Hessian against finite differences under q <- exp(delta) q."""
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
    xa, xb = rng.normal(size=3) * 0.05, rng.normal(size=3) * 0.05
    qa = quat_normalize(rng.normal(size=4))
    axis = rng.normal(size=3)
    qb = quat_mul(quat_exp(-angle * axis / np.linalg.norm(axis)), qa)
    return xa, qa, xb, qb


def _energy_perturbed(xa, qa, xb, qb, kx, kt, i, h):
    if i < 6:
        xa, qa = _perturb(xa, qa, i, h)
    else:
        xb, qb = _perturb(xb, qb, i - 6, h)
    return rc.pair_energy(xa, qa, xb, qb, kx, kt)


@pytest.mark.parametrize("angle", [0.01, 0.5, 2.0, 3.0])
def test_gradient_matches_central_differences(angle):
    """The analytic Eq. 14 gradient equals central differences of the energy for large and small
    relative rotations (relative error < 1e-6)."""
    rng = np.random.default_rng(1)
    xa, qa, xb, qb = _pair(rng, angle)
    kx, kt = 170.0, 70.0
    g = rc.pair_gradient(xa, qa, xb, qb, kx, kt)
    h = 1e-6
    fd = np.array([(_energy_perturbed(xa, qa, xb, qb, kx, kt, i, h)
                    - _energy_perturbed(xa, qa, xb, qb, kx, kt, i, -h)) / (2 * h) for i in range(12)])
    assert np.linalg.norm(g) > 1.0
    assert np.linalg.norm(g - fd) <= 1e-6 * np.linalg.norm(g)


@pytest.mark.parametrize("angle", [1e-3, 0.3, 1.0])
def test_hessian_is_gauss_newton_of_gradient(angle):
    """The Hessian's translation blocks equal the FD derivative of the gradient exactly; its
    rotation diagonal blocks equal the symmetric part of that derivative up to the stated t^2/12 gap
    (cross blocks up to t/2, the skew part),
    and the Hessian is symmetric positive semidefinite."""
    rng = np.random.default_rng(2)
    xa, qa, xb, qb = _pair(rng, angle)
    kx, kt = 50.0, 200.0
    H = rc.pair_hessian(kx, kt)
    h = 1e-6
    J = np.zeros((12, 12))
    for j in range(12):
        def grad_at(s):
            a_x, a_q, b_x, b_q = xa, qa, xb, qb
            if j < 6:
                a_x, a_q = _perturb(xa, qa, j, s)
            else:
                b_x, b_q = _perturb(xb, qb, j - 6, s)
            return rc.pair_gradient(a_x, a_q, b_x, b_q, kx, kt)
        J[:, j] = (grad_at(h) - grad_at(-h)) / (2 * h)
    tr = np.r_[0:3, 6:9]
    rot = np.r_[3:6, 9:12]
    assert np.allclose(H[np.ix_(tr, tr)], J[np.ix_(tr, tr)], rtol=1e-6, atol=1e-6 * kx)
    Jsym = 0.5 * (J + J.T)
    ra, rb = np.r_[3:6], np.r_[9:12]
    diag_gap = max(np.abs(H[np.ix_(r, r)] - Jsym[np.ix_(r, r)]).max() for r in (ra, rb)) / kt
    assert diag_gap <= angle ** 2 / 12 * 1.05 + 1e-6
    # cross blocks keep the skew part 1/2 [dtheta]x that no symmetric matrix can represent
    cross_gap = np.abs(H[np.ix_(ra, rb)] - Jsym[np.ix_(ra, rb)]).max() / kt
    assert cross_gap <= angle / 2 * 1.05 + 1e-6
    assert np.allclose(H, H.T)
    assert np.linalg.eigvalsh(H).min() >= -1e-9


def test_target_coupling_matches_pair():
    """Body-to-fixed-target coupling equals the pair energy/gradient with the target as body b."""
    rng = np.random.default_rng(3)
    xa, qa, xb, qb = _pair(rng, 0.7)
    g6 = np.zeros(6)
    e = rc.target_energy_gradient(xa, qa, xb, qb, 30.0, 9.0, g6)
    assert e == pytest.approx(rc.pair_energy(xa, qa, xb, qb, 30.0, 9.0))
    assert np.allclose(g6, rc.pair_gradient(xa, qa, xb, qb, 30.0, 9.0)[:6])
