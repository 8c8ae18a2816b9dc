"""The independent penetration measure of skin-skin contact (physics/contact/penetration.py):
inside by the winding number of the other segment's closed skin, depth = distance to the nearest
skin the point may touch; checked on boxes with known depths and on the hand at rest."""
from types import SimpleNamespace

import numpy as np

from softhand_sim.physics.contact.penetration import SegmentSurfaces

# a box as 12 outward triangles over its 8 corners (index = 4 x + 2 y + z)
_BOX_TRIS = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])


def _box(lo, hi):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return np.array([[(hi if (k >> (2 - i)) & 1 else lo)[i] for i in range(3)] for k in range(8)])


def _two_segments(a_verts, a_tris, b_verts, b_tris):
    """A two-segment 'skin' (segment 0 = a, 1 = b) in the fields SegmentSurfaces reads."""
    x = np.vstack([a_verts, b_verts])
    tris = np.vstack([a_tris, np.asarray(b_tris) + len(a_verts)])
    smodel = SimpleNamespace(point_segment=np.r_[np.zeros(len(a_verts), np.int32), np.ones(len(b_verts), np.int32)],
                             point_rest=x, pair_ok=np.array([[0, 1], [1, 0]], np.uint8),
                             point_exclude=np.zeros(len(x), np.uint64), segment_count=2)
    return SegmentSurfaces(smodel, tris), x


def _outward(tris, verts):
    """Every triangle of a closed box faces away from its centre (the test's own data is right)."""
    c = verts.mean(axis=0)
    v = verts[tris]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    return np.all(np.einsum("ij,ij->i", n, v.mean(axis=1) - c) > 0)


def test_a_box_corner_pushed_into_another_box_is_as_deep_as_it_went():
    """Box b's four corners at x = 0.9 lie 0.1 inside box a (the nearest face x = 1), the rest
    outside: deepest 0.1, four points inside; moved clear, nothing is inside."""
    a = _box([0, 0, 0], [1, 1, 1])
    assert _outward(_BOX_TRIS, a)
    surfaces, x = _two_segments(a, _BOX_TRIS, _box([0.9, 0.3, 0.4], [1.3, 0.6, 0.7]), _BOX_TRIS)
    depth, point, segment, inside = surfaces.deepest(x)
    assert inside == 4 and segment == 0 and point >= 8
    np.testing.assert_allclose(depth, 0.1, atol=1e-12)
    x[8:, 0] += 0.2
    assert surfaces.deepest(x) == (0.0, -1, -1, 0)


def test_an_open_segment_is_closed_by_its_cap_and_the_cap_is_no_skin():
    """Box a without its x = 1 face (a segment cut open at a joint): the cap closes it, so a point
    at x = 0.95 is inside; its depth is its distance to the skin (the box's other faces: 0.2 to
    y = 1), not to the cap (0.05)."""
    a = _box([0, 0, 0], [1, 1, 1])
    open_tris = np.array([t for t in _BOX_TRIS if not np.all(a[t][:, 0] == 1.0)])
    assert len(open_tris) == 10
    b = _box([0.95, 0.8, 0.3], [1.5, 1.4, 0.7])
    surfaces, x = _two_segments(a, open_tris, b, _BOX_TRIS)
    depth, point, segment, inside = surfaces.deepest(x)
    assert inside == 2 and segment == 0
    np.testing.assert_allclose(depth, 0.2, atol=1e-12)


def test_nothing_is_inside_anything_on_the_hand_at_rest():
    """The coarse hand at rest (open, fingers apart): no skin point lies inside a segment it may
    touch; the index's distal segment moved onto the middle finger's (its skin points carried
    halfway between the two centres), it is inside the middle finger, millimetres deep."""
    from softhand_sim.handmodel import load_or_build_hand
    from softhand_sim.handmodel.rigid_skin import skin_segments
    from softhand_sim.physics.contact.self_contact import build_self_contact_system
    from softhand_sim.physics.model import build_model
    from softhand_sim.scenarios.self_contact import skin_penetration

    asset = load_or_build_hand(resolution="coarse")
    model = build_model(asset)
    sm = build_self_contact_system(model, asset, skin_segments(asset)).model
    surfaces = SegmentSurfaces(sm, asset.skin_triangles)
    assert skin_penetration(sm, model.node_rest, model.tets, None, surfaces) == (0.0, -1, -1, 0)
    x = np.einsum("pa,pai->pi", sm.point_bary, model.node_rest[model.tets[sm.point_tet]])
    index, middle = sm.point_segment == 6, sm.point_segment == 9
    x[index] += 0.5 * (x[middle].mean(axis=0) - x[index].mean(axis=0))
    depth, point, segment, inside = surfaces.deepest(x)
    assert inside > 50 and depth > 0.002 and sm.point_segment[point] == 6 and segment in (7, 8, 9), (depth, inside, segment)
