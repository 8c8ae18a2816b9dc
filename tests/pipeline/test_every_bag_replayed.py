"""Every sample bag replayed into both hands' tracking nodes and the recorder: nothing is lost on
replay (issue #17 item 5) on every bag, not only on the ones the demos of test_demo_nodes run
through the whole node set. The sim and world nodes are left out: they neither publish nor take
tracker frames, and starting them would cost the suite ~30 s a bag."""
import pytest
from diagnostic_msgs.msg import DiagnosticArray

from softhand_sim.commands.demo import bag_sides
from softhand_sim.commands.run_summary import input_frames
from softhand_sim.paths import bags_dir
from softhand_sim.ros.bagio import topic_counts
from softhand_sim.topics import tracker_topic
from tests.support.rosproc import RosGraph, node_diagnostics

pytestmark = [pytest.mark.ros]

NODES = {"right": "tracking_node", "left": "tracking_node_left"}
RATE = 4.0  # four times the recorded speed: the 13 bags' ~110 s in ~28 s (56 s with the starts), and
            # a harder test of the QoS than the recorded rate (up to ~450 frames a second)


def test_every_frame_of_every_sample_bag_is_recorded_received_and_accepted(ros_env, tmp_path):
    """One tracking node per hand and record_node, then play_node once per bag of bags/ at four times
    the recorded speed, each waiting for the nodes of the hands its bag drives and the recorder: per
    side, the recorder's bag holds every frame of every bag, and the tracking node received and
    accepted every one of them, none rejected (the demo checks the same per run on its bags,
    test_demo_nodes.check_nothing_lost)."""
    bags = sorted(p for p in bags_dir().iterdir() if p.is_dir())
    assert len(bags) >= 13, bags
    want = {side: 0 for side in NODES}
    with RosGraph(ros_env) as g:
        diags = g.listen("/diagnostics", DiagnosticArray)
        nodes = {"right": g.start(["softhand-tracking"]),
                 "left": g.start(["softhand-tracking", "--ros-args", "-r", f"__node:={NODES['left']}",
                                  "-p", "hand:=left"])}
        record = g.start(["softhand-record", "--ros-args", "-p", f"output:={tmp_path / 'bag'}",
                          "-p", "live_lag:=false"])
        for side, name in NODES.items():
            g.wait_until(lambda: node_diagnostics(diags.msgs, name), 60, f"/diagnostics of {name}",
                         nodes[side])
        for bag in bags:
            wait = [NODES[side] for side in bag_sides(bag)] + ["record_node"]
            play = g.start(["softhand-play", str(bag), "--rate", str(RATE), "--wait-for-nodes", *wait])
            assert play.wait(120) == 0, f"{bag.name}: {play.output()}"
            for side, n in input_frames(bag).items():
                want[side] += n

        def settled(name, n):
            got = node_diagnostics(diags.msgs, name)
            return got and int(got[-1]["frames_received"]) >= n

        for side, name in NODES.items():
            g.wait_until(lambda: settled(name, want[side]), 20, f"{name}: {want[side]} frames", nodes[side])
        for proc in (*nodes.values(), record):
            assert proc.stop() == 0, proc.output()
    recorded = topic_counts(tmp_path / "bag")
    for side, name in NODES.items():
        last = node_diagnostics(diags.msgs, name)[-1]
        print(side, want[side], "frames in the bags;", recorded.get(tracker_topic(side)), "recorded;",
              {k: last[k] for k in ("frames_received", "frames_accepted", "frames_rejected")})
        assert recorded.get(tracker_topic(side)) == want[side]
        assert int(last["frames_received"]) == int(last["frames_accepted"]) == want[side]
        assert int(last["frames_rejected"]) == 0
