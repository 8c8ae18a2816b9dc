"""Skin: a closed, 2-manifold, outward triangle surface of the implicit hand.

Marching cubes (scikit-image) on a grid of the hand's signed distance, a few Taubin smoothing
passes (shrink-free), quadric decimation (fast-simplification) to the target triangle count, and
projection of the vertices back onto the zero level set so the decimated skin stays on the shape.
"""
import fast_simplification
import numpy as np
from skimage.measure import marching_cubes

SKIN_GRID_SPACING = 0.0009  # marching-cubes voxel [m]
SKIN_TARGET_TRIANGLES = 23640  # paper Sect. 5.1
TAUBIN_PASSES = 6


def mesh_edges(triangles):
    """Undirected edges (E,2) sorted per row and the count of triangles using each."""
    e = np.sort(np.vstack([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    uniq, counts = np.unique(e, axis=0, return_counts=True)
    return uniq, counts


def _neighbour_mean(vertices, triangles):
    n = vertices.shape[0]
    e = np.vstack([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    e = np.vstack([e, e[:, ::-1]])
    acc = np.zeros_like(vertices)
    np.add.at(acc, e[:, 0], vertices[e[:, 1]])
    deg = np.bincount(e[:, 0], minlength=n).astype(np.float64)
    return acc / deg[:, None]


def taubin_smooth(vertices, triangles, passes, lam=0.5, mu=-0.53):
    v = vertices.copy()
    for _ in range(passes):
        v = v + lam * (_neighbour_mean(v, triangles) - v)
        v = v + mu * (_neighbour_mean(v, triangles) - v)
    return v


def project_to_surface(shape, vertices, iterations=3):
    """Newton steps x <- x - f(x) grad f / |grad f|^2 onto the zero level set."""
    v = vertices.copy()
    for _ in range(iterations):
        f = shape.sdf(v)
        g = shape.gradient(v)
        v -= (f / np.maximum(np.einsum("ij,ij->i", g, g), 1e-12))[:, None] * g
    return v


def signed_volume(vertices, triangles):
    """Enclosed volume of a closed triangle surface [m^3] (positive when outward oriented)."""
    a, b, c = vertices[triangles[:, 0]], vertices[triangles[:, 1]], vertices[triangles[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def build_skin(shape, target_triangles=SKIN_TARGET_TRIANGLES, spacing=SKIN_GRID_SPACING):
    """Skin (vertices (V,3) [m], triangles (F,3) int32, outward) of `shape`."""
    lo, hi = shape.bounds
    axes = [np.arange(lo[k], hi[k] + spacing, spacing) for k in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    values = shape.sdf(grid).reshape(len(axes[0]), len(axes[1]), len(axes[2]))
    verts, faces, _, _ = marching_cubes(values, level=0.0, spacing=(spacing,) * 3,
                                        allow_degenerate=False)
    verts = verts.astype(np.float64) + lo
    faces = faces.astype(np.int64)
    verts = taubin_smooth(verts, faces, TAUBIN_PASSES)
    reduction = 1.0 - target_triangles / faces.shape[0]
    if reduction > 0.0:
        verts, faces = fast_simplification.simplify(verts, faces.astype(np.int32), reduction)
    verts = project_to_surface(shape, np.asarray(verts, dtype=np.float64))
    faces = np.asarray(faces, dtype=np.int32)
    if signed_volume(verts, faces) < 0.0:
        faces = faces[:, ::-1].copy()
    return verts, faces
