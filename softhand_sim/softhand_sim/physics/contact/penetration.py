"""How deep the skin of one segment lies inside another's, measured on the deformed skin without
the contact list: the independent check of skin-skin contact (issue #21's "no skin vertex more
than 1.5 mm inside another segment").

Each segment's skin (its triangles, physics/contact/self_contact.py's segments) is closed at its
cut boundary by a fan to the boundary loop's centre, on the current positions, so it is a closed
surface whatever the tissue did. A skin point of another segment is inside it where the
generalized winding number (the sum of the triangles' solid angles over 4 pi; Jacobson et al.
2013, "Robust inside-outside segmentation using generalized winding numbers") exceeds 1/2, and
its depth is its distance to that segment's skin triangles (the fan caps are no skin). The pairs
the contact model rules out are left out here too: two segments joined in the skeleton
(`pair_ok`) and a point within the rest clearance of the segment (`point_exclude`: the skin of a
crease). Points are tested against a segment only inside its current bounding box.

    surfaces = SegmentSurfaces(smodel, triangles)      # once: topology of each closed segment
    depth, point, segment, inside = surfaces.deepest(skin_x)   # skin_x (P,3) current skin points
    points, depths, nearest = surfaces.inside(skin_x)          # every point inside, with its depth
"""
from __future__ import annotations

import numpy as np
from numba import njit

from softhand_sim.physics.contact.self_contact import _close_segment

_FOUR_PI = 4.0 * np.pi


@njit(cache=True)
def _solid_angle(p, a, b, c):
    """Signed solid angle of triangle (a, b, c) seen from p (Van Oosterom and Strackee 1983)."""
    a0, a1, a2 = a[0] - p[0], a[1] - p[1], a[2] - p[2]
    b0, b1, b2 = b[0] - p[0], b[1] - p[1], b[2] - p[2]
    c0, c1, c2 = c[0] - p[0], c[1] - p[1], c[2] - p[2]
    la = np.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    lb = np.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
    lc = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
    det = a0 * (b1 * c2 - b2 * c1) - a1 * (b0 * c2 - b2 * c0) + a2 * (b0 * c1 - b1 * c0)
    den = la * lb * lc + (a0 * b0 + a1 * b1 + a2 * b2) * lc + (b0 * c0 + b1 * c1 + b2 * c2) * la \
        + (c0 * a0 + c1 * a1 + c2 * a2) * lb
    return 2.0 * np.arctan2(det, den)


@njit(cache=True)
def _point_triangle_distance2(p, a, b, c):
    """Squared distance from p to triangle (a, b, c) (Ericson, Real-Time Collision Detection 5.1.5)."""
    ab = b - a
    ac = c - a
    ap = p - a
    d1, d2 = ab @ ap, ac @ ap
    if d1 <= 0.0 and d2 <= 0.0:
        q = a
    else:
        bp = p - b
        d3, d4 = ab @ bp, ac @ bp
        if d3 >= 0.0 and d4 <= d3:
            q = b
        else:
            vc = d1 * d4 - d3 * d2
            if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
                q = a + d1 / (d1 - d3) * ab
            else:
                cp = p - c
                d5, d6 = ab @ cp, ac @ cp
                if d6 >= 0.0 and d5 <= d6:
                    q = c
                else:
                    vb = d5 * d2 - d1 * d6
                    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
                        q = a + d2 / (d2 - d6) * ac
                    else:
                        va = d3 * d6 - d5 * d4
                        if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
                            q = b + (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (c - b)
                        else:
                            den = 1.0 / (va + vb + vc)
                            q = a + ab * (vb * den) + ac * (vc * den)
    d = p - q
    return d @ d


@njit(cache=True)
def _inside(x, candidates, verts, tris, out):
    """out[i] = True where the point x[candidates[i]] lies inside the closed surface (verts, tris):
    generalized winding number above 1/2."""
    for i in range(candidates.shape[0]):
        p = x[candidates[i]]
        w = 0.0
        for t in range(tris.shape[0]):
            w += _solid_angle(p, verts[tris[t, 0]], verts[tris[t, 1]], verts[tris[t, 2]])
        out[i] = w > 0.5 * _FOUR_PI


@njit(cache=True)
def _distance2(p, verts, tris, count, best2):
    """min(best2, squared distance [m^2] from p to the first `count` triangles of (verts, tris))."""
    for t in range(count):
        d2 = _point_triangle_distance2(p, verts[tris[t, 0]], verts[tris[t, 1]], verts[tris[t, 2]])
        if d2 < best2:
            best2 = d2
    return best2


class SegmentSurfaces:
    """The closed skin surface of each segment of a SelfContactModel (topology at rest, positions
    from the current skin points)."""

    def __init__(self, smodel, triangles):
        self.smodel = smodel
        tri = np.asarray(triangles, np.int64)
        seg_of = smodel.point_segment
        tri_seg = seg_of[tri]
        self.segments = []
        for s in range(smodel.segment_count):
            own = np.flatnonzero(seg_of == s)
            if len(own) == 0:
                self.segments.append(None)
                continue
            remap = np.full(len(seg_of), -1, np.int64)
            remap[own] = np.arange(len(own))
            skin = remap[tri[(tri_seg == s).all(axis=1)]]
            _, closed = _close_segment(smodel.point_rest[own], skin)
            # the fan caps: each cap vertex (index >= len(own)) is the centre of its loop
            cap_tris = closed[len(skin):]
            loops = [np.unique(cap_tris[cap_tris[:, 2] == c][:, :2]) for c in np.unique(cap_tris[:, 2])]
            self.segments.append((own, np.ascontiguousarray(closed), loops, len(skin)))

    def deepest(self, x):
        """(depth [m], point, segment, inside count) of the deepest skin point inside another
        segment it may touch, for the current skin points x (P,3); depth 0.0 and point -1 when
        none is inside (`inside` gives every such point)."""
        points, depths, nearest = self.inside(x)
        k = int(np.argmax(depths)) if len(points) else -1
        if k < 0 or not depths[k] > 0.0:
            return 0.0, -1, -1, len(points)
        return float(depths[k]), int(points[k]), int(nearest[k]), len(points)

    def inside(self, x):
        """Every skin point inside another segment it may touch, for the current skin points x
        (P,3): (points (K,), depth (K,) [m], nearest segment (K,)). The depth of an inside point is
        its distance to the nearest skin of any segment it may touch (not only the one it is
        inside: the fan caps of two neighbouring segments of the other hand may overlap, while the
        skin they close is one surface)."""
        m = self.smodel
        x = np.ascontiguousarray(x, dtype=np.float64)
        surfaces = []  # per segment: (vertices now, closed triangles, skin triangle count, lo, hi)
        for seg in self.segments:
            if seg is None:
                surfaces.append(None)
                continue
            own, closed, loops, n_skin = seg
            verts = np.empty((len(own) + len(loops), 3))
            verts[:len(own)] = x[own]
            for k, loop in enumerate(loops):
                verts[len(own) + k] = verts[loop].mean(axis=0)
            surfaces.append((verts, closed, n_skin, verts.min(axis=0), verts.max(axis=0)))
        allowed = (m.pair_ok[m.point_segment] == 1) & (  # (P, S): point p may touch segment s
            (m.point_exclude[:, None] >> np.arange(m.segment_count, dtype=np.uint64)[None, :]) & np.uint64(1) == 0)
        inside = np.zeros(len(x), bool)
        for s, surf in enumerate(surfaces):
            if surf is None:
                continue
            verts, closed, _, lo, hi = surf
            cand = np.flatnonzero(allowed[:, s] & ~inside & np.all((x >= lo) & (x <= hi), axis=1)).astype(np.int64)
            if len(cand):
                hit = np.empty(len(cand), np.bool_)
                _inside(x, cand, verts, closed, hit)
                inside[cand[hit]] = True
        points = np.flatnonzero(inside)
        depths, nearest = np.zeros(len(points)), np.full(len(points), -1, np.int64)
        for i, p in enumerate(points):
            # the nearest allowed skin, segments in order of their boxes' distance
            gaps = [(float(np.linalg.norm(np.maximum(0.0, np.maximum(surf[3] - x[p], x[p] - surf[4])))), s)
                    for s, surf in enumerate(surfaces) if surf is not None and allowed[p, s]]
            d2, near = np.inf, -1
            for gap, s in sorted(gaps):
                if gap * gap >= d2:
                    break
                verts, closed, n_skin, _, _ = surfaces[s]
                e2 = _distance2(x[p], verts, closed, n_skin, d2)
                if e2 < d2:
                    d2, near = e2, s
            depths[i], nearest[i] = np.sqrt(d2), near
        return points, depths, nearest
