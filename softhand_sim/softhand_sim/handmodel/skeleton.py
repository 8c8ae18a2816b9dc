"""Skeleton of the parametric hand: 16 bone frames, capsules, masses and the 15 joints.

Rest pose (right hand): palm down (dorsal = +z), fingers straight along +x and fanned in the palm
plane by `finger_spread_deg` between neighbours, thumb toward +y at its anatomical angle
(metacarpal 42 deg off the palm axis and 10 deg palmar, pronated so that its nail faces up and
outward), wrist joint at the origin. Bone frames follow docs/INTERFACE.md: origin at the proximal
joint, +x toward the distal joint, +z dorsal, y = z x x. With +z dorsal, a positive rotation about
the bone's +y turns +x toward -z: positive flexion curls toward the palm.

Bone masses: bone density 1900 kg/m^3 (cortical/trabecular average) over the capsule volume;
the soft tissue mass (1000 kg/m^3) belongs to the tet mesh and is added by the solver.
"""
import numpy as np

from softhand_sim.physics.rotations import matrix_to_quat, quat_from_axes, quat_mul, quat_conj, quat_to_matrix
from softhand_sim.handmodel.skeleton_names import BONE_COUNT, BONE_PARENT

BONE_DENSITY = 1900.0  # [kg/m^3]
JOINT_SPHERICAL, JOINT_HINGE, JOINT_UNIVERSAL = 0, 1, 2

# Thumb direction per bone: (azimuth from +x toward +y, elevation toward dorsal) [deg]
THUMB_DIRECTIONS_DEG = ((42.0, -10.0), (30.0, 0.0), (22.0, 2.0))
THUMB_PRONATION_DEG = 50.0  # nail normal tilted from +z toward the radial side
# Anatomical limits relative to rest [rad]: [[flex_min, flex_max], [abd_min, abd_max]]
LIMITS_MCP = ((-0.35, 1.57), (-0.35, 0.35))
LIMITS_PIP = ((0.0, 1.75), (0.0, 0.0))
LIMITS_DIP = ((0.0, 1.40), (0.0, 0.0))
# Thumb CMC: wide enough for the opposition a real tracked thumb shows (Leap recording leap_grab:
# flexion up to 52 deg, abduction down to -33 deg from rest in a fist), with a few degrees spare.
LIMITS_THUMB_CMC = ((-0.35, 0.98), (-0.65, 0.60))
LIMITS_THUMB_MCP = ((-0.15, 1.00), (0.0, 0.0))
LIMITS_THUMB_IP = ((-0.35, 1.40), (0.0, 0.0))
FINGER_BONES = {"thumb": (1, 2, 3), "index": (4, 5, 6), "middle": (7, 8, 9), "ring": (10, 11, 12),
                "little": (13, 14, 15)}


def knuckle_span(m):
    """Index-to-little knuckle distance across the palm [m]: the palm width less the half widths
    of the two outer fingers (their skin edges span the palm width)."""
    return m.palm_width - 0.5 * (m.index_width + m.little_width)


def finger_base_layout(m):
    """MCP joint positions (palm frame = world at rest) and finger directions of the four fingers.

    Knuckles are spaced so that index-to-little skin edges span the palm width, the gaps between
    neighbours as `m.knuckle_gaps`; the row of knuckles is arched (default: index and ring 4.5 %,
    little 15.5 % of the palm length short of the middle, `m.knuckle_recess`).
    """
    s = knuckle_span(m) / 3.0  # mean gap
    g_im, g_mr, g_rl = (s * g for g in m.knuckle_gaps)
    r_idx, r_rng, r_lit = m.knuckle_recess
    x_back = {"index": r_idx, "middle": 0.0, "ring": r_rng, "little": r_lit}
    y = {"index": g_im, "middle": 0.0, "ring": -g_mr, "little": -(g_mr + g_rl)}
    spread = {"index": 1.0, "middle": 0.0, "ring": -1.0, "little": -2.0}
    out = {}
    for f in ("index", "middle", "ring", "little"):
        ang = np.radians(m.finger_spread_deg * spread[f])
        base = np.array([m.palm_length * (1.0 - x_back[f]), y[f], 0.0])
        out[f] = (base, np.array([np.cos(ang), np.sin(ang), 0.0]))
    return out


def thumb_layout(m):
    """CMC position and the three (direction, dorsal hint) pairs of the thumb bones."""
    s = knuckle_span(m) / 3.0
    fx, fy, fz = m.thumb_cmc
    cmc = np.array([fx * m.palm_length, fy * s, fz * m.palm_thickness])
    dirs = []
    for az_deg, el_deg in THUMB_DIRECTIONS_DEG:
        az, el = np.radians(az_deg), np.radians(el_deg)
        d = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        radial = np.array([-np.sin(az), np.cos(az), 0.0])
        beta = np.radians(THUMB_PRONATION_DEG)
        dirs.append((d, np.cos(beta) * np.array([0.0, 0.0, 1.0]) + np.sin(beta) * radial))
    return cmc, dirs


def bone_chain_points(m):
    """World rest positions of each bone's proximal and distal joint, and each bone's frame.

    Returns (proximal (16,3), distal (16,3), rotation (16,3,3) columns = bone x, y, z axes).
    """
    prox = np.zeros((BONE_COUNT, 3))
    dist = np.zeros((BONE_COUNT, 3))
    rot = np.zeros((BONE_COUNT, 3, 3))
    prox[0] = 0.0
    dist[0] = [m.palm_length, 0.0, 0.0]
    rot[0] = np.eye(3)
    layout = finger_base_layout(m)
    for f, bones in FINGER_BONES.items():
        lengths = m.finger_lengths(f)
        if f == "thumb":
            p, dirs = thumb_layout(m)
        else:
            p, d = layout[f]
            dirs = [(d, np.array([0.0, 0.0, 1.0]))] * 3
        for b, length, (d, z_hint) in zip(bones, lengths, dirs):
            prox[b] = p
            dist[b] = p + length * d
            rot[b] = quat_to_matrix(quat_from_axes(d, z_hint))
            p = dist[b]
    return prox, dist, rot


def capsule_inertia(radius, height, density):
    """Mass [kg] and inertia about the COM, axis along x [kg m^2], of a solid capsule.

    Cylinder (height h) plus two hemispheres; the hemisphere COM sits 3r/8 from its flat face.
    """
    r, h = radius, height
    m_cyl = density * np.pi * r * r * h
    m_hem = density * 2.0 / 3.0 * np.pi * r ** 3
    i_axis = m_cyl * r * r / 2.0 + 2.0 * m_hem * 2.0 * r * r / 5.0
    i_perp = m_cyl * (r * r / 4.0 + h * h / 12.0) + 2.0 * m_hem * (
        2.0 * r * r / 5.0 + h * h / 4.0 + 3.0 * h * r / 8.0)
    return m_cyl + 2.0 * m_hem, np.diag([i_axis, i_perp, i_perp])


def bone_capsules(m, bone_length):
    """Capsule (a, b, radius) of each bone in its own frame, lying well inside the tissue."""
    a = np.zeros((BONE_COUNT, 3))
    b = np.zeros((BONE_COUNT, 3))
    r = np.zeros(BONE_COUNT)
    palm_z = palm_centre_z(m)
    r[0] = 0.3 * m.palm_thickness
    a[0] = [0.18 * m.palm_length, 0.0, palm_z]
    b[0] = [0.80 * m.palm_length, 0.0, palm_z]
    for f, bones in FINGER_BONES.items():
        width = m.finger_width(f)
        for k, bone in enumerate(bones):
            length = bone_length[bone]
            rad = (0.26 if f == "thumb" and k == 0 else 0.22) * width * (1.0 - 0.08 * k)
            start = 0.1 * length + rad
            end = (0.62 if k == 2 else 0.9) * length - rad
            if end < start:
                start = end = 0.5 * (start + end)
            a[bone] = [start, 0.0, 0.0]
            b[bone] = [end, 0.0, 0.0]
            r[bone] = rad
    return a, b, r


def palm_centre_z(m):
    """Height of the palm slab's mid plane: its dorsal skin is flush with the fingers' backs."""
    return 0.5 * m.middle_width - 0.5 * m.palm_thickness


def build_skeleton(m):
    """Every skeleton field of HandAsset (see docs/ARCHITECTURE.md) for the right hand."""
    prox, dist, rot = bone_chain_points(m)
    return skeleton_from_frames(m, prox, dist, rot)


def skeleton_from_frames(m, prox, dist, rot):
    """Skeleton fields from bone joint points and frames (shared by the right and mirrored hand)."""
    n = BONE_COUNT
    pose = np.zeros((n, 7))
    quats = np.zeros((n, 4))
    for i in range(n):
        quats[i] = matrix_to_quat(np.ascontiguousarray(rot[i]))
        pose[i, :3] = prox[i]
        pose[i, 3:] = quats[i]
    length = np.linalg.norm(dist - prox, axis=1)
    cap_a, cap_b, cap_r = bone_capsules(m, length)
    mass = np.zeros(n)
    inertia = np.zeros((n, 3, 3))
    for i in range(n):
        mass[i], inertia[i] = capsule_inertia(cap_r[i], np.linalg.norm(cap_b[i] - cap_a[i]), BONE_DENSITY)
    com = 0.5 * (cap_a + cap_b)

    j = n - 1
    parent = np.array(BONE_PARENT[1:], dtype=np.int32)
    child = np.arange(1, n, dtype=np.int32)
    jtype = np.full(j, JOINT_HINGE, dtype=np.int32)
    limits = np.zeros((j, 2, 2))
    anchor_p = np.zeros((j, 3))
    flex = np.zeros((j, 3))
    abd = np.zeros((j, 3))
    rest_rot = np.zeros((j, 4))
    for k in range(j):
        p, c = parent[k], child[k]
        rel = rot[p].T @ rot[c]
        anchor_p[k] = rot[p].T @ (prox[c] - prox[p])
        flex[k] = rel[:, 1]
        abd[k] = rel[:, 2]
        rest_rot[k] = quat_mul(quat_conj(quats[p]), quats[c])
        pos = [b for b in FINGER_BONES.values() if c in b][0].index(c)
        thumb = c <= 3
        if pos == 0:
            jtype[k] = JOINT_UNIVERSAL
            limits[k] = LIMITS_THUMB_CMC if thumb else LIMITS_MCP
        elif pos == 1:
            limits[k] = LIMITS_THUMB_MCP if thumb else LIMITS_PIP
        else:
            limits[k] = LIMITS_THUMB_IP if thumb else LIMITS_DIP
    return dict(
        bone_rest_pose=pose, bone_length=length, bone_mass=mass, bone_com_local=com,
        bone_inertia_local=inertia, bone_capsule_a=cap_a, bone_capsule_b=cap_b,
        bone_capsule_radius=cap_r, joint_parent=parent, joint_child=child, joint_type=jtype,
        joint_anchor_parent=anchor_p, joint_anchor_child=np.zeros((j, 3)), joint_flex_axis=flex,
        joint_abd_axis=abd, joint_rest_rotation=rest_rot, joint_limits=limits,
    )
