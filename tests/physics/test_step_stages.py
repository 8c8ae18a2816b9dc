"""The per-stage split of Solver.step (issue #20) and `softhand bench --profile`: every stage is
timed, none twice, and together they account for the step (no timing thresholds: only how the
stages relate to each other and to the step measured around them)."""
import json
import time

import numpy as np
import pytest

from softhand_sim.commands import bench
from softhand_sim.handmodel import load_or_build_hand
from softhand_sim.physics.model import build_model
from tests.support.stage_checks import check_stage_coverage
from softhand_sim.physics.solver import STAGE_FIELDS, Solver

STEPS = 40
# The stages are contiguous perf_counter intervals inside Solver.step; outside them are only its
# bookkeeping (a StepStats, a few attribute reads: ~10 us of a ~1-10 ms coarse step). Summed over
# the steps they must cover 90% of the step measured around the call (measured: 99-100%):
# dropping the assembly or the factor stage (each >~25% of a coarse step) falls below that
# (MIN_COVERED in tests/support/stage_checks.py, shared with tests/runtime/test_runtime_stages.py).


def run_scenario(name, steps=STEPS):
    """(per-step totals [ms], per-step StepStats) of bench scenario `name` on the coarse hand."""
    asset = load_or_build_hand(resolution="coarse")
    scenario = bench.SCENARIOS[name]
    objects = scenario.objects(asset)
    params = getattr(scenario, "params", dict)()
    model = build_model(asset, params, objects=objects or ())
    contacts = getattr(scenario, "contacts", lambda m: None)(model)
    self_contacts = getattr(scenario, "self_contacts", lambda m: None)(model)
    solver = Solver(model, contacts=contacts, self_contacts=self_contacts)
    state, control = model.initial_state(), model.control()
    update = scenario(solver, state, control)
    totals, stats = [], []
    for k in range(steps):
        update(k, k * bench.DT)
        t0 = time.perf_counter()
        st = solver.step(state, control, bench.DT)
        totals.append(1e3 * (time.perf_counter() - t0))
        stats.append(st)
    assert np.all(np.isfinite(state.node_x))
    return np.array(totals), stats


def stage_matrix(stats):
    """(steps, stages) [ms] in STAGE_FIELDS order."""
    return np.array([[getattr(st, f) for _, f in STAGE_FIELDS] for st in stats])


@pytest.mark.parametrize("name", ["free", "grasp", "free_self"])
def test_stages_account_for_the_step(name):
    """free (no contact system), grasp (object contacts), free_self (skin-skin contacts only): each
    stage >= 0, their sum <= the step measured around the call and >= MIN_COVERED of it over the
    run; setup_ms / solve_ms are exactly assembly + factor / pcg + advance."""
    totals, stats = run_scenario(name)
    stages = stage_matrix(stats)
    names = [n for n, _ in STAGE_FIELDS]
    check_stage_coverage(f"{name}: ", totals, stages, names)
    for st in stats:
        assert st.setup_ms == st.assembly_ms + st.factor_ms
        assert st.solve_ms == st.pcg_ms + st.advance_ms
    col = dict(zip(names, stages.T))
    for stage in ("assembly", "factor", "pcg", "advance"):  # each runs a kernel every step
        assert np.all(col[stage] > 0.0), stage
    if name == "free":  # no contact system at all: only the two `is None` checks of collide
        assert np.all(col["self_collision"] == 0.0)
    if name == "grasp":
        assert max(st.contacts for st in stats) > 0
        assert np.all(col["self_collision"] == 0.0)
    if name == "free_self":
        # the skin-skin pass is timed once, as self_collision, not again in collision (which
        # holds only the `contacts is None` check here)
        assert col["collision"].sum() < 0.5 * col["self_collision"].sum()


def test_stage_profile_by_hand():
    """bench.stage_profile on numbers worked by hand: `other` is the step minus the stages, shares
    are totals over the step's total and add up to 1."""
    prof = bench.stage_profile([2.0, 4.0], {"a": [1.0, 1.0], "b": [0.5, 2.0]})
    assert list(prof) == ["a", "b", "other"]
    assert prof["other"]["median_ms"] == pytest.approx(0.75)  # other = [0.5, 1.0]
    assert prof["b"]["median_ms"] == pytest.approx(1.25)
    assert prof["b"]["p99_ms"] == pytest.approx(0.5 + 0.99 * 1.5)
    assert prof["a"]["share"] == pytest.approx(2.0 / 6.0)
    assert prof["b"]["share"] == pytest.approx(2.5 / 6.0)
    assert prof["other"]["share"] == pytest.approx(1.5 / 6.0)


def test_bench_profile_json_has_every_stage(capsys):
    """`softhand bench --profile --json --steps N`: each row has every stage with a median <= p99
    and a share in [0, 1], the shares adding up to 1, and with the factor preconditioner the
    factor's cost measured and estimated; without --profile the rows are as before."""
    assert bench.main(["--profile", "--json", "--steps", "5", "--mesh", "coarse", "--scenario", "free"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert len(rows) == 1
    stages = rows[0]["stages"]
    assert list(stages) == [n for n, _ in STAGE_FIELDS] + ["other"]
    for name, s in stages.items():
        assert set(s) == {"median_ms", "p99_ms", "share"}, name
        assert 0.0 <= s["median_ms"] <= s["p99_ms"], name
        assert 0.0 <= s["share"] <= 1.0, name
    assert sum(s["share"] for s in stages.values()) == pytest.approx(1.0)
    # the factor's cost model against this machine: a factorization and an iteration timed
    cost = rows[0]["factor_cost"]
    assert set(cost) == {"factor_ms", "iteration_ms", "measured", "estimated", "slices", "matching_scale"}
    assert cost["factor_ms"] > 0.0 and cost["iteration_ms"] > 0.0 and cost["slices"] == 1
    assert cost["measured"] == pytest.approx(cost["factor_ms"] / cost["iteration_ms"])
    assert cost["estimated"] > 1.0
    assert cost["matching_scale"] == pytest.approx(cost["measured"] / cost["estimated"])  # scale 1 here
    assert bench.main(["--json", "--steps", "2", "--mesh", "coarse", "--scenario", "free"]) == 0
    plain = json.loads(capsys.readouterr().out)[0]
    assert "stages" not in plain and "factor_cost" not in plain
    assert bench.main(["--profile", "--steps", "2", "--mesh", "coarse", "--scenario", "free"]) == 0
    text = capsys.readouterr().out
    assert "profile: free, coarse" in text and all(f" {n} " in text for n in stages)
    assert "CG iterations of" in text and "(estimated: " in text and "factor_cost_scale=" in text
    assert bench.main(["--profile", "--json", "--steps", "2", "--mesh", "coarse", "--scenario", "free",
                       "--preconditioner", "block_jacobi"]) == 0
    assert "factor_cost" not in json.loads(capsys.readouterr().out)[0]  # no factor to time


def test_bench_plot_draws_every_case(tmp_path, capsys):
    """`softhand bench --plot FILE.png` (implies --profile): the rows carry every step's time, the
    picture has a bar and a series per case, and it is not blank; a path that is not a PNG is
    refused before anything runs."""
    from PIL import Image

    from softhand_sim.commands.bench_plot import plot_profile

    out = tmp_path / "bench.png"
    assert bench.main(["--json", "--steps", "6", "--mesh", "coarse", "--scenario", "free", "--scenario", "press",
                       "--set", "factor_hold=0.5", "--plot", str(out)]) == 0
    captured = capsys.readouterr()
    rows = json.loads(captured.out)
    assert f"wrote {out}" in captured.err
    assert [len(r["step_ms"]) for r in rows] == [6, 6] and all("stages" in r for r in rows)
    assert all(min(r["step_ms"]) > 0.0 and np.median(r["step_ms"]) == pytest.approx(r["median_ms"]) for r in rows)
    pixels = np.asarray(Image.open(out).convert("L"), float)
    assert pixels.shape[1] > 1000 and pixels.std() > 10.0  # drawn, not an empty canvas
    labels = plot_profile(rows, tmp_path / "again.png")
    assert labels == ["free coarse, factor_hold=0.5", "press coarse, factor_hold=0.5"]
    with pytest.raises(SystemExit) as exc:
        bench.main(["--plot", str(tmp_path / "bench.svg")])
    assert exc.value.code == 2
    assert "--plot " in capsys.readouterr().err


def test_self_contact_model_follows_the_mesh_within_one_bench():
    """`softhand bench --scenario free_self` runs the coarse hand, then the fine one, with the same
    scenario object: each mesh gets the self-contact model of its own tets. (It kept the coarse
    one: the fine hand's skin points, embedded by the coarse tets' indices, lay inside other
    segments, 1,896 skin-skin contacts in free motion and CG at its 200-iteration cap.) The fine
    hand's free motion has no skin-skin contact, as when run alone."""
    coarse = bench.run("free_self", "coarse", 3, "factor")
    fine = bench.run("free_self", "fine", 3, "factor")
    assert coarse["self_contacts_median"] < 50 and fine["self_contacts_median"] == 0, (coarse, fine)
    assert fine["cg_hit_cap"] == 0, fine
    scenario = bench.SCENARIOS["free_self"]
    assert len({id(asset) for asset, _ in scenario._smodels.values()}) == len(scenario._smodels) >= 2


@pytest.mark.parametrize("argv, message", [
    (["--hands", "1,2", "--scenario", "free_self"], "--scenario free_self with --hands 2: the 2-hand scenarios are free, grasp, press"),
    (["--hands", "2", "--scenario", "fist"], "--scenario fist with --hands 2"),
    (["--hands", "3"], "--hands 3: expected 1 or 2"),
    (["--hands", "two"], "--hands 'two': expected 1, 2 or 1,2"),
])
def test_bench_refuses_a_case_it_has_not_before_running_any(argv, message, capsys):
    """A scenario without a two-hand version, or a hand count other than 1 and 2: exit 2 with the
    bad value named, before any case runs (`--hands 1,2 --scenario free_self` ran the one-hand
    case for a minute, then died of a KeyError)."""
    with pytest.raises(SystemExit) as exc:
        bench.main(["--mesh", "coarse", "--steps", "1", *argv])
    assert exc.value.code == 2
    captured = capsys.readouterr()
    assert message in captured.err and captured.out == ""
