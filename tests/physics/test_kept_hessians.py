"""The tissue Hessian kept per tet between steps (tissue.assemble_tissue's KEEP modes, params
tissue_hessian_tolerance): the kept sums are exactly the Hessians of the states each tet was last
assembled at, no kept state is more than the tolerance from the current one, the energy and the
gradient stay exact; in the solver, a held grasp re-assembles few tets and moves the hand by less
than a micrometre against the exact Hessian, free motion runs the whole kernel."""
import numpy as np
import pytest

from tests.support.solver_fixtures import box_mesh, dense_slots, random_quat, tet_stencils
from softhand_sim.params import defaults
from softhand_sim.physics.energies import tissue
from softhand_sim.physics.rotations import quat_exp, quat_mul, quat_to_matrix

E_YOUNG, NU, WMAX = 1e5, 0.33, 50.0
TOL = 0.01


def _box(size, cells):
    """A tet box with its rest data: X, tets, volumes, Dm^-1, Lame's (lam, mu), dense slots."""
    X, tets = box_mesh(size, cells)
    vol, Dm_inv, _ = tissue.rest_data(X, tets, E_YOUNG, NU)
    return X, tets, vol, Dm_inv, tissue.lame(E_YOUNG, NU), dense_slots(tet_stencils(tets), 3 * len(X))


def _kept_reference(X, tets, Dm_inv, vol, lam, mu, used_q, used_G, nl_k, slots, size):
    """Sum over tets of the whole kernel's Hessian at each tet's kept state: the tet alone with
    its nodes at F X (F = R_used G_used), its rotation given (no polar iteration)."""
    H = np.zeros(size)
    for e in range(len(tets)):
        u = used_q[e].copy()
        F = quat_to_matrix(u) @ used_G[e]
        x = X[tets[e]] @ F.T
        tissue.add_all_fused(x, np.arange(4).reshape(1, 4), Dm_inv[e:e + 1], vol[e:e + 1], lam, mu,
                             u.reshape(1, 4), 0, nl_k, WMAX, np.zeros(12), slots[e:e + 1], H, True)
    return H


@pytest.mark.parametrize("nl_k", [0.0, 1000.0])
def test_kept_hessians_are_those_of_the_kept_states(nl_k):
    """A box turned in steps, some of its nodes pushed: after every call the kept sums equal the
    whole kernel's Hessians at the kept states (to round-off), every kept rotation and stretch
    is within the tolerance of the current one, and energy and gradient equal the whole
    kernel's at the current state; small steps keep most tets, large ones re-assemble them."""
    rng = np.random.default_rng(5)
    X, tets, vol, Dm_inv, (lam, mu), slots = _box((0.03, 0.02, 0.02), (3, 2, 2))
    N, T = len(X), len(tets)
    q0 = random_quat(rng)
    x = X @ quat_to_matrix(q0).T + 0.0005 * rng.normal(size=X.shape)
    q_kept = np.tile(q0, (T, 1))
    q_whole = q_kept.copy()
    used_q, used_G = np.zeros((T, 4)), np.full((T, 3, 3), np.nan)
    kept_H = np.zeros((T, 12, 12))
    kept = np.zeros(9 * N * N)
    counts = []
    for k, turn in enumerate([0.0, 0.002, 0.003, 0.02, 0.001, 0.3, 0.004]):
        mode = tissue.KEEP_ALL if k == 0 else tissue.KEEP_MOVED
        dq = quat_exp(turn * np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8]))
        x = x @ quat_to_matrix(dq).T
        if k == 4:  # one corner pushed by 1 mm: its tets strain, the rest only turn
            x[0] += 0.001
        g_kept, g_whole, H_whole = np.zeros(3 * N), np.zeros(3 * N), np.zeros(9 * N * N)
        # 20 polar iterations: converged rotations, so turning the box changes no tet's stretch
        e_kept, changed = tissue.assemble_tissue(x, tets, Dm_inv, vol, lam, mu, q_kept, 20, nl_k, WMAX,
                                                 g_kept, slots, kept, True, mode, TOL, used_q, used_G,
                                                 kept_H)
        e_whole = tissue.add_all_fused(x, tets, Dm_inv, vol, lam, mu, q_whole, 20, nl_k, WMAX,
                                       g_whole, slots, H_whole, True)
        counts.append(changed)
        assert abs(e_kept - e_whole) <= 1e-12 * abs(e_whole)
        assert np.abs(g_kept - g_whole).max() <= 1e-12 * np.abs(g_whole).max()
        ref = _kept_reference(X, tets, Dm_inv, vol, lam, mu, used_q, used_G, nl_k, slots, 9 * N * N)
        assert np.abs(kept - ref).max() <= 1e-9 * np.abs(ref).max()
        summed = np.zeros(9 * N * N)  # the kept Hessians are those summed
        np.add.at(summed, slots.ravel(), kept_H.ravel())
        assert np.abs(kept - summed).max() <= 1e-9 * np.abs(ref).max()
        # the kept states are within the tolerance of the current ones
        cos = np.abs(np.sum(used_q * q_kept, axis=1))
        assert np.all(2 * np.arccos(np.minimum(cos, 1.0)) <= TOL + 1e-12)
        Ds = np.stack([x[t[1:]] - x[t[0]] for t in tets]).transpose(0, 2, 1)
        G = np.einsum("eji,ejk->eik", np.stack([quat_to_matrix(q) for q in q_kept]),
                      np.einsum("erk,ekc->erc", Ds, Dm_inv))
        assert np.abs(G - used_G).max() <= TOL + 1e-12
        if turn >= TOL:  # every tet turned past the tolerance: all re-assembled, the whole Hessian
            assert changed == T
            assert np.abs(kept - H_whole).max() <= 1e-9 * np.abs(H_whole).max()
    assert counts[0] == T  # the first call assembles every tet
    assert counts[1] == 0 and counts[2] == 0  # 2 and then 3 mrad more (5 in all): all kept
    assert 0 < counts[4] < T  # the pushed corner's tets alone


def test_keeping_every_tet_counts_what_moved_and_rotations_alone_count_the_turned():
    """KEEP_ALL assembles every tet, records its state and counts those past the tolerance (all of
    them the first time); rotation_update counts the turned ones from the rotations alone."""
    rng = np.random.default_rng(8)
    X, tets, vol, Dm_inv, (lam, mu), slots = _box((0.02, 0.02, 0.02), (2, 2, 2))
    N, T = len(X), len(tets)
    q = np.tile(random_quat(rng), (T, 1))
    x = X @ quat_to_matrix(q[0]).T
    used_q, used_G, kept_H = np.zeros((T, 4)), np.full((T, 3, 3), np.nan), np.zeros((T, 12, 12))

    def keep_all(x):
        return tissue.assemble_tissue(x, tets, Dm_inv, vol, lam, mu, q, 20, 0.0, WMAX, np.zeros(3 * N),
                                      slots, np.zeros(9 * N * N), True, tissue.KEEP_ALL, TOL, used_q,
                                      used_G, kept_H)[1]

    assert keep_all(x) == T
    np.testing.assert_allclose(used_G, np.broadcast_to(np.eye(3), (T, 3, 3)), atol=1e-12)
    assert keep_all(x) == 0
    x2 = x.copy()
    x2[0] += 0.001  # 1 mm on 1 cm tets: strains the tets at node 0 by up to 10 %
    assert 0 < keep_all(x2) == int(np.any(tets == 0, axis=1).sum())
    turned = q.copy()
    turned[: T // 2] = [quat_mul(quat_exp(np.array([0.0, 0.0, 0.02])), r) for r in q[: T // 2]]
    assert tissue.rotation_update(turned, TOL, used_q) == T // 2
    np.testing.assert_array_equal(used_q, turned)


def test_the_default_keeps_hessians():
    assert defaults("sim_node")["tissue_hessian_tolerance"] == TOL


def _run(scenario, tolerance, steps):
    """The coarse hand through a benchmark scenario: the final state and, per step, whether the
    kept Hessians were in use and the share of tets that had moved on."""
    from softhand_sim.commands import bench
    from softhand_sim.physics.model import build_model
    from softhand_sim.physics.solver import Solver
    scenes = bench.check_case(scenario, 1)
    asset = bench._asset("coarse")[0]
    objects = getattr(scenes[scenario], "objects", None)
    model = build_model(asset, {"tissue_hessian_tolerance": tolerance},
                        objects=objects(asset) if objects else ())
    solver = Solver(model)
    state, control = model.initial_state(), model.control()
    update = scenes[scenario](solver, state, control)
    kept, shares = [], []
    for k in range(steps):
        update(k, k * bench.DT)
        solver.step(state, control, bench.DT)
        kept.append(solver._kept_valid if tolerance > 0 else False)
        shares.append(solver.tissue_updated / len(model.tets))
    return state, np.array(kept), np.array(shares)


@pytest.mark.parametrize("scenario,whole_share", [("grasp", None), ("free", None), ("free", 0.3)])
def test_kept_hessians_move_the_hand_by_less_than_a_micrometre(scenario, whole_share, monkeypatch):
    """The coarse hand in the benchmark's pinch-and-lift and its open-close motion, 200 steps with
    the tissue Hessians kept (0.01 rad) and with every tet every step: nodes and bones within
    1 µm, the ball (grasp) too. In the hold after the grasp closes few tets are re-assembled. With
    the whole kernel from 30 % of the tets moved on (free motion then switches between the whole
    kernel and the kept Hessians), the same holds and both kinds of step occur."""
    from softhand_sim.physics import solver as solver_module
    if whole_share is not None:
        monkeypatch.setattr(solver_module, "KEEP_WHOLE_SHARE", whole_share)
    state, kept, shares = _run(scenario, TOL, 200)
    exact, _, _ = _run(scenario, 0.0, 200)
    assert np.abs(state.node_x - exact.node_x).max() < 1e-6
    assert np.abs(state.body_x - exact.body_x).max() < 1e-6
    assert np.abs(state.v - exact.v).max() < 1e-4
    if scenario == "grasp":
        assert np.median(shares[100:]) < 0.1 and kept[100:].all()
    elif whole_share is None:
        assert kept[20:].all()  # the default keeps Hessians through the benchmark's open-close
    else:
        assert 0.2 < kept[20:].mean() < 0.8
