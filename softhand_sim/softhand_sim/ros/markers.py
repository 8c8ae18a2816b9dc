"""Viewer markers built from simulation outputs: contact forces as arrows (/hand/contact_markers).

Message types only, like ros/msgs.py: no node here. RViz and Foxglove's 3D panel draw a
visualization_msgs/MarkerArray; this one holds

- a DELETEALL marker first, so arrows of contacts that ended vanish with the next message;
- one ARROW per contact (ns ``contact_forces``), from the contact point along the force on the
  hand, ``FORCE_SCALE`` metres per newton, green where the contact sticks and orange where it
  slips; the ``MAX_ARROWS`` largest forces only (a grasp has tens, a flat press a few hundred);
- one TEXT_VIEW_FACING marker (ns ``total_force``) above the contacts whose text is the summed
  magnitude of all contact forces in newtons, as a bare number ("0.8421"). A bare number is what
  Foxglove's Plot panel can read from a text field (it converts numeric strings), so the layout in
  docs/foxglove/ plots `/hand/contact_markers.markers[:]{ns=="total_force"}.text` over time
  without a separate topic.
"""
from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Point
from visualization_msgs.msg import Marker, MarkerArray

from softhand_sim.ros.msgs import WORLD_FRAME, _check_rows, _color, make_header

CONTACT_MARKERS_TOPIC = "/hand/contact_markers"
ARROW_NS = "contact_forces"
TOTAL_NS = "total_force"
FORCE_SCALE = 0.05        # [m/N] arrow length per newton of contact force
MIN_ARROW_LENGTH = 0.004  # [m] shorter arrows (< 0.08 N) are drawn at this length, still visible
MAX_ARROWS = 200          # arrows per message: the largest forces (the total counts all contacts)
SHAFT_DIAMETER = 0.0015   # [m]
HEAD_DIAMETER = 0.004     # [m]
HEAD_LENGTH = 0.003       # [m]
LABEL_HEIGHT = 0.012      # [m] text height of the total-force label
LABEL_LIFT = 0.04         # [m] the label floats this far above the highest contact
STICK_RGBA = (0.1, 0.8, 0.2, 1.0)
SLIP_RGBA = (1.0, 0.55, 0.0, 1.0)
LABEL_RGBA = (1.0, 1.0, 1.0, 1.0)


def total_force(forces) -> float:
    """Sum of the contact force magnitudes [N] of forces (n, 3) [N]."""
    f = np.asarray(forces, dtype=np.float64).reshape(-1, 3)
    return float(np.linalg.norm(f, axis=1).sum())


def contact_force_markers(points, forces, slip, stamp, frame_id: str = WORLD_FRAME,
                          force_scale: float = FORCE_SCALE, max_arrows: int = MAX_ARROWS) -> MarkerArray:
    """MarkerArray of contact force arrows and the total-force label (see the module docstring).

    points (n, 3) [m] contact points, forces (n, 3) [N] force on the hand, slip (n,) 0 stick /
    1 slip, stamp as Time, int ns or float s; force_scale [m/N]. Arrow ids are 0..k-1 in order of
    decreasing force; the label is id 0 of its namespace.
    """
    p = _check_rows("points", points, 3)
    f = _check_rows("forces", forces, 3)
    s = np.asarray(slip).reshape(-1)
    if f.shape[0] != p.shape[0] or s.shape[0] != p.shape[0]:
        raise ValueError(f"forces ({f.shape[0]}) and slip ({s.shape[0]}) need one row per contact point ({p.shape[0]})")
    header = make_header(stamp, frame_id)
    clear = Marker(header=header, action=Marker.DELETEALL)
    magnitude = np.linalg.norm(f, axis=1)
    order = np.argsort(-magnitude, kind="stable")[:max_arrows]
    length = np.maximum(force_scale * magnitude[order], MIN_ARROW_LENGTH)
    direction = f[order] / np.maximum(magnitude[order], 1e-12)[:, None]
    tips = p[order] + length[:, None] * direction
    stick, slipping = _color(STICK_RGBA), _color(SLIP_RGBA)
    markers = [clear]
    for k, (i, start, tip) in enumerate(zip(order.tolist(), p[order].tolist(), tips.tolist())):
        m = Marker(header=header, ns=ARROW_NS, id=k, type=Marker.ARROW, action=Marker.ADD,
                   color=slipping if s[i] else stick)
        m.pose.orientation.w = 1.0  # with points, the arrow is drawn between them in the frame
        m.scale.x, m.scale.y, m.scale.z = SHAFT_DIAMETER, HEAD_DIAMETER, HEAD_LENGTH
        m.points = [Point(x=start[0], y=start[1], z=start[2]), Point(x=tip[0], y=tip[1], z=tip[2])]
        markers.append(m)
    label = Marker(header=header, ns=TOTAL_NS, id=0, type=Marker.TEXT_VIEW_FACING, action=Marker.ADD,
                   text=f"{total_force(f):.4g}")
    label.pose.orientation.w = 1.0
    if p.shape[0]:
        top = p[np.argmax(p[:, 2])]
        label.pose.position.x, label.pose.position.y = float(p[:, 0].mean()), float(p[:, 1].mean())
        label.pose.position.z = float(top[2]) + LABEL_LIFT
        label.color = _color(LABEL_RGBA)
    else:  # nothing touches: the plot still gets its 0, the 3D view shows no label
        label.color = _color(LABEL_RGBA[:3] + (0.0,))
    label.scale.z = LABEL_HEIGHT
    markers.append(label)
    return MarkerArray(markers=markers)
