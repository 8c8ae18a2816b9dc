"""A short-lived rclpy node that waits until topics have publishers (used by `softhand demo`)."""
import time


def wait_for_topics(topics, timeout, procs):
    """Block until every topic has a publisher; returns the topics still missing after `timeout` [s].

    `procs` (demo.ProcessSet) is watched meanwhile: a child that exits ends the wait with its log.
    """
    import rclpy

    rclpy.init(args=[])
    node = rclpy.create_node("softhand_demo_probe")
    try:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            missing = [t for t in topics if node.count_publishers(t) == 0]
            if not missing:
                return []
            dead = procs.exited()
            if dead:
                raise SystemExit(f"error: {dead[0]} node exited during start-up:\n{procs.tail(dead[0])}")
            rclpy.spin_once(node, timeout_sec=0.2)
        return missing
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
