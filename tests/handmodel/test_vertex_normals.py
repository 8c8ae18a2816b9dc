"""rigid_skin.vertex_normals: unit, outward, area-weighted; a vertex on no triangle gets a zero
normal (the self-contact kernel skips it), not NaN (which its depth tests would let through)."""
import numpy as np

from softhand_sim.handmodel.rigid_skin import vertex_normals


def test_normals_of_a_tetrahedron_and_an_unused_vertex():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [5, 5, 5]], float)
    tri = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])  # outward, vertex 4 on none
    n = vertex_normals(v, tri)
    assert np.all(np.isfinite(n))
    assert np.allclose(np.linalg.norm(n[:4], axis=1), 1.0) and np.array_equal(n[4], np.zeros(3))
    assert np.allclose(n[0], -np.ones(3) / np.sqrt(3))  # three equal right-angle faces meet there
    centre = v[:4].mean(axis=0)
    assert np.all(np.sum(n[:4] * (v[:4] - centre), axis=1) > 0)  # outward
