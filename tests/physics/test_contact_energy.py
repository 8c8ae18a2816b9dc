"""Eq. 12-13 contact energy: gradient and Hessian against finite differences."""
import numpy as np
import pytest

from softhand_sim.physics.energies import contact as ce
from softhand_sim.physics.rotations import quat_exp, quat_mul

KN, KF = 3.0e7, 1.5e7
BODY_DOF0 = 3 * 6  # 6 nodes, then 2 bodies


def _setup(rng, at_rest=False):
    node_x = rng.normal(scale=0.02, size=(6, 3))
    body_x = rng.normal(scale=0.05, size=(2, 3))
    q = rng.normal(size=(2, 4))
    body_q = q / np.linalg.norm(q, axis=1, keepdims=True)
    nodes = np.array([[0, 1, 2, 3], [2, 3, 4, 5], [5, 5, 5, 5]], np.int32)
    bary = rng.dirichlet(np.ones(4), size=3)
    bary[2] = [1, 0, 0, 0]
    body = np.array([1, -1, 0], np.int32)
    normal = rng.normal(size=(3, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    anchor = rng.normal(scale=0.03, size=(3, 3))
    area = rng.uniform(1e-5, 1e-4, size=3)
    if at_rest:  # put every anchor exactly on its skin point: D = 0
        from softhand_sim.physics.rotations import quat_to_matrix
        for c in range(3):
            xn = bary[c] @ node_x[nodes[c]]
            b = body[c]
            if b >= 0:
                R = quat_to_matrix(body_q[b])
                anchor[c] = R.T @ (xn - body_x[b])
            else:
                anchor[c] = xn
    return dict(node_x=node_x, body_x=body_x, body_q=body_q, nodes=nodes, bary=bary, body=body,
                anchor=anchor, normal=normal, area=area)


def _args(s):
    return (s["node_x"], s["body_x"], s["body_q"], 3, s["nodes"], s["bary"], s["body"], s["anchor"],
            s["normal"], s["area"], KN, KF)


def _grad(s):
    g = np.zeros(BODY_DOF0 + 12)
    ce.add_gradient(*_args(s), BODY_DOF0, g)
    return g


def _perturbed(s, k, h):
    s2 = {key: (v.copy() if isinstance(v, np.ndarray) else v) for key, v in s.items()}
    if k < BODY_DOF0:
        s2["node_x"][k // 3, k % 3] += h
    else:
        b, i = divmod(k - BODY_DOF0, 6)
        if i < 3:
            s2["body_x"][b, i] += h
        else:
            d = np.zeros(3)
            d[i - 3] = h
            s2["body_q"][b] = quat_mul(quat_exp(d), s2["body_q"][b])
    return s2


def _dense_hessian(s):
    n = BODY_DOF0 + 12
    indptr = np.arange(0, n * n + 1, n, dtype=np.int32)
    indices = np.tile(np.arange(n, dtype=np.int32), n)
    values = np.zeros(n * n)
    slip = s.get("slip", np.zeros(3, np.uint8))
    skipped = ce.add_hessian(*_args(s), slip, BODY_DOF0, indptr, indices, values)
    assert skipped == 0
    return values.reshape(n, n)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_gradient_matches_central_differences(seed):
    """add_gradient equals central differences of value for node, body position and body
    rotation dofs (rotation perturbed on the left, world frame), with a nonzero norm."""
    s = _setup(np.random.default_rng(seed))
    g = _grad(s)
    assert np.linalg.norm(g) > 1.0
    h = 1e-7
    fd = np.array([(ce.value(*_args(_perturbed(s, k, h))) - ce.value(*_args(_perturbed(s, k, -h)))) / (2 * h)
                   for k in range(len(g))])
    np.testing.assert_allclose(g, fd, rtol=1e-5, atol=1e-6 * np.abs(g).max())
    # the energy's value against the definition of Eq. 12 + 13 for the static contact (index 1)
    e = ce.value(*_args(s))
    assert e > 0


@pytest.mark.parametrize("seed", [3, 4])
def test_hessian_node_blocks_match_differences_of_gradient(seed):
    """The Hessian's node-node and node-position blocks equal differences of the gradient at any
    state (they are exact); the full Hessian is symmetric PSD."""
    s = _setup(np.random.default_rng(seed))
    H = _dense_hessian(s)
    assert np.linalg.norm(H) > 1.0
    h = 1e-7
    cols = list(range(BODY_DOF0)) + [BODY_DOF0 + 6 * b + i for b in range(2) for i in range(3)]
    for k in cols:
        fd = (_grad(_perturbed(s, k, h)) - _grad(_perturbed(s, k, -h))) / (2 * h)
        np.testing.assert_allclose(H[cols, k], fd[cols], rtol=1e-5, atol=1e-6 * np.abs(H).max())
    np.testing.assert_allclose(H, H.T)
    assert np.linalg.eigvalsh(H).min() > -1e-6 * np.abs(H).max()


def test_full_hessian_exact_at_first_contact():
    """At D = 0 (anchor on the skin point: the moment of first contact) every block of the
    Hessian, rotations included, equals differences of the gradient."""
    s = _setup(np.random.default_rng(5), at_rest=True)
    assert np.abs(_grad(s)).max() < 1e-9
    H = _dense_hessian(s)
    h = 1e-7
    fd = np.stack([(_grad(_perturbed(s, k, h)) - _grad(_perturbed(s, k, -h))) / (2 * h)
                   for k in range(H.shape[0])], axis=1)
    assert np.linalg.norm(H) > 1.0
    np.testing.assert_allclose(H, fd, rtol=1e-5, atol=1e-6 * np.abs(H).max())


def test_forces_split_into_eq12_normal_and_eq13_tangential():
    """contact_forces returns f_n = w k_n (n.D) n and f_f = w k_f (I - n n^T) D, and their sum is
    minus the gradient w.r.t. a static contact's skin point (index 1: nodes 2..5)."""
    s = _setup(np.random.default_rng(6))
    c = 3
    pt, nrm, fn, ff = (np.zeros((c, 3)) for _ in range(4))
    ce.contact_forces(*_args(s), pt, nrm, fn, ff)
    xn = s["bary"][1] @ s["node_x"][s["nodes"][1]]
    D = s["anchor"][1] - xn
    n = s["normal"][1]
    np.testing.assert_allclose(pt[1], xn)
    np.testing.assert_allclose(fn[1], s["area"][1] * KN * (n @ D) * n)
    np.testing.assert_allclose(ff[1], s["area"][1] * KF * (D - (n @ D) * n))
    # a single static contact: gradient on its nodes is -beta_a (f_n + f_f)
    s1 = dict(s)
    s1["body"] = np.array([-1, -1, -1], np.int32)
    g = np.zeros(BODY_DOF0 + 12)
    one = list(_args(s1))
    one[3] = 2  # first two contacts
    ce.add_gradient(*one, BODY_DOF0, g)
    g0 = np.zeros_like(g)
    one[3] = 1
    ce.add_gradient(*one, BODY_DOF0, g0)
    g_second = (g - g0)[: BODY_DOF0].reshape(6, 3)
    for a, nd in enumerate(s["nodes"][1]):
        np.testing.assert_allclose(g_second[nd], -s["bary"][1, a] * (fn[1] + ff[1]), rtol=1e-10, atol=1e-12)


def test_slipping_contact_hessian_has_only_the_normal_stiffness():
    """A sliding contact (anchor follows the point) has no stiffness along its friction force:
    w beta_a beta_b (K - k_f t t^T); a sticking one w K beta_a beta_b."""
    s = _setup(np.random.default_rng(7))
    s["body"] = np.array([-1, -1, -1], np.int32)
    s["slip"] = np.array([2, 0, 2], np.uint8)
    H = _dense_hessian(s)
    for c in range(3):
        n = s["normal"][c]
        K = KN * np.outer(n, n) + KF * (np.eye(3) - np.outer(n, n))
        if s["slip"][c]:
            D = s["anchor"][c] - s["bary"][c] @ s["node_x"][s["nodes"][c]]
            t = D - (n @ D) * n
            t /= np.linalg.norm(t)
            K -= KF * np.outer(t, t)
        beta = s["bary"][c]
        Hc = s["area"][c] * np.kron(np.outer(beta, beta), K)
        s1 = dict(s)
        expected = np.zeros_like(H)
        dofs = (3 * s["nodes"][c][:, None] + np.arange(3)).ravel()
        np.add.at(expected, (dofs[:, None], dofs[None, :]), Hc)
        # isolate contact c by zeroing the others' areas
        s1["area"] = np.where(np.arange(3) == c, s["area"], 0.0)
        np.testing.assert_allclose(_dense_hessian(s1), expected, rtol=1e-10, atol=1e-9)


def _stencil(nodes, body):
    """The global dofs of a contact's nodes and (if dynamic) its body's (c, theta)."""
    dofs = [3 * n + i for n in sorted(set(nodes)) for i in range(3)]
    if body >= 0:
        dofs += [BODY_DOF0 + 6 * body + i for i in range(6)]
    return dofs


@pytest.mark.parametrize("seed", [8, 9])
def test_hessian_on_a_sparse_block_pattern_equals_the_dense_one(seed):
    """add_hessian finds its 3x3 blocks in a sparse pattern (one search per block, the same
    offset in the block's three rows) and writes what it writes into a dense one; a node-body
    pair the pattern leaves out is skipped and counted, the rest unchanged."""
    from scipy.sparse import csr_matrix

    from softhand_sim.physics.energies.assembly import build_pattern, stencil_slots

    s = _setup(np.random.default_rng(seed))
    s["slip"] = np.array([2, 0, 0], np.uint8)
    n = BODY_DOF0 + 12
    dense = _dense_hessian(s)
    for drop_body in (False, True):
        stencils = [np.array([_stencil(s["nodes"][c], -1 if (drop_body and c == 0) else s["body"][c])])
                    for c in range(3)]
        if drop_body:  # the pattern still holds body 1's own block, not its coupling to contact 0's nodes
            stencils.append(np.array([_stencil([], 1)]))
        indptr, indices = build_pattern(n, stencils)
        assert len(indices) < 0.7 * n * n and len(set(np.diff(indptr))) >= 3  # rows of different lengths
        values = np.zeros(len(indices))
        skipped = ce.add_hessian(*_args(s), s["slip"], BODY_DOF0, indptr, indices, values)
        H = csr_matrix((values, indices, indptr), shape=(n, n)).toarray()
        in_pattern = csr_matrix((np.ones(len(indices)), indices, indptr), shape=(n, n)).toarray() > 0
        np.testing.assert_allclose(H[in_pattern], dense[in_pattern], rtol=1e-12, atol=1e-9)
        assert skipped == np.count_nonzero(dense[~in_pattern])
        assert (skipped > 0) == drop_body
        # the solver's path: node-node blocks through the tets' slots (contacts 0 and 1 lie in
        # tets 0 and 1, nodes in tet order; contact 2 is a surface node: searched), body-body
        # blocks through the bodies' slots; the same values and skips
        tets = s["nodes"][:2]
        tet_slots = stencil_slots(indptr, indices, (3 * tets[:, :, None] + np.arange(3)).reshape(2, 12))
        body_slots = stencil_slots(indptr, indices, BODY_DOF0 + 6 * np.arange(2)[:, None] + np.arange(6))
        slotted = np.zeros(len(indices))
        skipped2 = ce.add_hessian(*_args(s), s["slip"], BODY_DOF0, indptr, indices, slotted,
                                  np.array([0, 1, -1], np.int32), tet_slots, body_slots)
        np.testing.assert_allclose(slotted, values, rtol=1e-12, atol=1e-9)
        assert skipped2 == skipped
