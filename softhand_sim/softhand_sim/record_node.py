"""record_node: records softhand topics into a rosbag2 directory with mcap storage.

    softhand-record [-o OUTPUT] [--topics T [T ...]] [--skin-vertices]
    ros2 run softhand_sim record_node --ros-args -p output:=run1 -p topics:="['/hand/right/bones']"

What it writes: one mcap file plus metadata.yaml (rosbags Writer, mcap storage, laid out like
rosbag2 Jazzy's: softhand_sim.ros.bagio.JazzyWriter). Every channel carries its message
definition as a ros2msg schema and, in its metadata, `topic_type_hash` (RIHS01) and
`offered_qos_profiles`; metadata.yaml has the same per topic and `ros_distro: jazzy`. So `ros2
bag info`, `ros2 bag play`, Foxglove and the mcap/mcap_ros2 readers open and decode it, and a
replay offers each topic with the recorded QoS (/hand/{side}/skin_mesh stays transient local
for a late-joining viewer).

Offered QoS: like `ros2 bag record`, the QoS profiles of the topic's publishers as discovery
reports them (get_publishers_info_by_topic: reliability, durability, deadline, lifespan,
liveliness; history "unknown" and depth 0, which DDS does not announce). They are read when the
topic's first message arrives -- the channel is added to the bag then -- because the INTERFACE.md
topics are subscribed at start, often before any publisher exists. A topic whose publishers
cannot be seen then (or that had no message at all: its channel is added on close) gets the
contract QoS of INTERFACE.md (softhand_sim.ros.common: LATCHED_QOS for the LATCHED_TOPICS,
/hand/{side}/skin_mesh and /tf_static, else PUB_QOS); the log says which was used.

Two hands (softhand_sim.topics): the default list holds both sides' topics; the side a system does
not run simply has no messages (its channel is listed with 0 messages, like rosbag2's).

How it subscribes: the topics of docs/INTERFACE.md are subscribed at start with their contract QoS
(reliable; /hand/{side}/skin_mesh transient local, so the mesh published once is received even
when the recorder starts later), but the tracker topics (topics.TRACKER_TOPICS:
/tracker/{side}/hand_joints and the legacy /tracker/hand_joints), whose QoS is the tracker's
choice: each is subscribed when its first publisher is seen, with that publisher's QoS (reliable
for softhand-play, so no frame is dropped; `softhand-play --wait-for-nodes record_node` starts
the replay only once the recorder has subscribed). Any
other topic is subscribed, like `ros2 bag record` does, when its first publisher is discovered
(checked every `discovery_period` s), with the publishers' QoS: reliable unless one of them is
best effort, transient local when all are. Messages are taken raw (CDR bytes, never
deserialized) and written with the receive time (node clock: sim time under use_sim_time) or,
with stamp_source=header, the header stamp of messages that have one.

Live lag: with `live_lag` on (the default), the recorder, which hears every hand's tracker frames,
intermediate bones and simulated bones, keeps the last 2 s of each and reports in /diagnostics
(status `record_node: recording`, at `diagnostics_rate`) how far each layer trails the tracked hand,
as `softhand lag` measures a finished recording (softhand_sim/live_lag.py): `{side}_sim_lag_ms`,
`{side}_sim_lag_palm_ms`, `{side}_intermediate_lag_ms` (NaN while the hand hardly moves), beside the
messages and bytes written. One hand is measured per report, the hands taking turns (with two,
each hand's figures are refreshed every second report and repeated in between). It records its
own /diagnostics, so the lags are in the bag (the Foxglove layout plots them).

Writing: a callback only takes the message with its receive time; a writer thread writes them into
the bag every WRITE_PERIOD (10 ms), so writing a chunk never holds back the callbacks (nor the
receive times they stamp).

Stopping: SIGINT or SIGTERM ends spin; close() writes the messages still taken, the pending chunk,
the summary and metadata.yaml, so every message that reached a callback is in the bag.
SIGKILL cannot be caught: the mcap then has no summary and no metadata.yaml, but every chunk
written before the kill is intact. The pending chunk is written every `flush_period` s (default
1 s), so a SIGKILL loses at most about that much. Recover with
`python -m softhand_sim.ros.bagio recover BROKEN.mcap NEW_BAG` (softhand_sim.ros.bagio.recover_mcap,
it streams the intact chunks into a new bag) or `ros2 bag reindex` where ROS is installed.
"""
from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from collections import deque

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from softhand_sim.ros.common import LATCHED_QOS, PUB_QOS, DiagnosticsPublisher, message_class, run_node, split_cli
from softhand_sim.ros.msgs import diagnostic_name, pose_array_from_cdr
from softhand_sim.topics import (HEAVY_TOPICS, LATCHED_TOPICS, POSE_ARRAY, SIDES, TOPIC_TYPES, TRACKER_TOPICS,
                                 hand_topic, tracker_topic)
from softhand_sim.params import ParamError
from softhand_sim.ros.params import declare_node_params
from softhand_sim.ros.bagio import (BagError, add_topic, flush_chunk, header_stamp_ns, known_type, open_writer,
                                    qos_from_profile, type_hash)

__all__ = ["RecordNode", "header_stamp_ns", "main"]  # header_stamp_ns: kept importable from here

#: Default topic list: every softhand topic of docs/INTERFACE.md, both sides, but the heavy
#: /hand/{side}/skin_vertices (HEAVY_TOPICS); /tf and /tf_static included (skipped with one
#: warning where tf2_msgs is not built).
DEFAULT_TOPICS = [t for t in TOPIC_TYPES if t not in HEAVY_TOPICS]

#: Contract topics whose publishers choose the QoS (a tracker may be reliable or sensor-data best
#: effort): subscribed when the first publisher is seen, with its QoS, like `ros2 bag record`. A
#: best-effort reader at start would match either, but under load it drops frames a reliable
#: tracker resent (measured: 664 of 666 recorded while tracking_node received all 666).
ADAPTIVE_TOPICS = TRACKER_TOPICS

WRITE_PERIOD = 0.01  # [s] the writer thread writes the messages taken this often


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="softhand-record",
        description="Record softhand topics into a rosbag2 directory (mcap storage, schemas included) "
                    "that ros2 bag info/play and Foxglove open. Stop with Ctrl-C or SIGTERM.",
        epilog="ROS parameters: output, topics, record_skin_vertices, progress_period, flush_period, "
               "discovery_period, stamp_source (--ros-args -p NAME:=VALUE); flags override them.")
    p.add_argument("-o", "--output", default=None, help="rosbag2 directory to create (must not exist)")
    p.add_argument("--topics", nargs="+", default=None, metavar="TOPIC",
                   help="topics to record (default: every softhand topic of both hands but /hand/{side}/skin_vertices)")
    p.add_argument("--skin-vertices", dest="record_skin_vertices", action="store_true", default=None,
                   help="also record /hand/right/skin_vertices and /hand/left/skin_vertices")
    p.add_argument("--stamp-source", dest="stamp_source", choices=("receive", "header"), default=None,
                   help="bag timestamp of each message (default: receive time)")
    return p


def record_qos(best_effort: bool, latched: bool) -> QoSProfile:
    """Subscription QoS of a recorded topic.

    Reliable topics keep ALL samples: a KEEP_LAST reader overwrites samples it has acknowledged but
    not yet handed to the callback, so a burst faster than the writer loses messages (measured:
    1758 of 3000 kept with depth 1000); with KEEP_ALL, reliable flow control makes the publisher
    wait instead. Best-effort topics cannot be throttled: a deep KEEP_LAST. Latched: the last one.
    """
    if latched:
        history, depth = HistoryPolicy.KEEP_LAST, 1
    elif best_effort:
        history, depth = HistoryPolicy.KEEP_LAST, 1000
    else:
        history, depth = HistoryPolicy.KEEP_ALL, 1000
    return QoSProfile(history=history, depth=depth,
                      reliability=ReliabilityPolicy.BEST_EFFORT if best_effort else ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


def _qos_words(q) -> str:
    """'reliable, transient_local' for a rosbags Qos (log text)."""
    return f"{q.reliability.name.lower()}, {q.durability.name.lower()}"


class RecordNode(Node):
    """Subscriptions appear with their publishers; each raw message goes straight into the writer."""

    def __init__(self, overrides: dict | None = None):
        super().__init__("record_node")
        cfg = declare_node_params(self, "record_node", flags=overrides)  # schema: softhand_sim/params.py
        if cfg["stamp_source"] not in ("receive", "header"):
            raise BagError(f"stamp_source must be 'receive' or 'header', got {cfg['stamp_source']!r}")
        topics = [t for t in cfg["topics"] if t] or list(DEFAULT_TOPICS)
        if cfg["record_skin_vertices"]:
            topics += sorted(HEAVY_TOPICS)  # both sides; duplicates dropped below
        self.wanted = list(dict.fromkeys(topics))
        output = cfg["output"] or os.path.join("runs", time.strftime("%Y%m%d-%H%M%S"), "bag")
        self.writer = open_writer(output, "mcap")
        self.output = output
        self.cfg = cfg
        self.subs, self.conns, self.counts = {}, {}, {}
        self.msgtypes, self.offers_seen = {}, {}
        self.bytes = 0
        self.header_types = set()
        self._closed = False
        self.create_timer(cfg["discovery_period"], self._discover)
        # The callbacks only take each message (with its receive time) into _pending; a thread of
        # its own writes them into the bag, under the writer's lock, and the pending chunk to disk
        # every flush_period. Written in the callbacks, a message that closed a 1 MiB chunk (the
        # skin marker's) held the executor 10-36 ms, and the flush as long: every message behind
        # it was stamped that late (22 callbacks over 3 ms in a 6 s demo), which the demo's latency
        # figures, taken from these receive times, showed as latency. (A flush timer in the
        # executor missed its turn after a burst of messages: 1 in 5 runs of the SIGKILL test lost
        # the last chunk; none with the thread.)
        self._writer_lock = threading.Lock()
        self._pending = deque()  # (connection, stamp [ns], CDR bytes), oldest first
        self._writer_stop = threading.Event()
        self._writer_thread = threading.Thread(target=self._write_loop, args=(cfg["flush_period"],),
                                               name="writer", daemon=True)
        self._writer_thread.start()
        self.create_timer(cfg["progress_period"], self._progress)
        # side -> LiveLag (live_lag.py), made here: made at a side's first message, its ~0.9 s of
        # imports and set-up blocked the callbacks, and a writer keeping the last 10 samples (/tf
        # at 60 Hz) overwrote some the recorder had not yet taken
        self.live_lag = None  # live_lag.HandLags: a LiveLag per hand, reported in turn
        self.lag_feeds = {}  # topic -> (side, layer) for the topics the live lag reads
        self.lag_values = {}  # side -> the last report, made in a thread of its own (_lag_reports)
        if cfg["live_lag"]:
            from softhand_sim.live_lag import HandLags
            self.live_lag = HandLags(SIDES)
            for side in SIDES:
                self.lag_feeds.update({tracker_topic(side): (side, "tracked"),
                                       hand_topic(side, "intermediate_bones"): (side, "intermediate"),
                                       hand_topic(side, "bones"): (side, "sim")})
            # a report takes ~50 ms: in the executor's thread it held back the recording's callbacks
            # that long every second, so it runs in a daemon thread of its own
            self._lag_stop = threading.Event()
            threading.Thread(target=self._lag_reports, args=(1.0 / cfg["diagnostics_rate"],), name="live-lag",
                             daemon=True).start()
        DiagnosticsPublisher(self, self.collect_diagnostics, period=1.0 / cfg["diagnostics_rate"],
                             name=diagnostic_name(self.get_name(), "recording"))
        self.get_logger().info(f"recording into {output}: {', '.join(self.wanted)}")
        self._discover()

    # --------------------------------------------------------------------------- subscriptions

    def _qos_for(self, topic: str) -> QoSProfile:
        """Adapt to the publishers like rosbag2: best effort if any is, transient local if all are."""
        infos = self.get_publishers_info_by_topic(topic)
        self.offers_seen[topic] = [i.qos_profile for i in infos]
        best_effort = any(i.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for i in infos)
        latched = bool(infos) and all(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in infos)
        return record_qos(best_effort, latched)

    def _known_qos(self, topic: str) -> QoSProfile:
        """QoS for a docs/INTERFACE.md topic, subscribed before any publisher is seen."""
        return record_qos(False, topic in LATCHED_TOPICS)

    def _discover(self) -> None:
        graph = None
        for topic in self.wanted:
            if topic in self.subs:
                continue
            if topic in ADAPTIVE_TOPICS:  # known type, QoS of its publishers: wait for one
                if self.count_publishers(topic):  # every tracker topic, the legacy one too, is a PoseArray
                    self._subscribe(topic, TOPIC_TYPES.get(topic, POSE_ARRAY), self._qos_for(topic))
                continue
            if topic in TOPIC_TYPES:  # known type: subscribe now, miss nothing at start
                self._subscribe(topic, TOPIC_TYPES[topic], self._known_qos(topic))
                continue
            if graph is None:
                graph = dict(self.get_topic_names_and_types())
            if topic not in graph or not self.count_publishers(topic):
                continue
            types = graph[topic]
            if len(types) > 1:
                self.get_logger().warn(f"{topic} has several types {types}; recording {types[0]}")
            self._subscribe(topic, types[0], self._qos_for(topic))
        # A topic's channel goes into the bag as soon as a publisher of it is seen, here, rather
        # than at its first message: adding one takes two graph queries and a log line, 2-8 ms,
        # and the ~17 channels added at a run's first messages held every callback back 50-90 ms,
        # which came out as that much latency in the demo's figures (taken from this node's
        # receive times). A topic whose publisher comes too late for this gets its channel at its
        # first message, as before.
        for topic, conn in self.conns.items():
            if conn is None and self.count_publishers(topic):
                with self._writer_lock:
                    if self.conns[topic] is None and not self._closed:
                        self._open_connection(topic)

    def _subscribe(self, topic: str, msgtype: str, qos: QoSProfile) -> None:
        if not known_type(msgtype):
            self.get_logger().error(f"cannot record {topic}: type {msgtype} has no schema in the typestore")
            self.subs[topic] = None
            return
        try:
            cls = message_class(msgtype)
        except ValueError as exc:  # e.g. /tf without tf2_msgs built into the venv (ros/tf.py)
            self.get_logger().warning(f"not recording {topic}: {exc}")
            self.subs[topic] = None
            return
        if cls.get_fields_and_field_types().get("header") == "std_msgs/Header":
            self.header_types.add(topic)
        self.msgtypes[topic] = msgtype
        self.conns[topic] = None  # added once its publishers are seen (_discover) or with its first message
        self.counts[topic] = 0
        self.subs[topic] = self.create_subscription(cls, topic, self._make_callback(topic), qos, raw=True)
        self.get_logger().info(
            f"subscribed {topic} [{msgtype}] "
            f"({'best effort' if qos.reliability == ReliabilityPolicy.BEST_EFFORT else 'reliable'}"
            f"{', transient local' if qos.durability == DurabilityPolicy.TRANSIENT_LOCAL else ''})")

    def _offered_qos(self, topic: str) -> tuple[list, str]:
        """The topic's offered QoS (rosbags Qos list) and where it came from (for the log)."""
        profiles = []
        try:
            profiles = [i.qos_profile for i in self.get_publishers_info_by_topic(topic)]
        except Exception:  # noqa: BLE001 -- the context may be shutting down (close after a signal)
            pass
        if profiles:
            return [qos_from_profile(p) for p in profiles], f"offered by {len(profiles)} publisher(s)"
        if self.offers_seen.get(topic):
            return [qos_from_profile(p) for p in self.offers_seen[topic]], "offered at subscription"
        contract = LATCHED_QOS if topic in LATCHED_TOPICS else PUB_QOS
        return [qos_from_profile(contract)], "contract QoS, no publisher seen"

    def _open_connection(self, topic: str):
        """Add the topic's channel to the bag, with its offered QoS and the type's RIHS01 hash."""
        msgtype = self.msgtypes[topic]
        offers, source = self._offered_qos(topic)
        self.conns[topic] = add_topic(self.writer, topic, msgtype, offers)
        self._check_type_hash(topic, msgtype)
        self.get_logger().info(
            f"{topic}: offered QoS {', '.join(sorted({_qos_words(q) for q in offers}))} ({source})")
        return self.conns[topic]

    def _check_type_hash(self, topic: str, msgtype: str) -> None:
        """Warn when a publisher's type hash differs from the Jazzy one written in the bag."""
        try:
            hashes = {str(i.topic_type_hash) for i in self.get_publishers_info_by_topic(topic)}
        except Exception:  # noqa: BLE001 -- as in _offered_qos
            return
        other = sorted(h for h in hashes if h.startswith("RIHS01_") and h != type_hash(msgtype))
        if other:
            self.get_logger().warn(f"{topic}: publisher type hash {', '.join(other)} differs from the Jazzy "
                                   f"{msgtype} ({type_hash(msgtype)}) written in the bag")

    def _make_callback(self, topic: str):
        use_header = self.cfg["stamp_source"] == "header" and topic in self.header_types

        def on_message(raw: bytes) -> None:
            if self._closed:
                return
            stamp = header_stamp_ns(raw) if use_header else None
            if stamp is None:
                stamp = self.get_clock().now().nanoseconds
            conn = self.conns[topic]
            if conn is None:  # a topic whose publisher _discover has not seen yet
                with self._writer_lock:
                    conn = self.conns[topic] or self._open_connection(topic)
            self._pending.append((conn, stamp, raw))
            self.counts[topic] += 1
            self.bytes += len(raw)
            if feed is not None:
                self._feed_lag(feed, raw)

        feed = self.lag_feeds.get(topic)
        return on_message

    def _feed_lag(self, feed, raw: bytes) -> None:
        """A tracker frame or a layer's bones into that hand's LiveLag (by header stamp)."""
        side, layer = feed
        stamp_ns = header_stamp_ns(raw)  # a thinned layer's sample is skipped before it is parsed
        if stamp_ns is not None and not self.live_lag[side].wants(layer, stamp_ns * 1e-9):
            return
        try:
            poses, stamp_ns, _frame = pose_array_from_cdr(raw)
        except ValueError:
            return  # not ours to judge: recorded as it came
        self.live_lag.heard_from(side)
        try:
            if layer == "tracked":
                self.live_lag[side].add_frame(stamp_ns * 1e-9, poses)
            elif poses.shape == (16, 7):
                self.live_lag[side].add(layer, stamp_ns * 1e-9, poses)
        except (ValueError, IndexError):
            pass  # a malformed frame: the tracking node rejects and counts it; the recorder only records

    def _write_loop(self, period: float) -> None:
        """Write what the callbacks took every WRITE_PERIOD s, the pending chunk to disk every
        `period` s; once stopped, write what is left and end."""
        next_flush = time.monotonic() + period
        while True:
            stopping = self._writer_stop.wait(WRITE_PERIOD)
            with self._writer_lock:
                if self._closed:
                    return
                self._write_pending()
                if time.monotonic() >= next_flush:
                    flush_chunk(self.writer)
                    next_flush = time.monotonic() + period
            if stopping:
                return

    def _write_pending(self) -> None:
        """Write the messages taken so far (the writer's lock held)."""
        pending = self._pending
        while pending:
            self.writer.write(*pending.popleft())

    def _lag_reports(self, period: float) -> None:
        """One hand's live lag per period, the hands heard from taking turns (live_lag.HandLags)."""
        while not self._lag_stop.wait(period):
            turn = self.live_lag.report_next()
            if turn is not None:
                side, report = turn
                self.lag_values[side] = report

    def collect_diagnostics(self):
        """What is recorded, and each hand's live lag ({side}_sim_lag_ms, ...; module doc)."""
        values = {"messages": sum(self.counts.values()), "megabytes": round(self.bytes / 1e6, 2),
                  "topics": len(self.conns)}
        for side, report in sorted(self.lag_values.items()):
            values.update({f"{side}_{key}": value for key, value in report.items()})
        return values, "ok", f"recording into {self.output}"

    # --------------------------------------------------------------------------------- logging

    def _progress(self) -> None:
        total = sum(self.counts.values())
        self.get_logger().info(f"{total} messages, {self.bytes / 1e6:.1f} MB on {len(self.conns)} topics")

    def close(self) -> None:
        """Finish the bag (pending chunk, summary, metadata.yaml); safe to call twice."""
        if self._closed:
            return
        if self.live_lag is not None:
            self._lag_stop.set()
        self._writer_stop.set()
        self._writer_thread.join(timeout=10.0)
        with self._writer_lock:
            self._write_pending()  # (the thread wrote them all, unless it was stuck)
            for topic, conn in self.conns.items():
                if conn is None:  # subscribed, never received: listed with 0 messages, like rosbag2
                    self._open_connection(topic)
            self._closed = True
            self.writer.close()
        counts = ", ".join(f"{t}: {n}" for t, n in self.counts.items()) or "nothing"
        print(f"[record_node] wrote {self.output} ({sum(self.counts.values())} messages, "
              f"{self.bytes / 1e6:.1f} MB; {counts})", file=sys.stderr, flush=True)


def main(args=None) -> None:
    ns, argv = split_cli(build_parser(), args)
    overrides = {"output": ns.output, "topics": ns.topics, "record_skin_vertices": ns.record_skin_vertices,
                 "stamp_source": ns.stamp_source}
    try:
        code = run_node(lambda: RecordNode(overrides), init_args=argv, drain_s=2.0)
    except (BagError, ParamError) as exc:
        print(f"softhand-record: error: {exc}", file=sys.stderr, flush=True)
        code = 1
    sys.exit(code)


if __name__ == "__main__":
    main()
