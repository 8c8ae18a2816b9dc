"""run_summary's latency figure: start-up is reported apart, not mixed into the percentiles."""
import numpy as np
import pytest

from softhand_sim.commands.run_summary import frame_latency_ms, steady_rate_hz


def test_steady_rate_leaves_out_a_start_up_catch_up():
    """A 250 Hz loop that stalled 0.4 s at start and then ran the 100 steps it missed within
    0.12 s (as recorded in a demo run on two busy cores): over the whole span 256 Hz, the steady
    rate 250 Hz. A loop that really runs fast (270 Hz) still reads as 270 Hz."""
    burst = np.linspace(0.0, 0.12, 100)
    steady = 0.12 + np.arange(1, 3000) / 250.0
    times = np.concatenate([burst, steady])
    assert (len(times) - 1) / (times[-1] - times[0]) > 255.0  # what the summary said before
    assert abs(steady_rate_hz(times) - 250.0) < 0.1
    assert abs(steady_rate_hz(np.arange(3000) / 270.0) - 270.0) < 0.1
    assert abs(steady_rate_hz([0.0, 0.5, 1.0]) - 2.0) < 1e-12  # too few to trim: the whole span
    assert steady_rate_hz([1.0]) is None and steady_rate_hz([1.0, 1.0]) is None


def test_latency_leaves_out_frames_before_the_first_bones():
    """Tracker frames every 10 ms from t = 0, /hand/bones every 1/60 s from t = 1.0 s: start-up is
    1.0 s; each later frame waits for the next bones message, so its latency lies in (0, 1/60 s]
    and the frames of the first second are not counted."""
    tracker = np.arange(0.0, 3.0, 0.01)
    bones = 1.0 + np.arange(0, 120) / 60.0
    latency, startup = frame_latency_ms(tracker, bones)
    assert np.isclose(startup, 1.0)
    assert len(latency) == np.sum((tracker >= 1.0) & (tracker < bones[-1]))
    assert latency.min() > 0.0 and latency.max() <= 1e3 / 60.0 + 1e-9
    assert frame_latency_ms([], bones)[0].size == 0


# ------------------------------------------------------------------ the hand measures in use

T0_NS = 1_800_000_000 * 10**9
DIAGNOSTICS = "diagnostic_msgs/msg/DiagnosticArray"


def _diagnostics_record(t_ns, statuses):
    """A /diagnostics record of rclpy statuses (as the nodes build them: softhand_sim.ros.msgs)."""
    from softhand_sim.ros.bagio import TYPESTORE, serialize

    T = TYPESTORE.types
    header = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9),
                                      frame_id="world")
    status = [T["diagnostic_msgs/msg/DiagnosticStatus"](
        level=int.from_bytes(s.level, "little"), name=s.name, message=s.message, hardware_id=s.hardware_id,
        values=[T["diagnostic_msgs/msg/KeyValue"](key=kv.key, value=kv.value) for kv in s.values]) for s in statuses]
    return "/diagnostics", DIAGNOSTICS, t_ns, serialize(T[DIAGNOSTICS](header=header, status=status), DIAGNOSTICS)


def _sim_status(values, node="sim_node"):
    from softhand_sim.ros.msgs import diagnostic_name, diagnostic_status

    return diagnostic_status(diagnostic_name(node), {"step_ms_p50": 3.0, "step_ms_p99": 5.0, **values},
                             hardware_id="softhand@test")


def test_summary_reports_the_last_hand_measures_of_sim_node(tmp_path):
    """An auto-sized run: sim_node first reports the default hand while the sizer collects frames,
    then the fitted hand (source auto, the sizer's keys gone). The summary holds the fitted hand's
    keys exactly, not the earlier ones, and not another node's status that uses the same keys."""
    from softhand_sim.commands.run_summary import hand_measures_line, summarize_run
    from softhand_sim.handmodel.measures import HandMeasures, scale_measures
    from softhand_sim.hand_sizer import measures_diagnostics
    from softhand_sim.ros.bagio import write_bag

    fitted = scale_measures(HandMeasures(), 1.12)
    collecting = {**measures_diagnostics(HandMeasures(), "default"), "hand_measures_source": "auto",
                  "hand_size_state": "collecting", "hand_size_frames": 40}
    decoy = measures_diagnostics(scale_measures(HandMeasures(), 0.8), "file")
    write_bag(tmp_path / "rec", [
        _diagnostics_record(T0_NS, [_sim_status(collecting)]),
        _diagnostics_record(T0_NS + 10**9, [_sim_status(measures_diagnostics(fitted, "auto"))]),
        _diagnostics_record(T0_NS + 2 * 10**9, [_sim_status(decoy, node="world_node")]),
    ])
    s = summarize_run(tmp_path / "rec")
    expected = measures_diagnostics(fitted, "auto")
    assert s["hand_measures"] == expected
    assert expected["hand_length_mm"] > measures_diagnostics(HandMeasures(), "default")["hand_length_mm"] + 10
    line = hand_measures_line(s["hand_measures"])
    assert line.startswith("  hand measures: auto,") and f"hand length {expected['hand_length_mm']:.1f} mm" in line
    assert "sizing" not in line


def test_summary_says_when_sizing_failed_and_when_nothing_was_reported(tmp_path):
    """A failed auto fit keeps the default hand: the summary names the default source, the state
    and the error; a recording without sim_node's status has no hand measures."""
    from softhand_sim.commands.run_summary import hand_measures_line, summarize_run
    from softhand_sim.handmodel.measures import HandMeasures
    from softhand_sim.hand_sizer import measures_diagnostics
    from softhand_sim.ros.bagio import write_bag

    failed = {**measures_diagnostics(HandMeasures(), "default"), "hand_size_state": "failed",
              "hand_size_frames": 3, "hand_size_error": "too few valid frames"}
    write_bag(tmp_path / "failed", [_diagnostics_record(T0_NS, [_sim_status(failed)])])
    s = summarize_run(tmp_path / "failed")
    assert s["hand_measures"]["hand_measures_source"] == "default"
    assert s["hand_measures"]["hand_size_frames"] == 3
    assert s["hand_measures"]["palm_length_mm"] == 90.0 and isinstance(s["hand_measures"]["palm_length_mm"], float)
    assert "(sizing: state failed, frames 3, error too few valid frames)" in hand_measures_line(s["hand_measures"])
    write_bag(tmp_path / "none", [_diagnostics_record(T0_NS, [_sim_status({}, node="tracking_node")])])
    none = summarize_run(tmp_path / "none")
    assert none["hand_measures"] == {} and "not reported" in hand_measures_line(none["hand_measures"])


# ------------------------------------------------------------------ two hands

def _pose_array_record(topic, t_ns, n, z=0.0):
    from softhand_sim.ros.bagio import TYPESTORE, serialize

    T = TYPESTORE.types
    header = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9),
                                      frame_id="world")
    pose = T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=z),
                                       orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))
    msg = T["geometry_msgs/msg/PoseArray"](header=header, poses=[pose] * n)
    return topic, "geometry_msgs/msg/PoseArray", t_ns, serialize(msg, "geometry_msgs/msg/PoseArray")


def _contacts_record(t_ns, hands):
    """A /hand/contacts cloud as sim_node builds it, one contact per entry of `hands` (0 right, 1 left)."""
    import numpy as np
    from rclpy.serialization import serialize_message

    from softhand_sim.ros import msgs as rm

    n = len(hands)
    msg = rm.contacts_cloud_from_numpy(np.zeros((n, 3)), np.tile([0.0, 0.0, 1.0], (n, 1)), np.zeros((n, 3)),
                                       np.zeros(n), np.zeros(n), rm.stamp_from_seconds(t_ns * 1e-9), hand=hands)
    return "/hand/contacts", "sensor_msgs/msg/PointCloud2", t_ns, serialize_message(msg)


def test_summary_counts_each_hand_apart(tmp_path):
    """A two-hand recording: 30 right and 20 left tracker frames, bones for both, the two tracking
    nodes' last counts (tracking_node and tracking_node_left, told apart by their `hand` value), a
    contact cloud with 3 right and 2 left contacts. The summary gives each hand its own counts,
    latency and contacts, and the sums at the top level."""
    from softhand_sim.commands.run_summary import summarize_run
    from softhand_sim.ros.bagio import write_bag
    from softhand_sim.ros.msgs import diagnostic_name, diagnostic_status

    ms = 10**6
    records = []
    for k in range(30):
        records.append(_pose_array_record("/tracker/right/hand_joints", T0_NS + k * 10 * ms, 26))
    for k in range(20):
        records.append(_pose_array_record("/tracker/left/hand_joints", T0_NS + 5 * ms + k * 10 * ms, 26))
    for k in range(20):
        records.append(_pose_array_record("/hand/right/bones", T0_NS + 2 * ms + k * 16 * ms, 16))
        records.append(_pose_array_record("/hand/left/bones", T0_NS + 3 * ms + k * 16 * ms, 16))
    records.append(_contacts_record(T0_NS + 100 * ms, [0, 1, 0, 1, 0]))

    def tracking(node, hand, n):
        return diagnostic_status(diagnostic_name(node), {"hand": hand, "frames_received": n, "frames_accepted": n,
                                                         "frames_rejected": 0}, hardware_id="softhand@test")
    records.append(_diagnostics_record(T0_NS + 400 * ms, [tracking("tracking_node", "right", 30),
                                                          tracking("tracking_node_left", "left", 20)]))
    records.sort(key=lambda r: r[2])
    write_bag(tmp_path / "two", records)
    s = summarize_run(tmp_path / "two")
    assert set(s["hands"]) == {"right", "left"}
    right, left = s["hands"]["right"], s["hands"]["left"]
    assert right["tracker_frames"] == {"recorded": 30, "received": 30, "accepted": 30, "rejected": 0}
    assert left["tracker_frames"] == {"recorded": 20, "received": 20, "accepted": 20, "rejected": 0}
    assert s["tracker_frames"] == {"recorded": 50, "received": 50, "accepted": 50, "rejected": 0}
    assert right["bones_messages"] == left["bones_messages"] == 20
    assert (right["max_contacts"], left["max_contacts"], s["max_contacts"]) == (3, 2, 5)
    assert 0 < right["latency_ms_p50"] <= 16.0 and 0 < left["latency_ms_p50"] <= 16.0


def test_summary_of_a_one_hand_run_has_only_that_hand(tmp_path):
    """A right-hand run recorded nothing on the left topics: `hands` has the right hand only."""
    from softhand_sim.commands.run_summary import summarize_run
    from softhand_sim.ros.bagio import write_bag

    records = [_pose_array_record("/tracker/right/hand_joints", T0_NS + k * 10**7, 26) for k in range(5)]
    records += [_pose_array_record("/hand/right/bones", T0_NS + 10**6 + k * 10**7, 16) for k in range(5)]
    records.sort(key=lambda r: r[2])
    write_bag(tmp_path / "one", records)
    s = summarize_run(tmp_path / "one")
    assert list(s["hands"]) == ["right"] and s["tracker_frames"]["recorded"] == 5


def test_summary_scores_each_hand_against_the_tracked_one(tmp_path):
    """The demo summary carries `softhand fidelity`'s figures per hand: on the lag tests' recording
    (the simulated layer 30 ms behind the tracked motion), the lag; on the one with no delay and the
    simulated palm 5 mm off, that offset as the palm error and the phalanx directions within the
    motion between two tracker frames (0.8 deg at most), and the tracker's noise; all printed."""
    from softhand_sim.commands.demo import format_summary
    from softhand_sim.commands.run_summary import summarize_run
    from tests.pipeline.test_lag import recording

    delayed = summarize_run(recording(tmp_path / "delayed"))["hands"]["right"]
    assert abs(delayed["lag_ms"]["sim"]["phalanx"] - 30.0) <= 1.0, delayed["lag_ms"]
    offset = summarize_run(recording(tmp_path / "offset", delays=(0.0, 0.0), palm_offset=(0.0, 0.003, 0.004)))
    f = offset["hands"]["right"]["fidelity"]
    assert abs(f["palm_mm"]["median"] - 5.0) < 0.01 and f["phalanx_direction_deg"]["median"] < 0.5, f
    assert "right hand vs the tracked one (median / p95): palm 5.0 / 5.0 mm" in format_summary(offset, tmp_path)
    # and what the input's own noise is (this recording's tracked hand has none)
    assert f["tracker_noise_mm"] < 0.01, f
    assert "(tracker noise 0.00 mm per coordinate)" in format_summary(offset, tmp_path)
    # scores=False: everything else, without the lag and fidelity (and the summary still prints)
    bare = summarize_run(tmp_path / "offset", scores=False)
    assert not {"lag_ms", "fidelity"} & set(bare["hands"]["right"])
    assert bare["hands"]["right"]["tracker_frames"] == offset["hands"]["right"]["tracker_frames"]
    assert "palm 5.0" not in format_summary(bare, tmp_path)


def test_summary_reports_every_objects_lift_and_where_it_ended(tmp_path):
    """/world/object_states of a run in which the big box rises 8.3 cm and ends 5 cm up, the ball
    is carried 20 cm along y on the table (a handover) and the mug barely moves: the summary's
    object_lift_m has each object's rise from its first state (two_hand_lift's box as well as the
    ball), object_moved_m each one's last position less its first, and the demo prints the other
    objects that rose, and the objects that moved, a centimetre or more."""
    from rclpy.serialization import serialize_message

    from softhand_sim.commands.demo import format_summary
    from softhand_sim.commands.run_summary import summarize_run
    from softhand_sim.ros.bagio import write_bag
    from softhand_sim.ros.msgs import object_states_from_numpy

    names = ["ball", "big_box", "mug"]
    records = []
    for k, rise in enumerate([0.0, 0.04, 0.083, 0.05]):
        poses = np.array([[0.0, 0.2 * k / 3, 0.8, 0, 0, 0, 1.0], [0.3, 0.0, 0.85 + rise, 0, 0, 0, 1.0],
                          [0.5, 0.0, 0.8 + 0.002 * k, 0, 0, 0, 1.0]])
        msg = object_states_from_numpy(names, poses, np.zeros((3, 6)), np.zeros((3, 6)), T0_NS + k * 10**8)
        records.append(("/world/object_states", "trajectory_msgs/msg/MultiDOFJointTrajectory", T0_NS + k * 10**8,
                        serialize_message(msg)))
    write_bag(tmp_path / "rec", records)
    s = summarize_run(tmp_path / "rec")
    assert abs(s["object_lift_m"]["big_box"] - 0.083) < 1e-9
    assert s["object_lift_m"]["ball"] == 0.0 and abs(s["object_lift_m"]["mug"] - 0.006) < 1e-9
    np.testing.assert_allclose(s["object_moved_m"]["ball"], [0.0, 0.2, 0.0], atol=1e-12)
    np.testing.assert_allclose(s["object_moved_m"]["big_box"], [0.0, 0.0, 0.05], atol=1e-12)
    np.testing.assert_allclose(s["object_moved_m"]["mug"], [0.0, 0.0, 0.006], atol=1e-12)
    text = format_summary(s, tmp_path)
    assert "other objects lifted: big_box 8.3 cm" in text and "mug" not in text
    assert ("objects moved, end against start: ball 20.0 cm (x +0.0, y +20.0, z +0.0), "
            "big_box 5.0 cm (x +0.0, y +0.0, z +5.0)") in text, text


@pytest.mark.parametrize("bad", [None, "/hand/right/bones", "/tracker/right/hand_joints"])
def test_summary_finds_a_non_finite_pose(tmp_path, bad):
    """One NaN coordinate in one bones message or tracker frame (read as numpy, not as message
    objects) makes `all_finite` false; none leaves it true."""
    from softhand_sim.commands.run_summary import summarize_run
    from softhand_sim.ros.bagio import write_bag

    ms = 10**6
    records = [_pose_array_record("/tracker/right/hand_joints", T0_NS + k * 10 * ms, 26,
                                  z=float("nan") if bad == "/tracker/right/hand_joints" and k == 7 else 0.0)
               for k in range(20)]
    records += [_pose_array_record("/hand/right/bones", T0_NS + 2 * ms + k * 16 * ms, 16,
                                   z=float("nan") if bad == "/hand/right/bones" and k == 5 else 0.0)
                for k in range(10)]
    records.sort(key=lambda r: r[2])
    write_bag(tmp_path / "run", records)
    assert summarize_run(tmp_path / "run")["all_finite"] is (bad is None)
