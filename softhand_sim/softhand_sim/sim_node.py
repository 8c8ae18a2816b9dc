"""sim_node: the full soft hand simulation at a fixed rate (paper Sect. 3.1–3.5), thin over SimRuntime.

One node simulates the hands of its `hands` parameter ([right] by default, [left], or [right,
left]: one model, one solve, runtime.py). For each simulated side it subscribes
/hand/{side}/intermediate_bones (bone targets, Sect. 3.6) and publishes /hand/{side}/bones,
/hand/{side}/skin_vertices (on demand), /hand/{side}/skin_mesh (transient local, once per hand
model, when the hand enters) and /hand/{side}/skin_marker (topics.py); a hand that has not had a
target yet publishes nothing on them. Shared: it subscribes /world/object_states (engine copies,
Sect. 3.7) and publishes /hand/object_states, /hand/contacts (both hands, `hand` field),
/hand/contact_markers (force arrows, at the skin marker rate), /diagnostics, and /tf (each
simulated hand's bone frames `{side}_{bone}`) + /tf_static (ground, static objects) when
tf2_msgs is built (ros/tf.py). A one-hand node does per step exactly the one hand's work.
All physics lives in softhand_sim.runtime; this file converts messages and owns timers.
/hand/{side}/bones and their /tf go out as soon as the step's state is final, before the skin,
the contact rows and the tick's other messages are computed (publish_bones).

/diagnostics also splits the tick into its stages (issue #20), rolling p50/p99 over DIAG_WINDOW
steps: stage_<name>_ms_p50 / _p99 for runtime.STAGES (SimRuntime.step's: targets, the solver's
collision .. advance, guard, skin, output) and NODE_STAGES (messages: building this tick's
messages, skin marker included; publish: the publish calls, /tf included, and the rest of the
tick), and tick_ms_p50 / _p99 for the whole tick (step_ms is SimRuntime.step alone);
factor_held_share: the share of those steps that kept the factor preconditioner's factor and
factored nothing (factor_hold, physics/factor_hold.py).
"""
from __future__ import annotations

import argparse
import gc
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
from softhand_sim.ros.cdr_messages import contacts_cloud_cdr, object_states_cdr
from softhand_sim.ros.markers import CONTACT_MARKERS_TOPIC, ContactMarkerSerializer
from softhand_sim.params import ParamError
from softhand_sim.scene import SceneError
from softhand_sim.ros.common import LATCHED_QOS, LATEST_QOS, PUB_QOS, SENSOR_QOS, STREAM_QOS, DiagnosticsPublisher, RejectionLog, RateMeter, fail, run_node, split_cli
from softhand_sim.ros.params import declare_node_params
from softhand_sim.ros.tf import TfBroadcaster
from softhand_sim.timing import StepStats, slow_motion
from softhand_sim.topics import hand_topic

NODE_NAME = "sim_node"
DIAG_WINDOW = 1000  # steps in the /diagnostics step-time and CG statistics
REJECT_LOG_PERIOD = 2.0  # [s] at most one log line per rejection reason per period
TARGET_GAP_S = 0.25  # [s] /hand/{side}/intermediate_bones silent this long: a gap (lost link, stopped tracker)
NODE_STAGES = ("messages", "publish")  # the tick's stages after SimRuntime.step (module docstring)


def p50_p99(stats):
    """(p50, p99) of a timing.StepStats window, from one sort (StepStats.percentiles)."""
    return stats.percentiles(50.0, 99.0)


def build_parser():
    return argparse.ArgumentParser(
        prog="sim_node",
        description="softhand full simulation: skeleton + nonlinear FEM tissue + SDF contact + grasped "
                    "objects, one Newton step and PCG per step at sim_rate, for the hands of parameter "
                    "`hands` in one solve. Per simulated side: subscribes /hand/{side}/intermediate_bones; "
                    "publishes /hand/{side}/bones, skin_vertices, skin_mesh and skin_marker. Shared: "
                    "subscribes /world/object_states; publishes /hand/object_states, /hand/contacts, "
                    "/hand/contact_markers, /tf and /diagnostics. Parameters (defaults in "
                    "config/softhand.yaml, list with `softhand params sim_node`) are set with --ros-args "
                    "-p key:=value or --params-file FILE.",
        epilog="example: softhand-sim --ros-args -p sim_rate:=60.0 -p \"hands:=[right, left]\" (sim_rate 0, the default: 200 Hz for one hand, 50 Hz for two)",
    )


class HandTopics:
    """One simulated hand's topics (/hand/{side}/...) and its input bookkeeping."""

    def __init__(self, node, side, code):
        self.side = side
        self.bones = node.create_publisher(PoseArray, hand_topic(side, "bones"), STREAM_QOS)
        self.skin = node.create_publisher(PointCloud2, hand_topic(side, "skin_vertices"), PUB_QOS)
        self.mesh = node.create_publisher(Mesh, hand_topic(side, "skin_mesh"), LATCHED_QOS)
        self.marker = node.create_publisher(Marker, hand_topic(side, "skin_marker"), PUB_QOS)
        # numpy-built CDR: 10x faster than rclpy's; marker id = the side's code, so two hands in
        # one viewer never replace each other's skin
        self.marker_serializer = rm.TriangleMarkerSerializer(marker_id=code)
        self.mesh_bytes = None  # the serialized rest mesh of the current hand model, sent when the hand enters
        self.mesh_sent = False
        self.last_skin = -np.inf
        self.last_target_rx, self.target_gaps = math.inf, 0  # inf: the first target is no gap
        self.target_delay_ms = StepStats(window=DIAG_WINDOW)  # [ms] receipt - stamp of the targets

    def new_model(self, runtime):
        """Serialize the skin rest mesh of `runtime`'s hand (again after hand_measures auto swapped
        it), now rather than in the tick where the hand enters (~0.1 s of rclpy for 23k triangles)."""
        from rclpy.serialization import serialize_message
        self.mesh_bytes = serialize_message(rm.mesh_from_numpy(*runtime.skin_rest_mesh(hand=self.side)))
        self.mesh_sent = False

    def target_age_s(self):
        return time.monotonic() - self.last_target_rx if math.isfinite(self.last_target_rx) else -1.0


class SimNode(Node):
    """Thin rclpy node over SimRuntime."""

    def __init__(self):
        super().__init__(NODE_NAME)
        self.params = declare_node_params(self, NODE_NAME)  # ParamError: run_node reports it, exit 1
        from softhand_sim.runtime import STAGES, SimRuntime, check_hand_measures  # heavy: numba kernels, hand model

        check_hand_measures(self.params)  # ParamError: auto sizes one hand only
        log = self.get_logger()
        log.info("building the hand model and solver (cached after the first run)...")
        t0 = time.monotonic()
        try:
            self.runtime = SimRuntime(self.params)
        except SceneError as exc:  # name the parameter that led to the bad scene
            fail(f"{NODE_NAME}: parameter 'scene_file' = {self.params['scene_file']!r}: {exc}")
        except (ParamError, ValueError, FileNotFoundError) as exc:
            fail(str(exc))
        self.dt = 1.0 / self.runtime.params["sim_rate"]  # sim_rate 0: by hand count (params.sim_rate_hz)
        self.max_step, self.last_tick, self.long_steps = self.params["max_step"], None, 0
        self.step_dt_ms = StepStats(window=DIAG_WINDOW)  # [ms] the steps' lengths (max_step set)
        log.info("compiling the solver kernels (first run of a checkout only: about a minute)...")
        self.runtime.warm_up(self.dt)
        log.info(f"ready in {time.monotonic() - t0:.1f} s: {self.runtime.describe()}")
        self.rejections = RejectionLog(self.get_logger(), REJECT_LOG_PERIOD)
        self.meter = RateMeter()
        # [ms] per step; over_budget counts the steps that took longer than their period (overruns)
        self.step_ms = StepStats(window=DIAG_WINDOW, budget=1e3 * self.dt)
        self.cg_iters = StepStats(window=DIAG_WINDOW)
        self.factor_held = StepStats(window=DIAG_WINDOW)  # 1: the step kept the factor (factor_hold)
        self.tick_ms = StepStats(window=DIAG_WINDOW)  # [ms] step + messages + publishing
        self.stage_ms = {name: StepStats(window=DIAG_WINDOW) for name in (*STAGES, *NODE_STAGES)}
        self.last_guard_warning = ""
        self.target_delay_ms = StepStats(window=DIAG_WINDOW)  # [ms] receipt - stamp, every hand's targets
        from softhand_sim.physics.hands import HAND_CODE
        self.hand_topics = [HandTopics(self, side, HAND_CODE[side]) for side in self.runtime.hands]
        for hand in self.hand_topics:
            hand.new_model(self.runtime)
            # 250 Hz of PoseArrays, taken as CDR bytes and read with numpy (msgs.pose_array_from_cdr)
            self.create_subscription(PoseArray, hand_topic(hand.side, "intermediate_bones"),
                                     lambda msg, hand=hand: self.on_bones(msg, hand), LATEST_QOS, raw=True)
        self.pub_objects = self.create_publisher(MultiDOFJointTrajectory, "/hand/object_states", STREAM_QOS)
        self.pub_contacts = self.create_publisher(PointCloud2, "/hand/contacts", PUB_QOS)
        self.pub_contact_markers = self.create_publisher(MarkerArray, CONTACT_MARKERS_TOPIC, PUB_QOS)  # viewers
        self.create_subscription(MultiDOFJointTrajectory, "/world/object_states", self.on_objects, LATEST_QOS)
        self.diag = DiagnosticsPublisher(self, self.collect_diagnostics, 1.0 / self.params["diagnostics_rate"])
        self.timer = self.create_timer(self.dt, self.on_timer)
        self.sizer = None
        if self.params["hand_measures"] == "auto":
            self.sizer = self.start_hand_sizer()
        self.marker_period = 1.0 / self.params["skin_marker_rate"]
        self.last_marker = -np.inf
        self.contact_serializer = ContactMarkerSerializer()  # force arrows, numpy-built CDR like the skin's
        # --- TF (ros/tf.py): each simulated hand's bones on /tf each step, ground and static objects
        # on /tf_static; without tf2_msgs in the venv it logs one warning and publishes nothing.
        self.tf = TfBroadcaster(self, self.runtime.hands, self.runtime.scene, PUB_QOS, LATCHED_QOS)
        rate = self.params["skin_vertices_rate"]
        self.skin_period = 1.0 / rate if rate > 0 else 0.0

    # -------------------------------------------------------------------- inputs
    def reject(self, reason, detail):
        self.rejections.log(reason, detail)

    def on_bones(self, msg, hand):
        now = time.monotonic()
        if now - hand.last_target_rx > TARGET_GAP_S:  # counted when the targets come back
            hand.target_gaps += 1
        hand.last_target_rx = now
        try:
            poses, stamp_ns, _frame = rm.pose_array_from_cdr(msg)
            delay = 1e3 * (self.now_s() - stamp_ns * 1e-9)  # clocks in sync
            self.target_delay_ms.add(delay)
            if len(self.hand_topics) > 1:
                hand.target_delay_ms.add(delay)
            self.runtime.set_bone_targets(poses, stamp_ns * 1e-9, hand=hand.side)
        except ValueError as exc:
            self.reject("intermediate_bones", f"{hand.side}: {exc}")

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
        nothing is simulated until the fitted hand replaces the default one (poll_hand_sizer).
        One hand only (runtime.check_hand_measures): it listens to that side's tracker topic."""
        from softhand_sim.hand_sizer import HandSizer, tracker_topic
        from softhand_sim.runtime import SimRuntime

        def make(measures):
            runtime = SimRuntime(self.params, scene=self.runtime.scene, measures=measures, measures_source="auto")
            runtime.warm_up(self.dt)
            return runtime

        side = self.runtime.hands[0]
        sizer = HandSizer(make, side=side)
        self.create_subscription(PoseArray, tracker_topic(side), self.on_tracker, SENSOR_QOS)
        self.get_logger().info(f"hand_measures auto: sizing the {side} hand on the first tracked second "
                               f"of {tracker_topic(side)}")
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
            for hand in self.hand_topics:  # the new hand's mesh goes out when it enters
                hand.new_model(runtime)
            gc.freeze()  # the fitted hand lives for the run too (run_node froze what came before it)
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
        dt = self.step_dt(t)
        self._bones_s = [0.0, 0.0]  # [s] building, publishing the bones (publish_bones)
        out = self.runtime.step(dt, t, on_bones=self.publish_bones)
        t1 = time.perf_counter()
        if out is None:  # no bone targets yet: nothing to simulate
            return
        self.meter.tick()
        self.step_ms.add(1e3 * (t1 - t0 - sum(self._bones_s)))  # the step alone, as the benchmark's
        self.cg_iters.add(out.stats.cg_iters)
        self.factor_held.add(out.stats.held)
        # the bones went out inside the step (publish_bones); now every other message of the tick
        # is built, then published (the messages and publish stages add the bones' share)
        stamp = rm.stamp_from_seconds(out.t)  # the time of the state: the end of the step
        build_s, publish_s = self._bones_s
        t1b = time.perf_counter()
        marker_tick = t - self.last_marker >= self.marker_period - 1e-6
        if marker_tick:
            self.last_marker = t
        skin_tick = self.params["publish_skin_vertices"]
        rest = []
        for hand in self.hand_topics:
            ho = out.hands[hand.side]
            if not ho.entered:  # no target yet: this hand publishes nothing
                continue
            if not hand.mesh_sent:  # once per hand model, latched
                hand.mesh_sent = True
                rest.append((hand.mesh, hand.mesh_bytes))
            # on demand (nobody subscribed: no 142 kB message built) and at most at skin_vertices_rate
            if (skin_tick and t - hand.last_skin >= self.skin_period - 1e-6
                    and hand.skin.get_subscription_count()):
                hand.last_skin = t
                rest.append((hand.skin, rm.xyz_cloud_from_numpy(ho.skin_vertices, stamp)))
            if marker_tick:
                verts, tris = self.runtime.display_mesh(out, hand=hand.side)
                rest.append((hand.marker, hand.marker_serializer.serialize(verts, tris, stamp)))
        # the per-step messages as CDR bytes built with numpy (cdr_messages: ~0.4 ms a tick less
        # than building and serializing message objects)
        stamp_ns = rm.stamp_to_ns(stamp)
        if len(out.object_names):
            rest.append((self.pub_objects, object_states_cdr(
                out.object_names, out.object_poses, out.object_twists, out.object_accels, stamp_ns)))
        c = out.contacts
        rest.append((self.pub_contacts, contacts_cloud_cdr(
            c["points"], c["normals"], c["forces"], c["objects"], c["slip"], stamp_ns, hand=c["hand"], bone=c["bone"],
            other_hand=c["other_hand"], other_bone=c["other_bone"])))
        if marker_tick:
            rest.append((self.pub_contact_markers,
                         self.contact_serializer.serialize(c["points"], c["forces"], c["slip"], stamp)))
        t2 = time.perf_counter()
        for pub, msg in rest:
            pub.publish(msg)
        if out.warning:
            self.last_guard_warning = out.warning
            self.get_logger().warning(out.warning, throttle_duration_sec=2.0)
        t3 = time.perf_counter()
        self.tick_ms.add(1e3 * (t3 - t0))
        for name, ms in (*out.stages.items(), ("messages", 1e3 * (build_s + t2 - t1b)),
                         ("publish", 1e3 * (publish_s + t3 - t2))):
            self.stage_ms[name].add(ms)

    def publish_bones(self, t_state, hands):
        """/hand/{side}/bones and their /tf, as soon as the step's state is final (SimRuntime.step's
        on_bones): the latency a user sees, tracker -> bones, leaves out the skin, the contact rows
        and every other message of the tick (2-4 ms of the tick's p99 in the demo)."""
        tb = time.perf_counter()
        stamp = rm.stamp_from_seconds(t_state)  # as the tick's other messages: the same stamp
        msgs = [rm.pose_array_cdr(poses, rm.stamp_to_ns(stamp)) for _, poses in hands]
        tp = time.perf_counter()
        topics = {hand.side: hand for hand in self.hand_topics}
        for (side, _), msg in zip(hands, msgs):
            topics[side].bones.publish(msg)
        for side, poses in hands:
            self.tf.publish_bones(poses, stamp, side)  # TF: the same poses and stamp as the bones
        self._bones_s = [tp - tb, time.perf_counter() - tp]

    def step_dt(self, t):
        """The step's length [s]: 1/sim_rate, or with `max_step` set, the time since the previous
        tick (at least 1/sim_rate, at most max_step): a node that cannot keep sim_rate then keeps
        real time with longer steps instead of simulating in slow motion (implicit Euler stays
        stable; the two-hand scenes hold at 12 steps/s offline)."""
        last, self.last_tick = self.last_tick, t
        if self.max_step <= self.dt or last is None:
            return self.dt
        dt = min(max(t - last, self.dt), self.max_step)
        if dt > 1.5 * self.dt:
            self.long_steps += 1
        self.step_dt_ms.add(1e3 * dt)
        return dt

    def stage_diagnostics(self):
        """stage_<name>_ms_p50 / _p99 of every stage of the tick (NaN before the first step)."""
        out = {}
        for name, stats in self.stage_ms.items():
            out[f"stage_{name}_ms_p50"], out[f"stage_{name}_ms_p99"] = p50_p99(stats)
        return out

    def target_diagnostics(self):
        """target_gaps / target_delay_ms_p50 / target_age_s over every hand (the stalest hand's
        age), and with two hands each side's, prefixed `{side}_`, with `{side}_entered`."""
        ages = [h.target_age_s() for h in self.hand_topics]
        received = [a for a in ages if a >= 0.0]
        out = {"target_gaps": sum(h.target_gaps for h in self.hand_topics),
               "target_delay_ms_p50": self.target_delay_ms.median(),
               "target_age_s": max(received) if received else -1.0}
        if len(self.hand_topics) > 1:
            for hand, age, entered in zip(self.hand_topics, ages, self.runtime.hand_placed):
                out.update({f"{hand.side}_entered": bool(entered), f"{hand.side}_target_gaps": hand.target_gaps,
                            f"{hand.side}_target_delay_ms_p50": hand.target_delay_ms.median(),
                            f"{hand.side}_target_age_s": age})
        return out

    def collect_diagnostics(self):
        rate = self.meter.stats()
        values = {
            "sim_rate_hz": rate["rate_hz"],
            "step_ms_p50": self.step_ms.median(), "step_ms_p99": self.step_ms.percentile(99),
            "step_ms_max": self.step_ms.max(),
            "cg_iters_p50": self.cg_iters.median(),
            "cg_iters_max": int(self.cg_iters.max()) if len(self.cg_iters) else 0,
            "factor_held_share": float(self.factor_held.values().mean()) if len(self.factor_held) else 0.0,
            "tick_ms_p50": self.tick_ms.median(), "tick_ms_p99": self.tick_ms.percentile(99),
            **self.stage_diagnostics(),
            "overruns": self.step_ms.over_budget,
            # max_step: steps longer than 1.5/sim_rate taken to keep real time, and their median length
            **({"long_steps": self.long_steps, "step_dt_ms_p50": self.step_dt_ms.median()}
               if self.max_step > self.dt else {}),
            **self.target_diagnostics(),
            **self.runtime.diagnostics(),
            **(self.sizer.diagnostics() if self.sizer is not None and self.sizer.state != "ready" else {}),
            **{f"rejected_{k}": v for k, v in self.rejections.counts.items()},
        }
        values["last_guard_warning"] = self.last_guard_warning or "-"
        waiting = " and ".join(hand_topic(h.side, "intermediate_bones") for h in self.hand_topics)
        message = "simulating" if self.step_ms.count else f"waiting for {waiting}"
        if self.last_guard_warning:  # the latest divergence stays visible in the status line
            message = f"{message}; {values['rejected_steps']} step(s) rejected, last: {self.last_guard_warning}"
        level = "warn" if values.get("rejected_steps", 0) else "ok"
        # the ticks' median period, not their mean rate: a pause (a new hand size) is no overload
        tick_hz = 1e3 / rate["period_p50_ms"] if rate["period_p50_ms"] > 0 else math.inf
        behind = slow_motion(tick_hz, rate["count"], self.dt, self.max_step, values["step_ms_p50"])
        if behind:  # in the status line while it lasts, and in the log
            message, level = f"{message}; {behind}", "warn"
            self.get_logger().warning(behind, throttle_duration_sec=10.0)
        return values, level, message


def main(args=None):
    parser = build_parser()
    _, argv = split_cli(parser, args)
    return run_node(SimNode, init_args=argv)


if __name__ == "__main__":
    raise SystemExit(main())
