"""The skin carried rigidly by its nearest bone: a kinematic stand-in for the soft hand's surface.

Used where a pose has to be judged before anything is simulated (planning a grasp pose for the
sample bags, checking it in tests): each skin vertex is bound to the bone whose axis segment is
nearest at rest and follows that bone rigidly. The simulated skin bends smoothly at the joints
and gives under contact; away from the joints (finger pads, palm) the two agree to a few
millimetres.
"""
from __future__ import annotations

import numpy as np

from softhand_sim.physics.rotations import quat_to_matrix


def _segment_distance(points, origin, axis, length):
    """Distance [m] of points (n, 3) to the segment origin + [0, length] * axis (unit)."""
    t = np.clip((points - origin) @ axis, 0.0, length)
    return np.linalg.norm(points - (origin + t[:, None] * axis), axis=1)


def vertex_normals(vertices, triangles):
    """Area-weighted outward unit normals (n, 3) of a closed triangle mesh."""
    v = np.asarray(vertices, dtype=np.float64)
    tri = np.asarray(triangles)
    face = np.cross(v[tri[:, 1]] - v[tri[:, 0]], v[tri[:, 2]] - v[tri[:, 0]])
    normals = np.zeros_like(v)
    for k in range(3):
        np.add.at(normals, tri[:, k], face)
    length = np.linalg.norm(normals, axis=1)[:, None]
    # a vertex on no triangle keeps a zero normal, not NaN: the self-contact kernel skips a contact
    # whose depth along a zero normal is 0, where NaN would pass its depth tests
    return np.divide(normals, length, out=np.zeros_like(normals), where=length > 0.0)


class RigidSkin:
    """Skin vertices of a HandAsset bound to bones.

    bone_of (n,) int: the bone each skin vertex follows; local_points / local_normals (n, 3): the
    vertex [m] and its outward normal in that bone's frame (bone frames as docs/INTERFACE.md: origin at
    the proximal joint, x along the bone).
    """

    def __init__(self, asset):
        rest = np.asarray(asset.bone_rest_pose, dtype=np.float64)
        length = np.asarray(asset.bone_length, dtype=np.float64)
        points = np.asarray(asset.skin_vertices, dtype=np.float64)
        normals = vertex_normals(points, asset.skin_triangles)
        self.bone_count = len(rest)
        distance = np.stack([_segment_distance(points, rest[b, :3], quat_to_matrix(rest[b, 3:])[:, 0], length[b])
                             for b in range(self.bone_count)], axis=1)
        self.bone_of = distance.argmin(axis=1)
        self.local_points = np.empty_like(points)
        self.local_normals = np.empty_like(normals)
        for b in range(self.bone_count):
            world_from_bone = quat_to_matrix(rest[b, 3:])
            on = self.bone_of == b
            self.local_points[on] = (points[on] - rest[b, :3]) @ world_from_bone
            self.local_normals[on] = normals[on] @ world_from_bone

    def pose(self, bone_poses):
        """(points (n, 3) [m], normals (n, 3)) of the skin for bone poses (bone_count, 7) [m, x y z w]."""
        bone_poses = np.asarray(bone_poses, dtype=np.float64)
        points = np.empty_like(self.local_points)
        normals = np.empty_like(self.local_normals)
        for b in range(self.bone_count):
            world_from_bone = quat_to_matrix(bone_poses[b, 3:])
            on = self.bone_of == b
            points[on] = self.local_points[on] @ world_from_bone.T + bone_poses[b, :3]
            normals[on] = self.local_normals[on] @ world_from_bone.T
        return points, normals

    def on_bones(self, bones):
        """Boolean mask (n,) of the skin vertices that follow any of `bones`."""
        return np.isin(self.bone_of, list(bones))


def skin_segments(asset, body_offset=0):
    """(point_segment (V,), segment_body (16,), adjacent pairs) of one hand asset, for skin-skin
    contact (physics/contact/self_contact.py): each skin vertex in the segment of its nearest bone
    axis (RigidSkin), segments = bones (at model bodies body_offset + bone), adjacency = the
    skeleton's joints."""
    nb = len(asset.bone_rest_pose)
    seg = RigidSkin(asset).bone_of.astype(np.int32)
    adjacent = list(zip(np.asarray(asset.joint_parent).tolist(), np.asarray(asset.joint_child).tolist()))
    return seg, np.arange(nb, dtype=np.int32) + body_offset, adjacent
