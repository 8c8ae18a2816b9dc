"""tracking_node at topic level: real processes (play_node -> tracking_node), real DDS on loopback; one
tracking_node per hand, each on its side's topics."""
import gc
import time
from pathlib import Path

import numpy as np
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray

from rclpy.serialization import serialize_message

from tests.support.rosproc import RosGraph, node_diagnostics
from softhand_sim.ros.bagio import write_bag
from softhand_sim.ros.msgs import pose_array_from_numpy, pose_array_to_numpy, stamp_to_seconds
from softhand_sim.scenarios.tracker_bags import sample
from softhand_sim.topics import hand_topic, tracker_topic
from softhand_tracking.adapter import AdapterConfig, TrackerAdapter, mirror_poses

# Timing over real DDS between processes on a shared 2-core machine: one retry absorbs a stall.
pytestmark = [pytest.mark.ros, pytest.mark.slow, pytest.mark.flaky(reruns=1, reruns_delay=2)]

REPO = Path(__file__).resolve().parents[2]
# [m] intermediate palm vs tracked palm. The loop alone keeps 5 cm on this bag, deterministically
# (test_tracking_loop: the paper's 50 N/m on a 28 g palm at 2 m/s, 25 m/s^2); through DDS, two
# Python processes and a 2-core machine shared with other test sessions, scheduling delays of
# tens of milliseconds at 2 m/s add up to ~3 cm more (measured max 33-68 mm, p99 31-55 mm).
FOLLOW_BOUND = 0.08


def _tracking_diag(msgs, node="tracking_node"):
    return node_diagnostics(msgs, node)


def test_fast_dropout_bag_through_tracking_node(ros_env):
    """play_node replays bags/fast_dropout (an older single-hand bag: played as the right hand) into
    tracking_node: /hand/right/intermediate_bones (16 finite
    poses, frame world) comes at 250 +- 5 Hz over the run (header stamps, and receive count), the
    intermediate palm stays within FOLLOW_BOUND (8 cm) of the tracked palm while tracked, bones
    keep coming and hold within 8 cm of the last target through the 300 ms dropout, settling on it, diagnostics report rate,
    jitter, step time, no rejected frames and the hold; SIGINT exits 0."""
    results = {}
    gc.disable()  # no collector pauses in this listener while it timestamps arrivals
    try:
        _run(ros_env, results)
    finally:
        gc.enable()
    bones, tracker, diags = results["bones"], results["tracker"], results["diags"]
    _check(bones, tracker, diags)


DEEP_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def _run(ros_env, results):
    with RosGraph(ros_env) as g:
        bones = g.listen(hand_topic("right", "intermediate_bones"), PoseArray)
        # deep: a keep-last-10 listener lost frames here while the shared machine stalled this process
        tracker = g.listen(tracker_topic("right"), PoseArray, DEEP_QOS)
        diags = g.listen("/diagnostics", DiagnosticArray)
        node = g.start(["softhand-tracking"])
        g.wait_until(lambda: len(diags) >= 1, 30, "first /diagnostics from tracking_node", node)
        assert len(bones) == 0  # nothing before the first tracker frame
        play = g.start(["softhand-play", str(REPO / "bags" / "fast_dropout"), "--wait-subscribers", "2"])
        assert play.wait(40) == 0, play.output()
        done = len(_tracking_diag(diags.msgs))
        g.wait_until(lambda: len(_tracking_diag(diags.msgs)) >= done + 2, 10, "diagnostics after the bag", node)
        assert node.alive(), node.output()
        assert node.stop() == 0, node.output()
    results.update(bones=bones, tracker=tracker, diags=diags)


def _check(bones, tracker, diags):
    assert len(tracker) > 600, len(tracker)
    poses = [pose_array_to_numpy(m) for m in bones.msgs]
    assert all(p.shape == (16, 7) and np.all(np.isfinite(p)) for p in poses)
    assert {m.header.frame_id for m in bones.msgs} == {"world"}

    # rate over the run, from the node's stamps and from what arrived here
    stamps = np.array([stamp_to_seconds(m.header.stamp) for m in bones.msgs])
    t_first_tracker, t_last_tracker = tracker.times[0], tracker.times[-1]
    recv = np.array(bones.times)
    during = (recv >= t_first_tracker) & (recv <= t_last_tracker)
    span = stamps[during][-1] - stamps[during][0]
    stamp_rate = (during.sum() - 1) / span
    recv_rate = (during.sum() - 1) / (recv[during][-1] - recv[during][0])
    print(f"intermediate bones: {stamp_rate:.1f} Hz by stamps, {recv_rate:.1f} Hz received, over {span:.2f} s")
    big = np.nonzero(np.diff(stamps) > 0.006)[0]
    print("stamp gaps > 1.5 periods:", [(round(stamps[i] - stamps[0], 3), round(stamps[i + 1] - stamps[i], 3)) for i in big])
    assert abs(stamp_rate - 250.0) <= 5.0
    assert abs(recv_rate - 250.0) <= 5.0

    # follow: compare each bones message with the tracker frame that was current at its step time.
    # Bones stamps are the node's (wall) clock; tracker stamps are play_node's publish times on the
    # same clock (stamps: publish), in general capture + offset: the offset is the least receive lag.
    adapter = TrackerAdapter()
    tracked_palm = np.array([adapter.convert(pose_array_to_numpy(m))[0, :3] for m in tracker.msgs])
    capture = np.array([stamp_to_seconds(m.header.stamp) for m in tracker.msgs])
    wall_minus_mono = time.time() - time.monotonic()
    offset = np.min(np.array(tracker.times) + wall_minus_mono - capture)
    ttimes = capture + offset                      # wall time each frame was due at the node
    step_wall = stamps
    idx = np.searchsorted(ttimes, step_wall, side="right") - 1
    valid = idx >= 0
    recv = step_wall
    t_first_tracker, t_last_tracker = ttimes[0], ttimes[-1]
    err = np.full(len(recv), np.nan)
    err[valid] = np.linalg.norm(np.array([p[0, :3] for p in poses])[valid] - tracked_palm[idx[valid]], axis=1)
    gap = np.argmax(np.diff(ttimes))
    gap_start, gap_end = ttimes[gap], ttimes[gap + 1]
    assert 0.25 < gap_end - gap_start < 0.45, gap_end - gap_start
    # A frame play_node (a Python process on a shared, loaded machine) delivered > 20 ms late left
    # the node with an old target: not the node's lag. Steps within 0.25 s of one are left out.
    # Likewise a step the node itself published > 20 ms after its time (the OS did not run it:
    # 2 cores shared by several test sessions) is the machine's lag, not the loop's.
    late = np.array(tracker.times) + wall_minus_mono - ttimes
    node_late = np.array(bones.times) + wall_minus_mono - stamps
    late_at = np.r_[ttimes[late > 0.02], stamps[node_late > 0.02]]
    near_late = np.zeros(len(recv), dtype=bool)
    for t_late in late_at:
        near_late |= (recv >= t_late - 0.05) & (recv <= t_late + 0.25)
    print(f"tracker delivery lateness p50 {1e3 * np.median(late):.1f} ms, max {1e3 * late.max():.1f} ms; "
          f"bones publication lateness p50 {1e3 * np.median(node_late):.1f} ms, max {1e3 * node_late.max():.1f} ms; "
          f"{late_at.size} late events, {near_late.sum()} of {len(recv)} steps left out")
    # enough steps left to judge: at least 40 % of the run (~3 s of it, the fast motion included).
    # Measured on an idle machine: 0-41 % left out (62 late events of ~35 ms, mostly this listening
    # process's own); once 91 %, which only says the machine could not be judged that time
    assert near_late.mean() < 0.6, f"{near_late.mean():.0%} of the steps near a late event: the machine was too busy"
    tracking = valid & ((recv < gap_start) | (recv > gap_end + 0.5)) & (recv <= t_last_tracker) & ~near_late
    print(f"palm error while tracking: p50 {1e3 * np.median(err[tracking]):.1f} mm, "
          f"p99 {1e3 * np.percentile(err[tracking], 99):.1f} mm, max {1e3 * err[tracking].max():.1f} mm")
    worst = np.nanargmax(np.where(tracking, err, np.nan))
    print(f"worst at {recv[worst] - t_first_tracker:.3f} s after the first tracker frame")
    assert err[tracking].max() < FOLLOW_BOUND
    in_gap = (recv > gap_start + 0.02) & (recv < gap_end - 0.01)
    assert in_gap.sum() > 0.8 * 250 * (gap_end - gap_start - 0.03)  # still publishing through the gap
    assert err[in_gap].max() < FOLLOW_BOUND
    assert err[in_gap][-10:].max() < 0.01  # settled onto the held target

    last = _tracking_diag(diags.msgs)[-1]
    print("diagnostics:", last)
    assert int(last["frames_rejected"]) == 0
    # best-effort (sensor QoS) subscription: a busy machine may drop a few frames, never many
    assert 0.97 * len(tracker) <= int(last["frames_accepted"]) <= len(tracker)
    assert int(last["holds"]) >= 2  # the dropout, and the end of the bag
    assert float(last["step_ms_p50"]) < 1.0
    assert abs(float(last["rate_hz"]) - 250.0) < 10.0
    for key in ("period_p50_ms", "period_p99_ms", "jitter_p99_ms", "time_since_tracker_s", "rejected_non_finite"):
        assert key in last


def test_sigterm_and_bad_parameter(ros_env):
    """tracking_node exits 0 on SIGTERM; a bad parameter value stops it at start with a message
    naming the parameter and the value."""
    import signal
    with RosGraph(ros_env) as g:
        diags = g.listen("/diagnostics", DiagnosticArray)
        node = g.start(["softhand-tracking"])
        g.wait_until(lambda: len(diags) >= 1, 30, "first /diagnostics", node)
        assert node.stop(signal.SIGTERM) == 0, node.output()
        bad = g.start(["softhand-tracking", "--ros-args", "-p", "hand:=middle"])
        assert bad.wait(30) != 0
        assert "hand" in bad.output() and "middle" in bad.output(), bad.output()


def two_hand_bag(path, n=150, left_shift=-0.3):
    """A two-hand tracker bag from the first n frames of the grasp_short scenario: the right hand's
    frames, and the left hand's = the same frames mirrored (adapter.mirror_poses) and moved by
    left_shift [m] along y, 3 ms later. Returns {side: joints (n, 26, 7)}."""
    stamps_ns, joints, _ = sample("grasp_short")
    stamps_ns, joints = stamps_ns[:n], joints[:n]
    left = np.stack([mirror_poses(j) for j in joints])
    left[:, :, 1] += left_shift
    records = []
    for side, frames, offset in (("right", joints, 0), ("left", left, 3_000_000)):
        for t, j in zip(stamps_ns, frames):
            t = int(t) + offset
            records.append((tracker_topic(side), "geometry_msgs/msg/PoseArray", t,
                            serialize_message(pose_array_from_numpy(j, t))))
    write_bag(path, records)
    return {"right": joints, "left": left}


def test_one_tracking_node_per_hand(ros_env, tmp_path):
    """Two tracking_nodes, the right one under its default name and the left one as
    `tracking_node_left -p hand:=left`, fed by play_node with a two-hand bag (--wait-for-nodes names
    both): each receives and accepts exactly its side's frames (/diagnostics of its own name, value
    hand), publishes /hand/{side}/intermediate_bones only, and its bones follow its own hand (the
    left hand is 30 cm from the right one); nothing on the old un-sided topic. The left one runs
    with `joint_filter:=one_euro` (the filter in a node: its /diagnostics name it, and its hand
    still follows)."""
    n = 150
    frames = two_hand_bag(tmp_path / "bag", n)
    tracked_palm = {side: np.array([TrackerAdapter(AdapterConfig(hand=side)).convert(j)[0, :3] for j in f])
                    for side, f in frames.items()}
    names = {"right": "tracking_node", "left": "tracking_node_left"}
    with RosGraph(ros_env) as g:
        bones = {side: g.listen(hand_topic(side, "intermediate_bones"), PoseArray) for side in names}
        legacy = g.listen("/hand/intermediate_bones", PoseArray)
        diags = g.listen("/diagnostics", DiagnosticArray)
        nodes = {"right": g.start(["softhand-tracking"]),
                 "left": g.start(["softhand-tracking", "--ros-args", "-r", "__node:=tracking_node_left",
                                  "-p", "hand:=left", "-p", "joint_filter:=one_euro"])}
        for side, name in names.items():
            g.wait_until(lambda: _tracking_diag(diags.msgs, name), 60, f"/diagnostics of {name}", nodes[side])
        play = g.start(["softhand-play", str(tmp_path / "bag"), "--wait-for-nodes", *names.values()])
        assert play.wait(40) == 0, play.output()

        def settled(name):
            got = [int(d["frames_received"]) for d in _tracking_diag(diags.msgs, name)]
            return len(got) >= 2 and got[-1] == got[-2] and got[-1] > 0
        for side, name in names.items():
            g.wait_until(lambda: settled(name), 20, f"{name}: frame count settled", nodes[side])
        for side in names:
            assert g.node.count_publishers(hand_topic(side, "intermediate_bones")) == 1
            assert g.node.count_subscribers(tracker_topic(side)) == 1  # its node only
        assert g.node.count_publishers("/hand/intermediate_bones") == 0 and len(legacy) == 0
        for side, proc in nodes.items():
            assert proc.alive(), proc.output()
            assert proc.stop() == 0, proc.output()
    for side, name in names.items():
        last = _tracking_diag(diags.msgs, name)[-1]
        print(name, {k: last[k] for k in ("hand", "frames_received", "frames_accepted", "frames_rejected",
                                          "published")})
        assert last["hand"] == side
        assert last["joint_filter"] == ("one_euro (min cutoff 1 Hz, beta 30 s/m)" if side == "left" else "none")
        assert int(last["frames_received"]) == int(last["frames_accepted"]) == n  # its side's frames, all of them
        assert int(last["frames_rejected"]) == 0
        palms = np.array([pose_array_to_numpy(m)[0, :3] for m in bones[side].msgs])
        assert len(palms) > 100
        # its own hand: the last intermediate palm near its side's last tracked palm, 30 cm from the other's
        other = "left" if side == "right" else "right"
        assert np.linalg.norm(palms[-1] - tracked_palm[side][-1]) < 0.02
        assert np.linalg.norm(palms[-1] - tracked_palm[other][-1]) > 0.2
    assert "tracking the left hand" in nodes["left"].output()
