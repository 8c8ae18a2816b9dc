"""CDR bytes of sim_node's per-step /hand/contacts and /hand/object_states, written with numpy.

At 150-200 Hz sim_node builds and publishes these every step. As rclpy message objects they cost
about 0.5 ms a tick (measured: a 290-contact PointCloud2 built in 260 us and serialized in 56 us,
the object states built in 80 us and serialized in 83 us), a tenth of the step beside it. As
bytes they cost a few tens of us; rclpy's publish() takes the bytes as they are (as it does for
the bones, msgs.pose_array_cdr). Each function returns what serialize_message gives for its
message-object twin in msgs, of the same length and read back by rclpy to the same message (the
alignment padding, which rclpy leaves uninitialised, is zero here; tests/ros/test_msgs.py).

XCDR1 little endian: a 4-byte encapsulation header, then each primitive aligned to its size
counted from the end of that header; strings are a uint32 length (with the NUL), the bytes and
the NUL; sequences a uint32 count, then the elements.
"""
from __future__ import annotations

import functools

import numpy as np

from softhand_sim.ros.msgs import _CDR_LE, _DTYPE_FIELDS, WORLD_FRAME, _pad, contact_points, header_cdr, object_rows


class _Writer:
    """Appends CDR primitives, aligned from the start of the body (after the encapsulation header)."""

    def __init__(self):
        self.parts, self.size = [], 0

    def raw(self, data: bytes, align: int = 1):
        pad = _pad(self.size, align)
        if pad:
            self.parts.append(bytes(pad))
        self.parts.append(data)
        self.size += pad + len(data)

    def u4(self, value: int):
        self.raw(int(value).to_bytes(4, "little"), 4)

    def u1(self, value: int):
        self.raw(bytes((int(value),)))

    def string(self, text: str):
        data = text.encode() + b"\x00"
        self.u4(len(data))
        self.raw(data)

    def header(self, stamp_ns: int, frame_id: str):
        self.raw(header_cdr(stamp_ns, frame_id), 4)

    def f8_rows(self, rows: np.ndarray):
        """A sequence of fixed-size float64 structs (Transform, Twist): count, then the values
        (aligned to 8 only when there are any, as rclpy writes them)."""
        self.u4(len(rows))
        if len(rows):
            self.raw(np.ascontiguousarray(rows, dtype="<f8").tobytes(), 8)

    def cdr(self) -> bytes:
        return _CDR_LE + b"".join(self.parts)


@functools.lru_cache(maxsize=8)
def _fields_cdr(dtype: np.dtype) -> bytes:
    """The PointField sequence of a structured dtype (constant per dtype). Its elements align to 4
    at most, so written from a 4-aligned offset its bytes do not depend on where it starts."""
    w = _Writer()
    w.u4(len(dtype.names))
    for name in dtype.names:
        dt, offset = dtype.fields[name][:2]
        w.string(name)
        w.u4(offset)
        w.u1(_DTYPE_FIELDS[dt.newbyteorder("<")])
        w.u4(1)  # count
    return b"".join(w.parts)


def pointcloud_cdr(points: np.ndarray, stamp_ns: int, frame_id: str = WORLD_FRAME) -> bytes:
    """CDR of the unordered little-endian PointCloud2 msgs.pointcloud_from_structured builds."""
    n, step = int(points.shape[0]), points.dtype.itemsize
    w = _Writer()
    w.header(stamp_ns, frame_id)
    w.u4(1)  # height
    w.u4(n)  # width
    w.raw(_fields_cdr(points.dtype), 4)
    w.u1(0)  # is_bigendian
    w.u4(step)
    w.u4(step * n)
    w.u4(step * n)  # data: length, then the bytes
    w.raw(np.ascontiguousarray(points).astype(points.dtype.newbyteorder("<"), copy=False).tobytes())
    w.u1(1)  # is_dense
    return w.cdr()


def contacts_cloud_cdr(points, normals, forces, objects, slip, stamp_ns: int, frame_id: str = WORLD_FRAME,
                       hand=None, bone=None, other_hand=None, other_bone=None) -> bytes:
    """CDR of msgs.contacts_cloud_from_numpy(...) (the same arguments; the stamp in ns)."""
    return pointcloud_cdr(contact_points(points, normals, forces, objects, slip, hand, bone, other_hand,
                                         other_bone), stamp_ns, frame_id)


def object_states_cdr(names, poses, twists, accels, stamp_ns: int, frame_id: str = WORLD_FRAME) -> bytes:
    """CDR of msgs.object_states_from_numpy(...) (the same arguments; the stamp in ns):
    trajectory_msgs/MultiDOFJointTrajectory with one point, time_from_start 0."""
    names, *rows = object_rows(names, poses, twists, accels)
    w = _Writer()
    w.header(stamp_ns, frame_id)
    w.u4(len(names))
    for name in names:
        w.string(name)
    w.u4(1)  # one point
    for arr in rows:  # transforms, velocities, accelerations
        w.f8_rows(arr)
    w.u4(0)  # time_from_start: sec
    w.u4(0)  # nanosec
    return w.cdr()
