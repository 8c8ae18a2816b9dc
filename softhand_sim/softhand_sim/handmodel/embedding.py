"""Point location in a tet mesh: barycentric embedding of skin vertices and bone samples.

A point inside the mesh is bound to the tet that contains it (all barycentric weights >= 0
up to round-off). A point outside (the skin bulges past the flat tet faces between surface
nodes) is bound to the tet owning the nearest boundary face; its weights are the unclamped
barycentric coordinates in that tet, so they still reproduce the rest position exactly and
extrapolate the tet's deformation. `embed_points` reports the distance from each point to its
tet (0 inside) so callers can check it against a tolerance.
"""
import numpy as np
from numba import njit
from scipy.spatial import cKDTree

from softhand_sim.handmodel.tets import boundary_triangles

INSIDE_TOLERANCE = 1e-9  # smallest barycentric weight still counted as inside
CANDIDATE_TETS = 48  # nearest tet centroids tested for containment


def _edge_matrices(p):
    """(n,3,3) of tets' corners p (n,4,3): the edges from the first corner as columns."""
    return np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]], axis=2)


def barycentric(nodes, tets, tet_index, points):
    """Barycentric weights (n,4) of points (n,3) in tets[tet_index] (n,)."""
    p = nodes[tets[tet_index]]
    w123 = np.linalg.solve(_edge_matrices(p), (points - p[:, 0])[:, :, None])[:, :, 0]
    return np.concatenate([1.0 - w123.sum(axis=1, keepdims=True), w123], axis=1)


@njit(cache=True)
def _best_of_all_tets(inv, p0, points):
    """(tet (n,), its smallest weight (n,)) of the tet whose smallest barycentric weight of each
    point is largest, over every tet (inv: each tet's inverse edge matrix, p0 its first node); the
    first such tet on a tie, as np.argmax."""
    n, T = points.shape[0], inv.shape[0]
    best = np.zeros(n, dtype=np.int64)
    best_w = np.full(n, -np.inf)
    for i in range(n):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        for t in range(T):
            dx, dy, dz = x - p0[t, 0], y - p0[t, 1], z - p0[t, 2]
            w1 = inv[t, 0, 0] * dx + inv[t, 0, 1] * dy + inv[t, 0, 2] * dz
            w2 = inv[t, 1, 0] * dx + inv[t, 1, 1] * dy + inv[t, 1, 2] * dz
            w3 = inv[t, 2, 0] * dx + inv[t, 2, 1] * dy + inv[t, 2, 2] * dz
            w = min(1.0 - (w1 + w2 + w3), w1, w2, w3)
            if w > best_w[i]:
                best_w[i], best[i] = w, t
    return best, best_w


@njit(cache=True)
def _closest_on_triangle(p, a, b, c):
    """Closest point to p on triangle abc (Ericson, Real-Time Collision Detection 5.1.5)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = ab @ ap, ac @ ap
    if d1 <= 0.0 and d2 <= 0.0:
        return a
    bp = p - b
    d3, d4 = ab @ bp, ac @ bp
    if d3 >= 0.0 and d4 <= d3:
        return b
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        return a + ab * (d1 / (d1 - d3))
    cp = p - c
    d5, d6 = ab @ cp, ac @ cp
    if d6 >= 0.0 and d5 <= d6:
        return c
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        return a + ac * (d2 / (d2 - d6))
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)))
    denom = 1.0 / (va + vb + vc)
    return a + ab * (vb * denom) + ac * (vc * denom)


def nearest_triangle(points, vertices, triangles):
    """Index of the nearest triangle and the distance to it [m] for each point: the first of the
    nearest in index order, exactly as a brute-force pass over every triangle gives them.

    Each point's pass starts from a bound, its distance to the triangle whose centroid is nearest
    (a k-d tree), and skips every triangle whose bounding sphere lies beyond it (the fine hand's
    build spent 6.5 s here brute force; its whole embedding now takes 0.6 s)."""
    points = np.asarray(points, dtype=np.float64)
    tri = np.asarray(triangles, dtype=np.int64)
    corners = vertices[tri]                                           # (T, 3, 3)
    centre = corners.mean(axis=1)
    radius = np.linalg.norm(corners - centre[:, None], axis=2).max(axis=1)
    _, seed = cKDTree(centre).query(points, k=1)
    return _nearest_triangle(points, vertices, tri, centre, radius, np.asarray(seed, dtype=np.int64))


@njit(cache=True)
def _nearest_triangle(points, vertices, triangles, centre, radius, seed):
    n = points.shape[0]
    best = np.zeros(n, dtype=np.int64)
    dist = np.empty(n)
    for i in range(n):
        p = points[i]
        s = seed[i]
        q = _closest_on_triangle(p, vertices[triangles[s, 0]], vertices[triangles[s, 1]], vertices[triangles[s, 2]])
        # a bound a hair above the seed's distance: the seed and any triangle as near are visited
        # in index order below, so the first of the nearest wins as in a brute-force pass
        bound = np.sqrt(np.sum((p - q) ** 2)) * (1.0 + 1e-9) + 1e-15
        bd = 1e30
        for t in range(triangles.shape[0]):
            dc = np.sqrt((p[0] - centre[t, 0]) ** 2 + (p[1] - centre[t, 1]) ** 2 + (p[2] - centre[t, 2]) ** 2)
            if dc - radius[t] > bound:
                continue  # every point of t is farther than the bound
            q = _closest_on_triangle(p, vertices[triangles[t, 0]], vertices[triangles[t, 1]],
                                     vertices[triangles[t, 2]])
            d = np.sum((p - q) ** 2)
            if d < bd:
                bd = d
                best[i] = t
        dist[i] = np.sqrt(bd)
    return best, dist


def embed_points(nodes, tets, points):
    """(tet (n,) int32, bary (n,4), distance to that tet (n,) [m]) for points (n,3)."""
    points = np.asarray(points, dtype=np.float64)
    centroids = nodes[tets].mean(axis=1)
    k = min(CANDIDATE_TETS, len(tets))
    _, cand = cKDTree(centroids).query(points, k=k)
    cand = cand.reshape(len(points), k)
    best_tet = np.full(len(points), -1, dtype=np.int64)
    best_min = np.full(len(points), -np.inf)
    for j in range(k):  # keep the candidate whose smallest weight is largest
        w = barycentric(nodes, tets, cand[:, j], points)
        wmin = w.min(axis=1)
        better = wmin > best_min
        best_min = np.where(better, wmin, best_min)
        best_tet = np.where(better, cand[:, j], best_tet)
    # the nearest centroids can miss the containing tet of a coarse, stretched mesh: test all
    # (every skin vertex outside the mesh comes here: about 12,000 over the fine hand's build, 47 s
    # of its 55 s as one batched solve per point; under a second as one compiled pass with each
    # tet's inverse)
    rest = np.flatnonzero(best_min < -INSIDE_TOLERANCE)
    if len(rest):
        corners = nodes[tets]
        t_all, w_all = _best_of_all_tets(np.linalg.inv(_edge_matrices(corners)), corners[:, 0], points[rest])
        better = w_all > best_min[rest]
        best_min[rest[better]], best_tet[rest[better]] = w_all[better], t_all[better]
    inside = best_min >= -INSIDE_TOLERANCE
    distance = np.zeros(len(points))
    outside = np.flatnonzero(~inside)
    if len(outside):
        faces, owner = boundary_triangles(tets, return_tet=True)
        tri, d = nearest_triangle(points[outside], nodes, faces.astype(np.int64))
        best_tet[outside] = owner[tri]
        distance[outside] = d
    bary = barycentric(nodes, tets, best_tet, points)
    return best_tet.astype(np.int32), bary, distance
