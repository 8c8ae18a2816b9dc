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
from numba import njit

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
        body_x, body_q = np.zeros((len(pose), 3)), np.zeros((len(pose), 4))
        com_from_poses(pose, model.body_com_local, 0, body_x, body_q)
        tet_q = np.zeros((len(model.tets), 4))
        tet_q[:, 3] = 1.0
        return cls(node_x=model.node_rest.copy(), v=np.zeros(model.dof_count), body_x=body_x,
                   body_q=body_q, body_pose=pose, tet_q=tet_q,
                   bone_count=model.bone_count)

    def copy(self):
        return State(self.node_x.copy(), self.v.copy(), self.body_x.copy(), self.body_q.copy(),
                     self.body_pose.copy(), self.tet_q.copy(), self.bone_count)

    def set_body_pose(self, model, b, pose):
        """Place body b at bone-frame pose (7,) (teleport; velocity unchanged)."""
        pose = np.array(pose, dtype=np.float64).reshape(1, 7)
        pose[0, 3:] /= np.linalg.norm(pose[0, 3:])
        com_from_poses(pose, model.body_com_local, b, self.body_x, self.body_q)
        self.body_pose[b] = pose[0]


@njit(cache=True)
def com_from_poses(poses, com_local, first, com_out, q_out):
    """Bone-frame poses (n, 7) of bodies first..first+n-1 -> their centres of mass com_out and
    orientations q_out (in place; com = origin + R(q) com_local): the one conversion of the state's
    bodies (at rest, teleports) and of Control's targets, compiled as the targets need it every
    step for every bone (a Python loop of per-bone kernel calls took ~0.2 ms of the node's tick)."""
    for i in range(poses.shape[0]):
        b = first + i
        for k in range(4):
            q_out[b, k] = poses[i, 3 + k]
        R = quat_to_matrix(q_out[b])
        for r in range(3):
            com_out[b, r] = poses[i, r] + R[r, 0] * com_local[b, 0] + R[r, 1] * com_local[b, 1] \
                + R[r, 2] * com_local[b, 2]
