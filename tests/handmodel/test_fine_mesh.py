"""Fine tissue mesh for the scaling work (issue #4): one build, counted and checked."""
import numpy as np
import pytest

from softhand_sim.handmodel import build_hand
from softhand_sim.handmodel.tets import dihedral_angles, tet_volumes


@pytest.mark.slow
def test_fine_mesh_counts_quality_volume_and_embedding():
    """Fine mesh: 7,000-10,000 tets, none inverted, minimum dihedral >= 10 deg, volume within 10 %
    of the skin's, every skin vertex in a tet or within 4 mm of one."""
    a = build_hand(resolution="fine")
    assert 7000 <= len(a.tets) <= 10000
    vol = tet_volumes(a.tet_nodes, a.tets)
    assert (vol > 0).all()
    assert np.degrees(dihedral_angles(a.tet_nodes, a.tets)).min() >= 10.0
    v, f = a.skin_vertices, a.skin_triangles
    skin_vol = np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6.0
    assert abs(vol.sum() / skin_vol - 1.0) < 0.10
    assert a.skin_embed_distance.max() <= 0.004
    assert (np.bincount(a.sample_bone, minlength=16) >= 1).all()
