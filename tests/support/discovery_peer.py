"""A publishing participant for tests/ros/test_discovery.py, run as its own process.

    python discovery_peer.py NAME SECONDS    a node publishing /discovery_NAME for SECONDS
"""
import sys
import time

import rclpy
from std_msgs.msg import String


def main(name: str, seconds: float) -> None:
    rclpy.init()
    node = rclpy.create_node(f"discovery_{name}")
    pub = node.create_publisher(String, f"/discovery_{name}", 10)
    node.create_timer(0.01, lambda: pub.publish(String(data=name)))
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)


if __name__ == "__main__":
    main(sys.argv[1], float(sys.argv[2]))
