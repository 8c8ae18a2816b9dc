"""Implicit shape of the hand: a signed distance-like function, negative inside [m].

One shape feeds both the skin (marching cubes) and the tissue mesh (isosurface stuffing), so
the two agree. It is a smooth union (polynomial smooth-min) of
- the palm: a planar polygon (wrist, hypothenar, knuckle row, thenar side) thickened by a
  sphere of radius palm_thickness / 2 (flat palm with fully rounded rims);
- the thenar pad: a round cone from the wrist's radial side to the thumb's MCP;
- each finger: round cones (capsules with linearly varying radius) between its joints and
  mid-shafts; the joints are a little wider than the shafts, which shapes the knuckles;
  the last cone ends in a sphere that touches the fingertip point.
Fingers blend with the palm but not with each other (each finger is unioned with the palm).
"""
import numpy as np
from numba import njit

from softhand_sim.handmodel.skeleton import FINGER_BONES, bone_chain_points, palm_centre_z

# Radius profile along a finger, as a fraction of half its width, at:
# proximal joint, proximal mid, middle joint, intermediate mid, distal joint, distal mid, tip
FINGER_PROFILE = (1.00, 0.90, 0.93, 0.84, 0.86, 0.80, 0.76)
THUMB_PROFILE = (1.25, 1.05, 1.00, 0.93, 0.95, 0.90, 0.86)
BLEND_IN_FINGER = 0.002  # smooth-min width inside a finger [m]
BLEND_FINGER_PALM = 0.007  # web between a finger and the palm [m]
BLEND_THENAR = 0.012  # thenar pad into the palm [m]


@njit(cache=True)
def _smin(a, b, k):
    """Polynomial smooth minimum (C1), blending over |a - b| < k."""
    if k <= 0.0:
        return min(a, b)
    h = max(k - abs(a - b), 0.0) / k
    return min(a, b) - h * h * k * 0.25


@njit(cache=True)
def _round_cone(px, py, pz, c):
    """Distance to a round cone c = (ax, ay, az, bx, by, bz, ra, rb) (exact, after I. Quilez)."""
    bax, bay, baz = c[3] - c[0], c[4] - c[1], c[5] - c[2]
    l2 = bax * bax + bay * bay + baz * baz
    rr = c[6] - c[7]
    a2 = l2 - rr * rr
    il2 = 1.0 / l2
    pax, pay, paz = px - c[0], py - c[1], pz - c[2]
    y = pax * bax + pay * bay + paz * baz
    z = y - l2
    qx = pax * l2 - bax * y
    qy = pay * l2 - bay * y
    qz = paz * l2 - baz * y
    x2 = qx * qx + qy * qy + qz * qz
    y2 = y * y * l2
    z2 = z * z * l2
    k = np.sign(rr) * rr * rr * x2
    if np.sign(z) * a2 * z2 > k:
        return np.sqrt(x2 + z2) * il2 - c[7]
    if np.sign(y) * a2 * y2 < k:
        return np.sqrt(x2 + y2) * il2 - c[6]
    return (np.sqrt(x2 * a2 * il2) + y * rr) * il2 - c[6]


@njit(cache=True)
def _polygon2d(px, py, poly):
    """Signed distance to a simple closed polygon (n,2) in the plane, negative inside."""
    n = poly.shape[0]
    d = (px - poly[0, 0]) ** 2 + (py - poly[0, 1]) ** 2
    s = 1.0
    j = n - 1
    for i in range(n):
        ex, ey = poly[j, 0] - poly[i, 0], poly[j, 1] - poly[i, 1]
        wx, wy = px - poly[i, 0], py - poly[i, 1]
        t = min(max((wx * ex + wy * ey) / (ex * ex + ey * ey), 0.0), 1.0)
        bx, by = wx - ex * t, wy - ey * t
        d = min(d, bx * bx + by * by)
        c1 = py >= poly[i, 1]
        c2 = py < poly[j, 1]
        c3 = ex * wy > ey * wx
        if (c1 and c2 and c3) or ((not c1) and (not c2) and (not c3)):
            s = -s
        j = i
    return s * np.sqrt(d)


@njit(cache=True)
def _hand_sdf(points, offset, poly, palm_z, palm_r, thenar, cones, cone_finger, n_fingers,
              k_in, k_palm, k_thenar, out):
    for i in range(points.shape[0]):
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        d2 = _polygon2d(px, py, poly)
        dz = pz - palm_z
        if d2 > 0.0:
            palm = np.sqrt(d2 * d2 + dz * dz) - palm_r
        else:
            palm = abs(dz) - palm_r
        d = _smin(palm, _round_cone(px, py, pz, thenar), k_thenar)
        for f in range(n_fingers):
            fd = 1e9
            for c in range(cones.shape[0]):
                if cone_finger[c] == f:
                    fd = _smin(fd, _round_cone(px, py, pz, cones[c]), k_in)
            d = _smin(d, fd, k_palm)
        out[i] = d - offset


class HandShape:
    """The implicit hand of one set of measures (right hand); call sdf(points) [m]."""

    def __init__(self, measures):
        m = measures
        prox, dist, rot = bone_chain_points(m)
        cones, owner = [], []
        for fi, (f, bones) in enumerate(FINGER_BONES.items()):
            prof = THUMB_PROFILE if f == "thumb" else FINGER_PROFILE
            half = 0.5 * m.finger_width(f)
            pts, rad = [], []
            for k, b in enumerate(bones):
                pts += [prox[b], 0.5 * (prox[b] + dist[b])]
                rad += [prof[2 * k] * half, prof[2 * k + 1] * half]
            r_tip = prof[6] * half
            axis = (dist[bones[2]] - prox[bones[2]]) / np.linalg.norm(dist[bones[2]] - prox[bones[2]])
            pts.append(dist[bones[2]] - r_tip * axis)
            rad.append(r_tip)
            for k in range(len(pts) - 1):
                cones.append(np.concatenate([pts[k], pts[k + 1], [rad[k], rad[k + 1]]]))
                owner.append(fi)
        self.cones = np.array(cones)
        self.cone_finger = np.array(owner, dtype=np.int64)
        self.palm_z = palm_centre_z(m)
        self.palm_r = 0.5 * m.palm_thickness
        self.poly = _palm_polygon(m, prox, self.palm_r)
        # thenar pad: from the radial wrist to the thumb MCP, below the palm's mid plane
        t_mcp = prox[2]
        start = np.array([0.12 * m.palm_length, 0.25 * m.palm_width * 0.5, self.palm_z - 0.2 * self.palm_r])
        self.thenar = np.concatenate([start, t_mcp, [0.95 * self.palm_r, 0.5 * m.thumb_width]])
        self.bounds = (np.min(np.vstack([self.cones[:, :3], self.cones[:, 3:6], [[0, 0, 0]]]), 0) - 0.03,
                       np.max(np.vstack([self.cones[:, :3], self.cones[:, 3:6]]), 0) + 0.03)

    def sdf(self, points, offset=0.0):
        """Signed distance-like value at points (n,3) [m], negative inside; minus `offset`."""
        pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        out = np.empty(pts.shape[0])
        _hand_sdf(pts, float(offset), self.poly, self.palm_z, self.palm_r, self.thenar, self.cones,
                  self.cone_finger, 5, BLEND_IN_FINGER, BLEND_FINGER_PALM, BLEND_THENAR, out)
        return out

    def gradient(self, points, offset=0.0, h=1e-5):
        """Central-difference gradient of sdf at points (n,3)."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        g = np.empty_like(pts)
        for k in range(3):
            e = np.zeros(3)
            e[k] = h
            g[:, k] = (self.sdf(pts + e, offset) - self.sdf(pts - e, offset)) / (2 * h)
        return g


def _palm_polygon(m, prox, r):
    """Palm outline (counter-clockwise seen from +z), inset by the rim radius r."""
    idx, mid, rng, lit = prox[4], prox[7], prox[10], prox[13]
    y_rad = idx[1] + 0.5 * m.index_width - r  # radial (thumb) rim
    y_uln = lit[1] - 0.5 * m.little_width + r  # ulnar rim
    x0 = 0.55 * r
    back = 0.25 * r  # the knuckle row sits a little behind the MCP joint centres
    pts = [
        (x0, y_uln + 0.10 * m.palm_width),
        (0.45 * m.palm_length, y_uln - 0.02 * m.palm_width),
        (lit[0] - 0.6 * r, y_uln),
        (lit[0] - back, lit[1]),
        (rng[0] - back, rng[1]),
        (mid[0] - back, mid[1]),
        (idx[0] - back, idx[1]),
        (idx[0] - 0.6 * r, y_rad),
        (0.35 * m.palm_length, y_rad),
        (x0, y_rad - 0.12 * m.palm_width),
    ]
    return np.array(pts, dtype=np.float64)
