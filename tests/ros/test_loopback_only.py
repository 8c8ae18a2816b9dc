"""Nothing of a loopback run leaves loopback: real node processes started as the demo and the tests
start them (softhand_sim.ros.env: LOCALHOST discovery, a domain of their own, the local Fast DDS
profile), every packet of their domain's ports counted on every interface of the machine."""
import socket

import pytest
from geometry_msgs.msg import PoseArray

from tests.support import netns
from tests.support.rosproc import RosGraph
from tests.tracking.test_play_node import TOPIC, tracker_bag

pytestmark = [pytest.mark.ros]


def test_a_replay_stays_on_loopback(ros_env, tmp_path):
    """play_node replays 100 frames to a listener in this process: the listener gets them, the
    capture sees the domain's DDS traffic on `lo`, and not one packet of it on any other interface
    (the capture covers every interface of the machine's namespace). Checked that it can fail: the
    same run with ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET put discovery multicast on eth0 and failed
    it. (Unicast to the machine's own addresses goes through `lo` in Linux, so a participant that
    also listens on other interfaces does not show here; ros/env keeps those out by the profile.)"""
    try:
        capture = netns.HostCapture(int(ros_env["ROS_DOMAIN_ID"]))
    except PermissionError:
        pytest.skip("counting packets on the machine's interfaces needs root (AF_PACKET)")
    try:
        tracker_bag(tmp_path / "bag", [0.01] * 99)
        with RosGraph(ros_env) as g:
            joints = g.listen(TOPIC, PoseArray)
            proc = g.start(["softhand-play", str(tmp_path / "bag"), "--wait-subscribers", "1"])
            assert proc.wait(60) == 0, proc.output()
            g.wait_until(lambda: len(joints) >= 100, 10, "all frames")
    finally:
        packets = capture.stop()
    interfaces = sorted({ifname for ifname, _ in packets})
    assert packets and "lo" in interfaces, "the capture saw no DDS packet at all: it would prove nothing"
    assert interfaces == ["lo"], f"DDS packets of the run's domain left loopback on {interfaces}"
    assert socket.if_nametoindex("lo")  # (the name the kernel gives loopback here)
