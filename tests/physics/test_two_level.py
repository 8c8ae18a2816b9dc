"""The two-level preconditioner (physics/two_level.py): its prolongation, its coarse matrix, the
V-cycle as a preconditioner (symmetric, positive, an error-reducing iteration), its sweeps split
by hand on two threads, and the solver's steps with it against the factor preconditioner's."""
import numba
import numpy as np
import pytest
import scipy.sparse as sp

from softhand_sim.commands import bench
from softhand_sim.physics import two_level
from softhand_sim.physics.model import build_model, rigid_asset
from softhand_sim.physics.solver import Solver
from tests.support.bench_runs import run_scene, scene_run

STEPS = 40


def free_motion(preconditioner, mesh="fine"):
    """The benchmark's open-close of one hand: (model, solver, state, CG iterations per step)."""
    return scene_run("free", [mesh], STEPS, preconditioner=preconditioner)


@pytest.fixture(scope="module")
def fine_two_level():
    return free_motion("two_level")


def system_matrix(model, values):
    n = model.dof_count
    return sp.csr_matrix((values, model.indices, model.indptr), shape=(n, n))


def test_prolongation_interpolates_the_coarse_mesh(fine_two_level):
    """P carries any affine motion of the coarse hand's nodes to the fine nodes inside the coarse
    mesh exactly (barycentric interpolation), and to the others (the skin layer outside it) as
    the nearest coarse tet's clamped coordinates: weights >= 0 summing to 1 everywhere, the
    bones and objects carried unchanged."""
    model, solver, _, _ = fine_two_level
    level = solver.coarse
    assert np.all(level.pw >= 0.0)
    used = level.pc >= 0
    np.testing.assert_allclose(np.where(used, level.pw, 0.0).sum(1), 1.0, atol=1e-12)
    coarse_x, _ = model.extra["coarse_meshes"][0]
    assert level.coarse_nodes == len(coarse_x)  # every coarse node serves some fine node
    rng = np.random.default_rng(0)
    F, c = np.eye(3) + 0.2 * rng.standard_normal((3, 3)), rng.standard_normal(3)
    coarse_u = coarse_x @ F.T + c
    u = np.zeros(level.n)
    u[:3 * len(coarse_x)] = coarse_u.ravel()
    u[3 * len(coarse_x):] = rng.standard_normal(level.n - 3 * len(coarse_x))  # bodies
    fine_u = level.prolongation() @ u
    expected = model.node_rest @ F.T + c
    err = np.linalg.norm(fine_u[:3 * model.node_count].reshape(-1, 3) - expected, axis=1)
    # the point each fine node is interpolated to (F = I): itself inside the coarse mesh, a point
    # of the nearest coarse tet outside it (the skin layer the coarse mesh leaves out)
    u_rest = np.zeros(level.n)
    u_rest[:3 * len(coarse_x)] = coarse_x.ravel()
    dist = np.linalg.norm((level.prolongation() @ u_rest)[:3 * model.node_count].reshape(-1, 3)
                          - model.node_rest, axis=1)
    inside = dist < 1e-12
    assert inside.mean() > 0.6, inside.mean()  # the measured hand: 1,369 of 1,939 fine nodes
    assert np.all(err[inside] < 1e-12)
    assert np.all(err <= np.linalg.norm(F, 2) * dist + 1e-12)  # F (y - x) for the point y
    assert dist.max() < 0.015 and np.median(dist[~inside]) < 0.002, (dist.max(), np.median(dist[~inside]))
    np.testing.assert_array_equal(fine_u[3 * model.node_count:], u[3 * len(coarse_x):])


def test_coarse_matrix_is_the_galerkin_product_whole_and_sliced(fine_two_level):
    """A_c = Pᵀ A P (scipy's product) from refresh(), and the same from refresh_steps advance()
    calls (the slices of the fine rows summed, then factored)."""
    model, solver, _, _ = fine_two_level
    level, values = solver.coarse, solver.values.copy()
    P = level.prolongation()
    expected = (P.T @ system_matrix(model, values) @ P).toarray()
    level.refresh(values)
    got = sp.csr_matrix((level.values, level.indices, level.indptr), shape=(level.n,) * 2).toarray()
    scale = np.abs(expected).max()
    assert np.abs(got - expected).max() <= 1e-13 * scale
    published = [level.advance(values) for _ in range(level.refresh_steps)]
    assert published == [False] * (level.refresh_steps - 1) + [True]
    got = sp.csr_matrix((level.values, level.indices, level.indptr), shape=(level.n,) * 2).toarray()
    assert np.abs(got - expected).max() <= 1e-13 * scale


def test_v_cycle_is_a_symmetric_positive_error_reducing_preconditioner(fine_two_level):
    """z = B r from the V-cycle: B symmetric (the backward sweep is the forward one's adjoint) and
    positive; and x <- x + B (b - A x) reduces the error in A's energy norm at every iteration
    (what makes it a preconditioner for CG: B A's eigenvalues in (0, 1])."""
    model, solver, _, _ = fine_two_level
    level, values = solver.coarse, solver.values
    level.refresh(values)
    A = system_matrix(model, values)
    n = model.dof_count

    def apply(r):
        z = np.zeros(n)
        two_level.v_cycle(model.indptr, model.indices, values, model.diag_slot, np.ascontiguousarray(r), z,
                          *level.arrays[:6])
        return z

    rng = np.random.default_rng(1)
    r1, r2 = rng.standard_normal((2, n))
    z1, z2 = apply(r1), apply(r2)
    assert abs(r2 @ z1 - r1 @ z2) <= 1e-12 * abs(r2 @ z1)
    assert r1 @ z1 > 0.0 and r2 @ z2 > 0.0
    x_true = rng.standard_normal(n)
    b, x = A @ x_true, np.zeros(n)
    energies = []
    for _ in range(6):
        x += apply(b - A @ x)
        e = x - x_true
        energies.append(e @ (A @ e))
    e0 = x_true @ (A @ x_true)
    rates = np.sqrt(np.array(energies) / np.r_[e0, energies[:-1]])
    assert np.all(rates < 0.9), rates  # measured: 0.4-0.6 a cycle


def test_solver_with_two_level_follows_the_factor_solver(fine_two_level):
    """The fine hand's open-close: the same motion as with the factor preconditioner to CG's
    tolerance (1 µm), in a bounded count of CG iterations a step (Jacobi takes 200 here)."""
    _, _, state, iterations = fine_two_level
    _, _, state_f, iterations_f = free_motion("factor")
    assert np.abs(state.node_x - state_f.node_x).max() < 1e-6
    assert np.abs(state.body_x - state_f.body_x).max() < 1e-6
    assert np.median(iterations[5:]) <= 16, iterations  # measured: 11-13
    assert max(iterations) < 40


def test_two_threads_sweep_each_hand_as_one_thread_does():
    """Two coarse hands gripping the big box with two_level (each hand's coarse level its own mesh):
    the V-cycle by hand on two threads (sweeps, restriction, coarse solve and prolongation of each
    hand on a core, the box's shared rows on one thread) gives the serial V-cycle's z to round-off;
    40 steps on one and on two threads take the same CG iterations (to one, where round-off moves
    CG's stop) and end within CG's reach of each other."""
    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.fail(f"NUMBA_NUM_THREADS={numba.config.NUMBA_NUM_THREADS}: this test needs 2")
    scene = bench.SCENARIOS_TWO_HANDS["grasp"]
    assets = [bench._asset("coarse")[0], bench._asset("coarse", "left")[0]]
    runs = []
    for threads in (1, 2):
        params = {**scene.params(), "solver_threads": threads, "preconditioner": "two_level"}
        model = build_model(assets, params, objects=scene.objects(assets),
                            coarse_meshes=[(a.tet_nodes, a.tets) for a in assets])
        solver = Solver(model, contacts=scene.contacts(model))
        assert solver.coarse.rows.shape[0] == threads
        runs.append(run_scene(scene, model, solver, STEPS) + (solver,))
    (x1, it1, _), (x2, it2, solver) = runs
    assert solver.last_stats.contacts > 100  # the box's rows couple both hands
    model, values = solver.model, solver.values
    by_hand = solver.coarse
    serial = two_level.CoarseLevel(model, model.extra["coarse_meshes"])
    by_hand.refresh(values)
    serial.refresh(values)
    scale = np.abs(serial.values).max()
    np.testing.assert_allclose(by_hand.values, serial.values, rtol=0, atol=1e-13 * scale)
    whole = by_hand.values.copy()  # the slices of each hand's rows, summed over refresh_steps steps
    assert [by_hand.advance(values) for _ in range(by_hand.refresh_steps)][-1]
    np.testing.assert_allclose(by_hand.values, whole, rtol=0, atol=1e-13 * np.abs(whole).max())
    r = np.random.default_rng(2).standard_normal(model.dof_count)
    z1, z2 = np.zeros_like(r), np.full_like(r, np.nan)
    args = (model.indptr, model.indices, values, model.diag_slot, r)
    two_level.v_cycle(*args, z1, *serial.arrays[:6])
    two_level.v_cycle_by_hand(*args, z2, *by_hand.arrays)
    assert np.abs(z2 - z1).max() <= 1e-12 * np.abs(z1).max()
    assert np.abs(np.subtract(it2, it1)).max() <= 1 and abs(sum(it2) - sum(it1)) <= 2, (it1, it2)
    assert np.abs(x2.node_x - x1.node_x).max() <= 1e-5  # measured: 1.9 µm after one step's extra iteration
    assert np.abs(x2.body_x - x1.body_x).max() <= 1e-5


def test_two_level_needs_a_coarse_mesh():
    """An asset that is not a hand (no measures, no side) has no coarse hand to find: build_model
    says to pass coarse_meshes; a model built without them is refused by the solver."""
    nodes = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float) * 0.01
    asset = rigid_asset(nodes, np.array([[0, 1, 2, 3]], np.int32))
    with pytest.raises(ValueError, match="coarse_meshes"):
        build_model(asset, {"preconditioner": "two_level"})
    model = build_model(asset, {"preconditioner": "two_level"}, coarse_meshes=[(nodes, [[0, 1, 2, 3]])])
    del model.extra["coarse_meshes"]
    with pytest.raises(ValueError, match="coarse hand's mesh"):
        Solver(model)


def test_sim_runtime_gives_each_hand_its_coarse_hand():
    """sim_node's runtime with `mesh: fine` and `preconditioner: two_level` for both hands: each
    hand's coarse level is the coarse hand of its own side and measures (every one of their nodes
    used), and a step from the hands' rest targets stays finite."""
    from softhand_sim.handmodel import load_or_build_hand
    from softhand_sim.params import load_params
    from softhand_sim.runtime import SimRuntime
    rt = SimRuntime(load_params("sim_node", overrides={"hands": ["right", "left"], "mesh": "fine",
                                                       "preconditioner": "two_level"}))
    coarse = [load_or_build_hand(rt.measures, side=side, resolution="coarse") for side in rt.hands]
    meshes = rt.model.extra["coarse_meshes"]
    for mesh, asset in zip(meshes, coarse):
        np.testing.assert_array_equal(mesh[0], asset.tet_nodes)
    assert rt.solver.coarse.coarse_nodes == sum(len(a.tet_nodes) for a in coarse)
    rt.warm_up(1.0 / rt.params["sim_rate"])
    assert rt.solver.coarse.valid and np.all(np.isfinite(rt.state.node_x))
