"""LiveLag (softhand_sim/live_lag.py): the lags record_node reports in /diagnostics, on
a motion with known, injected delays (the lag tests' motion: grasp_short's cage, tracked at 100 Hz,
an intermediate layer 8 ms behind at 250 Hz and a simulated one 30 ms behind at 150 Hz, one
hand's sim rate), fed in arrival order as the node gets them."""

import numpy as np
import pytest

from softhand_sim.handmodel.kinematics import forward_kinematics
from softhand_sim.scenarios import tracker_bags
from softhand_tracking.adapter import TrackerAdapter
from softhand_sim.live_lag import LAYER_HZ, WINDOW_S, LiveLag


def feed(lag, motion, t_from, t_to, delays=(0.008, 0.030), asked=None):
    adapter = TrackerAdapter()

    def joints(t):
        return forward_kinematics(*motion(float(np.clip(t, 0.0, motion.duration))))[0]

    events = [(t, "tracked", t) for t in np.arange(t_from, t_to, 0.01)]
    events += [(t, "intermediate", t - delays[0]) for t in np.arange(t_from, t_to, 1 / 250)]
    events += [(t, "sim", t - delays[1]) for t in np.arange(t_from, t_to, 1 / 150)]
    for t, layer, t_motion in sorted(events, key=lambda e: e[0]):
        if asked is not None:  # what `wants` said, and whether add() then kept the sample
            wanted = lag.wants(layer, t)
        if layer == "tracked":
            lag.add_frame(t, joints(t_motion))
        else:
            lag.add(layer, t, adapter.convert(joints(t_motion)[:, :3]))
        if asked is not None:
            buf = lag._data[layer]
            asked.append((layer, wanted, bool(buf) and buf[-1][0] == t))


def test_injected_delays_are_reported_within_a_millisecond():
    """While the digits close on the ball (grasp_short, 2.2-4.2 s), the last 2 s give the
    intermediate layer's 8 ms and the simulated hand's 30 ms within 1 ms. (What a report costs is
    not timed here: a timed test fails on a loaded machine, as this one did at 0.102 s against
    0.1; record_node makes one per second.)"""
    motion = tracker_bags.grasp_short()
    lag, asked = LiveLag(), []
    feed(lag, motion, 1.0, 4.2, asked=asked)
    # the recorder skips a message `wants` refuses before parsing it: it refuses exactly what
    # add() would drop, and thins both layers to LAYER_HZ (the tracked frames all kept)
    assert all(wanted == kept for _layer, wanted, kept in asked)
    for layer in ("intermediate", "sim"):
        steps = np.diff([t for t, _ in lag._data[layer]])
        assert steps.min() >= 1 / LAYER_HZ - 1e-9 and steps.max() < 1 / LAYER_HZ + 1 / 150, layer
    assert all(wanted for layer, wanted, _kept in asked if layer == "tracked")
    r = lag.report()
    assert r["intermediate_lag_ms"] == pytest.approx(8.0, abs=1.0), r
    assert r["sim_lag_ms"] == pytest.approx(30.0, abs=1.0), r


def test_a_still_hand_has_no_lag_to_report():
    """A hand held still (grasp_short's first keyframe) for the whole window: NaN, not a number
    made up from noise; the window keeps only the last WINDOW_S."""
    motion = tracker_bags.Keyframes().add(0.0, [0.0, 0.0, 1.0], 0.2).add(10.0, [0.0, 0.0, 1.0], 0.2)
    lag = LiveLag()
    feed(lag, motion, 0.0, 3.0)
    r = lag.report()
    assert all(np.isnan(v) for v in r.values()), r
    times = [t for t, _ in lag._data["tracked"]]
    assert times[-1] - times[0] <= WINDOW_S
    steps = np.diff([t for t, _ in lag._data["intermediate"]])
    assert steps.min() >= 1 / LAYER_HZ - 1e-9  # the 250 Hz layer kept at 60 Hz


def test_two_hands_are_reported_in_turn_each_with_its_own_lag():
    """HandLags, as record_node uses it: one hand's report per call, the hands heard from taking
    turns in sorted order (left, right), each report that hand's own injected delays (the right
    hand's layers 8 / 30 ms behind, the left's 12 / 45 ms); nothing before a hand is heard from."""
    from softhand_sim.live_lag import HandLags

    motion = tracker_bags.grasp_short()
    lags = HandLags(("right", "left"))
    assert lags.report_next() is None
    feed(lags["right"], motion, 1.0, 4.2)
    lags.heard_from("right")
    side, r = lags.report_next()
    assert side == "right" and r["sim_lag_ms"] == pytest.approx(30.0, abs=1.0), r
    feed(lags["left"], motion, 1.0, 4.2, delays=(0.012, 0.045))
    lags.heard_from("left")
    turns = [lags.report_next() for _ in range(4)]
    assert [side for side, _ in turns] == ["right", "left", "right", "left"]
    for side, r in turns:
        want = (8.0, 30.0) if side == "right" else (12.0, 45.0)
        assert (r["intermediate_lag_ms"], r["sim_lag_ms"]) == pytest.approx(want, abs=1.0), (side, r)
