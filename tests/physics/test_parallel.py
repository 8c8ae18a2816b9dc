"""solver_threads 2 (physics/parallel.py): the two hands' tissue, factorization, triangular solves
and matrix products on two cores give what one thread gives, with both hands pressing one box
(the shared rows of the factor: the box's body couples to both hands)."""
import numba
import numpy as np
import pytest

from softhand_sim.commands import bench
from softhand_sim.physics import panels, parallel, pcg
from softhand_sim.physics.model import build_model
from softhand_sim.physics.solver import Solver
from tests.support.bench_runs import run_scene

STEPS = 40


def two_hand_grip(threads):
    """The benchmark's two-hand grip (coarse hands pressing the big box from its sides):
    (solver, state, CG iterations of every step) after STEPS steps."""
    scene = bench.SCENARIOS_TWO_HANDS["grasp"]
    assets = [bench._asset("coarse")[0], bench._asset("coarse", "left")[0]]
    model = build_model(assets, {**scene.params(), "solver_threads": threads},
                        objects=scene.objects(assets))
    solver = Solver(model, contacts=scene.contacts(model))
    return (solver,) + run_scene(scene, model, solver, STEPS)


@pytest.fixture(scope="module")
def grips():
    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.fail(f"NUMBA_NUM_THREADS={numba.config.NUMBA_NUM_THREADS}: these tests need 2")
    return two_hand_grip(1), two_hand_grip(2)


def test_two_threads_step_as_one_thread_does(grips):
    """40 steps of the grip: the same nodes, bones and box to round-off, with contacts on both
    hands and the factor split by hand with shared rows (the box) after the hands' rows; and the
    same CG iterations (a preconditioner off by more than round-off takes more)."""
    (s1, x1, it1), (s2, x2, it2) = grips
    assert it2 == it1
    f = s2.factor
    assert s1.factor.arrays[9].size == 0 and f.by_group and f.shared_rows < f.sym.nb
    assert s2.last_stats.contacts > 100
    assert np.abs(x2.node_x - x1.node_x).max() <= 1e-9
    assert np.abs(x2.body_x - x1.body_x).max() <= 1e-9
    assert np.abs(x2.v - x1.v).max() <= 1e-6


def test_factor_by_group_is_the_one_thread_factor_in_any_slicing(grips):
    """The factor of the gripping hands' matrix, computed in 1 and in 5 slices with the groups
    in parallel, equals the one-thread factor entry for entry."""
    _, (solver, _, _) = grips
    m, values = solver.model, solver.values
    groups = solver.factor.groups
    one = pcg.Factor(m.dof_count, m.indptr, m.indices, groups=groups)
    one.refresh(m.indptr, m.indices, values)
    for slices in (1, 5):
        two = pcg.Factor(m.dof_count, m.indptr, m.indices, groups=groups, threads=2,
                         slice_flops=one.sym.flops / slices + 1.0, max_slices=slices)
        assert two.by_group and two.slices == slices
        for _ in range(slices):
            two.advance(values)
        assert two.valid
        np.testing.assert_array_equal(two.L, one.L)
        np.testing.assert_array_equal(two.D_inv, one.D_inv)
        np.testing.assert_array_equal(two.arrays[4], one.arrays[4])  # the panels


def test_solve_by_group_matches_the_serial_solve_through_the_shared_rows(grips):
    """z = A^-1 r by groups (each hand's panels on a core, the box's rows after them) equals the
    one-thread panel solve to round-off, for a right-hand side on every row; the box's rows
    (shared) receive from both hands' panels."""
    _, (solver, _, _) = grips
    f = solver.factor
    starts, rptr, rows, off, values, Dinv, perm, tmp, u, sb, acc, ug = f.arrays
    shared = starts[sb[-2]]
    assert len(sb) == 4 and shared == f.shared_rows  # two hands' supernodes, then the box's
    for h in range(2):  # each hand's panels reach the box's rows
        assert (rows[rptr[sb[h]]:rptr[sb[h + 1]]] >= shared).any()
    rng = np.random.default_rng(3)
    r = rng.standard_normal(solver.model.dof_count)
    z1, z2 = np.zeros_like(r), np.full_like(r, np.nan)
    panels.panel_solve(starts, rptr, rows, off, values, Dinv, perm, tmp, u, r, z1)
    parallel.panel_solve_by_group(starts, rptr, rows, off, values, Dinv, perm, tmp, r, z2, sb, acc, ug)
    assert np.abs(z2 - z1).max() <= 1e-12 * np.abs(z1).max()


def test_product_by_rows_is_the_product(grips):
    _, (solver, _, _) = grips
    m = solver.model
    x = np.random.default_rng(4).standard_normal(m.dof_count)
    a, b = np.zeros_like(x), np.zeros_like(x)
    pcg.csr_matvec3(m.indptr, m.indices, solver.values, x, a)
    pcg.csr_matvec3_by_rows(m.indptr, m.indices, solver.values, x, b, parallel.row_chunks(m.indptr, 2))
    np.testing.assert_array_equal(a, b)


def test_more_threads_than_numba_has_is_refused_by_name():
    assets = [bench._asset("coarse")[0], bench._asset("coarse", "left")[0]]
    too_many = numba.config.NUMBA_NUM_THREADS + 1
    model = build_model(assets, {"solver_threads": too_many})
    with pytest.raises(ValueError, match=f"solver_threads={too_many}"):
        Solver(model)


def test_bench_threads_needs_two_hands(capsys):
    with pytest.raises(SystemExit):
        bench.main(["--threads", "2", "--hands", "1", "--scenario", "free", "--mesh", "coarse"])
    assert "needs --hands 2" in capsys.readouterr().err


def test_two_threads_with_the_hands_pressed_palm_to_palm():
    """sim_node's two-hand runtime with self contact, the palms pressed together (the skin-skin
    contacts between the hands couple them outside the factor's pattern, in the CG's products):
    1 and 2 threads step the same states, with the same CG iterations, through the press."""
    from softhand_sim.params import load_params
    from softhand_sim.runtime import SimRuntime
    from softhand_sim.scenarios.bimanual import _table_top
    from softhand_sim.scenarios.self_contact import PalmsPressed

    runtimes = [SimRuntime(load_params("sim_node", overrides={
        "hands": ["right", "left"], "self_contact": True, "solver_threads": threads})) for threads in (1, 2)]
    assert runtimes[1].solver.factor.by_group
    script = PalmsPressed([0.0, 0.0, _table_top(runtimes[0].scene) + 0.30])
    dt = 1.0 / 60.0
    between = 0
    for k in range(int(script.T["approach1"] / dt) + 30):  # through the approach into the press
        t = k * dt
        stats = []
        for rt in runtimes:
            for side, poses in script.targets(t).items():
                rt.set_bone_targets(poses, t, hand=side)
            stats.append(rt.step(dt, t).stats)
        assert stats[0].cg_iters == stats[1].cg_iters
        assert np.abs(runtimes[0].state.node_x - runtimes[1].state.node_x).max() <= 1e-9
        between = max(between, stats[1].self_contacts)
    assert between >= 10
