"""Per-side topics of the tracking side (issue #18), at library level (no ROS process): which tracker
frames play_node plays on which topic, and which contacts turn on which hand's feedback."""
import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from geometry_msgs.msg import PoseArray
from std_msgs.msg import String

from softhand_sim.physics.hands import HAND_CODE
from softhand_sim.ros.bagio import BagError, write_bag
from softhand_sim.ros.msgs import (CONTACT_DTYPE, contacts_cloud_from_numpy, pointcloud_from_structured,
                                   pose_array_from_numpy, pose_array_to_numpy)
from softhand_sim.scenarios.tracker_bags import sample
from softhand_sim.topics import LEGACY_TRACKER, tracker_topic
from softhand_tracking.adapter import mirror_poses
from softhand_tracking.loop import FEEDBACK_HOLD, LoopConfig, TrackingLoop
from softhand_tracking.play_node import tracker_frames
from softhand_tracking.tracking_node import hand_contact_count

POSE_ARRAY = "geometry_msgs/msg/PoseArray"
T0_NS = 1_700_000_000 * 10**9
RIGHT, LEFT = tracker_topic("right"), tracker_topic("left")


def frame(i, t_ns, side="right"):
    """CDR bytes of a 26-joint PoseArray whose joint 0 x is i (joint 0 y < 0 on the left hand)."""
    poses = np.zeros((26, 7))
    poses[:, 6] = 1.0
    poses[0, :2] = i, 1.0
    if side == "left":
        poses = mirror_poses(poses)
    return serialize_message(pose_array_from_numpy(poses, int(t_ns)))


def legacy_bag(path, n=10, period_ns=10_000_000):
    write_bag(path, [(LEGACY_TRACKER, POSE_ARRAY, T0_NS + i * period_ns, frame(i, T0_NS + i * period_ns))
                     for i in range(n)])


def two_hand_bag(path, n=20, right_period=10_000_000, left_period=11_000_000, left_offset=3_000_000):
    """Both hands' tracker topics, each at its own rate and phase (so their frames interleave)."""
    records = []
    for i in range(n):
        records.append((RIGHT, POSE_ARRAY, T0_NS + i * right_period, frame(i, T0_NS + i * right_period)))
        t = T0_NS + left_offset + i * left_period
        records.append((LEFT, POSE_ARRAY, t, frame(i, t, "left")))
    write_bag(path, records)


def joint0(raw):
    return pose_array_to_numpy(deserialize_message(raw, PoseArray))[0, :2]


@pytest.mark.parametrize("hand", ["right", "left"])
def test_legacy_bag_plays_as_the_chosen_side(tmp_path, hand):
    """An older bag's /tracker/hand_joints is played on /tracker/{hand}/hand_joints, every frame in
    order; the default side is right."""
    legacy_bag(tmp_path / "bag")
    rec, frames, renamed = tracker_frames(tmp_path / "bag", hand=hand)
    assert renamed == {LEGACY_TRACKER: tracker_topic(hand)}
    assert [t for _s, t, _r in frames] == [tracker_topic(hand)] * 10
    assert [joint0(r)[0] for _s, _t, r in frames] == list(range(10))
    assert tracker_frames(tmp_path / "bag")[2] == {LEGACY_TRACKER: RIGHT}
    # an explicit legacy topic is renamed the same way
    assert tracker_frames(tmp_path / "bag", topic=LEGACY_TRACKER, hand=hand)[2] == {LEGACY_TRACKER: tracker_topic(hand)}


def test_two_hand_bag_interleaved_on_one_timeline(tmp_path):
    """A two-hand bag plays both side topics, as they are, all frames in bag time order (interleaved,
    each side's own frames in order); --hand does not rename side topics; an explicit side topic plays
    that side only."""
    two_hand_bag(tmp_path / "bag")
    for hand in ("right", "left"):
        _rec, frames, renamed = tracker_frames(tmp_path / "bag", hand=hand)
        assert renamed == {RIGHT: RIGHT, LEFT: LEFT}
        stamps = [s for s, _t, _r in frames]
        assert stamps == sorted(stamps)
        topics = [t for _s, t, _r in frames]
        assert topics.count(RIGHT) == topics.count(LEFT) == 20
        assert sum(a != b for a, b in zip(topics, topics[1:])) > 10  # interleaved, not one side then the other
        for side, topic in (("right", RIGHT), ("left", LEFT)):
            j0 = np.array([joint0(r) for _s, t, r in frames if t == topic])
            assert j0[:, 0].tolist() == list(range(20))
            assert np.all(np.sign(j0[:, 1]) == (1 if side == "right" else -1))  # the left frames are the left ones
    _rec, frames, renamed = tracker_frames(tmp_path / "bag", topic=LEFT)
    assert renamed == {LEFT: LEFT} and len(frames) == 20


def test_bag_without_tracker_topic_names_its_topics(tmp_path):
    """No tracker topic: BagError naming the topics the bag has; a tracker topic of another type, a
    legacy topic that would land on a side topic the bag also has, and a missing explicit topic:
    BagError saying so."""
    write_bag(tmp_path / "none", [("/hand/right/bones", POSE_ARRAY, T0_NS, frame(0, T0_NS)),
                                  ("/other", "std_msgs/msg/String", T0_NS, serialize_message(String(data="x")))])
    with pytest.raises(BagError, match=r"has no tracker topic .*topics in it: /hand/right/bones, /other"):
        tracker_frames(tmp_path / "none")
    with pytest.raises(BagError, match=r"has no topic /tracker/left/hand_joints \(topics in it: /hand/right/bones"):
        tracker_frames(tmp_path / "none", topic=LEFT)
    write_bag(tmp_path / "typed", [(LEFT, "std_msgs/msg/String", T0_NS, serialize_message(String(data="x")))])
    with pytest.raises(BagError, match="has type std_msgs/msg/String, expected geometry_msgs/msg/PoseArray"):
        tracker_frames(tmp_path / "typed")
    write_bag(tmp_path / "both", [(LEGACY_TRACKER, POSE_ARRAY, T0_NS, frame(0, T0_NS)),
                                  (RIGHT, POSE_ARRAY, T0_NS, frame(0, T0_NS))])
    with pytest.raises(BagError, match=r"both /tracker/hand_joints and /tracker/right/hand_joints.*--hand left"):
        tracker_frames(tmp_path / "both")
    _rec, frames, renamed = tracker_frames(tmp_path / "both", hand="left")  # the legacy one as the left hand
    assert renamed == {LEGACY_TRACKER: LEFT, RIGHT: RIGHT} and len(frames) == 2


def contacts(hands):
    n = len(hands)
    return contacts_cloud_from_numpy(np.zeros((n, 3)), np.tile([0.0, 0.0, 1.0], (n, 1)), np.zeros((n, 3)),
                                     np.zeros(n), np.zeros(n), 0, hand=np.asarray(hands, dtype=np.uint8))


def test_contact_count_per_hand():
    """hand_contact_count counts only the object contacts of its side's code (skin-on-skin rows
    left out); an old cloud without the `hand` field is the right hand's; a cloud whose data is
    short is refused."""
    for hands in ([], [0], [1], [0, 1, 1, 0, 1], [1] * 7):
        cloud = contacts(hands)
        for side, code in HAND_CODE.items():
            assert hand_contact_count(cloud, code) == hands.count(code), (hands, side)
    names = [k for k in CONTACT_DTYPE.names if k not in ("hand", "bone", "other_hand", "other_bone")]  # before two hands
    old = np.zeros(3, dtype=np.dtype({"names": names, "formats": [CONTACT_DTYPE.fields[k][0] for k in names],
                                      "offsets": [CONTACT_DTYPE.fields[k][1] for k in names],
                                      "itemsize": CONTACT_DTYPE.itemsize}))
    old_cloud = pointcloud_from_structured(old, 0)
    assert hand_contact_count(old_cloud, HAND_CODE["right"]) == 3
    assert hand_contact_count(old_cloud, HAND_CODE["left"]) == 0
    from softhand_sim.physics.contact.hand_self_contact import SKIN_OBJECT
    objects = np.array([0, SKIN_OBJECT, 3, SKIN_OBJECT, SKIN_OBJECT], dtype=np.uint32)  # skin on skin: not counted
    mixed = contacts_cloud_from_numpy(np.zeros((5, 3)), np.tile([0.0, 0.0, 1.0], (5, 1)), np.zeros((5, 3)),
                                      objects, np.zeros(5), 0, hand=np.array([0, 0, 1, 1, 0], np.uint8))
    assert hand_contact_count(mixed, HAND_CODE["right"]) == 1 and hand_contact_count(mixed, HAND_CODE["left"]) == 1
    short = contacts([1, 1])
    short.data = short.data[:50]
    with pytest.raises(ValueError, match="bytes"):
        hand_contact_count(short, HAND_CODE["left"])


def _feedback_gains(side):
    """Drive a TrackingLoop of `side` with frames and the contacts cloud of both hands; return the
    feedback gains after the other hand's contacts and after its own."""
    stamps_ns, joints, _ = sample("grasp_short")
    if side == "left":
        joints = np.stack([mirror_poses(j) for j in joints])
    from softhand_tracking.adapter import AdapterConfig, TrackerAdapter
    loop = TrackingLoop(LoopConfig(feedback="contact"), TrackerAdapter(AdapterConfig(hand=side)))
    code = HAND_CODE[side]
    other = 1 - code
    t = 0.0
    gains = {}
    for phase, cloud in (("other", contacts([other] * 4)), ("own", contacts([other, code]))):
        for k in range(60):  # 0.24 s at 250 Hz, contacts every step, a frame every 4th
            if k % 4 == 0:
                assert loop.on_tracker(joints[k // 4], t, t)
            loop.on_contacts(hand_contact_count(cloud, code), t)
            loop.step(t)
            t += 0.004
        gains[phase] = loop.bones.sim_gain
        t += FEEDBACK_HOLD + 0.1  # let the previous phase's contact expire
    return gains


@pytest.mark.parametrize("side", ["right", "left"])
def test_other_hands_contacts_leave_feedback_off(side):
    """Through the node's parsing function: the other hand's contacts leave this hand's feedback
    (feedback: contact) at gain 0; one contact point of its own turns it fully on."""
    gains = _feedback_gains(side)
    assert gains == {"other": 0.0, "own": 1.0}, gains
