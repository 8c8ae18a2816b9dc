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


def barycentric(nodes, tets, tet_index, points):
    """Barycentric weights (n,4) of points (n,3) in tets[tet_index] (n,)."""
    p = nodes[tets[tet_index]]
    m = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]], axis=2)
    w123 = np.linalg.solve(m, (points - p[:, 0])[:, :, None])[:, :, 0]
    return np.concatenate([1.0 - w123.sum(axis=1, keepdims=True), w123], axis=1)


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


@njit(cache=True)
def nearest_triangle(points, vertices, triangles):
    """Index of the nearest triangle and the distance to it [m] for each point (brute force)."""
    n = points.shape[0]
    best = np.zeros(n, dtype=np.int64)
    dist = np.empty(n)
    for i in range(n):
        bd = 1e30
        for t in range(triangles.shape[0]):
            q = _closest_on_triangle(points[i], vertices[triangles[t, 0]], vertices[triangles[t, 1]],
                                     vertices[triangles[t, 2]])
            d = np.sum((points[i] - q) ** 2)
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
    for p in np.flatnonzero(best_min < -INSIDE_TOLERANCE):
        w = barycentric(nodes, tets, np.arange(len(tets)), np.repeat(points[p][None], len(tets), 0))
        t = int(np.argmax(w.min(axis=1)))
        if w[t].min() > best_min[p]:
            best_min[p], best_tet[p] = w[t].min(), t
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
