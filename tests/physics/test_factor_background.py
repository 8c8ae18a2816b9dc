"""The factor preconditioner's factorizations on a thread of their own (`factor_background`,
pcg.Factor(background=True)): the factor that comes into use is the factor of the matrix as it was
when its factorization started, bit for bit the one the steps' slices compute (by hand groups
too); the solver with it follows the same motion as without to CG's tolerance, publishes new
factors as they finish and holds none; it refuses to share the step's cores."""
import os

import numpy as np
import pytest

from softhand_sim.physics import ldlt, pcg
from softhand_sim.physics.solver import Solver, hand_block_groups
from tests.support.bench_runs import scene_run


@pytest.fixture(scope="module")
def two_coarse():
    """Two coarse hands after 30 steps of the benchmark's open-close: (model, solver)."""
    return scene_run("free", ["coarse", "coarse"], 30, preconditioner="factor")[:2]


def _factor(model, background, threads, slices=4):
    """A factor of the model's pattern spread over `slices` slices (the coarse hands' own rule
    gives one, which no thread takes over)."""
    groups = hand_block_groups(model)
    flops = ldlt.Symbolic(model.indptr, model.indices, model.dof_count, groups=groups).flops
    return pcg.Factor(model.dof_count, model.indptr, model.indices, slice_flops=flops / (slices - 0.5),
                      groups=groups, threads=threads, background=background)


@pytest.mark.parametrize("threads", [1, 2])
def test_the_factor_in_use_is_that_of_the_matrix_when_its_thread_started(two_coarse, threads):
    """advance() starts a factorization on a snapshot of the step's values and returns at once;
    the values changed afterwards in the same buffer (as the solver's are every step) do not reach
    it. At the next advance after it is done it comes into use, equal bit for bit to the factor
    the slices compute of the snapshot (panels and D⁻¹; with threads 2 those slices factor the
    hands in parallel: the same arithmetic per row), and the next one starts."""
    model, solver = two_coarse
    a0 = solver.values.copy()
    a1, a2 = 1.5 * a0, 2.0 * a0  # SPD as a0 is, and factors of their own
    bg, ref = _factor(model, True, threads), _factor(model, False, threads)
    assert bg.slices == ref.slices == 4 and bg.threaded and not ref.threaded
    assert not pcg.Factor(model.dof_count, model.indptr, model.indices, background=True).threaded  # one slice
    bg.refresh(model.indptr, model.indices, a0)
    values = a1.copy()
    assert bg.advance(values) is False and bg.in_progress
    values[:] = a2
    for expected in (a1, a2):
        bg.wait()
        assert bg.advance(values) is True and bg.in_progress  # published, the next one started
        ref.refresh(model.indptr, model.indices, expected)
        assert np.array_equal(bg.arrays[4], ref.arrays[4]) and np.array_equal(bg.D_inv, ref.D_inv)
        z_bg, z_ref = np.zeros(model.dof_count), np.zeros(model.dof_count)
        r = np.linspace(-1.0, 1.0, model.dof_count)
        bg.solve(r, z_bg)
        ref.solve(r, z_ref)
        assert np.array_equal(z_bg, z_ref)
    bg.refresh(model.indptr, model.indices, a0)  # waits for the running one, then its own
    assert not bg.in_progress and bg.bad_pivots == 0


def test_the_solver_in_the_background_follows_the_same_motion():
    """The fine hand's open-close (80 steps) with factor_background: no step holds its factor or
    runs a slice, new factors come into use as the thread finishes them (17 of 80 steps here),
    and the hand is where it is without the thread to CG's tolerance (measured 4e-8 m and 1.1e-5
    m/s apart; bounds 1 µm and 1e-4 m/s, those of the kept Hessians' test). Which factor a step
    uses depends on the thread's timing, so the run itself is not repeatable to the bit."""
    _, _, ref, ref_iters = scene_run("free", ["fine"], 80)
    stats = []
    _, solver, bg, bg_iters = scene_run("free", ["fine"], 80, stats=stats, factor_background=True)
    assert solver.factor.threaded and solver.factor.slices > 1
    assert not any(s.held for s in stats)
    assert sum(s.refactored for s in stats[1:]) >= 2  # published after the first step's own
    assert np.abs(bg.node_x - ref.node_x).max() < 1e-6 and np.abs(bg.v - ref.v).max() < 1e-4
    # A factor that arrives later serves older matrices: measured 7.9 iterations a step against
    # the slices' 8.1 with the machine to itself, 10.3 with the other test worker busy on the
    # second core (the thread's factorizations take longer). A factor of another matrix would take
    # CG past 4 x factor_refresh_iterations (32), where the step factors its own.
    assert np.mean(bg_iters) <= 1.5 * np.mean(ref_iters) + 1.0
    assert solver.factor.bad_pivots == 0


def test_the_background_needs_a_core_beside_the_steps(two_coarse):
    """factor_background with solver_threads taking every core of this process (two hands):
    refused, naming the values (measured: a third thread on two cores ran two fine hands 2-3 times
    slower). One hand runs on one thread whatever solver_threads says: a second core suffices."""
    import numba
    cores = len(os.sched_getaffinity(0))
    if cores > numba.config.NUMBA_NUM_THREADS:
        pytest.skip(f"numba runs {numba.config.NUMBA_NUM_THREADS} threads, this process has {cores} cores")
    model, _ = two_coarse
    with pytest.raises(ValueError, match=rf"factor_background=true needs a core beside the step's {cores} "
                                         rf"\(solver_threads={cores}, 2 hand\(s\)\) and this process has "
                                         rf"{cores}: set factor_background false or solver_threads {cores - 1}"):
        Solver(model, params={"factor_background": True, "solver_threads": cores})
    Solver(model, params={"factor_background": True, "solver_threads": cores - 1})


def test_a_runtime_without_the_factor_describes_itself():
    """The placeholder Factor of a solver with another preconditioner (jacobi), which never
    analyses a pattern, answers `threaded` and `in_progress`: SimRuntime.describe (sim_node's
    start-up line) reads them."""
    from softhand_sim.params import load_params
    from softhand_sim.runtime import SimRuntime
    rt = SimRuntime(dict(load_params("sim_node"), preconditioner="jacobi", factor_background=True))
    assert not rt.solver.factor.threaded and not rt.solver.factor.in_progress
    text = rt.describe()
    assert "preconditioner jacobi" in text and "background" not in text
