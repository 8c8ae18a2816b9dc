"""Sample tracker bags in bags/: readable by rosbags and by the mcap reader, plausible hand data."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from softhand_sim.handmodel.skeleton_names import OPENXR_JOINT_COUNT
from softhand_sim.scenarios import tracker_bags
from softhand_tracking.adapter import AdapterConfig, TrackerAdapter, bone_lengths
from softhand_sim.ros.bagio import deserialize, read_topic
from softhand_sim.ros.msgs import pose_array_to_numpy
from softhand_sim.handmodel.kinematics import DIGIT_LIMITS, default_dims, forward_kinematics

REPO = Path(__file__).resolve().parents[2]
BAGS = REPO / "bags"
TOPIC = "/tracker/hand_joints"
MSGTYPE = "geometry_msgs/msg/PoseArray"
NAMES = ("grasp_lift", "squeeze", "press_table", "fast_dropout", "grasp_short", "pinch_lift")


def _expected_lengths():
    """Bone lengths (16,) of the kinematic hand the bags were made from."""
    return np.r_[default_dims().palm_length, default_dims().phalanx_length.reshape(-1)]


def _read_rosbags(name):
    data = read_topic(BAGS / name, TOPIC, MSGTYPE)
    msgs = [deserialize(raw, MSGTYPE) for raw in data.payloads]
    joints = np.array([[(p.position.x, p.position.y, p.position.z) for p in m.poses] for m in msgs])
    stamps = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in msgs])
    frames = {m.header.frame_id for m in msgs}
    counts = {len(m.poses) for m in msgs}
    return np.array(data.stamps_ns), stamps, joints, frames, counts


@pytest.fixture(scope="module", params=NAMES)
def bag(request):
    return request.param, _read_rosbags(request.param)


def test_bags_exist_and_are_small():
    """Every sample bag exists as an mcap rosbag2 directory, all of them together under 10 MB."""
    total = 0
    for name in NAMES:
        files = {p.suffix for p in (BAGS / name).iterdir()}
        assert files == {".yaml", ".mcap"}, (name, files)
        total += sum(p.stat().st_size for p in (BAGS / name).iterdir())
    assert total < 10e6


def test_rate_count_and_finiteness(bag):
    """Every message: 26 finite joints, frame 'world', header stamp = bag time; mean rate
    90-120 Hz with slight jitter (no period below 5 ms or, outside the dropout, above 15 ms)."""
    name, (log_ns, stamp_ns, joints, frames, counts) = bag
    assert counts == {OPENXR_JOINT_COUNT}
    assert frames == {"world"}
    assert np.all(np.isfinite(joints))
    np.testing.assert_array_equal(log_ns, stamp_ns)
    dt = np.diff(stamp_ns) * 1e-9
    rate = (len(dt)) / ((stamp_ns[-1] - stamp_ns[0]) * 1e-9)
    if name != "fast_dropout":
        assert 90.0 <= rate <= 120.0, rate
    assert dt.min() > 0.005
    regular = dt[dt < 0.1]
    assert 0 < regular.std() < 0.002  # jitter present, slight
    assert regular.max() < 0.015
    assert 90.0 <= 1.0 / np.median(regular) <= 120.0


def test_bone_lengths_constant_within_noise(bag):
    """Bone lengths stay those of the hand model within the position noise (std < 2.5 mm, mean
    within 1 mm), and the adapter accepts every frame."""
    _, (_, _, joints, _, _) = bag
    lengths = np.array([bone_lengths(j) for j in joints])
    assert lengths.std(axis=0).max() < 0.0025
    np.testing.assert_allclose(lengths.mean(axis=0), _expected_lengths(), atol=0.001)
    adapter = TrackerAdapter()
    assert all(adapter.convert(j) is not None for j in joints[::5])


def test_same_data_through_the_mcap_reader(bag):
    """The mcap library with the ROS 2 decoder reads the same messages (count, joints, stamps)."""
    name, (log_ns, _, joints, _, _) = bag
    mcap_file = next((BAGS / name).glob("*.mcap"))
    got = []
    with open(mcap_file, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, msg in reader.iter_decoded_messages(topics=[TOPIC]):
            assert schema.name == MSGTYPE
            got.append((message.log_time, [(p.position.x, p.position.y, p.position.z) for p in msg.poses]))
    assert len(got) == len(log_ns)
    np.testing.assert_array_equal([g[0] for g in got], log_ns)
    np.testing.assert_array_equal(np.array([g[1] for g in got]), joints)


def test_motions_do_what_they_say():
    """grasp_lift lifts the wrist GRASP_LIFT (20 cm) with the digits closed and holds it there
    GRASP_HOLD (3 s); press_table takes the palm joints 3 cm below the table top; fast_dropout
    peaks at 2 m/s and has one 300 ms gap; digit angles stay within limits, and joints of every bag
    but press_table stay a digit radius above the table."""
    stamps, _, clean = tracker_bags.sample("grasp_lift")
    t = (stamps - stamps[0]) * 1e-9
    wrist = clean[:, 1, :3]
    g = tracker_bags.cage_palm_pose()[:3]
    t0, t1 = tracker_bags.grasp_lift().phases["hold"]
    held = wrist[(t >= t0) & (t <= t1)]
    np.testing.assert_allclose(held - g, np.tile([0.0, 0.0, tracker_bags.GRASP_LIFT], (len(held), 1)), atol=1e-9)
    assert np.isclose(t1 - t0, tracker_bags.GRASP_HOLD)

    _, _, clean = tracker_bags.sample("press_table")
    palm_joints = clean[:, [0, 1, 7, 12, 17, 22], 2]
    assert np.isclose(palm_joints.min(), tracker_bags.TABLE_TOP - 0.03, atol=1e-6)

    stamps, _, clean = tracker_bags.sample("fast_dropout")
    t = (stamps - stamps[0]) * 1e-9
    gaps = np.diff(t)
    assert np.isclose(gaps.max(), 0.3, atol=0.012) and np.sum(gaps > 0.05) == 1
    motion = tracker_bags.FastMotion()
    tt = np.linspace(0, motion.duration, 3001)
    pos = np.array([motion(x)[0][:3] for x in tt])
    speed = np.linalg.norm(np.diff(pos, axis=0), axis=1) / np.diff(tt)
    assert 1.9 <= speed.max() <= 2.05, speed.max()

    for name, sc in tracker_bags.SCENARIOS.items():
        motion = sc.motion()
        for x in np.linspace(0, motion.duration, 50):
            angles = motion(x)[1]
            assert np.all(angles >= DIGIT_LIMITS[:, :, 0] - 1e-12) and np.all(angles <= DIGIT_LIMITS[:, :, 1] + 1e-12), name
            if name != "press_table":  # the others stay clear of the table by a digit radius
                assert forward_kinematics(*motion(x))[0][:, 2].min() > tracker_bags.TABLE_TOP + tracker_bags.DIGIT_RADIUS, name


def test_grasp_cages_the_ball():
    """The caging grasp on the kinematic hand's bone capsules: open, the digits clear the ball by
    over 5 mm all the way down from 6 cm above; at touch every digit's pad is within 2 mm of the
    ball surface, below the equator (each push on the ball has an upward part >= 0.3) and the
    pushes surround the ball (every horizontal direction is opposed by a push with a component
    >= 0.2 along it); the squeeze takes every digit deeper (up to 1-3 cm inside); no joint
    comes nearer the table than a digit radius."""
    pose = tracker_bags.cage_palm_pose()
    opened, touch, squeeze = tracker_bags.cage_angles()
    for dz in np.linspace(0.0, 0.06, 7):
        gaps, _ = tracker_bags.cage_report(pose + np.r_[0, 0, dz, 0, 0, 0, 0], opened)
        assert gaps.min() > 0.005, dz
    gaps, push = tracker_bags.cage_report(pose, touch)
    assert np.all(np.abs(gaps) < 0.002), gaps
    assert push[:, 2].min() >= 0.3, push
    dirs = np.array([[np.cos(a), np.sin(a), 0.0] for a in np.linspace(0, 2 * np.pi, 72, endpoint=False)])
    assert (push @ dirs.T).max(axis=0).min() >= 0.2
    deep, _ = tracker_bags.cage_report(pose, squeeze)
    assert np.all(deep < gaps) and -0.03 <= deep.min() and deep.max() < -0.005, deep
    for angles in (opened, touch, squeeze):
        assert forward_kinematics(pose, angles)[0][:, 2].min() > tracker_bags.TABLE_TOP + tracker_bags.DIGIT_RADIUS


def test_generation_is_deterministic(tmp_path):
    """tools/make_bags.py writes the messages shipped in bags/: same stamps and frame ids, poses equal to
    the last bits of float64 arithmetic (1e-12 m; another CPU or BLAS build may round the kinematics'
    products differently, so the bytes themselves are not compared)."""
    subprocess.run([sys.executable, str(REPO / "tools" / "make_bags.py"), "--out", str(tmp_path),
                    "--only", "grasp_short", "pinch_lift"], check=True, capture_output=True, timeout=60)
    for name in ("grasp_short", "pinch_lift"):
        new = read_topic(tmp_path / name, TOPIC, MSGTYPE)
        old = read_topic(BAGS / name, TOPIC, MSGTYPE)
        assert new.stamps_ns == old.stamps_ns, name
        for raw_new, raw_old in zip(new.payloads, old.payloads, strict=True):
            a, b = deserialize(raw_new, MSGTYPE), deserialize(raw_old, MSGTYPE)
            assert a.header.frame_id == b.header.frame_id and a.header.stamp == b.header.stamp, name
            np.testing.assert_allclose(pose_array_to_numpy(a), pose_array_to_numpy(b), rtol=0, atol=1e-12)


# ------------------------------------------------------------------ left-hand and two-hand bags

def _side_frames(path, side):
    from softhand_sim.topics import tracker_topic

    data = read_topic(path, tracker_topic(side), MSGTYPE)
    return data.stamps_ns, np.stack([pose_array_to_numpy(deserialize(raw, MSGTYPE)) for raw in data.payloads])


def test_left_bag_mirrors_its_right_original():
    """grasp_short_left holds grasp_short's frames, same stamps, every joint pose mirrored through
    the xz plane, on /tracker/left/hand_joints only."""
    from rosbags.rosbag2 import Reader

    from softhand_sim.scenarios.bimanual import mirror_poses

    with Reader(BAGS / "grasp_short_left") as r:
        assert {c.topic for c in r.connections} == {"/tracker/left/hand_joints"}
    stamps, left = _side_frames(BAGS / "grasp_short_left", "left")
    right = read_topic(BAGS / "grasp_short", TOPIC, MSGTYPE)
    assert stamps == right.stamps_ns
    for k, raw in enumerate(right.payloads):
        np.testing.assert_allclose(left[k], mirror_poses(pose_array_to_numpy(deserialize(raw, MSGTYPE))), atol=1e-12)


@pytest.mark.parametrize("name", ["handover", "two_hand_lift"])
def test_two_hand_bags_have_both_hands_on_one_timeline(name):
    """Both sides' tracker topics, ~100 Hz each over the script's duration, interleaved in one time
    order (bag time = capture stamp), 26 finite joints per frame; the left hand's frames are a left
    hand's: its adapter accepts every one. The two-hand lift carries its scene's parameters."""
    import yaml

    from softhand_sim.scenarios import bimanual

    duration = {"handover": bimanual.Handover.T["end"], "two_hand_lift": bimanual.TwoHandLift.T["end"]}[name]
    for side in ("right", "left"):
        stamps, joints = _side_frames(BAGS / name, side)
        rate = (len(stamps) - 1) / ((stamps[-1] - stamps[0]) * 1e-9)
        assert 95 <= rate <= 105 and abs((stamps[-1] - stamps[0]) * 1e-9 - duration) < 0.02, (side, rate)
        assert joints.shape[1:] == (26, 7) and np.all(np.isfinite(joints))
        adapter = TrackerAdapter(AdapterConfig(hand=side))
        assert all(adapter.convert(j[:, :3]) is not None for j in joints[::10]), side
    params = BAGS / name / "params.yaml"
    want = bimanual.TWO_HAND_BAGS[name]
    assert params.is_file() == bool(want)
    if want:
        data = yaml.safe_load(params.read_text())
        assert {node: v["ros__parameters"] for node, v in data.items()} == want


def test_two_hand_lift_bag_is_regenerated_exactly(tmp_path):
    """tools/make_bags.py writes two_hand_lift and grasp_short_left as shipped (a kinematic script:
    no simulation in it; the handover's aim comes from an offline run and is checked above)."""
    subprocess.run([sys.executable, str(REPO / "tools" / "make_bags.py"), "--out", str(tmp_path),
                    "--only", "two_hand_lift", "grasp_short_left"], check=True, capture_output=True, timeout=120)
    for name, sides in (("two_hand_lift", ("right", "left")), ("grasp_short_left", ("left",))):
        for side in sides:
            new, old = _side_frames(tmp_path / name, side), _side_frames(BAGS / name, side)
            assert new[0] == old[0], (name, side)
            np.testing.assert_allclose(new[1], old[1], rtol=0, atol=1e-12)
