"""`softhand view`: the live softhand topics in the Foxglove app, without a ROS install.

A pip-only user has no foxglove_bridge and no RViz. This command subscribes to the softhand topics
with rclpy and serves them over Foxglove's WebSocket protocol with Foxglove's own SDK
(`foxglove-sdk`), one channel per topic. Each channel carries the topic's ROS 2 type: the message
is forwarded as rclpy receives it (CDR bytes, `raw=True`, never deserialized here) with the type's
ros2msg definition as the schema, which is what foxglove_bridge sends too; so the Foxglove 3D panel
draws /hand/skin_marker, /world/markers and /hand/contact_markers, and the Plot panel reads
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
import time

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765
#: Topics not forwarded by default: the full-resolution skin cloud is heavy and off by default.
SKIPPED_BY_DEFAULT = ("/hand/skin_vertices",)


def default_topics():
    """topic -> ROS type of every softhand topic a viewer shows (docs/INTERFACE.md)."""
    from softhand_sim.ros.common import TOPIC_TYPES

    return {t: ty for t, ty in TOPIC_TYPES.items() if t not in SKIPPED_BY_DEFAULT}


def ros2msg_schema(msgtype: str) -> bytes:
    """The ros2msg definition text of `pkg/msg/Name` with its dependencies (what rosbag2 and
    foxglove_bridge send as a channel schema), from rosbags' Jazzy type store."""
    from rosbags.typesys import Stores, get_typestore

    text, _ = get_typestore(Stores.ROS2_JAZZY).generate_msgdef(msgtype, ros_version=2)
    return text.encode()


class TopicForwarder:
    """Forwards ROS topics to Foxglove channels: CDR bytes in, the same bytes out.

    topics: topic -> ROS type name. Each topic gets a Foxglove channel with message encoding
    'cdr' and schema (name = ROS type, encoding 'ros2msg'). Subscriptions are best effort
    (they match reliable and best-effort publishers alike), transient local for latched topics.
    `counts` holds the messages forwarded per topic.
    """

    def __init__(self, node, topics, context=None):
        import foxglove
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

        from softhand_sim.ros.common import LATCHED_QOS, LATCHED_TOPICS, message_class

        view_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5,
                              reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE)
        self.node = node
        self.counts = {t: 0 for t in topics}
        self.channels = {}
        for topic, msgtype in topics.items():
            schema = foxglove.Schema(name=msgtype, encoding="ros2msg", data=ros2msg_schema(msgtype))
            channel = foxglove.Channel(topic, schema=schema, message_encoding="cdr", context=context)
            self.channels[topic] = channel
            node.create_subscription(message_class(msgtype), topic, self._forward(topic, channel),
                                     LATCHED_QOS if topic in LATCHED_TOPICS else view_qos, raw=True)

    def _forward(self, topic, channel):
        def on_message(raw: bytes):
            self.counts[topic] += 1
            channel.log(bytes(raw), log_time=time.time_ns())
        return on_message


def serve(topics, host=DEFAULT_HOST, port=DEFAULT_PORT, ready=None, stop=None, say=print):
    """Run the viewer until `stop` (threading.Event) is set or SIGINT; returns the forwarded counts.

    ready: an optional callback(server) called once the server listens (tests read the port).
    """
    import foxglove
    import rclpy
    from rclpy.executors import ExternalShutdownException

    context = foxglove.Context()
    server = foxglove.start_server(name="softhand", host=host, port=port, context=context)
    rclpy.init(args=[])
    node = rclpy.create_node("softhand_view")
    forwarder = TopicForwarder(node, topics, context=context)
    say(f"softhand view: serving {len(topics)} topics on ws://{host}:{server.port} "
        f"(ROS_DOMAIN_ID={os.environ.get('ROS_DOMAIN_ID', '0')}); in the Foxglove app: Open connection -> "
        f"Foxglove WebSocket -> ws://localhost:{server.port}; Ctrl-C stops")
    if ready is not None:
        ready(server)
    stop = stop or threading.Event()
    try:
        while not stop.is_set() and rclpy.ok():
            rclpy.spin_once(node, timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        server.stop()
        node.destroy_node()
        rclpy.try_shutdown()
    return dict(forwarder.counts)


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
    p.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"WebSocket port (default {DEFAULT_PORT}; 0 = any free)")
    p.add_argument("--domain-id", type=int, default=None,
                   help="ROS_DOMAIN_ID to join (default: the environment's ROS_DOMAIN_ID, else 0)")
    p.add_argument("--topics", nargs="+", default=None, metavar="TOPIC",
                   help="softhand topics to forward (default: all but /hand/skin_vertices)")
    return p


def main(argv=None):
    args = build_parser().parse_args(argv)
    from softhand_sim.ros.common import TOPIC_TYPES

    topics = default_topics()
    if args.topics:
        unknown = [t for t in args.topics if t not in TOPIC_TYPES]
        if unknown:
            raise SystemExit(f"error: unknown topic(s) {unknown}; softhand topics: {', '.join(TOPIC_TYPES)}")
        topics = {t: TOPIC_TYPES[t] for t in args.topics}
    # loopback-only discovery, like every softhand process; the domain is the one to watch
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
    if args.domain_id is not None:
        os.environ["ROS_DOMAIN_ID"] = str(args.domain_id)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    counts = serve(topics, host=args.host, port=args.port, stop=stop)
    print("softhand view: forwarded " + ", ".join(f"{t} {n}" for t, n in counts.items() if n), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
