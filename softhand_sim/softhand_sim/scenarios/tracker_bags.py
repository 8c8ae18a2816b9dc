"""Deterministic synthetic tracker recordings for bags/ (tools/make_bags.py writes them).

A kinematic right hand (`kinematic_hand`, default dimensions) is driven by keyframed palm poses
and per digit a closure value (mapped to joint angles inside `DIGIT_LIMITS`) or explicit angles. The 26
OpenXR joints are sampled at the tracker's rate with timing jitter and white position noise, as a
real optical tracker reports them (POSITION_NOISE, a Leap recording's; fast_dropout 30 times it).
Placed in the default scene (config/scene.yaml): table top z = 0.75, ball r = 0.04 at (0, 0, 0.79).

The grasp bags (grasp_lift, grasp_short, squeeze) use a caging grasp (`cage_palm_pose`,
`cage_angles`, see the block comment above them): digits pre-shaped open over the ball, closed
until their pads touch the ball below its equator all around it, then squeezed deeper, and only
then lifted. `digit_depths` / `closure_for_depth` measure (or search) how deep each digit's bone
capsules (radius DIGIT_RADIUS) go into the ball for a closure.

The pinch bag (pinch_lift) uses the thumb-index pinch of softhand_sim.scenarios.contact.

The hand-size bags (small_hand, large_hand) move a hand of another size (SMALL_HAND, LARGE_HAND:
16 and 21 cm wrist to middle tip) through open, pinch and fist above the table, for calibration
and fidelity checks of fitted hands.

Scenarios (name -> Scenario): grasp_lift, squeeze, press_table, fast_dropout, grasp_short,
pinch_lift, small_hand, large_hand.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from softhand_sim.physics.rotations import quat_conj, quat_exp, quat_log, quat_mul, quat_to_matrix

from softhand_sim.scenarios.contact import PINCH_BALL_IN_PALM, pinch_angles, smoothstep
from softhand_sim.handmodel.kinematics import DIGIT_LIMITS, HandDims, forward_kinematics
from softhand_sim.handmodel.measures import HandMeasures, scale_measures

BALL_CENTER = np.array([0.0, 0.0, 0.79])   # [m] config/scene.yaml
BALL_RADIUS = 0.04                           # [m]
TABLE_TOP = 0.75                             # [m]
DIGIT_RADIUS = 0.009    # [m] half thickness of a digit around its bone axis (contact depth)
PALM_VENTRAL = 0.015    # [m] palm bone axis -> palm skin, ventral side
PALM_DOWN = np.array([0.0, 0.0, 0.0, 1.0])  # palm frame = world axes: fingers +x, dorsal +z
STAMP0_NS = 1_735_689_600_000_000_000     # 2025-01-01T00:00:00Z: fixed, so bags are reproducible

# Digit angles (abduction, flex_1, flex_2, flex_3) [rad] of the open hand and of a full fist.
OPEN_ANGLES = np.deg2rad(np.array([
    [0, 0, 5, 5], [-8, 5, 5, 3], [0, 5, 5, 3], [6, 5, 5, 3], [12, 5, 5, 3]], dtype=float))
CLOSED_ANGLES = np.deg2rad(np.array([
    [34, 20, 50, 70], [0, 85, 100, 75], [0, 85, 100, 75], [0, 85, 100, 75], [0, 85, 100, 75]], dtype=float))
assert np.all(OPEN_ANGLES >= DIGIT_LIMITS[:, :, 0]) and np.all(CLOSED_ANGLES <= DIGIT_LIMITS[:, :, 1])


def digit_angles(closure) -> np.ndarray:
    """(5, 4) joint angles [rad] for closures (5,) in [0, 1] (0 open, 1 fist), within limits."""
    c = np.clip(np.asarray(closure, dtype=np.float64), 0.0, 1.0)[:, None]
    return OPEN_ANGLES + c * (CLOSED_ANGLES - OPEN_ANGLES)


def _segment_distance(p, a, b):
    ab = b - a
    t = np.clip(np.dot(p - a, ab) / np.dot(ab, ab), 0.0, 1.0)
    return np.linalg.norm(p - (a + t * ab))


def digit_depths(palm_pose, closure, center=BALL_CENTER, radius=BALL_RADIUS) -> np.ndarray:
    """(5,) depth [m] of each digit inside the ball: r + DIGIT_RADIUS - distance of its bones."""
    joints, bones = forward_kinematics(palm_pose, digit_angles(closure))
    out = np.empty(5)
    tips = (5, 10, 15, 20, 25)
    for d in range(5):
        b0 = 1 + 3 * d
        pts = [bones[b0 + k, :3] for k in range(3)] + [joints[tips[d], :3]]
        dist = min(_segment_distance(center, pts[k], pts[k + 1]) for k in range(3))
        out[d] = radius + DIGIT_RADIUS - dist
    return out


def closure_for_depth(palm_pose, depth, center=BALL_CENTER, radius=BALL_RADIUS) -> np.ndarray:
    """(5,) smallest closure per digit at which it reaches `depth` [m] inside the ball; a digit
    that never gets that deep takes the closure of its deepest reach; one that never touches the
    ball curls along with the others (their mean closure), as a real hand does."""
    grid = np.linspace(0.0, 1.0, 201)
    depths = np.stack([digit_depths(palm_pose, np.full(5, s), center, radius) for s in grid])
    out = np.empty(5)
    for d in range(5):
        reached = np.nonzero(depths[:, d] >= depth)[0]
        if reached.size:
            out[d] = grid[reached[0]]
        elif depths[:, d].max() > 0.0:
            out[d] = grid[np.argmax(depths[:, d])]
        else:
            out[d] = np.nan
    touching = np.isfinite(out)
    out[~touching] = out[touching].mean() if touching.any() else 0.0
    return out


# ---------------------------------------------------------------------------- keyframed motion



@dataclass
class Keyframes:
    """Piecewise smooth motion through keys: (time [s], wrist position (3,), palm quat (4,),
    digit angles (5, 4) [rad]). `add` takes either a closure (5,) or scalar in [0, 1] (mapped by
    `digit_angles`, which is linear, so easing closures or their angles is the same) or explicit
    angles (5, 4). Between two keys each quantity eases from one to the next (zero velocity at
    the keys); orientation along the geodesic."""

    keys: list = field(default_factory=list)
    phases: dict = field(default_factory=dict)   # name -> (t0, t1) [s], e.g. "hold": ball held up

    def add(self, t, position, closure, quat=PALM_DOWN):
        c = np.asarray(closure, float)
        angles = c.copy() if c.shape == (5, 4) else digit_angles(np.broadcast_to(c, (5,)))
        self.keys.append((float(t), np.asarray(position, float), np.asarray(quat, float), angles))
        return self

    @property
    def duration(self):
        return self.keys[-1][0]

    def __call__(self, t):
        keys = self.keys
        if t <= keys[0][0]:
            k0 = k1 = keys[0]
            u = 0.0
        elif t >= keys[-1][0]:
            k0 = k1 = keys[-1]
            u = 0.0
        else:
            i = max(j for j in range(len(keys)) if keys[j][0] <= t)
            k0, k1 = keys[i], keys[i + 1]
            u = smoothstep((t - k0[0]) / (k1[0] - k0[0]))
        pos = k0[1] + u * (k1[1] - k0[1])
        q = quat_mul(quat_exp(u * quat_log(quat_mul(k1[2], quat_conj(k0[2])))), k0[2])
        return np.r_[pos, q], k0[3] + u * (k1[3] - k0[3])


# ---------------------------------------------------------------------------- caging grasp
#
# Closing a flat hand on the ball from above does not grasp it: the fingers meet the ball above
# its equator and push it down and toward the wrist, out of the hand. The grasp below CAGES the
# ball first: the palm over the ball and the five digit pads on the ball below its equator, all
# around it, so that contact normals push up and toward the ball's centre from every horizontal
# direction; only then do the digits squeeze deeper, and the hand lifts.
#
# The placement was found by a search on this kinematic hand's bone capsules (radius
# DIGIT_RADIUS; palm pose and the 20 angles within DIGIT_LIMITS, minimising the distance of each
# digit's middle/distal bones to the ball surface, with penalties on contact normals whose upward
# part is under 0.5, on horizontal directions no contact pushes against, and on joints nearer
# the table than a digit radius). It is a spherical grasp from above with the hand turned about
# the vertical (the forearm comes from +x, -y of the ball), the fingers fanned toward the little
# finger, the palm 5 mm into the ball top. `cage_report` checks the result.
CAGE_SAG = 0.006          # [m] the simulated ball hangs this far below the engine's on its copy spring
                          # (m g / object_kx = 0.98 / 170) before the hand touches it: design for it
CAGE_PALM_RPY = (0.0219, 0.1535, 2.4268)   # [rad] palm orientation: yaw(z) * pitch(y) * roll(x) of PALM_DOWN
CAGE_BALL_IN_PALM = (0.0808, -0.0016)       # [m] ball centre in the palm frame (x, y)
CAGE_PALM_PRESS = 0.005                      # [m] palm skin into the ball top
CAGE_TOUCH_DEG = np.array([                  # (abduction, flex_1, flex_2, flex_3) [deg], digit pads on the ball
    [34.0, 16.2, -8.0, 80.0],
    [-20.0, 32.6, 28.8, 50.5],
    [-20.0, 17.8, 70.6, 20.9],
    [-20.0, 26.6, 65.1, 23.2],
    [-20.0, 66.0, 21.8, 42.3]])
CAGE_OPEN = 0.45          # [-] open pre-shape: flexions at this fraction of the way from their lower limit to touch
CAGE_SQUEEZE = 0.3        # [-] squeeze: touch plus this fraction of (touch - open) (~1.5-2 cm deeper at the tips)


def cage_palm_pose(center=BALL_CENTER):
    """Palm pose (7,) of the caging grasp of a ball resting at `center` (its simulated copy sags
    CAGE_SAG lower)."""
    roll, pitch, yaw = CAGE_PALM_RPY
    q = quat_mul(quat_exp(np.array([0.0, 0.0, yaw])),
                 quat_mul(quat_exp(np.array([0.0, pitch, 0.0])), quat_exp(np.array([roll, 0.0, 0.0]))))
    rot = quat_to_matrix(q)
    c = np.asarray(center, float) - [0.0, 0.0, CAGE_SAG]
    bx, by = CAGE_BALL_IN_PALM
    wrist = c - rot @ np.array([bx, by, -(BALL_RADIUS + PALM_VENTRAL - CAGE_PALM_PRESS)])
    return np.r_[wrist, q]


def cage_angles():
    """(open, touch, squeeze) digit angles (5, 4) [rad] of the caging grasp, within DIGIT_LIMITS.
    open keeps the abductions and brings every flexion most of the way back toward its lower
    limit (never below 3 deg), so the hand can come down over the ball without touching it."""
    lo, hi = DIGIT_LIMITS[:, :, 0], DIGIT_LIMITS[:, :, 1]
    touch = np.deg2rad(CAGE_TOUCH_DEG)
    opened = touch.copy()
    opened[:, 1:] = np.maximum(lo[:, 1:] + CAGE_OPEN * (touch[:, 1:] - lo[:, 1:]), np.deg2rad(3.0))
    squeeze = np.clip(touch + CAGE_SQUEEZE * (touch - opened), lo, hi)
    return opened, touch, squeeze


def cage_report(palm_pose, angles, center=BALL_CENTER, dims=None, digit_radius=DIGIT_RADIUS):
    """Per digit (5,): gap [m] of its middle/distal bone capsules (radius digit_radius) to the
    ball surface (negative: inside) and the unit push direction (5, 3) of that contact on the ball
    (toward the centre), for the simulated ball at center - CAGE_SAG; dims: the kinematic hand's
    (HandDims, default: the default hand)."""
    c = np.asarray(center, float) - [0.0, 0.0, CAGE_SAG]
    joints, bones = forward_kinematics(palm_pose, angles, dims)
    gaps, pushes = np.empty(5), np.empty((5, 3))
    for d, tip in enumerate((5, 10, 15, 20, 25)):
        b0 = 1 + 3 * d
        pts = [bones[b0 + 1, :3], bones[b0 + 2, :3], joints[tip, :3]]
        best = None
        for a, b in zip(pts[:-1], pts[1:]):
            ab = b - a
            q = a + np.clip(np.dot(c - a, ab) / np.dot(ab, ab), 0.0, 1.0) * ab
            dist = np.linalg.norm(c - q)
            if best is None or dist < best[0]:
                best = (dist, (c - q) / dist)
        gaps[d], pushes[d] = best[0] - BALL_RADIUS - digit_radius, best[1]
    return gaps, pushes


# ---------------------------------------------------------------------------- other hand sizes
#
# The placements above were searched for the default hand. A user's hand of another size grasps
# the same ball with its own placement; `sized_plan` makes it from the default one, so that the
# fitted-size hands are tested on the same grasps (tests/pipeline/test_offline_grasp.py):
#   - the ball's place in the palm frame scales with the hand (hand length ratio s), the palm's
#     thickness too, while the palm still presses the same depth into the (unscaled) ball;
#   - each digit's touch flexions are scaled about the open pre-shape (factor c, the smallest on a
#     fine grid) until its capsules (radius DIGIT_RADIUS * s) reach the depth the default hand's
#     digit reaches at its touch, and likewise its squeeze to the default squeeze's depth (the
#     default's rule, touch + SQUEEZE x (touch - open), squeezes a small hand less deep: its
#     open-to-touch range is shorter, and a 15.6 cm hand then let the ball slip out on the lift).
# A digit that cannot reach a depth within its joint limits keeps the deepest it reaches.


def size_ratio(measures) -> float:
    """Wrist-to-middle-tip length of `measures` over the default hand's."""
    from softhand_sim.handmodel.fit import hand_length
    return hand_length(measures) / hand_length(HandMeasures())


def _touch_for_depth(palm_pose, opened, touch, goal_gap, dims, digit_radius, digits, center):
    """touch angles (5, 4) with each digit in `digits` scaled about `opened` to reach goal_gap (5,)."""
    lo, hi = DIGIT_LIMITS[:, :, 0], DIGIT_LIMITS[:, :, 1]
    grid = np.linspace(0.0, 2.5, 251)
    candidates = [np.clip(opened + c * (touch - opened), lo, hi) for c in grid]
    gaps = np.stack([cage_report(palm_pose, a, center, dims, digit_radius)[0] for a in candidates])
    out = touch.copy()
    for d in digits:
        reached = np.nonzero(gaps[:, d] <= goal_gap[d])[0]
        out[d] = candidates[reached[0] if reached.size else int(np.argmin(gaps[:, d]))][d]
    return out


def sized_plan(kind: str, measures=None):
    """(palm pose (7,) for the ball resting at BALL_CENTER, (open, touch, squeeze) angles (5, 4))
    of grasp `kind` ('cage' | 'pinch') for the hand at `measures` (None: the default hand, whose
    plan is returned unchanged); see the block comment above."""
    if kind == "cage":
        pose, (opened, touch, _), digits = cage_palm_pose(), cage_angles(), range(5)
        ball_in_palm, squeeze_rule = np.array([*CAGE_BALL_IN_PALM, -(BALL_RADIUS + PALM_VENTRAL - CAGE_PALM_PRESS)]), CAGE_SQUEEZE
    elif kind == "pinch":
        from softhand_sim.scenarios.contact import PINCH_SQUEEZE
        (opened, touch, _), digits = pinch_angles(), (0, 1)
        pose = np.r_[BALL_CENTER - [0.0, 0.0, CAGE_SAG] - quat_to_matrix(PALM_DOWN) @ PINCH_BALL_IN_PALM, PALM_DOWN]
        ball_in_palm, squeeze_rule = np.asarray(PINCH_BALL_IN_PALM, float), PINCH_SQUEEZE
    else:
        raise ValueError(f"kind must be 'cage' or 'pinch', got {kind!r}")
    squeeze = np.clip(touch + squeeze_rule * (touch - opened), DIGIT_LIMITS[:, :, 0], DIGIT_LIMITS[:, :, 1])
    if measures is None or measures == HandMeasures():
        return pose, (opened, touch, squeeze)
    s = size_ratio(measures)
    goal, goal_squeeze = cage_report(pose, touch)[0], cage_report(pose, squeeze)[0]  # the default hand's gaps
    rot = quat_to_matrix(pose[3:])
    c = BALL_CENTER - [0.0, 0.0, CAGE_SAG]
    scaled = ball_in_palm * s
    if kind == "cage":  # the palm skin still presses CAGE_PALM_PRESS into the ball's top
        scaled[2] = -(BALL_RADIUS + s * PALM_VENTRAL - CAGE_PALM_PRESS)
    sized_pose = np.r_[c - rot @ scaled, pose[3:]]
    dims = HandDims.from_measures(measures)
    sized_touch = _touch_for_depth(sized_pose, opened, touch, goal, dims, s * DIGIT_RADIUS, digits, BALL_CENTER)
    sized_squeeze = _touch_for_depth(sized_pose, opened, sized_touch, goal_squeeze, dims, s * DIGIT_RADIUS, digits,
                                     BALL_CENTER)
    return sized_pose, (opened, sized_touch, sized_squeeze)


def _cage_motion(start_offset, lift, t_lift, t_hold, retreat, measures=None):
    """Keyframes of a caging grasp: from start_offset above/beside the grasp, come down with the
    digits open, close them onto the ball (cage), squeeze, lift `lift` [m] in t_lift [s], hold
    t_hold [s], open the digits (the ball drops), retreat by `retreat` [m]. measures: a hand of
    another size (sized_plan), None the default hand."""
    if measures is None:
        pose, (opened, touch, squeeze) = cage_palm_pose(), cage_angles()
    else:
        pose, (opened, touch, squeeze) = sized_plan("cage", measures)
    g, q = pose[:3], pose[3:]
    above = g + [0.0, 0.0, 0.06]
    up = g + [0.0, 0.0, lift]
    k = Keyframes()
    t = 0.0
    if start_offset is not None:
        k.add(t, g + start_offset, opened, q)
        t += 1.5
    k.add(t, above, opened, q).add(t + 1.2, g, opened, q)
    t += 1.2
    k.add(t + 1.0, g, touch, q).add(t + 1.7, g, squeeze, q).add(t + 2.0, g, squeeze, q)
    t += 2.0
    if lift > 0.0:
        k.add(t + t_lift, up, squeeze, q).add(t + t_lift + t_hold, up, squeeze, q)
        k.phases["hold"] = (t + t_lift, t + t_lift + t_hold)
        t += t_lift + t_hold
    else:
        k.add(t + t_hold, up, squeeze, q).add(t + t_hold + 0.7, up, touch, q)
        k.phases["squeeze"] = (t - 0.3, t + t_hold)
        t += t_hold + 0.7
    k.add(t + 1.0, up, opened, q)
    k.phases["release"] = (t, t + 1.0)
    t += 1.0
    if retreat:
        k.add(t + 1.0, up + [0.0, 0.0, retreat], opened, q)
    return k


GRASP_LIFT = 0.20   # [m] wrist lift of grasp_lift while holding the ball
GRASP_HOLD = 3.0    # [s] grasp_lift holds the ball up this long


def grasp_lift():
    return _cage_motion(np.array([-0.15, 0.10, 0.20]), GRASP_LIFT, 2.0, GRASP_HOLD, 0.05)


def squeeze(measures=None):
    """Cage the ball, squeeze it on the table (no lift), ease back to touch, open (a hand of
    another size: `measures`, sized_plan)."""
    return _cage_motion(np.array([-0.10, -0.05, 0.18]), 0.0, 0.0, 1.0, 0.05, measures)


def grasp_short(measures=None):
    """The caging grasp with a short lift (12 cm in 1.5 s) and 1 s hold, then release (a hand of
    another size: `measures`, sized_plan)."""
    return _cage_motion(None, 0.12, 1.5, 1.0, 0.0, measures)


# ---------------------------------------------------------------------------- thumb-index pinch
#
# The pinch of the solver's contact tests (softhand_sim.scenarios.contact.PINCH_*: pads at the
# ball's equator, the grip line level, the other fingers straight), palm down over the ball on
# the table: come down with the pads open, close them on the ball, squeeze, lift, hold, open
# (the ball drops back onto the table), retreat.
PINCH_LIFT = 0.12   # [m] wrist lift of pinch_lift (the ball rises ~2 cm less: the palm's coupling
                    # sags under the ball's weight, carried twice, Sect. 3.7)
PINCH_HOLD = 3.0    # [s]


def pinch_lift(measures=None):
    if measures is None:
        opened, touch, squeeze = pinch_angles()
        q = PALM_DOWN
        wrist = BALL_CENTER - [0.0, 0.0, CAGE_SAG] - quat_to_matrix(q) @ PINCH_BALL_IN_PALM
    else:  # a hand of another size (sized_plan)
        pose, (opened, touch, squeeze) = sized_plan("pinch", measures)
        wrist, q = pose[:3], pose[3:]
    up = wrist + [0.0, 0.0, PINCH_LIFT]
    k = Keyframes().add(0.0, wrist + [0.0, 0.0, 0.08], opened, q).add(1.5, wrist, opened, q)
    k.add(2.5, wrist, touch, q).add(3.0, wrist, squeeze, q).add(3.3, wrist, squeeze, q)
    k.add(4.8, up, squeeze, q).add(4.8 + PINCH_HOLD, up, squeeze, q)
    k.phases["hold"] = (4.8, 4.8 + PINCH_HOLD)
    t = 4.8 + PINCH_HOLD
    k.add(t + 0.8, up, opened, q)
    k.phases["release"] = (t, t + 0.8)
    return k.add(t + 1.8, up + [0.0, 0.0, 0.05], opened, q)


PRESS_DEPTH = 0.03  # [m] joints of the palm and fingers below the table top at the deepest


def press_table():
    spot = np.array([0.10, 0.20, 0.0])       # clear of the ball, box and mug
    flat = np.array([0.5, 0.05, 0.05, 0.05, 0.05])  # thumb half in, fingers nearly straight
    above = spot + [0, 0, TABLE_TOP + 0.15]
    touch = spot + [0, 0, TABLE_TOP + PALM_VENTRAL]
    deep = spot + [0, 0, TABLE_TOP - PRESS_DEPTH]
    return (Keyframes().add(0.0, above, flat).add(2.0, touch + [0, 0, 0.03], flat).add(3.0, touch, flat)
            .add(4.0, deep, flat).add(5.0, deep, flat).add(6.0, touch + [0, 0, 0.03], flat)
            .add(7.0, above, flat))


FAST_PEAK_SPEED = 2.0   # [m/s]
FAST_GAP = (3.0, 3.3)   # [s] no tracker frames in this window (300 ms dropout)


class FastMotion:
    """Free motion above the table: a 2 Hz sweep along x (peak wrist speed FAST_PEAK_SPEED), a
    slower sway in y and yaw, fingers opening and closing; amplitude eased in and out."""

    duration = 6.0
    _omega = 2 * np.pi * 2.0   # [rad/s] sweep
    _sway = 0.04               # [m] y amplitude at omega/2

    def __init__(self):
        self.center = np.array([-0.05, 0.10, 1.00])
        self.amp_x, self.amp_y = 0.15, self._sway
        # The displacement is linear in the amplitudes: scale both so the peak wrist speed
        # (measured on a 1 ms grid) is FAST_PEAK_SPEED.
        t = np.arange(0.0, self.duration, 0.001)
        pos = np.array([self(x)[0][:3] for x in t])
        peak = (np.linalg.norm(np.diff(pos, axis=0), axis=1) / 0.001).max()
        self.amp_x *= FAST_PEAK_SPEED / peak
        self.amp_y *= FAST_PEAK_SPEED / peak

    def envelope(self, t):
        return smoothstep((t - 0.5) / 1.0) * smoothstep((5.5 - t) / 1.0)

    def __call__(self, t):
        e = self.envelope(t)
        pos = self.center + e * np.array([self.amp_x * np.sin(self._omega * t),
                                          self.amp_y * np.sin(0.5 * self._omega * t), 0.0])
        yaw = e * np.deg2rad(20.0) * np.sin(0.5 * self._omega * t)
        q = quat_exp(np.array([0.0, 0.0, yaw]))
        closure = 0.35 + 0.3 * np.sin(2 * np.pi * 1.0 * t)
        return np.r_[pos, q], digit_angles(np.full(5, closure))


# Hands of other sizes: the defaults scaled to 16 and 21 cm wrist to middle tip, with their own
# proportions (a shorter palm and little finger on the small hand, a longer thumb on the large).
SMALL_HAND = scale_measures(HandMeasures(), 0.16 / 0.19, palm_length=0.072, little_lengths=(0.027, 0.016, 0.016),
                            knuckle_recess=(0.04, 0.07, 0.2), thumb_cmc=(0.15, 1.1, -0.4))
LARGE_HAND = scale_measures(HandMeasures(), 0.21 / 0.19, thumb_lengths=(0.050, 0.037, 0.032))


TIP_PINCH_GAP = 0.010  # [m] thumb-index tip gap of the tip pinch (the pads' thickness apart)


def tip_pinch_angles(measures, tip_gap: float = TIP_PINCH_GAP):
    """Digit angles (5, 4) [rad] of a tip pinch of the hand at `measures`: thumb and index tips
    `tip_gap` [m] apart, the index flexed moderately, the other fingers open; found by a bounded
    least-squares search within DIGIT_LIMITS (deterministic)."""
    from scipy.optimize import least_squares
    dims = HandDims.from_measures(measures)
    base = OPEN_ANGLES.copy()
    lo = np.r_[DIGIT_LIMITS[0, :, 0], DIGIT_LIMITS[1, 1:, 0]]
    hi = np.r_[DIGIT_LIMITS[0, :, 1], DIGIT_LIMITS[1, 1:, 1]]
    want = np.deg2rad([30.0, 15.0, 20.0, 30.0, 40.0, 45.0, 30.0])  # a natural pinch to stay near

    def angles(x):
        a = base.copy()
        a[0], a[1, 1:] = x[:4], x[4:]
        return a

    def residual(x):
        j, _ = forward_kinematics(np.r_[0.0, 0.0, 0.0, PALM_DOWN], angles(x), dims)
        gap = np.linalg.norm(j[5, :3] - j[10, :3])
        return np.r_[10.0 * (gap - tip_gap) / TIP_PINCH_GAP, 0.3 * (x - want)]

    x = least_squares(residual, np.clip(want, lo, hi), bounds=(lo, hi)).x
    return angles(x)


def size_check(measures):
    """Open still for 1.2 s (the calibration window), pinch thumb and index tips, open, make a
    fist, open, above the table clear of the scene's objects."""
    pinch = tip_pinch_angles(measures)
    spot = np.array([0.10, 0.20, TABLE_TOP + 0.15])
    k = Keyframes().add(0.0, spot, 0.0).add(1.2, spot, 0.0)
    k.add(2.2, spot, pinch).add(2.7, spot, pinch).add(3.5, spot, 0.0)
    k.add(4.5, spot, 1.0).add(5.0, spot, 1.0).add(6.0, spot, 0.0)
    k.phases["pinch"] = (2.2, 2.7)
    k.phases["fist"] = (4.5, 5.0)
    return k


#: [m] std of the white noise per joint coordinate and frame of the sample bags: a tracker's
#: frame-to-frame noise as the Leap recordings of bags/ show it (0.024 and 0.044 mm per coordinate,
#: handmodel.fidelity.tracker_noise), rounded up.
POSITION_NOISE = 0.00005
#: [m] the noise of the one bag kept noisy (fast_dropout, with its dropout and 2 m/s sweep): 30 times
#: a real tracker's, for the filters and the lead's noise scaling to be seen at work.
NOISY_TRACKER = 0.0015


def noise_of(own: float | None, position_noise: float | None = None) -> float:
    """[m] the position noise of a bag: its own where it has one (fast_dropout), else the one asked
    for (tools/make_bags.py --position-noise), else POSITION_NOISE."""
    if own is not None:
        return own
    return POSITION_NOISE if position_noise is None else float(position_noise)


@dataclass(frozen=True)
class Scenario:
    """How a bag is made: motion factory, mean rate [Hz], gap [s] or None, seed, the hand's
    measures (None: the default hand), position noise [m] (None: POSITION_NOISE)."""
    motion: object
    rate: float
    gap: tuple | None = None
    seed: int = 0
    measures: HandMeasures | None = None
    noise: float | None = None


SCENARIOS = {
    "grasp_lift": Scenario(grasp_lift, 100.0, seed=1),
    "squeeze": Scenario(squeeze, 110.0, seed=2),
    "press_table": Scenario(press_table, 95.0, seed=3),
    "fast_dropout": Scenario(FastMotion, 120.0, gap=FAST_GAP, seed=4, noise=NOISY_TRACKER),
    "grasp_short": Scenario(grasp_short, 100.0, seed=5),
    "pinch_lift": Scenario(pinch_lift, 100.0, seed=6),
    "small_hand": Scenario(lambda: size_check(SMALL_HAND), 100.0, seed=7, measures=SMALL_HAND),
    "large_hand": Scenario(lambda: size_check(LARGE_HAND), 100.0, seed=8, measures=LARGE_HAND),
}

# The object tests at the fitted sizes (tests/pipeline/test_offline_grasp.py): the sample bags'
# motions made by the small and the large hand, placed for that size (sized_plan); no bag files.
# The small hand's caging grasp is not among them: scaled from the default's, its pads meet the
# 8 cm ball nearer its equator (upward push 0.14-0.27 against the default's 0.35-0.47) and the ball
# slips out on the lift; a hand that small needs a cage searched for it.
SIZED_SCENARIOS = {
    f"{name}@{size}": Scenario(lambda f=factory, m=measures: f(m), SCENARIOS[name].rate, seed=SCENARIOS[name].seed,
                               measures=measures)
    for name, factory in (("grasp_short", grasp_short), ("squeeze", squeeze), ("pinch_lift", pinch_lift),
                          ("press_table", lambda m: press_table()))
    for size, measures in (("small", SMALL_HAND), ("large", LARGE_HAND))
    if (name, size) not in {("grasp_short", "small"), ("squeeze", "small")}}

TIMING_JITTER = 0.0015   # [s] uniform +- jitter of each capture time around the nominal period


def sample(name: str, noise: bool = True, position_noise: float | None = None):
    """(stamps_ns (n,) int64, joints (n, 26, 7), clean_joints (n, 26, 7)) of scenario `name`.

    Capture times: k / rate plus uniform jitter, dropping those inside the scenario's gap.
    `joints` has the position noise (orientations are the clean ones); `clean_joints` has none.
    The noise is the scenario's own, else `position_noise` [m], else POSITION_NOISE.
    """
    known = {**SCENARIOS, **SIZED_SCENARIOS}
    if name not in known:
        raise ValueError(f"unknown scenario {name!r}; known: {', '.join(known)}")
    sc = known[name]
    rng = np.random.default_rng(sc.seed)
    motion = sc.motion()
    period = 1.0 / sc.rate
    count = int(np.floor(motion.duration / period)) + 1
    times = np.arange(count) * period + rng.uniform(-TIMING_JITTER, TIMING_JITTER, count)
    times[0] = 0.0
    times = np.clip(times, 0.0, motion.duration)
    if sc.gap is not None:
        times = times[(times < sc.gap[0]) | (times >= sc.gap[1])]
    dims = None if sc.measures is None else HandDims.from_measures(sc.measures)
    clean = np.stack([forward_kinematics(*motion(t), dims)[0] for t in times])
    noisy = clean.copy()
    if noise:
        sd = noise_of(sc.noise, position_noise)
        noisy[:, :, :3] += rng.normal(0.0, sd, size=noisy[:, :, :3].shape)
    stamps = STAMP0_NS + np.round(times * 1e9).astype(np.int64)
    return stamps, noisy, clean
