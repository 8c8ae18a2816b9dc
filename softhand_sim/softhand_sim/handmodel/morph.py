"""A hand at other measures in about a second: the default hand morphed per bone (issue #16).

A full build (build.py) meshes the skin and the tissue anew: 40-160 s coarse, ~450 s fine. The
morph instead carries every skin vertex and tet node of the default hand to the fitted skeleton,
so the topology (tets, skin triangles) and the mesh quality (up to the stretch) stay those of
the default hand:

* each finger bone b maps by the affine p' = R1 S R0^T (p - o0) + o1: out of its default frame
  (origin o0 at the proximal joint, R0), scaled along the bone by the length ratio and across it
  by the finger's width ratio (S), into its fitted frame (o1, R1);
* the palm (with the thenar pad) maps by a thin-plate spline in the palm plane through the
  landmarks that place the default and fitted palm outlines (wrist, knuckles, palm polygon
  corners, thumb CMC and MCP, thenar root: shape.py), which also gives a height offset, and
  across the palm z scales with the palm thickness;
* the maps are blended by smooth weights from the signed distance of the point to each part of
  the default hand (palm slab + thenar pad; each bone's segment less the finger's half width):
  a soft minimum, palm against digits over PALM_BLEND, one finger against the others over
  FINGER_BLEND (fingers lie ~4 mm apart: no leak between them), and along a finger across each
  joint over JOINT_BLEND. Each map puts its joints exactly where the fitted skeleton has them,
  so the blend is continuous and exact at the joints;
* where the stretch is largest (a thumb CMC moved 25 mm toward the wrist) a few tets lose their
  angles: improve_tets nudges their nodes (at most QUALITY_MAX_MOVE) until they pass
  QUALITY_TARGET_DEG.

Then what depends on geometry is recomputed: the skeleton (frames, capsules, masses, joint
anchors) from the fitted measures exactly as build.py does, the skin's barycentric weights in
its (kept) tets and its distance to them (a vertex carried past the embedding tolerance is bound
to the tet embedding.py picks for it), and the bone-tissue samples, drawn anew on the fitted
capsules (morph_hand's `samples`: carrying the default ones keeps the sparsity pattern but
couples the palm to the thenar where the palm map bends). Rest shapes and lumped masses are
computed by physics.model from the tets. The left hand is the morphed right hand mirrored, as
build.py makes it.

The result must still pass checks.morph_problems (cache.py falls back to a full build if not).
"""
from __future__ import annotations

import time

import numpy as np
from numba import njit

from softhand_sim.handmodel.asset import HandAsset
from softhand_sim.handmodel.build import MIRROR, SIDES
from softhand_sim.handmodel.checks import tet_figures
from softhand_sim.handmodel.embedding import _closest_on_triangle, barycentric, embed_points
from softhand_sim.handmodel.measures import HandMeasures, as_measures
from softhand_sim.handmodel.samples import coupling_samples
from softhand_sim.handmodel.shape import HandShape, _polygon2d, _round_cone
from softhand_sim.handmodel.skeleton import FINGER_BONES, bone_chain_points, palm_centre_z, skeleton_from_frames
from softhand_sim.handmodel.skin import signed_volume
from softhand_sim.handmodel.tissue import COARSE_EMBED_TOLERANCE
from softhand_sim.handmodel.tets import dihedral_angles

MORPH_VERSION = "2"  # bump when the morph's output changes (part of the cache key)
PALM_BLEND = 0.0025  # [m] soft-min width palm <-> digits
FINGER_BLEND = 0.0008  # [m] soft-min width between fingers (their skins lie ~4 mm apart)
JOINT_BLEND = 0.002  # [m] soft-min width between the bones of one finger, across a joint
# Tet repair after the morph (improve_tets): tets under QUALITY_TARGET_DEG get their nodes moved
# by at most QUALITY_MAX_MOVE, in at most QUALITY_ROUNDS sweeps.
QUALITY_TARGET_DEG = 12.0  # [deg] (checks: >= 10; the default coarse hand's least angle is 12.7)
QUALITY_MAX_MOVE = 0.002  # [m]
QUALITY_ROUNDS = 40
INSIDE_TOLERANCE = 1e-9
REEMBED_DISTANCE = COARSE_EMBED_TOLERANCE  # [m] skin vertices farther from their tet are embedded anew  # smallest barycentric weight still counted as inside (embedding.py)


# ------------------------------------------------------------------------------ the palm map
def palm_landmarks(m: HandMeasures) -> np.ndarray:
    """(k, 3) points [m] that place the palm of `m` (shape.py): the wrist, the four knuckles
    (MCP), the thumb CMC and MCP, the palm polygon's corners (on the palm's mid plane) and the
    thenar pad's root. The same list, point for point, for any measures."""
    shape = HandShape(m)
    prox, _, _ = bone_chain_points(m)
    pts = [np.zeros(3)] + [prox[b] for b in (4, 7, 10, 13, 1, 2)]
    pts += [np.array([x, y, shape.palm_z]) for x, y in shape.poly] + [shape.thenar[:3]]
    return np.array(pts, dtype=np.float64)


def _tps_kernel(r2):
    return 0.5 * r2 * np.log(np.maximum(r2, 1e-30))  # r^2 log r


class PalmMap:
    """Map of palm points src -> dst [m]: a thin-plate spline in the palm plane gives x', y' and a
    height offset; across the palm, z scales about the palm's mid plane with its thickness. The
    landmarks (palm_landmarks) land exactly where `dst` has them, the thumb CMC and MCP in height too."""

    def __init__(self, src: HandMeasures, dst: HandMeasures):
        a, b = palm_landmarks(src), palm_landmarks(dst)
        self.z_src, self.z_dst = palm_centre_z(src), palm_centre_z(dst)
        self.z_ratio = dst.palm_thickness / src.palm_thickness
        self.scale = src.palm_length  # [m] coordinates in palm lengths: a well-conditioned system
        self.centres = a[:, :2] / self.scale
        n = len(a)
        k = _tps_kernel(((self.centres[:, None] - self.centres[None]) ** 2).sum(-1))
        p = np.column_stack([np.ones(n), self.centres])
        lhs = np.zeros((n + 3, n + 3))
        lhs[:n, :n], lhs[:n, n:], lhs[n:, :n] = k, p, p.T
        rhs = np.zeros((n + 3, 3))
        rhs[:n, :2] = b[:, :2]
        rhs[:n, 2] = b[:, 2] - self._z(a[:, 2])
        self.coef = np.linalg.solve(lhs, rhs / self.scale)

    def _z(self, z):
        return self.z_dst + (z - self.z_src) * self.z_ratio

    def __call__(self, points):
        q = points[:, :2] / self.scale
        n = len(self.centres)
        k = _tps_kernel(((q[:, None] - self.centres[None]) ** 2).sum(-1))
        out = (k @ self.coef[:n] + self.coef[n] + q @ self.coef[n + 1:]) * self.scale
        out[:, 2] += self._z(points[:, 2])
        return out


# ------------------------------------------------------------------------------ the finger maps
def finger_bone_maps(src: HandMeasures, dst: HandMeasures):
    """Affine maps (A (16,3,3), t (16,3)): p' = A p + t of each finger bone (index 0, the palm,
    unused), from its default frame to its fitted frame, scaled by length and width ratios."""
    p0, d0, r0 = bone_chain_points(src)
    p1, d1, r1 = bone_chain_points(dst)
    a = np.zeros((16, 3, 3))
    t = np.zeros((16, 3))
    for f, bones in FINGER_BONES.items():
        k = dst.finger_width(f) / src.finger_width(f)
        for b in bones:
            s = np.diag([np.linalg.norm(d1[b] - p1[b]) / np.linalg.norm(d0[b] - p0[b]), k, k])
            a[b] = r1[b] @ s @ r0[b].T
            t[b] = p1[b] - a[b] @ p0[b]
    return a, t


@njit(cache=True)
def _palm_distance(points, poly, palm_z, palm_r, thenar, out):
    """Signed distance [m] of points to the palm slab united with the thenar pad (shape.py)."""
    for i in range(points.shape[0]):
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        d2 = _polygon2d(px, py, poly)
        dz = pz - palm_z
        palm = np.sqrt(d2 * d2 + dz * dz) - palm_r if d2 > 0.0 else abs(dz) - palm_r
        out[i] = min(palm, _round_cone(px, py, pz, thenar))


def _segment_distance(points, a, b):
    ab = b - a
    t = np.clip((points - a) @ ab / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(points - (a + t[:, None] * ab), axis=1)


def _softmin_weights(d, width):
    """Normalised weights exp(-(d - min d) / width) over the last axis."""
    e = np.exp(-(d - d.min(axis=-1, keepdims=True)) / width)
    return e / e.sum(axis=-1, keepdims=True)


def _softmin(d, width):
    """Smooth minimum -width log sum exp(-d / width) over the last axis (<= min d)."""
    m = d.min(axis=-1)
    return m - width * np.log(np.exp(-(d - m[:, None]) / width).sum(axis=-1))


def blend_weights(points, src: HandMeasures, shape=None):
    """Weights (n, 16) [-] of the bone maps at default-hand points (n, 3), rows summing to 1
    (module docstring); column 0 is the palm's. shape: HandShape(src), if at hand."""
    if shape is None:
        shape = HandShape(src)
        shape.prox, shape.dist, _ = bone_chain_points(src)
    prox, dist = shape.prox, shape.dist
    n = len(points)
    d_palm = np.empty(n)
    _palm_distance(np.ascontiguousarray(points), shape.poly, shape.palm_z, shape.palm_r, shape.thenar, d_palm)
    w = np.zeros((n, 16))
    d_finger, within = [], []
    for f, bones in FINGER_BONES.items():
        half = 0.5 * src.finger_width(f)
        d = np.stack([_segment_distance(points, prox[b], dist[b]) - half for b in bones], axis=1)
        d_finger.append(_softmin(d, JOINT_BLEND))
        within.append(_softmin_weights(d, JOINT_BLEND))
    d_finger = np.stack(d_finger, axis=1)
    palm_vs_digits = _softmin_weights(np.column_stack([d_palm, _softmin(d_finger, FINGER_BLEND)]), PALM_BLEND)
    per_finger = _softmin_weights(d_finger, FINGER_BLEND) * palm_vs_digits[:, 1:]
    w[:, 0] = palm_vs_digits[:, 0]
    for i, bones in enumerate(FINGER_BONES.values()):
        w[:, list(bones)] = per_finger[:, i:i + 1] * within[i]
    return w


class HandMorph:
    """The blended map of default-hand points (right hand) from `src` to `dst` measures."""

    def __init__(self, src: HandMeasures, dst: HandMeasures):
        self.src, self.dst = src, dst
        self.palm = PalmMap(src, dst)
        self.shape = HandShape(src)
        self.shape.prox, self.shape.dist, _ = bone_chain_points(src)
        self.a, self.t = finger_bone_maps(src, dst)

    def __call__(self, points):
        points = np.asarray(points, dtype=np.float64)
        w = blend_weights(points, self.src, self.shape)
        out = w[:, :1] * self.palm(points)
        mapped = np.einsum("bij,nj->nbi", self.a[1:], points) + self.t[1:]  # (n, 15, 3)
        return out + np.einsum("nb,nbi->ni", w[:, 1:], mapped)


# ------------------------------------------------------------------------------ tet quality
@njit(cache=True)
def _local_quality(x, tets):
    """Least dihedral angle [deg] of `tets` at node positions x (tets.dihedral_angles, one tet at
    a time: this runs thousands of times on a handful of tets); -1000 if a volume is not positive."""
    faces = ((1, 2, 3), (0, 3, 2), (0, 1, 3), (0, 2, 1))
    pairs = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))
    best = 180.0
    n = np.empty((4, 3))
    for t in range(tets.shape[0]):
        p = x[tets[t]]
        if np.dot(p[1] - p[0], np.cross(p[2] - p[0], p[3] - p[0])) <= 0.0:
            return -1000.0
        for f in range(4):
            a, b, c = faces[f]
            v = np.cross(p[b] - p[a], p[c] - p[a])
            n[f] = v / max(np.sqrt(np.dot(v, v)), 1e-30)
        for i, j in pairs:
            best = min(best, np.degrees(np.arccos(min(max(-np.dot(n[i], n[j]), -1.0), 1.0))))
    return best


def improve_tets(nodes, tets, target_deg=QUALITY_TARGET_DEG, max_move=QUALITY_MAX_MOVE, rounds=QUALITY_ROUNDS):
    """Node positions (N,3) [m] with the tets under `target_deg` improved: each of their nodes
    steps up the gradient of the least dihedral angle of the tets around it (a local, optimisation
    based smoothing), never farther than `max_move` [m] from where it started. Where the morph
    stretches the mesh most (e.g. a thumb CMC moved 25 mm toward the wrist) a few surface tets lose
    their angles; nudging their nodes by a millimetre or two gets them back."""
    x = np.array(nodes, dtype=np.float64)
    start = x.copy()
    order = np.argsort(tets.ravel(), kind="stable")
    bounds = np.searchsorted(tets.ravel()[order], np.arange(len(x) + 1))
    incident = lambda v: np.ascontiguousarray(tets[order[bounds[v]:bounds[v + 1]] // 4])  # noqa: E731
    eye = np.eye(3) * 1e-6
    for _ in range(rounds):
        q = np.degrees(dihedral_angles(x, tets)).min(axis=1)
        bad = np.flatnonzero(q < target_deg)
        if not len(bad):
            break
        moved = False
        for v in np.unique(tets[bad]):
            local = incident(v)
            p0 = x[v].copy()
            f0 = _local_quality(x, local)
            grad = np.zeros(3)
            for k in range(3):
                x[v] = p0 + eye[k]
                up = _local_quality(x, local)
                x[v] = p0 - eye[k]
                grad[k] = (up - _local_quality(x, local)) / 2e-6
            x[v] = p0
            norm = np.linalg.norm(grad)
            if not np.isfinite(norm) or norm == 0.0:
                continue
            for step in (1e-3, 5e-4, 2.5e-4, 1e-4, 5e-5):
                p = p0 + step * grad / norm
                off = p - start[v]
                if np.linalg.norm(off) > max_move:
                    p = start[v] + off * (max_move / np.linalg.norm(off))
                x[v] = p
                if _local_quality(x, local) > f0 + 1e-6:
                    moved = True
                    break
                x[v] = p0
        if not moved:
            break
    return x


# ------------------------------------------------------------------------------ the asset
@njit(cache=True)
def _distance_to_tets(points, corners, bary, out):
    """Distance [m] of each point to its tet (corners (n,4,3)); 0 when its weights are >= 0."""
    faces = ((1, 2, 3), (0, 3, 2), (0, 1, 3), (0, 2, 1))
    for i in range(points.shape[0]):
        if bary[i].min() >= -INSIDE_TOLERANCE:
            out[i] = 0.0
            continue
        best = 1e30
        for f in faces:
            q = _closest_on_triangle(points[i], corners[i, f[0]], corners[i, f[1]], corners[i, f[2]])
            best = min(best, np.sqrt(np.sum((points[i] - q) ** 2)))
        out[i] = best


def _sample_world(asset):
    """World rest positions (P,3) of the asset's bone-tissue samples."""
    return np.einsum("pk,pki->pi", asset.sample_bary, asset.tet_nodes[asset.tets[asset.sample_tet]])


def morph_hand(base: HandAsset, measures, side="right", samples="resample") -> HandAsset:
    """The hand at `measures` (dict or HandMeasures), side 'right' or 'left', morphed from `base`,
    a right hand built at other measures (normally the default hand). Not checked: see
    checks.morph_problems.

    samples: 'resample' (default): the bone-tissue samples are drawn anew on the fitted capsules
    in the morphed tets (samples.coupling_samples, as build.py; ~1-2 s); 'carry': the default
    hand's samples carried by the blended map (same (tet, bone) pairs, so the same sparsity
    pattern). Carried samples drift off the fitted capsules where the palm map bends most (a Leap
    hand whose thumb CMC sits 25 mm nearer the wrist: palm samples spread 7 mm toward the thumb,
    the thumb metacarpal's 6 mm sideways), which couples the palm to the thenar: on leap_grab the
    palm followed the tracked wrist 5.8 mm (median) off against 3.0 mm for the built hand;
    resampled, 3.2 mm."""
    if side not in SIDES:
        raise ValueError(f"side must be 'right' or 'left', got {side!r}")
    if base.side != "right":
        raise ValueError("morph_hand needs a right hand to morph from (the left is its mirror)")
    t0 = time.perf_counter()
    src, dst = as_measures(base.measures), as_measures(measures)
    morph = HandMorph(src, dst)
    tets = np.asarray(base.tets)
    skin = morph(base.skin_vertices)
    nodes = morph(base.tet_nodes)
    morphed_nodes = nodes
    nodes = improve_tets(nodes, tets)
    nudged = np.linalg.norm(nodes - morphed_nodes, axis=1)
    prox, dist, rot = bone_chain_points(dst)
    skel = skeleton_from_frames(dst, prox, dist, rot)
    skin_tet = np.asarray(base.skin_tet)
    skin_bary = barycentric(nodes, tets, skin_tet, skin)
    skin_dist = np.empty(len(skin))
    _distance_to_tets(skin, nodes[tets[skin_tet]], skin_bary, skin_dist)
    # a vertex the stretch carried past the tolerance from its tet's flat face: bind it anew
    far = np.flatnonzero(skin_dist > REEMBED_DISTANCE)
    if len(far):
        skin_tet = skin_tet.copy()
        skin_tet[far], skin_bary[far], skin_dist[far] = embed_points(nodes, tets, skin[far])
    if samples == "resample":
        fresh = coupling_samples(nodes, tets, skel["bone_rest_pose"], skel["bone_capsule_a"],
                                 skel["bone_capsule_b"], skel["bone_capsule_radius"])
        sample_tet, sample_bone, sample_count = fresh["sample_tet"], fresh["sample_bone"], fresh["sample_count"]
        sample_bary, sample_local, sample_total = fresh["sample_bary"], fresh["sample_local"], fresh["bone_sample_total"]
    elif samples == "carry":
        points = morph(_sample_world(base))
        sample_tet, sample_bone = np.asarray(base.sample_tet), np.asarray(base.sample_bone)
        sample_count, sample_total = np.asarray(base.sample_count), np.asarray(base.bone_sample_total)
        sample_bary = barycentric(nodes, tets, sample_tet, points)
        sample_local = np.einsum("pij,pi->pj", rot[sample_bone], points - prox[sample_bone])
    else:
        raise ValueError(f"samples must be 'resample' or 'carry', got {samples!r}")
    faces = np.asarray(base.skin_triangles)
    surface = np.asarray(base.tet_surface_triangles)  # same tets: same boundary
    if side == "left":  # as build.py: the right hand mirrored vertex for vertex
        skin, nodes = skin @ MIRROR, nodes @ MIRROR
        faces, tets, surface = faces[:, [0, 2, 1]], tets[:, [0, 2, 1, 3]], surface[:, [0, 2, 1]]
        skin_bary, sample_bary = skin_bary[:, [0, 2, 1, 3]], sample_bary[:, [0, 2, 1, 3]]
        skel = skeleton_from_frames(dst, prox @ MIRROR, dist @ MIRROR, MIRROR @ rot @ MIRROR)
        sample_local = sample_local @ MIRROR
    skin_volume = signed_volume(skin, faces)
    tf = tet_figures(nodes, tets, skin_volume)
    info = dict(method="morph", morph_version=MORPH_VERSION, samples=samples, morphed_from=src.digest(), resolution=base.build_info.get(
        "resolution"), tet_count=tf["tets"], inverted=tf["inverted"], min_dihedral_deg=tf["min_dihedral_deg"],
        volume_error=tf["volume_error"], skin_triangle_count=int(len(faces)), skin_vertex_count=int(len(skin)),
        skin_volume=float(skin_volume), max_skin_embed_distance=float(skin_dist.max()),
        skin_reembedded=int(len(far)), nodes_nudged=int((nudged > 0).sum()), max_nudge_mm=round(float(nudged.max()) * 1e3, 3),
        time_total_s=time.perf_counter() - t0)
    return HandAsset(
        side=side, skin_vertices=skin, skin_triangles=faces.astype(np.int32), tet_nodes=nodes,
        tets=tets.astype(np.int32), tet_surface_triangles=surface,
        skin_tet=skin_tet.astype(np.int32), skin_bary=skin_bary, skin_embed_distance=skin_dist,
        sample_tet=sample_tet.astype(np.int32), sample_bone=sample_bone.astype(np.int32),
        sample_count=np.asarray(sample_count, dtype=np.int32), sample_local=sample_local,
        sample_bary=sample_bary, bone_sample_total=np.asarray(sample_total, dtype=np.int32),
        measures=dst.to_dict(), build_info=info, **skel)
