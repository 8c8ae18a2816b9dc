"""tracking_node: the 250 Hz intermediate-bone loop of paper Sect. 3.6 as a ROS 2 node, one hand per process.

    ros2 run softhand_tracking tracking_node [--ros-args -p hand:=right -p rate:=250.0 ...]
    softhand-tracking --ros-args -r __node:=tracking_node_left -p hand:=left     (the second hand)

Parameter `hand` (right | left) picks the side and with it every topic (docs/INTERFACE.md "Topics"):
subscribes /tracker/{hand}/hand_joints (PoseArray of 26 OpenXR joints, best effort, TRACKER_QOS),
/hand/{hand}/bones (PoseArray of 16, latest only) and the shared /hand/contacts (only the number of
points whose `hand` field is this side's: the feedback acts in contact of this hand; a cloud without
the field is a single right hand's); publishes /hand/{hand}/intermediate_bones (PoseArray of 16,
frame world, stamped with the node-clock time of its step) from a timer at `rate`, and /diagnostics
at `diagnostics_rate` (status `<node name>: tracking loop`, value `hand`): achieved step rate, timer
period p50/p99 and jitter, compute per step, steps run late (a late timer callback runs the steps it
missed, so the rate holds on a busy machine) or skipped, tracker frames received, accepted and
rejected by reason, time since the last valid tracker frame, dropout holds. Two hands are two
processes (one core each, no shared state); everything that names the node uses its run-time name
(`tracking_node`, `tracking_node_left`). Nothing is published before the first valid tracker frame.
The physics and bookkeeping live in `loop.TrackingLoop`; this node converts messages, owns the timers
and parameters. Honours use_sim_time (all times are the node clock's); Ctrl-C / SIGTERM exit 0.
"""
from __future__ import annotations

import argparse
import time

import numpy as np
from geometry_msgs.msg import PoseArray
from sensor_msgs.msg import PointCloud2
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from softhand_sim.params import ParamError
from softhand_sim.topics import SKIN_OBJECT
from softhand_sim.physics.hands import HAND_CODE
from softhand_sim.ros.common import (LATEST_QOS, STREAM_QOS, DiagnosticsPublisher, RateMeter,
                                     fail, run_node, split_cli, take_pending)
from softhand_sim.ros.msgs import diagnostic_name, pose_array_cdr, pose_array_from_cdr
from softhand_sim.ros.params import declare_node_params
from softhand_sim.timing import FixedRateScheduler, StepStats
from softhand_sim.topics import hand_topic, tracker_topic
from softhand_tracking.adapter import tracker_adapter
from softhand_tracking.loop import (TrackingLoop, bone_inertia_for, default_bone_inertia, extrapolate_poses,
                                    loop_config_from, warm_up)

#: the default node name and the parameter schema's section; a second instance runs under another
#: name (`-r __node:=tracking_node_left`), so logs and diagnostics use self.get_name()
NODE_NAME = "tracking_node"
DIAGNOSTIC_TASK = "tracking loop"
# A late timer callback runs the steps it missed (each published, stamped with its own time) so the
# loop keeps `rate` on average on a busy machine; more than this far behind, it skips ahead.
MAX_CATCH_UP_S = 0.1
REJECT_LOG_PERIOD = 2.0  # [s] at most one log line about rejected tracker frames per period
#: The tracker subscription: best effort, so that every tracker matches (a live one offers sensor-data
#: QoS), and deep: a reliable publisher (play_node) then delivers best effort, where the only loss on
#: one machine is a reader queue that overflows while the node is busy. Keep-last 5 lost frames that
#: arrived in one 176 ms burst (issue #17); keep-last 200 (~2 s of a 100 Hz tracker) lost 6 of 925
#: when five processes saturated both cores and this node fell 2 s behind; 1000 frames are 10 s.
TRACKER_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                         reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE)
_UINT8 = 2  # sensor_msgs/PointField.UINT8
_UINT32 = 6  # sensor_msgs/PointField.UINT32


def hand_contact_count(cloud, code: int) -> int:
    """Number of object contacts in a /hand/contacts PointCloud2 whose `hand` field (uint8) equals
    `code` (physics.hands.HAND_CODE: 0 right, 1 left). Skin-on-skin contacts (`object` SKIN_OBJECT,
    sim parameter self_contact) do not count: the feedback keeps the hand stable where an object
    pushes it off its target; counting the fingers that touch each other (adducted fingers, a
    fist) kept it on all the time and doubled the lag (leap_grab: simulated 26 -> 43 ms).

    Reads those bytes straight from the data (no decoding of the rest: the cloud comes every sim
    step). A cloud without the field (recorded before two hands) is one right hand's: all its points
    count for code 0 and none for 1. ValueError for a cloud whose data is shorter than its header
    says or whose `hand` field is not uint8.
    """
    height, width, step = int(cloud.height), int(cloud.width), int(cloud.point_step)
    n = height * width
    field = next((f for f in cloud.fields if f.name == "hand"), None)
    if field is None or n == 0:
        return n if code == 0 else 0
    if field.datatype != _UINT8:
        raise ValueError(f"contacts field 'hand' has datatype {field.datatype}, expected UINT8 ({_UINT8})")
    row_step = int(cloud.row_step)
    data = np.frombuffer(cloud.data, dtype=np.uint8)
    if data.size < height * row_step or row_step < width * step or field.offset >= step:
        raise ValueError(f"contacts cloud has {data.size} bytes for {height} rows of {row_step} "
                         f"({width} points of {step})")
    rows = data[:height * row_step].reshape(height, row_step)
    mine = rows[:, field.offset:width * step:step] == code
    obj = next((f for f in cloud.fields if f.name == "object"), None)
    if obj is not None and obj.datatype == _UINT32 and obj.offset + 4 <= step:
        objects = np.ascontiguousarray(np.stack([rows[:, obj.offset + k:width * step:step] for k in range(4)], -1))
        mine &= objects.view("<u4")[..., 0] != SKIN_OBJECT
    return int(np.count_nonzero(mine))


class TrackingNode(Node):
    def __init__(self):
        super().__init__(NODE_NAME)
        name = self.get_name()  # NODE_NAME unless remapped (a second hand: tracking_node_left)
        # the couplings of Eq. 14 and the damping change while running (ros2 param set); other keys at start
        live = {key: (lambda value, key=key: self.loop.bones.set_coupling(**{key: value}))
                for key in ("tracked_kx", "tracked_ktheta", "sim_kx", "sim_ktheta", "damping_ratio")}
        try:
            p = declare_node_params(self, NODE_NAME, live=live)  # the schema's section is NODE_NAME's
        except ParamError as exc:  # ... but the message names this node
            raise ParamError(str(exc).replace(f"{NODE_NAME}:", f"{name}:", 1)) from None
        if len(p["tracker_to_world"]) != 7:
            raise ValueError(f"{name}: parameter 'tracker_to_world' must be 7 numbers "
                             f"[px py pz qx qy qz qw], got {p['tracker_to_world']!r}")
        adapter = tracker_adapter(p, p["hand"])
        loop_config = loop_config_from(p)
        inertia, self.measures, self.measures_source = self.hand_inertia(p["hand_measures"], name)
        self.loop = TrackingLoop(loop_config, adapter, tracker_timeout=p["tracker_timeout"],
                                 sim_timeout=p["sim_timeout"], inertia=inertia)
        warm_up(loop_config, adapter.config)  # every kernel compiled/loaded now, not mid-run
        self.hand = p["hand"]
        self.hand_code = HAND_CODE[self.hand]
        self.sizer = None  # hand_measures auto: the first tracked second gives the bones' masses
        if self.measures_source == "auto":
            from softhand_sim.hand_sizer import HandSizer
            self.sizer = HandSizer(bone_inertia_for, side=self.hand)
        self.topics = {"tracker": tracker_topic(self.hand), "bones": hand_topic(self.hand, "bones"),
                       "out": hand_topic(self.hand, "intermediate_bones")}
        self.pub = self.create_publisher(PoseArray, self.topics["out"], STREAM_QOS)
        # PoseArrays in and out as CDR bytes read and written with numpy (msgs.pose_array_cdr): the
        # rclpy message conversion was a third of this node's CPU at 250 Hz
        self.tracker_sub = self.create_subscription(PoseArray, self.topics["tracker"], self.on_tracker, TRACKER_QOS,
                                                    raw=True)
        self.create_subscription(PoseArray, self.topics["bones"], self.on_sim_bones, LATEST_QOS, raw=True)
        # contact gates the feedback (parameter feedback: contact); only this hand's points are counted
        self.create_subscription(PointCloud2, "/hand/contacts", self.on_contacts, LATEST_QOS)
        self.bad_contact_messages = 0
        self.rate_meter = RateMeter(window=int(5 * p["rate"]))
        self.step_ms = StepStats(window=int(5 * p["rate"]))  # [ms] compute per step
        self.published = 0
        self.published_stamp = 0.0  # [s] the stamp of the last message published
        self.lead_ns = int(round(p["lead"] * 1e9))
        self.drain_budget_s = 0.5 / p["rate"]  # [s] per tracker callback for the frames queued behind
        self.frames_received = 0
        self.bad_sim_messages = 0
        # late_steps: run late by a catch-up; skipped_steps: given up, more than MAX_CATCH_UP_S behind
        self.scheduler = FixedRateScheduler(p["rate"], max_catch_up=max(1, int(MAX_CATCH_UP_S * p["rate"])))
        self._diag_mark = (time.monotonic(), 0)
        self.timer = self.create_timer(1.0 / p["rate"], self.on_timer)
        DiagnosticsPublisher(self, self.collect_diagnostics, period=1.0 / p["diagnostics_rate"],
                             name=diagnostic_name(name, DIAGNOSTIC_TASK))
        self.get_logger().info(f"tracking the {self.hand} hand at {p['rate']:.0f} Hz; waiting for "
                               f"{self.topics['tracker']}, publishing {self.topics['out']}")

    def now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    @staticmethod
    def hand_inertia(spec: str, name: str):
        """(BoneInertia, HandMeasures, source) of parameter hand_measures: default, a measures file
        (ParamError naming it when unreadable) or auto (the default until the sizer has fitted)."""
        from softhand_sim.handmodel.measures import HandMeasures, read_measures_file
        if spec in ("default", "auto"):
            return default_bone_inertia(), HandMeasures(), spec
        try:
            measures = read_measures_file(spec)
        except ValueError as exc:
            raise ParamError(f"{name}: parameter 'hand_measures': {exc}") from None
        return bone_inertia_for(measures), measures, "file"

    def poll_sizer(self) -> None:
        """hand_measures auto: once the sizer has fitted the first second, the loop takes that hand's bones."""
        inertia = self.sizer.poll()
        if inertia is not None:
            self.loop.bones.set_inertia(inertia)
            self.measures, self.measures_source = self.sizer.fit.measures, "auto"
            self.get_logger().info(f"hand_measures auto: {self.sizer.describe()}")
        elif self.sizer.state == "failed":  # the loop keeps the default hand's bones
            self.get_logger().error(f"hand_measures auto: {self.sizer.describe()}", once=True)
            self.measures_source = "default"
        if self.sizer.done:
            self.sizer = None

    def on_tracker(self, msg: bytes) -> None:
        """A tracker frame, then the frames queued behind it for up to half a loop period
        (ros.common.take_pending): under load the executor's one message per cycle falls behind
        the tracker, and a flood must not stop the loop. The loop's steps that fall due meanwhile
        run between the frames: the events executor runs callbacks in arrival order, so under a
        flood (5,000 frames/s) the timer's turn came behind thousands of frames (13 steps/s)."""
        self.on_frame(msg)
        for queued in take_pending(self.tracker_sub, self.drain_budget_s):
            self.run_due_steps()
            self.on_frame(queued)
        self.run_due_steps()

    def on_frame(self, msg: bytes) -> None:
        self.frames_received += 1
        try:
            joints, stamp_ns, _frame = pose_array_from_cdr(msg)
        except ValueError as exc:  # counted with the adapter's rejections
            joints, stamp_ns = np.zeros((0, 7)), 0
            self.get_logger().warning(f"{self.topics['tracker']}: {exc}", throttle_duration_sec=REJECT_LOG_PERIOD)
        was_holding = self.loop.holding
        if self.loop.on_tracker(joints, self.now_s(), stamp_ns * 1e-9):
            if self.sizer is not None:
                self.sizer.add_frame(stamp_ns * 1e-9, joints)
                self.poll_sizer()
            if was_holding:
                self.get_logger().info("tracker frames are back: tracking resumed")
            return
        # Counted by reason in /diagnostics; logged at most once per period (a flood of bad frames
        # must not flood the log).
        self.get_logger().warning(f"{self.loop.adapter.last_reject} (rejected so far: "
                                  f"{sum(self.loop.adapter.rejected.values())})",
                                  throttle_duration_sec=REJECT_LOG_PERIOD)

    def on_sim_bones(self, msg: bytes) -> None:
        try:
            self.loop.on_sim_bones(pose_array_from_cdr(msg)[0], self.now_s())
        except ValueError as exc:
            self.bad_sim_messages += 1
            self.get_logger().warn(f"ignored {self.topics['bones']}: {exc}", throttle_duration_sec=5.0)

    def on_contacts(self, msg: PointCloud2) -> None:
        try:
            count = hand_contact_count(msg, self.hand_code)
        except ValueError as exc:
            self.bad_contact_messages += 1
            self.get_logger().warn(f"ignored /hand/contacts: {exc}", throttle_duration_sec=5.0)
            return
        self.loop.on_contacts(count, self.now_s())

    def on_timer(self) -> None:
        self.rate_meter.tick()
        self.run_due_steps()

    def run_due_steps(self) -> None:
        """The loop's steps due by now (none, one, or the ones a late call missed)."""
        for t_ns in self.scheduler.due(self.get_clock().now().nanoseconds):
            self.run_step(t_ns)

    def run_step(self, t_ns: int) -> None:
        """One loop step at node-clock time t_ns; publishes the bones stamped t_ns."""
        was_holding = self.loop.holding
        t0 = time.perf_counter()
        poses = self.loop.step(t_ns * 1e-9)
        self.step_ms.add(1e3 * (time.perf_counter() - t0))
        if self.loop.holding and not was_holding:
            self.get_logger().warn(f"no valid tracker frame for {self.loop.tracker_timeout:.3f} s: holding the last target")
        if poses is None or not np.all(np.isfinite(poses)):
            return  # nothing to publish before the first frame; never a non-finite pose
        if self.lead_ns:  # the pose lead seconds ahead, stamped with that time (parameter lead)
            poses = extrapolate_poses(poses, self.loop.bones.vel, self.loop.bones.com_local, self.lead_ns * 1e-9)
        self.pub.publish(pose_array_cdr(poses, int(t_ns) + self.lead_ns))
        self.published += 1
        self.published_stamp = (int(t_ns) + self.lead_ns) * 1e-9

    def measures_diagnostics(self) -> dict:
        """The hand whose bones the loop integrates (as sim_node reports its own), and while `auto`
        sizes, the sizer's state."""
        from softhand_sim.hand_sizer import measures_diagnostics
        if self.sizer is not None:
            self.poll_sizer()  # the fit finishes in the sizer's thread between frames
        if self.sizer is not None:
            return self.sizer.diagnostics()
        return measures_diagnostics(self.measures, self.measures_source)

    def collect_diagnostics(self):
        now = self.now_s()
        stats = self.rate_meter.stats()
        adapter = self.loop.adapter
        since = self.loop.time_since_tracker(now)
        mark_t, mark_steps = self._diag_mark
        wall = time.monotonic()
        self._diag_mark = (wall, self.step_ms.count)
        values = {
            "hand": self.hand,
            "rate_hz": (self.step_ms.count - mark_steps) / (wall - mark_t) if wall > mark_t else 0.0,
            "timer_rate_hz": stats["rate_hz"], "period_p50_ms": stats["period_p50_ms"],
            "period_p99_ms": stats["period_p99_ms"], "jitter_p99_ms": stats["jitter_p99_ms"],
            "step_ms_p50": self.step_ms.median(), "step_ms_p99": self.step_ms.percentile(99),
            "step_ms_max": self.step_ms.max(),
            "published": self.published, "published_stamp": f"{self.published_stamp:.6f}", "late_steps": self.scheduler.late_steps,
            "skipped_steps": self.scheduler.skipped_steps,
            "frames_received": self.frames_received, "frames_accepted": adapter.accepted,
            "frames_rejected": sum(adapter.rejected.values()),
            **{f"rejected_{reason}": n for reason, n in adapter.rejected.items()},
            "time_since_tracker_s": since if np.isfinite(since) else -1.0,
            "holding": self.loop.holding, "holds": self.loop.holds,
            "sim_copy": self.loop.bones.sim_active, "sim_copy_drops": self.loop.sim_drops,
            "bad_sim_messages": self.bad_sim_messages, "bad_contact_messages": self.bad_contact_messages,
            "feedback_gain": self.loop.bones.sim_gain,
            "joint_filter": str(adapter.joint_filter) if adapter.joint_filter is not None else "none",
            **self.measures_diagnostics(),
        }
        if not self.loop.initialized:
            return values, "warn", "waiting for the first valid tracker frame"
        if self.loop.holding:
            return values, "warn", f"tracker lost for {since:.2f} s: holding the last target"
        return values, "ok", "tracking"


def build_parser():
    return argparse.ArgumentParser(
        prog="tracking_node",
        description="softhand elastic tracking (paper Sect. 3.6) of one hand, the side of parameter `hand` "
                    "(right | left): turns /tracker/{hand}/hand_joints (26 OpenXR joints) into 16 "
                    "intermediate bones integrated at `rate` (250 Hz), each coupled to its tracked bone and "
                    "to the simulated skeleton (/hand/{hand}/bones, in contact of this hand: /hand/contacts); "
                    "publishes /hand/{hand}/intermediate_bones and /diagnostics. Holds the last target "
                    "during tracker dropouts. Two hands: one process each, the second under another node "
                    "name. Parameters (defaults in config/softhand.yaml, list with `softhand params "
                    "tracking_node`): --ros-args -p key:=value or --params-file FILE.",
        epilog="examples: softhand-tracking --ros-args -p tracker_timeout:=0.2   (right hand, node tracking_node); "
               "softhand-tracking --ros-args -r __node:=tracking_node_left -p hand:=left   (left hand)")


def main(args=None):
    _, argv = split_cli(build_parser(), args)
    try:
        return run_node(TrackingNode, init_args=argv)
    except ValueError as exc:  # ParamError and bad settings: one line naming key and value, exit 1
        fail(str(exc))


if __name__ == "__main__":
    raise SystemExit(main())
