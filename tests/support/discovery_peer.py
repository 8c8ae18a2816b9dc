"""A participant for tests/ros/test_discovery.py, run as its own process.

    python discovery_peer.py publish NAME SECONDS   a node publishing /discovery_NAME for SECONDS
    python discovery_peer.py join COUNT TIMEOUT     a node that prints how long [s] it took to see a
                                                     publisher on COUNT /discovery_* topics
"""
import sys
import time

import rclpy
from std_msgs.msg import String


def publish(name: str, seconds: float) -> None:
    node = rclpy.create_node(f"discovery_{name}")
    pub = node.create_publisher(String, f"/discovery_{name}", 10)
    node.create_timer(0.01, lambda: pub.publish(String(data=name)))
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)


def join(count: int, timeout: float) -> None:
    t0 = time.monotonic()  # the participant is created below: its discovery starts there
    node = rclpy.create_node("discovery_joiner")
    seen = []
    while time.monotonic() - t0 < timeout:
        seen = [t for t, _ in node.get_topic_names_and_types()
                if t.startswith("/discovery_") and node.count_publishers(t)]
        if len(seen) >= count:
            break
        time.sleep(0.005)
    print(f"{time.monotonic() - t0:.3f} {len(seen)}")


if __name__ == "__main__":
    rclpy.init()
    if sys.argv[1] == "publish":
        publish(sys.argv[2], float(sys.argv[3]))
    else:
        join(int(sys.argv[2]), float(sys.argv[3]))
