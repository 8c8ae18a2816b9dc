"""ROS 2 message <-> numpy conversions for every softhand topic (docs/INTERFACE.md).

Message types only: nothing here creates a node, so the sim, tracking and world nodes and the
tests share one set of conversions. Conventions of docs/ARCHITECTURE.md: SI units, poses
(n, 7) float64 as [px, py, pz, qx, qy, qz, qw] (quaternion x y z w, the ROS order), twists
(n, 6) as [vx, vy, vz, wx, wy, wz] in the world frame, every message stamped and in frame
``world``.

Stamps: a ROS ``builtin_interfaces/Time`` is (sec int32, nanosec uint32). Here a stamp is either
integer nanoseconds (exact; what bags store) or float seconds (convenient; ~0.1 us resolution at
epoch times, fine for physics but not for keys).

PointCloud2 payloads are packed with numpy structured arrays and ``tobytes`` and handed to the
message as an ``array.array('B')`` (the generated setter takes that without a per-byte check), so
a cloud of thousands of points costs microseconds, not milliseconds.
"""
from __future__ import annotations

import array
from typing import Iterable, Mapping, Sequence

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, Pose, PoseArray, Transform, Twist
from sensor_msgs.msg import PointCloud2, PointField
from shape_msgs.msg import Mesh, MeshTriangle
from std_msgs.msg import ColorRGBA, Header
from trajectory_msgs.msg import MultiDOFJointTrajectory, MultiDOFJointTrajectoryPoint
from visualization_msgs.msg import Marker, MarkerArray

from softhand_sim.topics import NO_BONE  # `bone` / `other_hand` / `other_bone` where there is none

WORLD_FRAME = "world"
_NS_PER_S = 1_000_000_000

# ----------------------------------------------------------------------------------------- stamps


def stamp_from_ns(ns: int) -> Time:
    """builtin_interfaces/Time from integer nanoseconds (>= 0)."""
    ns = int(ns)
    if ns < 0:
        raise ValueError(f"stamp must be >= 0 ns, got {ns}")
    return Time(sec=ns // _NS_PER_S, nanosec=ns % _NS_PER_S)


def seconds_to_ns(t: float) -> int:
    """Integer nanoseconds of float seconds (rounded to the nearest nanosecond)."""
    return int(round(float(t) * _NS_PER_S))


def stamp_from_seconds(t: float) -> Time:
    """builtin_interfaces/Time from float seconds (rounded to the nearest nanosecond)."""
    return stamp_from_ns(seconds_to_ns(t))


def stamp_to_ns(stamp) -> int:
    """Integer nanoseconds of a builtin_interfaces/Time (or a rosbags Time, same fields)."""
    return int(stamp.sec) * _NS_PER_S + int(stamp.nanosec)


def stamp_to_seconds(stamp) -> float:
    """Float seconds of a builtin_interfaces/Time."""
    return int(stamp.sec) + int(stamp.nanosec) * 1e-9


def _as_time(stamp) -> Time:
    """Accept a Time message, integer nanoseconds or float seconds."""
    if isinstance(stamp, Time):
        return stamp
    if isinstance(stamp, (int, np.integer)):
        return stamp_from_ns(int(stamp))
    if isinstance(stamp, (float, np.floating)):
        return stamp_from_seconds(float(stamp))
    raise TypeError(f"stamp must be builtin_interfaces/Time, int ns or float s, got {type(stamp).__name__}")


def make_header(stamp, frame_id: str = WORLD_FRAME) -> Header:
    """std_msgs/Header in frame `frame_id` (default 'world'); stamp as Time, int ns or float s."""
    return Header(stamp=_as_time(stamp), frame_id=frame_id)


# ------------------------------------------------------------------------------------------ poses


def _check_rows(name: str, arr, width: int) -> np.ndarray:
    out = np.asarray(arr, dtype=np.float64)
    if out.ndim != 2 or out.shape[1] != width:
        raise ValueError(f"{name} must have shape (n, {width}), got {out.shape}")
    if not np.all(np.isfinite(out)):
        raise ValueError(f"{name} contains non-finite values")
    return out


def pose_array_from_numpy(poses, stamp, frame_id: str = WORLD_FRAME) -> PoseArray:
    """geometry_msgs/PoseArray from poses (n, 7) [m, quaternion x y z w]."""
    p = _check_rows("poses", poses, 7)
    msg = PoseArray(header=make_header(stamp, frame_id))
    out = []
    for px, py, pz, qx, qy, qz, qw in p.tolist():
        pose = Pose()
        pose.position.x, pose.position.y, pose.position.z = px, py, pz
        pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = qx, qy, qz, qw
        out.append(pose)
    msg.poses = out
    return msg


def pose_array_to_numpy(msg) -> np.ndarray:
    """Poses (n, 7) float64 [px py pz qx qy qz qw] of a PoseArray (rclpy or rosbags message)."""
    out = np.empty((len(msg.poses), 7), dtype=np.float64)
    for i, pose in enumerate(msg.poses):
        p, q = pose.position, pose.orientation
        out[i] = (p.x, p.y, p.z, q.x, q.y, q.z, q.w)
    return out


# CDR (the bytes on the wire and in bags) of a PoseArray, written and read with numpy. Converting
# a PoseArray between Python objects and CDR is most of what publishing or taking it costs in
# rclpy (serialize_message of 16 poses: ~80 us; a publish of the bytes: ~5 us), and the tracking
# node does it 250 times a second. Layout (XCDR1, offsets after the 4-byte encapsulation header):
# Header.stamp sec int32, nanosec uint32; frame_id uint32 length (with the NUL), bytes, NUL;
# aligned to 4: uint32 pose count; aligned to 8: 7 float64 per pose (position x y z, orientation
# x y z w). rclpy's publish() and take with raw=True take and give exactly these bytes.
_CDR_LE = b"\x00\x01\x00\x00"


def _pad(offset: int, align: int) -> int:
    return (-offset) % align


def header_cdr(stamp_ns: int, frame_id: str) -> bytes:
    """CDR of a std_msgs/Header (stamp sec, nanosec; frame_id) at the start of a message body,
    unpadded at its end (the bytes of every message that begins with a Header)."""
    sec, nsec = divmod(int(stamp_ns), _NS_PER_S)
    if not 0 <= sec < 2**31:
        raise ValueError(f"stamp must be in [0, 2^31) s as builtin_interfaces/Time, got {stamp_ns} ns")
    name = frame_id.encode() + b"\x00"
    return np.array([sec, nsec], dtype="<u4").tobytes() + len(name).to_bytes(4, "little") + name


def pose_array_cdr(poses, stamp_ns: int, frame_id: str = WORLD_FRAME) -> bytes:
    """CDR bytes of a geometry_msgs/PoseArray of poses (n, 7) [m, quaternion x y z w] stamped
    `stamp_ns` [ns] (the bytes serialize_message gives for pose_array_from_numpy(...))."""
    p = _check_rows("poses", poses, 7)
    body = header_cdr(stamp_ns, frame_id)
    body += bytes(_pad(len(body), 4)) + len(p).to_bytes(4, "little")
    body += bytes(_pad(len(body), 8)) if len(p) else b""
    return _CDR_LE + body + p.astype("<f8").tobytes()


def _cdr_body(raw: bytes, what: str):
    """(body after the 4-byte encapsulation header, numpy byte-order prefix) of CDR bytes."""
    buf = memoryview(raw)
    if len(buf) < 16 or buf[0] != 0 or buf[1] not in (0, 1):
        raise ValueError(f"not a CDR {what}: {len(buf)} bytes starting {bytes(buf[:4])!r}")
    return buf[4:], "<" if buf[1] == 1 else ">"


def _cdr_f8_rows(body, off: int, e: str, width: int, what: str, rows: str) -> np.ndarray:
    """The sequence at `off` (aligned 4) of `body` whose elements are `width` float64 each, as an
    (n, width) array: its uint32 count, then the values aligned 8."""
    off += _pad(off, 4)
    if off + 4 > len(body):
        raise ValueError(f"not a CDR {what}: {len(body)} bytes end before the {rows[:-1]} count")
    n = int(np.frombuffer(body, dtype=e + "u4", count=1, offset=off)[0])
    off += 4
    off += _pad(off, 8) if n else 0
    if off + 8 * width * n > len(body):
        raise ValueError(f"not a CDR {what}: {n} {rows} need {8 * width * n} bytes, {len(body) - off} left")
    return np.frombuffer(body, dtype=e + "f8", count=width * n, offset=off).reshape(n, width).astype(np.float64)


def pose_array_from_cdr(raw: bytes):
    """(poses (n, 7) float64, stamp [ns], frame_id) of a PoseArray's CDR bytes (either byte order).
    ValueError naming what is wrong for bytes that are not a PoseArray."""
    body, e = _cdr_body(raw, "PoseArray")
    sec, nsec, nlen = np.frombuffer(body, dtype=e + "u4", count=3)
    sec = int(np.int32(sec))
    off = 12 + int(nlen)
    if nlen < 1 or off > len(body):
        raise ValueError(f"not a CDR PoseArray: frame_id length {int(nlen)} in {len(body)} bytes")
    frame_id = bytes(body[12:off - 1]).decode(errors="replace")
    poses = _cdr_f8_rows(body, off, e, 7, "PoseArray", "poses")
    return poses, sec * _NS_PER_S + int(nsec), frame_id


# ---------------------------------------------------------------------------------- object states


def object_states_from_numpy(names: Sequence[str], poses, twists, accels, stamp,
                             frame_id: str = WORLD_FRAME) -> MultiDOFJointTrajectory:
    """trajectory_msgs/MultiDOFJointTrajectory per docs/INTERFACE.md "Object state messages".

    joint_names = object names; exactly one point whose transforms (poses (n, 7) [m, quat xyzw]),
    velocities (twists (n, 6) [m/s, rad/s], world frame) and accelerations (accels (n, 6)
    [m/s^2, rad/s^2]) describe each object at header.stamp; time_from_start = 0.
    """
    names, p, v, a = object_rows(names, poses, twists, accels)
    point = MultiDOFJointTrajectoryPoint()
    transforms, velocities, accelerations = [], [], []
    for px, py, pz, qx, qy, qz, qw in p.tolist():
        tf = Transform()
        tf.translation.x, tf.translation.y, tf.translation.z = px, py, pz
        tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w = qx, qy, qz, qw
        transforms.append(tf)
    for rows, dest in ((v, velocities), (a, accelerations)):
        for lx, ly, lz, ax, ay, az in rows.tolist():
            tw = Twist()
            tw.linear.x, tw.linear.y, tw.linear.z = lx, ly, lz
            tw.angular.x, tw.angular.y, tw.angular.z = ax, ay, az
            dest.append(tw)
    point.transforms, point.velocities, point.accelerations = transforms, velocities, accelerations
    return MultiDOFJointTrajectory(header=make_header(stamp, frame_id), joint_names=names, points=[point])


def object_rows(names, poses, twists, accels):
    """(names as str, poses (n, 7), twists (n, 6), accels (n, 6)) of an object state message, checked
    (ValueError naming a non-finite value or a row count that is not the names')."""
    names = [str(n) for n in names]
    rows = _check_rows("poses", poses, 7), _check_rows("twists", twists, 6), _check_rows("accels", accels, 6)
    for label, arr in zip(("poses", "twists", "accels"), rows):
        if arr.shape[0] != len(names):
            raise ValueError(f"{label} has {arr.shape[0]} rows for {len(names)} object names")
    return (names, *rows)


def object_states_to_numpy(msg):
    """(names list, poses (n,7), twists (n,6), accels (n,6), stamp_ns int) of an object state message.

    Raises ValueError naming the problem when the message breaks the contract (not exactly one
    point, or transforms/velocities/accelerations not one per name). Missing velocities or
    accelerations (empty lists) read as zeros.
    """
    names = list(msg.joint_names)
    n = len(names)
    if len(msg.points) != 1:
        raise ValueError(f"object state message must have exactly one point, got {len(msg.points)}")
    pt = msg.points[0]
    if len(pt.transforms) != n:
        raise ValueError(f"object state message has {len(pt.transforms)} transforms for {n} joint_names")
    poses = np.empty((n, 7))
    for i, tf in enumerate(pt.transforms):
        t, q = tf.translation, tf.rotation
        poses[i] = (t.x, t.y, t.z, q.x, q.y, q.z, q.w)
    twists = _twists_to_numpy("velocities", pt.velocities, n)
    accels = _twists_to_numpy("accelerations", pt.accelerations, n)
    return names, poses, twists, accels, stamp_to_ns(msg.header.stamp)


def _twists_to_numpy(label: str, twists, n: int) -> np.ndarray:
    out = np.zeros((n, 6))
    if len(twists) == 0:
        return out
    if len(twists) != n:
        raise ValueError(f"object state message has {len(twists)} {label} for {n} joint_names")
    for i, tw in enumerate(twists):
        out[i] = (tw.linear.x, tw.linear.y, tw.linear.z, tw.angular.x, tw.angular.y, tw.angular.z)
    return out


# ------------------------------------------------------------------------------------ PointCloud2

# PointField datatype -> numpy dtype (little-endian; big-endian clouds are byte-swapped on read).
_FIELD_DTYPES = {
    PointField.INT8: np.int8, PointField.UINT8: np.uint8,
    PointField.INT16: np.int16, PointField.UINT16: np.uint16,
    PointField.INT32: np.int32, PointField.UINT32: np.uint32,
    PointField.FLOAT32: np.float32, PointField.FLOAT64: np.float64,
}
_DTYPE_FIELDS = {np.dtype(v): k for k, v in _FIELD_DTYPES.items()}

# /hand/contacts layout (docs/INTERFACE.md): 9 float32, object uint32, slip uint8, hand uint8
# (0 right, 1 left), bone uint8 (0-15, of that hand), other_hand and other_bone uint8 (skin-skin
# contacts: the touched skin's; NO_BONE otherwise), padded to 4 bytes.
CONTACT_DTYPE = np.dtype({
    "names": ["x", "y", "z", "nx", "ny", "nz", "fx", "fy", "fz", "object", "slip", "hand", "bone",
              "other_hand", "other_bone"],
    "formats": [np.float32] * 9 + [np.uint32] + [np.uint8] * 5,
    "offsets": [0, 4, 8, 12, 16, 20, 24, 28, 32, 36, 40, 41, 42, 43, 44],
    "itemsize": 48,
})
_OPTIONAL_CONTACT_FIELDS = ("hand", "bone", "other_hand", "other_bone")  # absent from older recordings
XYZ_DTYPE = np.dtype({"names": ["x", "y", "z"], "formats": [np.float32] * 3, "offsets": [0, 4, 8], "itemsize": 12})


def _bytes_to_uint8_array(buf: bytes) -> array.array:
    data = array.array("B")
    data.frombytes(buf)
    return data


def pointcloud_from_structured(points: np.ndarray, stamp, frame_id: str = WORLD_FRAME) -> PointCloud2:
    """Unordered (height 1) little-endian PointCloud2 from a structured array, one field per name."""
    if points.dtype.names is None:
        raise ValueError("points must be a numpy structured array (named fields)")
    fields = []
    for name in points.dtype.names:
        dt, offset = points.dtype.fields[name][:2]
        if dt.newbyteorder("<") not in _DTYPE_FIELDS:
            raise ValueError(f"field {name!r}: dtype {dt} has no PointField datatype")
        fields.append(PointField(name=name, offset=offset, datatype=_DTYPE_FIELDS[dt.newbyteorder("<")], count=1))
    n = int(points.shape[0])
    step = points.dtype.itemsize
    msg = PointCloud2(header=make_header(stamp, frame_id), height=1, width=n, fields=fields,
                      is_bigendian=False, point_step=step, row_step=step * n, is_dense=True)
    # copy=False: a little-endian array keeps its zeroed padding bytes (astype's copy leaves them
    # uninitialised, so recordings differed in bytes no field reads)
    msg.data = _bytes_to_uint8_array(np.ascontiguousarray(points).astype(points.dtype.newbyteorder("<"),
                                                                          copy=False).tobytes())
    return msg


def pointcloud_to_structured(msg) -> np.ndarray:
    """Structured array (height*width,) of a PointCloud2 (any field layout, row padding, endianness)."""
    names, formats, offsets = [], [], []
    for f in msg.fields:
        if f.datatype not in _FIELD_DTYPES:
            raise ValueError(f"PointCloud2 field {f.name!r} has unknown datatype {f.datatype}")
        dt = np.dtype(_FIELD_DTYPES[f.datatype]).newbyteorder(">" if msg.is_bigendian else "<")
        names.append(f.name)
        formats.append(dt if f.count <= 1 else (dt, int(f.count)))
        offsets.append(int(f.offset))
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": int(msg.point_step)})
    height, width, row_step = int(msg.height), int(msg.width), int(msg.row_step)
    raw = np.frombuffer(msg.data, dtype=np.uint8)
    if raw.size < height * row_step or row_step < width * msg.point_step:
        raise ValueError(f"PointCloud2 data has {raw.size} bytes, expected {height} rows of {row_step}")
    rows = raw[: height * row_step].reshape(height, row_step)[:, : width * msg.point_step]
    return np.ascontiguousarray(rows).view(dtype).reshape(-1)


def xyz_cloud_from_numpy(xyz, stamp, frame_id: str = WORLD_FRAME) -> PointCloud2:
    """PointCloud2 with fields x y z float32 from positions (n, 3) [m] (/hand/skin_vertices)."""
    p = _check_rows("xyz", xyz, 3)
    pts = np.empty(p.shape[0], dtype=XYZ_DTYPE)
    pts["x"], pts["y"], pts["z"] = p[:, 0], p[:, 1], p[:, 2]
    return pointcloud_from_structured(pts, stamp, frame_id)


def xyz_cloud_to_numpy(msg) -> np.ndarray:
    """Positions (n, 3) float64 [m] from a PointCloud2 that has x, y, z fields."""
    pts = pointcloud_to_structured(msg)
    for axis in ("x", "y", "z"):
        if axis not in pts.dtype.names:
            raise ValueError(f"PointCloud2 has no field {axis!r} (fields: {pts.dtype.names})")
    return np.stack([pts["x"], pts["y"], pts["z"]], axis=1).astype(np.float64)


def contacts_cloud_from_numpy(points, normals, forces, objects, slip, stamp,
                              frame_id: str = WORLD_FRAME, hand=None, bone=None, other_hand=None,
                              other_bone=None) -> PointCloud2:
    """/hand/contacts PointCloud2: one point per active contact.

    points (n, 3) [m], normals (n, 3) unit, forces (n, 3) [N] (force on the hand), objects (n,)
    object index (uint32; SKIN_OBJECT for skin on skin), slip (n,) 0 stick / 1 slip (uint8), hand
    (n,) 0 right / 1 left (uint8; None: all right), bone (n,) the bone (0-15) whose skin touches,
    other_hand / other_bone (n,) the touched skin's for skin-skin contacts (None: NO_BONE).
    (cdr_messages.contacts_cloud_cdr: the same message as CDR bytes, what sim_node publishes.)
    """
    return pointcloud_from_structured(contact_points(points, normals, forces, objects, slip, hand, bone,
                                                     other_hand, other_bone), stamp, frame_id)


def contact_points(points, normals, forces, objects, slip, hand=None, bone=None, other_hand=None,
                   other_bone=None) -> np.ndarray:
    """The CONTACT_DTYPE rows of contacts_cloud_from_numpy's arguments (ValueError naming a
    mismatched length)."""
    p = _check_rows("points", points, 3)
    n = p.shape[0]
    nrm = _check_rows("normals", normals, 3)
    frc = _check_rows("forces", forces, 3)
    obj = np.asarray(objects).reshape(-1)
    slp = np.asarray(slip).reshape(-1)
    hnd = np.zeros(n, np.uint8) if hand is None else np.asarray(hand).reshape(-1)
    extra = {name: np.full(n, NO_BONE, np.uint8) if arr is None else np.asarray(arr).reshape(-1)
             for name, arr in (("bone", bone), ("other_hand", other_hand), ("other_bone", other_bone))}
    for label, arr in (("normals", nrm), ("forces", frc), ("objects", obj), ("slip", slp), ("hand", hnd),
                       *extra.items()):
        if arr.shape[0] != n:
            raise ValueError(f"{label} has {arr.shape[0]} rows for {n} contact points")
    pts = np.zeros(n, dtype=CONTACT_DTYPE)
    for i, axis in enumerate("xyz"):
        pts[axis] = p[:, i]
        pts["n" + axis] = nrm[:, i]
        pts["f" + axis] = frc[:, i]
    pts["object"] = obj.astype(np.uint32)
    pts["slip"] = slp.astype(np.uint8)
    pts["hand"] = hnd.astype(np.uint8)
    for name, arr in extra.items():
        pts[name] = arr.astype(np.uint8)
    return pts


def contacts_cloud_to_numpy(msg) -> dict:
    """Dict of arrays from a /hand/contacts cloud: points, normals, forces (n,3) f8, object (n,) u4,
    slip (n,) u1, hand (n,) u1 (0 right, 1 left; all 0 in single-hand recordings made before the
    field existed), bone, other_hand, other_bone (n,) u1 (NO_BONE where a recording lacks them)."""
    pts = pointcloud_to_structured(msg)
    missing = [k for k in CONTACT_DTYPE.names if k not in pts.dtype.names and k not in _OPTIONAL_CONTACT_FIELDS]
    if missing:
        raise ValueError(f"contacts cloud lacks fields {missing}")

    def vec(prefix):
        return np.stack([pts[prefix + a] for a in "xyz"], axis=1).astype(np.float64)

    return {"points": vec(""), "normals": vec("n"), "forces": vec("f"),
            "object": pts["object"].astype(np.uint32), "slip": pts["slip"].astype(np.uint8),
            "hand": (pts["hand"].astype(np.uint8) if "hand" in pts.dtype.names else np.zeros(len(pts), np.uint8)),
            **{name: (pts[name].astype(np.uint8) if name in pts.dtype.names else np.full(len(pts), NO_BONE, np.uint8))
               for name in ("bone", "other_hand", "other_bone")}}


# ------------------------------------------------------------------------------- meshes, markers


def _points_from_numpy(xyz: np.ndarray) -> list:
    return [Point(x=x, y=y, z=z) for x, y, z in xyz.tolist()]


def _check_triangles(triangles, vertex_count: int) -> np.ndarray:
    tri = np.asarray(triangles)
    if tri.ndim != 2 or tri.shape[1] != 3:
        raise ValueError(f"triangles must have shape (F, 3), got {tri.shape}")
    if tri.size and (tri.min() < 0 or tri.max() >= vertex_count):
        raise ValueError(f"triangle indices out of range [0, {vertex_count})")
    return tri.astype(np.int64)


def mesh_from_numpy(vertices, triangles) -> Mesh:
    """shape_msgs/Mesh from vertices (V, 3) [m] and triangles (F, 3) (indices, CCW outward)."""
    v = _check_rows("vertices", vertices, 3)
    tri = _check_triangles(triangles, v.shape[0])
    msg = Mesh()
    msg.vertices = _points_from_numpy(v)
    msg.triangles = [MeshTriangle(vertex_indices=np.asarray(t, dtype=np.uint32)) for t in tri]
    return msg


def mesh_to_numpy(msg):
    """(vertices (V,3) f8, triangles (F,3) i4) of a shape_msgs/Mesh."""
    v = np.array([(p.x, p.y, p.z) for p in msg.vertices], dtype=np.float64).reshape(-1, 3)
    f = np.array([list(t.vertex_indices) for t in msg.triangles], dtype=np.int32).reshape(-1, 3)
    return v, f


def _color(rgba) -> ColorRGBA:
    r, g, b, a = (float(c) for c in rgba)
    return ColorRGBA(r=r, g=g, b=b, a=a)


def triangle_marker(vertices, triangles, stamp, color=(0.9, 0.7, 0.6, 1.0), ns: str = "skin",
                    marker_id: int = 0, frame_id: str = WORLD_FRAME) -> Marker:
    """visualization_msgs/Marker TRIANGLE_LIST: three points per triangle, identity pose, one colour."""
    v = _check_rows("vertices", vertices, 3)
    tri = _check_triangles(triangles, v.shape[0])
    m = Marker(header=make_header(stamp, frame_id), ns=ns, id=int(marker_id), type=Marker.TRIANGLE_LIST,
               action=Marker.ADD, frame_locked=False)
    m.pose.orientation.w = 1.0
    m.scale.x = m.scale.y = m.scale.z = 1.0
    m.color = _color(color)
    m.points = _points_from_numpy(v[tri.reshape(-1)])
    return m


class TriangleMarkerSerializer:
    """Serialized (CDR) TRIANGLE_LIST markers built with numpy, for publishing at a steady rate.

    rclpy needs ~1.7 us to build and ~5 us to serialize each geometry_msgs/Point, i.e. ~0.1 s for a
    6000-triangle skin: too slow for 10 Hz on two cores. The marker's CDR bytes are
    prefix | point count | pad | float64 xyz... | suffix, and only the stamp and the points change,
    so the prefix and suffix are taken once from rclpy's own serialization of a one-point template
    marker and reused. rclpy's
    ``Publisher.publish`` accepts the bytes as they are. That they decode to the same message as
    rclpy's serialization is checked in tests/ros/test_msgs.py.
    """

    def __init__(self, color=(0.9, 0.7, 0.6, 1.0), ns: str = "skin", marker_id: int = 0,
                 frame_id: str = WORLD_FRAME):
        from rclpy.serialization import serialize_message

        template = triangle_marker(np.zeros((3, 3)), np.zeros((0, 3), dtype=np.int64), 0, color, ns, marker_id,
                                   frame_id)
        template.points = [Point(x=1.5, y=2.5, z=3.5)]
        one = serialize_message(template)
        # padding bytes of rclpy's CDR are not zeroed, so locate the points by their values
        data_pos = one.find(np.array([1.5, 2.5, 3.5], "<f8").tobytes())
        count = np.array([1], "<u4").tobytes()
        if data_pos < 0 or count not in (one[data_pos - 4:data_pos], one[data_pos - 8:data_pos - 4]):
            raise RuntimeError("unexpected Marker CDR layout (is the platform big-endian?)")
        count_pos = data_pos - 4 if one[data_pos - 4:data_pos] == count else data_pos - 8
        self._prefix = bytearray(one[:count_pos])
        self._pad = b"\x00" * (data_pos - count_pos - 4)  # float64 elements are 8-aligned
        self._suffix = one[data_pos + 24:]

    def serialize(self, vertices, triangles, stamp) -> bytes:
        """CDR bytes of the TRIANGLE_LIST marker of mesh (vertices (V,3) [m], triangles (F,3)) at `stamp`."""
        v = _check_rows("vertices", vertices, 3)
        tri = _check_triangles(triangles, v.shape[0])
        t = _as_time(stamp)
        self._prefix[4:12] = np.array([t.sec], "<i4").tobytes() + np.array([t.nanosec], "<u4").tobytes()
        pts = np.ascontiguousarray(v[tri.reshape(-1)], dtype="<f8")
        return b"".join((self._prefix, np.array([pts.shape[0]], "<u4").tobytes(), self._pad, pts.tobytes(),
                         self._suffix))


def _cdr_string_end(body, off: int, e: str) -> int:
    """Offset just past the CDR string at `off` of `body` (its uint32 length, NUL included, aligned 4)."""
    off += _pad(off, 4)
    n = int(np.frombuffer(body, dtype=e + "u4", count=1, offset=off)[0])
    if n < 1 or off + 4 + n > len(body):
        raise ValueError(f"not a CDR Marker: a string of {n} bytes at {off} in {len(body)}")
    return off + 4 + n


def marker_points_from_cdr(raw: bytes) -> np.ndarray:
    """The points (n, 3) float64 of a visualization_msgs/Marker's CDR bytes (either byte order),
    read where they lie: after the header, ns, id, type, action, pose, scale, color, lifetime and
    frame_locked. For a skin marker (70,000 points) the deserializer's objects took 17 ms a message,
    this 0.08 ms. ValueError naming what is wrong for bytes that are not a Marker."""
    body, e = _cdr_body(raw, "Marker")
    off = _cdr_string_end(body, 8, e)   # stamp (8 bytes), then header.frame_id
    off = _cdr_string_end(body, off, e)  # ns
    off += _pad(off, 4) + 12            # id, type, action
    off += _pad(off, 8) + 80            # pose (7 float64), scale (3)
    off += 16 + 8 + 1                   # color (4 float32), lifetime (int32, uint32), frame_locked
    return _cdr_f8_rows(body, off, e, 3, "Marker", "points")


def _set_pose(m: Marker, pose) -> None:
    px, py, pz, qx, qy, qz, qw = (float(c) for c in pose)
    m.pose.position.x, m.pose.position.y, m.pose.position.z = px, py, pz
    m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z, m.pose.orientation.w = qx, qy, qz, qw


def _offset_pose(pose, local_z: float) -> np.ndarray:
    """Pose moved by local_z along its own z axis (capsule end spheres)."""
    p = np.asarray(pose, dtype=np.float64)
    x, y, z, w = p[3:]
    # third column of the rotation matrix of quaternion (x, y, z, w)
    axis = np.array([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)])
    out = p.copy()
    out[:3] += local_z * axis
    return out


GROUND_NS = "ground"
GROUND_SIZE = 4.0        # [m] edge of the square drawn for the ground plane (the plane is infinite)
GROUND_THICKNESS = 0.002  # [m] the slab's top face is the plane


def scene_markers(objects: Iterable, stamp, poses=None, ns: str = "world", frame_id: str = WORLD_FRAME,
                  static_color=(0.6, 0.6, 0.6, 1.0), dynamic_color=(0.2, 0.5, 0.9, 1.0),
                  ground_height: float | None = None, ground_color=(0.45, 0.5, 0.45, 1.0)) -> MarkerArray:
    """MarkerArray of scene objects as primitives (/world/markers).

    objects: items with attributes name, shape ('sphere' | 'box' | 'cylinder' | 'capsule' | 'mesh'),
    dims (dict: radius | size [sx, sy, sz] full edges | radius+length along z | file, scale),
    pose (7,) and static (bool) -- scene.SceneObject fits. poses: optional (n, 7) current poses
    overriding obj.pose. A capsule is three markers (cylinder + two end spheres); a mesh is a
    MESH_RESOURCE with a file:// URI. Marker ids are consecutive from 0 in object order.
    ground_height [m]: when given, the ground plane z = ground_height is drawn as well, a thin
    GROUND_SIZE square slab under the origin (namespace 'ground', id 0) whose top face is the plane.
    """
    objects = list(objects)
    cur = None if poses is None else _check_rows("poses", poses, 7)
    if cur is not None and cur.shape[0] != len(objects):
        raise ValueError(f"poses has {cur.shape[0]} rows for {len(objects)} objects")
    header = make_header(stamp, frame_id)
    out, next_id = [], 0

    def new(kind, pose, obj):
        nonlocal next_id
        m = Marker(header=header, ns=ns, id=next_id, type=kind, action=Marker.ADD)
        next_id += 1
        _set_pose(m, pose)
        m.color = _color(static_color if getattr(obj, "static", False) else dynamic_color)
        m.text = str(obj.name)
        out.append(m)
        return m

    for i, obj in enumerate(objects):
        pose = obj.pose if cur is None else cur[i]
        dims = dict(obj.dims)
        shape = str(obj.shape)
        try:
            if shape == "sphere":
                m = new(Marker.SPHERE, pose, obj)
                m.scale.x = m.scale.y = m.scale.z = 2.0 * float(dims["radius"])
            elif shape == "box":
                m = new(Marker.CUBE, pose, obj)
                m.scale.x, m.scale.y, m.scale.z = (float(s) for s in dims["size"])
            elif shape in ("cylinder", "capsule"):
                r, length = float(dims["radius"]), float(dims["length"])
                m = new(Marker.CYLINDER, pose, obj)
                m.scale.x = m.scale.y = 2.0 * r
                m.scale.z = length
                if shape == "capsule":
                    for end in (-0.5 * length, 0.5 * length):
                        s = new(Marker.SPHERE, _offset_pose(pose, end), obj)
                        s.scale.x = s.scale.y = s.scale.z = 2.0 * r
            elif shape == "mesh":
                m = new(Marker.MESH_RESOURCE, pose, obj)
                m.mesh_resource = "file://" + str(dims["file"])
                m.scale.x = m.scale.y = m.scale.z = float(dims.get("scale", 1.0))
            else:
                raise ValueError(f"object {obj.name!r}: unknown shape {shape!r}")
        except KeyError as exc:
            raise ValueError(f"object {obj.name!r} ({shape}) lacks dimension {exc.args[0]!r}") from None
    if ground_height is not None:
        g = Marker(header=header, ns=GROUND_NS, id=0, type=Marker.CUBE, action=Marker.ADD, text="ground")
        _set_pose(g, (0.0, 0.0, float(ground_height) - 0.5 * GROUND_THICKNESS, 0.0, 0.0, 0.0, 1.0))
        g.scale.x = g.scale.y = GROUND_SIZE
        g.scale.z = GROUND_THICKNESS
        g.color = _color(ground_color)
        out.append(g)
    return MarkerArray(markers=out)


# ------------------------------------------------------------------------------------ diagnostics

LEVELS = {"ok": DiagnosticStatus.OK, "warn": DiagnosticStatus.WARN,
          "error": DiagnosticStatus.ERROR, "stale": DiagnosticStatus.STALE}


def _level_byte(level) -> bytes:
    if isinstance(level, bytes):
        return level
    if isinstance(level, str):
        if level.lower() not in LEVELS:
            raise ValueError(f"diagnostic level must be one of {sorted(LEVELS)}, got {level!r}")
        return LEVELS[level.lower()]
    return bytes([int(level)])


def _format_value(value) -> str:
    if isinstance(value, (float, np.floating)):
        return f"{float(value):.6g}"
    return str(value)


# What each node's status is about: diagnostic_updater's convention names a status
# '<node>: <task>' and gives it a hardware id.
DIAGNOSTIC_TASKS = {"sim_node": "simulation", "tracking_node": "tracking loop", "world_node": "engine",
                    "record_node": "recorder", "play_node": "replay"}


def diagnostic_name(node_name: str, task: str | None = None) -> str:
    """'<node>: <task>' (the diagnostic_updater convention), e.g. 'sim_node: simulation'."""
    return f"{node_name}: {task or DIAGNOSTIC_TASKS.get(node_name, 'status')}"


def status_node(name: str) -> str:
    """The node part of a status name '<node>: <task>' (the whole name if it has no task)."""
    return name.split(":", 1)[0].strip()


def diagnostic_status(name: str, values: Mapping, level="ok", message: str = "",
                      hardware_id: str = "") -> DiagnosticStatus:
    """DiagnosticStatus from a dict key -> value (floats with 6 significant digits); level ok|warn|error|stale."""
    return DiagnosticStatus(level=_level_byte(level), name=name, message=message, hardware_id=hardware_id,
                            values=[KeyValue(key=str(k), value=_format_value(v)) for k, v in values.items()])


def diagnostic_array(statuses: Sequence[DiagnosticStatus], stamp) -> DiagnosticArray:
    """DiagnosticArray of statuses, stamped (frame 'world' like every softhand message)."""
    return DiagnosticArray(header=make_header(stamp), status=list(statuses))


def diagnostic_values(status) -> dict:
    """key -> value (strings) of a DiagnosticStatus."""
    return {kv.key: kv.value for kv in status.values}
