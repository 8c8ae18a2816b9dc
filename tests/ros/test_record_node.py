"""record_node: exact message counts after SIGINT/SIGTERM (also right after a fast burst), schemas
that decode, offered QoS / type hash / distro written like rosbag2 Jazzy, every bag well formed by
the mcap library's reading, and SIGKILL recovery."""
import signal
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray
from mcap.reader import make_reader
from mcap.records import Footer
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory
from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import Reader
from ruamel.yaml import YAML
from sensor_msgs.msg import PointCloud2
from shape_msgs.msg import Mesh
from std_msgs.msg import String
from trajectory_msgs.msg import MultiDOFJointTrajectory

from tests.support.rosproc import RosGraph, node_diagnostics
from softhand_sim.ros import msgs as rm
from softhand_sim.record_node import ADAPTIVE_TOPICS, DEFAULT_TOPICS, header_stamp_ns
from softhand_sim.topics import LEGACY_TRACKER, TOPIC_TYPES
from softhand_sim.ros.bagio import MCAP_MAGIC, BagError, deserialize, read_recording, read_topic, recover_mcap

pytestmark = pytest.mark.ros

# the test publishers keep every sample until acknowledged, so a slow recorder cannot lose one
DEEP = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                  durability=DurabilityPolicy.VOLATILE)
LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def assert_well_formed_mcap(bag_dir) -> dict:
    """The bag's one .mcap file passes the mcap library's checks; returns {topic: message count}.

    (The `mcap doctor` CLI is not on PyPI.) Checked: start and end magic; a full streaming pass
    with chunk and data CRCs validated ends at the Footer; the summary (via the seeking reader)
    has statistics whose message counts, per channel and in all, equal what iter_messages yields;
    every channel has a known schema and rosbag2's two channel metadata keys.
    """
    files = list(Path(bag_dir).glob("*.mcap"))
    assert len(files) == 1, files
    data = files[0].read_bytes()
    assert data[:8] == MCAP_MAGIC and data[-8:] == MCAP_MAGIC, "start/end magic"
    with open(files[0], "rb") as f:
        records = list(StreamReader(f, skip_magic=False, validate_crcs=True).records)
    assert isinstance(records[-1], Footer)
    with open(files[0], "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        per_channel = Counter(channel.id for _s, channel, _m in reader.iter_messages())
    stats = summary.statistics
    assert sum(per_channel.values()) == stats.message_count
    assert {k: v for k, v in stats.channel_message_counts.items() if v} == dict(per_channel)
    assert stats.channel_count == len(summary.channels)
    for ch in summary.channels.values():
        assert ch.schema_id in summary.schemas and ch.message_encoding == "cdr"
        assert {"offered_qos_profiles", "topic_type_hash"} <= set(ch.metadata), ch.metadata
    return {ch.topic: stats.channel_message_counts.get(ch.id, 0) for ch in summary.channels.values()}


def test_header_stamp_read_from_raw_cdr():
    """The header stamp parsed from raw CDR bytes equals the one serialized."""
    msg = rm.pose_array_from_numpy(np.tile([0, 0, 0, 0, 0, 0, 1.0], (2, 1)), 1_234_567_890_123)
    assert header_stamp_ns(serialize_message(msg)) == 1_234_567_890_123


def test_default_topics_are_both_hands_but_the_skin_clouds():
    """By default every contract topic of both sides is recorded but the two skin_vertices clouds;
    the tracker topics of both sides and the legacy single-hand one take the publisher's QoS."""
    assert set(DEFAULT_TOPICS) == set(TOPIC_TYPES) - {"/hand/right/skin_vertices", "/hand/left/skin_vertices"}
    assert {"/hand/right/bones", "/hand/left/bones", "/hand/left/skin_mesh", "/tf"} <= set(DEFAULT_TOPICS)
    assert ADAPTIVE_TOPICS == {"/tracker/right/hand_joints", "/tracker/left/hand_joints", LEGACY_TRACKER}


def _messages(i):
    """One message per recorded topic for sequence number i (i is in each payload)."""
    rng = np.random.default_rng(i)
    poses = np.tile([0, 0, 0, 0, 0, 0, 1.0], (16, 1))
    poses[0, 0] = i
    stamp = 10**9 + i * 10**7
    objs = rm.object_states_from_numpy(["ball"], np.array([[i, 0, 0, 0, 0, 0, 1.0]]), np.zeros((1, 6)),
                                       np.zeros((1, 6)), stamp)
    contacts = rm.contacts_cloud_from_numpy(rng.normal(size=(3, 3)), rng.normal(size=(3, 3)),
                                            rng.normal(size=(3, 3)), [i, i, i], [0, 1, 0], stamp)
    diag = rm.diagnostic_array([rm.diagnostic_status("test", {"i": i})], stamp)
    return {"/hand/right/bones": rm.pose_array_from_numpy(poses, stamp), "/hand/object_states": objs,
            "/hand/contacts": contacts, "/diagnostics": diag}


TYPES = {"/hand/right/bones": PoseArray, "/hand/object_states": MultiDOFJointTrajectory,
         "/hand/contacts": PointCloud2, "/diagnostics": DiagnosticArray}


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_record_exact_counts_and_schemas(ros_env, tmp_path, sig):
    """N messages on 4 topics + a transient-local mesh published before the recorder started: after the
    signal the bag has exactly N of each and 1 mesh, opens with rosbags and with the mcap reader, and every
    message decodes against the schema stored in the file."""
    n = 40
    out = tmp_path / "rec"
    with RosGraph(ros_env) as g:
        mesh_pub = g.publisher("/hand/right/skin_mesh", Mesh, LATCHED)
        mesh_pub.publish(rm.mesh_from_numpy(np.eye(3), [[0, 1, 2]]))
        pubs = {t: g.publisher(t, cls, DEEP) for t, cls in TYPES.items()}
        proc = g.start(["softhand-record", "-o", str(out), "--topics", *TYPES, "/hand/right/skin_mesh"])
        for pub in pubs.values():
            g.wait_matched(pub, proc=proc)
        g.wait_matched(mesh_pub, proc=proc)
        for i in range(n):
            for topic, msg in _messages(i).items():
                pubs[topic].publish(msg)
        for pub in pubs.values():
            assert pub.wait_for_all_acked(Duration(seconds=10))
        assert proc.stop(sig) == 0, proc.output()
    log = proc.output()
    assert "Traceback" not in log
    # rosbags: counts and content order
    with Reader(out) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    # /diagnostics also holds the recorder's own reports ("record_node: recording", at 1 Hz)
    diags = [deserialize(raw, "diagnostic_msgs/msg/DiagnosticArray").status[0].name
             for raw in read_topic(out, "/diagnostics", "diagnostic_msgs/msg/DiagnosticArray").payloads]
    assert diags.count("test") == n and set(diags) <= {"test", "record_node: recording"}, set(diags)
    assert {**counts, "/diagnostics": diags.count("test")} == {**{t: n for t in TYPES}, "/hand/right/skin_mesh": 1}
    assert assert_well_formed_mcap(out) == counts
    bones = read_topic(out, "/hand/right/bones", "geometry_msgs/msg/PoseArray")
    xs = [rm.pose_array_to_numpy(deserialize(raw, bones.msgtype))[0, 0] for raw in bones.payloads]
    assert sorted(xs) == list(range(n))
    # mcap reader + mcap_ros2 decoder: every channel has a ros2msg schema and every message decodes
    mcap_file = next(out.glob("*.mcap"))
    with open(mcap_file, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
        assert all(ch.schema_id in summary.schemas for ch in summary.channels.values())
        decoded = {}
        for schema, channel, _message, msg in reader.iter_decoded_messages():
            decoded.setdefault(channel.topic, []).append(msg)
    assert {t: len(v) for t, v in decoded.items()} == counts
    assert list(decoded["/hand/right/skin_mesh"][0].triangles[0].vertex_indices) == [0, 1, 2]
    assert sorted(m.points[0].transforms[0].translation.x for m in decoded["/hand/object_states"]) == list(range(n))


BEST_EFFORT = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.BEST_EFFORT,
                         durability=DurabilityPolicy.VOLATILE)
INFINITE = {"sec": 9223372036, "nsec": 854775807}  # RMW_DURATION_INFINITE as rosbag2 writes it


def test_offered_qos_type_hash_and_distro_like_rosbag2(ros_env, tmp_path):
    """metadata.yaml and the mcap channels hold what rosbag2 Jazzy writes: per topic the offered QoS of
    its publishers -- a latched mesh published before the recorder started, /hand/right/bones whose publisher
    appears after the recorder subscribed, a best-effort topic found by discovery -- or, for a topic
    without publishers, the INTERFACE.md contract QoS (listed with 0 messages); the type hash the
    publishers announce; ros_distro jazzy; and the same profiles in both places."""
    out = tmp_path / "rec"
    topics = ["/hand/right/skin_mesh", "/hand/right/bones", "/custom", "/world/object_states"]
    with RosGraph(ros_env) as g:
        mesh_pub = g.publisher("/hand/right/skin_mesh", Mesh, LATCHED)
        mesh_pub.publish(rm.mesh_from_numpy(np.eye(3), [[0, 1, 2]]))
        custom_pub = g.publisher("/custom", String, BEST_EFFORT)
        proc = g.start(["softhand-record", "-o", str(out), "--topics", *topics])
        g.wait_until(lambda: "subscribed /custom" in proc.output(), 30, "recorder subscription", proc)
        bones_pub = g.publisher("/hand/right/bones", PoseArray, DEEP)  # after the recorder subscribed
        for pub in (mesh_pub, custom_pub, bones_pub):
            g.wait_matched(pub, proc=proc)
        for i in range(5):
            bones_pub.publish(rm.pose_array_from_numpy(np.tile([0, 0, 0, 0, 0, 0, 1.0], (16, 1)), i))
            custom_pub.publish(String(data=str(i)))
        assert bones_pub.wait_for_all_acked(Duration(seconds=10))
        g.wait_until(lambda: proc.output().count("offered QoS") >= 3, 10, "three channels opened", proc)
        live_hash = {t: str(g.node.get_publishers_info_by_topic(t)[0].topic_type_hash)
                     for t in ("/hand/right/skin_mesh", "/hand/right/bones", "/custom")}
        assert proc.stop(signal.SIGINT) == 0, proc.output()
    assert "Traceback" not in proc.output()
    info = YAML(typ="safe").load((out / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["ros_distro"] == "jazzy" and info["version"] == 9
    meta = {t["topic_metadata"]["name"]: t for t in info["topics_with_message_count"]}
    assert sorted(meta) == sorted(topics)
    assert meta["/world/object_states"]["message_count"] == 0

    def policies(topic):
        return [(q["reliability"], q["durability"]) for q in meta[topic]["topic_metadata"]["offered_qos_profiles"]]

    assert policies("/hand/right/skin_mesh") == [("reliable", "transient_local")]
    assert policies("/hand/right/bones") == [("reliable", "volatile")]
    assert policies("/custom") == [("best_effort", "volatile")]
    assert policies("/world/object_states") == [("reliable", "volatile")]
    # discovered offers: what discovery announces (no history/depth), infinite durations as rmw's
    mesh_qos = meta["/hand/right/skin_mesh"]["topic_metadata"]["offered_qos_profiles"][0]
    assert mesh_qos == {"history": "unknown", "depth": 0, "reliability": "reliable", "durability": "transient_local",
                        "deadline": INFINITE, "lifespan": INFINITE, "liveliness": "automatic",
                        "liveliness_lease_duration": INFINITE, "avoid_ros_namespace_conventions": False}
    # the contract profile (common.PUB_QOS) for the topic nobody published
    contract = meta["/world/object_states"]["topic_metadata"]["offered_qos_profiles"][0]
    assert (contract["history"], contract["depth"]) == ("keep_last", 10)
    for topic, h in live_hash.items():
        assert h.startswith("RIHS01_") and meta[topic]["topic_metadata"]["type_description_hash"] == h
    assert meta["/world/object_states"]["topic_metadata"]["type_description_hash"].startswith("RIHS01_")
    # the mcap file: same profiles and hashes in the channel metadata, distro in its rosbag2 record
    counts = assert_well_formed_mcap(out)
    assert counts["/hand/right/skin_mesh"] == 1 and counts["/hand/right/bones"] == 5 and counts["/world/object_states"] == 0
    with open(next(out.glob("*.mcap")), "rb") as f:
        reader = make_reader(f)
        channels = reader.get_summary().channels.values()
        records = {m.name: m.metadata for m in reader.iter_metadata()}
    for ch in channels:
        tm = meta[ch.topic]["topic_metadata"]
        assert YAML(typ="safe").load(ch.metadata["offered_qos_profiles"]) == tm["offered_qos_profiles"]
        assert ch.metadata["topic_type_hash"] == tm["type_description_hash"]
    assert YAML(typ="safe").load(records["rosbag2"]["serialized_metadata"])["ros_distro"] == "jazzy"
    # rosbags reads the profiles back
    rec = read_recording(out)
    assert rec.topics["/hand/right/skin_mesh"].offered_qos[0].durability.name == "TRANSIENT_LOCAL"


def _recorded_count(diags) -> int:
    """The last `messages` count record_node reported on /diagnostics (0 before its first)."""
    counts = [int(v["messages"]) for v in node_diagnostics(diags.msgs, "record_node")]
    return counts[-1] if counts else 0


@pytest.mark.parametrize("flush_period", [0.3, 3600.0], ids=["periodic_flush", "no_flush"])
def test_sigkill_leaves_a_recoverable_bag(ros_env, tmp_path, flush_period):
    """After SIGKILL the bag has no metadata.yaml (rosbags refuses it); recover_mcap gets back exactly the
    messages of the chunks written before the kill, in order: all of them when the periodic flush ran after
    the last message, else all but the pending chunk (< 1 MiB of data: rosbags closes chunks at 1 MiB)."""
    n = 60
    out = tmp_path / "rec"
    cloud = rm.xyz_cloud_from_numpy(np.random.default_rng(0).normal(size=(4000, 3)), 0)  # 48 kB each
    with RosGraph(ros_env) as g:
        pub = g.publisher("/hand/right/skin_vertices", PointCloud2, DEEP)
        diags = g.listen("/diagnostics", DiagnosticArray)
        proc = g.start(["softhand-record", "-o", str(out), "--topics", "/hand/right/skin_vertices",
                        "--ros-args", "-p", f"flush_period:={flush_period}", "-p", "diagnostics_rate:=20.0"])
        g.wait_matched(pub, proc=proc)
        for i in range(n):
            cloud.header.stamp = rm.stamp_from_ns(i)
            pub.publish(cloud)
        assert pub.wait_for_all_acked(Duration(seconds=10))
        # acknowledged means received by the recorder's reader, not yet written by its callback:
        # wait for its own count of written messages (a fresh clone's run recovered 44 of 60)
        g.wait_until(lambda: _recorded_count(diags) >= n, 20, f"record_node to write {n} messages", proc)
        time.sleep(1.0)  # longer than the short flush_period: the recorder has written its pending chunk
        assert proc.stop(signal.SIGKILL) == -signal.SIGKILL
    assert not (out / "metadata.yaml").exists()
    with pytest.raises(BagError, match="no metadata.yaml") as err:
        read_topic(out, "/hand/right/skin_vertices", "sensor_msgs/msg/PointCloud2")
    assert f"python -m softhand_sim.ros.bagio recover {next(out.glob('*.mcap'))}" in str(err.value)
    recovered = recover_mcap(next(out.glob("*.mcap")), tmp_path / "fixed")
    per_chunk = 2**20 // len(serialize_message(cloud)) + 1
    if flush_period < 1.0:
        assert recovered == n
    else:
        assert recovered == (n // per_chunk) * per_chunk  # whole 1 MiB chunks only
    if recovered:
        assert assert_well_formed_mcap(tmp_path / "fixed") == {"/hand/right/skin_vertices": recovered}
        data = read_topic(tmp_path / "fixed", "/hand/right/skin_vertices", "sensor_msgs/msg/PointCloud2")
        assert [header_stamp_ns(p) for p in data.payloads] == list(range(recovered))


BURST = 3000
# The publisher keeps every sample until the recorder acknowledged it (its history is as deep as
# the burst), so "acknowledged" == "received by record_node's reader".
BURST_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=BURST, reliability=ReliabilityPolicy.RELIABLE,
                  durability=DurabilityPolicy.VOLATILE)


# Timing over real DDS between processes on a shared 2-core machine: one retry absorbs a stall.
@pytest.mark.flaky(reruns=1, reruns_delay=2)
@pytest.mark.parametrize("sig,topic", [(signal.SIGTERM, "/hand/right/bones"), (signal.SIGINT, "/tracker/left/hand_joints"),
                                       (signal.SIGINT, LEGACY_TRACKER)],
                         ids=["SIGTERM-bones", "SIGINT-tracker", "SIGINT-legacy-tracker"])
def test_burst_then_signal_loses_nothing(ros_env, tmp_path, sig, topic):
    """3,000 messages published as fast as possible (several thousand per second), the signal sent
    the moment the last is acknowledged: the bag holds exactly 3,000, each stamp once, in order.
    /tracker/left/hand_joints and the legacy /tracker/hand_joints too: the recorder takes its reliable
    publisher's QoS (a best-effort reader dropped frames under load)."""
    out = tmp_path / "rec"
    poses = np.tile([0, 0, 0, 0, 0, 0, 1.0], (16, 1))
    msgs = [rm.pose_array_from_numpy(poses, 10**9 + i) for i in range(BURST)]
    with RosGraph(ros_env) as g:
        pub = g.publisher(topic, PoseArray, BURST_QOS)
        proc = g.start(["softhand-record", "-o", str(out), "--topics", topic,
                        "--ros-args", "-p", "stamp_source:=header"])
        g.wait_until(lambda: f"subscribed {topic}" in proc.output(), 30, "recorder subscription", proc)
        g.wait_matched(pub, proc=proc)
        # exactly our recorder: another run on the same (random) ROS domain would take the samples
        assert pub.get_subscription_count() == 1, "another subscriber on this ROS domain: test void"
        t0 = time.monotonic()
        for m in msgs:
            pub.publish(m)
        sent_s = time.monotonic() - t0
        assert pub.wait_for_all_acked(Duration(seconds=30))
        acked_s = time.monotonic() - t0
        assert proc.stop(sig) == 0, proc.output()
    data = read_topic(out, topic, "geometry_msgs/msg/PoseArray")
    stamps = [header_stamp_ns(p) for p in data.payloads]
    print(f"{BURST} sent in {sent_s:.2f} s ({BURST / sent_s:.0f}/s), all acknowledged after {acked_s:.2f} s; "
          f"recorded {len(stamps)}")
    assert len(stamps) == BURST
    assert stamps == sorted(stamps) and len(set(stamps)) == BURST
    assert assert_well_formed_mcap(out) == {topic: BURST}
