"""Skin-skin contact inside a hand (and between hands): detection, anchors and Coulomb stick/slip
(the collide stage for energies/self_contact.py; issue #21).

Geometry. The skin is cut into segments, one per bone (each skin vertex follows its nearest bone
axis at rest, handmodel.rigid_skin). Each segment carries, built once at rest in its bone's
frame, the signed distance field of its own skin (the segment's triangles, its open joint cuts
closed by fans: a watertight surface) and, on the same grid, the index of its skin vertex nearest
to each grid node. Each step:
  broad phase   every skin point embedded; for the pairs allowed to touch, the bounding sphere
                of one segment's current skin, then of each of its clusters of 32 points,
                against the other segment's box (its bone's frame);
  narrow phase  the skin points of one segment of a pair, moved into the other's bone frame: a
                bounding-box test, then its field (both ways round: each way carries half of the
                point's skin area, so the pressure is k_n x depth, as against objects);
  anchor        a new contact's anchor starts at the field's closest surface point, kept as the
                other segment's nearest skin vertex plus a short rest-frame offset and normal that
                turn with that vertex's tet; a walk over the skin mesh then moves it to the vertex
                nearest the point on the *deformed* skin (with that vertex's own normal), and the
                offset's part along the normal is dropped, so the anchor sits on the deformed
                skin's tangent plane: both skins flatten and the penetration is measured against
                the deformed surface (n . D > 0), not against the rigid field (where tissue had
                bulged, the rest projection left anchors 2 mm off the skin and missed contacts);
  friction      as contact/detection.py: stick while k_f |t| <= mu k_n (n . D), else slide the
                anchor to the cone, back onto the surface (the field, at rest), then to the cone
                once more; SLIDING (moving away) drops the friction stiffness along the slip.
A contact is released when its point is outside the deformed surface (n . D <= 0) or deeper
than MAX_DEPTH (it has passed through; the field finds it afresh on the right side).

Which parts may touch (the rule):
  - never two segments adjacent in the skeleton (the two sides of one joint's crease: their skin
    is one continuous surface that the tissue itself keeps apart);
  - never a skin point that lies within `rest_clearance` [m] of the other segment's skin at rest
    (webs between the fingers, the thumb's base on the palm: skin that is already in touch or
    part of the same fold at rest).
Everything else may touch, across hands too: the two-hands case is the same code with both hands'
segments in one list (segment_body points into the model's bodies, adjacency from each hand's
joints; no pair of segments of different hands is adjacent).

Stiffness: k_n, k_f within a hand; between two hands both times `pair_scale` (the model's
self_contact_kn_hands / self_contact_kn), carried by the contact's weight w.

What the method misses (measured with physics/contact/penetration.py, which finds skin inside
another segment's deformed skin without the contact list): the field of a segment does not
deform. It decides which points are candidates, so a point touching skin that bulged out by more
than `margin` is caught late; the anchor and the depth follow the deformed skin (above). On the
tight fist (scenarios/self_contact.uncaught_penetration) points 1.6-2.05 mm deep were not contacts
0.33-0.40 s into the closing, none deeper than 0.1 mm once it was held.
Contacts with skin of the same segment (a finger folding onto itself) and with adjacent segments
are not handled.

Cost is bounded: at most `capacity` contacts (the rest are counted in `dropped`), one field
lookup per candidate point.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from numba import njit

from softhand_sim.physics.contact import sdf
from softhand_sim.physics.contact.clusters import spatial_clusters
from softhand_sim.physics.contact.contact_model import vertex_areas
from softhand_sim.physics.contact.sdf_mesh import mesh_signed_distance_grid
from softhand_sim.physics.embedded import embedded_positions
from softhand_sim.physics.energies import self_contact as energy
from softhand_sim.physics.energies.self_contact import normal_pressure
from softhand_sim.physics.rotations import quat_to_matrix, quat_to_matrix_into

STICK, SLIP, SLIDING = 0, 1, 2
_CONE_SLACK = 1e-9
MAX_DEPTH = 0.01  # [m] a kept contact deeper than this has passed through: released (found afresh)


@dataclass
class SelfContactModel:
    """Static data. P skin points, S segments; grids packed flat (bone frames)."""
    point_tet: np.ndarray      # (P,) i4
    point_bary: np.ndarray     # (P,4)
    point_rest: np.ndarray     # (P,3) [m] embedded rest position (world)
    point_area: np.ndarray     # (P,) [m^2] half the vertex area (each pair is tested both ways)
    point_segment: np.ndarray  # (P,) i4
    point_exclude: np.ndarray  # (P,) u8 bit s: never touches segment s (rest_clearance rule)
    point_normal: np.ndarray   # (P,3) outward skin normal at rest (world)
    nbr_ptr: np.ndarray        # (P+1,) i8 each point's skin neighbours of its own segment:
    nbr: np.ndarray            # nbr[nbr_ptr[p]:nbr_ptr[p+1]] (i4; the walk to the nearest vertex)
    seg_points: np.ndarray     # (P,) i4 point indices sorted by segment, then by cluster
    seg_clusters: np.ndarray   # (S+1,) i8 range of each segment's clusters
    cluster_start: np.ndarray  # (K+1,) i8 range of each cluster in seg_points
    seg_body: np.ndarray       # (S,) i4 solver body (bone) carrying the segment
    seg_rest_R: np.ndarray     # (S,3,3) bone rest rotation (world from bone)
    seg_rest_o: np.ndarray     # (S,3) [m] bone rest origin
    seg_lo: np.ndarray         # (S,3) [m] bone-frame box of the segment's skin
    seg_hi: np.ndarray
    pair_ok: np.ndarray        # (S,S) u1: the two segments may touch
    pair_scale: np.ndarray     # (S,S) f8: stiffness of a contact of the pair / (kn, kf) (between hands)
    grid_values: np.ndarray    # concatenated f4 signed distances
    grid_nearest: np.ndarray   # concatenated i4 nearest skin point of the segment
    grid_adr: np.ndarray       # (S,2) i8
    grid_origin: np.ndarray    # (S,3)
    grid_voxel: np.ndarray     # (S,)
    grid_dims: np.ndarray      # (S,3) i4
    kn: float                  # [N/m^3]
    kf: float
    kd: float                  # [N/m^3] normal stiffness added deeper than d0 (energies/self_contact.py)
    d0: float                  # [m]
    mu: float                  # Coulomb coefficient skin on skin
    margin: float              # [m] field value below which a point is a candidate
    build_s: float = 0.0

    @property
    def point_count(self):
        return len(self.point_tet)

    @property
    def segment_count(self):
        return len(self.seg_body)


def _close_segment(vertices, triangles):
    """Triangles (F,3) closed by a fan over each boundary loop to the loop's centroid, plus the
    extended vertex array: a watertight surface for the crossing-parity sign."""
    tri = np.asarray(triangles, np.int64)
    edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    key = {tuple(e) for e in edges.tolist()}
    boundary = [e for e in edges.tolist() if (e[1], e[0]) not in key]  # half-edges without a twin
    nxt = {}
    for a, b in boundary:
        nxt.setdefault(b, []).append(a)  # the cap walks the boundary the other way round
    verts = [np.asarray(vertices, float)]
    caps = []
    n0 = len(vertices)
    used = set()
    for a, b in boundary:
        if (a, b) in used:
            continue
        loop = [a]
        cur = a
        while True:  # follow reversed half-edges b -> a
            cands = [c for c in nxt.get(cur, []) if (c, cur) not in used]
            if not cands:
                break
            c = cands[0]
            used.add((c, cur))
            if c == a:
                break
            loop.append(c)
            cur = c
        if len(loop) < 3:
            continue
        centre = verts[0][loop].mean(axis=0)
        ci = n0 + len(caps)
        caps.append(centre)
        for i in range(len(loop)):
            tri = np.vstack([tri, [loop[i], loop[(i + 1) % len(loop)], ci]])
    if caps:
        verts.append(np.array(caps))
    return np.concatenate(verts), tri


def _segment_neighbours(triangles, point_segment, count):
    """(ptr (P+1,) i8, nbr (E,) i4): the skin-mesh neighbours of each point within its own segment."""
    tri = np.asarray(triangles, np.int64)
    e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    e = np.concatenate([e, e[:, ::-1]])
    e = e[point_segment[e[:, 0]] == point_segment[e[:, 1]]]
    e = np.unique(e, axis=0)  # sorted by the first point
    ptr = np.zeros(count + 1, np.int64)
    np.add.at(ptr, e[:, 0] + 1, 1)
    return np.cumsum(ptr), np.ascontiguousarray(e[:, 1], np.int32)


def build_self_contact_model(model, points_rest_tet, points_bary, triangles, point_segment,
                             segment_body, adjacent, kn=3.0e7, kf=1.5e7, mu=0.5,
                             kd=0.0, d0=0.001, rest_clearance=0.0015, voxel=0.001, band=4, margin=0.0005,
                             segment_hand=None, between_hands=1.0):
    """SelfContactModel of the skin points (embedded in model.tets: tet (P,), bary (P,4)),
    skin triangles (F,3) over those points, point_segment (P,) (segment of each point),
    segment_body (S,) (the model body, a bone, of each segment) and adjacent: pairs of segments
    that never touch (the skeleton's joints). segment_hand (S,): the hand of each segment (None:
    one hand); a contact between two hands is `between_hands` times as stiff (kn and kf alike).
    Units: m, N/m^3."""
    t0 = time.perf_counter()
    ptet = np.ascontiguousarray(points_rest_tet, np.int32)
    pbary = np.ascontiguousarray(points_bary, float)
    prest = np.einsum("pa,pai->pi", pbary, model.node_rest[model.tets[ptet]])
    pseg = np.asarray(point_segment, np.int32)
    segb = np.asarray(segment_body, np.int32)
    S = len(segb)
    if S > 64:
        raise ValueError(f"{S} segments: the exclusion mask holds 64")
    tri = np.asarray(triangles, np.int64)
    area = 0.5 * vertex_areas(prest, tri)
    pair_ok = np.ones((S, S), np.uint8)
    np.fill_diagonal(pair_ok, 0)
    for a, b in adjacent:
        pair_ok[a, b] = pair_ok[b, a] = 0
    pair_scale = np.ones((S, S))
    if segment_hand is not None:
        hand = np.asarray(segment_hand)
        pair_scale[hand[:, None] != hand[None, :]] = float(between_hands)
    rest_pose = model.body_rest_pose[segb]
    Rr = np.array([quat_to_matrix(q) for q in rest_pose[:, 3:]])
    orr = rest_pose[:, :3].copy()
    lo, hi = np.zeros((S, 3)), np.zeros((S, 3))
    values, nearest, adr, origin, vox, dims = [], [], [], [], [], []
    tri_seg = pseg[tri]
    start = 0
    grids = []
    from scipy.spatial import cKDTree
    for s in range(S):
        own = np.flatnonzero(pseg == s)
        local = (prest - orr[s]) @ Rr[s]  # all points in this bone's rest frame
        mine = local[own]
        lo[s], hi[s] = mine.min(axis=0), mine.max(axis=0)
        seg_tri = tri[(tri_seg == s).all(axis=1)]
        remap = np.full(len(prest), -1, np.int64)
        remap[own] = np.arange(len(own))
        cv, ct = _close_segment(mine, remap[seg_tri])
        org = lo[s] - band * voxel
        dim = (np.ceil((hi[s] - lo[s]) / voxel - 1e-9).astype(np.int64) + 2 * band + 1).astype(np.int32)
        vals = mesh_signed_distance_grid(np.ascontiguousarray(cv), np.ascontiguousarray(ct, np.int64),
                                         org, float(voxel), dim).astype(np.float32)
        nodes = sdf.grid_nodes(org, voxel, dim)
        near = own[cKDTree(mine).query(nodes)[1]].astype(np.int32)
        values.append(vals)
        nearest.append(near)
        adr.append((start, start + len(vals)))
        start += len(vals)
        origin.append(org)
        vox.append(float(voxel))
        dims.append(dim)
        grids.append(sdf.DistanceGrid(org, float(voxel), dim, vals))
    # points by segment, each segment's by cluster: the kernel skips a cluster whose sphere stays
    # clear of the other segment's box (a segment's sphere is loose: the proximal phalanxes' reach
    # over the knuckles)
    order, seg_clusters, cluster_start = [], [0], [0]
    for s in range(S):
        own = np.flatnonzero(pseg == s)
        for idx in spatial_clusters(prest[own]):
            order.append(own[idx])
            cluster_start.append(cluster_start[-1] + len(idx))
        seg_clusters.append(len(cluster_start) - 1)
    order = np.concatenate(order).astype(np.int32)
    # rest_clearance rule: a point never touches a segment whose rest skin is that close
    exclude = np.zeros(len(prest), np.uint64)
    for s in range(S):
        others = np.flatnonzero(pair_ok[pseg, s] == 1)
        if len(others) == 0:
            continue
        d, _ = grids[s].query((prest[others] - orr[s]) @ Rr[s])
        close = others[d < rest_clearance]
        exclude[close] |= np.uint64(1) << np.uint64(s)
    nbr_ptr, nbr = _segment_neighbours(tri, pseg, len(prest))
    from softhand_sim.handmodel.rigid_skin import vertex_normals
    return SelfContactModel(
        point_tet=ptet, point_bary=pbary, point_rest=prest, point_area=area, point_segment=pseg,
        point_exclude=exclude, point_normal=np.ascontiguousarray(vertex_normals(prest, tri), float),
        nbr_ptr=nbr_ptr, nbr=nbr, seg_points=order,
        seg_clusters=np.array(seg_clusters, np.int64), cluster_start=np.array(cluster_start, np.int64),
        seg_body=segb, seg_rest_R=Rr,
        seg_rest_o=orr, seg_lo=lo, seg_hi=hi, pair_ok=pair_ok, pair_scale=pair_scale,
        grid_values=np.concatenate(values), grid_nearest=np.concatenate(nearest),
        grid_adr=np.array(adr, np.int64), grid_origin=np.array(origin), grid_voxel=np.array(vox),
        grid_dims=np.array(dims, np.int32), kn=float(kn), kf=float(kf), kd=float(kd), d0=float(d0), mu=float(mu),
        margin=float(margin), build_s=time.perf_counter() - t0)


@njit(cache=True)
def _field(values, adr, origin, voxel, dims, s, p):
    return sdf.grid_value(values[adr[s, 0]:adr[s, 1]], origin[s], voxel[s], dims[s], p[0], p[1], p[2])


@njit(cache=True)
def _project(values, adr, origin, voxel, dims, s, p, out, nrm):
    """Closest rest surface point of segment s (bone frame) into out, unit normal there into nrm."""
    vs = values[adr[s, 0]:adr[s, 1]]
    for i in range(3):
        out[i] = p[i]
    for _ in range(2):  # second step: curved surfaces
        d, gx, gy, gz = sdf.grid_lookup(vs, origin[s], voxel[s], dims[s], out[0], out[1], out[2])
        gl = np.sqrt(gx * gx + gy * gy + gz * gz)
        if gl == 0.0:
            break
        out[0] -= d * gx / gl
        out[1] -= d * gy / gl
        out[2] -= d * gz / gl
    d, gx, gy, gz = sdf.grid_lookup(vs, origin[s], voxel[s], dims[s], out[0], out[1], out[2])
    gl = np.sqrt(gx * gx + gy * gy + gz * gz)
    if gl == 0.0:
        nrm[0], nrm[1], nrm[2] = 0.0, 0.0, 1.0
    else:
        nrm[0], nrm[1], nrm[2] = gx / gl, gy / gl, gz / gl


@njit(cache=True)
def _nearest(nearest, adr, origin, voxel, dims, s, p):
    i = min(max(int(np.floor((p[0] - origin[s, 0]) / voxel[s] + 0.5)), 0), dims[s, 0] - 1)
    j = min(max(int(np.floor((p[1] - origin[s, 1]) / voxel[s] + 0.5)), 0), dims[s, 1] - 1)
    k = min(max(int(np.floor((p[2] - origin[s, 2]) / voxel[s] + 0.5)), 0), dims[s, 2] - 1)
    return nearest[adr[s, 0] + (i * dims[s, 1] + j) * dims[s, 2] + k]


@njit(cache=True)
def _anchor_from_local(a_local, n_local, s, seg_rest_R, seg_rest_o, point_rest, o_rest, n_rest,
                       nearest, adr, origin, voxel, dims):
    """From a bone-frame surface point and normal of segment s: the anchor vertex (returned) and
    its rest-frame (world at rest) offset and normal."""
    vb = _nearest(nearest, adr, origin, voxel, dims, s, a_local)
    R = seg_rest_R[s]
    for i in range(3):
        a_rest = seg_rest_o[s, i] + R[i, 0] * a_local[0] + R[i, 1] * a_local[1] + R[i, 2] * a_local[2]
        o_rest[i] = a_rest - point_rest[vb, i]
        n_rest[i] = R[i, 0] * n_local[0] + R[i, 1] * n_local[1] + R[i, 2] * n_local[2]
    return vb


@njit(cache=True)
def _walk_to_nearest(vb, xp, p, nbr_ptr, nbr):
    """The skin vertex of vb's segment nearest the point xp[p] on the deformed skin, by a greedy
    walk over the skin mesh from vb (the rest field's choice): the field does not deform with
    its segment, so under strain the vertex nearest at rest can lie millimetres to the side."""
    best = 0.0
    for i in range(3):
        best += (xp[vb, i] - xp[p, i]) ** 2
    moved = True
    while moved:
        moved = False
        for k in range(nbr_ptr[vb], nbr_ptr[vb + 1]):
            u = nbr[k]
            d = 0.0
            for i in range(3):
                d += (xp[u, i] - xp[p, i]) ** 2
            if d < best:
                best, vb, moved = d, u, True
    return vb


@njit(cache=True)
def _store(c, p, seg, vb, o_rest, n_rest, o, n, slip, point_tet, point_bary, point_area, scale,
           c_point, c_seg, c_vb, c_orest, c_nrest, c_ptet, c_pbary, c_atet, c_abary, c_offset,
           c_normal, c_area, c_slip):
    """Row c of the new contact list: point p against segment seg, anchored at skin vertex vb."""
    c_point[c], c_seg[c], c_vb[c] = p, seg, vb
    c_orest[c] = o_rest
    c_nrest[c] = n_rest
    c_ptet[c] = point_tet[p]
    c_pbary[c] = point_bary[p]
    c_atet[c] = point_tet[vb]
    c_abary[c] = point_bary[vb]
    c_offset[c] = o
    c_normal[c] = n
    c_area[c] = scale * point_area[p]  # the pair's stiffness: kn, kf act through w
    c_slip[c] = slip


@njit(cache=True)
def _matvec(A, v, out):
    for i in range(3):
        out[i] = A[i, 0] * v[0] + A[i, 1] * v[1] + A[i, 2] * v[2]


@njit(cache=True)
def _sphere_box_gap2(c, RB, oB, lo, hi, margin):
    """Squared distance [m^2] from the world point c to segment B's box [lo - margin, hi +
    margin] (B's bone frame: world = oB + RB local)."""
    gap2 = 0.0
    for i in range(3):
        ci = RB[0, i] * (c[0] - oB[0]) + RB[1, i] * (c[1] - oB[1]) + RB[2, i] * (c[2] - oB[2])
        if ci < lo[i] - margin:
            gap2 += (lo[i] - margin - ci) ** 2
        elif ci > hi[i] + margin:
            gap2 += (ci - hi[i] - margin) ** 2
    return gap2


@njit(cache=True)
def _new_anchor(p_local, s, grid_values, grid_adr, grid_origin, grid_voxel, grid_dims, grid_nearest,
                seg_rest_R, seg_rest_o, point_rest, point_tet, tet_q, a_local, n_local, o_rest, n_rest,
                Rt, o, n):
    """A new anchor on segment s for the bone-frame point p_local: its closest rest surface point
    (a_local, n_local), the anchor vertex there (returned) with its rest offset and normal (o_rest,
    n_rest), and both turned with the vertex's tet now (Rt, o, n)."""
    _project(grid_values, grid_adr, grid_origin, grid_voxel, grid_dims, s, p_local, a_local, n_local)
    vb = _anchor_from_local(a_local, n_local, s, seg_rest_R, seg_rest_o, point_rest, o_rest,
                            n_rest, grid_nearest, grid_adr, grid_origin, grid_voxel, grid_dims)
    quat_to_matrix_into(tet_q[point_tet[vb]], Rt)
    _matvec(Rt, o_rest, o)
    _matvec(Rt, n_rest, n)
    return vb


@njit(cache=True)
def collide_kernel(node_x, body_x, body_q, body_com_local, v, tets, tet_q,
                   point_tet, point_bary, point_rest, point_area, point_segment, point_exclude,
                   point_normal, nbr_ptr, nbr, seg_points, seg_clusters, cluster_start,
                   seg_body, seg_rest_R, seg_rest_o, seg_lo, seg_hi, pair_ok, pair_scale, grid_values, grid_nearest, grid_adr, grid_origin,
                   grid_voxel, grid_dims, kn, kf, kd, d0, mu, margin, active, xp,
                   prev_count, prev_point, prev_seg, prev_vb, prev_orest, prev_nrest,
                   c_point, c_seg, c_vb, c_orest, c_nrest,
                   c_ptet, c_pbary, c_atet, c_abary, c_offset, c_normal, c_area, c_slip):
    """One detection pass from the previous list (prev_*) into the new one (c_*); returns
    (count, dropped, tested, near): the new list's size, the contacts beyond capacity, the points
    whose field was looked up (in the other segment's box, past the clusters' bounds) and of those
    the ones within margin of the other segment's rest skin (handed to the anchor step)."""
    S = seg_body.shape[0]
    # every skin point embedded (0.08 ms for a hand's ~12,000), then the bounds of each cluster of
    # them and of each segment as a sphere (the box's centre and half diagonal): the broad phase
    # tests those against the other segment's box. From the current points, not the bone's rigid
    # motion: a segment's skin moves against its bone by up to 27 mm in free motion (at the
    # knuckles) and 90 mm in the fist.
    embedded_positions(node_x, tets, point_tet, point_bary, xp)
    K = cluster_start.shape[0] - 1
    cl_c = np.empty((K, 3))
    cl_r = np.empty(K)
    sg_c = np.empty((S, 3))
    sg_r = np.empty(S)
    for s in range(S):
        s0, s1, s2, t0, t1, t2 = np.inf, np.inf, np.inf, -np.inf, -np.inf, -np.inf
        for kc in range(seg_clusters[s], seg_clusters[s + 1]):
            lo0, lo1, lo2, hi0, hi1, hi2 = np.inf, np.inf, np.inf, -np.inf, -np.inf, -np.inf
            for q in range(cluster_start[kc], cluster_start[kc + 1]):
                p = seg_points[q]
                x0, x1, x2 = xp[p, 0], xp[p, 1], xp[p, 2]
                lo0, lo1, lo2 = min(lo0, x0), min(lo1, x1), min(lo2, x2)
                hi0, hi1, hi2 = max(hi0, x0), max(hi1, x1), max(hi2, x2)
            cl_c[kc, 0], cl_c[kc, 1], cl_c[kc, 2] = 0.5 * (lo0 + hi0), 0.5 * (lo1 + hi1), 0.5 * (lo2 + hi2)
            cl_r[kc] = 0.5 * np.sqrt((hi0 - lo0) ** 2 + (hi1 - lo1) ** 2 + (hi2 - lo2) ** 2)
            s0, s1, s2 = min(s0, lo0), min(s1, lo1), min(s2, lo2)
            t0, t1, t2 = max(t0, hi0), max(t1, hi1), max(t2, hi2)
        sg_c[s, 0], sg_c[s, 1], sg_c[s, 2] = 0.5 * (s0 + t0), 0.5 * (s1 + t1), 0.5 * (s2 + t2)
        sg_r[s] = 0.5 * np.sqrt((t0 - s0) ** 2 + (t1 - s1) ** 2 + (t2 - s2) ** 2)
    R = np.empty((S, 3, 3))
    org = np.empty((S, 3))
    for s in range(S):
        b = seg_body[s]
        R[s] = quat_to_matrix(body_q[b])
        org[s] = body_x[b] - R[s] @ body_com_local[b]
    capacity = c_point.shape[0]
    count = 0
    dropped = 0
    tested = 0
    near = 0
    o = np.empty(3)
    n = np.empty(3)
    D = np.empty(3)
    a_local = np.empty(3)
    n_local = np.empty(3)
    local = np.empty(3)
    o_rest = np.empty(3)
    n_rest = np.empty(3)
    t = np.empty(3)
    Rt = np.empty((3, 3))  # the anchor tet's rotation
    # ---- kept contacts: release, Coulomb update
    for k in range(prev_count):
        p, s, vb = prev_point[k], prev_seg[k], prev_vb[k]
        o_rest[:] = prev_orest[k]
        n_rest[:] = prev_nrest[k]
        quat_to_matrix_into(tet_q[point_tet[vb]], Rt)
        _matvec(Rt, o_rest, o)
        _matvec(Rt, n_rest, n)
        for i in range(3):
            D[i] = xp[vb, i] + o[i] - xp[p, i]
        dn = n[0] * D[0] + n[1] * D[1] + n[2] * D[2]
        if dn <= 0.0 or dn > MAX_DEPTH or count >= capacity:
            active[p, s] = 0
            if dn > 0.0 and count >= capacity:
                dropped += 1
            continue
        slip = STICK
        for i in range(3):
            t[i] = D[i] - dn * n[i]
        tl = np.sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2])
        limit = mu * normal_pressure(dn, kn, kd, d0)[0] / kf
        if tl > limit * (1.0 + _CONE_SLACK):
            slip = SLIP
            sc = 1.0 - limit / tl
            for i in range(3):
                o[i] -= sc * t[i]
            # back onto the surface (rest field of s) and a new anchor vertex there
            for i in range(3):
                o_rest[i] = Rt[0, i] * o[0] + Rt[1, i] * o[1] + Rt[2, i] * o[2]
            Rr = seg_rest_R[s]
            for i in range(3):
                a = point_rest[vb, i] + o_rest[i] - seg_rest_o[s, i]
                local[i] = a  # world-at-rest offset from the bone origin
            for i in range(3):
                a_local[i] = Rr[0, i] * local[0] + Rr[1, i] * local[1] + Rr[2, i] * local[2]
            vb = _new_anchor(a_local, s, grid_values, grid_adr, grid_origin, grid_voxel, grid_dims, grid_nearest,
                             seg_rest_R, seg_rest_o, point_rest, point_tet, tet_q, a_local, n_local,
                             o_rest, n_rest, Rt, o, n)
            for i in range(3):
                D[i] = xp[vb, i] + o[i] - xp[p, i]
            dn = n[0] * D[0] + n[1] * D[1] + n[2] * D[2]
            if dn <= 0.0:
                active[p, s] = 0
                continue
            for i in range(3):
                t[i] = D[i] - dn * n[i]
            tl = np.sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2])
            limit = mu * normal_pressure(dn, kn, kd, d0)[0] / kf
            if tl > limit:
                sc = 1.0 - limit / tl
                for i in range(3):
                    o[i] -= sc * t[i]
                    D[i] -= sc * t[i]
            for i in range(3):
                o_rest[i] = Rt[0, i] * o[0] + Rt[1, i] * o[1] + Rt[2, i] * o[2]
            # sliding: the point moves away from its anchor relative to the anchor vertex
            rel = 0.0
            for i in range(3):
                vr = 0.0
                tp, ta = point_tet[p], point_tet[vb]
                for a in range(4):
                    vr += point_bary[p, a] * v[3 * tets[tp, a] + i] - point_bary[vb, a] * v[3 * tets[ta, a] + i]
                rel -= vr * D[i]
            if rel > 0.0:
                slip = SLIDING
        _store(count, p, s, vb, o_rest, n_rest, o, n, slip, point_tet, point_bary, point_area,
               pair_scale[point_segment[p], s],
               c_point, c_seg, c_vb, c_orest, c_nrest, c_ptet, c_pbary, c_atet, c_abary, c_offset,
               c_normal, c_area, c_slip)
        count += 1
    # ---- new contacts: broad phase on the bounds of segments and clusters against the other
    # segment's box, narrow phase on the fields
    for s in range(S):
        for u in range(s + 1, S):
            if pair_ok[s, u] == 0:
                continue
            for side in range(2):
                A = s if side == 0 else u
                B = u if side == 0 else s
                bit = np.uint64(1) << np.uint64(B)
                RB = R[B]
                if _sphere_box_gap2(sg_c[A], RB, org[B], seg_lo[B], seg_hi[B], margin) > sg_r[A] * sg_r[A]:
                    continue
                for kc in range(seg_clusters[A], seg_clusters[A + 1]):
                    if _sphere_box_gap2(cl_c[kc], RB, org[B], seg_lo[B], seg_hi[B], margin) > cl_r[kc] * cl_r[kc]:
                        continue
                    # the field at the cluster's centre: a distance changes by at most r over the
                    # cluster's sphere, and the trilinear grid (exact at its nodes) is within a
                    # voxel of it, so no point of a cluster this far out can come within margin.
                    # Inside B's box (a fist's fingers over the palm) most clusters are: -25 % of
                    # the fist's self-collision time, the same contacts (tests/physics/test_self_contact.py)
                    for i in range(3):
                        local[i] = (RB[0, i] * (cl_c[kc, 0] - org[B, 0]) + RB[1, i] * (cl_c[kc, 1] - org[B, 1])
                                    + RB[2, i] * (cl_c[kc, 2] - org[B, 2]))
                    d = _field(grid_values, grid_adr, grid_origin, grid_voxel, grid_dims, B, local)
                    if d - cl_r[kc] - grid_voxel[B] >= margin:
                        continue
                    for q in range(cluster_start[kc], cluster_start[kc + 1]):
                        p = seg_points[q]
                        if active[p, B] != 0 or (point_exclude[p] & bit) != 0:
                            continue
                        for i in range(3):
                            local[i] = (RB[0, i] * (xp[p, 0] - org[B, 0]) + RB[1, i] * (xp[p, 1] - org[B, 1])
                                        + RB[2, i] * (xp[p, 2] - org[B, 2]))
                        if (local[0] < seg_lo[B, 0] - margin or local[1] < seg_lo[B, 1] - margin
                                or local[2] < seg_lo[B, 2] - margin or local[0] > seg_hi[B, 0] + margin
                                or local[1] > seg_hi[B, 1] + margin or local[2] > seg_hi[B, 2] + margin):
                            continue
                        tested += 1
                        d = _field(grid_values, grid_adr, grid_origin, grid_voxel, grid_dims, B, local)
                        if d >= margin:
                            continue
                        near += 1
                        vb = _new_anchor(local, B, grid_values, grid_adr, grid_origin, grid_voxel, grid_dims,
                                         grid_nearest, seg_rest_R, seg_rest_o, point_rest, point_tet, tet_q,
                                         a_local, n_local, o_rest, n_rest, Rt, o, n)
                        vn = _walk_to_nearest(vb, xp, p, nbr_ptr, nbr)
                        if vn != vb:  # the deformed skin's nearest vertex: anchored there, its normal
                            vb = vn
                            for i in range(3):
                                o_rest[i] = 0.0
                                n_rest[i] = point_normal[vb, i]
                            quat_to_matrix_into(tet_q[point_tet[vb]], Rt)
                            _matvec(Rt, o_rest, o)
                            _matvec(Rt, n_rest, n)
                        # the anchor on the deformed skin's tangent plane at the vertex: the rest
                        # field's surface point can lie millimetres off it along the normal where
                        # the tissue has bulged or sunk against its bone
                        on = o[0] * n[0] + o[1] * n[1] + o[2] * n[2]
                        for i in range(3):
                            o[i] -= on * n[i]
                        dn = 0.0
                        for i in range(3):
                            D[i] = xp[vb, i] + o[i] - xp[p, i]
                            dn += n[i] * D[i]
                        if dn <= 0.0 or dn > MAX_DEPTH:  # outside the deformed skin, or through it
                            continue
                        if count >= capacity:
                            dropped += 1
                            continue
                        # a new anchor sits on the surface along the normal: no friction yet
                        for i in range(3):
                            o[i] -= D[i] - dn * n[i]
                        for i in range(3):
                            o_rest[i] = Rt[0, i] * o[0] + Rt[1, i] * o[1] + Rt[2, i] * o[2]
                        active[p, B] = 1
                        _store(count, p, B, vb, o_rest, n_rest, o, n, STICK, point_tet, point_bary, point_area,
                               pair_scale[A, B],
                               c_point, c_seg, c_vb, c_orest, c_nrest, c_ptet, c_pbary, c_atet, c_abary,
                               c_offset, c_normal, c_area, c_slip)
                        count += 1
    return count, dropped, tested, near


class SelfContactSystem:
    """Self-contact state of one simulation and the calls the solver's step makes (the same
    interface as contact/detection.ContactSystem): collide(...) the stage, add_all(state, model,
    grad, values) the term, output(node_x) the contacts for /hand/contacts."""

    def __init__(self, smodel: SelfContactModel, model, capacity=4096):
        self.model = smodel
        self.tets = model.tets
        self.body_com_local = model.body_com_local
        self.tet_slots = model.tet_slots
        P, S = smodel.point_count, smodel.segment_count
        self.active = np.zeros((P, S), np.uint8)
        self._xp = np.zeros((P, 3))
        C = int(capacity)
        self._lists = [self._new_list(C), self._new_list(C)]
        # the rows of pcg's low-rank term (energies/self_contact.gauss_newton_rows)
        self._rows = (np.zeros((C, 8), np.int32), np.zeros((C, 8)), np.zeros((C, 3, 3)))
        self.count = 0
        self.dropped = 0
        self.tested = 0
        self.near = 0
        self.collision_ms = 0.0

    @staticmethod
    def _new_list(C):
        return dict(point=np.zeros(C, np.int32), seg=np.zeros(C, np.int32), vb=np.zeros(C, np.int32),
                    orest=np.zeros((C, 3)), nrest=np.zeros((C, 3)), ptet=np.zeros(C, np.int32),
                    pbary=np.zeros((C, 4)), atet=np.zeros(C, np.int32), abary=np.zeros((C, 4)),
                    offset=np.zeros((C, 3)), normal=np.zeros((C, 3)), area=np.zeros(C),
                    slip=np.zeros(C, np.uint8))

    @property
    def list(self):
        return self._lists[0]

    def reset(self):
        self.active[:] = 0
        self.count = 0

    def collide(self, node_x, body_x, body_q, v=None, body_dof0=None, tet_q=None):
        """Detect, update anchors (stick/slip), build the active list; returns the count.
        tet_q: the state's tet rotations (the anchors turn with their tet)."""
        m = self.model
        if v is None:
            v = np.zeros(3 * node_x.shape[0])
        t0 = time.perf_counter()
        prev, new = self._lists
        self.count, self.dropped, self.tested, self.near = collide_kernel(
            node_x, body_x, body_q, self.body_com_local, v, self.tets, tet_q,
            m.point_tet, m.point_bary, m.point_rest, m.point_area, m.point_segment, m.point_exclude,
            m.point_normal, m.nbr_ptr, m.nbr, m.seg_points, m.seg_clusters, m.cluster_start,
            m.seg_body, m.seg_rest_R, m.seg_rest_o, m.seg_lo, m.seg_hi, m.pair_ok, m.pair_scale, m.grid_values, m.grid_nearest, m.grid_adr,
            m.grid_origin, m.grid_voxel, m.grid_dims, m.kn, m.kf, m.kd, m.d0, m.mu, m.margin, self.active, self._xp,
            self.count, prev["point"], prev["seg"], prev["vb"], prev["orest"], prev["nrest"],
            new["point"], new["seg"], new["vb"], new["orest"], new["nrest"],
            new["ptet"], new["pbary"], new["atet"], new["abary"], new["offset"], new["normal"],
            new["area"], new["slip"])
        self._lists = [new, prev]
        self.collision_ms = 1e3 * (time.perf_counter() - t0)
        return self.count

    def _args(self):
        L = self.list
        return (self.tets, self.count, L["ptet"], L["pbary"], L["atet"], L["abary"], L["offset"],
                L["normal"], L["area"], self.model.kn, self.model.kf, self.model.kd, self.model.d0)

    def value(self, node_x):
        return energy.value(node_x, *self._args())

    def add_all(self, state, model, grad, values):
        """Gradient of the self contacts at state into grad and the part of their Hessian that
        fits the CSR pattern into values (hessian_rows gives the rest); returns [J]."""
        e = energy.add_gradient(state.node_x, *self._args(), grad)
        energy.add_hessian(state.node_x, *self._args(), self.list["slip"], self.tet_slots, values)
        return e

    def hessian_rows(self, node_x, scale):
        """pcg's low_rank term: the exact Hessian of the active contacts at node_x that add_all
        leaves out of the CSR values (those across two tets), K scaled by `scale` (dt^2: the
        system is M + dt^2 H)."""
        nodes, weights, K = self._rows
        rows = energy.gauss_newton_rows(node_x, *self._args(), self.list["slip"], scale, nodes, weights, K)
        return rows, nodes, weights, K

    def output(self, node_x, cap_friction=True):
        """Per active contact: points (C,3) [m] (the point's side), normals (C,3) (from the
        anchor's skin toward the point's), forces on the point's side (C,3) [N] = force_normal +
        force_friction (the anchor's side feels the opposite), segment (C,) of the point and
        other (C,) the touched segment (index into SelfContactModel segments; seg_body gives the
        bone), slip (C,) u1, point (C,) skin point index, depth (C,) [m] of the point under the
        deformed other skin."""
        c = self.count
        L = self.list
        pts, fn, ff = (np.zeros((c, 3)) for _ in range(3))
        depth = np.zeros(c)
        energy.contact_forces(node_x, *self._args(), pts, fn, ff, depth)
        if cap_friction:
            fn_len = np.linalg.norm(fn, axis=1)
            ff_len = np.linalg.norm(ff, axis=1)
            cap = self.model.mu * fn_len
            ff *= np.where(ff_len > cap, cap / np.maximum(ff_len, 1e-300), 1.0)[:, None]
        return {"points": pts, "normals": L["normal"][:c].copy(), "forces": fn + ff,
                "force_normal": fn, "force_friction": ff,
                "segment": self.model.point_segment[L["point"][:c]].copy(), "other": L["seg"][:c].copy(),
                "slip": (L["slip"][:c] > 0).astype(np.uint8), "point": L["point"][:c].copy(),
                "depth": depth}


def build_self_contact_system(model, asset, segments, kn=None, kf=None, mu=None, capacity=None, **kwargs):
    """The SelfContactSystem of one hand (model built from asset), for
    Solver(model, self_contacts=...). segments: (point_segment (V,), segment_body, adjacent pairs) of
    the hand's skin, e.g. handmodel.rigid_skin.skin_segments(asset). kn, kf default to the model's self_contact_kn / self_contact_kf, mu to
    its self_contact_friction, capacity to self_contact_capacity; kwargs go to
    build_self_contact_model (rest_clearance, voxel, margin; with two hands segment_hand and
    between_hands = self_contact_kn_hands / kn by default).

    Two hands: the same build with both hands' skin points (their tets in the one model),
    triangles (the second hand's offset by the first's point count), segments (the second
    hand's offset by 16, bodies by its first bone) and both skeletons' adjacency."""
    p = model.params
    seg, segb, adjacent = segments
    kn = float(p["self_contact_kn"]) if kn is None else kn
    kf = float(p["self_contact_kf"]) if kf is None else kf
    mu = float(p["self_contact_friction"]) if mu is None else mu
    capacity = int(p["self_contact_capacity"]) if capacity is None else capacity
    kwargs.setdefault("rest_clearance", float(p["self_contact_rest_clearance"]))
    kwargs.setdefault("margin", float(p["self_contact_margin"]))
    kwargs.setdefault("kd", float(p["self_contact_kn_deep"]))
    kwargs.setdefault("d0", float(p["self_contact_deep_from"]))
    layout = getattr(model, "hands", None)
    if layout is not None and layout.count > 1 and "segment_hand" not in kwargs:
        # skin of two hands: their contacts are self_contact_kn_hands stiff
        kwargs["segment_hand"] = np.searchsorted(layout.bone0, np.asarray(segb), side="right") - 1
        kwargs.setdefault("between_hands", float(p["self_contact_kn_hands"]) / kn)
    sm = build_self_contact_model(model, model.skin_tet, model.skin_bary, asset.skin_triangles, seg, segb,
                                  adjacent, kn, kf, mu, **kwargs)
    return SelfContactSystem(sm, model, capacity)
