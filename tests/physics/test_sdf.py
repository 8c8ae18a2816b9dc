"""Signed distance grids of the scene shapes against their analytic distances (paper Sect. 5.1)."""
import numpy as np
import pytest
import trimesh

from softhand_sim.physics.contact import sdf
from softhand_sim.scene import load_scene

SHAPES = [
    ("sphere", {"radius": 0.04}),
    ("box", {"size": (0.05, 0.03, 0.08)}),
    ("capsule", {"radius": 0.02, "length": 0.06}),
    ("cylinder", {"radius": 0.04, "length": 0.10}),
]


def _analytic(shape, dims, p):
    if shape == "sphere":
        return sdf.sphere_distance(p, dims["radius"])
    if shape == "box":
        return sdf.box_distance(p, dims["size"])
    if shape == "capsule":
        return sdf.capsule_distance(p, dims["radius"], dims["length"])
    return sdf.cylinder_distance(p, dims["radius"], dims["length"])


def _smooth_mask(shape, dims, p, margin):
    """Points at least `margin` away from where the exact distance field is not smooth: the
    medial axis inside, the edges and corners outside (the field's curvature radius >= margin)."""
    if shape == "sphere":
        return np.linalg.norm(p, axis=1) > margin
    if shape == "capsule":
        return sdf.capsule_distance(p, 0.0, dims["length"]) > margin
    if shape == "box":
        q = np.abs(p) - 0.5 * np.asarray(dims["size"])
    else:
        rho = np.hypot(p[:, 0], p[:, 1])
        q = np.stack([rho - dims["radius"], np.abs(p[:, 2]) - 0.5 * dims["length"]], axis=1)
    top2 = np.sort(q, axis=1)[:, -2:]
    inside_ok = (top2[:, 1] < 0) & (top2[:, 1] - top2[:, 0] > margin)
    face_ok = (top2[:, 1] > 0) & (top2[:, 0] < -margin)
    edge_ok = np.linalg.norm(np.maximum(q, 0.0), axis=1) > margin
    ok = inside_ok | face_ok | edge_ok
    if shape == "cylinder":
        ok &= rho > margin
    return ok


def _band_points(grid, rng, count=40000):
    lo = grid.origin
    hi = grid.origin + grid.voxel * (grid.dims - 1)
    return rng.uniform(lo, hi, size=(count, 3))


@pytest.mark.parametrize("shape,dims", SHAPES, ids=[s for s, _ in SHAPES])
def test_primitive_value_within_half_voxel_and_unit_gradient(shape, dims):
    """Trilinear value is within half a voxel of the analytic distance everywhere in the grid
    (band and interior); in the 8-voxel band the gradient has unit length within 1% and points
    along the analytic normal wherever the exact field is smooth."""
    grid = sdf.build_grid(shape, dims)
    assert grid.voxel == pytest.approx(max(sdf.shape_bounds(shape, dims)[1] * 2) / 64)
    p = _band_points(grid, np.random.default_rng(1))
    d, g = grid.query(p)
    ref = _analytic(shape, dims, p)
    assert np.abs(d - ref).max() < 0.5 * grid.voxel
    # the narrow band, where contacts live, away from the medial axis (where the exact field
    # itself has no gradient)
    band = np.abs(ref) <= sdf.GRID_BAND * grid.voxel
    smooth = band & _smooth_mask(shape, dims, p, 8.0 * grid.voxel)
    assert smooth.sum() > 3000
    length = np.linalg.norm(g[smooth], axis=1)
    assert np.abs(length - 1.0).max() < 0.01
    # the gradient points along the analytic one (outward normal)
    eps = 1e-6
    fd = np.stack([(_analytic(shape, dims, p[smooth] + eps * e) - _analytic(shape, dims, p[smooth] - eps * e))
                   / (2 * eps) for e in np.eye(3)], axis=1)
    cos = np.sum(fd * g[smooth], axis=1) / length
    assert cos.min() > 0.99


def test_lookup_is_grid_value_and_its_one_voxel_central_differences():
    """grid_lookup and grid_gradient compute the inner cells' seven trilinear values from one
    cell position: the same numbers (to round-off) as grid_value at the point and one voxel either
    side along each axis, inside the grid, in its outermost voxel layer and outside it."""
    grid = sdf.build_grid("capsule", {"radius": 0.02, "length": 0.06})
    args = (grid.values, grid.origin, grid.voxel, grid.dims)
    lo, hi = grid.origin, grid.origin + grid.voxel * (grid.dims - 1)
    rng = np.random.default_rng(4)
    pts = np.concatenate([rng.uniform(lo, hi, size=(3000, 3)),                  # mostly inner cells
                          rng.uniform(lo - 2 * grid.voxel, lo + 2 * grid.voxel, size=(500, 3)),
                          rng.uniform(hi - 2 * grid.voxel, hi + 2 * grid.voxel, size=(500, 3))])
    h, worst, inner = grid.voxel, 0.0, 0
    for p in pts:
        ref = [sdf.grid_value(*args, *p)]
        for e in np.eye(3):
            ref.append((sdf.grid_value(*args, *(p + h * e)) - sdf.grid_value(*args, *(p - h * e))) / (2 * h))
        got = sdf.grid_lookup(*args, *p)
        worst = max(worst, np.abs(np.subtract(got, ref)).max(), np.abs(np.subtract(sdf.grid_gradient(*args, *p), ref[1:])).max())
        inner += bool(np.all(p >= lo + h) and np.all(p < hi - h))
    assert worst < 1e-9  # values ~0.1 m, gradients ~1: round-off
    assert 2000 < inner < len(pts) - 500  # both paths taken


def test_points_outside_grid_are_positive_and_grow_with_distance():
    """Outside the grid box: value = value at the projection onto the box + distance to it (> 0)."""
    grid = sdf.build_grid("sphere", {"radius": 0.04})
    hi = grid.origin + grid.voxel * (grid.dims - 1)
    p = np.array([[hi[0] + 0.1, 0.0, 0.0], [hi[0] + 0.2, 0.0, 0.0], [0.0, 0.0, grid.origin[2] - 0.05]])
    d, g = grid.query(p)
    edge, _ = grid.query(np.array([[hi[0], 0.0, 0.0], [0.0, 0.0, grid.origin[2]]]))
    assert np.all(d > 0)
    assert d[0] == pytest.approx(edge[0] + 0.1)
    assert d[1] == pytest.approx(edge[0] + 0.2)
    assert d[2] == pytest.approx(edge[1] + 0.05)
    np.testing.assert_allclose(g[0], [1, 0, 0])
    np.testing.assert_allclose(g[2], [0, 0, -1])


def test_mesh_grid_matches_analytic_box_and_sphere():
    """A watertight box mesh gives the exact box distance at the nodes; an icosphere mesh gives
    the sphere distance within the polygonal approximation error plus half a voxel."""
    size = (0.05, 0.06, 0.07)
    box = trimesh.creation.box(extents=size)
    grid = sdf.build_grid("mesh", {}, box.vertices, box.faces)
    nodes = sdf.grid_nodes(grid.origin, grid.voxel, grid.dims)
    np.testing.assert_allclose(grid.values, sdf.box_distance(nodes, size), atol=1e-6)
    ico = trimesh.creation.icosphere(subdivisions=3, radius=0.04)
    grid = sdf.build_grid("mesh", {}, ico.vertices, ico.faces)
    p = _band_points(grid, np.random.default_rng(2), 20000)
    d, _ = grid.query(p)
    # chord sag of the icosphere (edge ~ 5 mm on r = 40 mm) is below 0.2 mm
    assert np.abs(d - sdf.sphere_distance(p, 0.04)).max() < 0.5 * grid.voxel + 2e-4


def test_scene_objects_build_with_paper_memory_budget():
    """Every object of config/scene.yaml gets a grid of at most 81^3 float32 nodes (< 3 MB)."""
    for obj in load_scene().objects:
        grid = sdf.build_object_grid(obj)
        assert grid.nbytes <= 81 ** 3 * 4
        assert grid.values.min() < 0 < grid.values.max()
