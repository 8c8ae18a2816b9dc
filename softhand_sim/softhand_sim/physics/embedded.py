"""Points embedded in the tissue (skin vertices, contact points, anchors): their world position
is the barycentric interpolation of their tet's four nodes (Sect. 5.1, the embedded skin)."""
from numba import njit


@njit(cache=True)
def embedded_point(x, tets, t, bary, out):
    """out (3,) [m] = sum_a bary[a] x[tets[t, a]]: one point in tet t (x: (N,3) node positions)."""
    for i in range(3):
        acc = 0.0
        for a in range(4):
            acc += bary[a] * x[tets[t, a], i]
        out[i] = acc


@njit(cache=True)
def embedded_positions(x, tets, point_tet, point_bary, out):
    """out (P,3) [m]: every point p in tet point_tet[p] with weights point_bary[p] (P,4)."""
    for p in range(point_tet.shape[0]):
        embedded_point(x, tets, point_tet[p], point_bary[p], out[p])
