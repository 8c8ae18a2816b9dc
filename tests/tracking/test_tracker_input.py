"""Bad tracker input on /tracker/right/hand_joints (issue #10 item 1), through real tracking_node and
sim_node processes: every malformed frame is rejected, counted by reason in /diagnostics and logged
at a limited rate; nothing non-finite is ever published; a 5,000 msg/s burst and a 10,000-message
fuzz leave both nodes up; valid frames afterwards are tracked again. (Solver guard rejections of sim_node are printed, not
asserted: the burst replays the grasp 16x faster than real, legitimately fast targets.)
"""
import re
import time

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Pose, PoseArray
from rclpy.serialization import deserialize_message, serialize_message

from tests.support.rosproc import RosGraph, latest_node_diagnostics, node_diagnostics
from softhand_sim.ros import msgs as rm
from softhand_tracking.adapter import _SEG_DIST, _SEG_PROX
from softhand_sim.scenarios.tracker_bags import sample
from softhand_sim.topics import hand_topic, tracker_topic

PACED_HZ = 100.0   # categorized bad frames, paced (valid and bad alternate)
# The subscription is best effort (sensor QoS, depth 5): on a loaded 2-core machine a node stalled
# for > 50 ms drops frames in DDS before it sees them (measured: 0-40 % of a category). So counts
# are checked as: never more than sent, at least this share, and no other reason moving.
MIN_DELIVERED = 0.5
PER_CATEGORY = 20
BURST_N, BURST_HZ = 5000, 5000.0
FUZZ_N = 10_000
FUZZ_HZ = 2500.0  # node-level fuzz rate: unpaced (~80,000/s) DDS drops all but a few dozen


def frames():
    """(stamps [s], joints (n, 26, 7)) of a recorded-like hand hovering and grasping (valid frames)."""
    stamps_ns, joints, _ = sample("grasp_short")
    return stamps_ns * 1e-9, joints


_TEMPLATES = {}


def msg(joints, t):
    """Serialized PoseArray (CDR bytes, published as is) of any rows, NaN and inf included (the
    library's builder refuses those, rightly). Built by patching a template serialized by rclpy:
    the poses are the last 56 n bytes, the stamp follows the 4-byte encapsulation header; fast
    enough to make 15,000 frames in well under a second."""
    rows = np.asarray(joints, dtype=np.float64).reshape(-1, 7)
    n = len(rows)
    if n not in _TEMPLATES:
        template = PoseArray()
        template.header.frame_id = "world"
        template.poses = [Pose() for _ in range(n)]
        _TEMPLATES[n] = bytearray(serialize_message(template))
    out = bytearray(_TEMPLATES[n])
    ns = int(round(t * 1e9))
    out[4:12] = np.array([ns // 10**9, ns % 10**9], dtype="<u4").tobytes()
    if n:
        out[len(out) - 56 * n:] = rows.astype("<f8").tobytes()
    return bytes(out)


def test_raw_frame_builder_round_trips():
    """The CDR bytes built for the tests decode to the rows and stamp they were built from."""
    rows = np.arange(26 * 7, dtype=float).reshape(26, 7)
    rows[3, 1] = np.nan
    back = deserialize_message(msg(rows, 12.5), PoseArray)
    assert rm.stamp_to_seconds(back.header.stamp) == 12.5 and back.header.frame_id == "world"
    assert np.array_equal(rm.pose_array_to_numpy(back), rows, equal_nan=True)
    assert len(deserialize_message(msg(rows[:0], 1.0), PoseArray).poses) == 0


def bad_frame(kind, good, rng):
    """A frame of `good` (26, 7) broken in one way: the adapter reason it must be counted under."""
    j = good.copy()
    if kind == "joint_count":
        return j[:rng.choice([0, 1, 25])] if rng.random() < 0.7 else np.vstack([j, j[:1]]), "joint_count"
    if kind == "non_finite":
        j[rng.integers(26), rng.integers(3)] = rng.choice([np.nan, np.inf, -np.inf])
        return j, "non_finite"
    if kind == "huge":  # the whole hand (or one joint) 1e9 m away
        if rng.random() < 0.5:
            j[:, :3] += 1e9
        else:
            j[rng.integers(26), :3] = rng.choice([-1e9, 1e9])
        return j, "out_of_range"
    if kind == "zero_bone":  # a joint on top of its parent
        b = rng.integers(16)
        j[_SEG_DIST[b], :3] = j[_SEG_PROX[b], :3]
        return j, "bone_length"
    if kind == "absurd_bone":  # a finger joint 0.5 m away: the bone is >= 0.43 m long
        b = 1 + rng.integers(15)
        direction = rng.normal(size=3)
        j[_SEG_DIST[b], :3] += 0.5 * direction / np.linalg.norm(direction)
        return j, "bone_length"
    raise ValueError(kind)


KINDS = ("joint_count", "non_finite", "huge", "zero_bone", "absurd_bone")
REASON = {"joint_count": "joint_count", "non_finite": "non_finite", "huge": "out_of_range",
          "zero_bone": "bone_length", "absurd_bone": "bone_length"}


def tracking_diag(diags):
    return latest_node_diagnostics(diags.msgs, "tracking_node")


def sim_diag(diags):
    return latest_node_diagnostics(diags.msgs, "sim_node")


def counts(diags):
    d = tracking_diag(diags)
    return {k: int(v) for k, v in d.items() if k.startswith("rejected_") or k.startswith("frames_")
            or k == "holds"}


def settle_diag(g, diags, node):
    """Counters from a tracking_node /diagnostics issued after everything sent so far was processed:
    two fresh reports, the last two with the same frames_received (the node's queue, up to 1000
    frames deep, is drained; a fixed wait was too short after a burst on a loaded machine)."""
    def received():
        return [int(v["frames_received"]) for v in node_diagnostics(diags.msgs, "tracking_node")]
    n = len(received())
    g.wait_until(lambda: len(r := received()) >= n + 2 and r[-1] == r[-2], 30,
                 "tracking_node diagnostics with its frame count settled", node)
    return counts(diags)


def delta(after, before):
    return {k: after[k] - before.get(k, 0) for k in after if after[k] != before.get(k, 0)}


def test_fuzz_10000_frames_exact_counts_in_the_loop():
    """Library level, no transport loss: 10,000 random malformed frames (all seven defects, stamp ones
    included; a valid frame before each stamp defect and every 10th frame), into TrackingLoop stepped at 250 Hz: every one is counted
    under exactly its reason (counts equal to those sent), every valid one accepted, and no step
    output is ever non-finite or farther than 3 m from the origin."""
    from softhand_tracking.loop import TrackingLoop

    rng = np.random.default_rng(7)
    stamps, joints = frames()
    loop = TrackingLoop()
    all_kinds = KINDS + ("duplicate_stamp", "old_stamp")
    expected = {r: 0 for r in loop.adapter.rejected}
    t, worst, valid = 1.0, 0.0, 0
    for i in range(FUZZ_N):
        j = joints[i % len(joints)]
        t += 0.004
        kind = all_kinds[rng.integers(len(all_kinds))]
        if i % 10 == 0 or kind in ("duplicate_stamp", "old_stamp"):  # tracking, not holding
            assert loop.on_tracker(j[:, :3] if i % 2 else j, t, t)
            valid += 1
        if kind in ("duplicate_stamp", "old_stamp"):
            tb, bad, reason = (t if kind == "duplicate_stamp" else t - rng.uniform(0.001, 1.0)), j, "stamp_order"
        else:
            (bad, reason), tb = bad_frame(kind, j, rng), t + 0.001
        assert not loop.on_tracker(bad, t + 0.001, tb)
        expected[reason] += 1
        out = loop.step(t + 0.002)
        assert np.all(np.isfinite(out))
        worst = max(worst, float(np.abs(out[:, :3]).max()))
    print(f"loop fuzz: {FUZZ_N} malformed frames, counted {loop.adapter.rejected}, accepted {loop.adapter.accepted}")
    assert loop.adapter.rejected == expected
    assert loop.adapter.accepted == valid
    assert worst < 3.0


@pytest.mark.ros
@pytest.mark.flaky(reruns=1, reruns_delay=2)  # real DDS timing on a shared 2-core machine
def test_bad_frames_rejected_counted_logged_never_published(ros_env):
    """tracking_node + sim_node. (1) Paced categorized bad frames (wrong count, NaN/inf, 1e9 m, zero and
    absurd bones, duplicated and out-of-order stamps), each between two valid frames: each is counted
    under its own reason (>= MIN_DELIVERED of those sent arrive over best effort, never more than sent, no other
    reason moves) and the valid ones are accepted (same delivery bound). (2) 5,000 valid frames at 5,000/s. (3) 10,000 random
    malformed frames as fast as possible: frames_accepted does not move. Then valid frames are tracked
    again. Throughout: both nodes stay up, every /hand/right/intermediate_bones and /hand/right/bones is finite,
    sim_node rejected no intermediate bones, and the rejection log is rate limited."""
    rng = np.random.default_rng(10)
    stamps, joints = frames()
    n_valid = len(joints)
    k = 0  # index of the next valid frame (and its stamp); the stamps keep increasing
    t_base = 0.0

    def next_valid():
        nonlocal k, t_base
        if k == n_valid:
            k, t_base = 0, t_base + stamps[-1] - stamps[0] + 0.01
        j, t = joints[k], t_base + stamps[k]
        k += 1
        return j, t

    with RosGraph(ros_env) as g:
        inter = g.listen(hand_topic("right", "intermediate_bones"), PoseArray)
        sim_bones = g.listen(hand_topic("right", "bones"), PoseArray)
        diags = g.listen("/diagnostics", DiagnosticArray)
        pub = g.publisher(tracker_topic("right"), PoseArray)
        tracking = g.start(["softhand-tracking"])
        sim = g.start(["softhand-sim"])
        g.wait_matched(pub, proc=tracking, timeout=60)
        g.wait_until(lambda: tracking_diag(diags) and sim_diag(diags), 60, "diagnostics of both nodes", sim)

        # valid frames at 100 Hz: the hand is tracked and simulated
        for _ in range(50):
            pub.publish(msg(*next_valid()))
            time.sleep(0.01)
        g.wait_until(lambda: len(sim_bones) >= 5, 30, "/hand/right/bones", sim)
        base = settle_diag(g, diags, tracking)
        assert base["frames_accepted"] >= 45 and base["frames_rejected"] == 0, base

        # (1) categorized, paced: valid, bad, valid, bad, ... at PACED_HZ
        sent_bad, sent_valid = {}, 0
        for kind in KINDS + ("duplicate_stamp", "old_stamp"):
            for _ in range(PER_CATEGORY):
                j, t = next_valid()
                pub.publish(msg(j, t))
                sent_valid += 1
                time.sleep(1.0 / PACED_HZ)
                if kind == "duplicate_stamp":
                    bad, reason, tb = j, "stamp_order", t
                elif kind == "old_stamp":
                    bad, reason, tb = j, "stamp_order", t - 0.05
                else:
                    (bad, reason), tb = bad_frame(kind, j, rng), t + 0.001
                pub.publish(msg(bad, tb))
                sent_bad[reason] = sent_bad.get(reason, 0) + 1
                time.sleep(1.0 / PACED_HZ)
        after = settle_diag(g, diags, tracking)
        d = delta(after, base)
        print("categorized: sent bad", sent_bad, "valid", sent_valid, "-> diagnostics delta", d)
        for reason, n in sent_bad.items():
            assert MIN_DELIVERED * n <= d.get(f"rejected_{reason}", 0) <= n, (reason, n, d)
        moved = {k for k in d if k.startswith("rejected_")}
        assert moved == {f"rejected_{r}" for r in sent_bad}, d
        assert d["frames_rejected"] == sum(d[f"rejected_{r}"] for r in sent_bad)
        # a stall of the node beyond tracker_timeout (a loaded machine) enters a hold, and after a
        # hold any stamp is taken by design (loop.TrackingLoop.on_tracker: a restarted tracker
        # resyncs): a duplicate or old stamp right after one is accepted. One such frame made this
        # fail once in a make test (141 accepted of 140 valid sent)
        assert MIN_DELIVERED * sent_valid <= d["frames_accepted"] <= sent_valid + d.get("holds", 0), f"{d}"

        # (2) burst: 5,000 valid frames at 5,000/s
        burst = [msg(*next_valid()) for _ in range(BURST_N)]
        n_inter = len(inter)
        t0 = time.monotonic()
        for i, m in enumerate(burst):
            pub.publish(m)
            lag = t0 + (i + 1) / BURST_HZ - time.monotonic()
            if lag > 0:
                time.sleep(lag)
        burst_s = time.monotonic() - t0
        burst_inter = len(inter) - n_inter
        print(f"burst: {BURST_N} frames in {burst_s:.2f} s ({BURST_N / burst_s:.0f}/s); "
              f"{burst_inter} intermediate bones meanwhile ({burst_inter / burst_s:.0f} Hz)")
        assert burst_inter > 0.4 * 250 * burst_s  # the loop kept publishing through the burst
        before_fuzz = settle_diag(g, diags, tracking)
        d = delta(before_fuzz, after)
        print("burst: diagnostics delta", d)
        assert d.get("frames_rejected", 0) == 0 and 0 < d["frames_accepted"] <= BURST_N

        # (3) fuzz: 10,000 malformed frames, random defects, as fast as they can be sent
        j_last, t_last = next_valid()
        kinds = rng.choice(KINDS, size=FUZZ_N)
        fuzz, expected = [], {}
        for i, kind in enumerate(kinds):
            bad, reason = bad_frame(kind, j_last, rng)
            assert reason == REASON[kind]
            fuzz.append(msg(bad, t_last + 0.001 * (i + 1)))
            expected[reason] = expected.get(reason, 0) + 1
        t0 = time.monotonic()
        for i, m in enumerate(fuzz):
            pub.publish(m)
            lag = t0 + (i + 1) / FUZZ_HZ - time.monotonic()
            if lag > 0:
                time.sleep(lag)
        fuzz_s = time.monotonic() - t0
        after_fuzz = settle_diag(g, diags, tracking)
        d = delta(after_fuzz, before_fuzz)
        print(f"fuzz: {FUZZ_N} malformed frames in {fuzz_s:.2f} s, by kind {expected}; diagnostics delta {d}")
        assert "frames_accepted" not in d  # not one malformed frame got through
        assert 0 < d["frames_rejected"] <= FUZZ_N
        for reason, n in expected.items():
            assert d.get(f"rejected_{reason}", 0) <= n
        assert tracking_diag(diags)["holding"] == "True"  # no valid frame: the last target is held

        # valid frames again: tracked
        n_inter = len(inter)
        for _ in range(50):
            pub.publish(msg(*next_valid()))
            time.sleep(0.01)
        final = settle_diag(g, diags, tracking)
        print("valid again: diagnostics delta", delta(final, after_fuzz))
        assert final["frames_accepted"] - after_fuzz["frames_accepted"] >= 25
        assert len(inter) > n_inter
        assert tracking.alive() and sim.alive()
        sim_values = sim_diag(diags)
        assert tracking.stop() == 0 and sim.stop() == 0

    log = tracking.output()
    inter_poses = [rm.pose_array_to_numpy(m) for m in inter.msgs]
    sim_poses = [rm.pose_array_to_numpy(m) for m in sim_bones.msgs]
    print(f"published: {len(inter_poses)} intermediate bones, {len(sim_poses)} sim bones; "
          f"sim diagnostics: steps {sim_values['steps']}, rejected_steps {sim_values['rejected_steps']}")
    assert all(p.shape == (16, 7) and np.all(np.isfinite(p)) for p in inter_poses)
    assert all(p.shape == (16, 7) and np.all(np.isfinite(p)) for p in sim_poses)
    assert not any(k.startswith("rejected_intermediate") for k in sim_values)  # nothing bad reached sim_node
    # palm positions stay where a hand can be (no 1e9 m target ever went through)
    assert max(np.abs(p[:, :3]).max() for p in inter_poses + sim_poses) < 3.0
    reject_lines = [ln for ln in log.splitlines() if "tracker frame rejected" in ln]
    total = final["frames_rejected"]
    stamps_s = [float(m.group(1)) for ln in reject_lines if (m := re.search(r"\[(\d+\.\d+)\]", ln))]
    span = stamps_s[-1] - stamps_s[0] if len(stamps_s) > 1 else 0.0
    print(f"log: {len(reject_lines)} rejection lines for {total} rejected frames over {span:.1f} s")
    assert reject_lines and len(reject_lines) <= span / 2.0 + 2  # at most one per 2 s
    assert "Traceback" not in log and "Traceback" not in sim.output()
