"""Tracker adapter: 26 OpenXR joint positions -> 16 bone poses in the frames of docs/INTERFACE.md.

Input: joint positions (26, 3) [m] in the tracker frame, OpenXR XR_EXT_hand_tracking order
(`skeleton_names.OPENXR_JOINT_NAMES`). Joint orientations are not used: trackers often send
identity, and positions fix every frame once a twist convention is chosen.

Output: bone poses (16, 7) [m, quaternion x y z w] in `world`, bone order of
`skeleton_names.BONE_NAMES`, frame of each bone (docs/INTERFACE.md "Hand bones"):

* origin at the proximal joint of the bone's segment (`skeleton_names.BONE_SEGMENTS`);
* +x toward the distal joint;
* palm: +z dorsal = side * x × (INDEX_PROXIMAL − LITTLE_PROXIMAL), made orthogonal to x
  (side = +1 right hand: index lies toward +y of a palm-down right hand, so x × (+y) = +z;
  side = −1 left hand, whose index lies toward −y);
* fingers: y is the finger's flexion axis and z = x × y. The flexion axis is one vector per digit,

      a = n × x_1 + Σ_i x_i × x_(i+1)        (x_i: unit axes of its three bones)

  with n the digit's base abduction axis (fingers: the palm's z; thumb: the hand model's thumb
  base axis, `default_dims().abduction_axes()`, configurable). For a digit whose base joint abducts
  about n and then flexes, and whose two
  distal joints are hinges parallel to the flexed base axis, every term is parallel to that axis
  (the first with weight cos(base flexion), the others with the sine of each joint's bend), so
  a is exact for such a hand and never degenerate in the poses a hand reaches; for the rare
  straight digit pointing along the palm normal the palm's lateral axis takes over smoothly.
  Each bone's y is then a made orthogonal to its own x, so +z points to the back of the digit.
  For a mirrored (left) hand every cross product of mirrored vectors flips sign, so the same
  formula yields the mirrored frames without a side factor; only the palm's z needs it.
* thumb: the hand model's own rule for its thumb frames (handmodel.skeleton.thumb_layout):
  z = cos(b) z_palm + sin(b) unit(z_palm × x), made orthogonal to x, b = the thumb's pronation
  (50°). The thumb is no hinge chain at rest (its bones turn about different axes), so this,
  not the flexion axis, is what reproduces the simulated skeleton's rest thumb exactly (a
  constant twist offset would be a constant Eq. 14 torque on the simulated thumb).

Left hands use the mirrored frames (docs/INTERFACE.md): positions mirrored through the xz plane give
frames R_left = S R_right S with S = diag(1, −1, 1) — x and z keep their meaning (along the bone,
dorsal), y = z × x is recomputed. `mirror_poses` applies this to a pose array.

Validation before anything is passed on: exactly 26 joints, every coordinate finite and within
MAX_ABS_COORDINATE of the tracker origin, every bone length within [bone_length_min,
bone_length_max], a non-degenerate palm. A bad frame raises `RejectedFrame` with a reason from
REJECT_REASONS; `TrackerAdapter` counts rejections by reason (TrackingLoop adds "stamp_order":
a frame captured no later than the last accepted one).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from numba import njit

from softhand_sim.physics.rotations import cross, cross3, matrix_to_quat, quat_to_matrix
from softhand_sim.handmodel.skeleton_names import (BONE_COUNT, BONE_SEGMENTS, JOINT_INDEX, OPENXR_JOINT_COUNT)

from softhand_sim.handmodel.kinematics import default_dims, thumb_frame

REJECT_REASONS = ("joint_count", "non_finite", "out_of_range", "bone_length", "degenerate_palm", "stamp_order")
# [m] A joint farther than this from the tracker origin is a corrupt frame, not a hand in a room
# (a whole hand shifted by 1e9 m keeps plausible bone lengths and would pass the other checks).
MAX_ABS_COORDINATE = 100.0

# Default plausible bone lengths [m]: generous bounds around adult hands (palm wrist->middle
# knuckle 7-13 cm; thumb metacarpal 3-6 cm; phalanxes 1-6 cm), widened for tracker noise.
DEFAULT_BONE_LENGTH_MIN = np.array([0.05, 0.015] + [0.007] * 14)
DEFAULT_BONE_LENGTH_MAX = np.array([0.16, 0.08] + [0.07] * 14)

_SEG_PROX = np.array([s[0] for s in BONE_SEGMENTS], dtype=np.int64)
_SEG_DIST = np.array([s[1] for s in BONE_SEGMENTS], dtype=np.int64)
# The three bones of each digit (thumb, index, middle, ring, little), proximal to distal.
DIGIT_BONES = np.array([[1, 2, 3], [4, 5, 6], [7, 8, 9], [10, 11, 12], [13, 14, 15]], dtype=np.int64)
_INDEX_PROXIMAL = JOINT_INDEX["INDEX_PROXIMAL"]
_LITTLE_PROXIMAL = JOINT_INDEX["LITTLE_PROXIMAL"]
# Base abduction axis of each digit (thumb..little) in the right hand's palm frame: the fingers
# abduct about the palm normal; the thumb CMC about the kinematic hand's thumb base z axis
# (kinematic_hand.HandDims.thumb_base_rotation).
_MIRROR = np.diag([1.0, -1.0, 1.0])
# Below this length of the summed flexion-axis terms the palm's lateral axis is blended in.
_FLEX_AXIS_BLEND = 0.2
_PALM_MIN_CROSS = 1e-3  # |x × lateral| below this (palm axis ∥ knuckle line) is degenerate [m]


class RejectedFrame(ValueError):
    """A tracker frame that must not be used; `reason` is one of REJECT_REASONS."""

    def __init__(self, reason: str, detail: str):
        super().__init__(f"tracker frame rejected ({reason}): {detail}")
        self.reason = reason


def side_sign(hand: str) -> float:
    """+1 for 'right', -1 for 'left'; ValueError naming the bad value otherwise."""
    if hand == "right":
        return 1.0
    if hand == "left":
        return -1.0
    raise ValueError(f"hand must be 'right' or 'left', got {hand!r}")


def bone_frames(joints: np.ndarray, hand: str = "right", abduction_axes=None) -> np.ndarray:
    """Bone poses (16, 7) from validated joint positions (26, 3) [m], same frame as the joints.

    abduction_axes (5, 3): each digit's base abduction axis in the right hand's palm frame
    (default: the default hand model's); mirrored here for a left hand. No validation here (see
    `validate_joints`); the frame convention is the module docstring's.
    """
    n_local = default_dims().abduction_axes() if abduction_axes is None else np.asarray(abduction_axes, dtype=np.float64)
    poses = np.empty((BONE_COUNT, 7))
    _bone_frames(np.ascontiguousarray(joints, dtype=np.float64), np.ascontiguousarray(n_local), side_sign(hand),
                 _SEG_PROX, _SEG_DIST, DIGIT_BONES, _INDEX_PROXIMAL, _LITTLE_PROXIMAL, poses)
    return poses


@njit(cache=True)
def _bone_frames(p, n_local, s, seg_prox, seg_dist, digit_bones, index_proximal, little_proximal, poses):
    """bone_frames compiled (a tracker frame took ~0.35 ms in numpy on single vectors: ~4 % of a core
    per tracked hand at 100 Hz, in the tracking node and again in the recorder's live lag)."""
    nb = seg_prox.shape[0]
    x = np.empty((nb, 3))
    for b in range(nb):
        v = p[seg_dist[b]] - p[seg_prox[b]]
        x[b] = v / np.linalg.norm(v)
    rot = np.empty((nb, 3, 3))
    lateral = p[index_proximal] - p[little_proximal]
    z_palm = s * cross(x[0], lateral)
    z_palm /= np.linalg.norm(z_palm)
    y_palm = cross(z_palm, x[0])
    rot[0, :, 0] = x[0]
    rot[0, :, 1] = y_palm
    rot[0, :, 2] = z_palm
    for d in range(digit_bones.shape[0]):
        # the abduction axis in world: the palm frame is mirrored for a left hand, so are local vectors
        nl = np.array((n_local[d, 0], s * n_local[d, 1], n_local[d, 2]))
        n_world = rot[0] @ nl
        b0, b1, b2 = digit_bones[d, 0], digit_bones[d, 1], digit_bones[d, 2]
        a = cross(n_world, x[b0]) + cross(x[b0], x[b1]) + cross(x[b1], x[b2])
        norm = np.linalg.norm(a)
        if norm < _FLEX_AXIS_BLEND:  # straight digit along the palm normal: lean on the palm
            a = a + (_FLEX_AXIS_BLEND - norm) / _FLEX_AXIS_BLEND * y_palm
        for k in range(3):
            b = digit_bones[d, k]
            if d == 0:
                rot[b] = thumb_frame(x[b], z_palm, a, s)
                continue
            y = a - np.dot(a, x[b]) * x[b]
            y /= np.linalg.norm(y)
            rot[b, :, 0] = x[b]
            rot[b, :, 1] = y
            rot[b, :, 2] = cross(x[b], y)
    for b in range(nb):
        poses[b, :3] = p[seg_prox[b]]
        poses[b, 3:] = matrix_to_quat(rot[b])


def mirror_poses(poses: np.ndarray) -> np.ndarray:
    """Mirror poses (n, 7) through the world xz plane, keeping frames right-handed.

    Position y -> -y; rotation R -> S R S, S = diag(1, -1, 1) (x and z axes mirrored, y = z × x).
    Maps right-hand bone frames onto left-hand ones and back (docs/INTERFACE.md "frames mirrored").
    """
    p = np.asarray(poses, dtype=np.float64)
    out = p.copy()
    out[:, 1] = -p[:, 1]
    for i in range(p.shape[0]):
        out[i, 3:] = matrix_to_quat(_MIRROR @ quat_to_matrix(p[i, 3:].copy()) @ _MIRROR)
    return out


def transform_points(world_from_tracker: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points (n, 3) of the tracker frame expressed in world; world_from_tracker is a pose (7,)."""
    rot = quat_to_matrix(np.asarray(world_from_tracker[3:], dtype=np.float64).copy())
    return points @ rot.T + world_from_tracker[:3]


def bone_lengths(joints: np.ndarray) -> np.ndarray:
    """Length [m] of each of the 16 tracked segments of joints (26, 3)."""
    return np.linalg.norm(joints[_SEG_DIST] - joints[_SEG_PROX], axis=1)


@dataclass
class AdapterConfig:
    """Adapter settings.

    hand: 'right' | 'left'. world_from_tracker: pose (7,) [m, quat x y z w] of the tracker frame in
    world. bone_length_min / bone_length_max: (16,) plausible bone lengths [m] (scalars broadcast).
    """

    hand: str = "right"
    world_from_tracker: np.ndarray = field(default_factory=lambda: np.array([0, 0, 0, 0, 0, 0, 1.0]))
    bone_length_min: np.ndarray = field(default_factory=lambda: DEFAULT_BONE_LENGTH_MIN.copy())
    bone_length_max: np.ndarray = field(default_factory=lambda: DEFAULT_BONE_LENGTH_MAX.copy())

    def __post_init__(self):
        side_sign(self.hand)
        t = np.asarray(self.world_from_tracker, dtype=np.float64).reshape(-1)
        if t.shape != (7,) or not np.all(np.isfinite(t)):
            raise ValueError(f"world_from_tracker must be 7 finite numbers [px py pz qx qy qz qw], got {t}")
        qn = np.linalg.norm(t[3:])
        if qn < 1e-9:
            raise ValueError(f"world_from_tracker quaternion has zero norm: {t[3:]}")
        t[3:] /= qn
        self.world_from_tracker = t
        for name in ("bone_length_min", "bone_length_max"):
            v = np.broadcast_to(np.asarray(getattr(self, name), dtype=np.float64), (BONE_COUNT,)).copy()
            if not np.all(np.isfinite(v)) or np.any(v < 0):
                raise ValueError(f"{name} must be finite and >= 0, got {v}")
            setattr(self, name, v)
        if np.any(self.bone_length_min >= self.bone_length_max):
            raise ValueError("bone_length_min must be < bone_length_max for every bone, got "
                             f"{self.bone_length_min} / {self.bone_length_max}")


def validate_joints(joints, config: AdapterConfig) -> np.ndarray:
    """Joint positions (26, 3) float64 of a frame, or RejectedFrame naming why it is unusable.

    `joints` may be (26, 3) positions or (26, 7) poses (orientations ignored).
    """
    p = np.asarray(joints, dtype=np.float64)
    if p.ndim != 2 or p.shape[0] != OPENXR_JOINT_COUNT or p.shape[1] not in (3, 7):
        raise RejectedFrame("joint_count", f"expected {OPENXR_JOINT_COUNT} joints, got array of shape {p.shape}")
    p = p[:, :3]
    if not np.all(np.isfinite(p)):
        bad = np.unique(np.nonzero(~np.isfinite(p))[0]).tolist()
        raise RejectedFrame("non_finite", f"non-finite position in joints {bad}")
    if np.abs(p).max() > MAX_ABS_COORDINATE:
        raise RejectedFrame("out_of_range", f"coordinate {np.abs(p).max():.3g} m beyond +-{MAX_ABS_COORDINATE} m")
    lengths = bone_lengths(p)
    bad = np.nonzero((lengths < config.bone_length_min) | (lengths > config.bone_length_max))[0]
    if bad.size:
        b = int(bad[0])
        raise RejectedFrame("bone_length", f"{bad.size} bone(s) out of bounds, first: bone {b} length "
                            f"{lengths[b]:.4f} m not in [{config.bone_length_min[b]:.4f}, "
                            f"{config.bone_length_max[b]:.4f}]")
    cross = cross3(p[_SEG_DIST[0]] - p[_SEG_PROX[0]], p[_INDEX_PROXIMAL] - p[_LITTLE_PROXIMAL])
    if np.linalg.norm(cross) < _PALM_MIN_CROSS * lengths[0]:
        raise RejectedFrame("degenerate_palm", "palm axis parallel to the INDEX-LITTLE knuckle line")
    return p


_warm = False


def warm_up() -> None:
    """Compile (or load from numba's cache) the bone-frame kernels now, once per process: every
    TrackerAdapter calls it when made, so a node does it before it spins. Left to the first
    tracker frame, a fresh checkout compiled them inside the tracking node's (and the recorder's)
    first callback, a stall of seconds while frames arrive."""
    global _warm
    if _warm:
        return
    from softhand_sim.handmodel.kinematics import forward_kinematics
    joints, _ = forward_kinematics(np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]), np.zeros((5, 4)))
    bone_frames(joints[:, :3], "right")  # a left hand runs the same kernels with the same types
    _warm = True


class TrackerAdapter:
    """Converts tracker frames to bone targets, counting rejected frames by reason.

    `convert(joints)` returns bone poses (16, 7) in world, or None when the frame is rejected
    (the reason is counted in `rejected` and kept in `last_reject`); a rejected frame never
    produces poses.
    """

    def __init__(self, config: AdapterConfig | None = None, joint_filter=None):
        self.config = config if config is not None else AdapterConfig()
        self.joint_filter = joint_filter  # e.g. joint_filter.OneEuroJointFilter; None: frames as they come
        self.rejected = {reason: 0 for reason in REJECT_REASONS}
        self.accepted = 0
        self.last_reject = ""
        warm_up()

    def reject(self, err: RejectedFrame) -> None:
        """Count a rejected frame (also used by the loop for frames refused on their stamp)."""
        self.rejected[err.reason] += 1
        self.last_reject = str(err)

    def convert(self, joints, t: float | None = None) -> np.ndarray | None:
        """Bone poses of a frame captured at `t` [s] (the joint filter's time; without a filter
        `t` is unused), or None (rejected, counted)."""
        try:
            p = validate_joints(joints, self.config)
        except RejectedFrame as err:
            self.reject(err)
            return None
        if self.joint_filter is not None and t is not None:
            # valid frames only (a rejected one never enters it), relative to the tracked wrist: the
            # joints' jitter against each other and the hand's turning are smoothed, its travel is
            # not delayed. (In the palm's own frame the palm's orientation jitter stayed, and with
            # it the slip of a held object: 9.7 / 13.1 mm against 10.3 / 13.1 unfiltered.)
            origin = p[_SEG_PROX[0]]
            p = origin + self.joint_filter.filter(p - origin, t)
        world = transform_points(self.config.world_from_tracker, p)
        poses = bone_frames(world, self.config.hand)
        if not np.all(np.isfinite(poses)):  # cannot happen after validation; never pass it on
            self.rejected["degenerate_palm"] += 1
            self.last_reject = "non-finite bone frame"
            return None
        self.accepted += 1
        return poses


def tracker_adapter(p: dict, hand: str) -> TrackerAdapter:
    """The adapter of one hand from tracking_node's parameters `p` (softhand_sim.params.TRACKING):
    as tracking_node and `softhand offline` build it."""
    from softhand_tracking.joint_filter import OneEuroJointFilter

    joint_filter = None
    if p["joint_filter"] == "one_euro":
        joint_filter = OneEuroJointFilter(p["joint_filter_min_cutoff"], p["joint_filter_beta"])
    return TrackerAdapter(AdapterConfig(hand=hand, world_from_tracker=np.asarray(p["tracker_to_world"], dtype=float),
                                        bone_length_min=p["min_bone_length"], bone_length_max=p["max_bone_length"]),
                          joint_filter)
