"""Parametric hand model (issue #4): skin, tissue, embedding, skeleton, samples, mirror, cache.

The right and left coarse hands are each built once per session from scratch (no cache): the
left build repeats the whole pipeline, so left == mirrored right also shows the build is
deterministic.
"""

import numpy as np
import pytest

from softhand_sim.handmodel import HandAsset, HandMeasures, build_hand, load_or_build_hand
from softhand_sim.handmodel.samples import capsule_surface_samples
from softhand_sim.handmodel.skeleton import BONE_DENSITY, FINGER_BONES
from softhand_sim.handmodel.tets import dihedral_angles, tet_volumes
from softhand_sim.handmodel.tissue import COARSE_EMBED_TOLERANCE
from softhand_sim.physics.rotations import quat_to_matrix

MIRROR = np.diag([1.0, -1.0, 1.0])


@pytest.fixture(scope="session")
def right():
    return build_hand(side="right", resolution="coarse")


@pytest.fixture(scope="session")
def left():
    return build_hand(side="left", resolution="coarse")


def closed_volume(v, f):
    return np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6.0


def winding_number(points, v, f, chunk=256):
    """Generalized winding number (van Oosterom-Strackee solid angles): ~1 inside, ~0 outside."""
    out = []
    for s in range(0, len(points), chunk):
        p = points[s:s + chunk, None, None, :]
        a, b, c = (v[f[:, k]][None] - p[:, 0] for k in range(3))
        la, lb, lc = (np.linalg.norm(x, axis=2) for x in (a, b, c))
        det = np.einsum("pij,pij->pi", a, np.cross(b, c))
        den = la * lb * lc + np.einsum("pij,pij->pi", a, b) * lc + np.einsum("pij,pij->pi", b, c) * la \
            + np.einsum("pij,pij->pi", c, a) * lb
        out.append(np.arctan2(det, den).sum(axis=1) / (2 * np.pi))
    return np.concatenate(out)


def bone_world(asset, bone, local):
    pose = asset.bone_rest_pose[bone]
    return local @ quat_to_matrix(pose[3:]).T + pose[:3]


def test_skin_is_closed_manifold_outward_and_sized(right):
    """Skin: every edge in exactly two triangles, once in each direction (consistent orientation),
    Euler characteristic 2 (one closed sphere-like surface), positive enclosed volume (outward),
    and 20k-25k triangles."""
    f = right.skin_triangles
    assert 20000 <= len(f) <= 25000
    directed = np.vstack([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    assert len(np.unique(directed, axis=0)) == len(directed)  # no directed edge twice
    und, counts = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
    assert (counts == 2).all()
    assert len(right.skin_vertices) - len(und) + len(f) == 2
    assert closed_volume(right.skin_vertices, f) > 0
    assert f.dtype == np.int32 and right.skin_vertices.dtype == np.float64


def test_tet_mesh_valid_quality_and_volume(right):
    """No inverted tet, minimum dihedral >= 10 deg, tet volume within 10 % of the skin volume,
    and the boundary faces close the tet surface outward."""
    vol = tet_volumes(right.tet_nodes, right.tets)
    assert (vol > 0).all()
    assert np.degrees(dihedral_angles(right.tet_nodes, right.tets)).min() >= 10.0
    skin_vol = closed_volume(right.skin_vertices, right.skin_triangles)
    assert abs(vol.sum() / skin_vol - 1.0) < 0.10
    assert closed_volume(right.tet_nodes, right.tet_surface_triangles) == pytest.approx(vol.sum(), rel=1e-9)


def test_coarse_tet_count_matches_paper(right):
    """Paper Sect. 5.1: the coarse tissue mesh has 800-900 tets (856)."""
    assert 800 <= len(right.tets) <= 900


def test_coarse_tet_count_bounded(right):
    """The coarse mesh stays small enough for a real-time step (< 4000 tets)."""
    assert len(right.tets) < 4000


def test_every_skin_vertex_embedded(right):
    """Each skin vertex has a tet and weights summing to 1 that reproduce its rest position; it lies
    in the tet or within the coarse mesh's stated tolerance (COARSE_EMBED_TOLERANCE, 6.5 mm; the
    flat faces of ~850 tets cut the curved webs and thenar), and 95 % of them within 3 mm."""
    x = np.einsum("vk,vkj->vj", right.skin_bary, right.tet_nodes[right.tets[right.skin_tet]])
    assert np.allclose(x, right.skin_vertices, atol=1e-9)
    assert np.allclose(right.skin_bary.sum(axis=1), 1.0)
    assert right.skin_embed_distance.max() <= COARSE_EMBED_TOLERANCE
    assert np.mean(right.skin_embed_distance <= 0.003) >= 0.95
    inside = right.skin_bary.min(axis=1) >= -1e-9
    assert (right.skin_embed_distance[inside] == 0).all()


def test_capsules_inside_skin_and_tissue(right):
    """Every bone capsule's surface samples lie inside the skin (winding number ~1) and inside the
    tissue (all samples of each bone are in some tet: sample counts sum to N_total)."""
    for bone in range(16):
        local = capsule_surface_samples(right.bone_capsule_a[bone], right.bone_capsule_b[bone],
                                        right.bone_capsule_radius[bone], spacing=0.004)
        w = winding_number(bone_world(right, bone, local), right.skin_vertices, right.skin_triangles)
        assert (w > 0.5).all(), f"bone {bone}: {np.sum(w <= 0.5)} capsule samples outside the skin"
        assert right.sample_count[right.sample_bone == bone].sum() == right.bone_sample_total[bone]


def test_finger_lengths_match_measures(right):
    """Each finger measured on the skin (knuckle joint to the farthest skin point along the finger)
    is within 5 % of the sum of its bone-length measures; bone lengths equal the measures."""
    m = HandMeasures()
    for finger, bones in FINGER_BONES.items():
        assert np.allclose(right.bone_length[list(bones)], m.finger_lengths(finger))
        last = bones[2]
        origin = right.bone_rest_pose[last, :3]
        axis = quat_to_matrix(right.bone_rest_pose[last, 3:])[:, 0]
        rel = right.skin_vertices - origin
        along = rel @ axis
        radial = np.linalg.norm(rel - along[:, None] * axis, axis=1)
        tip = along[radial < m.finger_width(finger)].max()
        proximal = sum(np.linalg.norm(right.bone_rest_pose[b + 1, :3] - right.bone_rest_pose[b, :3])
                       for b in bones[:2])
        assert abs((proximal + tip) / sum(m.finger_lengths(finger)) - 1.0) < 0.05, finger
    tip_mid = (right.skin_vertices[:, 0]).max()
    assert 0.18 <= tip_mid <= 0.20  # wrist -> middle fingertip about 19 cm


def test_left_is_mirrored_right_and_build_deterministic(right, left):
    """Left hand = right hand mirrored through the xz plane, vertex for vertex, with orientation
    fixed (positive tets, outward skin); as the left build repeats the whole pipeline, equality
    also shows two builds give identical arrays."""
    assert np.array_equal(left.skin_vertices, right.skin_vertices @ MIRROR)
    assert np.array_equal(left.tet_nodes, right.tet_nodes @ MIRROR)
    assert np.array_equal(left.skin_triangles, right.skin_triangles[:, [0, 2, 1]])
    assert np.array_equal(left.tets, right.tets[:, [0, 2, 1, 3]])
    assert (tet_volumes(left.tet_nodes, left.tets) > 0).all()
    assert closed_volume(left.skin_vertices, left.skin_triangles) > 0
    assert np.array_equal(left.skin_tet, right.skin_tet)
    assert np.array_equal(left.sample_tet, right.sample_tet)
    assert np.allclose(left.sample_local, right.sample_local @ MIRROR)
    for i in range(16):  # frames: x and z mirrored, right-handed
        rl = quat_to_matrix(left.bone_rest_pose[i, 3:])
        rr = quat_to_matrix(right.bone_rest_pose[i, 3:])
        assert np.allclose(rl[:, 0], MIRROR @ rr[:, 0]) and np.allclose(rl[:, 2], MIRROR @ rr[:, 2])
        assert np.linalg.det(rl) == pytest.approx(1.0)


def test_bone_samples_per_bone(right):
    """Every bone has coupling samples; each representative point's barycentric weights (sum 1)
    and its bone-frame position give the same rest point inside its tet."""
    assert (np.bincount(right.sample_bone, minlength=16) >= 1).all()
    world = np.array([bone_world(right, b, p[None])[0] for b, p in zip(right.sample_bone, right.sample_local)])
    via_tet = np.einsum("pk,pkj->pj", right.sample_bary, right.tet_nodes[right.tets[right.sample_tet]])
    assert np.allclose(world, via_tet, atol=1e-9)
    assert (right.sample_bary >= -1e-9).all() and np.allclose(right.sample_bary.sum(axis=1), 1.0)
    assert (right.sample_count >= 1).all()


def test_skeleton_frames_joints_and_mass(right):
    """Palm frame is the world frame at the wrist; each joint anchor maps to the child's origin;
    flexion axes are the child's y (positive flexion turns the child's x toward the parent's
    palmar side for the fingers); masses are 1900 kg/m^3 times the capsule volume; inertias are
    symmetric positive definite."""
    assert np.allclose(right.bone_rest_pose[0], [0, 0, 0, 0, 0, 0, 1])
    assert np.allclose(np.linalg.norm(right.bone_rest_pose[:, 3:], axis=1), 1.0)
    assert right.joint_parent.shape == (15,) and right.joint_limits.shape == (15, 2, 2)
    for j in range(15):
        p, c = right.joint_parent[j], right.joint_child[j]
        assert np.allclose(bone_world(right, p, right.joint_anchor_parent[j][None])[0],
                           right.bone_rest_pose[c, :3], atol=1e-12)
        rp = quat_to_matrix(right.bone_rest_pose[p, 3:])
        rc = quat_to_matrix(right.bone_rest_pose[c, 3:])
        assert np.allclose(rp @ right.joint_flex_axis[j], rc[:, 1])
        assert right.joint_limits[j, 0, 0] < right.joint_limits[j, 0, 1]
    assert list(right.joint_type[[0, 3, 6, 9, 12]]) == [2] * 5  # CMC + 4 MCP universal
    assert (np.delete(right.joint_type, [0, 3, 6, 9, 12]) == 1).all()
    # flexing the index MCP by +0.5 rad about its flex axis moves the finger toward -z (palmar)
    from scipy.spatial.transform import Rotation
    j = 3
    axis = quat_to_matrix(right.bone_rest_pose[0, 3:]) @ right.joint_flex_axis[j]
    x_child = quat_to_matrix(right.bone_rest_pose[4, 3:])[:, 0]
    assert (Rotation.from_rotvec(0.5 * axis).apply(x_child))[2] < x_child[2] - 0.3
    r = right.bone_capsule_radius
    h = np.linalg.norm(right.bone_capsule_b - right.bone_capsule_a, axis=1)
    assert np.allclose(right.bone_mass, BONE_DENSITY * (np.pi * r ** 2 * h + 4.0 / 3.0 * np.pi * r ** 3))
    for i in range(16):
        inertia = right.bone_inertia_local[i]
        assert np.allclose(inertia, inertia.T) and np.linalg.eigvalsh(inertia).min() > 0


def test_cache_round_trip(tmp_path, monkeypatch, right):
    """load_or_build_hand stores the asset under $SOFTHAND_CACHE and a cached load builds nothing and
    returns the same arrays."""
    monkeypatch.setenv("SOFTHAND_CACHE", str(tmp_path))
    from softhand_sim.handmodel.cache import cache_path
    path = cache_path()
    path.parent.mkdir(parents=True, exist_ok=True)
    right.save(path)  # the session's fresh build stands in for the first (slow) call
    import softhand_sim.handmodel.cache as cache_mod

    def no_build(*args, **kwargs):
        raise AssertionError("a cached hand was rebuilt")
    monkeypatch.setattr(cache_mod, "build_hand", no_build)
    loaded = load_or_build_hand()
    assert isinstance(loaded, HandAsset)
    assert np.array_equal(loaded.skin_vertices, right.skin_vertices)
    assert np.array_equal(loaded.tets, right.tets)
    assert loaded.measures == right.measures


def test_bad_measures_rejected():
    """Unknown or out-of-range measures raise errors that name them."""
    with pytest.raises(ValueError, match="palm_widht"):
        build_hand({"palm_widht": 0.08})
    with pytest.raises(ValueError, match="palm_width"):
        HandMeasures(palm_width=2.0)
    with pytest.raises(ValueError, match="side"):
        build_hand(side="middle")


def test_coarse_tissue_deterministic():
    """Building the coarse hex-grid tissue twice from the same shape gives identical arrays
    (no randomness, fixed iteration orders), with no inverted tet."""
    from softhand_sim.handmodel.hexmesh import coarse_tissue
    from softhand_sim.handmodel.measures import as_measures
    from softhand_sim.handmodel.shape import HandShape

    m = as_measures(None)
    shape = HandShape(m)
    skin_volume = 314e-6
    n1, t1, f1 = coarse_tissue(shape, m, skin_volume)
    n2, t2, f2 = coarse_tissue(shape, m, skin_volume)
    assert np.array_equal(n1, n2) and np.array_equal(t1, t2) and f1 == f2
    assert (tet_volumes(n1, t1) > 0).all()
