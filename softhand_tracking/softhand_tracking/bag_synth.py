"""Deterministic synthetic tracker recordings for bags/ (tools/make_bags.py writes them).

A kinematic right hand (`kinematic_hand`, default dimensions) is driven by keyframed palm poses
and one closure value per digit; the closure maps to joint angles inside `DIGIT_LIMITS`. The 26
OpenXR joints are sampled at the tracker's rate with timing jitter and white position noise,
as a real optical tracker reports them. Placed in the default scene (config/scene.yaml):
table top z = 0.75, ball r = 0.04 at (0, 0, 0.79).

Grasp closures are not guessed: `closure_for_depth` searches, for each digit, the closure at
which the digit's bone capsules (radius DIGIT_RADIUS) reach a given depth inside the ball, so
"close 1 cm inside the ball" means exactly that for the kinematic hand.

Scenarios (name -> Scenario): grasp_lift, squeeze, press_table, fast_dropout, grasp_short.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from softhand_sim.rotations import quat_exp, quat_log, quat_mul, quat_conj

from .kinematic_hand import DEFAULT_DIMS, DIGIT_LIMITS, forward_kinematics

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


def _smooth(u):
    """C1 ease 0 -> 1 with zero slope at both ends."""
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


@dataclass
class Keyframes:
    """Piecewise smooth motion through keys: (time [s], wrist position (3,), palm quat (4,),
    closure (5,)). Between two keys each quantity eases from one to the next (zero velocity at
    the keys); orientation along the geodesic."""

    keys: list = field(default_factory=list)

    def add(self, t, position, closure, quat=PALM_DOWN):
        self.keys.append((float(t), np.asarray(position, float), np.asarray(quat, float),
                          np.broadcast_to(np.asarray(closure, float), (5,)).copy()))
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
            u = _smooth((t - k0[0]) / (k1[0] - k0[0]))
        pos = k0[1] + u * (k1[1] - k0[1])
        q = quat_mul(quat_exp(u * quat_log(quat_mul(k1[2], quat_conj(k0[2])))), k0[2])
        closure = k0[3] + u * (k1[3] - k0[3])
        return np.r_[pos, q], digit_angles(closure)


def grasp_wrist(center=BALL_CENTER, press=0.004):
    """Wrist position of the palm-down grasp, the palm's ventral skin `press` [m] into the ball top.

    The ball sits under the knuckles (11 cm from the wrist, 1 cm toward the little finger): of the
    placements (1.5 cm grid) and thumb closing directions searched, this one gives contact normals
    (four fingers 1 cm inside, the thumb at its deepest reach, 7 mm) that best surround the ball in the horizontal plane (every
    horizontal direction has a contact with n.u >= 0.2), with contacts below the equator, so the
    hand can hold the ball by friction when it lifts.
    """
    z = center[2] + BALL_RADIUS + PALM_VENTRAL - press
    return np.array([center[0] - 0.11, center[1] + 0.01, z])


def grasp_lift():
    g = grasp_wrist()
    pose = np.r_[g, PALM_DOWN]
    hold = closure_for_depth(pose, 0.010)
    up = g + [0, 0, 0.10]
    return (Keyframes().add(0.0, g + [-0.20, 0.05, 0.20], 0).add(2.5, g + [0, 0, 0.08], 0)
            .add(3.5, g, 0).add(4.8, g, hold).add(5.8, up, hold).add(8.8, up, hold)
            .add(9.8, up, 0).add(11.0, g + [-0.05, 0, 0.25], 0))


def squeeze():
    g = grasp_wrist()
    pose = np.r_[g, PALM_DOWN]
    touch, inside = closure_for_depth(pose, 0.0), closure_for_depth(pose, 0.030)
    return (Keyframes().add(0.0, g + [-0.15, -0.05, 0.18], 0).add(2.0, g + [0, 0, 0.06], 0)
            .add(3.0, g, 0).add(4.0, g, touch).add(5.2, g, inside).add(6.0, g, inside)
            .add(7.0, g, touch).add(7.8, g, 0).add(9.0, g + [-0.05, 0, 0.20], 0))


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
        return _smooth((t - 0.5) / 1.0) * _smooth((5.5 - t) / 1.0)

    def __call__(self, t):
        e = self.envelope(t)
        pos = self.center + e * np.array([self.amp_x * np.sin(self._omega * t),
                                          self.amp_y * np.sin(0.5 * self._omega * t), 0.0])
        yaw = e * np.deg2rad(20.0) * np.sin(0.5 * self._omega * t)
        q = quat_exp(np.array([0.0, 0.0, yaw]))
        closure = 0.35 + 0.3 * np.sin(2 * np.pi * 1.0 * t)
        return np.r_[pos, q], digit_angles(np.full(5, closure))


def grasp_short():
    g = grasp_wrist()
    hold = closure_for_depth(np.r_[g, PALM_DOWN], 0.010)
    return (Keyframes().add(0.0, g + [0, 0, 0.05], 0).add(1.0, g, 0).add(2.0, g, hold)
            .add(3.0, g + [0, 0, 0.03], hold))


@dataclass(frozen=True)
class Scenario:
    """How a bag is made: motion factory, mean rate [Hz], gap [s] or None, seed."""
    motion: object
    rate: float
    gap: tuple | None = None
    seed: int = 0


SCENARIOS = {
    "grasp_lift": Scenario(grasp_lift, 100.0, seed=1),
    "squeeze": Scenario(squeeze, 110.0, seed=2),
    "press_table": Scenario(press_table, 95.0, seed=3),
    "fast_dropout": Scenario(FastMotion, 120.0, gap=FAST_GAP, seed=4),
    "grasp_short": Scenario(grasp_short, 100.0, seed=5),
}

TIMING_JITTER = 0.0015   # [s] uniform +- jitter of each capture time around the nominal period
POSITION_NOISE = 0.0015  # [m] std of white noise per joint coordinate


def sample(name: str, noise: bool = True):
    """(stamps_ns (n,) int64, joints (n, 26, 7), clean_joints (n, 26, 7)) of scenario `name`.

    Capture times: k / rate plus uniform jitter, dropping those inside the scenario's gap.
    `joints` has the position noise (orientations are the clean ones); `clean_joints` has none.
    """
    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; known: {', '.join(SCENARIOS)}")
    sc = SCENARIOS[name]
    rng = np.random.default_rng(sc.seed)
    motion = sc.motion()
    period = 1.0 / sc.rate
    count = int(np.floor(motion.duration / period)) + 1
    times = np.arange(count) * period + rng.uniform(-TIMING_JITTER, TIMING_JITTER, count)
    times[0] = 0.0
    times = np.clip(times, 0.0, motion.duration)
    if sc.gap is not None:
        times = times[(times < sc.gap[0]) | (times >= sc.gap[1])]
    clean = np.stack([forward_kinematics(*motion(t))[0] for t in times])
    noisy = clean.copy()
    if noise:
        noisy[:, :, :3] += rng.normal(0.0, POSITION_NOISE, size=noisy[:, :, :3].shape)
    stamps = STAMP0_NS + np.round(times * 1e9).astype(np.int64)
    return stamps, noisy, clean
