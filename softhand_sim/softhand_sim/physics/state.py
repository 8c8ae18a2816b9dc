"""Solver State: what a step changes. Quaternions [x, y, z, w]; SI units.

  node_x (N,3) [m]        tissue node positions
  v (3N + 6B,) [m/s, rad/s] generalized velocities (flat, the CG unknown); views:
      node_v (N,3)         node velocities
      body_v (B,6)         COM linear velocity, then world-frame angular velocity
  body_x (B,3) [m]        centres of mass;   body_q (B,4) orientations
  body_pose (B,7)         bone-frame poses (public form), refreshed after each step
  tet_q (T,4)             per-tet rotation of the co-rotational FEM (warm start)
"""
from dataclasses import dataclass

import numpy as np

from softhand_sim.physics.rotations import quat_to_matrix


@dataclass
class State:
    node_x: np.ndarray
    v: np.ndarray
    body_x: np.ndarray
    body_q: np.ndarray
    body_pose: np.ndarray
    tet_q: np.ndarray
    bone_count: int

    @property
    def node_v(self):
        n = self.node_x.shape[0]
        return self.v[:3 * n].reshape(n, 3)

    @property
    def body_v(self):
        n = self.node_x.shape[0]
        return self.v[3 * n:].reshape(-1, 6)

    @property
    def bone_pose(self):
        """(bone_count,7) bone-frame poses of the bones of every hand (16 per hand, model.hands order)."""
        return self.body_pose[:self.bone_count]

    def hand_bone_pose(self, model, hand):
        """(16,7) bone-frame poses of hand `hand` (index into model.hands)."""
        return self.body_pose[model.hands.bones(hand)]

    @property
    def object_pose(self):
        return self.body_pose[self.bone_count:]

    @classmethod
    def at_rest(cls, model):
        pose = model.body_rest_pose.copy()
        B = len(pose)
        body_x = np.zeros((B, 3))
        for b in range(B):
            body_x[b] = pose[b, :3] + quat_to_matrix(pose[b, 3:]) @ model.body_com_local[b]
        tet_q = np.zeros((len(model.tets), 4))
        tet_q[:, 3] = 1.0
        return cls(node_x=model.node_rest.copy(), v=np.zeros(model.dof_count), body_x=body_x,
                   body_q=np.ascontiguousarray(pose[:, 3:]), body_pose=pose, tet_q=tet_q,
                   bone_count=model.bone_count)

    def copy(self):
        return State(self.node_x.copy(), self.v.copy(), self.body_x.copy(), self.body_q.copy(),
                     self.body_pose.copy(), self.tet_q.copy(), self.bone_count)

    def set_body_pose(self, model, b, pose):
        """Place body b at bone-frame pose (7,) (teleport; velocity unchanged)."""
        pose = np.asarray(pose, float)
        self.body_q[b] = pose[3:] / np.linalg.norm(pose[3:])
        self.body_x[b] = pose[:3] + quat_to_matrix(self.body_q[b]) @ model.body_com_local[b]
        self.body_pose[b, :3] = pose[:3]
        self.body_pose[b, 3:] = self.body_q[b]
