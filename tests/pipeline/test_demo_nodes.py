"""Topic-level integration: the real node set (separate processes, real Fast DDS, real pybullet)
driven by the sample bags through `softhand demo`, checked from what record_node wrote.

Each run uses a private ROS domain with loopback-only discovery (softhand_sim.ros.env).
"""
import json
import math
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest


# Timing over real DDS between processes on a shared 2-core machine: a retry absorbs a stall. Two:
# on fresh clones the first one or two node-level demos of a session failed a grasp check
# (grasp_lift's ball slipped out at 3-12 cm). One cause, the undamped engine-side coupling spring
# that late copies drive unstable, is fixed (docs/DESIGN.md); the other is not: on a cold numba
# cache world_node's state stream stopped for 0.65 s at the first contact, the copies went stale
# and the ball fell (README, "What the tests prove"). The least sensitive bags run first.
pytestmark = [pytest.mark.ros, pytest.mark.slow, pytest.mark.flaky(reruns=2, reruns_delay=2)]

SOFTHAND = str(Path(sys.executable).parent / "softhand")
SKIN_PARAMS = """\
record_node:
  ros__parameters:
    record_skin_vertices: true
"""


def run_demo(tmp_path, bag, params=None, preview=False, timeout=420):
    out = tmp_path / bag
    cmd = [SOFTHAND, "demo", "--bag", bag, "--out", str(out)]
    if params:
        pfile = tmp_path / f"{bag}_params.yaml"
        pfile.write_text(params)
        cmd += ["--params-file", str(pfile)]
    if not preview:
        cmd.append("--no-preview")
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return out, json.loads((out / "summary.json").read_text()), proc.stdout


def read_topic(bag_dir, topic):
    """[(receive time [s], message)] of one topic, read with rosbags."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    with Reader(bag_dir) as reader:
        conns = [c for c in reader.connections if c.topic == topic]
        assert conns, f"no {topic} in {bag_dir}"  # (rosbags would read every topic when given none)
        return [(t * 1e-9, store.deserialize_cdr(raw, c.msgtype)) for c, t, raw in reader.messages(connections=conns)]


def object_z(bag_dir, name, topic="/world/object_states"):
    rows = []
    for t, msg in read_topic(bag_dir, topic):
        names = list(msg.joint_names)
        if name in names and msg.points:
            rows.append((t, msg.points[0].transforms[names.index(name)].translation.z))
    return np.array(rows)


# viewer artefacts of ~1 MB a message (every skin triangle as points): decoding all of them took
# most of this check's 8 s; their first and last messages are decoded, every one is counted
HEAVY_TOPICS = {"/hand/right/skin_marker", "/hand/right/skin_vertices", "/hand/left/skin_marker",
                "/hand/left/skin_vertices"}


def check_recording_opens_everywhere(bag_dir):
    """The recording opens with rosbags and with the mcap reader, and decodes against its own
    schemas: every message of every topic (of the heavy viewer topics the first and the last).
    Returns the number of messages in the mcap file."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    mcap_files = list(Path(bag_dir).glob("*.mcap"))
    assert len(mcap_files) == 1
    factory = DecoderFactory()
    count, heavy = 0, {}
    with open(mcap_files[0], "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert all(ch.schema_id in summary.schemas for ch in summary.channels.values())
        for schema, channel, message in reader.iter_messages():
            count += 1
            if channel.topic in HEAVY_TOPICS:
                heavy.setdefault(channel.topic, [None, None, schema, channel])
                heavy[channel.topic][0 if heavy[channel.topic][0] is None else 1] = message.data
                continue
            factory.decoder_for(channel.message_encoding, schema)(message.data)
    for first, last, schema, channel in heavy.values():
        decode = factory.decoder_for(channel.message_encoding, schema)
        for data in (first, last):
            if data is not None:
                decode(data)
    assert count > 100
    return count


def check_single_hand_run(out, summary):
    """/hand/right/bones and /hand/right/intermediate_bones (the sample bags are old single-hand bags:
    the right hand) come at their rates, all values finite, bag readable, every tracker frame
    through, nothing on the left hand's topics."""
    rates = summary["rates_hz"]
    # the 250 Hz loop skips the ticks it cannot catch up when the two cores are saturated by five
    # processes and whatever else runs on the machine (measured: 230 Hz with other work running)
    assert 225 <= rates["/hand/right/intermediate_bones"] <= 260, rates
    assert rates["/hand/right/bones"] >= 0.8 * 60.0 * 0.5, rates  # sim_rate 60 Hz; at least half on 2 shared cores
    assert not [t for t, n in summary["messages_per_topic"].items() if "/left/" in t and n], summary
    assert list(summary["hands"]) == ["right"], summary["hands"]
    assert summary["all_finite"], summary
    decoded = check_recording_opens_everywhere(out / "bag")
    assert decoded == summary["bag_messages"]
    check_nothing_lost(summary)


# Through the nodes: grasp_lift (the demo's bag, below) and press_table (skin against the table).
# pinch_lift, squeeze and fast_dropout are left out for the suite's time (30-40 s each): their
# motions are the offline grasp and pinch tests' and tracking_node's dropout test's, and through
# the nodes they make the same generic checks. That every bag's frames are all recorded, received
# and accepted is test_every_bag_replayed's (every sample bag, without the sim and world nodes).
def test_press_table_through_the_nodes(tmp_path):
    """press_table with the skin recorded: the generic checks, and no skin vertex deeper than 5 mm
    in the table while the tracked hand goes 3 cm into it."""
    out, summary, _ = run_demo(tmp_path, "press_table", SKIN_PARAMS)
    check_single_hand_run(out, summary)
    check_press(out / "bag")


def check_nothing_lost(summary):
    """Every frame of the input bag is published, recorded, received and accepted by tracking_node
    (the sample bags hold no invalid frame), none rejected (issue #17 item 5)."""
    frames = summary["tracker_frames"]
    n = frames["in_bag"]
    assert n > 100, frames
    assert (frames["published"], frames["recorded"], frames["received"], frames["accepted"]) == (n, n, n, n), frames
    assert frames["rejected"] == 0, frames


def check_grasp(bag_dir):
    """Ball lifted >= 8 cm in the engine while held, stays up during the hold, falls after release."""
    z = object_z(bag_dir, "ball")
    assert len(z) > 100
    z0 = z[0, 1]
    top = z[:, 1].max()
    assert top - z0 >= 0.08, f"ball rose only {100 * (top - z0):.1f} cm"
    t_up = z[z[:, 1] > z0 + 0.07, 0]
    assert t_up.max() - t_up.min() >= 2.0, "ball held up for less than 2 s"
    assert z[-1, 1] < z0 + 0.02, f"ball did not come down after release (z {z[-1, 1]:.3f})"


def check_press(bag_dir):
    """Tracked hand 3 cm below the table top: no simulated skin vertex deeper than 5 mm, bounded forces."""
    from softhand_sim.ros.msgs import contacts_cloud_to_numpy, xyz_cloud_to_numpy
    from softhand_sim.scene import load_scene

    table = load_scene().object("table")
    top = table.pose[2] + table.dims["size"][2] / 2
    deepest = math.inf
    for _, msg in read_topic(bag_dir, "/hand/right/skin_vertices"):
        xyz = xyz_cloud_to_numpy(msg)
        over = (np.abs(xyz[:, 0] - table.pose[0]) < 0.39) & (np.abs(xyz[:, 1] - table.pose[1]) < 0.39)
        if over.any():
            deepest = min(deepest, float(xyz[over, 2].min() - top))
    assert math.isfinite(deepest), "no skin vertex over the table"
    assert deepest > -0.005, f"skin went {1000 * -deepest:.1f} mm into the table"
    fmax = 0.0
    for _, msg in read_topic(bag_dir, "/hand/contacts"):
        c = contacts_cloud_to_numpy(msg)
        if len(c["forces"]):
            fmax = max(fmax, float(np.linalg.norm(c["forces"].sum(axis=0))))
    assert 0.5 < fmax < 50.0, f"total contact force {fmax:.2f} N"


def test_demo_command_end_to_end(demo_run):
    """`softhand demo` as `make demo` runs it (grasp_lift) writes the bag, summary.json and the
    preview pictures; the summary names the hand simulated (the default 19 cm hand, from sim_node's
    /diagnostics); the generic checks; the ball lifted >= 8 cm, held, set down."""
    out, summary, stdout, failed = demo_run
    if failed:  # shown in the run's warnings summary, not only with -s
        print("failed demo attempts before this one:", *failed, sep="\n")
        warnings.warn("softhand demo failed before this attempt: " + " | ".join(f.splitlines()[0] for f in failed))
    check_single_hand_run(out, summary)
    check_grasp(out / "bag")
    assert (out / "bag" / "metadata.yaml").is_file()
    assert (out / "preview.png").stat().st_size > 10_000 and (out / "preview.gif").is_file()
    assert "sim step" in stdout and "latency" in stdout and "tracker frames" in stdout
    hand = summary["hand_measures"]
    assert hand["hand_measures_source"] == "default" and hand["hand_length_mm"] == 190.0, hand
    assert "hand measures: default, hand length 190.0 mm" in stdout
    assert all(code == 0 for code in summary["exit_codes"].values()), summary["exit_codes"]
    assert summary["bag_mb"] < 100


def test_handover_through_both_hands(tmp_path):
    """`softhand demo --bag handover` (two hands: one sim_node, two tracking nodes) at full speed
    (the busier case; half speed, as the README suggests, cost the suite 14 s more):
    every frame of each hand published, recorded, received and accepted by its own tracking node;
    both hands' bones recorded, every value finite. The ball's fate is printed, not asserted: one
    sim_node steps two hands at 18-38 Hz on this 2-core machine; the handover through the nodes
    succeeded in 2 of 2 full-speed runs with the events executor, 1 of 2 half-speed and 0 of 2
    full-speed runs before it (README, "Two hands"); offline it is asserted (test_bimanual.py)."""
    from softhand_sim.scenarios.bimanual import HANDOVER_CARRY

    out = tmp_path / "handover"
    proc = subprocess.run([SOFTHAND, "demo", "--bag", "handover", "--out", str(out), "--no-preview"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["hands"]) == {"right", "left"}, summary["hands"]
    for side, h in summary["hands"].items():
        f = h["tracker_frames"]
        assert f["in_bag"] > 1000 and f["in_bag"] == f["recorded"] == f["received"] == f["accepted"], (side, f)
        assert h["bones_messages"] > 100, (side, h)
    assert summary["all_finite"], summary
    # where the ball ended against where it started, from the summary (the demo prints it)
    miss = np.linalg.norm(np.asarray(summary["object_moved_m"]["ball"]) - HANDOVER_CARRY)
    print(f"handover through the nodes: ball lifted {100 * summary['ball_lift_m']:.1f} cm, ended "
          f"{100 * miss:.1f} cm from its spot (offline: 0.3 cm)")


def test_hand_measures_auto_on_a_real_recording(tmp_path):
    """sim_node with `hand_measures: auto` on leap_grab (a real Leap Motion recording, 3.3 s),
    played 3 times in a row (`softhand demo --repeat 3`): the first tracked second sizes the hand
    to what `softhand calibrate` gives for the same frames (0.1 mm), the fitted hand is placed and
    simulated (its bones recorded), every frame of the three plays recorded and accepted, and the
    fitted hand follows the real hand within the user-fit acceptance (`softhand fidelity`)."""
    proc = subprocess.run([SOFTHAND, "calibrate", "leap_grab", "--json", "--out", str(tmp_path / "measures.yaml")],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    calibrated = json.loads(proc.stdout)
    params = "sim_node:\n  ros__parameters:\n    hand_measures: auto\n"
    pfile = tmp_path / "auto.yaml"
    pfile.write_text(params)
    out = tmp_path / "auto"
    proc = subprocess.run([SOFTHAND, "demo", "--bag", "leap_grab", "--repeat", "3", "--params-file", str(pfile),
                           "--out", str(out), "--no-preview"], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    hand = summary["hand_measures"]
    assert hand["hand_measures_source"] == "auto", hand
    assert abs(hand["palm_length_mm"] - calibrated["palm_length_mm"]) <= 0.1, (hand, calibrated["palm_length_mm"])
    assert abs(hand["palm_width_mm"] - calibrated["palm_width_mm"]) <= 0.1, (hand, calibrated["palm_width_mm"])
    assert abs(hand["hand_length_mm"] - calibrated["wrist_to_middle_tip_mm"]) <= 0.1, hand
    assert summary["messages_per_topic"].get("/hand/right/bones", 0) > 50, summary["messages_per_topic"]
    assert summary["all_finite"], summary
    frames = summary["tracker_frames"]
    assert frames["in_bag"] == 3 * 374, frames  # leap_grab: 374 frames, played three times
    check_nothing_lost(summary)
    # the user-fit acceptance through the node set, scored with the fitted hand's bone lengths
    # that sim_node reported (measured: tips 3.8 / 12.3 mm, knuckles 3.4 mm, pinch gap 1.0 mm; the
    # p95 includes the jump back to the start at each repeat)
    proc = subprocess.run([SOFTHAND, "fidelity", str(out)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    f = json.loads(proc.stdout.strip().splitlines()[-1])
    print("leap_grab, auto, through the nodes:", {k: f[k] for k in ("measures", "fingertip_mm", "knuckle_mm",
                                                                    "pinch_gap_error_mm", "lag_ms")})
    assert f["measures"] == "recorded (auto)", f["measures"]
    assert f["fingertip_mm"]["median"] <= 8.0 and f["fingertip_mm"]["p95"] <= 20.0, f["fingertip_mm"]
    assert f["knuckle_mm"]["median"] <= 6.0 and f["pinch_gap_error_mm"]["median"] <= 5.0, f
