"""Tissue mesh of a target size.

"coarse" (paper Sect. 5.1: 856 tets) comes from the structured hex grid of hexmesh.py (~850 tets,
fingers one ring of cells across). "fine" uses isosurface stuffing, described below.

The stuffed mesh's boundary nodes lie on the level set, and its flat faces cut the curved skin
(fingers are only one or two lattice cells across), so at the zero level it holds less volume than
the skin. We therefore stuff the level set sdf = offset, with the offset (a fraction of a
millimetre) found by bisection so that the tet volume matches the skin volume, and scan the
lattice spacing until the tet count falls in the requested range. Everything is deterministic.
"""
import numpy as np

from softhand_sim.handmodel.hexmesh import coarse_tissue
from softhand_sim.handmodel.tets import dihedral_angles, stuff, tet_volumes

TET_COUNT_RANGES = {"coarse": (800, 900, 850), "fine": (7000, 10000, 8500)}  # (min, max, aim)
# [m] stated embedding tolerance of the coarse mesh: its flat faces span up to ~15 mm of curved
# skin (webs between fingers, thenar), so a few % of skin vertices lie 3-6 mm outside their tet
COARSE_EMBED_TOLERANCE = 0.0065
OFFSET_RANGE = (-0.002, 0.004)  # [m] search interval of the level-set offset
OFFSET_BISECTIONS = 11
SPACING_STEP = 1.01  # relative step of the fine lattice-spacing scan
SPACING_TRIES = 60


def _stuff_matched(shape, lo, hi, h, skin_volume, stretch=np.ones(3)):
    """Stuff at spacing h (lattice stretched by `stretch`) with the offset whose tet volume is
    closest to skin_volume. Returns nodes, tets, offset, relative volume error."""
    a, b = OFFSET_RANGE
    best = None
    for _ in range(OFFSET_BISECTIONS):
        off = 0.5 * (a + b)
        nodes, tets = stuff(lambda u: shape.sdf(u * stretch, off), lo / stretch, hi / stretch, h)
        nodes = nodes * stretch
        err = tet_volumes(nodes, tets).sum() / skin_volume - 1.0
        if best is None or abs(err) < abs(best[3]):
            best = (nodes, tets, off, err)
        if err > 0:
            b = off
        else:
            a = off
    return best


def _figures(nodes, tets, h, off, err, cover):
    da = np.degrees(dihedral_angles(nodes, tets))
    return dict(spacing=float(h), offset=float(off), volume_error=float(err),
                min_dihedral_deg=float(da.min()), max_dihedral_deg=float(da.max()),
                tet_count=int(len(tets)), max_skin_distance=float(cover))


def build_tissue(shape, skin_vertices, skin_volume, resolution="coarse", measures=None):
    """Tet mesh with its volume matched to the skin's.

    "coarse": the hex-grid mesh of hexmesh.coarse_tissue (needs `measures`), 800-900 tets.
    "fine": isosurface stuffing with a tet count in TET_COUNT_RANGES["fine"] (isotropic lattice).
    Returns nodes (N,3), tets (T,4) int32 (positive volume) and a dict of figures.
    """
    from softhand_sim.handmodel.embedding import embed_points

    if resolution not in TET_COUNT_RANGES:
        raise ValueError(f"resolution must be one of {sorted(TET_COUNT_RANGES)}, got {resolution!r}")
    if resolution == "coarse":
        if measures is None:
            raise ValueError("build_tissue(resolution='coarse') needs the hand measures")
        nodes, tets, fig = coarse_tissue(shape, measures, skin_volume)
        cover = embed_points(nodes, tets, skin_vertices)[2].max()
        return nodes, tets.astype(np.int32), _figures(nodes, tets, fig["spacing"], fig["offset"],
                                                      fig["volume_error"], cover)
    lo = skin_vertices.min(axis=0) - 0.005
    hi = skin_vertices.max(axis=0) + 0.005
    t_min, t_max, t_aim = TET_COUNT_RANGES[resolution]
    # first guess from the volume: a BCC tet holds h^3 / 12, boundary stencils are smaller
    h = (12.0 * skin_volume / (0.7 * t_aim)) ** (1.0 / 3.0)
    tried = []
    for _ in range(SPACING_TRIES):
        nodes, tets, off, err = _stuff_matched(shape, lo, hi, h, skin_volume)
        count = len(tets)
        tried.append((h, count))
        if t_min <= count <= t_max:
            break
        # count ~ h^-3: step toward the aim, at least one scan step, at most 5 %
        ratio = np.clip((count / t_aim) ** (1.0 / 3.0), 1.0 / 1.05, 1.05)
        if abs(ratio - 1.0) < SPACING_STEP - 1.0:
            ratio = SPACING_STEP if count > t_aim else 1.0 / SPACING_STEP
        h *= ratio
    else:
        raise RuntimeError(f"no lattice spacing gave {t_min}-{t_max} tets; tried (h, count): {tried}")
    cover = embed_points(nodes, tets, skin_vertices)[2].max()
    return nodes, tets.astype(np.int32), _figures(nodes, tets, h, off, err, cover)
