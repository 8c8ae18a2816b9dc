"""Figures of a recorded run, read back from its rosbag2 directory with rosbags (no ROS needed).

Measured, not reported by the nodes alone:
- rates [Hz] of every recorded topic from the recorder's receive times, steady state: over the
  middle 80 % of its messages (`steady_rate_hz`), so a start-up catch-up (the 250 Hz loop runs
  the steps a stall at start missed: 100 in 0.12 s measured) does not pass for a fast loop;
- tracker -> bones latency, per hand: for each frame on /tracker/{side}/hand_joints received after
  the first /hand/{side}/bones, the time until the next /hand/{side}/bones message (the delay
  before the simulated skeleton can reflect that frame; it spans one tracking period and one sim
  period plus transport). Frames before the first bones only measure start-up: that wait is
  `startup_s` (first tracker frame -> first bones);
- sim step time p50/p99 from sim_node's own /diagnostics;
- tracker frames, per hand: in the input bag, recorded, and received / accepted / rejected by that
  hand's tracking node (its last /diagnostics), and published (play_node's log, all hands
  together): nothing may be lost on replay (issue #17);
- fidelity per hand (`softhand fidelity`, softhand_sim.commands.fidelity, with the bone lengths
  sim_node reported): the lag (the best time shift of the intermediate and the simulated phalanx
  directions and palm behind the tracked ones [ms]), and the simulated hand's palm position and
  orientation, knuckle, fingertip and phalanx direction errors and thumb-index gap error against
  the tracked hand (median, p95, max);
- max active contacts from /hand/contacts (per hand by its `hand` field), and of them skin on
  skin (`object` SKIN_OBJECT, sim parameter self_contact); from the engine side
  /world/object_states, every object's lift (its highest z less its first) and where it ended
  against where it started (`object_moved_m`: the handover sets the ball down 20 cm on);
- the hand measures in use (source default | file | auto, hand and palm sizes [mm], the sizing state
  while `hand_measures: auto` fits) from sim_node's last /diagnostics status that names them;
- finiteness of every numeric field of every recorded message.

Two hands (docs/INTERFACE.md): `hands` holds the per-hand figures of every side that has tracker
frames or bones in the recording; the top-level `tracker_frames` are the sums over the hands and
the top-level latency pools the frames of all hands, so a one-hand run reads as before.
"""
from __future__ import annotations

import dataclasses
import math
from collections import defaultdict
from itertools import chain
from operator import attrgetter
from pathlib import Path

import numpy as np

from softhand_sim.topics import LEGACY_TRACKER, POSE_ARRAY, SIDES, SKIN_OBJECT, hand_topic, side_of, tracker_topic

LIFT_OBJECT = "ball"
TRACKING_NODE = "tracking_node"  # the second hand's runs as tracking_node_left (status names carry it)


def _reader(bag_dir):
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    return Reader(Path(bag_dir)), get_typestore(Stores.ROS2_JAZZY)


_LEAVES: dict = {}


def _float_leaves(obj):
    """The dotted paths of the float fields of a message, through nested messages, skipping
    integers and strings (Pose: position.x ... orientation.w; TransformStamped: transform.*), or
    None when it holds a list or an array (those are walked element by element). Per type, cached."""
    cls = type(obj)
    if cls in _LEAVES:
        return _LEAVES[cls]
    paths = []

    def walk(o, prefix):
        for f in (f.name for f in dataclasses.fields(o) if not f.name.startswith("__")):  # not __msgtype__
            v = getattr(o, f)
            if isinstance(v, float):
                paths.append(prefix + f)
            elif dataclasses.is_dataclass(v):
                if not walk(v, f"{prefix}{f}."):
                    return False
            elif isinstance(v, (list, tuple, np.ndarray)):
                return False
        return True

    leaves = tuple(paths) if dataclasses.is_dataclass(obj) and walk(obj, "") and paths else None
    _LEAVES[cls] = leaves
    return leaves


def _finite(msg, depth=0):
    """True if every float in the message (recursively, arrays included) is finite."""
    if depth > 8:
        return True
    if isinstance(msg, float):
        return math.isfinite(msg)
    if isinstance(msg, np.ndarray):
        return msg.dtype.kind != "f" or bool(np.all(np.isfinite(msg)))
    if isinstance(msg, (list, tuple)):
        names = _float_leaves(msg[0]) if msg else None
        if names and all(type(m) is type(msg[0]) for m in msg):
            # a list of poses, points, transforms: one array instead of a call per float (the skin
            # marker has 70k points; a summary walked 1.8 M fields one call each, 7 s of a demo)
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


FIDELITY_KEYS = ("palm_mm", "palm_deg", "knuckle_mm", "fingertip_mm", "phalanx_direction_deg", "held_phalanx_deg",
                 "pinch_gap_error_mm")


def _fidelity(bag_dir, side, bone_length):
    """(lag {layer: {phalanx, palm}} [ms], errors {FIDELITY_KEYS: {median, p95, max}}) of one hand
    (softhand fidelity on the recording, scored with `bone_length`, fidelity.bone_lengths_of);
    ({}, {}) where they cannot be told."""
    from softhand_sim.commands.fidelity import recorded_fidelity
    from softhand_sim.ros.bagio import BagError
    try:
        f = recorded_fidelity(bag_dir, bone_length, side)
    except (ValueError, BagError):
        return {}, {}
    errors = {k: f[k] for k in FIDELITY_KEYS if k in f and f[k].get("median") is not None}
    if f.get("tracker_noise_mm") is not None:  # a number, not a median / p95 / max
        errors["tracker_noise_mm"] = f["tracker_noise_mm"]
    return f.get("lag_ms", {}), errors


def steady_rate_hz(times, middle: float = 0.8):
    """Messages per second [Hz] over the middle `middle` fraction of the receive times `times` [s]
    (sorted): the first and last (1 - middle) / 2 left out, start-up and shut-down bursts with
    them. The whole span when there are too few messages to trim (< 10); None for fewer than 2 or
    a span of zero."""
    n = len(times)
    if n < 2:
        return None
    trim = int(round(0.5 * (1.0 - middle) * (n - 1))) if n >= 10 else 0
    a, b = trim, n - 1 - trim
    span = times[b] - times[a]
    return (b - a) / span if span > 0 else None


def frame_latency_ms(tracker_t, bones_t):
    """(latency [ms] per tracker frame received after the first bones message: time to the next
    one, startup_s: first tracker frame -> first bones [s]) from receive times [s] of one hand's
    /tracker/{side}/hand_joints and /hand/{side}/bones."""
    if not len(tracker_t) or not len(bones_t):
        return np.empty(0), float("nan")
    b, tr = np.asarray(bones_t, dtype=np.float64), np.asarray(tracker_t, dtype=np.float64)
    idx = np.searchsorted(b, tr, side="right")
    ok = (idx < b.size) & (tr >= b[0])
    return (b[idx[ok]] - tr[ok]) * 1e3, float(b[0] - tr[0])


def input_frames(input_bag, legacy_side="right"):
    """{side: messages on that side's tracker topic} of the input bag; an old single-hand bag's
    /tracker/hand_joints counts for `legacy_side` (as play_node plays it). None if unreadable."""
    from softhand_sim.ros.bagio import BagError, topic_counts

    try:
        topics = topic_counts(input_bag)
    except BagError:
        return None
    counts = {}
    for topic, n in topics.items():
        side = legacy_side if topic == LEGACY_TRACKER else side_of(topic)
        if side is not None and topic in (LEGACY_TRACKER, tracker_topic(side)):
            counts[side] = counts.get(side, 0) + n
    return counts


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


def tracking_frame_counts(values: dict) -> dict:
    """received / accepted / rejected of one tracking node /diagnostics status (key -> string)."""
    return {key.removeprefix("frames_"): int(float(values[key]))
            for key in ("frames_received", "frames_accepted", "frames_rejected") if key in values}


def summarize_run(bag_dir, bag_name="", exit_codes=None, input_bag=None, play_log=None, legacy_side="right", repeat=1,
                  scores=True):
    """The figures of the module docstring for the recording at bag_dir. input_bag: the bag that
    was played (its frame counts); play_log: play_node's log; legacy_side: the hand an old
    single-hand input bag was played as. scores=False leaves out each hand's lag and fidelity
    (`lag_ms`, `fidelity`): they read the recording twice more, over half of a summary's time."""
    from softhand_sim.ros.msgs import pose_array_from_cdr, status_node  # ROS packages only when reading a run

    bag_dir = Path(bag_dir)
    summary = {"bag": bag_name, "exit_codes": exit_codes or {}}
    if not bag_dir.exists():
        summary["error"] = f"no recording at {bag_dir}"
        return summary
    reader, store = _reader(bag_dir)
    times = defaultdict(list)
    step_p50, step_p99 = [], []
    tracking_counts = {}  # side -> counts of that hand's tracking node
    hand_measures = {}
    max_contacts = max_skin_contacts = 0
    max_contacts_hand, max_skin_hand = defaultdict(int), defaultdict(int)
    object_z = defaultdict(list)  # every object of the world's states: its lift (two_hand_lift lifts the big box)
    object_first, object_last = {}, {}  # name -> position [m] in the first / last state
    all_finite = True
    count = 0
    with reader:
        for conn, t_ns, raw in reader.messages():
            count += 1
            t = t_ns * 1e-9
            times[conn.topic].append(t)
            if conn.msgtype == POSE_ARRAY:  # tracker frames and bones, half of a run's messages:
                try:                        # read as numpy (a third of the summary's time as objects)
                    if not np.all(np.isfinite(pose_array_from_cdr(raw)[0])):
                        all_finite = False
                    continue
                except ValueError:
                    pass  # not what a PoseArray's CDR should be: the deserializer says what it is
            msg = store.deserialize_cdr(raw, conn.msgtype)
            if conn.msgtype == "sensor_msgs/msg/PointCloud2":
                cloud = _pointcloud_fields(msg)
                floats = [cloud[n] for n in cloud.dtype.names if cloud.dtype[n].kind == "f"]
                if any(not np.all(np.isfinite(f)) for f in floats):
                    all_finite = False
                if conn.topic == "/hand/contacts":
                    max_contacts = max(max_contacts, int(cloud.size))
                    hands = cloud["hand"] if "hand" in cloud.dtype.names else np.zeros(cloud.size, np.uint8)
                    skin = cloud["object"] == SKIN_OBJECT  # skin on skin (self_contact)
                    max_skin_contacts = max(max_skin_contacts, int(skin.sum()))
                    for code, side in enumerate(SIDES):  # the `hand` field: 0 right, 1 left
                        max_contacts_hand[side] = max(max_contacts_hand[side], int(np.sum(hands == code)))
                        max_skin_hand[side] = max(max_skin_hand[side], int(np.sum(skin & (hands == code))))
            elif not _finite(msg):
                all_finite = False
            if conn.topic == "/world/object_states":
                names = list(msg.joint_names)
                if msg.points:
                    for name, tf in zip(names, msg.points[0].transforms):
                        object_z[name].append(tf.translation.z)
                        object_last[name] = (tf.translation.x, tf.translation.y, tf.translation.z)
                        object_first.setdefault(name, object_last[name])
            elif conn.topic == "/diagnostics":
                for status in msg.status:
                    if status_node(status.name).startswith(TRACKING_NODE):  # the last report: final counts
                        values = {kv.key: kv.value for kv in status.values}
                        side = values.get("hand", "right")
                        tracking_counts[side] = {**tracking_counts.get(side, {}), **tracking_frame_counts(values)}
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
        rate = steady_rate_hz(ts)
        if rate is not None:
            rates[topic] = rate
    in_bag = input_frames(input_bag, legacy_side) if input_bag is not None else None
    if in_bag is not None:  # the bag played `repeat` times (softhand demo --repeat)
        in_bag = {side: n * repeat for side, n in in_bag.items()}
    hands, latencies, startups = {}, [], []
    bone_length = None  # the hand the run simulated (read from its /diagnostics once, when needed)
    for side in SIDES:
        tracker_t, bones_t = times.get(tracker_topic(side), []), times.get(hand_topic(side, "bones"), [])
        if not tracker_t and not bones_t and side not in tracking_counts and not (in_bag or {}).get(side):
            continue  # a hand this run did not have
        latency, startup_s = frame_latency_ms(tracker_t, bones_t)
        latencies.append(latency)
        startups.append(startup_s)
        frames = {"in_bag": (in_bag or {}).get(side) if in_bag is not None else None,
                  "recorded": len(tracker_t), **tracking_counts.get(side, {})}
        hands[side] = {
            "tracker_frames": {k: v for k, v in frames.items() if v is not None},
            "bones_messages": len(bones_t),
            "latency_ms_p50": float(np.percentile(latency, 50)) if len(latency) else float("nan"),
            "latency_ms_p99": float(np.percentile(latency, 99)) if len(latency) else float("nan"),
            "startup_s": startup_s,
            "max_contacts": max_contacts_hand.get(side, 0),
            "max_skin_contacts": max_skin_hand.get(side, 0),
        }
        if scores and tracker_t and bones_t:
            if bone_length is None:
                from softhand_sim.commands.fidelity import bone_lengths_of
                bone_length = bone_lengths_of(bag_dir)[0]
            hands[side]["lag_ms"], hands[side]["fidelity"] = _fidelity(bag_dir, side, bone_length)
    latency = np.concatenate(latencies) if latencies else np.empty(0)
    startup_s = float(np.nanmax(startups)) if startups and not np.all(np.isnan(startups)) else float("nan")
    size = sum(f.stat().st_size for f in bag_dir.rglob("*") if f.is_file())
    totals = {}
    for h in hands.values():
        for key, value in h["tracker_frames"].items():
            totals[key] = totals.get(key, 0) + value
    published = _published_frames(play_log) if play_log is not None else None
    frames = {"in_bag": totals.get("in_bag") if in_bag is not None else None, "published": published,
              **{k: v for k, v in totals.items() if k != "in_bag"}}
    ball_z = object_z.get(LIFT_OBJECT, [])
    summary.update({
        "tracker_frames": {k: v for k, v in frames.items() if v is not None},
        "hands": hands,
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
        "max_skin_contacts": max_skin_contacts,
        "ball_lift_m": float(max(ball_z) - ball_z[0]) if ball_z else 0.0,
        "ball_lifted": bool(ball_z and max(ball_z) - ball_z[0] >= 0.08),
        "object_lift_m": {name: float(max(z) - z[0]) for name, z in sorted(object_z.items())},
        "object_moved_m": {name: [float(b - a) for a, b in zip(object_first[name], last)]
                           for name, last in sorted(object_last.items())},
        "all_finite": all_finite,
    })
    return summary
