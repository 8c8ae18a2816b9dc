"""`softhand view`: the live softhand topics in the Foxglove app, without a ROS install.

A pip-only user has no foxglove_bridge and no RViz. This command subscribes to the softhand topics
with rclpy and serves them over Foxglove's WebSocket protocol with Foxglove's own SDK
(`foxglove-sdk`), one channel per topic. Each channel carries the topic's ROS 2 type: the message
is forwarded as rclpy receives it (CDR bytes, `raw=True`, never deserialized here) with the type's
ros2msg definition as the schema, which is what foxglove_bridge sends too; so the Foxglove 3D panel
draws /hand/{right,left}/skin_marker, /world/markers, /hand/contact_markers and the /tf bone
frames, and the Plot panel reads
/diagnostics, exactly as from a recording (docs/foxglove/softhand_layout.json works for both).

The server binds to 127.0.0.1 by default: nothing leaves the machine. In the Foxglove app:
Open connection -> Foxglove WebSocket -> ws://localhost:8765.

ROS side: the command joins the ROS domain of the environment (ROS_DOMAIN_ID) or --domain-id, with
loopback-only discovery; `softhand demo --view` starts it inside the demo's own domain.
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import threading

from softhand_sim.ros.foxglove import DEFAULT_HOST, DEFAULT_PORT  # no rclpy at import


def _in_range(lo, hi, why):
    """An argparse type: an int within lo..hi, else an error naming the value and the range."""
    def parse(text):
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"{value} is outside {lo}..{hi} ({why})")
        return value
    return parse


def build_parser():
    p = argparse.ArgumentParser(
        prog="softhand view",
        description="Serve the live softhand topics to the Foxglove app over its WebSocket protocol "
                    "(Foxglove SDK; no ROS install needed). Open ws://localhost:PORT in Foxglove, then "
                    "import the layout docs/foxglove/softhand_layout.json.",
        epilog="example: softhand view --domain-id 42   (the domain `softhand demo` prints); "
               "or `softhand demo --view` to run both at once",
    )
    p.add_argument("--host", default=DEFAULT_HOST,
                   help=f"address to bind (default {DEFAULT_HOST}: this machine only; 0.0.0.0 exposes it to the network)")
    p.add_argument("--port", type=_in_range(0, 65535, "a TCP port"), default=DEFAULT_PORT,
                   help=f"WebSocket port (default {DEFAULT_PORT}; 0 = any free)")
    p.add_argument("--domain-id", type=_in_range(0, 232, "ROS 2's domain ids"), default=None,
                   help="ROS_DOMAIN_ID to join (default: the environment's ROS_DOMAIN_ID, else 0)")
    p.add_argument("--topics", nargs="+", default=None, metavar="TOPIC",
                   help="softhand topics to forward (default: all but the heavy /hand/{side}/skin_vertices)")
    return p


def main(argv=None):
    args = build_parser().parse_args(argv)
    from softhand_sim.topics import TOPIC_TYPES
    from softhand_sim.ros.env import set_loopback
    from softhand_sim.ros.foxglove import default_topics, serve  # rclpy from here on

    topics = default_topics()
    if args.topics:
        unknown = [t for t in args.topics if t not in TOPIC_TYPES]
        if unknown:
            raise SystemExit(f"error: unknown topic(s) {unknown}; softhand topics: {', '.join(TOPIC_TYPES)}")
        topics = {t: TOPIC_TYPES[t] for t in args.topics}
    # loopback-only discovery, like every softhand process (ros/env.py: the local profile, no LAN
    # profile); the domain is the one to watch
    set_loopback(os.environ)
    if args.domain_id is not None:
        os.environ["ROS_DOMAIN_ID"] = str(args.domain_id)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):  # Ctrl-C and SIGTERM end the serve loop cleanly
        signal.signal(sig, lambda *_: stop.set())
    counts = serve(topics, host=args.host, port=args.port, stop=stop)
    print("softhand view: forwarded " + ", ".join(f"{t} {n}" for t, n in counts.items() if n), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
