"""The factor preconditioner's factor kept over steps (factor_hold, physics/factor_hold.py): the
rule itself, step by step, and on the hand: a held press keeps its factor for most of its steps
and ends where a new factor every step ends; a fast motion is not held every other step."""
import numpy as np
import pytest

from softhand_sim.commands import bench
from softhand_sim.physics.factor_hold import MAX_BACKOFF, FactorHold
from softhand_sim.physics import pcg
from softhand_sim.physics.model import build_model
from softhand_sim.physics.solver import Solver


def test_hold_until_the_excess_iterations_reach_the_budget():
    hold = FactorHold(0.5)  # budget 0.5 * 10 = 5 iterations beyond one, summed
    # the held steps' iterations over one, summed, and the last one again as the next step's forecast
    assert hold.keep(1, 10.0)        # a fresh factor's CG took one iteration: 0 + 0
    assert hold.keep(2, 10.0)        # 1 + 1
    assert hold.keep(2, 10.0)        # 2 + 1
    assert hold.keep(2, 10.0)        # 3 + 1
    assert not hold.keep(2, 10.0)    # 4 + 1 = 5: a new factorization
    hold.published()
    assert hold.keep(1, 10.0)        # and the new factor is held again
    assert not FactorHold(0.0).keep(1, 10.0)  # 0: never held
    with pytest.raises(ValueError, match="factor_hold=-1"):
        FactorHold(-1.0)


def test_a_hold_that_fails_at_once_backs_off():
    """First held steps that cost the whole budget: the next attempts wait 1, 2, 4, ... factorizations;
    one that pays resets the wait."""
    hold = FactorHold(0.5)
    assert hold.keep(1, 10.0)            # the first attempt
    waits = []
    for _ in range(9):
        assert not hold.keep(9, 10.0)    # its step took 8 iterations over one: failed, factor
        hold.published()
        n = 0
        while not hold.keep(1, 10.0):    # the factorizations before the next attempt
            hold.published()
            n += 1
        waits.append(n)
    assert waits == [1, 2, 4, 8, 16, 32, 64, MAX_BACKOFF, MAX_BACKOFF]
    assert hold.keep(2, 10.0)            # an attempt whose first step stays under the budget ...
    assert hold.backoff == 0 and hold.wait == 0
    hold.rescued()                       # a held step that had to factor: a failed attempt too
    assert (hold.backoff, hold.wait, hold.held, hold.excess) == (1, 1, 0, 0.0)
    assert not hold.keep(1, 10.0)        # one factorization before the next attempt
    assert hold.keep(1, 10.0)


def _scene(name, params):
    """The coarse hand in the benchmark's scenario `name` with solver `params`: (model, solver,
    state, control, update(k, t))."""
    scenes = bench.check_case(name, 1)
    asset = bench._asset("coarse")[0]
    model = build_model(asset, params, objects=scenes[name].objects(asset))
    solver = Solver(model)
    state, control = model.initial_state(), model.control()
    return model, solver, state, control, scenes[name](solver, state, control)


def _press(factor_hold, steps=200):
    _, solver, state, control, update = _scene("press", {"factor_hold": factor_hold})
    stats = []
    for k in range(steps):
        update(k, k * bench.DT)
        stats.append(solver.step(state, control, bench.DT))
    return stats, state


def test_a_held_press_keeps_its_factor_and_its_result():
    """The coarse hand pressing its fingertips (the benchmark's press): with factor_hold 1 most
    steps keep the factor in use, and the hand ends within 1 µm of the run that factors every step
    (the same CG tolerance)."""
    every, state_every = _press(0.0)
    held, state_held = _press(1.0)
    assert sum(s.held for s in every) == 0 and sum(s.refactored for s in every) >= 190
    n_held = sum(s.held for s in held)
    assert n_held >= 150, n_held
    assert sum(s.refactored for s in held) + n_held == 200
    assert all(s.held != s.refactored for s in held)
    assert max(s.cg_iters for s in held[100:]) <= 6
    assert not any(s.hit_cap for s in held)
    assert np.abs(state_held.node_x - state_every.node_x).max() < 1e-6
    assert np.abs(state_held.body_x - state_every.body_x).max() < 1e-6


def test_bench_set_reaches_the_solver_and_refuses_bad_values(capsys):
    """`softhand bench --set factor_hold=0`: no step holds (the default holds most of the press);
    a bad key, value or form, and the parameters with options of their own, exit 2 naming it."""
    import json
    argv = ["--json", "--steps", "40", "--mesh", "coarse", "--scenario", "press"]
    assert bench.main(argv) == 0
    default = json.loads(capsys.readouterr().out)[0]
    assert bench.main([*argv, "--set", "factor_hold=0"]) == 0
    off = json.loads(capsys.readouterr().out)[0]
    assert default["factor_held"] >= 20 and default["settings"] == {}
    assert off["factor_held"] == 0 and off["settings"] == {"factor_hold": 0.0}
    for bad, message in (("factor_hold=-1", "'factor_hold' must be >= 0.0"),
                         ("no_such=1", "unknown parameter 'no_such'"),
                         ("factor_hold", "--set 'factor_hold': expected KEY=VALUE"),
                         ("solver_threads=2", "use --threads")):
        with pytest.raises(SystemExit) as exc:
            bench.main([*argv, "--set", bad])
        captured = capsys.readouterr()
        assert exc.value.code == 2 and message in captured.err and captured.out == "", bad


@pytest.mark.parametrize("cap", [5, 200])
def test_a_held_step_whose_cg_runs_long_is_solved_again_with_its_own_factor(cap):
    """A kept factor far from the step's matrix (here the factor of its diagonal alone, as after a
    jump or an impact): CG on it stops after a factorization's worth of iterations (10 on the coarse
    hand) or at the cap if lower, then the step factors its own matrix and goes on from where CG
    stopped, converged and not capped: no step runs up a long CG on a kept factor, nor hands the
    runtime's guard a capped step to reject."""
    model, solver, state, control, update = _scene("free", {"cg_max_iterations": cap})
    for k in range(20):
        update(k, k * bench.DT)
        assert not solver.step(state, control, bench.DT).hit_cap
    diagonal = np.zeros_like(solver.values)
    diagonal[model.diag_slot] = solver.values[model.diag_slot]
    solver.factor.refresh(model.indptr, model.indices, diagonal)
    solver.hold.keep = lambda last_iters, iterations_per_factor: True  # hold whatever it costs
    limit = min(cap, int(np.ceil(solver.factor.iterations_per_factor)))
    assert limit == (5 if cap == 5 else 10)
    update(20, 20 * bench.DT)
    st = solver.step(state, control, bench.DT)
    assert st.refactored and not st.held and not st.hit_cap, st
    assert st.residual <= 1e-5 and limit < st.cg_iters <= limit + 3, st
    assert solver._last_iters == st.cg_iters - limit  # the next step's forecast: the fresh factor's


def test_factor_cost_scale_scales_the_unit_and_the_slices():
    """factor_cost_scale (for a machine whose kernels run at other speeds than the estimate's)
    multiplies a factorization's estimated cost in CG iterations, so factor_hold's budget and the
    kept factor's limit with it, and the slice count K = 0.095 x that cost (K = 1 on the coarse hand
    at 9.1 iterations, 2 at three times that); `softhand bench --set` refuses a scale of 0."""
    _, default, *_ = _scene("press", {})
    _, tripled, *_ = _scene("press", {"factor_cost_scale": 3.0})
    assert tripled.factor.iterations_per_factor == pytest.approx(3.0 * default.factor.iterations_per_factor)
    assert default.factor.slices == 1
    assert tripled.factor.slices == int(pcg.SLICES_PER_ITERATION * tripled.factor.iterations_per_factor) == 2
    with pytest.raises(ValueError, match="factor_cost_scale"):
        bench.parse_settings(["factor_cost_scale=0"])
