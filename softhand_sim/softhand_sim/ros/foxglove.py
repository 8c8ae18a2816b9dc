"""Forward live ROS topics to the Foxglove app over its WebSocket protocol (Foxglove's own SDK,
`foxglove-sdk`): one channel per topic, each message forwarded as rclpy receives it (CDR bytes,
never deserialized) with its type's ros2msg definition as the schema, as foxglove_bridge does.
`softhand view` (commands/view.py) is the command around it.
"""
from __future__ import annotations

import os
import threading
import time

from softhand_sim.topics import HEAVY_TOPICS

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765
#: Topics not forwarded by default: the full-resolution skin clouds (both sides) are heavy.
SKIPPED_BY_DEFAULT = HEAVY_TOPICS


def default_topics():
    """topic -> ROS type of every softhand topic a viewer shows (docs/INTERFACE.md)."""
    from softhand_sim.topics import TOPIC_TYPES

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

        from softhand_sim.ros.common import LATCHED_QOS, message_class
        from softhand_sim.topics import LATCHED_TOPICS

        view_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5,
                              reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE)
        self.node = node
        self.counts = {}
        self.channels = {}
        self.missing = {}  # topic -> type whose package is not installed (tf2_msgs without a C compiler)
        for topic, msgtype in topics.items():
            try:
                msg_class = message_class(msgtype)
            except ValueError:
                self.missing[topic] = msgtype
                continue
            self.counts[topic] = 0
            schema = foxglove.Schema(name=msgtype, encoding="ros2msg", data=ros2msg_schema(msgtype))
            channel = foxglove.Channel(topic, schema=schema, message_encoding="cdr", context=context)
            self.channels[topic] = channel
            node.create_subscription(msg_class, topic, self._forward(topic, channel),
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
    from rclpy.signals import SignalHandlerOptions

    context = foxglove.Context()
    try:
        server = foxglove.start_server(name="softhand", host=host, port=port, context=context)
    except RuntimeError as exc:  # the SDK's FoxgloveError: the port taken, the host not this machine's
        raise SystemExit(f"softhand view: cannot serve on ws://{host}:{port}: {exc} (another viewer or "
                         f"`softhand demo --view` may hold it; --port 0 takes any free port)") from None
    # rclpy's own SIGINT handler shuts the context down under a running spin_once, which then
    # fails ("the given context is not valid") and the viewer exited 1 on Ctrl-C now and then; as
    # run_node does for the nodes, the caller's signal handling sets `stop` instead
    rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("softhand_view")
    forwarder = TopicForwarder(node, topics, context=context)
    if forwarder.missing:  # e.g. /tf without tf2_msgs (no C compiler at set-up): the rest is served
        say(f"softhand view: not serving {', '.join(sorted(forwarder.missing))}: message package not installed "
            f"({', '.join(sorted(set(forwarder.missing.values())))}; see `make tf2_msgs`)")
    say(f"softhand view: serving {len(forwarder.counts)} topics on ws://{host}:{server.port} "
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


