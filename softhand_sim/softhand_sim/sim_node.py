"""sim_node: the full soft hand simulation at a fixed rate (paper Sect. 3.1–3.5), thin over SimRuntime.

Subscribes /hand/intermediate_bones (bone targets, Sect. 3.6) and /world/object_states (engine
copies, Sect. 3.7). Publishes /hand/bones, /hand/object_states, /hand/skin_vertices,
/hand/skin_mesh (once, transient local), /hand/skin_marker, /hand/contacts, /hand/contact_markers
(force arrows, at the skin marker rate), /diagnostics, and /tf (bone frames) + /tf_static (ground,
static objects) when tf2_msgs is built (ros/tf.py).
All physics lives in softhand_sim.runtime; this file converts messages and owns timers.

/diagnostics also splits the tick into its stages (issue #20), rolling p50/p99 over DIAG_WINDOW
steps: stage_<name>_ms_p50 / _p99 for runtime.STAGES (SimRuntime.step's: targets, the solver's
collision .. advance, guard, skin, output) and NODE_STAGES (messages: building this tick's
messages, skin marker included; publish: the publish calls, /tf included, and the rest of the
tick), and tick_ms_p50 / _p99 for the whole tick (step_ms is SimRuntime.step alone).
"""
from __future__ import annotations

import argparse
import math
import time

import numpy as np
from geometry_msgs.msg import PoseArray
from rclpy.node import Node
from sensor_msgs.msg import PointCloud2
from shape_msgs.msg import Mesh
from trajectory_msgs.msg import MultiDOFJointTrajectory
from visualization_msgs.msg import Marker, MarkerArray

from softhand_sim.ros import msgs as rm
from softhand_sim.ros.markers import CONTACT_MARKERS_TOPIC, ContactMarkerSerializer
from softhand_sim.params import ParamError
from softhand_sim.scene import SceneError
from softhand_sim.ros.common import LATCHED_QOS, LATEST_QOS, PUB_QOS, SENSOR_QOS, DiagnosticsPublisher, RejectionLog, RateMeter, fail, run_node, split_cli
from softhand_sim.ros.params import declare_node_params
from softhand_sim.ros.tf import TfBroadcaster
from softhand_sim.timing import StepStats

NODE_NAME = "sim_node"
DIAG_WINDOW = 1000  # steps in the /diagnostics step-time and CG statistics
REJECT_LOG_PERIOD = 2.0  # [s] at most one log line per rejection reason per period
TARGET_GAP_S = 0.25  # [s] /hand/intermediate_bones silent this long: a gap (lost link, stopped tracker)
NODE_STAGES = ("messages", "publish")  # the tick's stages after SimRuntime.step (module docstring)


def p50_p99(stats):
    """(p50, p99) of a timing.StepStats window, from one sort (StepStats.percentiles)."""
    return stats.percentiles(50.0, 99.0)


def build_parser():
    return argparse.ArgumentParser(
        prog="sim_node",
        description="softhand full simulation: skeleton + nonlinear FEM tissue + SDF contact + grasped "
                    "objects, one Newton step and PCG per step at sim_rate. Subscribes "
                    "/hand/intermediate_bones and /world/object_states; publishes /hand/bones, "
                    "/hand/object_states, /hand/skin_vertices, /hand/skin_mesh, /hand/skin_marker, "
                    "/hand/contacts and /diagnostics. Parameters (defaults in config/softhand.yaml, "
                    "list with `softhand params sim_node`) are set with --ros-args -p key:=value or "
                    "--params-file FILE.",
        epilog="example: softhand-sim --ros-args -p sim_rate:=60.0 -p mesh:=coarse",
    )


class SimNode(Node):
    """Thin rclpy node over SimRuntime."""

    def __init__(self):
        super().__init__(NODE_NAME)
        self.params = declare_node_params(self, NODE_NAME)  # ParamError: run_node reports it, exit 1
        from softhand_sim.runtime import STAGES, SimRuntime  # heavy: numba kernels, hand model

        log = self.get_logger()
        log.info("building the hand model and solver (cached after the first run)...")
        t0 = time.monotonic()
        try:
            self.runtime = SimRuntime(self.params)
        except SceneError as exc:  # name the parameter that led to the bad scene
            fail(f"{NODE_NAME}: parameter 'scene_file' = {self.params['scene_file']!r}: {exc}")
        except (ParamError, ValueError, FileNotFoundError) as exc:
            fail(str(exc))
        self.dt = 1.0 / self.params["sim_rate"]
        log.info("compiling the solver kernels (first run of a checkout only: about a minute)...")
        self.runtime.warm_up(self.dt)
        log.info(f"ready in {time.monotonic() - t0:.1f} s: {self.runtime.describe()}")
        self.rejections = RejectionLog(self.get_logger(), REJECT_LOG_PERIOD)
        self.meter = RateMeter()
        # [ms] per step; over_budget counts the steps that took longer than their period (overruns)
        self.step_ms = StepStats(window=DIAG_WINDOW, budget=1e3 * self.dt)
        self.cg_iters = StepStats(window=DIAG_WINDOW)
        self.tick_ms = StepStats(window=DIAG_WINDOW)  # [ms] step + messages + publishing
        self.stage_ms = {name: StepStats(window=DIAG_WINDOW) for name in (*STAGES, *NODE_STAGES)}
        self.last_guard_warning = ""
        self.last_target_rx, self.target_gaps = math.inf, 0  # inf: the first target is no gap
        self.target_delay_ms = StepStats(window=DIAG_WINDOW)  # [ms] receipt - stamp of the targets
        self.pub_bones = self.create_publisher(PoseArray, "/hand/bones", PUB_QOS)
        self.pub_objects = self.create_publisher(MultiDOFJointTrajectory, "/hand/object_states", PUB_QOS)
        self.pub_skin = self.create_publisher(PointCloud2, "/hand/skin_vertices", PUB_QOS)
        self.pub_mesh = self.create_publisher(Mesh, "/hand/skin_mesh", LATCHED_QOS)
        self.pub_marker = self.create_publisher(Marker, "/hand/skin_marker", PUB_QOS)
        self.pub_contacts = self.create_publisher(PointCloud2, "/hand/contacts", PUB_QOS)
        self.pub_contact_markers = self.create_publisher(MarkerArray, CONTACT_MARKERS_TOPIC, PUB_QOS)  # viewers
        self.create_subscription(PoseArray, "/hand/intermediate_bones", self.on_bones, LATEST_QOS)
        self.create_subscription(MultiDOFJointTrajectory, "/world/object_states", self.on_objects, LATEST_QOS)
        verts, tris = self.runtime.skin_rest_mesh()
        self.pub_mesh.publish(rm.mesh_from_numpy(verts, tris))
        self.diag = DiagnosticsPublisher(self, self.collect_diagnostics, 1.0 / self.params["diagnostics_rate"])
        self.timer = self.create_timer(self.dt, self.on_timer)
        self.sizer = None
        if self.params["hand_measures"] == "auto":
            self.sizer = self.start_hand_sizer()
        self.marker_period = 1.0 / self.params["skin_marker_rate"]
        self.marker_serializer = rm.TriangleMarkerSerializer()  # numpy-built CDR: 10x faster than rclpy's
        self.last_marker = -np.inf
        self.contact_serializer = ContactMarkerSerializer()  # force arrows, numpy-built CDR like the skin's
        # --- TF (ros/tf.py): bones on /tf each step, ground and static objects on /tf_static;
        # without tf2_msgs in the venv it logs one warning and publishes nothing.
        self.tf = TfBroadcaster(self, self.params["hand_side"], self.runtime.scene, PUB_QOS, LATCHED_QOS)
        rate = self.params["skin_vertices_rate"]
        self.skin_period, self.last_skin = (1.0 / rate if rate > 0 else 0.0), -np.inf

    # -------------------------------------------------------------------- inputs
    def reject(self, reason, detail):
        self.rejections.log(reason, detail)

    def on_bones(self, msg):
        now = time.monotonic()
        if now - self.last_target_rx > TARGET_GAP_S:  # counted when the targets come back
            self.target_gaps += 1
        self.last_target_rx = now
        self.target_delay_ms.add(1e3 * (self.now_s() - rm.stamp_to_seconds(msg.header.stamp)))  # clocks in sync
        try:
            poses = rm.pose_array_to_numpy(msg)
            self.runtime.set_bone_targets(poses, rm.stamp_to_seconds(msg.header.stamp))
        except ValueError as exc:
            self.reject("intermediate_bones", exc)

    def on_objects(self, msg):
        try:
            names, poses, twists, accels, stamp = rm.object_states_to_numpy(msg)
            errors = self.runtime.set_object_copies(names, poses, twists, accels, stamp * 1e-9)  # the state's time
            for e in errors:
                self.reject("object_states", e)
        except ValueError as exc:
            self.reject("object_states", exc)

    def now_s(self):
        return self.get_clock().now().nanoseconds * 1e-9

    # -------------------------------------------------------------------- hand_measures: auto
    def start_hand_sizer(self):
        """The first tracked second sizes the hand (softhand_sim.hand_sizer, in a worker thread);
        nothing is simulated until the fitted hand replaces the default one (poll_hand_sizer)."""
        from softhand_sim.hand_sizer import HandSizer, tracker_topic
        from softhand_sim.runtime import SimRuntime

        def make(measures):
            runtime = SimRuntime(self.params, scene=self.runtime.scene, measures=measures, measures_source="auto")
            runtime.warm_up(self.dt)
            return runtime

        sizer = HandSizer(make, side=self.params["hand_side"])
        self.create_subscription(PoseArray, tracker_topic(self.params["hand_side"]), self.on_tracker, SENSOR_QOS)
        self.get_logger().info("hand_measures auto: sizing the hand on the first tracked second")
        return sizer

    def on_tracker(self, msg):
        if self.sizer is not None and self.sizer.state == "collecting":
            self.sizer.add_frame(rm.stamp_to_seconds(msg.header.stamp), rm.pose_array_to_numpy(msg))

    def poll_hand_sizer(self):
        """True once the hand to simulate is known (fitted and swapped in, or the sizing failed)."""
        from softhand_sim.hand_sizer import handover
        runtime = self.sizer.poll()
        if runtime is not None:
            self.runtime = handover(self.runtime, runtime)
            self.pub_mesh.publish(rm.mesh_from_numpy(*runtime.skin_rest_mesh()))
            self.get_logger().info(f"hand_measures auto: {self.sizer.describe()}")
        elif self.sizer.state == "failed":
            self.get_logger().error(f"hand_measures auto: {self.sizer.describe()}", once=True)
        return self.sizer.done

    # -------------------------------------------------------------------- the step
    def on_timer(self):
        if self.sizer is not None and not self.poll_hand_sizer():
            return
        t = self.now_s()
        t0 = time.perf_counter()
        out = self.runtime.step(self.dt, t)
        t1 = time.perf_counter()
        if out is None:  # no bone targets yet: nothing to simulate
            return
        self.meter.tick()
        self.step_ms.add(1e3 * (t1 - t0))
        self.cg_iters.add(out.stats.cg_iters)
        # build every message of the tick first, then publish them (the two stages timed apart)
        stamp = rm.stamp_from_seconds(out.t)  # the time of the state: the end of the step
        bones = rm.pose_array_from_numpy(out.bone_poses, stamp)
        rest = []
        if len(out.object_names):
            rest.append((self.pub_objects, rm.object_states_from_numpy(
                out.object_names, out.object_poses, out.object_twists, out.object_accels, stamp)))
        # on demand (nobody subscribed: no 142 kB message built) and at most at skin_vertices_rate
        if (self.params["publish_skin_vertices"] and t - self.last_skin >= self.skin_period - 1e-6
                and self.pub_skin.get_subscription_count()):
            self.last_skin = t
            rest.append((self.pub_skin, rm.xyz_cloud_from_numpy(out.skin_vertices, stamp)))
        c = out.contacts
        rest.append((self.pub_contacts, rm.contacts_cloud_from_numpy(
            c["points"], c["normals"], c["forces"], c["objects"], c["slip"], stamp)))
        if t - self.last_marker >= self.marker_period - 1e-6:
            self.last_marker = t
            verts, tris = self.runtime.display_mesh(out)
            rest.append((self.pub_marker, self.marker_serializer.serialize(verts, tris, stamp)))
            rest.append((self.pub_contact_markers,
                         self.contact_serializer.serialize(c["points"], c["forces"], c["slip"], stamp)))
        t2 = time.perf_counter()
        self.pub_bones.publish(bones)
        self.tf.publish_bones(out.bone_poses, stamp)  # TF: the same poses and stamp as /hand/bones
        for pub, msg in rest:
            pub.publish(msg)
        if out.warning:
            self.last_guard_warning = out.warning
            self.get_logger().warning(out.warning, throttle_duration_sec=2.0)
        t3 = time.perf_counter()
        self.tick_ms.add(1e3 * (t3 - t0))
        for name, ms in (*out.stages.items(), ("messages", 1e3 * (t2 - t1)), ("publish", 1e3 * (t3 - t2))):
            self.stage_ms[name].add(ms)

    def stage_diagnostics(self):
        """stage_<name>_ms_p50 / _p99 of every stage of the tick (NaN before the first step)."""
        out = {}
        for name, stats in self.stage_ms.items():
            out[f"stage_{name}_ms_p50"], out[f"stage_{name}_ms_p99"] = p50_p99(stats)
        return out

    def collect_diagnostics(self):
        rate = self.meter.stats()
        values = {
            "sim_rate_hz": rate["rate_hz"],
            "step_ms_p50": self.step_ms.median(), "step_ms_p99": self.step_ms.percentile(99),
            "step_ms_max": self.step_ms.max(),
            "cg_iters_p50": self.cg_iters.median(),
            "cg_iters_max": int(self.cg_iters.max()) if len(self.cg_iters) else 0,
            "tick_ms_p50": self.tick_ms.median(), "tick_ms_p99": self.tick_ms.percentile(99),
            **self.stage_diagnostics(),
            "overruns": self.step_ms.over_budget,
            "target_gaps": self.target_gaps, "target_delay_ms_p50": self.target_delay_ms.median(),
            "target_age_s": time.monotonic() - self.last_target_rx if math.isfinite(self.last_target_rx) else -1.0,
            **self.runtime.diagnostics(),
            **(self.sizer.diagnostics() if self.sizer is not None and self.sizer.state != "ready" else {}),
            **{f"rejected_{k}": v for k, v in self.rejections.counts.items()},
        }
        values["last_guard_warning"] = self.last_guard_warning or "-"
        message = "simulating" if self.step_ms.count else "waiting for /hand/intermediate_bones"
        if self.last_guard_warning:  # the latest divergence stays visible in the status line
            message = f"{message}; {values['rejected_steps']} step(s) rejected, last: {self.last_guard_warning}"
        level = "warn" if values.get("rejected_steps", 0) else "ok"
        return values, level, message


def main(args=None):
    parser = build_parser()
    _, argv = split_cli(parser, args)
    return run_node(SimNode, init_args=argv)


if __name__ == "__main__":
    raise SystemExit(main())
