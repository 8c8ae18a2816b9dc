"""Hand measures fitted from tracker frames (softhand_sim.handmodel.fit, `softhand calibrate`).

Synthetic hands: the kinematic hand (handmodel.kinematics.forward_kinematics) built at known
measures of a small (~16 cm) and a large (~21 cm) hand with per-bone ratios, knuckle layout and
thumb CMC unlike the default's, in random poses, with 2 mm position noise and outlier frames.
Real hands: the two Leap Motion recordings in bags/.
"""
import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from softhand_sim.handmodel.fit import fit_measures, hand_length
from softhand_sim.handmodel.kinematics import DIGIT_LIMITS, HandDims, forward_kinematics
from softhand_sim.handmodel.measures import HandMeasures, read_measures_file
from softhand_sim.handmodel.skeleton import finger_base_layout, thumb_layout
from softhand_sim.physics.rotations import quat_exp

REPO = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent  # the venv's console scripts
FINGERS = ("thumb", "index", "middle", "ring", "little")


def scaled_hand(scale, seed):
    """Default measures scaled by `scale`, each bone by a further random ratio in [0.9, 1.1], the
    knuckle row and thumb CMC moved off the default layout."""
    rng = np.random.default_rng(seed)
    d = HandMeasures()
    lengths = {f + "_lengths": tuple(scale * v * rng.uniform(0.9, 1.1) for v in d.finger_lengths(f)) for f in FINGERS}
    widths = {f + "_width": scale * d.finger_width(f) for f in FINGERS}
    return replace(d, palm_length=scale * d.palm_length * rng.uniform(0.9, 1.1), palm_width=scale * d.palm_width,
                   palm_thickness=scale * d.palm_thickness, knuckle_recess=(0.03, 0.07, 0.2),
                   knuckle_gaps=(1.15, 0.97, 0.88), thumb_cmc=(0.05, 1.3, -0.5), **lengths, **widths)


def synthetic_frames(m, seconds=1.5, rate=100.0, noise=0.002, outlier_every=10, seed=0):
    """(times [s], joints (n, 26, 7)) of the kinematic hand at measures m in random poses (palm
    anywhere in a 40 cm cube, any orientation, digit angles uniform within DIGIT_LIMITS), with
    Gaussian position noise of `noise` [m] per coordinate; every `outlier_every`-th frame is an
    outlier (one random joint thrown 2-6 cm, or the whole fingertip row swapped)."""
    rng = np.random.default_rng(seed)
    dims = HandDims.from_measures(m)
    times = np.arange(int(seconds * rate) + 1) / rate
    frames = []
    for k in range(len(times)):
        q = quat_exp(rng.normal(0.0, 1.5, 3))
        angles = rng.uniform(DIGIT_LIMITS[:, :, 0], DIGIT_LIMITS[:, :, 1])
        joints, _ = forward_kinematics(np.r_[rng.uniform(-0.2, 0.2, 3), q], angles, dims)
        joints[:, :3] += rng.normal(0.0, noise, (26, 3))
        if k % outlier_every == outlier_every - 1:
            if (k // outlier_every) % 2:
                j = rng.integers(26)
                joints[j, :3] += rng.choice([-1, 1]) * rng.uniform(0.02, 0.06) * np.eye(3)[rng.integers(3)]
            else:
                tips = [5, 10, 15, 20, 25]
                joints[tips, :3] = joints[np.roll(tips, 1), :3]
        frames.append(joints)
    return times, np.array(frames)


def truth_points(m):
    """Knuckles (4, 3) and thumb CMC (3,) of measures m in the palm frame [m]."""
    layout = finger_base_layout(m)
    return np.array([layout[f][0] for f in FINGERS[1:]]), thumb_layout(m)[0]


@pytest.mark.parametrize("noise,tol", [(0.0015, 0.001), (0.003, 0.002)])
@pytest.mark.parametrize("scale,seed", [(16.0 / 19.0, 1), (21.0 / 19.0, 2)])
def test_synthetic_hand_recovered(scale, seed, noise, tol):
    """Small and large hands, 1 s of frames with 10 % outlier frames: with fast_dropout's noise
    (1.5 mm per coordinate, 30 times the other sample bags') every bone length, knuckle and the CMC
    within 1 mm of the truth, with 3 mm noise within 2 mm. The outlier frames are rejected (at
    least 8 of the 10 in the window; a joint thrown that no measure reads, a finger METACARPAL,
    leaves its frame usable)."""
    truth = scaled_hand(scale, seed)
    times, joints = synthetic_frames(truth, noise=noise, seed=seed)
    result = fit_measures(times, joints, seconds=1.0)
    m = result.measures
    assert 0.15 <= hand_length(truth) <= 0.22
    assert result.window_s >= 1.0 - 1e-9
    assert result.frames_window - result.frames_used >= 8
    assert abs(m.palm_length - truth.palm_length) < tol
    for f in FINGERS:
        np.testing.assert_allclose(m.finger_lengths(f), truth.finger_lengths(f), atol=tol, err_msg=f)
    knuckles, cmc = truth_points(truth)
    got_knuckles, got_cmc = truth_points(m)
    np.testing.assert_allclose(got_knuckles[:, :2], knuckles[:, :2], atol=tol)
    np.testing.assert_allclose(got_cmc, cmc, atol=tol)
    np.testing.assert_allclose(result.knuckles, knuckles, atol=tol)


def test_outliers_do_not_bend_the_estimate():
    """A third of the frames broken (half of them with their fingertips swapped): the bones stay within
    1 mm; without outlier rejection the plain mean would be off by more than that."""
    truth = scaled_hand(1.0, 3)
    times, joints = synthetic_frames(truth, outlier_every=3, noise=0.0015, seed=3)
    m = fit_measures(times, joints).measures
    for f in FINGERS:
        np.testing.assert_allclose(m.finger_lengths(f), truth.finger_lengths(f), atol=0.001, err_msg=f)
    mean_index_distal = np.mean(np.linalg.norm(joints[:, 10, :3] - joints[:, 9, :3], axis=1))
    assert abs(mean_index_distal - truth.index_lengths[2]) > 0.002


def test_left_hand_mirrors():
    """A left hand (frames mirrored through the xz plane) gives the right hand's measures."""
    truth = scaled_hand(0.9, 4)
    times, joints = synthetic_frames(truth, outlier_every=1000, seed=4)
    left = joints.copy()
    left[:, :, 1] *= -1.0
    a = fit_measures(times, joints).measures
    b = fit_measures(times, left, hand="left").measures
    np.testing.assert_allclose(list(a.to_dict()["knuckle_gaps"]), list(b.to_dict()["knuckle_gaps"]), atol=1e-9)
    np.testing.assert_allclose(a.thumb_cmc, b.thumb_cmc, atol=1e-9)


def test_no_valid_frame_is_an_error():
    times, joints = synthetic_frames(HandMeasures(), seconds=0.1, outlier_every=1000)
    joints[:, 3, 0] = np.nan
    with pytest.raises(ValueError, match="valid"):
        fit_measures(times, joints)


def test_real_recordings_calibrate(tmp_path):
    """`softhand calibrate` on both Leap Motion recordings: plausible adult hands (15-17 cm wrist
    to middle tip, palm 6-8 cm long) of one shape: every bone length of one recording is the
    other's times one common factor within 0.5 %; the measures file reads back."""
    out = {}
    for bag in ("leap_grab", "leap_roll_pitch"):
        path = tmp_path / f"{bag}.yaml"
        proc = subprocess.run([str(BIN / "softhand"), "calibrate", str(REPO / "bags" / bag),
                               "--out", str(path), "--json"], capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stderr
        figures = json.loads(proc.stdout.strip().splitlines()[-1])
        m = read_measures_file(path)
        assert m.to_dict() == figures["measures"]
        assert 0.15 <= hand_length(m) <= 0.17, hand_length(m)
        assert 0.06 <= m.palm_length <= 0.08
        assert figures["frames_used"] >= 100 and figures["window_s"] >= 1.0
        out[bag] = np.array(figures["bone_lengths_mm"])
    ratio = out["leap_roll_pitch"] / out["leap_grab"]
    assert np.all(np.abs(ratio / np.median(ratio) - 1.0) < 0.005), ratio
