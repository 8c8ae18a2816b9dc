"""A voxel "box hand" with the HandAsset fields, for benchmarks and tests that must not wait for
(or depend on) the parametric hand builder: palm + 4 fingers + thumb of boxes, 16 bones in the
docs/INTERFACE.md order, Kuhn-split voxels (conforming tets), capsule samples per Sect. 3.4.

Right hand, palm down (dorsal +z), fingers along +x, thumb toward +y, wrist at the origin.
`box_hand(cell)` with cell [m] the voxel size; `box_hand_with_tets(target)` picks the cell that
gives about `target` tets (850 ~ the paper's 856; 8500 for the fine benchmark).
"""
from types import SimpleNamespace

import numpy as np

from softhand_sim.physics.rotations import quat_from_axes

_KUHN = [(0, 1, 3, 7), (0, 3, 2, 7), (0, 2, 6, 7), (0, 6, 4, 7), (0, 4, 5, 7), (0, 5, 1, 7)]
PALM = (0.0, 0.09, -0.04, 0.04, -0.0125, 0.0125)  # x0 x1 y0 y1 z0 z1 [m]
FINGER_Y = (0.03, 0.01, -0.01, -0.03)              # index, middle, ring, little
FINGER_LEN = ((0.045, 0.027, 0.02), (0.05, 0.03, 0.022), (0.047, 0.029, 0.021), (0.038, 0.021, 0.019))
THUMB = (0.03, 0.04, (0.04, 0.03, 0.027))          # x, y start, lengths along +y
HALF_W = 0.009                                     # finger half width [m]
BONE_RADIUS = 0.0045
BONE_DENSITY = 1900.0                              # [kg/m^3]


def _bones():
    """(origin, direction, length) for the 16 bones in docs/INTERFACE.md order."""
    bones = [((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), 0.09)]
    x, y0, lens = THUMB
    p = np.array([x, y0, 0.0])
    for L in lens:
        bones.append((tuple(p), (0.0, 1.0, 0.0), L))
        p = p + np.array([0.0, L, 0.0])
    for y, lens in zip(FINGER_Y, FINGER_LEN):
        p = np.array([PALM[1], y, 0.0])
        for L in lens:
            bones.append((tuple(p), (1.0, 0.0, 0.0), L))
            p = p + np.array([L, 0.0, 0.0])
    return bones


def _inside(c):
    """Voxel centres (n,3) inside the hand's boxes."""
    x, y, z = c[:, 0], c[:, 1], c[:, 2]
    zin = np.abs(z) < HALF_W
    palm = (x > PALM[0]) & (x < PALM[1]) & (y > PALM[2]) & (y < PALM[3]) & (z > PALM[4]) & (z < PALM[5])
    out = palm.copy()
    for yf, lens in zip(FINGER_Y, FINGER_LEN):
        out |= (x >= PALM[1] - 1e-9) & (x < PALM[1] + sum(lens)) & (np.abs(y - yf) < HALF_W) & zin
    tx, ty, lens = THUMB
    out |= (np.abs(x - tx) < HALF_W) & (y >= ty - 1e-9) & (y < ty + sum(lens)) & zin
    return out


def box_hand(cell, samples_per_bone=400, seed=0):
    lo = np.array([PALM[0], PALM[2] - 0.001, -HALF_W - 0.004])
    hi = np.array([PALM[1] + max(sum(f) for f in FINGER_LEN), THUMB[1] + sum(THUMB[2]), HALF_W + 0.004])
    dims = np.ceil((hi - lo) / cell).astype(int)
    lo = 0.5 * (lo + hi) - 0.5 * dims * cell
    idx = np.stack(np.meshgrid(*[np.arange(d) for d in dims], indexing="ij"), -1).reshape(-1, 3)
    keep = _inside(lo + (idx + 0.5) * cell)
    vox = idx[keep]
    grid_id = lambda ijk: (ijk[..., 0] * (dims[1] + 1) + ijk[..., 1]) * (dims[2] + 1) + ijk[..., 2]
    corners = np.array([[c & 1, c >> 1 & 1, c >> 2 & 1] for c in range(8)])
    cid = grid_id(vox[:, None, :] + corners[None])  # (V,8)
    tets = cid[:, np.array(_KUHN)].reshape(-1, 4)
    used, tets = np.unique(tets, return_inverse=True)
    tets = tets.reshape(-1, 4).astype(np.int32)
    gi = np.stack(np.unravel_index(used, dims + 1), -1)
    nodes = lo + gi * cell
    X = nodes[tets]
    det = np.linalg.det(np.stack([X[:, 1] - X[:, 0], X[:, 2] - X[:, 0], X[:, 3] - X[:, 0]], 2))
    flip = det < 0
    tets[flip, 1], tets[flip, 2] = tets[flip, 2].copy(), tets[flip, 1].copy()
    # boundary faces (appear once), outward orientation not needed by the solver
    faces = np.sort(tets[:, [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]]].reshape(-1, 3), axis=1)
    uf, cnt = np.unique(faces, axis=0, return_counts=True)
    surface = uf[cnt == 1].astype(np.int32)

    bones = _bones()
    pose = np.zeros((16, 7))
    length = np.zeros(16)
    mass = np.zeros(16)
    com = np.zeros((16, 3))
    inertia = np.zeros((16, 3, 3))
    for b, (o, d, L) in enumerate(bones):
        pose[b, :3] = o
        pose[b, 3:] = quat_from_axes(d, (0.0, 0.0, 1.0))
        length[b] = L
        r = BONE_RADIUS if b else 0.012
        mass[b] = BONE_DENSITY * np.pi * r * r * L
        com[b] = (0.5 * L, 0.0, 0.0)
        ia = 0.5 * mass[b] * r * r
        it = mass[b] * (3 * r * r + L * L) / 12.0
        inertia[b] = np.diag([ia, it, it])
    parent = [0, 1, 2, 0, 4, 5, 0, 7, 8, 0, 10, 11, 0, 13, 14]
    child = list(range(1, 16))
    anchor_parent = np.zeros((15, 3))
    from softhand_sim.physics.rotations import quat_to_matrix
    for j, (p, c) in enumerate(zip(parent, child)):
        R = quat_to_matrix(pose[p, 3:])
        anchor_parent[j] = R.T @ (pose[c, :3] - pose[p, :3])
    jtype = np.array([0 if p == 0 else 1 for p in parent], np.int32)  # base joints spherical
    flex = np.tile([0.0, 1.0, 0.0], (15, 1))   # about bone y: +angle curls toward -z (palm)
    abd = np.tile([0.0, 0.0, 1.0], (15, 1))
    limits = np.tile(np.array([[-0.3, 1.7], [-0.4, 0.4]]), (15, 1, 1))
    limits[jtype == 1, 1] = 0.0
    rest_rot = np.zeros((15, 4))
    from softhand_sim.physics.rotations import quat_conj, quat_mul
    for j, (p, c) in enumerate(zip(parent, child)):
        rest_rot[j] = quat_mul(quat_conj(pose[p, 3:]), pose[c, 3:])

    # Sect. 3.4: capsule surface samples -> one representative point per (tet, bone)
    rng = np.random.default_rng(seed)
    s_tet, s_bone, s_cnt, s_loc, s_bary = [], [], [], [], []
    total = np.zeros(16, np.int32)
    vox_of = {tuple(v): i for i, v in enumerate(vox)}
    for b, (o, d, L) in enumerate(bones):
        r = BONE_RADIUS if b else 0.008
        t = rng.uniform(0.1, 0.9, samples_per_bone) * L
        ang = rng.uniform(0, 2 * np.pi, samples_per_bone)
        local = np.stack([t, r * np.cos(ang), r * np.sin(ang)], 1)
        total[b] = samples_per_bone
        R = quat_to_matrix(pose[b, 3:])
        world = pose[b, :3] + local @ R.T
        hits = {}
        for k, pw in enumerate(world):
            v = tuple(np.floor((pw - lo) / cell).astype(int))
            if v not in vox_of:
                continue
            for tt in range(6 * vox_of[v], 6 * vox_of[v] + 6):
                P = nodes[tets[tt]]
                T = np.column_stack([P[1] - P[0], P[2] - P[0], P[3] - P[0]])
                w123 = np.linalg.solve(T, pw - P[0])
                w = np.r_[1 - w123.sum(), w123]
                if w.min() >= -1e-9:
                    hits.setdefault(tt, []).append(k)
                    break
        for tt, ks in hits.items():
            loc = local[ks].mean(0)
            pw = pose[b, :3] + R @ loc
            P = nodes[tets[tt]]
            w123 = np.linalg.solve(np.column_stack([P[1] - P[0], P[2] - P[0], P[3] - P[0]]), pw - P[0])
            s_tet.append(tt), s_bone.append(b), s_cnt.append(len(ks)), s_loc.append(loc)
            s_bary.append(np.r_[1 - w123.sum(), w123])
    surf_nodes = np.unique(surface)
    node_tet = np.zeros(len(nodes), np.int32)
    node_tet[tets.ravel()] = np.repeat(np.arange(len(tets)), 4)
    skin_bary = (tets[node_tet[surf_nodes]] == surf_nodes[:, None]).astype(float)
    return SimpleNamespace(
        side="right", tet_nodes=nodes, tets=tets, tet_surface_triangles=surface,
        skin_vertices=nodes[surf_nodes], skin_tet=node_tet[surf_nodes], skin_bary=skin_bary,
        bone_rest_pose=pose, bone_length=length, bone_mass=mass, bone_com_local=com,
        bone_inertia_local=inertia, joint_parent=np.array(parent, np.int32),
        joint_child=np.array(child, np.int32), joint_type=jtype, joint_anchor_parent=anchor_parent,
        joint_anchor_child=np.zeros((15, 3)), joint_flex_axis=flex, joint_abd_axis=abd,
        joint_rest_rotation=rest_rot, joint_limits=limits,
        sample_tet=np.array(s_tet, np.int32), sample_bone=np.array(s_bone, np.int32),
        sample_count=np.array(s_cnt, np.int32), sample_local=np.array(s_loc),
        sample_bary=np.array(s_bary), bone_sample_total=total)


def box_hand_with_tets(target):
    """The box hand whose tet count is closest to target (cell sizes searched coarse to fine)."""
    best = None
    for cell in np.geomspace(0.015, 0.003, 40):
        lo = np.array([PALM[0], PALM[2] - 0.001, -HALF_W - 0.004])
        count = _count_tets(cell, lo)
        if best is None or abs(count - target) < abs(best[1] - target):
            best = (cell, count)
    return box_hand(best[0])


def _count_tets(cell, lo):
    hi = np.array([PALM[1] + max(sum(f) for f in FINGER_LEN), THUMB[1] + sum(THUMB[2]), HALF_W + 0.004])
    dims = np.ceil((hi - lo) / cell).astype(int)
    lo = 0.5 * (lo + hi) - 0.5 * dims * cell
    idx = np.stack(np.meshgrid(*[np.arange(d) for d in dims], indexing="ij"), -1).reshape(-1, 3)
    return 6 * int(_inside(lo + (idx + 0.5) * cell).sum())


# ---- bench drivers that work on any HandAsset-like hand (the real hand model or the box hand)

def flexed_pose(asset, flex, palm_offset=(0.0, 0.0, 0.0)):
    """Bone poses (16,7) by forward kinematics: every joint j rotated by flex[j] [rad] about its
    flexion axis (parent frame; positive curls toward the palm), the palm shifted by palm_offset [m].
    q_child = q_parent exp(flex a_parent) q_rest_rel;  p_child = p_parent + R_parent anchor_parent."""
    from softhand_sim.physics.rotations import quat_exp, quat_mul, quat_to_matrix
    pose = np.asarray(asset.bone_rest_pose, float).copy()
    pose[0, :3] += palm_offset
    for j in np.argsort(np.asarray(asset.joint_child)):
        p, c = int(asset.joint_parent[j]), int(asset.joint_child[j])
        qp = pose[p, 3:]
        rot = quat_exp(np.asarray(asset.joint_flex_axis[j], float) * float(flex[j]))
        pose[c, 3:] = quat_mul(quat_mul(qp, rot), np.asarray(asset.joint_rest_rotation[j], float))
        pose[c, :3] = pose[p, :3] + quat_to_matrix(qp) @ np.asarray(asset.joint_anchor_parent[j], float)
    return pose


def fingertip_pad_nodes(asset, radius=0.008):
    """Per distal bone (thumb, index..little): tissue nodes within radius [m] of the bone's distal
    end on its ventral (palm) side: where a fingertip presses on a surface."""
    from softhand_sim.physics.rotations import quat_to_matrix
    X = np.asarray(asset.tet_nodes, float)
    pads = []
    for b in (3, 6, 9, 12, 15):
        pose = np.asarray(asset.bone_rest_pose[b], float)
        R = quat_to_matrix(pose[3:])
        tip = pose[:3] + R @ np.array([float(asset.bone_length[b]), 0.0, 0.0])
        d = X - tip
        near = (np.linalg.norm(d, axis=1) < radius) & (d @ R[:, 2] < 0.0)  # -z of the bone: ventral
        if not near.any():
            near = np.linalg.norm(d, axis=1) <= np.sort(np.linalg.norm(d, axis=1))[3]
        pads.append(np.flatnonzero(near))
    return pads
