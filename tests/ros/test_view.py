"""`softhand view`: live topics reach a WebSocket client over Foxglove's protocol, decodable as ROS messages.

Real processes: the viewer runs as a subprocess on the test's ROS domain; this process publishes the
skin marker, the scene markers and the contact markers with rclpy and reads them back as a Foxglove
client would (the `websockets` package: handshake with the protocol's subprotocol, JSON control
messages, binary message frames).
"""
import json
import re
import struct
import time

import numpy as np
import pytest
from rclpy.serialization import deserialize_message
from visualization_msgs.msg import Marker, MarkerArray

from softhand_sim.ros import markers as mk
from softhand_sim.ros import msgs as rm
from softhand_sim.topics import HEAVY_TOPICS
from tests.support.rosproc import RosGraph

pytestmark = [pytest.mark.ros]

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
MESSAGE_DATA = 0x01  # binary opcode: subscription id u32, log time u64, payload (little-endian)
WANTED = {"/hand/right/skin_marker": Marker, "/hand/left/skin_marker": Marker, "/world/markers": MarkerArray,
          mk.CONTACT_MARKERS_TOPIC: MarkerArray}


def _port_of(proc, graph, timeout=120.0):
    found = {}

    def listening():
        m = re.search(r"serving \d+ topics on ws://([\d.]+):(\d+)", proc.output())
        if m:
            found["host"], found["port"] = m.group(1), int(m.group(2))
        return bool(found)

    graph.wait_until(listening, timeout, "softhand view to listen", proc)
    return found["host"], found["port"]


def _listening_addresses(port):
    """IPv4 addresses with a socket listening on `port`, from /proc/net/tcp (state 0A = LISTEN)."""
    out = []
    for line in open("/proc/net/tcp").read().splitlines()[1:]:
        local, state = line.split()[1], line.split()[3]
        ip_hex, port_hex = local.split(":")
        if state == "0A" and int(port_hex, 16) == port:
            out.append(".".join(str(b) for b in bytes.fromhex(ip_hex)[::-1]))
    return out


def test_view_serves_hand_scene_and_contacts_to_a_websocket_client(ros_env):
    """The client sees one channel per softhand topic (cdr, ros2msg schema of the ROS type) but the
    heavy skin clouds, subscribes to both hands' skin, the scene and contact channels and decodes their
    messages to what was published; the server listens on 127.0.0.1 only."""
    from websockets.sync.client import connect

    with RosGraph(ros_env) as g:
        view = g.start(["softhand", "view", "--port", "0"])
        host, port = _port_of(view, g)
        assert host == "127.0.0.1" and _listening_addresses(port) == ["127.0.0.1"]

        pubs = {t: g.publisher(t, ty) for t, ty in WANTED.items()}
        for pub in pubs.values():
            g.wait_matched(pub, 1, 60.0, view)
        tri_v = np.array([[0, 0, 0.8], [0.1, 0, 0.8], [0, 0.1, 0.8], [0.1, 0.1, 0.8]])
        tris = np.array([[0, 1, 2], [1, 3, 2]])
        table = [type("O", (), dict(name="table", shape="box", dims={"size": [0.8, 0.8, 0.75]},
                                    pose=[0, 0, 0.375, 0, 0, 0, 1], static=True))()]
        contact_pts, contact_f = np.array([[0.0, 0.0, 0.8]]), np.array([[0.0, 0.0, 1.5]])

        def publish_all():
            stamp = time.time()
            pubs["/hand/right/skin_marker"].publish(rm.triangle_marker(tri_v, tris, stamp))
            pubs["/hand/left/skin_marker"].publish(rm.triangle_marker(tri_v, tris[:1], stamp, marker_id=1))
            pubs["/world/markers"].publish(rm.scene_markers(table, stamp, ground_height=0.0))
            pubs[mk.CONTACT_MARKERS_TOPIC].publish(mk.contact_force_markers(contact_pts, contact_f, [1], stamp))

        got = {}
        with connect(f"ws://127.0.0.1:{port}", subprotocols=SUBPROTOCOLS, open_timeout=30,
                     max_size=None) as ws:
            channels = {}
            deadline = time.monotonic() + 30
            while not set(WANTED) <= set(channels):
                assert time.monotonic() < deadline, f"advertised only {sorted(channels)}"
                msg = ws.recv(timeout=30)
                if isinstance(msg, str):
                    data = json.loads(msg)
                    if data.get("op") == "advertise":
                        channels.update({c["topic"]: c for c in data["channels"]})
            assert HEAVY_TOPICS.isdisjoint(channels), sorted(channels)  # skipped by default
            for topic, ty in WANTED.items():
                c = channels[topic]
                assert c["encoding"] == "cdr" and c["schemaEncoding"] == "ros2msg"
                assert c["schemaName"] == f"visualization_msgs/msg/{ty.__name__}"
                assert "MSG: geometry_msgs/Point" in c["schema"]  # the definition with its dependencies
            sub_ids = {i + 1: t for i, t in enumerate(WANTED)}
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                {"id": sid, "channelId": channels[t]["id"]} for sid, t in sub_ids.items()]}))
            deadline = time.monotonic() + 60
            while set(got) != set(WANTED):
                assert time.monotonic() < deadline, f"messages only on {sorted(got)}\n{view.output()}"
                publish_all()
                try:
                    msg = ws.recv(timeout=0.5)
                except TimeoutError:
                    continue
                if isinstance(msg, bytes) and msg[0] == MESSAGE_DATA:
                    sid, _log_time = struct.unpack_from("<IQ", msg, 1)
                    topic = sub_ids[sid]
                    got[topic] = deserialize_message(msg[13:], WANTED[topic])
        assert view.stop() == 0, view.output()

    skin = got["/hand/right/skin_marker"]
    assert skin.type == Marker.TRIANGLE_LIST and len(skin.points) == 6
    left = got["/hand/left/skin_marker"]
    assert left.type == Marker.TRIANGLE_LIST and len(left.points) == 3 and left.id == 1
    scene = got["/world/markers"].markers
    assert [(m.ns, m.type) for m in scene] == [("world", Marker.CUBE), (rm.GROUND_NS, Marker.CUBE)]
    contacts = got[mk.CONTACT_MARKERS_TOPIC].markers
    slipping = contacts[1]  # the one contact slips: its arrow is in the slip list
    assert (slipping.ns, slipping.id, slipping.type) == (mk.ARROW_NS, 1, Marker.TRIANGLE_LIST)
    tip_z = max(p.z for p in slipping.points)
    assert len(slipping.points) == 3 * mk.TRIANGLES_PER_ARROW and tip_z == pytest.approx(0.8 + mk.FORCE_SCALE * 1.5)
    assert float([m for m in contacts if m.ns == mk.TOTAL_NS][0].text) == pytest.approx(1.5)
