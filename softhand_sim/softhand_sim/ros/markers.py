"""Viewer markers built from simulation outputs: contact forces as arrows (/hand/contact_markers).

Message types only, like ros/msgs.py: no node here. RViz and Foxglove's 3D panel draw a
visualization_msgs/MarkerArray; this one always holds three markers:

- id 0, ns ``contact_forces``: the arrows of the contacts that stick (green), one TRIANGLE_LIST;
- id 1, same ns: the arrows of the contacts that slip (orange);
- id 0, ns ``total_force``: a TEXT_VIEW_FACING label above the contacts whose text is the summed
  magnitude of all contact forces in newtons, a right-aligned number ("    0.8421"). A number is
  what Foxglove's Plot panel can read from a text field (it converts numeric strings), so the
  layout in docs/foxglove/ plots `/hand/contact_markers.markers[:]{ns=="total_force"}.text`
  without a topic of its own. Without contacts the label is transparent and reads 0.

Each arrow starts at the contact point and points along the force on the hand, FORCE_SCALE metres
per newton (at least MIN_ARROW_LENGTH), a three-sided shaft and a three-sided cone: 9 triangles.
The MAX_ARROWS largest forces are drawn; the total counts every contact. The same ids every
message, so a message replaces the previous arrows whole (no DELETEALL needed).

Why triangles and not one ARROW marker per contact: rclpy builds and serializes a Marker in about
0.5 ms on this project's 2 shared cores, i.e. 50 ms for 100 contacts at each skin marker tick, in
sim_node's thread. `ContactMarkerSerializer` writes the CDR bytes with numpy instead (as
msgs.TriangleMarkerSerializer does for the skin) in well under a millisecond.
"""
from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Point
from visualization_msgs.msg import Marker, MarkerArray

from softhand_sim.ros.msgs import WORLD_FRAME, _as_time, _check_rows, _color, make_header

CONTACT_MARKERS_TOPIC = "/hand/contact_markers"
ARROW_NS = "contact_forces"
TOTAL_NS = "total_force"
FORCE_SCALE = 0.05        # [m/N] arrow length per newton of contact force
MIN_ARROW_LENGTH = 0.004  # [m] shorter arrows (< 0.08 N) are drawn at this length, still visible
MAX_ARROWS = 100          # arrows per message: the largest forces (the total counts all contacts)
SHAFT_RADIUS = 0.0008     # [m]
HEAD_RADIUS = 0.0022      # [m]
HEAD_LENGTH = 0.004       # [m] (at most half the arrow)
TRIANGLES_PER_ARROW = 9
LABEL_HEIGHT = 0.012      # [m] text height of the total-force label
LABEL_LIFT = 0.04         # [m] the label floats this far above the highest contact
LABEL_WIDTH = 10          # characters: fixed, so the serialized message keeps its layout
STICK_RGBA = (0.1, 0.8, 0.2, 1.0)
SLIP_RGBA = (1.0, 0.55, 0.0, 1.0)
LABEL_RGBA = (1.0, 1.0, 1.0, 1.0)


def total_force(forces) -> float:
    """Sum of the contact force magnitudes [N] of forces (n, 3) [N]."""
    f = np.asarray(forces, dtype=np.float64).reshape(-1, 3)
    return float(np.linalg.norm(f, axis=1).sum())


def format_total(total: float) -> str:
    """The label text: the total force [N], right-aligned in LABEL_WIDTH characters."""
    return f"{total:{LABEL_WIDTH}.4g}"[-LABEL_WIDTH:]


# Arrow corners: 0-2 the shaft's base ring, 3-5 its neck ring, 6-8 the head's ring, 9 the tip.
_ARROW_FACES = np.array([f for k in range(3) for f in
                         ((k, (k + 1) % 3, 3 + (k + 1) % 3), (k, 3 + (k + 1) % 3, 3 + k),
                          (6 + k, 6 + (k + 1) % 3, 9))])
_RING = np.stack([np.cos(2.0 * np.pi * np.arange(3) / 3.0), np.sin(2.0 * np.pi * np.arange(3) / 3.0)], axis=1)


def arrow_triangles(starts, forces, force_scale: float = FORCE_SCALE) -> np.ndarray:
    """Triangle-list vertices (9 * 3 * n, 3) [m] of one arrow per force (n, 3) [N] from starts (n, 3) [m]."""
    p = np.asarray(starts, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(forces, dtype=np.float64).reshape(-1, 3)
    n = p.shape[0]
    if n == 0:
        return np.zeros((0, 3))
    mag = np.sqrt((f * f).sum(axis=1))
    d = f / np.maximum(mag, 1e-12)[:, None]
    d[mag <= 1e-12] = (0.0, 0.0, 1.0)
    length = np.maximum(force_scale * mag, MIN_ARROW_LENGTH)
    head = np.minimum(HEAD_LENGTH, 0.5 * length)
    # u: across the arrow (d x z, or d x x when d is near z); v = d x u
    near_z = np.abs(d[:, 2]) >= 0.9
    u = np.where(near_z[:, None], np.stack([np.zeros(n), d[:, 2], -d[:, 1]], axis=1),
                 np.stack([d[:, 1], -d[:, 0], np.zeros(n)], axis=1))
    u /= np.sqrt((u * u).sum(axis=1))[:, None]
    v = np.stack([d[:, 1] * u[:, 2] - d[:, 2] * u[:, 1], d[:, 2] * u[:, 0] - d[:, 0] * u[:, 2],
                  d[:, 0] * u[:, 1] - d[:, 1] * u[:, 0]], axis=1)
    ring = _RING[None, :, 0, None] * u[:, None, :] + _RING[None, :, 1, None] * v[:, None, :]  # (n, 3, 3)
    neck = p + (length - head)[:, None] * d
    corners = np.concatenate([p[:, None] + SHAFT_RADIUS * ring, neck[:, None] + SHAFT_RADIUS * ring,
                              neck[:, None] + HEAD_RADIUS * ring, (p + length[:, None] * d)[:, None]], axis=1)
    return corners[:, _ARROW_FACES].reshape(-1, 3)


def _split_contacts(points, forces, slip, max_arrows):
    p = _check_rows("points", points, 3)
    f = _check_rows("forces", forces, 3)
    s = np.asarray(slip).reshape(-1)
    if f.shape[0] != p.shape[0] or s.shape[0] != p.shape[0]:
        raise ValueError(f"forces ({f.shape[0]}) and slip ({s.shape[0]}) need one row per contact point ({p.shape[0]})")
    keep = np.argsort(-np.linalg.norm(f, axis=1), kind="stable")[:max_arrows]
    slipping = s[keep].astype(bool)
    return p, f, keep[~slipping], keep[slipping]


def _label_pose(p):
    if p.shape[0] == 0:
        return np.zeros(3), 0.0
    return np.array([p[:, 0].mean(), p[:, 1].mean(), p[:, 2].max() + LABEL_LIFT]), 1.0


def contact_force_markers(points, forces, slip, stamp, frame_id: str = WORLD_FRAME,
                          force_scale: float = FORCE_SCALE, max_arrows: int = MAX_ARROWS) -> MarkerArray:
    """MarkerArray of the contact force arrows and the total-force label (see the module docstring).

    points (n, 3) [m] contact points, forces (n, 3) [N] force on the hand, slip (n,) 0 stick /
    1 slip, stamp as Time, int ns or float s; force_scale [m/N]. The rclpy message (tests, tools);
    sim_node publishes ContactMarkerSerializer's bytes of the same message.
    """
    p, f, stick, slipping = _split_contacts(points, forces, slip, max_arrows)
    header = make_header(stamp, frame_id)
    markers = []
    for marker_id, rows, rgba in ((0, stick, STICK_RGBA), (1, slipping, SLIP_RGBA)):
        m = Marker(header=header, ns=ARROW_NS, id=marker_id, type=Marker.TRIANGLE_LIST, action=Marker.ADD,
                   color=_color(rgba))
        m.pose.orientation.w = 1.0
        m.scale.x = m.scale.y = m.scale.z = 1.0
        m.points = [Point(x=x, y=y, z=z) for x, y, z in arrow_triangles(p[rows], f[rows], force_scale).tolist()]
        markers.append(m)
    position, alpha = _label_pose(p)
    label = Marker(header=header, ns=TOTAL_NS, id=0, type=Marker.TEXT_VIEW_FACING, action=Marker.ADD,
                   text=format_total(total_force(f)), color=_color(LABEL_RGBA[:3] + (alpha,)))
    label.pose.position.x, label.pose.position.y, label.pose.position.z = (float(c) for c in position)
    label.pose.orientation.w = 1.0
    label.scale.z = LABEL_HEIGHT
    markers.append(label)
    return MarkerArray(markers=markers)


class ContactMarkerSerializer:
    """CDR bytes of `contact_force_markers(...)` written with numpy, for sim_node's timer.

    The message's layout is fixed but for the two arrow point lists, whose float64 blocks are
    24 bytes per point (a multiple of 8, so every later field keeps its alignment). The bytes are
    taken once from rclpy's serialization of a template whose stamps, point values, label
    position, label alpha and label text are recognisable sentinels; serialize() splices the
    current values in. tests/ros/test_markers.py checks that the bytes decode to the same message
    as contact_force_markers builds.
    """

    _SEC, _NSEC = 1_234_567_891, 987_654_321
    _POINTS = ((1.25, 2.25, 3.25), (4.75, 5.75, 6.75))
    _LABEL_XYZ = (7.125, 8.125, 9.125)
    _TEXT = "#" * LABEL_WIDTH

    def __init__(self, frame_id: str = WORLD_FRAME, force_scale: float = FORCE_SCALE,
                 max_arrows: int = MAX_ARROWS):
        from rclpy.serialization import serialize_message

        self.force_scale, self.max_arrows = force_scale, max_arrows
        stamp = (self._SEC * 1_000_000_000 + self._NSEC)
        template = contact_force_markers([[0.0, 0.0, 0.0]], [[0.0, 0.0, 1.0]], [0], stamp, frame_id)
        for m, xyz in zip(template.markers[:2], self._POINTS):
            m.points = [Point(x=xyz[0], y=xyz[1], z=xyz[2])]
        label = template.markers[2]
        label.pose.position.x, label.pose.position.y, label.pose.position.z = self._LABEL_XYZ
        label.text = self._TEXT
        label.color.a = 0.375  # a float32 sentinel for the label's alpha
        raw = serialize_message(template)
        cuts = []  # (count offset, data offset) of each point list
        for xyz in self._POINTS:
            data = raw.find(np.array(xyz, "<f8").tobytes())
            one = np.array([1], "<u4").tobytes()
            if data < 0 or one not in (raw[data - 4:data], raw[data - 8:data - 4]):
                raise RuntimeError("unexpected MarkerArray CDR layout (is the platform big-endian?)")
            cuts.append((data - 4 if raw[data - 4:data] == one else data - 8, data))
        (c0, d0), (c1, d1) = cuts
        self._pieces = [bytearray(raw[:c0]), bytearray(raw[d0 + 24:c1]), bytearray(raw[d1 + 24:])]
        self._pads = [b"\x00" * (d0 - c0 - 4), b"\x00" * (d1 - c1 - 4)]
        stamp_bytes = np.array([self._SEC], "<i4").tobytes() + np.array([self._NSEC], "<u4").tobytes()
        self._stamps = [[i for i in _find_all(piece, stamp_bytes)] for piece in self._pieces]
        last = self._pieces[2]
        self._label_xyz = last.find(np.array(self._LABEL_XYZ, "<f8").tobytes())
        self._label_text = last.find(self._TEXT.encode())
        self._label_alpha = last.find(np.array([0.375], "<f4").tobytes())
        if min(self._label_xyz, self._label_text, self._label_alpha) < 0 or sum(map(len, self._stamps)) != 3:
            raise RuntimeError("unexpected MarkerArray CDR layout: label or stamps not found")

    def serialize(self, points, forces, slip, stamp) -> bytes:
        """CDR bytes of the /hand/contact_markers message (arguments as contact_force_markers)."""
        p, f, stick, slipping = _split_contacts(points, forces, slip, self.max_arrows)
        t = _as_time(stamp)
        stamp_bytes = np.array([t.sec], "<i4").tobytes() + np.array([t.nanosec], "<u4").tobytes()
        for piece, offsets in zip(self._pieces, self._stamps):
            for i in offsets:
                piece[i:i + 8] = stamp_bytes
        position, alpha = _label_pose(p)
        last = self._pieces[2]
        last[self._label_xyz:self._label_xyz + 24] = np.asarray(position, "<f8").tobytes()
        last[self._label_text:self._label_text + LABEL_WIDTH] = format_total(total_force(f)).encode()
        last[self._label_alpha:self._label_alpha + 4] = np.array([alpha], "<f4").tobytes()
        blocks = []
        for rows, pad in ((stick, self._pads[0]), (slipping, self._pads[1])):
            pts = np.ascontiguousarray(arrow_triangles(p[rows], f[rows], self.force_scale), dtype="<f8")
            blocks.append(np.array([pts.shape[0]], "<u4").tobytes() + pad + pts.tobytes())
        return b"".join((self._pieces[0], blocks[0], self._pieces[1], blocks[1], self._pieces[2]))


def _find_all(buf: bytes, pattern: bytes):
    i = buf.find(pattern)
    while i >= 0:
        yield i
        i = buf.find(pattern, i + 1)
