"""Wait until this host's view of the ROS graph has the given publishers and subscribers.

    python graph_probe.py --timeout 60 --pub /world/object_states --sub /hand/right/bones:1

Run inside a host namespace (tests/support/netns.py): the discovery of another host is done when
its publishers and subscribers show here. Exit 0 when every condition holds ("graph complete after
T s" on stdout, T counted from this probe's node creation: how long a newcomer took to find the
graph), 1 with the missing ones on stdout after the timeout. Uses the environment's ROS_DOMAIN_ID
and discovery range.
"""
import argparse
import sys
import time

import rclpy


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--pub", nargs="*", default=[], help="TOPIC[:N]: at least N (1) publishers")
    ap.add_argument("--sub", nargs="*", default=[], help="TOPIC[:N]: at least N (1) subscribers")
    ap.add_argument("--timeout", type=float, default=60.0)
    args = ap.parse_args(argv)

    def parse(items):
        return [(t.rsplit(":", 1)[0], int(t.rsplit(":", 1)[1])) if ":" in t else (t, 1) for t in items]

    pubs, subs = parse(args.pub), parse(args.sub)
    rclpy.init(args=[])
    t0 = time.monotonic()  # before the node (and its participant) exists
    node = rclpy.create_node("graph_probe")
    try:
        deadline = t0 + args.timeout
        while True:
            missing = [f"pub {t} ({node.count_publishers(t)}/{n})" for t, n in pubs if node.count_publishers(t) < n]
            missing += [f"sub {t} ({node.count_subscribers(t)}/{n})" for t, n in subs if node.count_subscribers(t) < n]
            if not missing:
                print(f"graph complete after {time.monotonic() - t0:.3f} s", flush=True)
                return 0
            if time.monotonic() > deadline:
                print("missing: " + ", ".join(missing), flush=True)
                return 1
            rclpy.spin_once(node, timeout_sec=0.02)  # graph changes wake no wait: poll
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
