"""The One Euro filter on the tracked joints (softhand_tracking.joint_filter) against its analytic
behaviour, and the adapter's use of it (relative to the wrist)."""
import math

import numpy as np
import pytest

from softhand_tracking.joint_filter import OneEuroJointFilter
from tests.tracking.test_adapter import _good_joints


def test_first_frame_passes_and_reset_forgets():
    f = OneEuroJointFilter()
    x = np.random.default_rng(0).normal(size=(26, 3))
    assert np.array_equal(f.filter(x, 1.0), x)
    f.filter(x + 1.0, 1.01)
    f.reset()
    assert np.array_equal(f.filter(x + 5.0, 2.0), x + 5.0)
    # a frame not after the last starts afresh from it, as after a reset
    assert np.array_equal(f.filter(x, 2.0), x)


def test_ramp_lags_by_the_time_constant_of_its_cutoff():
    """A joint moving at constant speed v: the exponential low-pass settles to a lag of exactly
    tau = 1 / (2 pi fc), fc = min_cutoff + beta * s. As in the authors' reference, the speed s is
    taken against the last filtered position, so it settles at v (1 + tau / dt): a fixed point,
    solved here apart from the filter."""
    dt, v, min_cutoff, beta = 0.01, 0.2, 1.0, 30.0  # 100 Hz frames, 0.2 m/s along a diagonal
    direction = np.array([1.0, 2.0, 2.0]) / 3.0
    f = OneEuroJointFilter(min_cutoff=min_cutoff, beta=beta)
    for k in range(400):
        t = k * dt
        out = f.filter((v * t * direction)[None, :], t)
    tau = 0.0
    for _ in range(200):
        tau = 1.0 / (2.0 * math.pi * (min_cutoff + beta * v * (1.0 + tau / dt)))
    lag_s = np.linalg.norm(v * t * direction - out[0]) / v
    assert abs(lag_s - tau) < 1e-6, (lag_s, tau)


def test_still_joint_jitter_is_smoothed_by_the_min_cutoff():
    """1.5 mm of white noise on a still joint at 100 Hz: the output's spread falls to what a 1 Hz
    first-order low-pass leaves, sqrt(alpha / (2 - alpha)) of it, within the speed term's opening."""
    rng = np.random.default_rng(1)
    noise = rng.normal(scale=0.0015, size=(3000, 26, 3))
    f = OneEuroJointFilter(min_cutoff=1.0, beta=0.0)
    out = np.array([f.filter(x, 0.01 * k) for k, x in enumerate(noise)])[500:]
    alpha = 1.0 / (1.0 + 1.0 / (2.0 * math.pi * 1.0 * 0.01))
    expect = 0.0015 * math.sqrt(alpha / (2.0 - alpha))
    assert abs(out.std() / expect - 1.0) < 0.1, (out.std(), expect)
    g = OneEuroJointFilter(min_cutoff=1.0, beta=30.0)  # the speed term opens the cutoff a little
    out_b = np.array([g.filter(x, 0.01 * k) for k, x in enumerate(noise)])[500:]
    assert expect < out_b.std() < 0.3 * 0.0015, out_b.std()


@pytest.mark.parametrize("kwargs, name", [({"min_cutoff": 0.0}, "min_cutoff"), ({"beta": -1.0}, "beta"),
                                          ({"min_cutoff": float("nan")}, "min_cutoff")])
def test_bad_settings_name_the_value(kwargs, name):
    with pytest.raises(ValueError, match=name):
        OneEuroJointFilter(**kwargs)


def _hand():
    return _good_joints()[:, :3]  # the adapter tests' hand


def test_adapter_filters_relative_to_the_wrist():
    """Through the adapter (tracking_node's parameters): a still hand carried at 0.5 m/s comes out
    exactly as it went in (its travel is never delayed), while jitter of the joints against each
    other is smoothed; a rejected frame never enters the filter."""
    from softhand_sim.params import load_params
    from softhand_tracking.adapter import bone_frames, tracker_adapter

    p = load_params("tracking_node", None, {"joint_filter": "one_euro"})
    hand = _hand()
    a = tracker_adapter(p, "right")
    for k in range(50):
        t = 0.01 * k
        moved = hand + np.array([0.5 * t, 0.0, 0.0])
        poses = a.convert(moved, t)
    assert np.allclose(poses, bone_frames(moved, "right"), atol=1e-9)
    rng = np.random.default_rng(2)
    b = tracker_adapter(p, "right")
    tips, raw = [], []
    for k in range(300):
        noisy = hand + rng.normal(scale=0.0015, size=hand.shape)
        noisy[1] = hand[1]  # the wrist still: only the joints' jitter against it
        if k == 150:
            assert b.convert(noisy * np.nan, 0.01 * k) is None  # rejected: counted, not filtered
        out = b.convert(noisy, 0.01 * k)
        tips.append(out[15, :3])
        raw.append(bone_frames(noisy, "right")[15, :3])
    assert b.rejected["non_finite"] == 1
    assert np.std(tips[100:], axis=0).max() < 0.3 * np.std(raw[100:], axis=0).max()


def test_loop_starts_the_filter_afresh_after_a_dropout():
    """A hand that comes back after a dropout (the loop held its last target) is taken as it is,
    not blended with where it was before."""
    from softhand_sim.params import load_params
    from softhand_tracking.adapter import bone_frames, tracker_adapter
    from softhand_tracking.loop import TrackingLoop

    p = load_params("tracking_node", None, {"joint_filter": "one_euro"})
    loop = TrackingLoop(adapter=tracker_adapter(p, "right"), tracker_timeout=0.1)
    hand = _hand()
    bent = hand.copy()
    bent[2:] += 0.02  # every finger joint 2 cm away from the wrist's old relation
    for k in range(20):
        loop.on_tracker(hand, 0.01 * k)
        loop.step(0.01 * k)
    loop.step(0.5)  # 0.3 s without a frame: holding
    assert loop.holding
    loop.on_tracker(bent, 0.51)
    assert np.allclose(loop.tracked, bone_frames(bent, "right"), atol=1e-9)
