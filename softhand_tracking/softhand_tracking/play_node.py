"""play_node: replays a tracker rosbag2 (mcap or sqlite3), or any topics of a recording, on its recorded timing.

    softhand-play BAG [--rate R] [--loop | --repeat N] [--start S] [--wait-subscribers N] [--wait-for-nodes NODE ...]
                      [--stamps publish|recorded] [--topic T] [--hand right|left]
    softhand-play BAG --all | --topics T [T ...]      (a record_node / ros2 bag recording)
    ros2 run softhand_tracking play_node --ros-args -p bag:=BAG -p rate:=2.0

Tracker mode (the default) publishes the bag's tracker frames (geometry_msgs/PoseArray): every
tracker topic found in it (docs/INTERFACE.md "Topics"), /tracker/right/hand_joints and
/tracker/left/hand_joints as they are, and the single-hand /tracker/hand_joints of older bags as
/tracker/{hand}/hand_joints (parameter `hand`, default right; it renames only that legacy topic).
A two-hand bag's frames are played interleaved on one timeline, in bag time order. `topic` plays
that one topic only (the legacy name renamed as above). Each frame goes out at wall time
t0 + (bag_time - bag_start) / rate. Stamps (docs/INTERFACE.md "Stamps and clocks"): with
`stamps: publish` (the default) each frame is stamped, as a live tracker stamps its capture, with
its publish time on the run's clock: the node clock at the start of the replay plus
(bag_time - bag_start) / rate, so every stamp of a run is on one clock and an output can be paired
with the tracker frame it answers; `stamps: recorded` keeps the bag's header stamps. /clock
(rosgraph_msgs/Clock) carries the same time as the stamps (publish: the run's time; recorded: the
bag time), before each message and every 1/clock_rate s in between, so nodes running with
use_sim_time see a clock that advances through gaps (a tracker dropout) too. With --loop the bag
repeats; each repeat shifts /clock and the stamps forward by the bag's duration plus one median
period, so time never goes backwards.

Nothing lost (docs/INTERFACE.md "QoS"): the publishers are reliable (they match best-effort and
reliable subscribers alike); with --wait-for-nodes the replay starts only once every named node
has a subscription on at least one replayed topic and each replayed topic's publisher has matched
every named node subscribed to it (a recorder takes both hands' topics, a tracking_node only its
own side's), so no subscriber misses the first frames; at the end it waits for the reliable
subscribers' acknowledgements.

With --all (every topic) or --topics, the recording is replayed like `ros2 bag play`: each topic
of any type is published raw (the recorded CDR bytes, never deserialized) with the QoS its
publishers offered when it was recorded (metadata `offered_qos_profiles`, chosen as rosbag2
Jazzy's Rosbag2QoS::adapt_offer_to_recorded_offers does: the recorded profile with keep-last 10,
or rosbag2's default when the publishers differed), so /hand/{side}/skin_mesh is transient local again
and a viewer that joins late still gets a skin mesh. /clock is published as above (a recorded /clock
topic is then left out); on --loop the header stamps of Header-first messages move with it.
--wait-subscribers N then counts the subscribers of all replayed topics together.

A recording cut short (recorder killed: mcap without summary and end magic, no metadata.yaml) is
played from its complete chunks, with a warning that names the recover command
(`python -m softhand_sim.ros.bagio recover BROKEN.mcap NEW_BAG`).

Exit codes: 0 when the bag is done (non-looping) or on Ctrl-C/SIGTERM; 1 when the bag cannot be
used (the message on stderr names the bag and the problem); 2 for a bad command line.
Flags given on the command line override the ROS parameters of the same name.
"""
from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np
import rclpy
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, LivelinessPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rosbags.rosbag2 import Reader
from geometry_msgs.msg import PoseArray
from rosgraph_msgs.msg import Clock

from softhand_sim.ros.common import PUB_QOS, message_class, split_cli
from softhand_sim.ros.msgs import stamp_from_ns
from softhand_sim.params import ParamError
from softhand_sim.ros.params import declare_node_params
from softhand_sim.ros.bagio import (BagError, check_bag_path, header_stamp_ns, mcap_is_closed, read_recording,
                                    starts_with_header, with_header_stamp)
from softhand_sim.topics import LEGACY_TRACKER, SIDES, TRACKER_TOPICS, tracker_topic

MSGTYPE = "geometry_msgs/msg/PoseArray"
#: The tracker replay: reliable like PUB_QOS, but the writer keeps the last 1000 frames (10 s of a
#: 100 Hz tracker) for its reliable readers. With PUB_QOS's keep last 10, a recorder that stalled
#: 0.9 s while writing a two-hand run lost 45 frames per hand: a reliable keep-last writer drops
#: what a slow reader has not acknowledged once its history is full.
REPLAY_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)
END_LINGER_S = 0.5  # [s] after the last frame, before the publishers go away (best-effort readers)
ACK_TIMEOUT_S = 10.0  # [s] at the end, wait this long at most for reliable subscribers' acknowledgements
REPLAY_STARTED = "replay started"  # the log line of the first frame (tests wait for it)
_MAX_SLEEP_S = 0.02  # sleep in slices so a shutdown (signal) is noticed quickly



def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="softhand-play",
        description="Replay a tracker rosbag2 (mcap or sqlite3) on its recorded timing: every tracker topic "
                    "in it, /tracker/{right,left}/hand_joints as they are (a two-hand bag interleaved on "
                    "one timeline) and an older bag's /tracker/hand_joints as /tracker/{--hand}/hand_joints; "
                    "publishes /clock with the bag time (for use_sim_time). Exits when done. "
                    "With --all or --topics, replay a recording's topics with their recorded QoS.",
        epilog="ROS parameters of the same names (bag, rate, loop, repeat, start, topic, hand, publish_clock, clock_rate, "
               "wait_subscribers, wait_for_nodes, wait_timeout, stamps, replay_topics, replay_all) work with "
               "--ros-args -p NAME:=VALUE; flags override them.")
    p.add_argument("bag", nargs="?", default=None, help="rosbag2 directory (folder with metadata.yaml)")
    p.add_argument("--rate", type=float, default=None, help="playback speed factor (default 1.0)")
    p.add_argument("--loop", action="store_true", default=None, help="repeat the bag until stopped")
    p.add_argument("--repeat", type=int, default=None, metavar="N",
                   help="play the bag N times, one after the other (default 1)")
    p.add_argument("--start", type=float, default=None, metavar="S", help="skip the first S seconds of the bag")
    p.add_argument("--topic", default=None,
                   help="play only this tracker topic of the bag (default: every tracker topic in it)")
    p.add_argument("--hand", choices=SIDES, default=None,
                   help="the side an older bag's /tracker/hand_joints is played as (default right)")
    p.add_argument("--no-clock", dest="publish_clock", action="store_false", default=None,
                   help="do not publish /clock")
    p.add_argument("--clock-rate", dest="clock_rate", type=float, default=None, metavar="HZ",
                   help="/clock ticks per second between messages (default 250, 0: only with messages)")
    p.add_argument("--wait-subscribers", dest="wait_subscribers", type=int, default=None, metavar="N",
                   help="wait until N subscriptions (all replayed topics together) match before playing "
                        "(default 0)")
    p.add_argument("--wait-for-nodes", dest="wait_for_nodes", nargs="+", default=None, metavar="NODE",
                   help="wait until each of these nodes subscribes to a replayed topic and is matched on "
                        "every replayed topic it subscribes to")
    p.add_argument("--stamps", dest="stamps", choices=("publish", "recorded"), default=None,
                   help="header stamps: publish time on the run's clock (default) or as recorded")
    which = p.add_mutually_exclusive_group()
    which.add_argument("--topics", dest="replay_topics", nargs="+", default=None, metavar="T",
                       help="replay these topics (any type, raw) with their recorded QoS, like ros2 bag play")
    which.add_argument("--all", dest="replay_all", action="store_true", default=None,
                       help="replay every topic of the recording with its recorded QoS")
    return p


#: rosbag2's default playback offer (Rosbag2QoS{}: rmw_qos_profile_default, keep last 10).
DEFAULT_PLAY_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
                              durability=DurabilityPolicy.VOLATILE)


def _duration(t) -> Duration:
    """rclpy Duration of a recorded QoS time (sec, nsec); (0, 0) is rmw's 'default'."""
    return Duration(nanoseconds=int(t.sec) * 1_000_000_000 + int(t.nsec))


def playback_qos(offers: list) -> tuple[QoSProfile, str]:
    """The QoS to publish a recorded topic with, from its recorded offers (rosbags Qos list).

    As rosbag2 Jazzy's Rosbag2QoS::adapt_offer_to_recorded_offers: no offers -> rosbag2's default
    (reliable, volatile, keep last 10); offers that agree on every policy that affects matching
    (reliability, durability, deadline, liveliness and its lease) -> that profile with keep last 10
    (discovery records no history); otherwise the default. Returns the profile and a note for the log.
    """
    if not offers:
        return DEFAULT_PLAY_QOS, " (no QoS recorded: rosbag2's default)"
    keys = {(q.reliability, q.durability, q.deadline, q.liveliness, q.liveliness_lease_duration) for q in offers}
    if len(keys) > 1:
        return DEFAULT_PLAY_QOS, " (its publishers offered different QoS: rosbag2's default)"
    q = offers[0]

    def policy(enum, value, default):
        return enum[value.name] if value.name in enum.__members__ and value.name != "UNKNOWN" else default

    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                      reliability=policy(ReliabilityPolicy, q.reliability, ReliabilityPolicy.RELIABLE),
                      durability=policy(DurabilityPolicy, q.durability, DurabilityPolicy.VOLATILE),
                      deadline=_duration(q.deadline), lifespan=_duration(q.lifespan),
                      liveliness=policy(LivelinessPolicy, q.liveliness, LivelinessPolicy.SYSTEM_DEFAULT),
                      liveliness_lease_duration=_duration(q.liveliness_lease_duration),
                      avoid_ros_namespace_conventions=bool(q.avoid_ros_namespace_conventions)), ""


def _indexed_topics(bag):
    """The topics of a finished bag from its index (no message read), or None for a recording cut
    short (one .mcap without metadata.yaml or without end magic: only reading it tells its topics)."""
    p = check_bag_path(bag, allow_torn=True)
    mcaps = sorted(p.glob("*.mcap"))
    if len(mcaps) == 1 and (not (p / "metadata.yaml").is_file() or not mcap_is_closed(mcaps[0])):
        return None
    try:
        with Reader(p) as reader:
            return sorted({c.topic for c in reader.connections})
    except Exception as exc:  # rosbags raises ReaderError, yaml, KeyError, struct errors...
        raise BagError(f"cannot read bag {p} (corrupt or unsupported): {type(exc).__name__}: {exc}") from None


def tracker_frames(bag, topic: str = "", hand: str = "right"):
    """The tracker frames to replay: (recording, [(bag stamp [ns], topic to publish on, raw CDR)] in
    bag time order, {bag topic: topic to publish on}).

    topic "": every tracker topic of the bag (topics.TRACKER_TOPICS); else that topic only. The
    per-side topics keep their names; the legacy /tracker/hand_joints becomes tracker_topic(hand).
    BagError (naming the bag's topics) when there is no tracker topic, when a topic is not a
    PoseArray, or when the legacy topic would be played on a side topic the bag also has.
    """
    if hand not in SIDES:
        raise BagError(f"hand must be 'right' or 'left', got {hand!r}")
    if topic:
        rec = read_recording(bag, [topic], allow_torn=True)
    else:
        indexed = _indexed_topics(bag)
        wanted = None if indexed is None else [t for t in indexed if t in TRACKER_TOPICS]
        if wanted == []:
            raise BagError(f"bag {Path(bag)} has no tracker topic ({', '.join(sorted(TRACKER_TOPICS))}); "
                           f"topics in it: {', '.join(indexed) or 'none'}")
        rec = read_recording(bag, wanted, allow_torn=True)
        if indexed is None and not any(t in TRACKER_TOPICS for t in rec.topics):
            raise BagError(f"bag {rec.path} has no tracker topic in its complete chunks "
                           f"({', '.join(sorted(TRACKER_TOPICS))}); topics there: {', '.join(sorted(rec.topics))}")
    played = sorted(t for t in rec.topics if t == topic or (not topic and t in TRACKER_TOPICS))
    for t in played:
        if rec.topics[t].msgtype != MSGTYPE:
            raise BagError(f"topic {t} in bag {rec.path} has type {rec.topics[t].msgtype}, expected {MSGTYPE}")
    out = {t: tracker_topic(hand) if t == LEGACY_TRACKER else t for t in played}
    if LEGACY_TRACKER in out and list(out.values()).count(out[LEGACY_TRACKER]) > 1:
        other = "left" if hand == "right" else "right"
        hint = ("" if tracker_topic(other) in out.values()
                else f", or play the legacy one as the {other} hand (--hand {other})")
        raise BagError(f"bag {rec.path} has both {LEGACY_TRACKER} and {out[LEGACY_TRACKER]}, which would play "
                       f"on the same topic: choose one with --topic{hint}")
    frames = [(stamp, out[t], raw) for stamp, t, raw in rec.messages if t in out]
    return rec, frames, out


class PlayNode(Node):
    """Loads the bag in __init__ (so a bad bag fails before anything is published); play() replays it."""

    def __init__(self, overrides: dict):
        super().__init__("play_node")
        cfg = declare_node_params(self, "play_node", flags=overrides)  # schema: softhand_sim/params.py
        cfg["replay_topics"] = [t for t in cfg["replay_topics"] if t]  # [""]: ROS cannot type an empty list
        cfg["wait_for_nodes"] = [n.lstrip("/") for n in cfg["wait_for_nodes"] if n]
        if cfg["stamps"] not in ("publish", "recorded"):
            raise BagError(f"stamps must be 'publish' or 'recorded', got {cfg['stamps']!r}")
        self.cfg = cfg
        if not cfg["bag"]:
            raise BagError("no bag given: pass BAG on the command line or -p bag:=DIR")
        self.raw_pubs = None  # topic -> publisher when replaying a recording's topics raw
        self.pubs = {}        # tracker mode: topic -> publisher
        if cfg["replay_all"] or cfg["replay_topics"]:
            self._load_recording()
            return
        rec, frames, renamed = tracker_frames(cfg["bag"], cfg["topic"], cfg["hand"])
        if rec.warning:
            self.get_logger().warn(rec.warning)
        stamps = np.asarray([f[0] for f in frames], dtype=np.int64)
        keep = stamps >= stamps[0] + int(round(cfg["start"] * 1e9))
        if not keep.any():
            raise BagError(f"start {cfg['start']} s is past the end of bag {rec.path} "
                           f"(duration {(stamps[-1] - stamps[0]) * 1e-9:.3f} s)")
        # (topic, CDR bytes) in bag time order, both hands' on one timeline: published as bytes with
        # the stamp written in (bagio.with_header_stamp); building a PoseArray object per frame and
        # converting it back was most of this node's CPU. Each is decoded once here to check it.
        self.msgs = []
        for (_stamp, out, raw), k in zip(frames, keep):
            if not k:
                continue
            try:
                deserialize_message(raw, PoseArray)
                self.msgs.append((out, bytes(raw)))
            except Exception as exc:
                raise BagError(f"bag {rec.path}: a message for {out} does not decode as {MSGTYPE}: {exc}") from None
        self.stamps = stamps[keep]
        periods = np.diff(self.stamps)
        self.loop_shift_ns = int(self.stamps[-1] - self.stamps[0]) + (int(np.median(periods)) if periods.size else 0)
        self.pubs = {out: self.create_publisher(PoseArray, out, REPLAY_QOS) for out in sorted(set(renamed.values()))}
        self.clock_pub = self.create_publisher(Clock, "/clock", PUB_QOS) if cfg["publish_clock"] else None
        self.published = 0
        self.published_by_topic = Counter()
        per_topic = Counter(out for out, _m in self.msgs)
        listing = ", ".join(f"{per_topic[out]} on {out}" + (f" (recorded as {src})" if src != out else "")
                            for src, out in sorted(renamed.items(), key=lambda kv: kv[1]))
        self.get_logger().info(
            f"bag {rec.path} ({rec.storage}): {listing}, " + self._timing_line())

    def _timing_line(self) -> str:
        """'3.30 s, rate x1, 3 times' of the loaded bag, for the start-up log of either kind of replay."""
        cfg = self.cfg
        return (f"{(self.stamps[-1] - self.stamps[0]) * 1e-9:.2f} s, rate x{cfg['rate']:g}"
                + (", looping" if cfg["loop"] else f", {cfg['repeat']} times" if cfg["repeat"] > 1 else ""))

    def _load_recording(self) -> None:
        """Raw replay: the chosen topics' messages, one publisher per topic with its recorded QoS."""
        cfg = self.cfg
        rec = read_recording(cfg["bag"], None if cfg["replay_all"] else cfg["replay_topics"], allow_torn=True)
        if rec.warning:
            self.get_logger().warn(rec.warning)
        self.clock_pub = self.create_publisher(Clock, "/clock", PUB_QOS) if cfg["publish_clock"] else None
        self.raw_pubs, self.header_first = {}, set()
        for topic, info in sorted(rec.topics.items()):
            if topic == "/clock" and self.clock_pub is not None:
                self.get_logger().info("leaving out the recorded /clock: /clock is published with the bag time")
                continue
            try:
                cls = message_class(info.msgtype)
            except ValueError as exc:  # a type this rclpy installation does not have
                if not cfg["replay_all"]:
                    raise BagError(f"bag {rec.path}: cannot replay {topic}: {exc}") from None
                self.get_logger().warn(f"skipping {topic}: {exc}")
                continue
            qos, note = playback_qos(info.offered_qos)
            self.raw_pubs[topic] = self.create_publisher(cls, topic, qos)
            if starts_with_header(info.msgtype):
                self.header_first.add(topic)
            self.get_logger().info(f"{topic} [{info.msgtype}]: {qos.reliability.name.lower()}, "
                                   f"{qos.durability.name.lower()}{note}")
        msgs = [m for m in rec.messages if m[1] in self.raw_pubs]
        if not msgs:
            raise BagError(f"bag {rec.path}: nothing to replay (topics: {', '.join(sorted(rec.topics))})")
        stamps = np.asarray([m[0] for m in msgs], dtype=np.int64)
        keep = stamps >= stamps[0] + int(round(cfg["start"] * 1e9))
        if not keep.any():
            raise BagError(f"start {cfg['start']} s is past the end of bag {rec.path} "
                           f"(duration {(stamps[-1] - stamps[0]) * 1e-9:.3f} s)")
        self.raw_msgs = [(topic, raw) for (_s, topic, raw), k in zip(msgs, keep) if k]
        self.stamps = stamps[keep]
        periods = np.diff(self.stamps)
        self.loop_shift_ns = int(self.stamps[-1] - self.stamps[0]) + (int(np.median(periods)) if periods.size else 0)
        self.published = 0
        self.published_by_topic = Counter()
        self.get_logger().info(
            f"bag {rec.path} ({rec.storage}): {len(self.raw_msgs)} messages on {len(self.raw_pubs)} topics, "
            + self._timing_line())

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

    def _pubs_by_topic(self) -> dict:
        return dict(self.raw_pubs) if self.raw_pubs is not None else dict(self.pubs)

    def missing_nodes(self) -> list:
        """The wait_for_nodes not yet subscribed and matched. A node counts once the graph shows a
        subscription of it on at least one replayed topic, and every replayed topic it subscribes to
        has a publisher that matched at least as many subscriptions as the named nodes hold there
        (a recorder subscribes both hands' tracker topics, a tracking_node its own side's only)."""
        want = self.cfg["wait_for_nodes"]
        if not want:
            return []
        seen, unmatched = set(), set()
        for topic, pub in self._pubs_by_topic().items():
            subs = [i.node_name for i in self.get_subscriptions_info_by_topic(topic) if i.node_name in want]
            seen.update(subs)
            if subs and pub.get_subscription_count() < len(subs):
                unmatched.update(subs)
        return [n for n in want if n not in seen or n in unmatched]

    def _subscribers_seen(self) -> str:
        """Who the ROS graph lists as subscribed to each replayed topic, and the publisher's match
        count: what a missing node's error needs (a node name the graph has not resolved yet shows
        as rmw's placeholder for an unknown node)."""
        return "; ".join(f"{topic}: [{', '.join(i.node_name for i in self.get_subscriptions_info_by_topic(topic))}]"
                         f" {pub.get_subscription_count()} matched" for topic, pub in self._pubs_by_topic().items())

    def wait_for_subscribers(self) -> bool:
        """Block until `wait_subscribers` subscriptions match and every node of `wait_for_nodes` is
        subscribed and matched (a plain TimeoutError naming what is missing after `wait_timeout`)."""
        want = int(self.cfg["wait_subscribers"])
        deadline = time.monotonic() + float(self.cfg["wait_timeout"])
        pubs = list(self._pubs_by_topic().values())

        def matched() -> int:
            return sum(p.get_subscription_count() for p in pubs)

        def ready() -> bool:
            return matched() >= want and not self.missing_nodes()

        def named_subs() -> set:
            return {(topic, i.node_name) for topic in self._pubs_by_topic()
                    for i in self.get_subscriptions_info_by_topic(topic) if i.node_name in self.cfg["wait_for_nodes"]}

        waited = want or self.cfg["wait_for_nodes"]
        while True:
            while not ready():
                if time.monotonic() > deadline:
                    where = ", ".join(self._pubs_by_topic())
                    missing = self.missing_nodes()
                    # "N of M" only when a count was asked for (--wait-subscribers): with node
                    # names alone, "1 of 0 subscribers" read as if nothing had been waited for
                    count = f"{matched()} of {want} subscribers" if want else f"{matched()} subscriber(s) matched"
                    raise TimeoutError(f"{count} on {where} after {self.cfg['wait_timeout']} s"
                                       + (f"; not subscribed and matched: {', '.join(missing)}"
                                          f" (the graph shows: {self._subscribers_seen()})" if missing else ""))
                if not self._sleep_until(time.monotonic() + 0.05):
                    return False
            # the writer has matched the readers; give the readers' side of discovery a moment too,
            # so the first messages are not sent to a reader that does not know this writer yet
            subs = named_subs()
            if not self._sleep_until(time.monotonic() + (0.3 if waited else 0.0)):
                return False
            # ... and check again: a named node may meanwhile have subscribed to another replayed
            # topic (a recorder finds the other hand's topic a discovery period later), which then
            # gets its match and its moment too
            if ready() and named_subs() == subs:
                return True

    def _run_clock_ns(self) -> int:
        """The node clock now [ns]: the run's time the publish stamps start from."""
        return self.get_clock().now().nanoseconds

    def _stamp_map(self, t0: int, rate: float):
        """bag time [ns] -> the time frames are stamped with and /clock carries (module docstring)."""
        if self.cfg["stamps"] == "recorded":
            return lambda bag_ns: int(bag_ns)
        run0 = self._run_clock_ns()
        return lambda bag_ns: run0 + int(round((int(bag_ns) - t0) / rate))

    def play(self) -> None:
        """Replay (forever with loop); returns when done or when ROS shuts down."""
        try:
            if self.raw_pubs is not None:
                self._timed_replay(list(zip(self.stamps, self.raw_msgs)), self._publish_raw)
            else:
                recorded = [header_stamp_ns(raw) for _topic, raw in self.msgs]
                self._timed_replay(list(zip(self.stamps, zip(self.msgs, recorded))), self._publish_frame)
        except Exception:
            # Ctrl-C shuts ROS down from the signal handler, at any moment: between the replay's
            # rclpy.ok() check and a publish, the publish raises "publisher's context is
            # invalid" (seen once in a fresh clone's test run: exit code 1 for a clean stop)
            if rclpy.ok():
                raise
            self.get_logger().info(f"stopped: published {self.published} messages")

    def _publish_frame(self, item, bag_ns: int, shift: int, stamp_of) -> None:
        """One tracker frame. publish: the bag time of this frame on the run's clock (its capture,
        as a live tracker stamps it); recorded: the bag's header stamp, moved on by the loops."""
        (topic, raw), rec_ns = item
        self.pubs[topic].publish(with_header_stamp(raw, stamp_of(bag_ns) if self.cfg["stamps"] == "publish"
                                                   else rec_ns + shift))
        self.published_by_topic[topic] += 1

    def _publish_raw(self, item, bag_ns: int, shift: int, stamp_of) -> None:
        """One message of a recording's topics, raw CDR bytes on its topic's publisher."""
        topic, raw = item
        if topic in self.header_first and (shift or self.cfg["stamps"] == "publish"):
            # every header stamp moves with the same map as the bag time, so the recorded
            # stamps keep their relations (an output still pairs with its tracker frame)
            raw = with_header_stamp(raw, stamp_of(header_stamp_ns(raw) + shift))
        self.raw_pubs[topic].publish(raw)
        self.published_by_topic[topic] += 1

    def _timed_replay(self, items: list, publish) -> None:
        """Publish each (bag stamp [ns], item) at its bag time / rate with publish(item, bag_ns,
        shift, stamp_of), /clock ticking in the gaps on the same wall mapping; loops with `loop`."""
        rate = float(self.cfg["rate"])
        tick_ns = int(1e9 / self.cfg["clock_rate"]) if self.cfg["clock_rate"] > 0 else 0
        t0 = int(self.stamps[0])
        wall0 = time.monotonic()
        stamp_of = self._stamp_map(t0, rate)
        # the moment the first frame goes out (the waits for subscribers are over): what a user
        # lines a run's other logs up with, and what the across-hosts test times its outage from
        self.get_logger().info(f"{REPLAY_STARTED}: the first frame goes out now")
        loop = 0
        next_log = wall0 + 10.0
        while True:
            shift = loop * self.loop_shift_ns
            last_clock = None
            for stamp, item in items:
                bag_ns = int(stamp) + shift
                if tick_ns and self.clock_pub is not None and last_clock is not None:
                    t = last_clock + tick_ns
                    while t < bag_ns:
                        if not self._sleep_until(wall0 + (t - t0) * 1e-9 / rate):
                            return
                        self._publish_clock(stamp_of(t))
                        t += tick_ns
                if not self._sleep_until(wall0 + (bag_ns - t0) * 1e-9 / rate):
                    return
                if last_clock != bag_ns:  # messages of one bag time share one /clock tick
                    self._publish_clock(stamp_of(bag_ns))
                last_clock = bag_ns
                publish(item, bag_ns, shift, stamp_of)
                self.published += 1
                if time.monotonic() > next_log:
                    next_log = time.monotonic() + 10.0
                    self.get_logger().info(f"published {self.published} messages, bag time "
                                           f"{(bag_ns - t0) * 1e-9:.1f} s")
            if not self.cfg["loop"] and loop + 1 >= self.cfg["repeat"]:
                # let reliable subscribers acknowledge the tail before the publishers go away: a
                # reliable reader delivers in order, so one lost frame not yet resent holds back
                # every later one, and dies with this process. The writer resends at its next
                # heartbeat (Fast DDS: every few seconds), so with packet loss this takes seconds:
                # 2 s lost the last 36 of 671 frames to a recorder across a link with 2 % loss.
                for topic, pub in self._pubs_by_topic().items():
                    if not pub.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S)):
                        self.get_logger().warn(f"{topic}: not every reliable subscriber acknowledged the last "
                                               f"frames within {ACK_TIMEOUT_S:.0f} s; they may have missed them")
                # and give best-effort subscribers (tracking_node's tracker subscription) a moment:
                # they acknowledge nothing, and a sample on its way to one is lost when this process
                # tears its participant down (measured: the last of 200 frames missing in 3 of 20
                # runs of test_waits_for_the_named_nodes; none in 20 with this linger)
                self._sleep_until(time.monotonic() + END_LINGER_S)
                per_topic = ", ".join(f"{n} on {t}" for t, n in sorted(self.published_by_topic.items()))
                self.get_logger().info(f"done: published {self.published} messages ({per_topic})")
                return
            loop += 1
            self.get_logger().info(f"loop {loop}: restarting the bag")


def main(args=None) -> None:
    ns, argv = split_cli(build_parser(), args)
    overrides = {k: getattr(ns, k) for k in ("bag", "rate", "loop", "repeat", "start", "topic", "hand", "publish_clock",
                                             "clock_rate", "wait_subscribers", "wait_for_nodes", "stamps",
                                             "replay_topics", "replay_all")}
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
