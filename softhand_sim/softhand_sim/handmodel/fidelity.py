"""Fidelity of the simulated hand to the tracked hand: position and direction errors (no ROS).

    from softhand_sim.handmodel.fidelity import fidelity
    report = fidelity(track_t, track_joints, sim_t, sim_bones, bone_length)

Inputs: tracked joints (n, 26, 3|7) [m] at capture times track_t (n,) [s]; simulated bone poses
(k, 16, 7) [m, quat x y z w] at state times sim_t (k,) [s], same clock; the simulated hand's bone
lengths (16,) [m] (HandAsset.bone_length) to place its fingertips. Each simulated state is
compared with the latest tracked frame captured at or before its time (so the pipeline's lag
counts as error, as a user would see it); states before the first frame are skipped.

Figures (positions in mm, angles in degrees; each as median and p95 over states and points):
* palm: simulated palm origin vs tracked WRIST;
* knuckles: simulated proximal-phalanx origins vs tracked F_PROXIMAL (4 fingers) and the thumb
  metacarpal origin vs THUMB_METACARPAL (5 points);
* fingertips: simulated distal bone origin + its length along +x vs tracked F_TIP (5 points);
* phalanx direction: angle between each simulated digit bone's +x and the tracked segment (15);
* thumb-index gap: |thumb tip - index tip| tracked and simulated; for states whose tracked gap
  is below PINCH_GAP the difference simulated - tracked (median, p95 of its magnitude, max);
* held pose: at the states at which the tracked hand has been still for HELD_S (`_still`: the
  joints within HELD_M of their mean over that window), the angle between the simulated phalanx
  directions averaged over the window and the tracked ones averaged over it (`held_states`,
  `held_phalanx_deg`): what is left once the hand has settled, e.g. an offset the feedback to the
  simulated hand leaves. Both sides are averaged because a hand that follows its tracker also
  follows the tracker's noise: on the Leap recording leap_roll_pitch the tracked directions
  themselves lie 0.84 deg (median) from their window's mean, the simulated ones 0.1-0.2 deg from
  the tracked ones of the same instant. `held_phalanx_noisy_deg` keeps the state itself against
  the tracked mean (that noise included);
* tracker noise (`tracker_noise_mm`, of the input alone): the white noise per joint coordinate
  from frame to frame (`tracker_noise`), to read the other figures by: a simulated hand follows
  that noise, and the errors and lags of a noisy input are partly its.
"""
from __future__ import annotations

import numpy as np

from softhand_sim.physics.rotations import quat_to_matrix
from softhand_sim.handmodel.skeleton_names import BONE_SEGMENTS, JOINT_INDEX

PINCH_GAP = 0.015  # [m] tracked thumb-index tip gaps below this count as a pinch
HELD_S = 0.3       # [s] the tracked hand still for this long ...
HELD_M = 0.006     # [m] ... every joint within this of its mean (1.5 mm tracker noise stays inside)
HELD_MIN_FRAMES = 10
_DIGIT_FIRST = (1, 4, 7, 10, 13)
_DISTAL = (3, 6, 9, 12, 15)
_TIPS = [JOINT_INDEX[d + "_TIP"] for d in ("THUMB", "INDEX", "MIDDLE", "RING", "LITTLE")]
_BASES = [JOINT_INDEX["THUMB_METACARPAL"]] + [JOINT_INDEX[f + "_PROXIMAL"] for f in ("INDEX", "MIDDLE", "RING", "LITTLE")]


def _stats(values_mm) -> dict:
    v = np.asarray(values_mm, dtype=np.float64).reshape(-1)
    if v.size == 0:
        return dict(median=None, p95=None, max=None)
    return dict(median=round(float(np.median(v)), 2), p95=round(float(np.percentile(v, 95)), 2),
                max=round(float(v.max()), 2))


def _still(window: np.ndarray) -> bool:
    """Tracked joints (m, 26, 3) held still: no joint's mean moved HELD_M / 2 from the window's
    first half to its second, and 95 % of the joints' positions within HELD_M of their mean
    (single noisy frames may stray further)."""
    half = len(window) // 2
    drift = np.linalg.norm(window[half:].mean(axis=0) - window[:half].mean(axis=0), axis=1).max()
    spread = np.percentile(np.linalg.norm(window - window.mean(axis=0), axis=2), 95)
    return bool(drift < 0.5 * HELD_M and spread < HELD_M)


def tracker_noise(track_joints) -> float:
    """Std [m] of the white noise per coordinate of the tracked joints (n, 26, 3|7), frame to
    frame: the second difference of a white noise of std s has std s sqrt(6); taken robustly
    (1.4826 x the median absolute deviation over the frames) per joint and coordinate, then the
    median of those. Smooth motion adds its own second differences (a dt^2: 0.1 mm for 1 m/s^2 at
    100 Hz), so on a real recording this is an upper bound. NaN for fewer than 3 frames."""
    j = np.asarray(track_joints, dtype=np.float64)[:, :, :3]
    if len(j) < 3:
        return float("nan")
    d2 = j[2:] - 2.0 * j[1:-1] + j[:-2]
    mad = np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0)
    return float(np.median(1.4826 * mad) / np.sqrt(6.0))


def simulated_points(bones: np.ndarray, bone_length: np.ndarray):
    """Palm origin (3,), digit bases (5, 3), fingertips (5, 3) and bone x axes (16, 3) of one
    simulated state bones (16, 7)."""
    rot = np.array([quat_to_matrix(np.ascontiguousarray(b[3:])) for b in bones])
    x = rot[:, :, 0]
    tips = np.array([bones[b, :3] + bone_length[b] * x[b] for b in _DISTAL])
    return bones[0, :3], bones[list(_DIGIT_FIRST), :3], tips, x


def fidelity(track_t, track_joints, sim_t, sim_bones, bone_length) -> dict:
    """The figures of the module docstring as a JSON-friendly dict."""
    track_t = np.asarray(track_t, dtype=np.float64)
    joints = np.asarray(track_joints, dtype=np.float64)[:, :, :3]
    sim_t = np.asarray(sim_t, dtype=np.float64)
    bone_length = np.asarray(bone_length, dtype=np.float64)
    idx = np.searchsorted(track_t, sim_t + 1e-9, side="right") - 1
    palm, base, tip, direction, gap_t, gap_s, held, held_noisy = [], [], [], [], [], [], [], []
    xs = np.zeros((len(sim_t), len(BONE_SEGMENTS) - 1, 3))  # simulated phalanx directions per state
    seg_p = np.array([s[0] for s in BONE_SEGMENTS[1:]])
    seg_d = np.array([s[1] for s in BONE_SEGMENTS[1:]])
    segs = joints[:, seg_d] - joints[:, seg_p]
    segs /= np.linalg.norm(segs, axis=2, keepdims=True)
    for k in np.nonzero(idx >= 0)[0]:
        j = joints[idx[k]]
        p0, bases, tips, x = simulated_points(np.asarray(sim_bones[k], dtype=np.float64), bone_length)
        xs[k] = x[1:]
        palm.append(np.linalg.norm(p0 - j[JOINT_INDEX["WRIST"]]))
        base.append(np.linalg.norm(bases - j[_BASES], axis=1))
        tip.append(np.linalg.norm(tips - j[_TIPS], axis=1))
        seg = j[seg_d] - j[seg_p]
        seg /= np.linalg.norm(seg, axis=1, keepdims=True)
        direction.append(np.degrees(np.arccos(np.clip(np.sum(seg * x[1:], axis=1), -1.0, 1.0))))
        w0 = np.searchsorted(track_t, track_t[idx[k]] - HELD_S, side="left")
        window = joints[w0:idx[k] + 1]
        if (len(window) >= HELD_MIN_FRAMES and track_t[idx[k]] - track_t[w0] >= 0.9 * HELD_S
                and _still(window)):
            mean = segs[w0:idx[k] + 1].mean(axis=0)
            mean /= np.linalg.norm(mean, axis=1, keepdims=True)
            s0 = np.searchsorted(sim_t, track_t[w0], side="left")  # the simulated states of the window
            sim_mean = xs[s0:k + 1].mean(axis=0)
            sim_mean /= np.linalg.norm(sim_mean, axis=1, keepdims=True)
            held.append(np.degrees(np.arccos(np.clip(np.sum(mean * sim_mean, axis=1), -1.0, 1.0))))
            held_noisy.append(np.degrees(np.arccos(np.clip(np.sum(mean * x[1:], axis=1), -1.0, 1.0))))
        gap_t.append(np.linalg.norm(j[_TIPS[0]] - j[_TIPS[1]]))
        gap_s.append(np.linalg.norm(tips[0] - tips[1]))
    gap_t, gap_s = np.array(gap_t), np.array(gap_s)
    pinch = gap_t < PINCH_GAP
    return dict(
        states=int(len(palm)),
        palm_mm=_stats(np.array(palm) * 1e3),
        knuckle_mm=_stats(np.array(base) * 1e3),
        fingertip_mm=_stats(np.array(tip) * 1e3),
        fingertip_per_digit_median_mm=np.round(np.median(np.array(tip), axis=0) * 1e3, 1).tolist() if tip else None,
        phalanx_direction_deg=_stats(direction),
        thumb_index_gap_tracked_min_mm=round(float(gap_t.min()) * 1e3, 1) if len(gap_t) else None,
        thumb_index_gap_sim_min_mm=round(float(gap_s.min()) * 1e3, 1) if len(gap_s) else None,
        pinch_states=int(pinch.sum()),
        pinch_gap_error_mm=_stats(np.abs(gap_s[pinch] - gap_t[pinch]) * 1e3),
        pinch_gap_sim_minus_tracked_median_mm=(round(float(np.median(gap_s[pinch] - gap_t[pinch])) * 1e3, 1)
                                               if pinch.any() else None),
        held_states=len(held),
        held_phalanx_deg=_stats(held),
        held_phalanx_noisy_deg=_stats(held_noisy),
        tracker_noise_mm=round(tracker_noise(joints) * 1e3, 3),
    )
