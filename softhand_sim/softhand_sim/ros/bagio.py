"""rosbag2 read/write helpers (rosbags library; no rclpy).

Reading: `read_topic(path, topic, msgtype)` loads every message of one topic of a rosbag2
directory (mcap or sqlite3 storage, found from its metadata.yaml) as raw CDR bytes with their
bag timestamps, and turns every way a bag can be unusable into a `BagError` whose text names the
problem (missing path, not a bag, corrupt file, missing topic, wrong type, no messages).

Writing: `open_writer(path)` starts an mcap rosbag2 directory whose channels carry their
message definitions as ros2msg schemas (what `ros2 bag info/play` and Foxglove need);
`add_topic` adds a connection for a ROS type from the Jazzy typestore; `flush_chunk` closes the
writer's pending mcap chunk so that a later SIGKILL loses at most what came after it.

Recovery: an mcap file whose writer was killed has no summary, footer or metadata.yaml; the
chunks written before the kill are intact. `recover_mcap(src_mcap, dst_bag)` streams those
chunks with the `mcap` library (stopping at the torn tail) and writes a new, finalized bag.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)


class BagError(RuntimeError):
    """A bag cannot be used; the text says which bag and why."""


@dataclass(frozen=True)
class TopicData:
    """The messages of one topic: bag timestamps [ns] (ascending) and raw CDR payloads."""
    path: Path
    topic: str
    msgtype: str
    storage: str
    stamps_ns: list
    payloads: list

    @property
    def duration_s(self) -> float:
        return (self.stamps_ns[-1] - self.stamps_ns[0]) * 1e-9 if self.stamps_ns else 0.0


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


def check_bag_path(path) -> Path:
    """The bag directory as a Path, or BagError saying why it is not one."""
    p = Path(path)
    if not p.exists():
        raise BagError(f"bag not found: {p}")
    if not p.is_dir():
        raise BagError(f"{p} is not a rosbag2 directory (expected a folder with metadata.yaml and .mcap or .db3)")
    if not (p / "metadata.yaml").is_file():
        raise BagError(f"{p} is not a rosbag2 directory: it has no metadata.yaml")
    return p


def read_topic(path, topic: str, msgtype: str) -> TopicData:
    """All messages of `topic` in the bag at `path`, checked to be of ROS type `msgtype`.

    BagError for: a missing path, a folder that is not a rosbag2 bag, a corrupt metadata.yaml or
    storage file, a missing topic (the text lists the topics that are there), a topic of another
    type, or a topic without messages.
    """
    p = check_bag_path(path)
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


def deserialize(raw: bytes, msgtype: str):
    """A rosbags message object (attribute access like rclpy's) from CDR bytes."""
    return TYPESTORE.deserialize_cdr(raw, msgtype)


def serialize(msg, msgtype: str) -> bytes:
    """CDR bytes of a rosbags message object."""
    return bytes(TYPESTORE.serialize_cdr(msg, msgtype))


# ------------------------------------------------------------------------------------- writing


def open_writer(path, storage: str = "mcap") -> Writer:
    """An opened rosbags Writer for a new rosbag2 directory (BagError if `path` exists)."""
    p = Path(path)
    if p.exists():
        raise BagError(f"output {p} exists already; choose a new directory")
    plugin = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}.get(storage)
    if plugin is None:
        raise BagError(f"storage must be 'mcap' or 'sqlite3', got {storage!r}")
    p.parent.mkdir(parents=True, exist_ok=True)
    writer = Writer(p, version=Writer.VERSION_LATEST, storage_plugin=plugin)
    writer.open()
    return writer


def known_type(msgtype: str) -> bool:
    """Whether the Jazzy typestore can give the schema of `msgtype` ('pkg/msg/Name')."""
    return msgtype in TYPESTORE.fielddefs


def add_topic(writer: Writer, topic: str, msgtype: str, offered_qos_profiles=()):
    """A connection for `topic` whose schema (ros2msg definition + RIHS01 hash) comes from the typestore."""
    if not known_type(msgtype):
        raise BagError(f"message type {msgtype} of topic {topic} is not in the ROS 2 Jazzy typestore")
    return writer.add_connection(topic, msgtype, typestore=TYPESTORE, offered_qos_profiles=offered_qos_profiles)


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


def write_bag(path, records: Iterable, storage: str = "mcap") -> Path:
    """Write a bag from (topic, msgtype, stamp_ns, cdr_bytes) records (tests, synthetic bags)."""
    writer = open_writer(path, storage)
    conns = {}
    try:
        for topic, msgtype, stamp, raw in records:
            if topic not in conns:
                conns[topic] = add_topic(writer, topic, msgtype)
            writer.write(conns[topic], int(stamp), raw)
    finally:
        writer.close()
    return Path(path)


# ------------------------------------------------------------------------------------ recovery


def recover_mcap(src_mcap, dst_bag) -> int:
    """Copy every message of the complete chunks of a (possibly torn) mcap file into a new bag.

    For a recording whose writer died (SIGKILL, power loss): the torn file has no summary and no
    metadata.yaml, so neither rosbags nor `ros2 bag` opens it; its finished chunks are intact.
    Returns the number of messages recovered. (`ros2 bag reindex` does the same where ROS is
    installed.)
    """
    from mcap.exceptions import McapError
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader

    schemas, channels, conns, count = {}, {}, {}, 0
    writer = open_writer(dst_bag)
    try:
        with open(src_mcap, "rb") as f:
            try:
                for record in StreamReader(f, skip_magic=False).records:
                    if isinstance(record, Schema):
                        schemas[record.id] = record
                    elif isinstance(record, Channel):
                        channels[record.id] = record
                    elif isinstance(record, Message):
                        ch = channels[record.channel_id]
                        if ch.id not in conns:
                            conns[ch.id] = add_topic(writer, ch.topic, schemas[ch.schema_id].name)
                        writer.write(conns[ch.id], record.log_time, record.data)
                        count += 1
            except (McapError, EOFError, ValueError, OSError):
                pass  # the torn tail: everything before it is already copied
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
