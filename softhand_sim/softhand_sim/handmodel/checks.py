"""Figures that say whether a built hand is usable: skin closed and manifold, tet quality, embedding.

Shared by `softhand model info` and the tests of hands at other measures.
"""
import numpy as np

from softhand_sim.handmodel.skin import signed_volume
from softhand_sim.handmodel.tets import dihedral_angles, tet_volumes


def skin_is_closed_manifold(vertices, triangles) -> bool:
    """Every edge in exactly two triangles, once in each direction (consistently oriented), Euler
    characteristic 2 (one closed sphere-like surface) and positive enclosed volume (outward)."""
    f = np.asarray(triangles)
    directed = np.vstack([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    if len(np.unique(directed, axis=0)) != len(directed):
        return False
    und, counts = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
    if not (counts == 2).all():
        return False
    used = len(np.unique(f))
    return used - len(und) + len(f) == 2 and signed_volume(np.asarray(vertices), f) > 0


def tet_figures(nodes, tets, skin_volume) -> dict:
    """tets, inverted (count of tets of non-positive volume), min_dihedral_deg, volume_error
    (tet volume / skin volume - 1)."""
    vol = tet_volumes(nodes, tets)
    return dict(tets=int(len(tets)), inverted=int((vol <= 0).sum()),
                min_dihedral_deg=float(np.degrees(dihedral_angles(nodes, tets)).min()),
                volume_error=float(vol.sum() / skin_volume - 1.0))


def asset_figures(asset, tolerance) -> dict:
    """The figures of one built asset: skin, tets and embedding (fraction of skin vertices within
    `tolerance` [m] of their tet; 0 distance = inside)."""
    skin_volume = signed_volume(np.asarray(asset.skin_vertices), np.asarray(asset.skin_triangles))
    out = dict(skin_triangles=int(len(asset.skin_triangles)),
               skin_watertight=bool(skin_is_closed_manifold(asset.skin_vertices, asset.skin_triangles)),
               skin_volume_cm3=round(float(skin_volume) * 1e6, 2))
    out.update(tet_figures(asset.tet_nodes, asset.tets, skin_volume))
    d = np.asarray(asset.skin_embed_distance)
    out.update(embedded_fraction=float(np.mean(d <= tolerance)), max_embed_distance_mm=round(float(d.max()) * 1e3, 2))
    return out
