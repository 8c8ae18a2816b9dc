"""play_node: replays a tracker rosbag2 (mcap or sqlite3) on its recorded timing.

    softhand-play BAG [--rate R] [--loop] [--start S] [--wait-subscribers N]
    ros2 run softhand_tracking play_node --ros-args -p bag:=BAG -p rate:=2.0

Publishes the bag's /tracker/hand_joints messages (geometry_msgs/PoseArray, header stamps as
recorded) at wall time  t0 + (bag_time - bag_start) / rate, and /clock (rosgraph_msgs/Clock) with
the bag time, before each message and every 1/clock_rate s in between, so nodes running with
use_sim_time see a clock that advances through gaps (a tracker dropout) too. With --loop the
bag repeats; each repeat shifts both /clock and the header stamps forward by the bag's duration
plus one median period, so time never goes backwards.

Exit codes: 0 when the bag is done (non-looping) or on Ctrl-C/SIGTERM; 1 when the bag cannot be
used (the message on stderr names the bag and the problem); 2 for a bad command line.
Flags given on the command line override the ROS parameters of the same name.
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np
import rclpy
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from geometry_msgs.msg import PoseArray
from rosgraph_msgs.msg import Clock

from softhand_sim.ros.common import PUB_QOS, split_cli
from softhand_sim.ros.msgs import stamp_from_ns, stamp_to_ns
from softhand_sim.params import ParamError
from softhand_sim.ros.params import declare_node_params
from softhand_sim.ros.bagio import BagError, read_topic

MSGTYPE = "geometry_msgs/msg/PoseArray"
_MAX_SLEEP_S = 0.02  # sleep in slices so a shutdown (signal) is noticed quickly



def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="softhand-play",
        description="Replay a tracker rosbag2 (mcap or sqlite3) on /tracker/hand_joints on its recorded "
                    "timing, publishing /clock with the bag time (for use_sim_time). Exits when done.",
        epilog="ROS parameters of the same names (bag, rate, loop, start, topic, publish_clock, clock_rate, "
               "wait_subscribers, wait_timeout) work with --ros-args -p NAME:=VALUE; flags override them.")
    p.add_argument("bag", nargs="?", default=None, help="rosbag2 directory (folder with metadata.yaml)")
    p.add_argument("--rate", type=float, default=None, help="playback speed factor (default 1.0)")
    p.add_argument("--loop", action="store_true", default=None, help="repeat the bag until stopped")
    p.add_argument("--start", type=float, default=None, metavar="S", help="skip the first S seconds of the bag")
    p.add_argument("--topic", default=None, help="topic (default /tracker/hand_joints)")
    p.add_argument("--no-clock", dest="publish_clock", action="store_false", default=None,
                   help="do not publish /clock")
    p.add_argument("--clock-rate", dest="clock_rate", type=float, default=None, metavar="HZ",
                   help="/clock ticks per second between messages (default 250, 0: only with messages)")
    p.add_argument("--wait-subscribers", dest="wait_subscribers", type=int, default=None, metavar="N",
                   help="wait until N subscribers match the topic before playing (default 0)")
    return p


class PlayNode(Node):
    """Loads the bag in __init__ (so a bad bag fails before anything is published); play() replays it."""

    def __init__(self, overrides: dict):
        super().__init__("play_node")
        cfg = declare_node_params(self, "play_node")  # schema: softhand_sim/params.py
        cfg.update({k: v for k, v in overrides.items() if v is not None})
        self.cfg = cfg
        if not cfg["bag"]:
            raise BagError("no bag given: pass BAG on the command line or -p bag:=DIR")
        if cfg["rate"] <= 0:
            raise BagError(f"rate must be > 0, got {cfg['rate']}")
        if cfg["start"] < 0:
            raise BagError(f"start must be >= 0 s, got {cfg['start']}")
        data = read_topic(cfg["bag"], cfg["topic"], MSGTYPE)
        stamps = np.asarray(data.stamps_ns, dtype=np.int64)
        keep = stamps >= stamps[0] + int(round(cfg["start"] * 1e9))
        if not keep.any():
            raise BagError(f"start {cfg['start']} s is past the end of bag {data.path} "
                           f"(duration {data.duration_s:.3f} s)")
        try:
            self.msgs = [deserialize_message(raw, PoseArray) for raw, k in zip(data.payloads, keep) if k]
        except Exception as exc:
            raise BagError(f"bag {data.path}: a {cfg['topic']} message does not decode as {MSGTYPE}: {exc}") from None
        self.stamps = stamps[keep]
        periods = np.diff(self.stamps)
        self.loop_shift_ns = int(self.stamps[-1] - self.stamps[0]) + (int(np.median(periods)) if periods.size else 0)
        self.pub = self.create_publisher(PoseArray, cfg["topic"], PUB_QOS)
        self.clock_pub = self.create_publisher(Clock, "/clock", PUB_QOS) if cfg["publish_clock"] else None
        self.published = 0
        self.get_logger().info(
            f"bag {data.path} ({data.storage}): {len(self.msgs)} messages on {cfg['topic']}, "
            f"{(self.stamps[-1] - self.stamps[0]) * 1e-9:.2f} s, rate x{cfg['rate']:g}"
            + (", looping" if cfg["loop"] else ""))

    # ---------------------------------------------------------------------------------- replay

    def _sleep_until(self, wall_target: float) -> bool:
        """Sleep until monotonic time `wall_target`; False if ROS shut down meanwhile."""
        while True:
            if not rclpy.ok():
                return False
            left = wall_target - time.monotonic()
            if left <= 0:
                return True
            time.sleep(min(left, _MAX_SLEEP_S))

    def _publish_clock(self, bag_ns: int) -> None:
        if self.clock_pub is not None:
            self.clock_pub.publish(Clock(clock=stamp_from_ns(bag_ns)))

    def wait_for_subscribers(self) -> bool:
        """Block until `wait_subscribers` subscriptions match (BagError-free: a plain timeout error)."""
        want = int(self.cfg["wait_subscribers"])
        deadline = time.monotonic() + float(self.cfg["wait_timeout"])
        while self.pub.get_subscription_count() < want:
            if time.monotonic() > deadline:
                raise TimeoutError(f"{self.pub.get_subscription_count()} of {want} subscribers on "
                                   f"{self.cfg['topic']} after {self.cfg['wait_timeout']} s")
            if not self._sleep_until(time.monotonic() + 0.05):
                return False
        # the writer has matched the readers; give the readers' side of discovery a moment too,
        # so the first messages are not sent to a reader that does not know this writer yet
        return self._sleep_until(time.monotonic() + (0.3 if want else 0.0))

    def play(self) -> None:
        """Replay (forever with loop); returns when done or when ROS shuts down."""
        rate = float(self.cfg["rate"])
        tick_ns = int(1e9 / self.cfg["clock_rate"]) if self.cfg["clock_rate"] > 0 else 0
        t0 = int(self.stamps[0])
        wall0 = time.monotonic()
        loop = 0
        next_log = wall0 + 10.0
        while True:
            shift = loop * self.loop_shift_ns
            last_clock = None
            for msg, stamp in zip(self.msgs, self.stamps):
                bag_ns = int(stamp) + shift
                # /clock ticks in the gap before this message, on the same wall mapping
                if tick_ns and self.clock_pub is not None and last_clock is not None:
                    t = last_clock + tick_ns
                    while t < bag_ns:
                        if not self._sleep_until(wall0 + (t - t0) * 1e-9 / rate):
                            return
                        self._publish_clock(t)
                        t += tick_ns
                if not self._sleep_until(wall0 + (bag_ns - t0) * 1e-9 / rate):
                    return
                self._publish_clock(bag_ns)
                last_clock = bag_ns
                if shift:
                    msg.header.stamp = stamp_from_ns(stamp_to_ns(msg.header.stamp) + self.loop_shift_ns)
                self.pub.publish(msg)
                self.published += 1
                if time.monotonic() > next_log:
                    next_log = time.monotonic() + 10.0
                    self.get_logger().info(f"published {self.published} messages, bag time "
                                           f"{(bag_ns - t0) * 1e-9:.1f} s")
            if not self.cfg["loop"]:
                # let reliable subscribers acknowledge the tail before the publisher goes away
                self.pub.wait_for_all_acked(Duration(seconds=2.0))
                self.get_logger().info(f"done: published {self.published} messages")
                return
            loop += 1
            self.get_logger().info(f"loop {loop}: restarting the bag")


def main(args=None) -> None:
    ns, argv = split_cli(build_parser(), args)
    overrides = {k: getattr(ns, k) for k in ("bag", "rate", "loop", "start", "topic", "publish_clock",
                                             "clock_rate", "wait_subscribers")}
    rclpy.init(args=argv)
    node = None
    code = 0
    try:
        node = PlayNode(overrides)
        if node.wait_for_subscribers():
            node.play()
    except (BagError, ParamError, TimeoutError) as exc:
        print(f"softhand-play: error: {exc}", file=sys.stderr, flush=True)
        code = 1
    except (KeyboardInterrupt, ExternalShutdownException):
        code = 0
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    sys.exit(code)


if __name__ == "__main__":
    main()
