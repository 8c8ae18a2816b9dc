"""hand_measures auto without ROS (softhand_sim.hand_sizer): the first tracked second of a bag is
fitted, the hand made in a worker thread while the caller goes on, handed over once; the
runtime's /diagnostics values name the measures in use and their source."""
import threading

import numpy as np
import pytest

from softhand_sim.commands.offline import read_frames
from softhand_sim.hand_sizer import HandSizer, handover, measures_diagnostics, tracker_topic
from softhand_sim.handmodel.fit import fit_measures, hand_length
from softhand_sim.handmodel.measures import HandMeasures
from softhand_sim.params import load_params
from softhand_sim.runtime import SimRuntime
from softhand_sim.scenarios.tracker_bags import SMALL_HAND


@pytest.fixture(scope="module")
def small_bag():
    return read_frames("small_hand")


def feed(sizer, times, joints):
    """Frames in order until the sizer stops collecting; the time of the last frame fed."""
    for t, j in zip(times, joints):
        sizer.add_frame(t, j)
        if sizer.state != "collecting":
            return t
    return None


def test_first_second_fitted_in_a_worker(small_bag):
    """Collecting stops at the first frame 1 s after the first valid one; make() runs in another
    thread on the measures `softhand calibrate` would give; poll() hands its product over once."""
    times, joints = small_bag
    threads = []

    def make(m):
        threads.append(threading.get_ident())
        return ("hand", m)

    sizer = HandSizer(make)
    assert sizer.diagnostics() == {"hand_measures_source": "auto", "hand_size_state": "collecting",
                                   "hand_size_frames": 0}
    t_end = feed(sizer, times, joints)
    assert times[0] + 1.0 <= t_end < times[0] + 1.1
    assert sizer.wait(60) == "ready" and threads and threads[0] != threading.get_ident()
    kind, m = sizer.poll()
    assert kind == "hand" and sizer.poll() is None and sizer.done
    assert m == fit_measures(times, joints, seconds=1.0).measures
    for f in ("thumb", "index", "middle", "ring", "little"):  # the synthetic small hand, within 2 mm per bone
        np.testing.assert_allclose(m.finger_lengths(f), SMALL_HAND.finger_lengths(f), atol=0.002)
    d = sizer.diagnostics()
    assert d["hand_measures_source"] == "auto" and abs(d["hand_length_mm"] - 1e3 * hand_length(SMALL_HAND)) < 3.0
    sizer.add_frame(times[-1], joints[-1])  # after the window: ignored
    assert sizer.frames == 0


def test_invalid_frames_do_not_count(small_bag):
    """NaN frames neither start the window nor count toward it."""
    times, joints = small_bag
    sizer = HandSizer(lambda m: m)
    bad = np.full_like(joints[0], np.nan)
    for t in np.arange(-3.0, 0.0, 0.1):
        sizer.add_frame(t, bad)
    assert sizer.frames == 0 and sizer.state == "collecting"
    assert times[0] + 1.0 <= feed(sizer, times, joints) < times[0] + 1.1
    sizer.wait(60)


def test_failure_keeps_the_default_hand(small_bag):
    times, joints = small_bag

    def make(m):
        raise RuntimeError("no hand today")

    sizer = HandSizer(make)
    feed(sizer, times, joints)
    assert sizer.wait(60) == "failed" and sizer.done and sizer.poll() is None
    d = sizer.diagnostics()
    assert d["hand_measures_source"] == "default" and "no hand today" in d["hand_size_error"]
    assert "keeping the default hand" in sizer.describe()


def test_topic_and_side():
    assert tracker_topic("right") == "/tracker/right/hand_joints"  # each side's own frames
    assert tracker_topic("left") == "/tracker/left/hand_joints"
    with pytest.raises(ValueError, match="side"):
        HandSizer(lambda m: m, side="both")


def test_runtime_reports_its_measures_and_takes_over(small_bag):
    """A runtime made for `auto` (the morphed small hand) reports source auto and its size;
    handover() gives it the old runtime's latest bone targets, which place the new hand."""
    params = load_params("sim_node")
    old = SimRuntime(params)
    assert {k: old.diagnostics()[k] for k in ("hand_measures_source", "hand_length_mm")} == {
        "hand_measures_source": "default", "hand_length_mm": 190.0}
    new = SimRuntime(params, scene=old.scene, measures=SMALL_HAND, measures_source="auto")
    assert new.diagnostics()["hand_length_mm"] == round(hand_length(SMALL_HAND) * 1e3, 1)
    assert new.diagnostics()["hand_measures_source"] == "auto"
    assert new.asset.build_info["method"] in ("morph", "build") and new.measures == SMALL_HAND
    targets = new.model.body_rest_pose[:16].copy()
    targets[:, 0] += 0.3
    old.set_bone_targets(targets, 12.5)
    handover(old, new)
    assert new.placed and new.bone_target_stamp == 12.5
    np.testing.assert_allclose(new.state.bone_pose[0], targets[0], atol=1e-9)
    assert new.step(1.0 / 60.0, 0.0) is not None
    assert measures_diagnostics(HandMeasures(), "file")["palm_width_mm"] == 85.0
