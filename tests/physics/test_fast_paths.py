"""The solver's fast kernels give the same energy, gradient and Hessian as the reference kernels
they replace (to round-off): fused rotation + isotropic tissue vs update_rotations + the K0 kernel,
the structured bone-tissue Hessian vs the dense Gauss-Newton k JᵀJ, the triplet CSR product vs
scipy."""
import numpy as np
import pytest
import scipy.sparse as sp

from tests.support.solver_fixtures import box_mesh, dense_slots, random_quat, tet_stencils
from softhand_sim.physics import pcg
from softhand_sim.scenarios.bench_scenes import box_hand_with_tets
from softhand_sim.physics.energies import bone_tissue, tissue
from softhand_sim.physics.model import build_model
from softhand_sim.physics.rotations import quat_to_matrix

E_YOUNG, NU = 1e5, 0.33


@pytest.mark.parametrize("nl_k,amp", [(0.0, 0.002), (1000.0, 0.002), (1000.0, 0.0002)])
def test_fused_tissue_matches_rotations_plus_K0_kernel(nl_k, amp):
    """add_all_fused (closed-form isotropic K0, rotation update inside) = update_rotations +
    add_all (K0 = V Bᵀ C B from rest_data): rotations, energy, gradient and Hessian to 1e-12,
    in the linear and the nonlinear (W > Wmax) regimes."""
    rng = np.random.default_rng(11)
    X, tets = box_mesh((0.03, 0.02, 0.02), (3, 2, 2))
    vol, Dm_inv, K0 = tissue.rest_data(X, tets, E_YOUNG, NU)
    lam, mu = tissue.lame(E_YOUNG, NU)
    assert tissue.is_isotropic_K0(K0, Dm_inv, vol, lam, mu)
    assert not tissue.is_isotropic_K0(K0, Dm_inv, vol, lam, 1.01 * mu)
    R = quat_to_matrix(random_quat(rng))
    x = X @ R.T + amp * rng.normal(size=X.shape)
    N, T = len(X), len(tets)
    slots = dense_slots(tet_stencils(tets), 3 * N)
    wmax = 50.0  # low enough that the amp = 2 mm shape has tets above it
    q_ref = np.tile([0.0, 0.0, 0.0, 1.0], (T, 1))
    q_new = q_ref.copy()
    # first round from the identity, ~150 degrees from the tets' rotations: iterated to convergence
    # (the polar update switches between Newton's and Mueller's step on a condition, and round-off
    # in F may flip it in an unconverged iteration); second round: the next step's small motion
    # from those warm-started rotations, the solver's one iteration
    for iterations in (30, 1):
        if iterations == 1:
            x = x + 0.1 * amp * rng.normal(size=X.shape)
        g_ref, g_new = np.zeros(3 * N), np.zeros(3 * N)
        H_ref, H_new = np.zeros(9 * N * N), np.zeros(9 * N * N)
        tissue.update_rotations(x, tets, Dm_inv, q_ref, iterations)
        e_new = tissue.add_all_fused(x, tets, Dm_inv, vol, lam, mu, q_new, iterations, nl_k, wmax,
                                     g_new, slots, H_new)
        # the K0 kernel at the fused kernel's rotations: same terms, other formula
        e_ref = tissue.add_all(x, X, tets, K0, vol, q_new, nl_k, wmax, g_ref, slots, H_ref)
        assert abs(e_new - e_ref) <= 1e-12 * abs(e_ref)
        assert np.linalg.norm(g_new - g_ref) <= 1e-12 * np.linalg.norm(g_ref)
        assert np.abs(H_new - H_ref).max() <= 1e-12 * np.abs(H_ref).max()
        # same rotation update; the polar rotation of strongly deformed tets amplifies the round-off
        # of F (computed in another order), hence 1e-9 rather than 1e-15
        # (q and -q are the same rotation: a large step of the first round may end on either)
        sign = np.where(np.sum(q_new * q_ref, axis=1) < 0.0, -1.0, 1.0)
        np.testing.assert_allclose(sign[:, None] * q_new, q_ref, rtol=0, atol=1e-9)


def test_bone_tissue_structured_hessian_equals_dense_gauss_newton():
    """The written-out bone-tissue Hessian (node-node diagonal blocks, per-body accumulated body
    block) equals k JᵀJ built densely from J = [-w_a I, I, -[R r]x] for several points on two
    bodies; the gradient equals k Jᵀ d."""
    rng = np.random.default_rng(4)
    X, tets = box_mesh((0.02, 0.02, 0.02), (1, 1, 1))
    x = X + rng.normal(size=X.shape) * 0.002
    N, B, P = len(X), 2, 6
    body_x = rng.normal(size=(B, 3)) * 0.01
    body_q = np.array([random_quat(rng) for _ in range(B)])
    s_tet = rng.integers(0, len(tets), P).astype(np.int32)
    s_body = np.array([0, 1, 0, 1, 1, 0], np.int32)
    s_r = rng.normal(size=(P, 3)) * 0.01
    bary = rng.dirichlet(np.ones(4), size=P)
    s_k = rng.uniform(1e5, 3e5, P)
    n = 3 * N + 6 * B
    stencils = [np.r_[(3 * tets[s_tet[s]][:, None] + np.arange(3)).ravel(),
                      3 * N + 6 * s_body[s] + np.arange(6)] for s in range(P)]
    g, vals = np.zeros(n), np.zeros(n * n)
    e = bone_tissue.add_all(x, body_x, body_q, tets, s_tet, s_body, s_r, bary, s_k, 3 * N, g,
                            dense_slots(stencils, n), vals, True)
    H_ref, g_ref, e_ref = np.zeros((n, n)), np.zeros(n), 0.0
    for s in range(P):
        b = s_body[s]
        rw = quat_to_matrix(body_q[b]) @ s_r[s]
        d = body_x[b] + rw - bary[s] @ x[tets[s_tet[s]]]
        J = np.zeros((3, 18))
        for a in range(4):
            J[:, 3 * a:3 * a + 3] = -bary[s, a] * np.eye(3)
        J[:, 12:15] = np.eye(3)
        J[:, 15:18] = -np.array([[0, -rw[2], rw[1]], [rw[2], 0, -rw[0]], [-rw[1], rw[0], 0]])
        st = stencils[s]
        H_ref[np.ix_(st, st)] += s_k[s] * J.T @ J
        g_ref[st] += s_k[s] * J.T @ d
        e_ref += 0.5 * s_k[s] * d @ d
    assert abs(e - e_ref) <= 1e-12 * e_ref
    assert np.linalg.norm(g - g_ref) <= 1e-12 * np.linalg.norm(g_ref)
    assert np.abs(vals.reshape(n, n) - H_ref).max() <= 1e-12 * np.abs(H_ref).max()


def test_triplet_matvec_matches_scipy_and_detects_the_pattern():
    """csr_matvec3 on the model pattern (whole 3x3 node / body blocks) equals scipy's product to
    round-off, as does the generic csr_matvec; triplet_pattern rejects a pattern with a lone entry."""
    m = build_model(box_hand_with_tets(200))
    assert pcg.triplet_pattern(m.indptr, m.indices)
    rng = np.random.default_rng(2)
    vals = rng.normal(size=len(m.indices))
    x = rng.normal(size=m.dof_count)
    ref = sp.csr_matrix((vals, m.indices, m.indptr), shape=(m.dof_count,) * 2) @ x
    out3, out1 = np.zeros(m.dof_count), np.zeros(m.dof_count)
    pcg.csr_matvec3(m.indptr, m.indices, vals, x, out3)
    pcg.csr_matvec(m.indptr, m.indices, vals, x, out1)
    assert np.abs(out3 - ref).max() <= 1e-12 * np.abs(ref).max()
    assert np.abs(out1 - ref).max() <= 1e-12 * np.abs(ref).max()
    assert not pcg.triplet_pattern(np.array([0, 1, 2, 3]), np.array([0, 1, 2]))
