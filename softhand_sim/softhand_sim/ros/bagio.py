"""rosbag2 read/write helpers (rosbags library; no rclpy).

Reading: `read_topic(path, topic, msgtype)` loads every message of one topic of a rosbag2
directory (mcap or sqlite3 storage, found from its metadata.yaml) as raw CDR bytes with their
bag timestamps, and turns every way a bag can be unusable into a `BagError` whose text names the
problem (missing path, not a bag, corrupt file, missing topic, wrong type, no messages).

`read_recording(path, topics)` loads every topic (or the named ones) with each topic's type,
recorded offered QoS and type hash: what a player needs to replay it like `ros2 bag play`.

Writing: `open_writer(path)` starts an mcap rosbag2 directory laid out like rosbag2 Jazzy's own
(`JazzyWriter`): channels carry their message definitions as ros2msg schemas (what `ros2 bag
info/play` and Foxglove need) and the channel metadata `offered_qos_profiles` (YAML, version 9
format) and `topic_type_hash` (RIHS01); metadata.yaml says `ros_distro: jazzy`. `add_topic` adds
a connection for a ROS type from the Jazzy typestore with the publishers' offered QoS;
`flush_chunk` closes the writer's pending mcap chunk so that a later SIGKILL loses at most what
came after it.

Recovery: an mcap file whose writer was killed has no summary, footer, end magic or
metadata.yaml; the chunks written before the kill are intact. `recover_mcap(src_mcap, dst_bag)`
streams those chunks with the `mcap` library (stopping at the torn tail) and writes a new,
finalized bag; `read_topic`/`read_recording` with allow_torn=True read them in place (with a
warning), and without it their error names the recover command.
"""
from __future__ import annotations

import struct
import sys
from dataclasses import dataclass, field
from io import BytesIO, StringIO
from pathlib import Path
from typing import Iterable

from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness, QosReliability,
                                QosTime)
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.rosbag2.metadata import parse_qos
from rosbags.rosbag2.storage_mcap import Channel, McapWriter, write_channel, write_string
from rosbags.typesys import Stores, get_typestore
from ruamel.yaml import YAML

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
#: What rosbag2 Jazzy writes as ros_distro (it takes $ROS_DISTRO; rosbags writes 'rosbags').
ROS_DISTRO = "jazzy"
#: An mcap file starts and (when its writer closed it) ends with these 8 bytes.
MCAP_MAGIC = b"\x89MCAP0\r\n"
#: rmw's RMW_DURATION_INFINITE [ns]: what discovery reports for an unset deadline/lifespan/lease.
DURATION_INFINITE_NS = 2**63 - 1


class BagError(RuntimeError):
    """A bag cannot be used; the text says which bag and why."""


@dataclass(frozen=True)
class TopicData:
    """The messages of one topic: bag timestamps [ns] (ascending) and raw CDR payloads.

    `warning` is set when the messages come from a torn recording (see read_topic's allow_torn).
    """
    path: Path
    topic: str
    msgtype: str
    storage: str
    stamps_ns: list
    payloads: list
    warning: str | None = None

    @property
    def duration_s(self) -> float:
        return (self.stamps_ns[-1] - self.stamps_ns[0]) * 1e-9 if self.stamps_ns else 0.0


@dataclass(frozen=True)
class RecordedTopic:
    """One topic of a recording: ROS type, the QoS its publishers offered (rosbags Qos list, may
    be empty for bags that did not record it) and the type's RIHS01 hash."""
    topic: str
    msgtype: str
    offered_qos: list
    type_hash: str


@dataclass(frozen=True)
class Recording:
    """Several topics of a bag: `messages` is a list of (stamp_ns, topic, raw CDR) by stamp."""
    path: Path
    storage: str
    topics: dict
    messages: list = field(default_factory=list)
    warning: str | None = None

    @property
    def duration_s(self) -> float:
        return (self.messages[-1][0] - self.messages[0][0]) * 1e-9 if self.messages else 0.0


# ------------------------------------------------------------------------------------- reading


def _storage_of(path: Path) -> str:
    meta = path / "metadata.yaml"
    try:
        text = meta.read_text()
    except OSError:
        return "?"
    for line in text.splitlines():
        if "storage_identifier" in line:
            return line.split(":", 1)[1].strip()
    return "?"


def mcap_is_closed(mcap_path) -> bool:
    """Whether an mcap file ends with the magic bytes its writer writes last (False: torn)."""
    with open(mcap_path, "rb") as f:
        f.seek(0, 2)
        if f.tell() < 2 * len(MCAP_MAGIC):
            return False
        f.seek(-len(MCAP_MAGIC), 2)
        return f.read() == MCAP_MAGIC


def _torn_mcap(p: Path) -> Path | None:
    """The .mcap file of a bag directory whose writer died (no metadata.yaml, or no end magic)."""
    files = sorted(p.glob("*.mcap"))
    if len(files) != 1:
        return None
    if not (p / "metadata.yaml").is_file() or not mcap_is_closed(files[0]):
        return files[0]
    return None


def recover_hint(mcap_path) -> str:
    """The command that turns a torn recording into a finished bag."""
    return f"python -m softhand_sim.ros.bagio recover {mcap_path} NEW_BAG_DIR"


def check_bag_path(path, allow_torn: bool = False) -> Path:
    """The bag directory as a Path, or BagError saying why it is not one.

    A directory holding only the .mcap of a recording cut short (no metadata.yaml) passes with
    allow_torn; otherwise the error names the recover command.
    """
    p = Path(path)
    if not p.exists():
        raise BagError(f"bag not found: {p}")
    if not p.is_dir():
        raise BagError(f"{p} is not a rosbag2 directory (expected a folder with metadata.yaml and .mcap or .db3)")
    if not (p / "metadata.yaml").is_file():
        torn = _torn_mcap(p)
        if torn is not None and allow_torn:
            return p
        hint = (f" (a recording cut short? its complete chunks can be recovered with "
                f"`{recover_hint(torn)}`)") if torn is not None else ""
        raise BagError(f"{p} is not a rosbag2 directory: it has no metadata.yaml{hint}")
    return p


def _torn_error(p: Path, mcap_path: Path) -> BagError:
    return BagError(f"bag {p} was cut short (its mcap file has no summary and no end magic, e.g. the "
                    f"recorder was killed); recover its complete chunks with `{recover_hint(mcap_path)}`")


def _torn_warning(mcap_path: Path, n: int) -> str:
    return (f"{mcap_path} was cut short (no summary, no end magic): using the {n} messages of its "
            f"complete chunks; `{recover_hint(mcap_path)}` makes a finished bag of them")


def iter_intact_mcap(mcap_path):
    """(schema, channel, message) records of the complete chunks of a possibly torn mcap file.

    Streams with the `mcap` library and stops quietly at the torn tail (a cut chunk or record);
    everything before it is yielded. The mcap records' `.metadata` of channels is a dict.
    """
    from mcap.exceptions import McapError
    from mcap.records import Channel as McapChannel, Message, Schema
    from mcap.stream_reader import StreamReader

    schemas, channels = {}, {}
    with open(mcap_path, "rb") as f:
        try:
            for record in StreamReader(f, skip_magic=False).records:
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, McapChannel):
                    channels[record.id] = record
                elif isinstance(record, Message):
                    ch = channels[record.channel_id]
                    yield schemas[ch.schema_id], ch, record
        except (McapError, EOFError, ValueError, OSError, KeyError, struct.error):
            return  # the torn tail: everything before it is already yielded


def _read_torn(p: Path, mcap_path: Path, topics) -> Recording:
    found, messages, seen = {}, [], 0
    for schema, ch, msg in iter_intact_mcap(mcap_path):
        seen += 1
        if topics is not None and ch.topic not in topics:
            continue
        if ch.topic not in found:
            found[ch.topic] = RecordedTopic(ch.topic, schema.name,
                                            parse_qos(ch.metadata.get("offered_qos_profiles", "")),
                                            ch.metadata.get("topic_type_hash", ""))
        messages.append((int(msg.log_time), ch.topic, bytes(msg.data)))
    if not seen:
        raise BagError(f"cannot read bag {p}: its mcap file {mcap_path.name} is corrupt or was cut short "
                       f"before its first complete chunk (no summary, no end magic, no readable message)")
    messages.sort(key=lambda m: m[0])
    return Recording(p, "mcap", found, messages, _torn_warning(mcap_path, seen))


def read_recording(path, topics=None, allow_torn: bool = False) -> Recording:
    """The messages of `topics` (None: all) of the bag at `path`, with each topic's type and QoS.

    BagError like read_topic (missing path, not a bag, corrupt, missing topic). A recording cut
    short (mcap without metadata.yaml or without end magic): with allow_torn its complete chunks
    are read and `warning` says so; without, the error names the recover command.
    """
    p = check_bag_path(path, allow_torn)
    wanted = None if topics is None else list(dict.fromkeys(topics))
    torn = _torn_mcap(p)
    if torn is not None:
        if not allow_torn:
            raise _torn_error(p, torn)
        rec = _read_torn(p, torn, None if wanted is None else set(wanted))
        have = sorted(rec.topics)
    else:
        try:
            with Reader(p) as reader:
                conns = [c for c in reader.connections if wanted is None or c.topic in wanted]
                found = {}
                for c in conns:
                    found.setdefault(c.topic, RecordedTopic(c.topic, c.msgtype,
                                                            list(getattr(c.ext, "offered_qos_profiles", [])),
                                                            c.digest))
                messages = [(int(stamp), conn.topic, bytes(raw))
                            for conn, stamp, raw in reader.messages(connections=conns)]
                have = sorted({c.topic for c in reader.connections})
        except Exception as exc:  # rosbags raises ReaderError, yaml, KeyError, struct errors...
            raise BagError(f"cannot read bag {p} (corrupt or unsupported): {type(exc).__name__}: {exc}") from None
        messages.sort(key=lambda m: m[0])
        rec = Recording(p, _storage_of(p), found, messages)
    missing = [t for t in (wanted or []) if t not in rec.topics]
    if missing:
        raise BagError(f"bag {p} has no topic {', '.join(missing)} (topics in it: {', '.join(have) or 'none'})")
    if not rec.messages:
        raise BagError(f"bag {p} has no messages")
    return rec


def read_topic(path, topic: str, msgtype: str, allow_torn: bool = False) -> TopicData:
    """All messages of `topic` in the bag at `path`, checked to be of ROS type `msgtype`.

    BagError for: a missing path, a folder that is not a rosbag2 bag, a corrupt metadata.yaml or
    storage file, a missing topic (the text lists the topics that are there), a topic of another
    type, or a topic without messages. A recording cut short (see read_recording): read from its
    complete chunks with allow_torn (TopicData.warning says so), else an error naming the recover
    command.
    """
    p = check_bag_path(path, allow_torn)
    torn = _torn_mcap(p)
    if torn is not None:
        if not allow_torn:
            raise _torn_error(p, torn)
        rec = _read_torn(p, torn, None)
        if topic not in rec.topics:
            raise BagError(f"bag {p} has no topic {topic} in its complete chunks "
                           f"(topics there: {', '.join(sorted(rec.topics)) or 'none'})")
        if rec.topics[topic].msgtype != msgtype:
            raise BagError(f"topic {topic} in bag {p} has type {rec.topics[topic].msgtype}, expected {msgtype}")
        mine = [(s, raw) for s, t, raw in rec.messages if t == topic]
        return TopicData(p, topic, msgtype, "mcap", [s for s, _ in mine], [raw for _, raw in mine], rec.warning)
    try:
        with Reader(p) as reader:
            conns = [c for c in reader.connections if c.topic == topic]
            if not conns:
                have = sorted({c.topic for c in reader.connections})
                raise BagError(f"bag {p} has no topic {topic} (topics in it: {', '.join(have) or 'none'})")
            wrong = sorted({c.msgtype for c in conns if c.msgtype != msgtype})
            if wrong:
                raise BagError(f"topic {topic} in bag {p} has type {', '.join(wrong)}, expected {msgtype}")
            stamps, payloads = [], []
            for _conn, stamp, raw in reader.messages(connections=conns):
                stamps.append(int(stamp))
                payloads.append(bytes(raw))
    except BagError:
        raise
    except Exception as exc:  # rosbags raises ReaderError, yaml, KeyError, struct errors...
        raise BagError(f"cannot read bag {p} (corrupt or unsupported): {type(exc).__name__}: {exc}") from None
    if not stamps:
        raise BagError(f"topic {topic} in bag {p} has no messages")
    order = sorted(range(len(stamps)), key=stamps.__getitem__)
    return TopicData(p, topic, msgtype, _storage_of(p), [stamps[i] for i in order], [payloads[i] for i in order])


def topic_counts(path) -> dict:
    """{topic: messages} of the (finalized) bag at `path`, from its index, no message read. A
    recorder lists every topic it subscribed to, so a topic may be there with 0 messages.
    BagError naming the bag when it cannot be read."""
    try:
        with Reader(Path(path)) as reader:
            counts = {}
            for c in reader.connections:
                counts[c.topic] = counts.get(c.topic, 0) + int(c.msgcount)
            return counts
    except Exception as exc:  # rosbags raises ReaderError, yaml, KeyError, struct errors...
        raise BagError(f"cannot read bag {path}: {type(exc).__name__}: {exc}") from None


def read_tracker(path, side: str = "right", allow_torn: bool = False) -> TopicData:
    """The tracked frames of hand `side` in a tracker bag: its /tracker/{side}/hand_joints, or,
    in an old single-hand bag, /tracker/hand_joints (the bag's one hand, whichever side the caller
    takes it for). BagError as read_topic, naming the side's topic when neither is there."""
    from softhand_sim.topics import LEGACY_TRACKER, POSE_ARRAY, tracker_topic

    try:
        return read_topic(path, tracker_topic(side), POSE_ARRAY, allow_torn)
    except BagError as exc:
        if "has no topic" not in str(exc):
            raise
        try:
            return read_topic(path, LEGACY_TRACKER, POSE_ARRAY, allow_torn)
        except BagError as legacy:
            if "has no topic" not in str(legacy):
                raise
            raise exc from None


def deserialize(raw: bytes, msgtype: str):
    """A rosbags message object (attribute access like rclpy's) from CDR bytes."""
    return TYPESTORE.deserialize_cdr(raw, msgtype)


def serialize(msg, msgtype: str) -> bytes:
    """CDR bytes of a rosbags message object."""
    return bytes(TYPESTORE.serialize_cdr(msg, msgtype))


def starts_with_header(msgtype: str) -> bool:
    """Whether CDR messages of `msgtype` begin with a std_msgs/Header (stamp at bytes 4..12)."""
    fields = TYPESTORE.fielddefs.get(msgtype)
    if not fields or not fields[1]:
        return False
    _name, (_kind, sub) = fields[1][0]
    return sub == "std_msgs/msg/Header"


def header_stamp_ns(raw: bytes):
    """Header stamp [ns] of a CDR message that starts with std_msgs/Header, else None.

    CDR: 4-byte encapsulation (byte 1: 0x01 little endian), then Header.stamp = sec int32,
    nanosec uint32. Only used for types known to start with a Header.
    """
    if len(raw) < 12:
        return None
    order = "little" if raw[1] & 1 else "big"
    sec = int.from_bytes(raw[4:8], order, signed=True)
    nsec = int.from_bytes(raw[8:12], order, signed=False)
    return sec * 1_000_000_000 + nsec


def with_header_stamp(raw: bytes, stamp_ns: int) -> bytes:
    """A copy of a Header-first CDR message whose header stamp is `stamp_ns` (layout as above)."""
    order = "little" if raw[1] & 1 else "big"
    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    return raw[:4] + sec.to_bytes(4, order, signed=True) + nsec.to_bytes(4, order) + raw[12:]


# ------------------------------------------------------------------------------------------ QoS


def _time_of(duration) -> QosTime:
    ns = int(duration.nanoseconds)
    return QosTime(*divmod(min(ns, DURATION_INFINITE_NS), 1_000_000_000))


def qos_from_profile(profile) -> Qos:
    """The rosbags Qos of an rclpy QoSProfile (e.g. TopicEndpointInfo.qos_profile), field by field.

    Duck-typed (enum names, Duration.nanoseconds) so this module needs no rclpy. A publisher seen
    through discovery reports history UNKNOWN and depth 0 (DDS does not announce them), and the
    infinite durations as RMW_DURATION_INFINITE = 9223372036 s 854775807 ns: rosbag2 Jazzy writes
    exactly these values, and so do we.
    """
    return Qos(history=QosHistory[profile.history.name],
               depth=int(profile.depth),
               reliability=QosReliability[profile.reliability.name],
               durability=QosDurability[profile.durability.name],
               deadline=_time_of(profile.deadline),
               lifespan=_time_of(profile.lifespan),
               liveliness=QosLiveliness[profile.liveliness.name],
               liveliness_lease_duration=_time_of(profile.liveliness_lease_duration),
               avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions))


#: Key order of rosbag2 Jazzy's YAML (yaml.hpp BagMetadata/TopicInformation/TopicMetadata,
#: qos.cpp convert<rclcpp::QoS>), one order for all maps (so `files` entries differ a little);
#: rosbags sorts keys alphabetically. YAML maps are unordered: this is for people and diffs only.
_ROSBAG2_KEY_ORDER = {k: i for i, k in enumerate((
    "rosbag2_bagfile_information", "path", "version", "storage_identifier", "duration", "starting_time",
    "topic_metadata", "message_count", "topics_with_message_count", "name", "type",
    "serialization_format", "offered_qos_profiles", "type_description_hash", "compression_format",
    "compression_mode", "relative_file_paths", "files", "custom_data", "ros_distro",
    "history", "depth", "reliability", "durability", "deadline", "lifespan", "liveliness",
    "liveliness_lease_duration", "avoid_ros_namespace_conventions", "sec", "nsec",
    "nanoseconds", "nanoseconds_since_epoch"))}


def _in_rosbag2_order(node):
    if isinstance(node, dict):
        keys = sorted(node, key=lambda k: _ROSBAG2_KEY_ORDER.get(k, len(_ROSBAG2_KEY_ORDER)))
        return {k: _in_rosbag2_order(node[k]) for k in keys}
    if isinstance(node, list):
        return [_in_rosbag2_order(x) for x in node]
    return node


def _yaml_text(data) -> str:
    """Block-style YAML in rosbag2's key order, long scalars (type hashes) on one line."""
    yaml = YAML(typ="safe")
    yaml.default_flow_style = False
    yaml.width = 4096
    yaml.representer.sort_base_mapping_type_on_output = False
    out = StringIO()
    yaml.dump(_in_rosbag2_order(data), out)
    return out.getvalue()


def dump_qos_profiles(profiles) -> str:
    """The YAML text rosbag2 Jazzy stores as a channel's `offered_qos_profiles` (metadata version 9:
    a sequence of maps with lower-case policy names; '' for none, as rosbags writes)."""
    from rosbags.rosbag2.metadata import dump_qos_v9

    dumped = dump_qos_v9(list(profiles))
    return _yaml_text(dumped).strip() if dumped else ""


# ------------------------------------------------------------------------------------- writing


def _yaml_with_jazzy_distro(text: str, nested: bool) -> str:
    """`text` (rosbags' bag metadata YAML) with ros_distro = jazzy instead of 'rosbags'."""
    data = YAML(typ="safe").load(text)
    (data["rosbag2_bagfile_information"] if nested else data)["ros_distro"] = ROS_DISTRO
    out = _yaml_text(data)
    return out if nested else out.strip()


class JazzyMcapWriter(McapWriter):
    """rosbags' mcap storage writer with the channel metadata of rosbag2 Jazzy's mcap plugin.

    rosbag2_storage_mcap (jazzy, MCAPStorage::create_topic) gives every channel two metadata
    entries: `offered_qos_profiles` (serialize_rclcpp_qos_vector, version 9) and
    `topic_type_hash` (RIHS01_...); rosbags 0.11.9 writes only the first. And rosbags hard-codes
    `ros_distro: rosbags` in the 'rosbag2' metadata record it writes on close (pinned version:
    this mirrors McapWriter.add_connection and wraps its close).
    """

    def add_connection(self, connection, offered_qos_profiles: str) -> None:
        # the same profiles as rosbags' text, dumped in rosbag2's key order
        _ = offered_qos_profiles
        metadata = BytesIO()
        write_string(metadata, "offered_qos_profiles")
        write_string(metadata, dump_qos_profiles(connection.ext.offered_qos_profiles))
        write_string(metadata, "topic_type_hash")
        write_string(metadata, connection.digest)
        self.channels.append(Channel(connection.id, connection.msgtype, connection.topic,
                                     connection.ext.serialization_format, metadata.getvalue()))
        self.channel_stats[connection.id] = 0
        write_channel(self.chunk.bio, self.channels[-1], self.schemas)

    def close(self, version: int, metadata: str) -> None:
        super().close(version, _yaml_with_jazzy_distro(metadata, nested=False))


class JazzyWriter(Writer):
    """rosbags' Writer whose bags read like rosbag2 Jazzy's: mcap channels through JazzyMcapWriter,
    and metadata.yaml rewritten on close with `ros_distro: jazzy` (rosbags' Writer.close
    hard-codes 'rosbags'; rosbag2 Jazzy writes $ROS_DISTRO there)."""

    STORAGE_PLUGINS = {**Writer.STORAGE_PLUGINS, StoragePlugin.MCAP: JazzyMcapWriter}

    def close(self) -> None:
        super().close()
        text = self.metapath.read_text("utf8")
        tmp = self.metapath.with_suffix(".yaml.tmp")
        tmp.write_text(_yaml_with_jazzy_distro(text, nested=True), "utf8")
        tmp.replace(self.metapath)


def open_writer(path, storage: str = "mcap") -> JazzyWriter:
    """An opened JazzyWriter for a new rosbag2 directory (BagError if `path` exists)."""
    p = Path(path)
    if p.exists():
        raise BagError(f"output {p} exists already; choose a new directory")
    plugin = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}.get(storage)
    if plugin is None:
        raise BagError(f"storage must be 'mcap' or 'sqlite3', got {storage!r}")
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        writer = JazzyWriter(p, version=Writer.VERSION_LATEST, storage_plugin=plugin)
        writer.open()
    except OSError as exc:  # a read-only or missing place: its own words, naming the path
        raise BagError(f"cannot create the recording {p}: {exc.strerror or exc}") from None
    return writer


def known_type(msgtype: str) -> bool:
    """Whether the Jazzy typestore can give the schema of `msgtype` ('pkg/msg/Name')."""
    return msgtype in TYPESTORE.fielddefs


def type_hash(msgtype: str) -> str:
    """The RIHS01 hash of `msgtype` from the Jazzy typestore ('RIHS01_<64 hex>')."""
    return TYPESTORE.hash_rihs01(msgtype)


def add_topic(writer: Writer, topic: str, msgtype: str, offered_qos_profiles=()):
    """A connection for `topic` whose schema (ros2msg definition + RIHS01 hash) comes from the
    typestore, with the publishers' offered QoS (rosbags Qos list; see qos_from_profile)."""
    if not known_type(msgtype):
        raise BagError(f"message type {msgtype} of topic {topic} is not in the ROS 2 Jazzy typestore")
    return writer.add_connection(topic, msgtype, typestore=TYPESTORE, offered_qos_profiles=list(offered_qos_profiles))


def flush_chunk(writer: Writer) -> None:
    """Write the pending mcap chunk to disk now (bounds what a SIGKILL can lose).

    rosbags closes a chunk only when it passes 1 MiB; this reaches into its mcap storage
    (pinned rosbags version; a no-op for sqlite3, which commits per message) so a recorder can
    do it on a timer.
    """
    storage = getattr(writer, "storage", None)
    chunk = getattr(storage, "chunk", None)
    if chunk is not None and hasattr(storage, "close_chunk") and chunk.bio.tell():
        storage.close_chunk()
    bio = getattr(storage, "bio", None)
    if bio is not None:
        bio.flush()


def write_bag(path, records: Iterable, storage: str = "mcap", qos: dict | None = None) -> Path:
    """Write a bag from (topic, msgtype, stamp_ns, cdr_bytes) records (tests, synthetic bags);
    `qos` maps a topic to its offered QoS list (default: none recorded, like rosbags)."""
    writer = open_writer(path, storage)
    conns = {}
    try:
        for topic, msgtype, stamp, raw in records:
            if topic not in conns:
                conns[topic] = add_topic(writer, topic, msgtype, (qos or {}).get(topic, ()))
            writer.write(conns[topic], int(stamp), raw)
    finally:
        writer.close()
    return Path(path)


# ------------------------------------------------------------------------------------ recovery


def recover_mcap(src_mcap, dst_bag) -> int:
    """Copy every message of the complete chunks of a (possibly torn) mcap file into a new bag.

    For a recording whose writer died (SIGKILL, power loss): the torn file has no summary and no
    metadata.yaml, so neither rosbags nor `ros2 bag` opens it; its finished chunks are intact.
    The channels keep their recorded offered QoS. Returns the number of messages recovered.
    (`ros2 bag reindex` does the same where ROS is installed.)
    """
    conns, count = {}, 0
    writer = open_writer(dst_bag)
    try:
        for schema, ch, msg in iter_intact_mcap(src_mcap):
            if ch.id not in conns:
                conns[ch.id] = add_topic(writer, ch.topic, schema.name,
                                         parse_qos(ch.metadata.get("offered_qos_profiles", "")))
            writer.write(conns[ch.id], msg.log_time, msg.data)
            count += 1
    finally:
        writer.close()
    return count


def main(argv=None) -> int:
    """`python -m softhand_sim.ros.bagio recover BROKEN.mcap NEW_BAG_DIR`."""
    import argparse

    parser = argparse.ArgumentParser(prog="python -m softhand_sim.ros.bagio",
                                     description="rosbag2 helpers: recover a recording whose writer was killed")
    sub = parser.add_subparsers(dest="cmd", required=True)
    rec = sub.add_parser("recover", help="copy the intact chunks of a torn .mcap into a new bag directory")
    rec.add_argument("mcap", help="the .mcap file of the killed recording")
    rec.add_argument("output", help="new rosbag2 directory to create")
    ns = parser.parse_args(argv)
    try:
        n = recover_mcap(ns.mcap, ns.output)
    except (BagError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"recovered {n} messages into {ns.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
