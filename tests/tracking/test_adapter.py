"""Tracker adapter: bone frames from OpenXR joints, mirrored left hands, rejection of bad frames."""
import numpy as np
import pytest

from softhand_sim.physics.rotations import quat_exp, quat_to_matrix, relative_rotvec
from softhand_tracking.adapter import (REJECT_REASONS, AdapterConfig, TrackerAdapter, bone_frames,
                                       mirror_poses)
from softhand_sim.handmodel.measures import HandMeasures
from softhand_sim.handmodel.skeleton import build_skeleton
from softhand_sim.handmodel.skeleton_names import BONE_SEGMENTS
from softhand_sim.handmodel.kinematics import DIGIT_LIMITS, forward_kinematics

MAX_ORIENTATION_ERROR = np.deg2rad(0.5)


def _angle_errors(a, b):
    return np.array([np.linalg.norm(relative_rotvec(a[i, 3:].copy(), b[i, 3:].copy())) for i in range(a.shape[0])])


def _random_hands(count, seed=0):
    """Random palm poses and digit angles within limits, skipping the one unobservable case: a
    digit lying straight along its base abduction axis (then its twist is not in the positions)."""
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < count:
        palm = np.r_[rng.uniform(-1, 1, 3), quat_exp(rng.normal(size=3))]
        angles = rng.uniform(DIGIT_LIMITS[:, :, 0], DIGIT_LIMITS[:, :, 1])
        # cos(base flexion) + |sin| of the two hinge bends is what fixes the digit's twist
        observable = np.cos(angles[:, 1]) + np.abs(np.sin(angles[:, 2])) + np.abs(np.sin(angles[:, 3]))
        if observable.min() > 0.4:
            out.append((palm, angles))
    return out


def test_bone_frames_match_known_hand():
    """Frames built from joint positions alone match the kinematic hand's bone poses: positions
    exact, orientations within 0.5 deg, over random palm poses and digit angles within limits."""
    worst = 0.0
    for palm, angles in _random_hands(60):
        joints, truth = forward_kinematics(palm, angles)
        poses = bone_frames(joints[:, :3], "right")
        np.testing.assert_allclose(poses[:, :3], truth[:, :3], atol=1e-12)
        worst = max(worst, _angle_errors(poses, truth).max())
    assert worst < MAX_ORIENTATION_ERROR, np.rad2deg(worst)


def test_frames_follow_the_contract_axes():
    """Rest hand palm down: palm x toward the middle knuckle, z dorsal (+z), y toward the thumb;
    every finger bone's x along its (fanned) segment and z dorsal (+z); all 16 frames are those of
    the hand model's rest skeleton (softhand_sim.handmodel), thumb included."""
    joints, _ = forward_kinematics(np.array([0, 0, 0.8, 0, 0, 0, 1.0]), np.zeros((5, 4)))
    poses = bone_frames(joints[:, :3], "right")
    rot = [quat_to_matrix(p[3:].copy()) for p in poses]
    np.testing.assert_allclose(rot[0], np.eye(3), atol=1e-12)
    for b in range(4, 16):
        seg = joints[BONE_SEGMENTS[b][1], :3] - joints[BONE_SEGMENTS[b][0], :3]
        np.testing.assert_allclose(rot[b][:, 0], seg / np.linalg.norm(seg), atol=1e-12)
        np.testing.assert_allclose(rot[b][:, 2], [0, 0, 1], atol=1e-12)
    rest = build_skeleton(HandMeasures())["bone_rest_pose"]
    np.testing.assert_allclose(poses[:, :3] - [0, 0, 0.8], rest[:, :3], atol=1e-12)
    assert _angle_errors(poses, rest).max() < 1e-9


def test_left_hand_frames_are_mirrored():
    """A left hand (right-hand joints mirrored through xz) with hand='left' gives exactly the
    mirrored right-hand frames (R -> S R S): x along the bone, z still dorsal, right-handed."""
    for palm, angles in _random_hands(20, seed=1):
        joints, truth = forward_kinematics(palm, angles)
        left = bone_frames(joints[:, :3] * np.array([1.0, -1.0, 1.0]), "left")
        expect = mirror_poses(truth)
        np.testing.assert_allclose(left[:, :3], expect[:, :3], atol=1e-12)
        assert _angle_errors(left, expect).max() < MAX_ORIENTATION_ERROR
    joints, _ = forward_kinematics(np.array([0, 0, 0.8, 0, 0, 0, 1.0]), np.zeros((5, 4)))
    left = bone_frames(joints[:, :3] * np.array([1.0, -1.0, 1.0]), "left")
    palm_rot = quat_to_matrix(left[0, 3:].copy())
    np.testing.assert_allclose(palm_rot[:, 2], [0, 0, 1], atol=1e-12)  # dorsal stays up
    assert np.linalg.det(palm_rot) == pytest.approx(1.0)


def test_tracker_to_world_transform_applies():
    """A tracker frame rotated/translated by T: the adapter with world_from_tracker = T returns
    the bones of the untransformed hand."""
    joints, truth = forward_kinematics(np.array([0.1, 0, 0.8, 0, 0, 0, 1.0]), np.full((5, 4), 0.3))
    world_from_tracker = np.r_[0.2, -0.4, 1.1, quat_exp(np.array([0.3, -1.2, 0.5]))]
    rot = quat_to_matrix(world_from_tracker[3:].copy())
    in_tracker = (joints[:, :3] - world_from_tracker[:3]) @ rot  # inverse transform, row-wise R^T
    adapter = TrackerAdapter(AdapterConfig(world_from_tracker=world_from_tracker))
    poses = adapter.convert(in_tracker)
    np.testing.assert_allclose(poses[:, :3], truth[:, :3], atol=1e-12)
    assert _angle_errors(poses, truth).max() < 1e-9


def _good_joints():
    return forward_kinematics(np.array([0, 0, 0.9, 0, 0, 0, 1.0]), np.full((5, 4), 0.2))[0]


@pytest.mark.parametrize("reason, corrupt", [
    ("joint_count", lambda j: j[:25]),
    ("joint_count", lambda j: np.zeros((0, 3))),
    ("non_finite", lambda j: np.where(np.arange(26)[:, None] == 9, np.nan, j)),
    ("non_finite", lambda j: np.where(np.arange(26)[:, None] == 0, np.inf, j)),
    ("bone_length", lambda j: j * 3.0),                       # a giant hand
    ("bone_length", lambda j: np.where(np.arange(26)[:, None] == 10, j + 0.2, j)),  # index tip flies off
    ("bone_length", lambda j: np.where(np.arange(26)[:, None] == 13, j * 0 + j[12], j)),  # zero-length bone
    ("degenerate_palm", lambda j: _collinear_palm(j)),
])
def test_bad_frames_are_rejected_and_counted(reason, corrupt):
    """Every kind of bad frame is rejected (None, never poses) and counted under its reason."""
    adapter = TrackerAdapter()
    assert adapter.convert(_good_joints()) is not None
    assert adapter.convert(corrupt(_good_joints().copy())) is None
    assert adapter.rejected[reason] == 1
    assert sum(adapter.rejected.values()) == 1
    assert reason in adapter.last_reject
    assert adapter.accepted == 1
    assert set(adapter.rejected) == set(REJECT_REASONS)


def _collinear_palm(j):
    """Index and little knuckles moved onto the palm axis line (bone lengths kept plausible)."""
    j = j.copy()
    wrist, middle = j[1, :3], j[12, :3]
    axis = (middle - wrist) / np.linalg.norm(middle - wrist)
    for knuckle in (7, 22):
        shift = wrist + axis * np.dot(j[knuckle, :3] - wrist, axis) - j[knuckle, :3]
        finger = slice(knuckle, knuckle + 4)
        j[finger, :3] += shift
    return j


def test_bone_length_bounds_are_configurable():
    """Tightening the palm's bounds below the hand's palm length rejects the frame."""
    cfg = AdapterConfig(bone_length_min=0.005, bone_length_max=np.r_[0.08, np.full(15, 0.15)])
    adapter = TrackerAdapter(cfg)
    assert adapter.convert(_good_joints()) is None and adapter.rejected["bone_length"] == 1


def test_bad_config_names_the_value():
    """Bad settings raise errors that name the setting."""
    with pytest.raises(ValueError, match="hand"):
        AdapterConfig(hand="middle")
    with pytest.raises(ValueError, match="world_from_tracker"):
        AdapterConfig(world_from_tracker=[0, 0, 0])
    with pytest.raises(ValueError, match="bone_length_min"):
        AdapterConfig(bone_length_min=0.2, bone_length_max=0.1)


def test_a_new_adapter_has_compiled_what_its_frames_need():
    """In a fresh process: once a TrackerAdapter exists (nodes make theirs before they spin),
    converting right- and left-hand frames of flexed hands compiles nothing more (left to the
    first frame, a fresh checkout compiled the bone-frame kernels inside a node's callback)."""
    from tests.support.compiles import compiled_by
    compiled = compiled_by("""
        from softhand_tracking import adapter as ad
        from softhand_sim.handmodel import kinematics
        from softhand_sim.physics import rotations
        import numpy as np
        right, left = ad.TrackerAdapter(), ad.TrackerAdapter(ad.AdapterConfig(hand="left"))
        """, "[ad._bone_frames, kinematics.thumb_frame, rotations.cross, rotations.matrix_to_quat]", """
        rng = np.random.default_rng(0)
        palm = np.array([0.1, -0.2, 0.9, 0.0, 0.0, np.sin(0.3), np.cos(0.3)])
        joints = [kinematics.forward_kinematics(palm, rng.uniform(0.0, 0.8, (5, 4)))[0] for _ in range(20)]
        for j in joints:
            assert right.convert(j) is not None
            assert left.convert(j * [1.0, -1.0, 1.0, 1.0, 1.0, 1.0, 1.0]) is not None
        """)
    assert compiled == "{}", f"compiled on the first frames: {compiled}"
