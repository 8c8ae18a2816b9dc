"""Unit tests of softhand_sim.ros.msgs: message <-> numpy round trips (no DDS, no node)."""
from types import SimpleNamespace

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message

from softhand_sim.ros import msgs as rm
from sensor_msgs.msg import PointCloud2, PointField
from trajectory_msgs.msg import MultiDOFJointTrajectory
from visualization_msgs.msg import Marker


def _random_poses(rng, n):
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return np.hstack([rng.normal(size=(n, 3)), q])


def test_stamp_round_trip_exact_in_nanoseconds():
    """Integer-nanosecond stamps survive Time <-> ns exactly; float seconds within 1 ns."""
    for ns in (0, 1, 999_999_999, 1_000_000_000, 1_715_000_123_456_789_012):
        assert rm.stamp_to_ns(rm.stamp_from_ns(ns)) == ns
    t = 12.345678901
    assert abs(rm.stamp_to_seconds(rm.stamp_from_seconds(t)) - t) < 1e-9
    st = rm.stamp_from_seconds(3.5)
    assert (st.sec, st.nanosec) == (3, 500_000_000)
    with pytest.raises(ValueError, match="stamp"):
        rm.stamp_from_ns(-1)


def test_pose_array_round_trip_through_serialization():
    """PoseArray from (n,7) poses serializes (CDR) and decodes back to the same floats, frame 'world'."""
    rng = np.random.default_rng(0)
    poses = _random_poses(rng, 26)
    msg = rm.pose_array_from_numpy(poses, 1_000_000_123)
    back = deserialize_message(serialize_message(msg), type(msg))
    assert back.header.frame_id == "world"
    assert rm.stamp_to_ns(back.header.stamp) == 1_000_000_123
    np.testing.assert_array_equal(rm.pose_array_to_numpy(back), poses)


def test_pose_array_cdr_is_what_rclpy_reads_and_writes():
    """The numpy-built PoseArray CDR (the nodes' hot topics) against rclpy's own serializer, both
    ways: rclpy decodes ours to the same poses, stamp and frame, ours decodes rclpy's; the lengths
    are equal (only alignment padding, which rclpy leaves uninitialised, may differ)."""
    rng = np.random.default_rng(3)
    for n in (0, 1, 16, 26):
        for frame in ("world", "", "abc", "tracker_frame"):
            poses = _random_poses(rng, n)
            stamp = int(rng.integers(0, 2**31 - 1)) * 1_000_000_000 + int(rng.integers(0, 10**9))
            ours = rm.pose_array_cdr(poses, stamp, frame)
            theirs = serialize_message(rm.pose_array_from_numpy(poses, stamp, frame))
            assert len(ours) == len(theirs)
            back = deserialize_message(ours, rm.PoseArray)
            assert (rm.stamp_to_ns(back.header.stamp), back.header.frame_id) == (stamp, frame)
            np.testing.assert_array_equal(rm.pose_array_to_numpy(back), poses)
            got, got_stamp, got_frame = rm.pose_array_from_cdr(theirs)
            assert (got_stamp, got_frame) == (stamp, frame)
            np.testing.assert_array_equal(got, poses)
    big_endian = b"\x00\x00\x00\x00" + (7).to_bytes(4, "big") + (5).to_bytes(4, "big") \
        + (1).to_bytes(4, "big") + b"\x00\x00\x00\x00" + (1).to_bytes(4, "big") + bytes(4) \
        + np.arange(7, dtype=">f8").tobytes()
    got, got_stamp, got_frame = rm.pose_array_from_cdr(big_endian)
    assert (got_stamp, got_frame) == (7_000_000_005, "")
    np.testing.assert_array_equal(got, np.arange(7.0).reshape(1, 7))
    for bad, what in ((b"", "bytes"), (ours[:-8], "poses need"), (b"\x00\x01\x00\x00" + bytes(8) + (99).to_bytes(4, "little"), "frame_id")):
        with pytest.raises(ValueError, match=what):
            rm.pose_array_from_cdr(bad)
    with pytest.raises(ValueError, match="non-finite"):
        rm.pose_array_cdr(np.full((1, 7), np.nan), 0)


def test_pose_array_rejects_bad_shape_and_nan():
    """A wrong width or a NaN pose is refused with a message naming the array."""
    with pytest.raises(ValueError, match=r"poses must have shape \(n, 7\)"):
        rm.pose_array_from_numpy(np.zeros((3, 6)), 0)
    bad = np.zeros((2, 7))
    bad[1, 2] = np.nan
    with pytest.raises(ValueError, match="poses contains non-finite"):
        rm.pose_array_from_numpy(bad, 0)


def test_object_states_round_trip_and_contract():
    """Object states: names, poses, twists, accels and stamp round-trip; one point, as docs/INTERFACE.md fixes."""
    rng = np.random.default_rng(1)
    names = ["ball", "small_box", "mug"]
    poses, tw, acc = _random_poses(rng, 3), rng.normal(size=(3, 6)), rng.normal(size=(3, 6))
    msg = rm.object_states_from_numpy(names, poses, tw, acc, 5.25)
    assert len(msg.points) == 1 and msg.header.frame_id == "world"
    back = deserialize_message(serialize_message(msg), MultiDOFJointTrajectory)
    n2, p2, t2, a2, stamp = rm.object_states_to_numpy(back)
    assert n2 == names and stamp == 5_250_000_000
    np.testing.assert_array_equal(p2, poses)
    np.testing.assert_array_equal(t2, tw)
    np.testing.assert_array_equal(a2, acc)
    with pytest.raises(ValueError, match="twists has 2 rows for 3 object names"):
        rm.object_states_from_numpy(names, poses, tw[:2], acc, 0)
    back.points.append(back.points[0])
    with pytest.raises(ValueError, match="exactly one point"):
        rm.object_states_to_numpy(back)


def test_contacts_and_object_states_cdr_are_what_rclpy_reads():
    """sim_node's numpy-built CDR of /hand/contacts and /hand/object_states (cdr_messages) against
    rclpy's serializer of the message objects: the same length, and rclpy reads ours back to the
    message it serializes (every field, every value), for 0 to 300 contacts and 0 to 4 objects,
    with frame ids of every length modulo 4; a bad row count is refused by name."""
    from softhand_sim.ros import cdr_messages as cdr
    rng = np.random.default_rng(11)
    for n in (0, 1, 7, 290):
        for frame in ("world", "", "abc", "ab"):
            args = (rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), rng.normal(size=(n, 3)),
                    rng.integers(0, 4, size=n), rng.integers(0, 2, size=n))
            extra = dict(hand=rng.integers(0, 2, size=n), bone=rng.integers(0, 16, size=n),
                         other_hand=rng.integers(0, 2, size=n), other_bone=rng.integers(0, 16, size=n))
            stamp = int(rng.integers(0, 2**31 - 1)) * 1_000_000_000 + int(rng.integers(0, 10**9))
            ours = cdr.contacts_cloud_cdr(*args, stamp, frame, **extra)
            msg = rm.contacts_cloud_from_numpy(*args, rm.stamp_from_ns(stamp), frame, **extra)
            theirs = serialize_message(msg)
            assert len(ours) == len(theirs), (n, frame)
            assert deserialize_message(ours, PointCloud2) == msg, (n, frame)
    for k in (0, 1, 4):
        for frame in ("world", "", "abc"):
            names = ["ball", "big_box", "mug", "small_box"][:k]
            poses, tw, acc = _random_poses(rng, k), rng.normal(size=(k, 6)), rng.normal(size=(k, 6))
            ours = cdr.object_states_cdr(names, poses, tw, acc, 5_250_000_001, frame)
            msg = rm.object_states_from_numpy(names, poses, tw, acc, rm.stamp_from_ns(5_250_000_001), frame)
            assert len(ours) == len(serialize_message(msg)), (k, frame)
            assert deserialize_message(ours, MultiDOFJointTrajectory) == msg, (k, frame)
    with pytest.raises(ValueError, match="twists has 2 rows for 3 object names"):
        cdr.object_states_cdr(["a", "b", "c"], _random_poses(rng, 3), np.zeros((2, 6)), np.zeros((3, 6)), 0)
    with pytest.raises(ValueError, match="forces has 1 rows for 2 contact points"):
        cdr.contacts_cloud_cdr(np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((1, 3)), [0, 0], [0, 0], 0)


def test_xyz_cloud_round_trip_float32():
    """Skin-vertex cloud: x y z float32 fields, width n, values equal to the float32 rounding of the input."""
    rng = np.random.default_rng(2)
    xyz = rng.uniform(-1, 1, size=(5000, 3))
    msg = rm.xyz_cloud_from_numpy(xyz, 7)
    assert [f.name for f in msg.fields] == ["x", "y", "z"]
    assert all(f.datatype == PointField.FLOAT32 for f in msg.fields)
    assert msg.width == 5000 and msg.point_step == 12 and len(msg.data) == 60000
    back = deserialize_message(serialize_message(msg), PointCloud2)
    np.testing.assert_array_equal(rm.xyz_cloud_to_numpy(back), xyz.astype(np.float32).astype(np.float64))


def test_contacts_cloud_round_trip_all_fields():
    from softhand_sim.topics import SKIN_OBJECT

    """Contacts cloud has the 15 docs/INTERFACE.md fields with their types and round-trips each of
    them; 48 bytes a point; a cloud written before the hand field existed reads as the right
    hand's, one before the bone fields with NO_BONE; skin-skin rows carry SKIN_OBJECT and the
    other hand and bone."""
    rng = np.random.default_rng(3)
    n = 40
    pts, nrm, frc = rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    obj = rng.integers(0, 4, size=n)
    slip = rng.integers(0, 2, size=n)
    hand = rng.integers(0, 2, size=n)
    bone = rng.integers(0, 16, size=n)
    skin = rng.random(n) < 0.3  # skin-skin rows
    obj[skin] = SKIN_OBJECT
    other_hand = np.where(skin, rng.integers(0, 2, size=n), rm.NO_BONE)
    other_bone = np.where(skin, rng.integers(0, 16, size=n), rm.NO_BONE)
    msg = rm.contacts_cloud_from_numpy(pts, nrm, frc, obj, slip, 1.0, hand=hand, bone=bone,
                                       other_hand=other_hand, other_bone=other_bone)
    types = {f.name: f.datatype for f in msg.fields}
    assert list(types) == ["x", "y", "z", "nx", "ny", "nz", "fx", "fy", "fz", "object", "slip", "hand", "bone",
                           "other_hand", "other_bone"]
    assert types["object"] == PointField.UINT32 and types["slip"] == PointField.UINT8
    assert all(types[k] == PointField.UINT8 for k in ("hand", "bone", "other_hand", "other_bone"))
    assert msg.point_step == 48
    assert all(types[k] == PointField.FLOAT32 for k in list(types)[:9])
    back = rm.contacts_cloud_to_numpy(deserialize_message(serialize_message(msg), PointCloud2))
    np.testing.assert_array_equal(back["points"], pts.astype(np.float32))
    np.testing.assert_array_equal(back["normals"], nrm.astype(np.float32))
    np.testing.assert_array_equal(back["forces"], frc.astype(np.float32))
    np.testing.assert_array_equal(back["object"], obj)
    np.testing.assert_array_equal(back["slip"], slip)
    np.testing.assert_array_equal(back["hand"], hand)
    for name, want in (("bone", bone), ("other_hand", other_hand), ("other_bone", other_bone)):
        np.testing.assert_array_equal(back[name], want)
    old = deserialize_message(serialize_message(msg), PointCloud2)
    old.fields = [f for f in old.fields if f.name not in ("hand", "bone", "other_hand", "other_bone")]
    back_old = rm.contacts_cloud_to_numpy(old)  # as recorded before the fields existed
    assert not back_old["hand"].any() and np.all(back_old["bone"] == rm.NO_BONE)
    empty = rm.contacts_cloud_from_numpy(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), [], [], 0)
    assert rm.contacts_cloud_to_numpy(empty)["points"].shape == (0, 3)


def test_cloud_parser_handles_row_padding_and_big_endian():
    """The generic parser honours row_step padding and big-endian data written by another tool."""
    xyz = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0], [10.0, 11.0, 12.0]], dtype=">f4")
    rows = np.zeros((2, 2 * 12 + 4), dtype=np.uint8)  # 2 rows of 2 points, 4 pad bytes per row
    rows[:, :24] = np.frombuffer(xyz.tobytes(), dtype=np.uint8).reshape(2, 24)
    msg = PointCloud2(height=2, width=2, is_bigendian=True, point_step=12, row_step=28,
                      fields=[PointField(name=a, offset=4 * i, datatype=PointField.FLOAT32, count=1)
                              for i, a in enumerate("xyz")])
    msg.data = rows.tobytes()
    np.testing.assert_array_equal(rm.xyz_cloud_to_numpy(msg), xyz.astype(np.float64))


def test_mesh_and_triangle_marker():
    """Mesh round-trips vertices and triangles; the TRIANGLE_LIST marker has 3 points per triangle in order."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    v2, f2 = rm.mesh_to_numpy(rm.mesh_from_numpy(v, f))
    np.testing.assert_array_equal(v2, v)
    np.testing.assert_array_equal(f2, f)
    m = rm.triangle_marker(v, f, 0.5, color=(1, 0, 0, 0.5))
    assert m.type == Marker.TRIANGLE_LIST and m.header.frame_id == "world" and len(m.points) == 12
    got = np.array([(p.x, p.y, p.z) for p in m.points])
    np.testing.assert_array_equal(got, v[f.reshape(-1)])
    assert m.pose.orientation.w == 1.0 and m.color.a == pytest.approx(0.5)
    with pytest.raises(ValueError, match="out of range"):
        rm.mesh_from_numpy(v, [[0, 1, 4]])


def test_scene_markers_primitives():
    """Scene objects become primitives with the right scales; a capsule adds two end spheres along its z."""
    ident = [0, 0, 0, 0, 0, 0, 1]
    objs = [
        SimpleNamespace(name="table", shape="box", dims={"size": [0.8, 0.8, 0.75]}, pose=ident, static=True),
        SimpleNamespace(name="ball", shape="sphere", dims={"radius": 0.04}, pose=ident, static=False),
        SimpleNamespace(name="mug", shape="cylinder", dims={"radius": 0.04, "length": 0.1}, pose=ident, static=False),
        SimpleNamespace(name="pill", shape="capsule", dims={"radius": 0.02, "length": 0.1},
                        pose=[1, 2, 3, np.sin(np.pi / 4), 0, 0, np.cos(np.pi / 4)], static=False),
    ]
    arr = rm.scene_markers(objs, 1.0)
    kinds = [m.type for m in arr.markers]
    assert kinds == [Marker.CUBE, Marker.SPHERE, Marker.CYLINDER, Marker.CYLINDER, Marker.SPHERE, Marker.SPHERE]
    assert [m.id for m in arr.markers] == list(range(6))
    assert (arr.markers[0].scale.x, arr.markers[0].scale.z) == (0.8, 0.75)
    assert arr.markers[1].scale.x == pytest.approx(0.08)
    # capsule rotated 90 deg about x: its z axis is world -y, so the end spheres sit at y = 2 -/+ 0.05
    ends = sorted(m.pose.position.y for m in arr.markers[4:])
    assert ends == pytest.approx([1.95, 2.05])
    with pytest.raises(ValueError, match="'ball' .* lacks dimension 'radius'"):
        rm.scene_markers([SimpleNamespace(name="ball", shape="sphere", dims={}, pose=ident)], 0)


def test_diagnostics_from_dict():
    """DiagnosticArray from a dict: keys kept, floats formatted, level mapped; an unknown level is refused."""
    st = rm.diagnostic_status("sim_node", {"step_ms_p50": 1.23456789, "overruns": 3}, "warn", "slow")
    arr = rm.diagnostic_array([st], 2.0)
    assert arr.header.frame_id == "world" and arr.status[0].level == rm.LEVELS["warn"]
    assert rm.diagnostic_values(arr.status[0]) == {"step_ms_p50": "1.23457", "overruns": "3"}
    with pytest.raises(ValueError, match="diagnostic level"):
        rm.diagnostic_status("x", {}, "fatal")


def test_large_cloud_packing_keeps_every_point():
    """A 20k-vertex skin cloud (numpy tobytes path) packs every point as float32 x y z, in order."""
    xyz = np.random.default_rng(4).normal(size=(20000, 3))
    cloud = rm.xyz_cloud_from_numpy(xyz, 0)
    back = np.frombuffer(bytes(cloud.data), dtype=np.float32).reshape(-1, cloud.point_step // 4)[:, :3]
    assert cloud.width * cloud.height == 20000
    np.testing.assert_array_equal(back, xyz.astype(np.float32))


def test_fast_triangle_marker_bytes_equal_rclpy_serialization():
    """The numpy-built CDR of a TRIANGLE_LIST marker decodes to exactly the marker rclpy builds (all fields)."""
    rng = np.random.default_rng(5)
    v = rng.normal(size=(50, 3))
    f = rng.integers(0, 50, size=(70, 3))
    fast = rm.TriangleMarkerSerializer(color=(0.1, 0.2, 0.3, 0.4), ns="skin", marker_id=7)
    for stamp, tris in ((12.25, f), (1_700_000_000_123_456_789, f[:1]), (0, f[:0])):
        ref = rm.triangle_marker(v, tris, stamp, color=(0.1, 0.2, 0.3, 0.4), ns="skin", marker_id=7)
        fast_bytes = fast.serialize(v, tris, stamp)
        assert len(fast_bytes) == len(serialize_message(ref))
        # compare decoded messages (float32 colour fields are rounded by any serialization)
        assert deserialize_message(fast_bytes, Marker) == deserialize_message(serialize_message(ref), Marker)
    back = deserialize_message(fast.serialize(v, f, 3.0), Marker)
    assert len(back.points) == 210 and back.points[5].y == v[f[1, 2], 1]


def test_marker_points_read_from_cdr_as_rclpy_reads_them():
    """marker_points_from_cdr (the preview's reader of skin markers) gives the points rclpy
    decodes, for every length of frame_id and ns modulo the alignments (each string shifts what
    follows), with and without points, from rclpy's serialization and from the sim's numpy-built
    one; bytes too short for their point count are refused by name."""
    rng = np.random.default_rng(9)
    v = rng.normal(size=(30, 3))
    f = rng.integers(0, 30, size=(12, 3))
    for frame in ("", "w", "wo", "wor", "worl", "world", "world_frame"):
        for ns in ("", "s", "sk", "ski", "skin", "skin_x", "skin_xyz"):
            for tris in (f, f[:0]):
                raw = serialize_message(rm.triangle_marker(v, tris, 3.5, ns=ns, frame_id=frame))
                expected = np.array([[p.x, p.y, p.z] for p in deserialize_message(raw, Marker).points]).reshape(-1, 3)
                np.testing.assert_array_equal(rm.marker_points_from_cdr(raw), expected)
    fast = rm.TriangleMarkerSerializer(ns="skin", marker_id=1).serialize(v, f, 2.0)
    np.testing.assert_array_equal(rm.marker_points_from_cdr(fast), v[f.reshape(-1)])
    for bad, what in ((b"", "bytes"), (fast[:-220], "points need"),  # cut within the 36 points
                      (b"\x00\x01\x00\x00" + bytes(8) + (99).to_bytes(4, "little"), "string")):
        with pytest.raises(ValueError, match=what):
            rm.marker_points_from_cdr(bad)
