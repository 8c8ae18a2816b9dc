"""Coarse tissue mesh of the hand (paper Sect. 5.1: ~850 tets) from one structured hex grid.

Every node has an integer index (i, j, k): i runs along the fingers (wrist -> knuckles ->
fingertips), j across the hand (little -> index side, then on along the thumb), k through the
thickness (palmar 0, middle 1, dorsal 2).
- Palm: NI x 7 cells by 2 layers. Row i = 0 is the wrist, row NI is the knuckle row, where node
  columns j = 2f, 2f+1 are the first cross-section ("ring") of finger f.
- Each finger is a tube of 1 x 2 cells continuing the grid along i; its rings are hexagons of
  6 nodes (col 0/1 = j offset, k = 0..2) on the skin, placed at the joints and mid-phalanges.
- The thumb is a 1 x 2-cell tube continuing the grid along j from the palm's radial face at rows
  i = THUMB_ROW, THUMB_ROW + 1; its hexagons twist from the palm's frame to the thumb's.
- Each tube is closed by a tip node: every triangle of the tube's end face makes a tet with it.
Each hex is split into 6 tets by the Kuhn (Freudenthal) rule on the index grid: a tet is the
path c -> c + e_a -> c + e_a + e_b -> c + 1 for each order (a, b, c) of the three axes, so
neighbouring hexes always split shared faces alike and the mesh is conforming. Node positions
come from rays cast from the bone axes / palm mid plane to the level set sdf = offset; the
offset is chosen by bisection to match the tet volume to the skin volume, then boundary nodes
slide on that level set and inner nodes move to raise the worst dihedral angle (greedy, fixed
order). Everything is deterministic: no randomness, fixed iteration counts and orders.
"""
import numpy as np

from itertools import permutations

from softhand_sim.handmodel.skeleton import FINGER_BONES, bone_chain_points
from softhand_sim.handmodel.tets import tet_volumes

FINGER_ORDER = ("little", "ring", "middle", "index")  # finger f owns palm node columns 2f, 2f+1
PALM_ROWS = 6  # NI: cells along the palm from the wrist to the knuckle row
THUMB_START = 0.5  # first thumb ring: this fraction along the metacarpal
THUMB_TURN_RINGS = 2  # rings over which the thumb's ring planes turn to normal
THUMB_FACE_REACH = (2.0, 1.9, 1.6)  # [palm_r] rays (palmar, mid, dorsal) of the palm face the thumb leaves
RIM_REACH = 4.0  # [palm_r] other palm rim rays
THUMB_ROW = 2  # the thumb leaves the palm's radial face between rows THUMB_ROW and THUMB_ROW + 1
# hexagon node (col, k) -> angle from the ring's +y axis toward its +z (dorsal) axis [deg]
RING_ANGLES = {(1, 1): 0.0, (1, 2): 60.0, (0, 2): 120.0, (0, 1): 180.0, (0, 0): 240.0, (1, 0): 300.0}
RING_SPACING = 0.0145  # [m] between finger rings, for the default 9 cm palm (scales with it)
RING_REACH = 1.5  # rays of a finger ring stop at this many finger radii
KNUCKLE_SIDE = 0.75  # [finger radius] side nodes of the knuckle ring, leaving room for the web
RIM_HEIGHT = 0.55  # rim nodes of the palm: height of their rays over the mid plane / palm_r
RIM_TILT = 0.3  # and the rays' slope
OFFSET_RANGE = (-0.002, 0.004)  # [m] search interval of the level-set offset
OFFSET_BISECTIONS = 12
SMOOTH_PASSES = 8
SMOOTH_TARGET = np.radians(25.0)  # nodes whose worst tet is better are left alone
SMOOTH_REACH = 0.003  # [m] farthest a node may move from where it was cast
SMOOTH_STEPS = (0.002, 0.001, 0.0005)  # [m] trial moves of the quality pass
RAY_STEPS = 120  # marching samples per ray before bisection
RAY_BISECTIONS = 30


class RayCaster:
    """First crossing of sdf = offset along rays from inside points (vectorised march + bisection)."""

    def __init__(self, shape, offset):
        self.shape, self.offset = shape, offset

    def __call__(self, origins, directions, reach):
        o = np.atleast_2d(origins).astype(float)
        d = np.atleast_2d(directions).astype(float)
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
        reach = np.broadcast_to(np.asarray(reach, float), (len(o),))
        t = np.linspace(0.0, 1.0, RAY_STEPS + 1)[None, :] * reach[:, None]
        pts = o[:, None, :] + t[..., None] * d[:, None, :]
        f = self.shape.sdf(pts.reshape(-1, 3), self.offset).reshape(len(o), -1)
        outside = f > 0
        first = np.where(outside.any(axis=1), outside.argmax(axis=1), RAY_STEPS)  # capped at reach
        hit = outside.any(axis=1) & (first > 0)
        a = t[np.arange(len(o)), np.maximum(first - 1, 0)]
        b = t[np.arange(len(o)), first]
        for _ in range(RAY_BISECTIONS):
            m = 0.5 * (a + b)
            inside = self.shape.sdf(o + m[:, None] * d, self.offset) < 0
            a, b = np.where(inside, m, a), np.where(inside, b, m)
        s = np.where(hit, a, reach)
        return o + s[:, None] * d


def _ring(cast, centre, ex, ez, reach, squeeze=1.0):
    """Six hexagon nodes {(col, k): position} around `centre` in the plane normal to ex.

    ez is made normal to ex; ey = ez x ex. squeeze < 1 narrows the two side nodes (k = 1).
    """
    ex = ex / np.linalg.norm(ex)
    ez = ez - (ez @ ex) * ex
    ez /= np.linalg.norm(ez)
    ey = np.cross(ez, ex)
    keys = list(RING_ANGLES)
    dirs = np.array([np.cos(np.radians(RING_ANGLES[q])) * ey + np.sin(np.radians(RING_ANGLES[q])) * ez
                     for q in keys])
    p = cast(np.repeat(centre[None], 6, 0), dirs, reach)
    out = dict(zip(keys, p))
    if squeeze != 1.0:
        for q in ((0, 1), (1, 1)):
            out[q] = centre + squeeze * (out[q] - centre)
    return out


def _knuckle_ring(cast, joint, frame, r, outer=None):
    """First ring of a finger at its MCP joint: the palm continues sideways there, so the side
    nodes sit KNUCKLE_SIDE * r from the axis and the others straight above/below them."""
    ey, ez = frame[:, 1], frame[:, 2]
    out = {}
    for col in (0, 1):
        sgn = 2 * col - 1
        if outer == col:  # the palm's rim: the ring reaches the skin like the others
            out[(col, 1)] = cast(joint, sgn * ey, RING_REACH * r)[0]
        else:
            out[(col, 1)] = joint + sgn * KNUCKLE_SIDE * r * ey
        for k in (0, 2):
            out[(col, k)] = cast(joint + sgn * 0.5 * r * ey, (k - 1) * ez, 4 * r)[0]
    return out


def _stations(a, b, spacing, stop_short=0.0):
    """Points strictly after a up to b (minus stop_short) at about `spacing` apart."""
    length = np.linalg.norm(b - a)
    n = max(1, int(round((length - stop_short) / spacing)))
    end = (length - stop_short) / length
    return [a + (end * q / n) * (b - a) for q in range(1, n + 1)]


def hand_grid(shape, m, offset, spacing):
    """Node positions {(i, j, k): xyz}, hex cells [(i, j, k) corner] and tip caps.

    spacing: target distance between finger rings [m]. Returns (pos, cells, caps) where caps is
    a list of (tip key, end-face corner key, free axes (two of 0, 1, 2)).
    """
    cast = RayCaster(shape, offset)
    prox, dist, rot = bone_chain_points(m)
    pos, cells, caps = {}, [], []
    ni = PALM_ROWS
    for f_i, f in enumerate(FINGER_ORDER):
        bones = FINGER_BONES[f]
        r = 0.5 * m.finger_width(f)
        reach = RING_REACH * r
        for (col, k), p in _knuckle_ring(cast, prox[bones[0]], rot[bones[0]], r, {0: 0, 3: 1}.get(f_i)).items():
            pos[(ni, 2 * f_i + col, k)] = p
        i = ni
        r_tip = 0.76 * r
        for s, b in enumerate(bones):
            stop = 1.2 * r_tip if s == 2 else 0.0
            for c in _stations(prox[b], dist[b], spacing, stop):
                i += 1
                for (col, k), p in _ring(cast, c, rot[b][:, 0], rot[b][:, 2], reach).items():
                    pos[(i, 2 * f_i + col, k)] = p
                cells += [(i - 1, 2 * f_i, 0), (i - 1, 2 * f_i, 1)]
        tip_dir = rot[bones[2]][:, 0]
        pos[(i + 1, 2 * f_i, 1)] = cast(pos[(i, 2 * f_i, 1)] * 0 + 0.5 * (pos[(i, 2 * f_i, 1)] + pos[(i, 2 * f_i + 1, 1)]),
                                        tip_dir, 3 * r)[0]
        caps.append(((i + 1, 2 * f_i, 1), (i, 2 * f_i, 0), (1, 2)))
    # palm rows: blend from the wrist line to the knuckle row, nodes on the skin above/below
    pr, pz = shape.palm_r, shape.palm_z
    xw = shape.poly[:, 0].min()
    yw = np.linspace(shape.poly[0, 1], shape.poly[-1, 1], 8)  # the polygon's two wrist corners
    centre = {}
    for j in range(8):
        kn = pos[(ni, j, 1)]
        for i in range(ni):
            t = i / ni
            centre[(i, j)] = np.array([xw + t * (kn[0] - xw), yw[j] + t * (kn[1] - yw[j]), pz])
    for (i, j), c in sorted(centre.items()):
        side = np.array([-1.0 if i == 0 else 0.0, -1.0 if j == 0 else (1.0 if j == 7 else 0.0), 0.0])
        # rim nodes are cast from the next inner column / row, which lies inside the palm
        inner = centre[(i + (i == 0), j + (j == 0) - (j == 7))]
        origin = np.where(side != 0, inner, c)
        for k in range(3):
            if not side.any():  # inside the palm: straight down / up to the skin
                pos[(i, j, k)] = c if k == 1 else cast(c, np.array([0.0, 0.0, k - 1.0]), 4 * pr)[0]
            else:  # rim: horizontal rays at three heights, so the side face stands upright
                lift = np.array([0.0, 0.0, (k - 1) * RIM_HEIGHT * pr])
                tilt = np.array([0.0, 0.0, (k - 1) * RIM_TILT])
                # where the thumb leaves the palm the thenar would pull the face far out
                reach = (THUMB_FACE_REACH[k] if j == 7 and i in (THUMB_ROW, THUMB_ROW + 1) else RIM_REACH) * pr
                pos[(i, j, k)] = cast(origin + lift, side + tilt, reach)[0]
    cells += [(i, j, k) for i in range(ni) for j in range(7) for k in range(2)]
    # thumb: tube along +j from the radial face, rows THUMB_ROW, THUMB_ROW + 1. The face's normal
    # is ~48 deg off the thumb axis, so the first rings' planes turn gradually from the face's
    # orientation to normal to the thumb (and from the palm's up to the thumb's pronated up).
    a = THUMB_ROW
    tb = FINGER_BONES["thumb"]
    r = 0.5 * m.thumb_width
    base = [pos[(a + c, 7, k)] for c in (0, 1) for k in (0, 1, 2)]
    n_face = np.cross(base[2] + base[5] - base[0] - base[3], base[5] + base[3] - base[2] - base[0])
    n_face /= np.linalg.norm(n_face)
    z_up = np.array([0.0, 0.0, 1.0])
    st = [(c, tb[0]) for c in _stations(prox[tb[0]], dist[tb[0]], spacing)
          if (c - prox[tb[0]]) @ rot[tb[0]][:, 0] > THUMB_START * np.linalg.norm(dist[tb[0]] - prox[tb[0]])]
    st += [(c, tb[1]) for c in _stations(prox[tb[1]], dist[tb[1]], spacing)]
    st += [(c, tb[2]) for c in _stations(prox[tb[2]], dist[tb[2]], spacing, 1.2 * 0.86 * r)]
    j = 7
    for n, (c, b) in enumerate(st):
        w = min(1.0, (n + 1) / (THUMB_TURN_RINGS + 1.0))
        ex = (1 - w) * n_face + w * rot[b][:, 0]
        ez = (1 - w) * z_up + w * rot[b][:, 2]
        j += 1
        for (col, k), p in _ring(cast, c, ex, ez, RING_REACH * r).items():
            pos[(a + 1 - col, j, k)] = p
        cells += [(a, j - 1, 0), (a, j - 1, 1)]
    pos[(a, j + 1, 1)] = cast(0.5 * (pos[(a, j, 1)] + pos[(a + 1, j, 1)]), rot[tb[2]][:, 0], 3 * r)[0]
    caps.append(((a, j + 1, 1), (a, j, 0), (0, 2)))
    return pos, cells, caps


_KUHN = []
for _p in permutations(range(3)):
    _path = [np.zeros(3, int)]
    for _ax in _p:
        _path.append(_path[-1] + np.eye(3, dtype=int)[_ax])
    _odd = sum(1 for x in range(3) for y in range(x + 1, 3) if _p[x] > _p[y]) % 2
    _order = [0, 2, 1, 3] if _odd else [0, 1, 2, 3]
    _KUHN.append(np.array([_path[q] for q in _order]))


def grid_tets(pos, cells, caps):
    """Nodes (N,3) in sorted key order, tets (T,4) (Kuhn split, positive in index space), keys."""
    keys = sorted(pos)
    kid = {q: n for n, q in enumerate(keys)}
    nodes = np.array([pos[q] for q in keys])
    tets = []
    for c in sorted(cells):
        c = np.array(c)
        for pattern in _KUHN:
            tets.append([kid[tuple(c + d)] for d in pattern])
    for tip, corner, (u, w) in caps:
        c = np.array(corner)
        for k0 in range(2):  # the two quads of the end face, split like the Kuhn rule does
            base = c + k0 * np.eye(3, dtype=int)[w]
            eu, ew = np.eye(3, dtype=int)[u], np.eye(3, dtype=int)[w]
            for tri in ((base, base + eu, base + eu + ew), (base, base + ew, base + eu + ew)):
                t = [kid[tuple(x)] for x in tri] + [kid[tip]]
                if tet_volumes(nodes, np.array([t]))[0] < 0:
                    t[1], t[2] = t[2], t[1]
                tets.append(t)
    return nodes, np.array(tets, dtype=np.int64), keys


def _quality(p):
    """Smallest dihedral angle [rad] of tets with corner points p (..., 4, 3); an inverted or
    flat tet scores -1 - its smallest angle (below every valid tet)."""
    faces = ((1, 2, 3), (0, 3, 2), (0, 1, 3), (0, 2, 1))
    n = np.stack([np.cross(p[..., b, :] - p[..., a, :], p[..., c, :] - p[..., a, :]) for a, b, c in faces], -2)
    n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-30)
    cos = np.stack([-(n[..., i, :] * n[..., j, :]).sum(-1)
                    for i, j in ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))], -1)
    q = np.arccos(np.clip(cos, -1.0, 1.0)).min(-1)
    e1, e2, e3 = (p[..., k, :] - p[..., 0, :] for k in (1, 2, 3))
    vol = (e1 * np.cross(e2, e3)).sum(-1)
    return np.where(vol > 0, q, -1.0 - q)


def improve_quality(nodes, tets, shape, offset, on_skin, passes=SMOOTH_PASSES):
    """Greedy node relocation raising the worst dihedral angle around each node.

    Nodes are visited worst-first (stable order); each tries the moves +-step along x, y, z
    for the steps in SMOOTH_STEPS, skin nodes then return to the level set sdf = offset along
    the gradient. A move is kept only if the smallest dihedral of the node's tets grows and the
    node stays within SMOOTH_REACH of its start (so the skin stays covered).
    """
    start = nodes.copy()
    nodes = nodes.copy()
    incident = [[] for _ in range(len(nodes))]
    for t, tet in enumerate(tets):
        for v in tet:
            incident[v].append(t)
    incident = [np.array(x) for x in incident]
    moves = np.vstack([s * d for s in SMOOTH_STEPS for d in np.vstack([np.eye(3), -np.eye(3)])])
    for _ in range(passes):
        q = _quality(nodes[tets])
        node_q = np.array([q[inc].min() for inc in incident])
        order = np.argsort(node_q, kind="stable")
        changed = False
        for v in order[node_q[order] < SMOOTH_TARGET]:
            inc = tets[incident[v]]
            cand = nodes[v] + moves
            if on_skin[v]:
                for _ in range(2):
                    g = shape.gradient(cand, offset)
                    cand = cand - (shape.sdf(cand, offset) / np.maximum((g * g).sum(1), 1e-12))[:, None] * g
            cand = cand[np.linalg.norm(cand - start[v], axis=1) <= SMOOTH_REACH]
            if not len(cand):
                continue
            p = np.broadcast_to(nodes[inc], (len(cand),) + inc.shape + (3,)).copy()
            mask = inc == v
            p[:, mask] = cand[:, None, :]
            qc = _quality(p).min(axis=1)
            best = int(np.argmax(qc))
            if qc[best] > _quality(nodes[inc]).min() + 1e-9:
                nodes[v] = cand[best]
                changed = True
        if not changed:
            break
    return nodes


def coarse_tissue(shape, measures, skin_volume):
    """The coarse tissue mesh: (nodes (N,3), tets (T,4) int64 positive, figures dict).

    The level-set offset the rays stop at is bisected (OFFSET_RANGE, OFFSET_BISECTIONS) so that
    the grid's tet volume matches skin_volume; the quality pass then runs once on that grid.
    """
    spacing = RING_SPACING * measures.palm_length / 0.09
    a, b = OFFSET_RANGE
    best = None
    for _ in range(OFFSET_BISECTIONS):
        off = 0.5 * (a + b)
        nodes, tets, _ = grid_tets(*hand_grid(shape, measures, off, spacing))
        err = tet_volumes(nodes, tets).sum() / skin_volume - 1.0
        if best is None or abs(err) < abs(best[1]):
            best = (off, err)
        a, b = (a, off) if err > 0 else (off, b)
    off = best[0]
    nodes, tets, _ = grid_tets(*hand_grid(shape, measures, off, spacing))
    on_skin = np.abs(shape.sdf(nodes, off)) < 1e-6
    nodes = improve_quality(nodes, tets, shape, off, on_skin)
    vol = tet_volumes(nodes, tets)
    if (vol <= 0).any():
        raise RuntimeError(f"coarse hex grid has {int((vol <= 0).sum())} inverted tets")
    figures = dict(spacing=float(spacing), offset=float(off), volume_error=float(vol.sum() / skin_volume - 1.0))
    return nodes, tets, figures
