"""Viewer markers: contact force arrows, the ground in the scene markers, the Foxglove layout file."""
import json
from types import SimpleNamespace

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from visualization_msgs.msg import Marker, MarkerArray

from softhand_sim.ros import markers as mk
from softhand_sim.ros import msgs as rm
from softhand_sim.topics import TOPIC_TYPES

IDENT = [0, 0, 0, 0, 0, 0, 1]


def _arrows(marker):
    """(n, 9 triangles, 3 corners, 3) of an arrow TRIANGLE_LIST marker."""
    return np.array([[p.x, p.y, p.z] for p in marker.points]).reshape(-1, mk.TRIANGLES_PER_ARROW, 3, 3)


def _tip_and_base(arrow):
    """Tip (the cone's apex) and base centre (mean of the shaft's first ring) of one arrow."""
    ring = np.unique(np.round(np.concatenate([arrow[i * 3, :2] for i in range(3)]), 12), axis=0)
    centre = ring.mean(axis=0)
    tip = arrow[2, 2]
    return tip, centre


def test_contact_arrows_start_at_the_contact_and_scale_with_the_force():
    """Stick and slip arrows (one TRIANGLE_LIST each, green / orange) from each contact point along its
    force, FORCE_SCALE m/N long, largest first; the label's text is the summed force magnitude."""
    pts = np.array([[0.0, 0.0, 0.8], [0.01, 0.02, 0.81], [0.02, -0.01, 0.79]])
    frc = np.array([[0.0, 0.0, 1.0], [0.3, 0.4, 0.0], [0.0, -2.0, 0.0]])  # magnitudes 1, 0.5, 2 N
    slip = np.array([0, 1, 0])
    arr = deserialize_message(serialize_message(mk.contact_force_markers(pts, frc, slip, 7.5)), MarkerArray)
    stick, slipping, label = arr.markers
    assert [(m.ns, m.id, m.type) for m in arr.markers] == [
        (mk.ARROW_NS, 0, Marker.TRIANGLE_LIST), (mk.ARROW_NS, 1, Marker.TRIANGLE_LIST),
        (mk.TOTAL_NS, 0, Marker.TEXT_VIEW_FACING)]
    assert all(m.header.frame_id == "world" and rm.stamp_to_seconds(m.header.stamp) == 7.5 for m in arr.markers)
    assert (stick.color.r, stick.color.g) == pytest.approx(mk.STICK_RGBA[:2])
    assert (slipping.color.r, slipping.color.g) == pytest.approx(mk.SLIP_RGBA[:2])
    for marker, rows in ((stick, [2, 0]), (slipping, [1])):  # decreasing force within each marker
        arrows = _arrows(marker)
        assert len(arrows) == len(rows)
        for arrow, i in zip(arrows, rows):
            tip, centre = _tip_and_base(arrow)
            np.testing.assert_allclose(centre, pts[i], atol=1e-12)
            np.testing.assert_allclose(tip - pts[i], mk.FORCE_SCALE * frc[i], atol=1e-12)
            # every vertex lies within the head radius of the contact-to-tip segment
            d = frc[i] / np.linalg.norm(frc[i])
            rel = arrow.reshape(-1, 3) - pts[i]
            radial = np.linalg.norm(rel - np.outer(rel @ d, d), axis=1)
            assert radial.max() <= mk.HEAD_RADIUS + 1e-12
    assert float(label.text) == pytest.approx(3.5, rel=1e-3) and len(label.text) == mk.LABEL_WIDTH
    assert label.color.a == 1.0 and label.pose.position.z == pytest.approx(0.81 + mk.LABEL_LIFT)


def test_contact_arrows_capped_tiny_forces_visible_and_no_contacts():
    """More contacts than MAX_ARROWS: the largest are drawn, the total counts all; a tiny force still gets
    MIN_ARROW_LENGTH; no contacts: empty arrow lists and a transparent label reading 0."""
    n = mk.MAX_ARROWS + 50
    pts = np.zeros((n, 3))
    frc = np.zeros((n, 3))
    frc[:, 2] = np.arange(1, n + 1) * 1e-3
    arr = mk.contact_force_markers(pts, frc, np.zeros(n), 0)
    arrows = _arrows(arr.markers[0])
    assert len(arrows) == mk.MAX_ARROWS and len(arr.markers[1].points) == 0
    assert _tip_and_base(arrows[0])[0][2] == pytest.approx(mk.FORCE_SCALE * n * 1e-3)
    assert _tip_and_base(arrows[-1])[0][2] == pytest.approx(max(mk.MIN_ARROW_LENGTH, mk.FORCE_SCALE * 51e-3))
    assert float(arr.markers[2].text) == pytest.approx(frc[:, 2].sum(), rel=1e-3)
    tiny = _arrows(mk.contact_force_markers([[0, 0, 0]], [[1e-6, 0, 0]], [0], 0).markers[0])[0]
    assert _tip_and_base(tiny)[0] == pytest.approx([mk.MIN_ARROW_LENGTH, 0, 0])
    empty = mk.contact_force_markers(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), 0)
    assert [len(m.points) for m in empty.markers[:2]] == [0, 0]
    assert float(empty.markers[2].text) == 0.0 and empty.markers[2].color.a == 0.0
    with pytest.raises(ValueError, match="one row per contact"):
        mk.contact_force_markers(np.zeros((2, 3)), np.zeros((3, 3)), np.zeros(2), 0)


@pytest.mark.parametrize("n", [0, 1, 7, 130])
def test_fast_contact_marker_bytes_decode_to_the_rclpy_message(n):
    """ContactMarkerSerializer's numpy-built CDR decodes to exactly the message contact_force_markers builds
    (stamps, both arrow lists, label position, alpha and text), for several contact counts in a row."""
    rng = np.random.default_rng(n)
    ser = mk.ContactMarkerSerializer()
    for k in range(2):  # the serializer is reused: nothing of the previous message may remain
        pts, frc = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
        slip = rng.integers(0, 2, n)
        stamp = 1_700_000_000_123_456_789 + k
        fast = deserialize_message(ser.serialize(pts, frc, slip, stamp), MarkerArray)
        ref = mk.contact_force_markers(pts, frc, slip, stamp)
        assert fast == deserialize_message(serialize_message(ref), MarkerArray)  # colours as float32


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


def _layout(repo_root):
    return json.loads((repo_root / "docs" / "foxglove" / "softhand_layout.json").read_text())


def _panel_ids(node):
    if isinstance(node, str):
        return [node]
    return _panel_ids(node["first"]) + _panel_ids(node["second"])


def test_foxglove_layout_names_only_softhand_topics(repo_root):
    """The layout file: every panel of the tree is configured; the 3D panel shows both hands' skin
    markers, the bone frames (/tf), the scene and contact markers; every plotted path starts with a
    softhand topic; the force plot reads the label."""
    layout = _layout(repo_root)
    assert sorted(_panel_ids(layout["layout"])) == sorted(layout["configById"])
    three_d = next(v for k, v in layout["configById"].items() if k.startswith("3D!"))
    shown = {t for t, s in three_d["topics"].items() if s.get("visible")}
    assert shown == {"/hand/right/skin_marker", "/hand/left/skin_marker", "/tf", "/world/markers",
                     mk.CONTACT_MARKERS_TOPIC}
    assert set(three_d["topics"]) <= set(TOPIC_TYPES)
    paths = [p["value"] for k, v in layout["configById"].items() if k.startswith("Plot!") for p in v["paths"]]
    assert paths and all(p.split(".")[0] in TOPIC_TYPES for p in paths)
    assert f'{mk.CONTACT_MARKERS_TOPIC}.markers[:]{{ns=="{mk.TOTAL_NS}"}}.text' in paths
    assert any(p.startswith("/diagnostics.") and "step_ms" in p for p in paths)
