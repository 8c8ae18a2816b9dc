"""Signed distance grid of a watertight triangle mesh (build time only; used by sdf.build_grid).

Method (Bridson, makelevelset3): exact point-triangle distances at the grid nodes near each
triangle, then closest-triangle propagation sweeps, so that every node ends up with the exact
distance to a triangle that a neighbour found closest (exact near the surface, where contacts
happen; a close upper bound far inside). The sign comes from the parity of ray crossings along
each grid row in +x (a watertight mesh is crossed an odd number of times from outside to a point
inside). Rows are shifted by a tiny irrational fraction of a voxel so that they do not pass
exactly through mesh edges or vertices of meshes aligned with the grid.
"""
import numpy as np
from numba import njit

_NEAR_CELLS = 1              # exact distances within this many voxels of each triangle's box
_ROW_SHIFT = (1.3e-7, 2.7e-7)  # row offsets in voxels (y, z) for the crossing parity


@njit(cache=True)
def _point_triangle_distance(px, py, pz, a, b, c):
    """Distance from a point to the triangle (a, b, c) (Ericson, Real-Time Collision Detection)."""
    abx, aby, abz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    acx, acy, acz = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    apx, apy, apz = px - a[0], py - a[1], pz - a[2]
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        qx, qy, qz = a[0], a[1], a[2]
    else:
        bpx, bpy, bpz = px - b[0], py - b[1], pz - b[2]
        d3 = abx * bpx + aby * bpy + abz * bpz
        d4 = acx * bpx + acy * bpy + acz * bpz
        cpx, cpy, cpz = px - c[0], py - c[1], pz - c[2]
        d5 = abx * cpx + aby * cpy + abz * cpz
        d6 = acx * cpx + acy * cpy + acz * cpz
        vc = d1 * d4 - d3 * d2
        vb = d5 * d2 - d1 * d6
        va = d3 * d6 - d5 * d4
        if d3 >= 0.0 and d4 <= d3:
            qx, qy, qz = b[0], b[1], b[2]
        elif d6 >= 0.0 and d5 <= d6:
            qx, qy, qz = c[0], c[1], c[2]
        elif vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
            v = d1 / (d1 - d3)
            qx, qy, qz = a[0] + v * abx, a[1] + v * aby, a[2] + v * abz
        elif vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
            w = d2 / (d2 - d6)
            qx, qy, qz = a[0] + w * acx, a[1] + w * acy, a[2] + w * acz
        elif va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
            w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
            qx = b[0] + w * (c[0] - b[0])
            qy = b[1] + w * (c[1] - b[1])
            qz = b[2] + w * (c[2] - b[2])
        else:
            den = 1.0 / (va + vb + vc)
            v = vb * den
            w = vc * den
            qx = a[0] + abx * v + acx * w
            qy = a[1] + aby * v + acy * w
            qz = a[2] + abz * v + acz * w
    dx, dy, dz = px - qx, py - qy, pz - qz
    return np.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True)
def _near_distances(verts, faces, origin, voxel, nx, ny, nz, dist, closest):
    for t in range(faces.shape[0]):
        a, b, c = verts[faces[t, 0]], verts[faces[t, 1]], verts[faces[t, 2]]
        lo = np.empty(3, np.int64)
        hi = np.empty(3, np.int64)
        n3 = (nx, ny, nz)
        for ax in range(3):
            mn = min(a[ax], b[ax], c[ax])
            mx = max(a[ax], b[ax], c[ax])
            lo[ax] = max(int(np.floor((mn - origin[ax]) / voxel)) - _NEAR_CELLS, 0)
            hi[ax] = min(int(np.ceil((mx - origin[ax]) / voxel)) + _NEAR_CELLS, n3[ax] - 1)
        for i in range(lo[0], hi[0] + 1):
            for j in range(lo[1], hi[1] + 1):
                for k in range(lo[2], hi[2] + 1):
                    d = _point_triangle_distance(origin[0] + i * voxel, origin[1] + j * voxel,
                                                 origin[2] + k * voxel, a, b, c)
                    n = (i * ny + j) * nz + k
                    if d < dist[n]:
                        dist[n] = d
                        closest[n] = t


@njit(cache=True)
def _sweep(verts, faces, origin, voxel, nx, ny, nz, dist, closest, di, dj, dk):
    """One closest-triangle propagation sweep in the direction (di, dj, dk): each node takes the
    closest triangle of its three upwind neighbours and their diagonal when that is nearer. A
    neighbour's triangle that is already the node's own is skipped (the node's distance is that
    triangle's: a node's closest is only ever set together with its distance)."""
    i0, i1 = (1, nx) if di > 0 else (nx - 2, -1)
    j0, j1 = (1, ny) if dj > 0 else (ny - 2, -1)
    k0, k1 = (1, nz) if dk > 0 else (nz - 2, -1)
    up = np.empty(4, np.int64)
    for i in range(i0, i1, di):
        px = origin[0] + i * voxel
        for j in range(j0, j1, dj):
            py = origin[1] + j * voxel
            row, row_i, row_j = (i * ny + j) * nz, ((i - di) * ny + j) * nz, (i * ny + j - dj) * nz
            row_ij = ((i - di) * ny + j - dj) * nz
            for k in range(k0, k1, dk):
                n = row + k
                up[0], up[1], up[2], up[3] = row_i + k, row_j + k, row + k - dk, row_ij + k - dk
                for m in range(4):
                    t = closest[up[m]]
                    if t < 0 or t == closest[n]:
                        continue
                    d = _point_triangle_distance(px, py, origin[2] + k * voxel,
                                                 verts[faces[t, 0]], verts[faces[t, 1]], verts[faces[t, 2]])
                    if d < dist[n]:
                        dist[n] = d
                        closest[n] = t


@njit(cache=True)
def _crossing_counts(verts, faces, origin, voxel, nx, ny, nz, shift_y, shift_z, counts):
    """counts[i, j, k] += 1 for each triangle crossing of row (j, k) between node i-1 and node i."""
    for t in range(faces.shape[0]):
        a, b, c = verts[faces[t, 0]], verts[faces[t, 1]], verts[faces[t, 2]]
        jlo = max(int(np.ceil((min(a[1], b[1], c[1]) - origin[1]) / voxel - shift_y)), 0)
        jhi = min(int(np.floor((max(a[1], b[1], c[1]) - origin[1]) / voxel - shift_y)), ny - 1)
        klo = max(int(np.ceil((min(a[2], b[2], c[2]) - origin[2]) / voxel - shift_z)), 0)
        khi = min(int(np.floor((max(a[2], b[2], c[2]) - origin[2]) / voxel - shift_z)), nz - 1)
        for j in range(jlo, jhi + 1):
            y = origin[1] + (j + shift_y) * voxel
            for k in range(klo, khi + 1):
                z = origin[2] + (k + shift_z) * voxel
                # barycentric coordinates of (y, z) in the triangle projected onto the yz plane
                wa = (b[1] - y) * (c[2] - z) - (c[1] - y) * (b[2] - z)
                wb = (c[1] - y) * (a[2] - z) - (a[1] - y) * (c[2] - z)
                wc = (a[1] - y) * (b[2] - z) - (b[1] - y) * (a[2] - z)
                if not ((wa > 0 and wb > 0 and wc > 0) or (wa < 0 and wb < 0 and wc < 0)):
                    continue
                s = wa + wb + wc
                x = (wa * a[0] + wb * b[0] + wc * c[0]) / s
                i = int(np.ceil((x - origin[0]) / voxel))
                if i < 0:
                    i = 0
                if i < nx:
                    counts[(i * ny + j) * nz + k] += 1


@njit(cache=True)
def _apply_sign(counts, dist, nx, ny, nz):
    for j in range(ny):
        for k in range(nz):
            total = 0
            for i in range(nx):
                n = (i * ny + j) * nz + k
                total += counts[n]
                if total % 2 == 1:
                    dist[n] = -dist[n]


def mesh_signed_distance_grid(vertices, faces, origin, voxel, dims):
    """Signed distances (nx*ny*nz,) [m] at the grid nodes, storage order of sdf.DistanceGrid."""
    nx, ny, nz = (int(n) for n in dims)
    dist = np.full(nx * ny * nz, np.inf)
    closest = np.full(nx * ny * nz, -1, dtype=np.int64)
    _near_distances(vertices, faces, origin, voxel, nx, ny, nz, dist, closest)
    for _ in range(2):
        for di in (1, -1):
            for dj in (1, -1):
                for dk in (1, -1):
                    _sweep(vertices, faces, origin, voxel, nx, ny, nz, dist, closest, di, dj, dk)
    counts = np.zeros(nx * ny * nz, dtype=np.int32)
    _crossing_counts(vertices, faces, origin, voxel, nx, ny, nz, _ROW_SHIFT[0], _ROW_SHIFT[1], counts)
    _apply_sign(counts, dist, nx, ny, nz)
    return dist
