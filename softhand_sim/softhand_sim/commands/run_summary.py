"""Figures of a recorded run, read back from its rosbag2 directory with rosbags (no ROS needed).

Measured, not reported by the nodes alone:
- rates [Hz] of every recorded topic from the recorder's receive times;
- tracker -> /hand/bones latency: for each tracker frame received after the first /hand/bones,
  the time until the next /hand/bones message (the delay before the simulated skeleton can
  reflect that frame; it spans one tracking period and one sim period plus transport). Frames
  before the first /hand/bones only measure start-up: that wait is `startup_s` (first tracker
  frame -> first /hand/bones);
- sim step time p50/p99 from sim_node's own /diagnostics;
- tracker frames: in the input bag, published (play_node's log), recorded, and received / accepted /
  rejected by tracking_node (its last /diagnostics): nothing may be lost on replay (issue #17);
- max active contacts from /hand/contacts; ball lift from the engine side /world/object_states;
- the hand measures in use (source default | file | auto, hand and palm sizes [mm], the sizing state
  while `hand_measures: auto` fits) from sim_node's last /diagnostics status that names them;
- finiteness of every numeric field of every recorded message.
"""
from __future__ import annotations

import dataclasses
import math
from collections import defaultdict
from itertools import chain
from operator import attrgetter
from pathlib import Path

import numpy as np

LIFT_OBJECT = "ball"


def _reader(bag_dir):
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    return Reader(Path(bag_dir)), get_typestore(Stores.ROS2_JAZZY)


def _float_fields(obj):
    """The field names of a message whose fields are all floats (Point, Quaternion, ColorRGBA...), else None."""
    if not dataclasses.is_dataclass(obj):
        return None
    names = tuple(f.name for f in dataclasses.fields(obj) if not f.name.startswith("__"))  # not __msgtype__
    return names if names and all(isinstance(getattr(obj, f), float) for f in names) else None


def _finite(msg, depth=0):
    """True if every float in the message (recursively, arrays included) is finite."""
    if depth > 8:
        return True
    if isinstance(msg, float):
        return math.isfinite(msg)
    if isinstance(msg, np.ndarray):
        return msg.dtype.kind != "f" or bool(np.all(np.isfinite(msg)))
    if isinstance(msg, (list, tuple)):
        names = _float_fields(msg[0]) if msg else None
        if names and all(type(m) is type(msg[0]) for m in msg):
            # a marker's points: one array instead of a call per float (the skin marker has 70k)
            values = np.fromiter(chain.from_iterable(map(attrgetter(*names), msg)) if len(names) > 1
                                 else map(attrgetter(names[0]), msg), dtype=np.float64)
            return bool(np.all(np.isfinite(values)))
        return all(_finite(m, depth + 1) for m in msg)
    if hasattr(msg, "__dataclass_fields__"):
        return all(_finite(getattr(msg, f), depth + 1) for f in msg.__dataclass_fields__)
    return True


def _pointcloud_fields(msg):
    from softhand_sim.ros.msgs import pointcloud_to_structured

    return pointcloud_to_structured(msg)


def frame_latency_ms(tracker_t, bones_t):
    """(latency [ms] per tracker frame received after the first /hand/bones: time to the next
    /hand/bones, startup_s: first tracker frame -> first /hand/bones [s]) from receive times [s]."""
    if not len(tracker_t) or not len(bones_t):
        return np.empty(0), float("nan")
    b, tr = np.asarray(bones_t, dtype=np.float64), np.asarray(tracker_t, dtype=np.float64)
    idx = np.searchsorted(b, tr, side="right")
    ok = (idx < b.size) & (tr >= b[0])
    return (b[idx[ok]] - tr[ok]) * 1e3, float(b[0] - tr[0])


def _input_frames(input_bag):
    """Messages on /tracker/hand_joints in the input bag (None if it cannot be read)."""
    try:
        from softhand_sim.ros.bagio import read_topic

        return len(read_topic(input_bag, "/tracker/hand_joints", "geometry_msgs/msg/PoseArray").stamps_ns)
    except Exception:
        return None


def _published_frames(play_log):
    """N of play_node's 'done: published N messages' log line (None if absent)."""
    import re

    try:
        found = re.findall(r"done: published (\d+) messages", Path(play_log).read_text(errors="replace"))
    except OSError:
        return None
    return int(found[-1]) if found else None


HAND_KEY_PREFIXES = ("hand_", "palm_")  # sim_node's measures keys (hand_sizer.measures_diagnostics, HandSizer)


def hand_measures_values(values: dict) -> dict:
    """The hand measures keys of one sim_node status (key -> value string), numbers parsed: e.g.
    {'hand_measures_source': 'auto', 'hand_length_mm': 181.2, 'palm_length_mm': 99.0, ...};
    empty if the status does not name its measures."""
    if "hand_measures_source" not in values:
        return {}
    out = {}
    for key, value in values.items():
        if key.startswith(HAND_KEY_PREFIXES):
            number = _number(value)  # sizes stay floats in summary.json ('190' is how 190.0 is sent)
            out[key] = float(number) if key.endswith(("_mm", "_s")) and isinstance(number, int) else number
    return out


def _number(text: str):
    """int or float of a /diagnostics value string if it is one, else the string."""
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def hand_measures_line(h: dict) -> str:
    """The printed summary's line of summarize_run()['hand_measures']: which hand was simulated."""
    if not h:
        return "  hand measures: not reported by sim_node"
    sizes = ", ".join(f"{k.removesuffix('_mm').replace('_', ' ')} {v:.1f} mm" for k, v in h.items()
                      if k.endswith("_mm") and isinstance(v, (int, float)))
    line = f"  hand measures: {h.get('hand_measures_source', '?')}" + (f", {sizes}" if sizes else "")
    extra = [f"{k[10:-2]} {v} s" if k.endswith("_s") else f"{k[10:]} {v}"  # k[10:]: after 'hand_size_'
             for k, v in h.items() if k.startswith("hand_size_")]
    return line + (f" (sizing: {', '.join(extra)})" if extra else "")


def summarize_run(bag_dir, bag_name="", exit_codes=None, input_bag=None, play_log=None):
    from softhand_sim.ros.msgs import status_node  # ROS message packages only when reading a run

    bag_dir = Path(bag_dir)
    summary = {"bag": bag_name, "exit_codes": exit_codes or {}}
    if not bag_dir.exists():
        summary["error"] = f"no recording at {bag_dir}"
        return summary
    reader, store = _reader(bag_dir)
    times = defaultdict(list)
    tracker_t, bones_t = [], []
    step_p50, step_p99 = [], []
    tracking_counts = {}
    hand_measures = {}
    max_contacts = 0
    ball_z = []
    all_finite = True
    count = 0
    with reader:
        for conn, t_ns, raw in reader.messages():
            count += 1
            t = t_ns * 1e-9
            times[conn.topic].append(t)
            msg = store.deserialize_cdr(raw, conn.msgtype)
            if conn.msgtype == "sensor_msgs/msg/PointCloud2":
                cloud = _pointcloud_fields(msg)
                floats = [cloud[n] for n in cloud.dtype.names if cloud.dtype[n].kind == "f"]
                if any(not np.all(np.isfinite(f)) for f in floats):
                    all_finite = False
                if conn.topic == "/hand/contacts":
                    max_contacts = max(max_contacts, int(cloud.size))
            elif not _finite(msg):
                all_finite = False
            if conn.topic == "/tracker/hand_joints":
                tracker_t.append(t)
            elif conn.topic == "/hand/bones":
                bones_t.append(t)
            elif conn.topic == "/world/object_states":
                names = list(msg.joint_names)
                if LIFT_OBJECT in names and msg.points:
                    ball_z.append(msg.points[0].transforms[names.index(LIFT_OBJECT)].translation.z)
            elif conn.topic == "/diagnostics":
                for status in msg.status:
                    if status_node(status.name) == "tracking_node":  # the last report holds the final counts
                        values = {kv.key: kv.value for kv in status.values}
                        for key in ("frames_received", "frames_accepted", "frames_rejected"):
                            if key in values:
                                tracking_counts[key.removeprefix("frames_")] = int(float(values[key]))
                    if status_node(status.name) == "sim_node":
                        values = {kv.key: kv.value for kv in status.values}
                        # the last status wins whole: the sizer's keys leave it once the fitted hand runs
                        hand_measures = hand_measures_values(values) or hand_measures
                        try:
                            p50, p99 = float(values["step_ms_p50"]), float(values["step_ms_p99"])
                        except (KeyError, ValueError):
                            continue
                        if math.isfinite(p50) and math.isfinite(p99):  # nan before the first step
                            step_p50.append(p50)
                            step_p99.append(p99)
    rates = {}
    for topic, ts in sorted(times.items()):
        if len(ts) > 1 and ts[-1] > ts[0]:
            rates[topic] = (len(ts) - 1) / (ts[-1] - ts[0])
    latency, startup_s = frame_latency_ms(tracker_t, bones_t)
    size = sum(f.stat().st_size for f in bag_dir.rglob("*") if f.is_file())
    frames = {"in_bag": _input_frames(input_bag) if input_bag is not None else None,
              "published": _published_frames(play_log) if play_log is not None else None,
              "recorded": len(times.get("/tracker/hand_joints", [])), **tracking_counts}
    summary.update({
        "tracker_frames": {k: v for k, v in frames.items() if v is not None},
        "bag_messages": count,
        "bag_mb": size / 1e6,
        "messages_per_topic": {k: len(v) for k, v in sorted(times.items())},
        "rates_hz": rates,
        "sim_step_ms_p50": float(np.median(step_p50)) if step_p50 else float("nan"),
        # each /diagnostics window covers the last 1000 steps; the first includes the first
        # factorization and first-call overheads, so the median window is the steady figure
        "sim_step_ms_p99": float(np.median(step_p99)) if step_p99 else float("nan"),
        "sim_step_ms_p99_worst_window": float(np.max(step_p99)) if step_p99 else float("nan"),
        "latency_ms_p50": float(np.percentile(latency, 50)) if len(latency) else float("nan"),
        "latency_ms_p99": float(np.percentile(latency, 99)) if len(latency) else float("nan"),
        "startup_s": startup_s,
        "hand_measures": hand_measures,
        "max_contacts": max_contacts,
        "ball_lift_m": float(max(ball_z) - ball_z[0]) if ball_z else 0.0,
        "ball_lifted": bool(ball_z and max(ball_z) - ball_z[0] >= 0.08),
        "all_finite": all_finite,
    })
    return summary
