"""The default hand morphed to other measures (handmodel.morph, issue #16): same topology, the
quality checks of a built hand, the fitted skeleton exactly, skin and samples consistent with it;
the cache morphs non-default sizes and falls back to a full build when a morph fails its checks."""
import os

import numpy as np
import pytest

from softhand_sim.handmodel import cache
from softhand_sim.handmodel.build import MIRROR
from softhand_sim.handmodel.checks import asset_figures, morph_problems
from softhand_sim.handmodel.fit import fit_measures, hand_length
from softhand_sim.handmodel.measures import HandMeasures, scale_measures
from softhand_sim.handmodel.morph import HandMorph, improve_tets, morph_hand
from softhand_sim.handmodel.skeleton import bone_chain_points, build_skeleton, skeleton_from_frames
from softhand_sim.handmodel.tets import boundary_triangles, dihedral_angles
from softhand_sim.handmodel.tissue import COARSE_EMBED_TOLERANCE
from softhand_sim.physics.rotations import quat_to_matrix
from softhand_sim.scenarios.tracker_bags import LARGE_HAND, SMALL_HAND

# per-bone ratios at the ends of 0.7-1.3 (palm 0.7 with the thumb metacarpal 1.3, index 0.7, middle 1.3)
STRETCHED = scale_measures(HandMeasures(), 1.0, palm_length=0.063, middle_lengths=(0.061, 0.037, 0.031),
                           index_lengths=(0.030, 0.018, 0.015), thumb_lengths=(0.057, 0.041, 0.020))


@pytest.fixture(scope="module")
def base():
    return cache.load_or_build_hand(None, "right", "coarse", method="build")


@pytest.fixture(scope="module")
def leap():
    """The measures of the real Leap recording leap_grab (thumb CMC 25 mm nearer the wrist)."""
    from softhand_sim.commands.offline import read_frames
    return fit_measures(*read_frames("leap_grab")).measures


def test_default_measures_morph_to_the_default_hand(base):
    """The identity: every bone map and the palm spline reproduce the default hand."""
    a = morph_hand(base, HandMeasures(), samples="carry")
    np.testing.assert_allclose(a.tet_nodes, base.tet_nodes, atol=1e-12)
    np.testing.assert_allclose(a.skin_vertices, base.skin_vertices, atol=1e-12)
    np.testing.assert_allclose(a.sample_local, base.sample_local, atol=1e-12)
    np.testing.assert_allclose(a.skin_bary, base.skin_bary, atol=1e-9)
    # drawn anew, the samples are the build's up to round-off deciding a few on tet faces
    b = morph_hand(base, HandMeasures())
    assert abs(len(b.sample_tet) - len(base.sample_tet)) <= 0.01 * len(base.sample_tet)
    np.testing.assert_array_equal(b.bone_sample_total, base.bone_sample_total)


@pytest.mark.parametrize("name", ["small", "large", "stretched", "leap", "15cm", "22cm"])
def test_morphed_hand(base, leap, name):
    """Same tets and skin triangles; the checks of
    a built hand; the skeleton of the measures exactly; the skin embedded (its barycentric
    weights give back its vertices); the samples where their bone frame and their tet both put
    them; the middle fingertip skin at the fitted fingertip (within 1.5 mm)."""
    m = {"small": SMALL_HAND, "large": LARGE_HAND, "stretched": STRETCHED, "leap": leap,
         "15cm": scale_measures(HandMeasures(), 0.15 / hand_length(HandMeasures())),
         "22cm": scale_measures(HandMeasures(), 0.22 / hand_length(HandMeasures()))}[name]
    a = morph_hand(base, m)
    assert morph_problems(a, COARSE_EMBED_TOLERANCE) == []
    f = asset_figures(a, COARSE_EMBED_TOLERANCE)
    assert f["skin_watertight"] and f["inverted"] == 0 and f["min_dihedral_deg"] >= 10.0
    for k in ("tets", "skin_triangles", "tet_surface_triangles"):
        np.testing.assert_array_equal(getattr(a, k), getattr(base, k))
    skel = build_skeleton(m)
    for k, v in skel.items():
        np.testing.assert_allclose(getattr(a, k), v, atol=1e-12, err_msg=k)
    nodes = a.tet_nodes[a.tets]
    np.testing.assert_allclose(np.einsum("vk,vki->vi", a.skin_bary, nodes[a.skin_tet]), a.skin_vertices, atol=1e-10)
    by_tet = np.einsum("pk,pki->pi", a.sample_bary, nodes[a.sample_tet])
    pose = a.bone_rest_pose[a.sample_bone]
    by_bone = np.einsum("pij,pj->pi", np.array([quat_to_matrix(q) for q in pose[:, 3:]]), a.sample_local) + pose[:, :3]
    np.testing.assert_allclose(by_bone, by_tet, atol=1e-10)
    assert np.mean(a.skin_tet == base.skin_tet) > 0.999  # a few far skin vertices may be embedded anew
    _, dist, _ = bone_chain_points(m)
    assert np.linalg.norm(a.skin_vertices - dist[9], axis=1).min() < 1.5e-3
    assert a.build_info["method"] == "morph" and a.measures == m.to_dict()


def test_carried_samples_keep_the_pairs(base, leap):
    """samples='carry': the default hand's (tet, bone) pairs and counts, consistent at rest."""
    a = morph_hand(base, leap, samples="carry")
    for k in ("sample_tet", "sample_bone", "sample_count", "bone_sample_total"):
        np.testing.assert_array_equal(getattr(a, k), getattr(base, k))
    by_tet = np.einsum("pk,pki->pi", a.sample_bary, a.tet_nodes[a.tets][a.sample_tet])
    pose = a.bone_rest_pose[a.sample_bone]
    by_bone = np.einsum("pij,pj->pi", np.array([quat_to_matrix(q) for q in pose[:, 3:]]), a.sample_local) + pose[:, :3]
    np.testing.assert_allclose(by_bone, by_tet, atol=1e-10)


def test_left_is_the_mirrored_right(base):
    r, le = morph_hand(base, SMALL_HAND, "right"), morph_hand(base, SMALL_HAND, "left")
    np.testing.assert_allclose(le.tet_nodes, r.tet_nodes @ MIRROR, atol=1e-12)
    np.testing.assert_allclose(le.skin_vertices, r.skin_vertices @ MIRROR, atol=1e-12)
    np.testing.assert_array_equal(le.tets, r.tets[:, [0, 2, 1, 3]])
    surface = {tuple(np.roll(f, -np.argmin(f))) for f in le.tet_surface_triangles}
    assert surface == {tuple(np.roll(f, -np.argmin(f))) for f in boundary_triangles(le.tets)}
    assert morph_problems(le, COARSE_EMBED_TOLERANCE) == []
    prox, dist, rot = bone_chain_points(SMALL_HAND)
    mirrored = skeleton_from_frames(SMALL_HAND, prox @ MIRROR, dist @ MIRROR, MIRROR @ rot @ MIRROR)
    np.testing.assert_allclose(le.bone_rest_pose, mirrored["bone_rest_pose"], atol=1e-12)
    np.testing.assert_allclose(le.sample_local, r.sample_local @ MIRROR, atol=1e-12)


def test_bone_maps_put_joints_on_the_fitted_skeleton(leap):
    """The blended map takes every default joint (and fingertip) to the fitted one, within 0.3 mm
    (the joints are exact for each adjacent bone map; the palm spline is exact at the knuckles)."""
    d = HandMeasures()
    p0, d0, _ = bone_chain_points(d)
    p1, d1, _ = bone_chain_points(leap)
    moved = HandMorph(d, leap)(np.vstack([p0[1:], d0[1:]]))
    np.testing.assert_allclose(moved, np.vstack([p1[1:], d1[1:]]), atol=3e-4)


def test_improve_tets_lifts_a_flattened_tet():
    """A tet squashed to 4 deg among good ones: its nodes move (within max_move) until its least
    dihedral angle passes the target; no tet inverts."""
    nodes = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.3, 0.3, 0.02], [0.3, 0.3, -1.0]]) * 0.01
    tets = np.array([[0, 1, 2, 3], [0, 2, 1, 4]])
    before = np.degrees(dihedral_angles(nodes, tets)).min()
    out = improve_tets(nodes, tets, target_deg=12.0, max_move=0.004)
    after = np.degrees(dihedral_angles(out, tets)).min()
    assert before < 5.0 and after >= 12.0
    assert np.linalg.norm(out - nodes, axis=1).max() <= 0.004 + 1e-12


def test_cache_morphs_other_sizes(base, tmp_path, monkeypatch):
    """A non-default size is morphed from the cached default hand and cached under its own key;
    asking again loads the file."""
    src = cache.cache_path(None, "right", "coarse", method="build")
    monkeypatch.setenv("SOFTHAND_CACHE", str(tmp_path))
    os.symlink(src, cache.cache_path(None, "right", "coarse", method="build"))
    path = cache.cache_path(SMALL_HAND, "left", "coarse")
    assert "m" in path.name.split("_")[1] and not path.exists()
    a = cache.load_or_build_hand(SMALL_HAND, "left", "coarse")
    assert path.exists() and a.build_info["method"] == "morph" and a.side == "left"
    b = cache.load_or_build_hand(SMALL_HAND, "left", "coarse")
    np.testing.assert_array_equal(a.tet_nodes, b.tet_nodes)


@pytest.mark.slow
def test_failed_morph_falls_back_to_a_full_build(base, tmp_path, monkeypatch, caplog):
    """A morph that fails its checks (here: an embedding limit no hand meets) is built in full,
    and the log and build_info say why (a coarse full build: 7-15 s)."""
    src = cache.cache_path(None, "right", "coarse", method="build")
    monkeypatch.setenv("SOFTHAND_CACHE", str(tmp_path))
    os.symlink(src, cache.cache_path(None, "right", "coarse", method="build"))
    monkeypatch.setattr("softhand_sim.handmodel.checks.EMBED_MAX", 0.0)
    with caplog.at_level("WARNING", logger="softhand_sim.handmodel"):
        a = cache.load_or_build_hand(SMALL_HAND, "right", "coarse")
    assert a.build_info["method"] == "build" and "skin embedding" in a.build_info["morph_fallback"]
    assert "building it in full" in caplog.text
