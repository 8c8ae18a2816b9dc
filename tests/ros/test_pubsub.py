"""Real rclpy pub/sub between two separate processes in the venv, with the discovery rule applied
by the code that starts them (softhand_sim.ros.env.isolated_env via the ros_env fixture)."""
import sys
import textwrap

import pytest

from tests.support.rosproc import RosProc
from softhand_sim.ros.env import isolated_env

pytestmark = pytest.mark.ros

N = 20

TALKER = textwrap.dedent(f"""
    import os, time, rclpy
    from std_msgs.msg import String
    print("ENV", os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE"), os.environ.get("ROS_DOMAIN_ID"), flush=True)
    rclpy.init()
    node = rclpy.create_node("talker")
    pub = node.create_publisher(String, "/chatter", 100)
    deadline = time.monotonic() + 30
    while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
        time.sleep(0.05)
    for i in range({N}):
        pub.publish(String(data=f"hello {{i}}"))
        time.sleep(0.01)
    pub.wait_for_all_acked(rclpy.duration.Duration(seconds=5))
    print("SENT", pub.get_subscription_count(), flush=True)
    node.destroy_node(); rclpy.shutdown()
""")

LISTENER = textwrap.dedent(f"""
    import os, sys, time, rclpy
    from std_msgs.msg import String
    print("ENV", os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE"), os.environ.get("ROS_DOMAIN_ID"), flush=True)
    rclpy.init()
    node = rclpy.create_node("listener")
    got = []
    node.create_subscription(String, "/chatter", lambda m: got.append(m.data), 100)
    deadline = time.monotonic() + float(sys.argv[1])
    while len(got) < {N} and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    print("GOT", len(got), got[:1], flush=True)
    node.destroy_node(); rclpy.shutdown()
""")


def _env_line(out: str):
    return next(line.split()[1:] for line in out.splitlines() if line.startswith("ENV"))


def test_two_processes_talk_on_loopback_with_own_domain(ros_env):
    """A talker and a listener process exchange all N messages; both children got LOCALHOST and the test's domain."""
    listener = RosProc([sys.executable, "-c", LISTENER, "25"], ros_env)
    other = isolated_env(domain_id=(int(ros_env["ROS_DOMAIN_ID"]) - 40 + 30) % 61 + 40)  # another domain
    stranger = RosProc([sys.executable, "-c", LISTENER, "8"], other)
    talker = RosProc([sys.executable, "-c", TALKER], ros_env)
    try:
        assert talker.wait(40) == 0, talker.output()
        assert listener.wait(40) == 0, listener.output()
        assert stranger.wait(40) == 0, stranger.output()
        for proc in (talker, listener):
            assert _env_line(proc.output()) == ["LOCALHOST", ros_env["ROS_DOMAIN_ID"]]
        assert f"GOT {N} ['hello 0']" in listener.output()
        # the same program on another domain id hears nothing: the isolation is real
        assert _env_line(stranger.output()) == ["LOCALHOST", other["ROS_DOMAIN_ID"]]
        assert other["ROS_DOMAIN_ID"] != ros_env["ROS_DOMAIN_ID"]
        assert "GOT 0 []" in stranger.output()
    finally:
        for proc in (talker, listener, stranger):
            proc.cleanup()
