"""The topic names of docs/INTERFACE.md, in one place and without rclpy (the commands that read
recordings use them too).

Two hands (docs/INTERFACE.md, "Topics"): the tracker input, the intermediate and simulated bones
and the skin topics are per side, `/tracker/{side}/hand_joints` and `/hand/{side}/<name>`;
`/hand/contacts` (with its `hand` field), `/hand/object_states` and the world's topics are shared.
A system that runs one hand publishes its side's topics only. Old single-hand bags carry
`/tracker/hand_joints` (LEGACY_TRACKER): play_node publishes it as one side's tracker topic.
"""
from __future__ import annotations

SIDES = ("right", "left")

#: the single-hand tracker topic of older bags (played as the right hand unless told otherwise)
LEGACY_TRACKER = "/tracker/hand_joints"

POSE_ARRAY = "geometry_msgs/msg/PoseArray"
#: per-side topic name (under /hand/{side}/) -> ROS type
HAND_TOPICS = {
    "intermediate_bones": POSE_ARRAY,
    "bones": POSE_ARRAY,
    "skin_vertices": "sensor_msgs/msg/PointCloud2",
    "skin_mesh": "shape_msgs/msg/Mesh",
    "skin_marker": "visualization_msgs/msg/Marker",
}
#: topics shared by both hands -> ROS type
SHARED_TOPICS = {
    "/hand/object_states": "trajectory_msgs/msg/MultiDOFJointTrajectory",
    "/world/object_states": "trajectory_msgs/msg/MultiDOFJointTrajectory",
    "/hand/contacts": "sensor_msgs/msg/PointCloud2",
    "/hand/contact_markers": "visualization_msgs/msg/MarkerArray",
    "/world/markers": "visualization_msgs/msg/MarkerArray",
    "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
    # built into the venv by tools/build_tf2_msgs.py; may be missing (no compiler): see ros/tf.py
    "/tf": "tf2_msgs/msg/TFMessage",
    "/tf_static": "tf2_msgs/msg/TFMessage",
}

# /hand/contacts (docs/INTERFACE.md): the `object` of a skin-on-skin contact (sim parameter
# self_contact), and the `bone` / `other_hand` / `other_bone` where there is none (an object
# contact's other side; recordings made before those fields existed)
SKIN_OBJECT = 0xFFFFFFFF
NO_BONE = 255


def check_side(side: str) -> str:
    """side, or ValueError naming it when it is neither 'right' nor 'left'."""
    if side not in SIDES:
        raise ValueError(f"hand side must be 'right' or 'left', got {side!r}")
    return side


def tracker_topic(side: str) -> str:
    """/tracker/{side}/hand_joints: the tracked joints of hand `side` (26 OpenXR poses)."""
    return f"/tracker/{check_side(side)}/hand_joints"


def hand_topic(side: str, name: str) -> str:
    """/hand/{side}/{name} for a per-side topic name of HAND_TOPICS (KeyError names the unknown one)."""
    if name not in HAND_TOPICS:
        raise KeyError(f"{name!r} is not a per-side hand topic; they are {sorted(HAND_TOPICS)}")
    return f"/hand/{check_side(side)}/{name}"


def side_of(topic: str):
    """The side a per-side topic belongs to ('right' / 'left'), None for shared topics."""
    for side in SIDES:
        if topic.startswith((f"/hand/{side}/", f"/tracker/{side}/")):
            return side
    return None


#: docs/INTERFACE.md topic table: topic -> ROS type name (both sides' topics).
TOPIC_TYPES = {
    **{tracker_topic(s): POSE_ARRAY for s in SIDES},
    **{hand_topic(s, n): t for s in SIDES for n, t in HAND_TOPICS.items()},
    **SHARED_TOPICS,
}
#: Topics whose publisher is transient local (subscribe with LATCHED_QOS to get the kept sample).
LATCHED_TOPICS = frozenset({*(hand_topic(s, "skin_mesh") for s in SIDES), "/tf_static"})
#: Tracker topics: the tracker's QoS, not ours (record_node adapts to the publisher's).
TRACKER_TOPICS = frozenset({*(tracker_topic(s) for s in SIDES), LEGACY_TRACKER})
#: Topics too heavy to record or forward by default (11.8k vertices per hand per step).
HEAVY_TOPICS = frozenset(hand_topic(s, "skin_vertices") for s in SIDES)
