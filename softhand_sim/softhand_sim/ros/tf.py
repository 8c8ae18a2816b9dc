"""TF for softhand: the simulated bones on /tf, the fixed scene frames on /tf_static.

Frames (docs/INTERFACE.md):
  /tf         every sim step, one tf2_msgs/TFMessage per simulated hand: each bone of BONE_NAMES
              as frame `{side}_{bone}` (e.g. `right_index_distal`), parent `world`, at the bone
              pose that /hand/{side}/bones carries at the same stamp (the bone frame = the bone's
              body frame).
  /tf_static  once, transient local: `world` -> `ground` (the ground plane, z = ground height) and
              `world` -> `{name}` for each static object of the scene (e.g. `table`, at its pose).

tf2_msgs is not on PyPI: tools/build_tf2_msgs.py builds it into the venv (the Makefile's venv
step). Where it could not be built, `tf_message_class()` returns None with the reason,
`TfBroadcaster` publishes nothing and logs that once; the rest of the node is unaffected.

Without tf2_ros (not on PyPI either) a lookup composes the recorded transforms: `lookup`.
Only nodes and ros/ modules import this (it imports rclpy message classes).
"""
from __future__ import annotations

from functools import lru_cache
from typing import Iterable, Mapping, Sequence

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import TransformStamped

from softhand_sim.handmodel.skeleton_names import BONE_NAMES
from softhand_sim.ros.msgs import WORLD_FRAME, _as_time, _check_rows

TF_TOPIC = "/tf"
TF_STATIC_TOPIC = "/tf_static"
TF_TYPE = "tf2_msgs/msg/TFMessage"
GROUND_FRAME = "ground"
MISSING_HINT = "build it with `make tf2_msgs` (needs a C/C++ compiler and python3-dev)"


@lru_cache(maxsize=1)
def tf_message_class():
    """(TFMessage class, "") when tf2_msgs imports, else (None, why not). Cached per process."""
    try:
        from tf2_msgs.msg import TFMessage
    except ImportError as exc:  # not built for this venv (no compiler), or a broken build
        return None, f"no tf2_msgs ({exc})"
    return TFMessage, ""


def bone_frames(side: str) -> list[str]:
    """Frame names of hand `side`'s simulated bones, in /hand/{side}/bones order: ['right_palm', ...]."""
    return [f"{side}_{bone}" for bone in BONE_NAMES]


def transforms(children: Sequence[str], poses, stamp, parent: str = WORLD_FRAME) -> list:
    """geometry_msgs/TransformStamped list: child i at poses[i] [px py pz qx qy qz qw] in `parent`."""
    p = _check_rows("poses", poses, 7)
    if len(children) != p.shape[0]:
        raise ValueError(f"{len(children)} frame names for {p.shape[0]} poses")
    t = _as_time(stamp)
    out = []
    for child, (px, py, pz, qx, qy, qz, qw) in zip(children, p.tolist()):
        ts = TransformStamped(child_frame_id=child)
        ts.header.stamp, ts.header.frame_id = Time(sec=t.sec, nanosec=t.nanosec), parent  # own copy each
        tr, rot = ts.transform.translation, ts.transform.rotation
        tr.x, tr.y, tr.z = px, py, pz
        rot.x, rot.y, rot.z, rot.w = qx, qy, qz, qw
        out.append(ts)
    return out


def static_scene_frames(scene) -> tuple[list[str], np.ndarray]:
    """(names, poses (n, 7)) of what never moves: the ground plane and the static scene objects."""
    names = [GROUND_FRAME] + [o.name for o in scene.static_objects]
    ground = np.array([0.0, 0.0, float(scene.ground_height), 0.0, 0.0, 0.0, 1.0])
    poses = np.vstack([ground] + [np.asarray(o.pose, dtype=np.float64) for o in scene.static_objects])
    return names, poses


class BoneTfSerializer:
    """CDR bytes of the bones' TFMessage built with numpy: rclpy needs ~2.4 ms per 16-frame message
    (measured, loaded machine), 15 % of a 60 Hz step; this takes tens of microseconds.

    With fixed frame names the CDR layout is fixed: only the stamps and the 7 doubles of each
    transform change. Their offsets are found once in rclpy's own serialization of a template
    whose stamps and values are distinct sentinels (padding bytes are not zeroed by rclpy, so the
    fields are located by value, not by computing alignment). rclpy's Publisher.publish takes the
    bytes as they are; tests/ros/test_tf.py checks they decode to the message `transforms` builds.
    """

    def __init__(self, children: Sequence[str], parent: str = WORLD_FRAME):
        from rclpy.serialization import serialize_message

        cls, why = tf_message_class()
        if cls is None:
            raise RuntimeError(why)
        n = len(children)
        values = 1.0e6 + np.arange(n * 7, dtype=np.float64).reshape(n, 7) + 0.125  # exact in binary
        template = cls(transforms=transforms(children, values, 0, parent))
        for i, ts in enumerate(template.transforms):
            ts.header.stamp = Time(sec=0x5EC00000 + i, nanosec=0x0A000000 + i)
        raw = serialize_message(template)
        self._template = bytes(raw)
        self._n = n
        value_pos, stamp_pos = [], []
        for i in range(n):
            pos = raw.find(values[i].astype("<f8").tobytes())
            stamp = np.array([0x5EC00000 + i, 0x0A000000 + i], "<u4").tobytes()
            spos = raw.find(stamp)
            if pos < 0 or spos < 0 or (pos - 4) % 8 or (spos - 4) % 4 or raw.find(stamp, spos + 1) >= 0:
                raise RuntimeError("unexpected TFMessage CDR layout (is the platform big-endian?)")
            value_pos.append(pos)
            stamp_pos.append(spos)
        # element indices into float64 / uint32 views that start after the 4-byte CDR header
        self._value_idx = ((np.asarray(value_pos)[:, None] - 4) // 8 + np.arange(7)).ravel()
        self._sec_idx = (np.asarray(stamp_pos) - 4) // 4

    def serialize(self, poses, stamp) -> bytes:
        """CDR bytes of the TFMessage with child i at poses[i] (n, 7) [m, quaternion x y z w] at `stamp`."""
        p = _check_rows("poses", poses, 7)
        if p.shape[0] != self._n:
            raise ValueError(f"{self._n} frames, got {p.shape[0]} poses")
        t = _as_time(stamp)
        buf = bytearray(self._template)
        body = memoryview(buf)[4:]
        np.frombuffer(body, "<f8", count=len(body) // 8)[self._value_idx] = p.ravel()
        words = np.frombuffer(body, "<u4", count=len(body) // 4)
        words[self._sec_idx] = np.uint32(t.sec)
        words[self._sec_idx + 1] = np.uint32(t.nanosec)
        return bytes(buf)


class TfBroadcaster:
    """Publishes the bone frames on /tf and the scene's fixed frames on /tf_static for one node.

    sides: the simulated hands ('right', or a sequence such as ('right', 'left')).
    `publish_bones(poses, stamp, side)` each step for each hand that is simulated (poses (16, 7)
    as on /hand/{side}/bones): one TFMessage per hand, so a hand that has not entered yet is
    simply not published and one hand costs what it cost before two existed. QoS: /tf as every
    softhand publisher (`pub_qos`), /tf_static transient local (`latched_qos`), like tf2_ros'
    static broadcaster, so a late listener still gets it. Without tf2_msgs: a no-op, and one
    warning on the node's log naming the reason.
    """

    def __init__(self, node, sides, scene, pub_qos, latched_qos):
        cls, why = tf_message_class()
        self.sides = (sides,) if isinstance(sides, str) else tuple(sides)
        self.available = cls is not None
        self.reason = why
        self.frames = {side: bone_frames(side) for side in self.sides}
        if not self.available:
            node.get_logger().warning(f"{why}: not publishing /tf and /tf_static; {MISSING_HINT}")
            return
        self._serializers = {side: BoneTfSerializer(frames) for side, frames in self.frames.items()}
        self._pub = node.create_publisher(cls, TF_TOPIC, pub_qos)
        self._pub_static = node.create_publisher(cls, TF_STATIC_TOPIC, latched_qos)
        names, poses = static_scene_frames(scene)
        self._pub_static.publish(cls(transforms=transforms(names, poses, node.get_clock().now().to_msg())))

    def publish_bones(self, poses, stamp, side: str | None = None) -> None:
        """Hand `side`'s bone frames (default: the first of `sides`) at `stamp`."""
        if self.available:
            self._pub.publish(self._serializers[side or self.sides[0]].serialize(poses, stamp))


# ------------------------------------------------------------------------- lookup (no tf2_ros)


def _quat_mul(a, b) -> np.ndarray:
    """Hamilton product of quaternions [x y z w]."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz])


def _rotate(q, v) -> np.ndarray:
    """Vector v rotated by unit quaternion q [x y z w]."""
    u, w = np.asarray(q[:3]), q[3]
    return v + 2.0 * np.cross(u, np.cross(u, v) + w * v)


def compose(parent_pose, child_pose) -> np.ndarray:
    """Pose (7,) of a frame given in its parent (child_pose) expressed in the parent's parent."""
    p, c = np.asarray(parent_pose, float), np.asarray(child_pose, float)
    return np.concatenate([p[:3] + _rotate(p[3:], c[:3]), _quat_mul(p[3:], c[3:])])


def transform_table(messages: Iterable) -> dict:
    """child -> (parent, pose (7,), stamp ns) from TFMessages (rclpy or rosbags), the latest per child."""
    table = {}
    for msg in messages:
        for ts in msg.transforms:
            tr, rot = ts.transform.translation, ts.transform.rotation
            stamp = int(ts.header.stamp.sec) * 1_000_000_000 + int(ts.header.stamp.nanosec)
            table[ts.child_frame_id] = (ts.header.frame_id,
                                        np.array([tr.x, tr.y, tr.z, rot.x, rot.y, rot.z, rot.w]), stamp)
    return table


def lookup(table: Mapping, frame: str, root: str = WORLD_FRAME) -> np.ndarray:
    """Pose (7,) of `frame` in `root`, composing the parent chain of `table` (see transform_table).

    KeyError naming the frame when the chain does not reach `root` (or loops).
    """
    pose = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
    seen = []
    while frame != root:
        if frame not in table or frame in seen:
            raise KeyError(f"no transform chain from {seen[0] if seen else frame!r} to {root!r} (stuck at {frame!r})")
        seen.append(frame)
        parent, local, _stamp = table[frame]
        pose = compose(local, pose)
        frame = parent
    return pose
