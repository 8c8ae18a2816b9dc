"""build_hand: measures -> HandAsset (right hand built, left hand mirrored through the xz plane)."""
import time

import numpy as np

from softhand_sim.handmodel.asset import HandAsset
from softhand_sim.handmodel.embedding import embed_points
from softhand_sim.handmodel.measures import as_measures
from softhand_sim.handmodel.samples import coupling_samples
from softhand_sim.handmodel.shape import HandShape
from softhand_sim.handmodel.skeleton import bone_chain_points, skeleton_from_frames
from softhand_sim.handmodel.skin import build_skin, signed_volume
from softhand_sim.handmodel.tets import boundary_triangles
from softhand_sim.handmodel.tissue import build_tissue

SIDES = ("right", "left")
MIRROR = np.diag([1.0, -1.0, 1.0])  # y -> -y


def build_hand(measures=None, side="right", resolution="coarse"):
    """Build the hand asset of `measures` (None: defaults; dict or HandMeasures).

    side: "right" or "left" (the right hand mirrored vertex for vertex); resolution: "coarse"
    (solver mesh) or "fine" (7-10k tets, for scaling studies).
    """
    if side not in SIDES:
        raise ValueError(f"side must be 'right' or 'left', got {side!r}")
    m = as_measures(measures)
    t0 = time.perf_counter()
    shape = HandShape(m)
    skin_v, skin_f = build_skin(shape)
    skin_volume = signed_volume(skin_v, skin_f)
    t1 = time.perf_counter()
    nodes, tets, figures = build_tissue(shape, skin_v, skin_volume, resolution, m)
    t2 = time.perf_counter()
    skin_tet, skin_bary, skin_dist = embed_points(nodes, tets, skin_v)
    prox, dist, rot = bone_chain_points(m)
    skel = skeleton_from_frames(m, prox, dist, rot)
    samples = coupling_samples(nodes, tets, skel["bone_rest_pose"], skel["bone_capsule_a"],
                               skel["bone_capsule_b"], skel["bone_capsule_radius"])
    if side == "left":  # mirror everything, so that left is the right hand's exact mirror image
        skin_v, nodes = skin_v @ MIRROR, nodes @ MIRROR
        skin_f = skin_f[:, [0, 2, 1]]
        tets = tets[:, [0, 2, 1, 3]]
        skin_bary = skin_bary[:, [0, 2, 1, 3]]
        prox, dist = prox @ MIRROR, dist @ MIRROR
        rot = MIRROR @ rot @ MIRROR  # mirrored x and z axes, y = z x x
        skel = skeleton_from_frames(m, prox, dist, rot)
        # a mirror keeps flexion (about y = z x x) but reverses abduction (about z): the mirror
        # of a right-hand abduction range [lo, hi] is [-hi, -lo] (the thumb CMC's is asymmetric)
        skel["joint_limits"][:, 1] = -skel["joint_limits"][:, 1, ::-1]
        samples["sample_local"] = samples["sample_local"] @ MIRROR  # bone-frame y flips
        samples["sample_bary"] = samples["sample_bary"][:, [0, 2, 1, 3]]
    t3 = time.perf_counter()
    figures.update(skin_triangle_count=int(len(skin_f)), skin_vertex_count=int(len(skin_v)),
                   skin_volume=float(skin_volume), resolution=resolution,
                   max_skin_embed_distance=float(skin_dist.max()),
                   time_skin_s=t1 - t0, time_tissue_s=t2 - t1, time_embed_samples_s=t3 - t2,
                   time_total_s=t3 - t0)
    return HandAsset(
        side=side, skin_vertices=skin_v, skin_triangles=skin_f.astype(np.int32), tet_nodes=nodes,
        tets=tets.astype(np.int32), tet_surface_triangles=boundary_triangles(tets),
        skin_tet=skin_tet, skin_bary=skin_bary, skin_embed_distance=skin_dist,
        measures=m.to_dict(), build_info=figures, **skel, **samples)
