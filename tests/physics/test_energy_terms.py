"""Tissue (Eq. 7-10), joints (Eq. 6 + hinge/universal/limits), bone-tissue (Eq. 11), gravity:
gradients against central differences, Hessians against differences of the gradient."""
import numpy as np
import pytest

from tests.support.solver_fixtures import box_mesh, random_quat, svd_polar
from softhand_sim.physics.energies import bone_tissue, joints, tissue
from softhand_sim.physics.rotations import matrix_to_quat, quat_exp, quat_mul, quat_normalize

E_YOUNG, NU = 1e5, 0.33


def exact_polar_quats(x, X, tets):
    """Polar rotation of every tet by SVD (independent of the solver's iterative update)."""
    out = np.zeros((len(tets), 4))
    for e, t in enumerate(tets):
        Ds = np.column_stack([x[t[i]] - x[t[0]] for i in (1, 2, 3)])
        Dm = np.column_stack([X[t[i]] - X[t[0]] for i in (1, 2, 3)])
        out[e] = matrix_to_quat(svd_polar(Ds @ np.linalg.inv(Dm)))
    return out


def tissue_setup(seed, amp, invert=True):
    rng = np.random.default_rng(seed)
    X, tets = box_mesh((0.03, 0.02, 0.02), (3, 2, 2))
    vol, Dm_inv, K0 = tissue.rest_data(X, tets, E_YOUNG, NU)
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    R *= np.sign(np.linalg.det(R))
    x = X @ R.T + 0.01 + amp * rng.normal(size=X.shape)
    if invert:  # push one interior-ish node through the opposite face of its tets
        c = X.mean(axis=0)
        n = np.argmin(np.linalg.norm(X - c, axis=1))
        x[n] += 0.012 * R[:, 2]
    return X, tets, vol, Dm_inv, K0, x


def tissue_energy(x, X, tets, vol, K0, nl_k, wmax):
    return tissue.value(x, X, tets, K0, vol, exact_polar_quats(x, X, tets), nl_k, wmax)


@pytest.mark.parametrize("nl_k", [0.0, 1000.0])
def test_tissue_gradient_matches_central_differences(nl_k):
    """Eq. 9 gradient (with exact polar rotations) equals central differences of Eq. 7-8 on a
    randomly deformed, rotated block with inverted tets, for the linear and nonlinear material."""
    X, tets, vol, Dm_inv, K0, x = tissue_setup(0, 0.002)
    q = exact_polar_quats(x, X, tets)
    F_det = [np.linalg.det(np.column_stack([x[t[i]] - x[t[0]] for i in (1, 2, 3)])) for t in tets]
    assert min(F_det) < 0, "the state must contain inverted tets"
    wmax = 2500.0
    g = np.zeros(x.size)
    tissue.add_gradient(x, X, tets, K0, vol, q, nl_k, wmax, g)
    h = 1e-8
    fd = np.zeros(x.size)
    for i in range(x.size):
        xp, xm = x.copy(), x.copy()
        xp.flat[i] += h
        xm.flat[i] -= h
        fd[i] = (tissue_energy(xp, X, tets, vol, K0, nl_k, wmax)
                 - tissue_energy(xm, X, tets, vol, K0, nl_k, wmax)) / (2 * h)
    assert np.linalg.norm(g) > 1.0
    assert np.linalg.norm(g - fd) <= 1e-5 * np.linalg.norm(g)


@pytest.mark.parametrize("nl_k", [0.0, 1000.0])
def test_tissue_hessian_is_derivative_of_gradient_at_fixed_rotation(nl_k):
    """Eq. 10 Hessian times v equals differences of the gradient with the rotations held fixed
    (the stated co-rotational choice), on inverted states; it is symmetric PSD."""
    from softhand_sim.physics.energies.assembly import build_pattern, stencil_slots
    X, tets, vol, Dm_inv, K0, x = tissue_setup(1, 0.003)
    q = exact_polar_quats(x, X, tets)
    n = x.size
    st = (3 * tets[:, :, None] + np.arange(3)).reshape(len(tets), 12)
    indptr, indices = build_pattern(n, [st])
    slots = stencil_slots(indptr, indices, st)
    vals = np.zeros(len(indices))
    tissue.add_hessian(x, X, tets, K0, vol, q, nl_k, 2500.0, slots, vals)
    import scipy.sparse as sp
    H = sp.csr_matrix((vals, indices, indptr), shape=(n, n)).toarray()
    v = np.random.default_rng(2).normal(size=n)
    h = 1e-7

    def grad(xx):
        g = np.zeros(n)
        tissue.add_gradient(xx, X, tets, K0, vol, q, nl_k, 2500.0, g)
        return g
    fd = (grad(x + h * v.reshape(x.shape)) - grad(x - h * v.reshape(x.shape))) / (2 * h)
    Hv = H @ v
    assert np.linalg.norm(Hv) > 1.0
    assert np.linalg.norm(Hv - fd) <= 1e-5 * np.linalg.norm(Hv)
    assert np.allclose(H, H.T, atol=1e-9 * np.abs(H).max())
    assert np.linalg.eigvalsh(H).min() >= -1e-8 * np.abs(H).max()


def test_tissue_hessian_close_to_full_derivative_at_small_strain():
    """With rotations recomputed, Hessian*v matches the full derivative of the gradient to within
    the dropped dR/dx term: < 2% relative error at ~0.1% strain on a rotated block."""
    X, tets, vol, Dm_inv, K0, x = tissue_setup(3, 2e-5, invert=False)
    from softhand_sim.physics.energies.assembly import build_pattern, stencil_slots
    import scipy.sparse as sp
    n = x.size
    st = (3 * tets[:, :, None] + np.arange(3)).reshape(len(tets), 12)
    indptr, indices = build_pattern(n, [st])
    vals = np.zeros(len(indices))
    tissue.add_hessian(x, X, tets, K0, vol, exact_polar_quats(x, X, tets), 0.0, 2500.0,
                       stencil_slots(indptr, indices, st), vals)
    H = sp.csr_matrix((vals, indices, indptr), shape=(n, n))
    v = np.random.default_rng(4).normal(size=n)
    h = 1e-8

    def grad(xx):
        g = np.zeros(n)
        tissue.add_gradient(xx, X, tets, K0, vol, exact_polar_quats(xx, X, tets), 0.0, 2500.0, g)
        return g
    fd = (grad(x + h * v.reshape(x.shape)) - grad(x - h * v.reshape(x.shape))) / (2 * h)
    rel = np.linalg.norm(H @ v - fd) / np.linalg.norm(fd)
    assert rel < 0.02, rel


def test_tissue_rest_shape_under_rigid_motion_has_no_force():
    """The rest shape, rotated and translated arbitrarily, has zero energy and zero force, and the
    solver's warm-started rotation update recovers the rotation."""
    rng = np.random.default_rng(5)
    X, tets = box_mesh((0.03, 0.02, 0.02), (3, 2, 2))
    vol, Dm_inv, K0 = tissue.rest_data(X, tets, E_YOUNG, NU)
    for _ in range(3):
        q = random_quat(rng)
        from softhand_sim.physics.rotations import quat_to_matrix
        x = X @ quat_to_matrix(q).T + rng.normal(size=3)
        tq = np.tile([0.0, 0.0, 0.0, 1.0], (len(tets), 1))
        tissue.update_rotations(x, tets, Dm_inv, tq, 50)
        g = np.zeros(x.size)
        tissue.add_gradient(x, X, tets, K0, vol, tq, 1000.0, 2500.0, g)
        assert np.abs(g).max() < 1e-9 * E_YOUNG * 0.01
        assert tissue.value(x, X, tets, K0, vol, tq, 1000.0, 2500.0) < 1e-12


# ---------------------------------------------------------------- rigid bodies: joints, Eq. 11
def _perturbed(body_x, body_q, dof, h):
    bx, bq = body_x.copy(), body_q.copy()
    b, i = divmod(dof, 6)
    if i < 3:
        bx[b, i] += h
    else:
        d = np.zeros(3)
        d[i - 3] = h
        bq[b] = quat_normalize(quat_mul(quat_exp(d), bq[b]))
    return bx, bq


def joint_setup(seed):
    rng = np.random.default_rng(seed)
    B = 4
    body_x = rng.normal(size=(B, 3)) * 0.02
    body_q = np.array([random_quat(rng) for _ in range(B)])
    parent = np.array([0, 1, 2], np.int32)
    child = np.array([1, 2, 3], np.int32)
    rp = rng.normal(size=(3, 3)) * 0.01
    rc = rng.normal(size=(3, 3)) * 0.01
    rest = np.array([random_quat(rng) for _ in range(3)])
    jtype = [0, 1, 2]
    flex = np.array([[0, 1.0, 0]] * 3)
    abd = np.array([[0, 0, 1.0]] * 3)
    lim = np.array([[[-0.1, 0.1], [-0.05, 0.05]]] * 3)  # tight: the random poses violate them
    rows = joints.angular_rows(jtype, flex, abd, lim, 20.0, 30.0)
    return body_x, body_q, parent, child, rp, rc, rest, rows


def joint_energy_grad(body_x, body_q, parent, child, rp, rc, rest, rows, k=2e5):
    g = np.zeros(6 * len(body_x))
    e = joints.add_all(body_x, body_q, parent, child, rp, rc, k, rest, *rows, 0, g,
                       np.zeros((3, 12, 12), np.int32), np.zeros(1), False)
    return e, g


def test_joint_gradient_matches_central_differences():
    """Spherical (Eq. 6), hinge and universal locks and active limits: the gradient equals central
    differences of the energy under x += h and q <- exp(h e_i) q (relative error < 1e-6)."""
    args = joint_setup(6)
    e, g = joint_energy_grad(*args)
    assert len(args[-1][0]) >= 5 and e > 0
    h = 1e-7
    fd = np.zeros_like(g)
    for d in range(g.size):
        ep = joint_energy_grad(*_perturbed(args[0], args[1], d, h), *args[2:])[0]
        em = joint_energy_grad(*_perturbed(args[0], args[1], d, -h), *args[2:])[0]
        fd[d] = (ep - em) / (2 * h)
    assert np.linalg.norm(g) > 1.0
    assert np.linalg.norm(g - fd) <= 1e-6 * np.linalg.norm(g)


def test_spherical_joint_hessian_gauss_newton_near_closed_joint():
    """Near a closed joint (0.1 mm gap, 1 cm levers) the Gauss-Newton Eq. 6 Hessian times v
    matches differences of the gradient within 2% (the dropped term scales with the gap)."""
    rng = np.random.default_rng(7)
    body_q = np.array([random_quat(rng) for _ in range(2)])
    rp, rc = rng.normal(size=(1, 3)) * 0.01, rng.normal(size=(1, 3)) * 0.01
    from softhand_sim.physics.rotations import quat_to_matrix
    body_x = np.zeros((2, 3))
    body_x[1] = quat_to_matrix(body_q[0]) @ rp[0] - quat_to_matrix(body_q[1]) @ rc[0] + 1e-4
    par, chi = np.array([0], np.int32), np.array([1], np.int32)
    rest = np.array([[0, 0, 0, 1.0]])
    rows = joints.angular_rows([0], np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 2, 2)), 0, 0)
    slots = np.arange(144, dtype=np.int32).reshape(1, 12, 12)
    H = np.zeros(144)
    joints.add_all(body_x, body_q, par, chi, rp, rc, 2e5, rest, *rows, 0, np.zeros(12), slots, H, True)
    H = H.reshape(12, 12)
    v = rng.normal(size=12)
    h = 1e-7

    def grad_along(s):
        bx, bq = body_x.copy(), body_q.copy()
        for d in range(12):
            bx, bq = _perturbed(bx, bq, d, s * v[d])
        return joint_energy_grad(bx, bq, par, chi, rp, rc, rest, rows)[1]
    fd = (grad_along(h) - grad_along(-h)) / (2 * h)
    assert np.linalg.norm(H @ v - fd) <= 0.02 * np.linalg.norm(fd)
    assert np.linalg.eigvalsh(H).min() >= -1e-6


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_angular_row_hessian_is_its_gauss_newton_outer_product(seed):
    """One active angular row (a universal joint's twist lock; no spherical spring, limits far):
    U = 1/2 k h^2, grad = k h ds, so the Gauss-Newton Hessian k ds ds^T is exactly
    grad grad^T / (2 U), and the gradient itself is checked against differences above. The
    kernel writes only the rotation entries of the row: that sum must equal the full outer
    product over all 12 coordinates (the positions' entries are 0)."""
    rng = np.random.default_rng(seed)
    body_x = rng.normal(size=(2, 3)) * 0.02
    body_q = np.array([random_quat(rng) for _ in range(2)])
    par, chi = np.array([0], np.int32), np.array([1], np.int32)
    rp, rc = rng.normal(size=(1, 3)) * 0.01, rng.normal(size=(1, 3)) * 0.01
    rest = np.array([random_quat(rng)])
    wide = np.array([[[-10.0, 10.0], [-10.0, 10.0]]])
    rows = joints.angular_rows([2], np.array([[0, 1.0, 0]]), np.array([[0, 0, 1.0]]), wide, 20.0, 30.0)
    slots = np.arange(144, dtype=np.int32).reshape(1, 12, 12)
    H, g = np.zeros(144), np.zeros(12)
    e = joints.add_all(body_x, body_q, par, chi, rp, rc, 0.0, rest, *rows, 0, g, slots, H, True)
    assert e > 1e-6
    assert np.all(g[:3] == 0.0) and np.all(g[6:9] == 0.0)
    np.testing.assert_allclose(H.reshape(12, 12), np.outer(g, g) / (2.0 * e), rtol=1e-9,
                               atol=1e-12 * np.abs(H).max())


def test_bone_tissue_gradient_and_hessian():
    """Eq. 11: gradient equals central differences over nodes and the bone (x, exp-map rotation);
    the Gauss-Newton Hessian is exact in the node block (linear there) and symmetric PSD."""
    rng = np.random.default_rng(8)
    X, tets = box_mesh((0.02, 0.02, 0.02), (1, 1, 1))
    x = X + rng.normal(size=X.shape) * 0.002
    body_x = rng.normal(size=(1, 3)) * 0.01
    body_q = np.array([random_quat(rng)])
    P = 3
    s_tet = np.array([0, 2, 5], np.int32)
    s_body = np.zeros(P, np.int32)
    s_r = rng.normal(size=(P, 3)) * 0.01
    bary = rng.dirichlet(np.ones(4), size=P)
    s_k = np.array([1e5, 2e5, 3e5])
    N = len(X)

    def eg(xx, bx, bq):
        g = np.zeros(3 * N + 6)
        e = bone_tissue.add_all(xx, bx, bq, tets, s_tet, s_body, s_r, bary, s_k, 3 * N, g,
                                np.zeros((P, 18, 18), np.int32), np.zeros(1), False)
        return e, g
    e, g = eg(x, body_x, body_q)
    h = 1e-8
    fd = np.zeros_like(g)
    for d in range(g.size):
        if d < 3 * N:
            xp, xm = x.copy(), x.copy()
            xp.flat[d] += h
            xm.flat[d] -= h
            fd[d] = (eg(xp, body_x, body_q)[0] - eg(xm, body_x, body_q)[0]) / (2 * h)
        else:
            fd[d] = (eg(x, *_perturbed(body_x, body_q, d - 3 * N, h))[0]
                     - eg(x, *_perturbed(body_x, body_q, d - 3 * N, -h))[0]) / (2 * h)
    assert np.linalg.norm(g) > 1.0
    assert np.linalg.norm(g - fd) <= 1e-6 * np.linalg.norm(g)
    # Hessian: assemble dense through identity slots
    n = 3 * N + 6
    vals = np.zeros(n * n)
    slots = np.zeros((P, 18, 18), np.int32)
    for s in range(P):
        dofs = np.r_[(3 * tets[s_tet[s]][:, None] + np.arange(3)).ravel(), 3 * N + np.arange(6)]
        slots[s] = dofs[:, None] * n + dofs[None, :]
    bone_tissue.add_all(x, body_x, body_q, tets, s_tet, s_body, s_r, bary, s_k, 3 * N,
                        np.zeros(n), slots, vals, True)
    H = vals.reshape(n, n)
    v = np.zeros(n)
    v[:3 * N] = rng.normal(size=3 * N)
    fdv = (eg(x + h * v[:3 * N].reshape(N, 3), body_x, body_q)[1]
           - eg(x - h * v[:3 * N].reshape(N, 3), body_x, body_q)[1]) / (2 * h)
    assert np.linalg.norm(H @ v - fdv) <= 1e-6 * np.linalg.norm(fdv)
    assert np.allclose(H, H.T) and np.linalg.eigvalsh(H).min() >= -1e-6 * np.abs(H).max()
