"""Figures that say whether a built hand is usable: skin closed and manifold, tet quality, embedding.

Shared by `softhand model info` and the tests of hands at other measures.
"""
import numpy as np

from softhand_sim.handmodel.skin import signed_volume
from softhand_sim.handmodel.tets import dihedral_angles, tet_volumes


def skin_is_closed_manifold(vertices, triangles) -> bool:
    """Every edge in exactly two triangles, once in each direction (consistently oriented), Euler
    characteristic 2 (one closed sphere-like surface) and positive enclosed volume (outward)."""
    f = np.asarray(triangles, dtype=np.int64)
    directed = np.vstack([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    n = int(f.max()) + 1  # edges as one integer each: 1-d np.unique is far faster than axis=0
    if len(np.unique(directed[:, 0] * n + directed[:, 1])) != len(directed):
        return False
    _, counts = np.unique(directed.min(axis=1) * n + directed.max(axis=1), return_counts=True)
    if not (counts == 2).all():
        return False
    used = len(np.unique(f))
    return used - len(counts) + len(f) == 2 and signed_volume(np.asarray(vertices), f) > 0


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


MIN_DIHEDRAL_DEG = 10.0  # issue #16: the least dihedral angle of any usable tet mesh
MAX_VOLUME_ERROR = 0.10  # |tet volume / skin volume - 1|
EMBEDDED_FRACTION = 0.999  # of the skin vertices within the stated tolerance ...
EMBED_MAX = 0.0075  # [m] ... and every one within this (the fitted hands' figure, tests/handmodel)


def morph_problems(asset, tolerance) -> list:
    """What makes `asset` (a morphed hand, handmodel.morph) unusable, as sentences; [] if nothing:
    skin not a closed outward 2-manifold, an inverted tet, a dihedral angle under MIN_DIHEDRAL_DEG,
    tet volume off the skin's by more than MAX_VOLUME_ERROR, fewer than EMBEDDED_FRACTION of the
    skin vertices within `tolerance` [m] of their tet or one farther than EMBED_MAX."""
    skin_volume = signed_volume(np.asarray(asset.skin_vertices), np.asarray(asset.skin_triangles))
    problems = []
    if not skin_is_closed_manifold(asset.skin_vertices, asset.skin_triangles):
        problems.append("skin is not a closed outward 2-manifold")
    t = tet_figures(asset.tet_nodes, asset.tets, skin_volume)
    if t["inverted"]:
        problems.append(f"{t['inverted']} inverted tet(s)")
    if t["min_dihedral_deg"] < MIN_DIHEDRAL_DEG:
        problems.append(f"min dihedral {t['min_dihedral_deg']:.1f} deg < {MIN_DIHEDRAL_DEG} deg")
    if abs(t["volume_error"]) > MAX_VOLUME_ERROR:
        problems.append(f"tet volume off the skin's by {100 * t['volume_error']:.1f} %")
    d = np.asarray(asset.skin_embed_distance)
    if np.mean(d <= tolerance) < EMBEDDED_FRACTION or d.max() > EMBED_MAX:
        problems.append(f"skin embedding: {100 * np.mean(d <= tolerance):.2f} % of the vertices within "
                        f"{tolerance * 1e3:.1f} mm, farthest {d.max() * 1e3:.2f} mm (limit {EMBED_MAX * 1e3:.1f} mm)")
    return problems
