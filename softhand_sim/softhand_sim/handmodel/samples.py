"""Bone-tissue coupling samples (paper Sect. 3.4, Eq. 11, Fig. 4).

Each bone capsule's surface is sampled uniformly (a grid on the cylinder, a Fibonacci spiral on
each hemispherical cap, about one sample per SAMPLE_SPACING^2 of area). Samples are grouped by
the tet that contains them; the mean of a group is the representative point x_e of that
(tet, bone) pair, stored in the bone frame (r_e) and as barycentric weights in the tet (w_i),
with the group's size N. N_total counts every sample on the capsule, so the solver's per-pair
stiffness k = k_total / N_total weighted by N is proportional to the intersected area.
Samples outside every tet (none when the capsules lie inside the tissue) are counted in N_total
but belong to no pair.
"""
import numpy as np

from softhand_sim.handmodel.embedding import barycentric, embed_points
from softhand_sim.physics.rotations import quat_to_matrix

SAMPLE_SPACING = 0.001  # [m] between neighbouring capsule surface samples


def capsule_surface_samples(a, b, radius, spacing=SAMPLE_SPACING):
    """Uniform samples (n,3) on the capsule with segment a -> b along x (bone frame) and radius."""
    length = float(np.linalg.norm(b - a))
    n_theta = max(6, int(round(2 * np.pi * radius / spacing)))
    n_len = int(round(length / spacing))
    pts = []
    if n_len > 0:
        s = (np.arange(n_len) + 0.5) / n_len * length
        th = (np.arange(n_theta) + 0.5) / n_theta * 2 * np.pi
        S, TH = np.meshgrid(s, th, indexing="ij")
        pts.append(np.stack([S.ravel(), radius * np.cos(TH.ravel()), radius * np.sin(TH.ravel())], 1))
    n_sphere = max(8, 2 * int(round(2 * np.pi * radius * radius / spacing ** 2)))
    k = np.arange(n_sphere) + 0.5
    polar = np.arccos(1 - 2 * k / n_sphere)  # Fibonacci sphere: equal area per point
    az = np.pi * (1 + 5 ** 0.5) * k
    unit = np.stack([np.cos(polar), np.sin(polar) * np.cos(az), np.sin(polar) * np.sin(az)], 1)
    caps = np.where(unit[:, :1] >= 0, length + radius * unit[:, :1], radius * unit[:, :1])
    pts.append(np.concatenate([caps, radius * unit[:, 1:]], axis=1))
    local = np.vstack(pts)
    local[:, 0] += a[0]
    local[:, 1] += a[1]
    local[:, 2] += a[2]
    return local


def coupling_samples(nodes, tets, bone_pose, cap_a, cap_b, cap_r, spacing=SAMPLE_SPACING):
    """Representative points per (tet, bone): dict of the HandAsset sample_* fields."""
    out = {k: [] for k in ("sample_tet", "sample_bone", "sample_count", "sample_local")}
    totals = np.zeros(len(bone_pose), dtype=np.int32)
    for bone in range(len(bone_pose)):
        local = capsule_surface_samples(cap_a[bone], cap_b[bone], cap_r[bone], spacing)
        totals[bone] = len(local)
        rot = quat_to_matrix(bone_pose[bone, 3:])
        world = local @ rot.T + bone_pose[bone, :3]
        tet, _, dist = embed_points(nodes, tets, world)
        inside = dist == 0.0
        tet, local = tet[inside], local[inside]
        ids, inverse, counts = np.unique(tet, return_inverse=True, return_counts=True)
        mean = np.zeros((len(ids), 3))
        np.add.at(mean, inverse, local)
        mean /= counts[:, None]
        out["sample_tet"].append(ids)
        out["sample_bone"].append(np.full(len(ids), bone))
        out["sample_count"].append(counts)
        out["sample_local"].append(mean)
    fields = {k: np.concatenate(v) for k, v in out.items()}
    world = np.empty_like(fields["sample_local"])
    for bone in range(len(bone_pose)):
        sel = fields["sample_bone"] == bone
        world[sel] = fields["sample_local"][sel] @ quat_to_matrix(bone_pose[bone, 3:]).T + bone_pose[bone, :3]
    fields["sample_bary"] = barycentric(nodes, tets, fields["sample_tet"], world)
    for k in ("sample_tet", "sample_bone", "sample_count"):
        fields[k] = fields[k].astype(np.int32)
    fields["bone_sample_total"] = totals
    return fields
