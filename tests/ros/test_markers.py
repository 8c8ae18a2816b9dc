"""Viewer markers: contact force arrows, the ground in the scene markers."""
from types import SimpleNamespace

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from visualization_msgs.msg import Marker, MarkerArray

from softhand_sim.ros import markers as mk
from softhand_sim.ros import msgs as rm

IDENT = [0, 0, 0, 0, 0, 0, 1]


def _points(arrow):
    return np.array([[p.x, p.y, p.z] for p in arrow.points])


def test_contact_arrows_start_at_the_contact_and_scale_with_the_force():
    """One ARROW per contact from the point along the force (FORCE_SCALE m/N), slip coloured, largest first;
    a DELETEALL first; the label's text is the summed force magnitude; the CDR round trip keeps it all."""
    pts = np.array([[0.0, 0.0, 0.8], [0.01, 0.02, 0.81], [0.02, -0.01, 0.79]])
    frc = np.array([[0.0, 0.0, 1.0], [0.3, 0.4, 0.0], [0.0, -2.0, 0.0]])  # magnitudes 1, 0.5, 2 N
    slip = np.array([0, 1, 0])
    arr = deserialize_message(serialize_message(mk.contact_force_markers(pts, frc, slip, 7.5)), MarkerArray)
    assert arr.markers[0].action == Marker.DELETEALL
    arrows = [m for m in arr.markers if m.ns == mk.ARROW_NS]
    assert [m.type for m in arrows] == [Marker.ARROW] * 3 and [m.id for m in arrows] == [0, 1, 2]
    for arrow, i in zip(arrows, [2, 0, 1]):  # decreasing force
        p = _points(arrow)
        np.testing.assert_allclose(p[0], pts[i], atol=1e-12)
        np.testing.assert_allclose(p[1] - p[0], mk.FORCE_SCALE * frc[i], atol=1e-12)
        assert arrow.header.frame_id == "world" and rm.stamp_to_seconds(arrow.header.stamp) == 7.5
    assert (arrows[2].color.r, arrows[2].color.g) == pytest.approx(mk.SLIP_RGBA[:2])  # the slipping one
    assert (arrows[0].color.r, arrows[0].color.g) == pytest.approx(mk.STICK_RGBA[:2])
    (label,) = [m for m in arr.markers if m.ns == mk.TOTAL_NS]
    assert label.type == Marker.TEXT_VIEW_FACING and float(label.text) == pytest.approx(3.5, rel=1e-3)
    assert label.color.a == 1.0 and label.pose.position.z == pytest.approx(0.81 + mk.LABEL_LIFT)


def test_contact_arrows_capped_tiny_forces_visible_and_no_contacts():
    """More contacts than MAX_ARROWS: the largest are drawn, the total counts all; a tiny force still gets
    MIN_ARROW_LENGTH; no contacts: only the DELETEALL and an invisible label reading 0."""
    n = mk.MAX_ARROWS + 50
    pts = np.zeros((n, 3))
    frc = np.zeros((n, 3))
    frc[:, 2] = np.arange(1, n + 1) * 1e-3
    arr = mk.contact_force_markers(pts, frc, np.zeros(n), 0)
    arrows = [m for m in arr.markers if m.ns == mk.ARROW_NS]
    assert len(arrows) == mk.MAX_ARROWS
    assert _points(arrows[0])[1, 2] == pytest.approx(mk.FORCE_SCALE * n * 1e-3)
    assert _points(arrows[-1])[1, 2] == pytest.approx(max(mk.MIN_ARROW_LENGTH, mk.FORCE_SCALE * 51e-3))
    assert float(arr.markers[-1].text) == pytest.approx(frc[:, 2].sum(), rel=1e-3)
    tiny = mk.contact_force_markers([[0, 0, 0]], [[1e-6, 0, 0]], [0], 0)
    assert _points(tiny.markers[1])[1, 0] == pytest.approx(mk.MIN_ARROW_LENGTH)
    empty = mk.contact_force_markers(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), 0)
    assert [m.action for m in empty.markers] == [Marker.DELETEALL, Marker.ADD]
    assert float(empty.markers[1].text) == 0.0 and empty.markers[1].color.a == 0.0
    with pytest.raises(ValueError, match="one row per contact"):
        mk.contact_force_markers(np.zeros((2, 3)), np.zeros((3, 3)), np.zeros(2), 0)


def test_scene_markers_draw_the_ground_plane():
    """With ground_height the scene markers end with a thin square slab (ns 'ground') whose top face is
    the plane; the objects' markers and ids are unchanged; without it, no ground."""
    objs = [SimpleNamespace(name="table", shape="box", dims={"size": [0.8, 0.8, 0.75]},
                            pose=[0, 0, 0.375, 0, 0, 0, 1], static=True)]
    plain = rm.scene_markers(objs, 0)
    arr = rm.scene_markers(objs, 0, ground_height=-0.25)
    assert len(plain.markers) == 1 and len(arr.markers) == 2
    assert (arr.markers[0].ns, arr.markers[0].id, arr.markers[0].type) == ("world", 0, Marker.CUBE)
    g = arr.markers[1]
    assert (g.ns, g.id, g.type) == (rm.GROUND_NS, 0, Marker.CUBE)
    assert g.pose.position.z + 0.5 * g.scale.z == pytest.approx(-0.25)
    assert g.scale.x == g.scale.y == rm.GROUND_SIZE and g.scale.z < 0.01
