"""`softhand lag RUN`: how far, and by how much, the simulated hand trails the tracked hand (issue #17).

    softhand lag runs/<stamp>            # a demo run directory (its bag/) or any recording
    softhand lag RECORDING --json out.json

Reads a recording with one hand's /tracker/{side}/hand_joints, /hand/{side}/intermediate_bones and
/hand/{side}/bones (--hand, default right; rosbags, no ROS needed) and reports, for the
intermediate layer and for the simulated skeleton each:

* lag [ms]: the time shift tau that best aligns the layer with the tracked hand, i.e. minimises the
  mean squared difference between the layer at time t and the tracked hand at t - tau (tracked
  bones linearly interpolated between frames; frames further apart than MAX_GAP_S are not
  bridged). Separately for the 15 phalanx directions (each bone's +x axis; mean squared angle)
  and the palm position (mean squared distance); searched on a 1 ms grid over SHIFT_RANGE_MS and
  refined by a parabola through the best three; NaN for what the tracked hand hardly moves (the
  palm of a bag that only opens and closes the fingers: MIN_TRAVEL_M, MIN_TURN_RAD);
* the simulated skeleton's lag in free air (`sim_free_air`): the same, over the simulated states
  at least FREE_AIR_S from any contact of that hand (object or skin, /hand/contacts), where the
  hand follows its targets alone. A grasp bag's fingers move mostly while they close on an object,
  which holds them back (a best shift there is not a lag); this is the lag of the free-air motion
  around it. Left out when fewer than MIN_FREE_SAMPLES states are free (the hand in contact all
  along) or the recording has no /hand/contacts;
* the simulated skeleton's lag off tracker dropouts (`sim_off_dropouts`, only for a recording
  with one): the free-air states (all of them without /hand/contacts) outside every tracker
  dropout and FREE_AIR_S after it. A dropout is an interval between tracked frames over
  DROPOUT_FACTOR times the median one; the tracked hand is drawn straight across it (or not at
  all, past MAX_GAP_S), and a tracker that finds the hand again often puts it somewhere else: the
  Leap recording leap_grab loses two frames 0.34 s before its end and puts the palm 25 mm on,
  and the hand's response to that jump sets the whole run's best shift (the states before it:
  phalanx / palm lag 2.3 / 4.9 ms, offline with the node set's transport delays, against 11.4 /
  16.2 over the run). `dropouts` in the report gives each one's time, length and palm jump;
* errors at zero shift: phalanx direction angle, palm position and palm orientation (median /
  p95 / max), and the phalanx angle p95 at the best shift (what is left once the lag is removed);
* tracker frames: recorded, and that hand's tracking node's received / accepted / rejected (its
  last /diagnostics).

Time base: header stamps (docs/INTERFACE.md "Stamps and clocks": tracker frames carry their capture
time on the run's clock, outputs the time of their state). A recording whose tracker stamps are
not on the outputs' clock (a replay with `stamps: recorded`, or a run made before issue #17) is
measured by receive times instead, and the report says so (`time_base`).

The tracked bones are the tracker adapter's (softhand_tracking.adapter, default configuration:
the demo's tracker_to_world is the identity), so tracked and simulated bones are compared in the
same frames. Self-contained: the fidelity report of positions and fingertips is another command.
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from softhand_sim.topics import hand_topic, tracker_topic

LAYER_TOPICS = {"intermediate": "intermediate_bones", "sim": "bones"}  # layer -> per-side topic name
REPORT_LAYERS = (*LAYER_TOPICS, "sim_free_air", "sim_off_dropouts")  # the layers of a report, in its order
# as printed, where not the key
LAYER_NAMES = {"sim_free_air": "sim in free air", "sim_off_dropouts": "sim off dropouts"}
SHIFT_RANGE_MS = (-60.0, 250.0)  # [ms] lags searched (negative: the layer leads)
COARSE_MS = 5.0                  # [ms] the search's first grid; then 1 ms steps around the best
MAX_GAP_S = 0.05                 # [s] tracked frames further apart are not interpolated across
CLOCK_MISMATCH_S = 1.0           # [s] tracker vs output stamps further apart: not one clock
# A lag is only defined for what moves (the best shift of a still signal is that of the noise or
# of the simulated hand's own wobble about it): the phalanx lag needs the tracked phalanx
# directions to spread MIN_TURN_RAD from their mean, the palm's the tracked palm MIN_TRAVEL_M
# (`spread`; else NaN). The same rule holds for the live lag of a 2 s window (live_lag.py).
MIN_TURN_RAD = 0.1      # [rad] spread of the tracked phalanx directions
SMOOTH = 7              # tracked frames averaged before the spread is taken
MIN_TRAVEL_M = 0.01     # [m] spread of the tracked palm position
CONTACTS_TOPIC, CONTACTS_TYPE = "/hand/contacts", "sensor_msgs/msg/PointCloud2"
FREE_AIR_S = 0.3        # [s] a state this far in time from any contact of its hand is in free air
MIN_FREE_SAMPLES = 30   # free-air states needed for a free-air lag (half a second at 60 Hz)
DROPOUT_FACTOR = 2.5    # a tracked frame interval this many times the median one is a dropout (one
                        # frame lost is not: 2x, the ordinary jitter of a Leap at ~115 Hz)


@dataclass
class Series:
    """Bone poses over time: t (n,) [s] ascending, poses (n, 16, 7) [m, quaternion x y z w]."""

    t: np.ndarray
    poses: np.ndarray


def quat_rotate_x(q: np.ndarray) -> np.ndarray:
    """(..., 3) the unit +x axis rotated by quaternions q (..., 4) [x y z w] (each bone's direction)."""
    x, y, z, w = (q[..., i] for i in range(4))
    return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)], axis=-1)


def quat_angle(qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """(...,) angle [rad] of the rotation between unit quaternions qa and qb (..., 4)."""
    d = np.abs(np.sum(qa * qb, axis=-1))
    return 2.0 * np.arccos(np.clip(d, 0.0, 1.0))


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(...,) angle [rad] between vectors a and b (..., 3)."""
    cross = np.linalg.norm(np.cross(a, b), axis=-1)
    return np.arctan2(cross, np.sum(a * b, axis=-1))


def _interp(ref: Series, t: np.ndarray, ref_dirs: np.ndarray | None = None):
    """Tracked phalanx directions (m, 15, 3), palm positions (m, 3), palm quaternions (m, 4) at times
    t (m,), and a mask of the times that lie inside the tracked series between frames at most
    MAX_GAP_S apart (values elsewhere are meaningless). ref_dirs: the tracked phalanx directions
    (n, 15, 3) if already computed (the search calls this once per shift)."""
    i = np.searchsorted(ref.t, t, side="right")
    ok = (i > 0) & (i < ref.t.size)
    i = np.clip(i, 1, ref.t.size - 1)
    t0, t1 = ref.t[i - 1], ref.t[i]
    ok &= (t1 - t0) <= MAX_GAP_S
    w = np.clip((t - t0) / np.maximum(t1 - t0, 1e-12), 0.0, 1.0)
    p0, p1 = ref.poses[i - 1], ref.poses[i]
    if ref_dirs is None:
        d0, d1 = quat_rotate_x(p0[:, 1:, 3:]), quat_rotate_x(p1[:, 1:, 3:])
    else:
        d0, d1 = ref_dirs[i - 1], ref_dirs[i]
    dirs = (1 - w)[:, None, None] * d0 + w[:, None, None] * d1
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    palm = (1 - w)[:, None] * p0[:, 0, :3] + w[:, None] * p1[:, 0, :3]
    q0, q1 = p0[:, 0, 3:], p1[:, 0, 3:]
    q1 = np.where(np.sum(q0 * q1, axis=-1, keepdims=True) < 0, -q1, q1)  # same hemisphere: nlerp
    q = (1 - w)[:, None] * q0 + w[:, None] * q1
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return dirs, palm, q, ok


def _refine(shifts: np.ndarray, cost: np.ndarray) -> float:
    """The minimising shift, refined by a parabola through the best grid point and its neighbours."""
    k = int(np.nanargmin(cost))
    if 0 < k < len(cost) - 1 and np.all(np.isfinite(cost[k - 1:k + 2])):
        c0, c1, c2 = cost[k - 1:k + 2]
        den = c0 - 2 * c1 + c2
        if den > 0:
            return float(shifts[k] + 0.5 * (c0 - c2) / den * (shifts[1] - shifts[0]))
    return float(shifts[k])


def _stats(x: np.ndarray, scale: float) -> dict:
    if x.size == 0:
        return {"median": float("nan"), "p95": float("nan"), "max": float("nan")}
    return {"median": scale * float(np.median(x)), "p95": scale * float(np.percentile(x, 95)),
            "max": scale * float(np.max(x))}


def spread(ref: Series) -> tuple[float, float]:
    """(phalanx spread [rad], palm spread [m]) of tracked bones: the 90th percentile of each phalanx
    direction's angle from its mean (after a moving average over SMOOTH frames: tracker noise of
    1.5 mm alone then spreads them about 4 degrees, not 9), the median over the phalanxes; and the
    90th percentile of the palm's distance from its mean position."""
    dirs = quat_rotate_x(ref.poses[:, 1:, 3:])                       # (n, 15, 3)
    if len(dirs) > SMOOTH:  # a moving average first: noise alone then spreads them ~4 deg, not ~9
        kernel = np.ones(SMOOTH) / SMOOTH
        dirs = np.apply_along_axis(lambda x: np.convolve(x, kernel, mode="valid"), 0, dirs)
        dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    mean = dirs.mean(axis=0)
    mean /= np.linalg.norm(mean, axis=-1, keepdims=True)
    angles = np.arccos(np.clip(np.sum(dirs * mean, axis=-1), -1.0, 1.0))
    palm = ref.poses[:, 0, :3]
    return (float(np.median(np.percentile(angles, 90, axis=0))),
            float(np.percentile(np.linalg.norm(palm - palm.mean(axis=0), axis=-1), 90)))


def lag_text(ms, unit: str = "") -> str:
    """A lag [ms] as printed (with `unit` after a number): "still" where it is not defined (NaN,
    or null from JSON: that part of the tracked hand hardly moved, `spread`)."""
    return "still" if ms is None or not np.isfinite(ms) else f"{ms:.1f}{unit}"


def layer_lag(ref: Series, out: Series, shift_range_ms=SHIFT_RANGE_MS, ref_spread=None) -> dict:
    """Lag and error of one layer `out` against the tracked bones `ref` (module docstring).
    ref_spread: spread(ref) when the caller has it (every layer of one recording shares its ref).

    Returns lag_phalanx_ms, lag_palm_ms (NaN where the tracked phalanxes / palm hardly move:
    `spread`, reported as tracked_turn_deg, tracked_travel_mm), phalanx_deg / palm_mm / palm_deg
    (median, p95, max at zero shift), phalanx_deg_p95_at_lag, and samples (the output samples
    compared at zero shift)."""
    lo, hi = shift_range_ms
    out_dirs = quat_rotate_x(out.poses[:, 1:, 3:])
    out_palm = out.poses[:, 0, :3]
    # only output samples comparable at every shift: the cost curves then compare like with like
    common = np.ones(out.t.size, dtype=bool)
    for s in (lo, hi, 0.0):
        common &= _interp(ref, out.t - 1e-3 * s)[3]
    t, cache = out.t[common], {}
    ref_dirs = quat_rotate_x(ref.poses[:, 1:, 3:])

    def cost(s):
        """(phalanx, palm) mean squared error at shift s [ms]; NaN where too few samples compare."""
        if s not in cache:
            dirs, palm, _, ok = _interp(ref, t - 1e-3 * s, ref_dirs)
            cache[s] = (np.nan, np.nan) if ok.sum() < 0.9 * t.size else (
                np.mean(_angle(out_dirs[common][ok], dirs[ok]) ** 2),
                np.mean(np.sum((out_palm[common][ok] - palm[ok]) ** 2, axis=-1)))
        return cache[s]

    res = {"samples": int(common.sum())}
    if common.sum() < 3:
        return {**res, "lag_phalanx_ms": float("nan"), "lag_palm_ms": float("nan")}
    # a 5 ms grid over the range, then 1 ms steps around each curve's best (a tenth of the
    # evaluations of a 1 ms grid over the range; the curves are smooth on that scale)
    coarse = np.arange(lo, hi + 0.5, COARSE_MS)
    for i, key in enumerate(("lag_phalanx_ms", "lag_palm_ms")):
        c = np.array([cost(float(s))[i] for s in coarse])
        if not np.any(np.isfinite(c)):
            return {**res, "lag_phalanx_ms": float("nan"), "lag_palm_ms": float("nan")}
        best = coarse[int(np.nanargmin(c))]
        fine = np.arange(max(lo, best - COARSE_MS), min(hi, best + COARSE_MS) + 0.5, 1.0)
        res[key] = _refine(fine, np.array([cost(float(s))[i] for s in fine]))
    turn, travel = spread(ref) if ref_spread is None else ref_spread
    res["tracked_turn_deg"], res["tracked_travel_mm"] = float(np.degrees(turn)), 1e3 * travel
    if turn < MIN_TURN_RAD:
        res["lag_phalanx_ms"] = float("nan")
    if travel < MIN_TRAVEL_M:
        res["lag_palm_ms"] = float("nan")
    dirs, palm, q, ok = _interp(ref, out.t)
    ang = np.degrees(_angle(out_dirs[ok], dirs[ok]))
    res["phalanx_deg"] = _stats(ang.reshape(-1), 1.0)
    res["palm_mm"] = _stats(np.linalg.norm(out_palm[ok] - palm[ok], axis=-1), 1e3)
    res["palm_deg"] = _stats(quat_angle(out.poses[ok, 0, 3:], q[ok]), np.degrees(1.0))
    res["phalanx_deg_p95_at_lag"] = float("nan")
    if np.isfinite(res["lag_phalanx_ms"]):
        dirs, _, _, ok = _interp(ref, out.t - 1e-3 * res["lag_phalanx_ms"])
        res["phalanx_deg_p95_at_lag"] = _stats(np.degrees(_angle(out_dirs[ok], dirs[ok])).reshape(-1), 1.0)["p95"]
    return res


def tracked_bones(joints: np.ndarray, t: np.ndarray, hand: str = "right") -> Series:
    """The adapter's bone poses of tracker frames (n, 26, 3+) at t (n,); rejected frames left out."""
    from softhand_tracking.adapter import AdapterConfig, TrackerAdapter

    adapter = TrackerAdapter(AdapterConfig(hand=hand))
    keep, poses = [], []
    for i, j in enumerate(joints):
        p = adapter.convert(np.asarray(j)[:, :3])
        if p is not None:
            keep.append(i)
            poses.append(p)
    return Series(np.asarray(t, float)[keep], np.asarray(poses).reshape(-1, 16, 7))


def layer_topics(hand: str) -> dict:
    """{layer: topic} of hand `hand`: its intermediate and simulated bones."""
    return {name: hand_topic(hand, topic) for name, topic in LAYER_TOPICS.items()}


def read_run(path, hand: str = "right"):
    """{topic: (header stamps [s], receive times [s], poses (n, k, 7))} of hand `hand`'s tracker and
    layer topics, and its tracking node's last frame counts, from a recording (or a run dir with
    bag/)."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    from softhand_sim.commands.run_summary import tracking_frame_counts
    from softhand_sim.ros.msgs import pose_array_from_cdr, status_node

    path = recording_dir(path)
    store = get_typestore(Stores.ROS2_JAZZY)
    rows = {t: ([], [], []) for t in (tracker_topic(hand), *layer_topics(hand).values())}
    counts = {}
    with Reader(path) as reader:
        conns = [c for c in reader.connections if c.topic in rows or c.topic == "/diagnostics"]
        # (rosbags reads every connection when given none)
        for conn, t_ns, raw in reader.messages(connections=conns) if conns else ():
            if conn.topic == "/diagnostics":
                for status in store.deserialize_cdr(raw, conn.msgtype).status:
                    values = {kv.key: kv.value for kv in status.values}
                    if status_node(status.name).startswith("tracking_node") and values.get("hand", "right") == hand:
                        counts.update(tracking_frame_counts(values))
                continue
            pose_rows, stamp_ns, _frame = pose_array_from_cdr(raw)  # numpy, not message objects
            stamps, recv, poses = rows[conn.topic]
            stamps.append(stamp_ns * 1e-9)
            recv.append(t_ns * 1e-9)
            poses.append(pose_rows)
    out = {}
    for topic, (stamps, recv, poses) in rows.items():
        if poses and len({p.shape for p in poses}) == 1:
            out[topic] = (np.asarray(stamps), np.asarray(recv), np.asarray(poses))
    return out, counts


def recording_dir(path) -> Path:
    """The rosbag2 directory of a recording or of a run directory (its bag/)."""
    path = Path(path)
    return path / "bag" if (path / "bag" / "metadata.yaml").is_file() else path


@dataclass
class ContactSteps:
    """One hand's contacts per simulation step of a recording's /hand/contacts: header stamps [s],
    receive times [s], the hand's contacts and, of them, skin on skin (sim parameter self_contact)."""

    stamp: np.ndarray
    recv: np.ndarray
    count: np.ndarray
    skin: np.ndarray


def contact_steps(path, hand: str = "right") -> ContactSteps | None:
    """The ContactSteps of hand `hand` (its `hand` field; a cloud recorded before two hands is one
    right hand's), or None when the recording has no /hand/contacts."""
    from softhand_sim.physics.hands import HAND_CODE
    from softhand_sim.ros.bagio import BagError, deserialize, read_topic
    from softhand_sim.ros.msgs import contacts_cloud_to_numpy, stamp_to_seconds
    from softhand_sim.topics import SKIN_OBJECT

    try:
        data = read_topic(recording_dir(path), CONTACTS_TOPIC, CONTACTS_TYPE)
    except BagError:
        return None
    stamp, count, skin = [], [], []
    for raw in data.payloads:
        msg = deserialize(raw, CONTACTS_TYPE)
        c = contacts_cloud_to_numpy(msg)
        mine = c["hand"] == HAND_CODE[hand]
        stamp.append(stamp_to_seconds(msg.header.stamp))
        count.append(int(mine.sum()))
        skin.append(int(np.sum(mine & (c["object"] == SKIN_OBJECT))))
    return ContactSteps(np.asarray(stamp), 1e-9 * np.asarray(data.stamps_ns, np.float64),
                        np.asarray(count), np.asarray(skin))


def free_air(t, contact_t, contact_count, margin=FREE_AIR_S) -> np.ndarray:
    """Mask of the times t [s] with no step of a nonzero contact_count within `margin` [s] (the
    contact messages at contact_t [s])."""
    touch = np.sort(np.asarray(contact_t, float)[np.asarray(contact_count) > 0])
    t = np.asarray(t, float)
    if not touch.size:
        return np.ones(t.size, dtype=bool)
    i = np.searchsorted(touch, t)
    before = np.where(i > 0, t - touch[np.maximum(i - 1, 0)], np.inf)
    after = np.where(i < touch.size, touch[np.minimum(i, touch.size - 1)] - t, np.inf)
    return (before > margin) & (after > margin)


def dropouts(ref: Series) -> list[dict]:
    """The tracker dropouts of the tracked bones `ref` (module docstring): each one's start and end
    [s] (the frames either side), its length [ms] and how far the palm moved across it [mm]."""
    if ref.t.size < 3:
        return []
    dt = np.diff(ref.t)
    gaps = np.flatnonzero(dt > DROPOUT_FACTOR * np.median(dt))
    palm = ref.poses[:, 0, :3]
    return [{"start_s": float(ref.t[i]), "end_s": float(ref.t[i + 1]),
             "length_ms": round(1e3 * float(dt[i]), 1),
             "palm_jump_mm": round(1e3 * float(np.linalg.norm(palm[i + 1] - palm[i])), 1)}
            for i in gaps]


def off_dropouts(t, gaps, margin=FREE_AIR_S) -> np.ndarray:
    """Mask of the times t [s] outside every dropout of `gaps` (`dropouts`) and `margin` [s] after it."""
    t = np.asarray(t, float)
    keep = np.ones(t.size, dtype=bool)
    for g in gaps:
        keep &= (t <= g["start_s"]) | (t > g["end_s"] + margin)
    return keep


def _sorted(t, poses) -> Series:
    order = np.argsort(t, kind="stable")
    return Series(np.asarray(t)[order], np.asarray(poses)[order])


_READ = object()  # lag_report's contacts: read them from the recording


def lag_report(path, hand: str = "right", time_base: str = "auto", contacts=_READ) -> dict:
    """The report of a recording (module docstring): {time_base, frames, intermediate, sim, ...}.

    time_base: "stamp" (header stamps), "receive" (recording times) or "auto" (stamps when the
    tracker's and the outputs' are on one clock, else receive times). contacts: the hand's
    contact_steps when the caller has them (None: the recording has none)."""
    data, counts = read_run(path, hand)
    if contacts is _READ:
        contacts = contact_steps(path, hand)
    tracker, layers = tracker_topic(hand), layer_topics(hand)
    if tracker not in data:
        raise ValueError(f"{path}: no {tracker} in the recording")
    tr_stamp, tr_recv, joints = data[tracker]
    report = {"frames": {"recorded": int(len(tr_stamp)), **counts}}
    if time_base == "auto":
        # one clock: every topic's stamps sit near the recorder's receive times. (Comparing the
        # medians of the tracker's and the outputs' stamps instead took a long or repeated run,
        # whose outputs go on after the last frame, for two clocks.)
        offsets = [np.median(np.abs(data[t][1] - data[t][0])) for t in (tracker, *layers.values()) if t in data]
        time_base = "stamp" if max(offsets) < CLOCK_MISMATCH_S else "receive"
    col = 0 if time_base == "stamp" else 1
    report["time_base"] = time_base
    ref = tracked_bones(joints, (tr_stamp, tr_recv)[col], hand)
    ref = _sorted(ref.t, ref.poses)
    report["frames"]["valid"] = int(ref.t.size)
    report["first_frame_s"] = float(ref.t[0]) if ref.t.size else 0.0  # the times below are on this clock
    if ref.t.size < 2:  # nothing to compare with (no valid tracker frame, or one)
        return report
    ref_spread = spread(ref)
    for name, topic in layers.items():
        if topic in data:
            s = data[topic]
            report[name] = layer_lag(ref, _sorted(s[col], s[2]), ref_spread=ref_spread)
            report[name]["messages"] = int(len(s[0]))
    s = data.get(layers["sim"])
    free = ref_free = True  # without /hand/contacts every state counts as free (the masks below)
    if s is not None and contacts is not None:
        c_t = (contacts.stamp, contacts.recv)[col]
        free, ref_free = free_air(s[col], c_t, contacts.count), free_air(ref.t, c_t, contacts.count)
        if free.sum() >= MIN_FREE_SAMPLES:
            report["sim_free_air"] = _states_lag(ref, s[col], s[2], free, ref_free)
    gaps = dropouts(ref)
    report["frames"]["dropouts"] = len(gaps)
    if gaps:
        report["dropouts"] = gaps
    if gaps and s is not None:
        keep, ref_keep = off_dropouts(s[col], gaps) & free, off_dropouts(ref.t, gaps) & ref_free
        if keep.sum() >= MIN_FREE_SAMPLES:
            report["sim_off_dropouts"] = _states_lag(ref, s[col], s[2], keep, ref_keep)
    return report


def _states_lag(ref: Series, t, poses, keep, ref_keep) -> dict:
    """layer_lag of the simulated states `keep` (masks of t, poses) with their count (`messages`).
    Its own stillness rule: what the tracked hand moves over ref_keep, the frames of those windows."""
    ref_spread = spread(Series(ref.t[ref_keep], ref.poses[ref_keep]))
    r = layer_lag(ref, _sorted(t[keep], poses[keep]), ref_spread=ref_spread)
    r["messages"] = int(keep.sum())
    return r


def format_report(r: dict, title: str = "") -> str:
    lines = [f"lag report {title} (time base: {r['time_base']})".replace("  ", " "),
             "  tracker frames: " + ", ".join(f"{k} {v}" for k, v in r["frames"].items())]
    if r.get("dropouts"):
        t0 = r.get("first_frame_s", 0.0)
        longest = max(r["dropouts"], key=lambda g: g["length_ms"])
        lines.append(f"  tracker dropouts: {len(r['dropouts'])}, the longest {longest['length_ms']:.0f} ms "
                     f"at {longest['start_s'] - t0:.2f} s into the recording, the palm "
                     f"{longest['palm_jump_mm']:.1f} mm on across it")
    for name in REPORT_LAYERS:
        if name not in r:
            continue
        x = r[name]
        if "phalanx_deg" not in x:
            lines.append(f"  {name}: not enough overlapping samples")
            continue
        pd, pm, pa = x["phalanx_deg"], x["palm_mm"], x["palm_deg"]
        label = LAYER_NAMES.get(name, name)
        lines.append(f"  {label:16s} lag: phalanx {lag_text(x['lag_phalanx_ms'], ' ms'):>8s}, palm "
                     f"{lag_text(x['lag_palm_ms'], ' ms'):>8s} | "
                     f"phalanx {pd['median']:.1f}/{pd['p95']:.1f}/{pd['max']:.1f} deg (median/p95/max; p95 at lag "
                     f"{x['phalanx_deg_p95_at_lag']:.1f}), palm {pm['median']:.1f}/{pm['p95']:.1f}/{pm['max']:.1f} mm, "
                     f"{pa['median']:.1f}/{pa['p95']:.1f}/{pa['max']:.1f} deg")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(prog="softhand lag", description="Lag and error of the intermediate and simulated "
                                 "hand against the tracked hand in a recording (a demo run directory or a bag).")
    ap.add_argument("run", help="run directory (with bag/) or rosbag2 recording")
    ap.add_argument("--hand", default="right", choices=("right", "left"))
    ap.add_argument("--time-base", default="auto", choices=("auto", "stamp", "receive"),
                    help="pair messages by header stamps or receive times (auto: stamps when on one clock)")
    ap.add_argument("--json", help="also write the report here")
    args = ap.parse_args(argv)
    try:
        r = lag_report(args.run, args.hand, args.time_base)
    except (ValueError, FileNotFoundError) as exc:
        print(f"softhand lag: error: {exc}", file=sys.stderr)
        return 1
    print(format_report(r, str(args.run)))
    if args.json:
        Path(args.json).write_text(json.dumps(r, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
