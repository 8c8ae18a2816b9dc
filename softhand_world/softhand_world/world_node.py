"""world_node: the pybullet world at engine_rate, coupled to the hand through copies (paper Sect. 3.7).

Subscribes /hand/object_states (latest kept, bad entries rejected and counted); publishes
/world/object_states every engine step (stamped with the engine time), /world/markers at
marker_rate and /diagnostics. All physics lives in softhand_world.world.World; this file converts
messages, owns the timers and keeps the engine clock on the node clock (wall or /clock).
"""
from __future__ import annotations

import argparse
import time

import numpy as np
from rclpy.node import Node
from trajectory_msgs.msg import MultiDOFJointTrajectory
from visualization_msgs.msg import MarkerArray

from softhand_sim.ros import msgs as rm
from softhand_sim.ros.cdr_messages import object_states_cdr
from softhand_sim.ros.common import LATEST_QOS, PUB_QOS, STREAM_QOS, DiagnosticsPublisher, RejectionLog, RateMeter, fail, run_node, split_cli
from softhand_sim.ros.params import declare_node_params
from softhand_sim.scene import SceneError, load_scene
from softhand_sim.timing import FixedRateScheduler, StepStats

from softhand_world.world import World, WorldConfig

NODE_NAME = "world_node"
REJECT_LOG_PERIOD = 2.0   # [s] at most one log line per rejection reason per period
MAX_CATCH_UP_STEPS = 4    # engine steps per timer tick when the timer fell behind the clock
CLOCK_BACK_S = 1.0        # [s] a clock this far behind the engine restarts it at the clock (bag restart)
DIAG_WINDOW = 1000        # engine steps in the /diagnostics step-time statistics


def build_parser():
    return argparse.ArgumentParser(
        prog="world_node",
        description="softhand pybullet world (paper Sect. 3.7): steps the scene at engine_rate, couples "
                    "its dynamic objects by Eq. 14 to the hand's copies from /hand/object_states and "
                    "publishes /world/object_states, /world/markers and /diagnostics. Parameters "
                    "(defaults in config/softhand.yaml) via --ros-args -p key:=value or --params-file.",
        epilog="example: softhand-world --ros-args -p engine_rate:=60.0 -p extrapolate:=false",
    )


class WorldNode(Node):
    """Thin rclpy node over World."""

    def __init__(self):
        super().__init__(NODE_NAME)
        self.params = declare_node_params(self, NODE_NAME)  # ParamError: run_node reports it, exit 1
        p = self.params
        try:
            self.scene = load_scene(p["scene_file"] or None)
        except SceneError as exc:  # name the parameter that led to the bad scene
            fail(f"{NODE_NAME}: parameter 'scene_file' = {p['scene_file']!r}: {exc}")
        try:
            config = WorldConfig(engine_rate=p["engine_rate"], coupling_kx=p["coupling_kx"],
                                 coupling_ktheta=p["coupling_ktheta"], copy_timeout=p["copy_timeout"],
                                 extrapolate=p["extrapolate"], coupling_damping=p["coupling_damping"],
                                 coupling_mode=p["coupling_mode"], coupling_max_omega=p["coupling_max_omega"],
                                 gravity=p["gravity"])
            self.world = World(self.scene, config, start_time=self.now_s())
        except (SceneError, ValueError) as exc:
            fail(str(exc))
        self.get_logger().info(
            f"scene {self.scene.path}: dynamic {list(self.world.names)}; engine {p['engine_rate']} Hz; "
            f"coupling (kx, ktheta) per object {self.world.stiffness.round(4).tolist()}")
        self.rejections = RejectionLog(self.get_logger(), REJECT_LOG_PERIOD)
        self.meter = RateMeter()
        self.step_ms = StepStats(window=DIAG_WINDOW)  # [ms] per engine step
        self.published = 0  # /world/object_states messages: with published_stamp (the engine time, the
        # stamp of the last one) what a recorder should hold (tests/pipeline/test_across_hosts.py)
        # Engine step k ends at scheduler time k: the first one at start + dt. late_resyncs in
        # /diagnostics counts the times it fell more than MAX_CATCH_UP_STEPS behind and skipped ahead.
        self.scheduler = FixedRateScheduler(p["engine_rate"], max_catch_up=MAX_CATCH_UP_STEPS,
                                            clock_back_ns=int(CLOCK_BACK_S * 1e9),
                                            first_due_ns=int(round((self.world.time + self.world.dt) * 1e9)))
        self.pub_states = self.create_publisher(MultiDOFJointTrajectory, "/world/object_states", STREAM_QOS)
        self.pub_markers = self.create_publisher(MarkerArray, "/world/markers", PUB_QOS)
        self.create_subscription(MultiDOFJointTrajectory, "/hand/object_states", self.on_hand_objects, LATEST_QOS)
        self.diag = DiagnosticsPublisher(self, self.collect_diagnostics, 1.0 / p["diagnostics_rate"])
        self.timer = self.create_timer(self.world.dt, self.on_timer)
        self.marker_timer = self.create_timer(1.0 / p["marker_rate"], self.on_markers)

    def now_s(self):
        return self.get_clock().now().nanoseconds * 1e-9

    def close(self):
        self.world.close()

    # -------------------------------------------------------------------- inputs
    def reject(self, reason, detail):
        self.rejections.log(reason, detail)

    def on_hand_objects(self, msg):
        try:
            names, poses, twists, accels, stamp_ns = rm.object_states_to_numpy(msg)
        except ValueError as exc:
            self.reject("hand_object_states", exc)
            return
        for i, name in enumerate(names):  # each object on its own: one bad entry spoils no other
            try:
                self.world.set_copy(name, poses[i], twists[i], accels[i], stamp_ns * 1e-9)
            except KeyError as exc:
                self.reject("unknown_object", exc)
            except ValueError as exc:
                self.reject("bad_values", exc)

    # -------------------------------------------------------------------- the step
    def on_timer(self):
        dt = self.world.dt
        for t_end_ns in self.scheduler.due(self.get_clock().now().nanoseconds):
            t_end = t_end_ns * 1e-9
            if abs(self.world.time + dt - t_end) > 0.5 * dt:  # the schedule skipped ahead or restarted
                self.world.set_time(t_end - dt)  # (clock jump, bag restart, /clock reset)
            t0 = time.perf_counter()
            self.world.step()
            self.step_ms.add(1e3 * (time.perf_counter() - t0))
            self.meter.tick()
            s = self.world.states()
            # CDR bytes built with numpy, as sim_node's (cdr_messages: 120 Hz of message objects cost
            # ~0.15 ms each to build and serialize)
            self.pub_states.publish(object_states_cdr(s.names, s.pose, s.twist, s.accel,
                                                      rm.seconds_to_ns(s.stamp)))
            self.published += 1

    def on_markers(self):
        s = self.world.states()
        poses = np.array([self.world.states().pose[self.world.object_index(o.name)] if not o.static else o.pose
                          for o in self.scene.objects]).reshape(-1, 7)
        self.pub_markers.publish(rm.scene_markers(self.scene.objects, rm.stamp_from_seconds(s.stamp), poses=poses,
                                                  ground_height=self.scene.ground_height))  # table and ground drawn

    def collect_diagnostics(self):
        status = self.world.copy_status()
        coupled = sorted(n for n, v in status.items() if v == "coupled")
        stale = sorted(n for n, v in status.items() if v == "stale")
        values = {
            "engine_rate_hz": self.meter.stats()["rate_hz"],
            "step_ms_p50": self.step_ms.median(), "step_ms_p99": self.step_ms.percentile(99),
            "step_ms_max": self.step_ms.max(),
            "engine_time": self.world.time,
            "coupled_objects": ",".join(coupled),
            "stale_copies": ",".join(stale),
            "copy_gaps": sum(c.gaps for c in self.world.copies),
            "late_resyncs": self.scheduler.resyncs,
            "published": self.published, "published_stamp": f"{self.world.time:.6f}",
            **{f"rejected_{k}": v for k, v in self.rejections.counts.items()},
        }
        level = "warn" if stale or self.rejections.counts else "ok"
        message = f"{len(coupled)} coupled, {len(stale)} stale" if status else "no dynamic objects"
        return values, level, message


def main(args=None):
    parser = build_parser()
    _, argv = split_cli(parser, args)
    return run_node(WorldNode, init_args=argv)


if __name__ == "__main__":
    raise SystemExit(main())
