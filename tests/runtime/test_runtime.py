"""SimRuntime (what sim_node runs, without ROS): placement, guard, bad input, teleports, copies."""
import numpy as np
import pytest

from softhand_sim.params import load_params
from softhand_sim.runtime import SimRuntime

DT = 1.0 / 60.0


@pytest.fixture(scope="module")
def params():
    return load_params("sim_node")


@pytest.fixture
def runtime(params):
    return SimRuntime(params)


def hover_targets(rt, z=0.95):
    """The rest skeleton moved up to hover well above the table (no contact)."""
    poses = rt.model.body_rest_pose[:16].copy()
    poses[:, 2] += z
    return poses


def test_waits_for_targets_then_places_hand(runtime):
    """No step before the first bone target; the first target places the palm exactly there."""
    assert runtime.step(DT, 0.0) is None
    targets = hover_targets(runtime)
    runtime.set_bone_targets(targets)
    assert np.allclose(runtime.state.bone_pose[0], targets[0], atol=1e-9)
    out = runtime.step(DT, 0.0)
    assert out is not None and not out.rejected
    assert np.all(np.isfinite(out.skin_vertices))
    assert out.skin_vertices[:, 2].min() > 0.85  # the whole skin moved up with the palm


@pytest.mark.parametrize("bad, words", [
    (np.full((16, 7), np.nan), "non-finite"),
    (np.zeros((15, 7)), "shape"),
    (np.zeros((16, 7)), "unit"),  # zero quaternions
])
def test_bad_bone_targets_refused(runtime, bad, words):
    """Malformed intermediate bones raise ValueError naming the problem; the last good target stays."""
    good = hover_targets(runtime)
    runtime.set_bone_targets(good)
    with pytest.raises(ValueError, match=words):
        runtime.set_bone_targets(bad)
    assert np.array_equal(runtime.bone_targets, good)


def test_guard_rejects_diverged_step_and_restores(runtime):
    """A non-finite state after a step is rejected: the last good state is restored and reported."""
    runtime.set_bone_targets(hover_targets(runtime))
    for i in range(3):
        good = runtime.step(DT, i * DT)
    before = runtime.state.node_x.copy()
    runtime.state.v[5] = np.nan  # what a diverged solve leaves behind
    out = runtime.step(DT, 3 * DT)
    assert out.rejected and "non-finite" in out.warning
    assert np.array_equal(runtime.state.node_x, before)
    assert np.all(np.isfinite(out.skin_vertices)) and np.all(np.isfinite(out.bone_poses))
    assert runtime.diagnostics()["rejected_steps"] == 1
    assert not runtime.step(DT, 4 * DT).rejected and good is not None


def test_teleport_of_the_target_stays_bounded(runtime, params):
    """A 1 m jump of the targets: the hand's kinetic energy never exceeds the energy the palm
    spring received, 1/2 kx d^2 (backward Euler only dissipates), nothing diverges (Sect. 3.6)."""
    targets = hover_targets(runtime)
    runtime.set_bone_targets(targets)
    for i in range(10):
        runtime.step(DT, i * DT)
    jump = 1.0
    jumped = targets.copy()
    jumped[:, 0] += jump
    runtime.set_bone_targets(jumped)
    spring_energy = 0.5 * params["tracking_kx"] * jump ** 2
    peak = 0.0
    for i in range(10, 130):
        out = runtime.step(DT, i * DT)
        assert np.all(np.isfinite(out.bone_poses)) and not out.rejected
        peak = max(peak, runtime.solver.kinetic_energy(runtime.state))
    assert 0.0 < peak <= spring_energy * 1.01, (peak, spring_energy)
    # and the palm has moved most of the way toward the new target after 2 s
    assert runtime.state.bone_pose[0, 0] - targets[0, 0] > 0.5


def test_object_copies_validated_and_followed(runtime):
    """Unknown objects and non-finite copies are rejected; a valid copy pulls the hand-side object."""
    runtime.set_bone_targets(hover_targets(runtime))
    names = runtime.object_names
    i = names.index("ball")
    pose = runtime.scene.object("ball").pose.copy()
    errors = runtime.set_object_copies(["nope"], pose[None], np.zeros((1, 6)), np.zeros((1, 6)), 0.0)
    assert errors and "nope" in errors[0]
    bad = pose.copy()
    bad[0] = np.inf
    errors = runtime.set_object_copies(["ball"], bad[None], np.zeros((1, 6)), np.zeros((1, 6)), 0.0)
    assert errors and "non-finite" in errors[0]
    moved = pose.copy()
    moved[0] += 0.02
    t = 0.0
    for k in range(90):
        runtime.set_object_copies(["ball"], moved[None], np.zeros((1, 6)), np.zeros((1, 6)), t)
        out = runtime.step(DT, t)
        t += DT
    assert abs(out.object_poses[i, 0] - moved[0]) < 0.005


def test_warm_up_leaves_the_runtime_as_it_was(runtime):
    """warm_up (compiling every step kernel before the node publishes) changes no state."""
    before = runtime.state.copy()
    runtime.warm_up(DT)
    assert runtime.step(DT, 0.0) is None and not runtime.placed and runtime.steps == 0
    assert np.array_equal(runtime.state.node_x, before.node_x)
    assert np.array_equal(runtime.state.body_pose, before.body_pose)
    runtime.set_bone_targets(hover_targets(runtime))
    out = runtime.step(DT, 0.0)
    assert not out.rejected and runtime.diagnostics()["rejected_steps"] == 0
