"""Point location in the tet mesh (handmodel/embedding.py): the two searches over the whole mesh,
the tet that holds a point best and the nearest boundary triangle, against plain brute force."""

import numpy as np
import pytest

from softhand_sim.handmodel import load_or_build_hand
from softhand_sim.handmodel.embedding import (_best_of_all_tets, _closest_on_triangle, barycentric,
                                              embed_points, nearest_triangle)
from softhand_sim.handmodel.tets import boundary_triangles


@pytest.fixture(scope="module")
def hand():
    return load_or_build_hand(side="right", resolution="coarse")


def around_the_skin(hand, n, spread, seed=0):
    """n points scattered `spread` [m] around random skin vertices: inside, outside and near the
    mesh's boundary, where the two searches have to decide."""
    rng = np.random.default_rng(seed)
    v = hand.skin_vertices[rng.integers(0, len(hand.skin_vertices), n)]
    return v + rng.normal(0.0, spread, v.shape)


def test_nearest_triangle_is_the_brute_force_one(hand):
    """The bounded search returns the brute-force pass's triangle (the first of the nearest in
    index order) and its distance, for points on both sides of the boundary and far away."""
    nodes = hand.tet_nodes
    faces = boundary_triangles(hand.tets).astype(np.int64)
    points = np.vstack([around_the_skin(hand, 60, 0.003), around_the_skin(hand, 20, 0.05, seed=1)])
    got, dist = nearest_triangle(points, nodes, faces)
    for i, p in enumerate(points):
        d2 = [np.sum((p - _closest_on_triangle(p, *nodes[f])) ** 2) for f in faces]
        assert got[i] == int(np.argmin(d2)), i
        assert dist[i] == pytest.approx(np.sqrt(min(d2)), rel=1e-12, abs=1e-15)


def test_every_point_gets_the_tet_that_holds_it_best(hand):
    """Each point's tet is one whose smallest barycentric weight is the largest over every tet of
    the mesh (the points inside: the tet that contains them), and its weights reproduce the point;
    a point outside is bound to the owner of its nearest boundary face, at that face's distance."""
    nodes, tets = hand.tet_nodes, hand.tets
    points = around_the_skin(hand, 150, 0.002, seed=2)
    tet, bary, dist = embed_points(nodes, tets, points)
    assert np.allclose(np.einsum("nk,nkc->nc", bary, nodes[tets[tet]]), points, atol=1e-12)
    faces, owner = boundary_triangles(tets, return_tet=True)
    inside = dist == 0.0
    assert 20 < inside.sum() < len(points) - 20  # both kinds are tested
    for i in np.flatnonzero(inside):
        w = barycentric(nodes, tets, np.arange(len(tets)), np.repeat(points[i][None], len(tets), 0))
        assert bary[i].min() >= w.min(axis=1).max() - 1e-12, i
    for i in np.flatnonzero(~inside):
        d2 = [np.sum((points[i] - _closest_on_triangle(points[i], *nodes[f])) ** 2) for f in faces]
        assert tet[i] == owner[int(np.argmin(d2))], i
        assert dist[i] == pytest.approx(np.sqrt(min(d2)), rel=1e-12)


def test_the_search_over_every_tet_is_the_batched_solve(hand):
    """The pass over every tet (embed_points' fallback when no nearby tet holds the point) picks,
    for each point, the tet and smallest weight that the batched solve of every tet gives."""
    nodes, tets = hand.tet_nodes, hand.tets
    points = around_the_skin(hand, 40, 0.004, seed=3)
    p0 = nodes[tets[:, 0]]
    edges = np.stack([nodes[tets[:, k]] - p0 for k in (1, 2, 3)], axis=2)
    got, w_got = _best_of_all_tets(np.linalg.inv(edges), p0, points)
    for i, p in enumerate(points):
        w = barycentric(nodes, tets, np.arange(len(tets)), np.repeat(p[None], len(tets), 0)).min(axis=1)
        assert got[i] == int(np.argmax(w)), i
        assert w_got[i] == pytest.approx(w.max(), abs=1e-12)
