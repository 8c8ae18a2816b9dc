"""Solver Control: what comes in from outside for each step (NVIDIA newton's Model/State/Control split).

Every body (bones first, then objects, as in Model) is coupled by Eq. 14 to a target that is
fixed during the step (energies/rigid_coupling.py):
  bones    the intermediate bones of the tracked hand (Sect. 3.6),
  objects  the copies of the engine's instances, extrapolated to the end of the step (Sect. 3.7).

  target_x (B,3) [m]          target centres of mass
  target_q (B,4)              target orientations, unit quaternions [x, y, z, w]
  target_kx (B,) [N/m]        Eq. 14 stiffnesses per body (0 releases a body)
  target_ktheta (B,) [N m/rad]
  node_force (N,3) [N]        external dead loads on the tissue nodes (U = -f . x) ...
  body_force (B,3) [N]        ... and on the bodies' centres of mass; zero by default (SimRuntime
                              loads a hand's masses with its palm target's acceleration, target_lead.py)

The setters take poses as they come from the runtime boundary, which validates them once
(finite, shapes, unit quaternions, normalised: runtime.SimRuntime.set_bone_targets for the bones,
coupling.ObjectCopy.update for the copies); here they are only converted from bone-frame poses to
centres of mass.
"""
from dataclasses import dataclass

import numpy as np

from softhand_sim.physics.state import com_from_poses


@dataclass
class Control:
    target_x: np.ndarray
    target_q: np.ndarray
    target_kx: np.ndarray
    target_ktheta: np.ndarray
    node_force: np.ndarray
    body_force: np.ndarray

    @classmethod
    def at_rest(cls, model):
        """Every body held at its rest pose with the model's Eq. 14 stiffnesses; no load."""
        B = model.body_count
        control = cls(target_x=np.zeros((B, 3)), target_q=np.zeros((B, 4)),
                      target_kx=model.body_target_kx.copy(), target_ktheta=model.body_target_ktheta.copy(),
                      node_force=np.zeros((model.node_count, 3)), body_force=np.zeros((B, 3)))
        control._set_targets(model, 0, model.body_rest_pose)
        return control

    def copy(self):
        return Control(self.target_x.copy(), self.target_q.copy(), self.target_kx.copy(),
                       self.target_ktheta.copy(), self.node_force.copy(), self.body_force.copy())

    def _set_targets(self, model, first, poses):
        com_from_poses(np.ascontiguousarray(poses), model.body_com_local, first, self.target_x, self.target_q)

    def set_bone_targets(self, model, poses):
        """Intermediate-bone targets (bone_count, 7) bone-frame poses [m, unit quaternion] (Sect. 3.6);
        with several hands, every hand's bones in model order (set_hand_targets sets one hand)."""
        self._set_targets(model, 0, np.asarray(poses, dtype=np.float64).reshape(model.bone_count, 7))

    def set_hand_targets(self, model, hand, poses):
        """Intermediate-bone targets (16, 7) of hand `hand` (index into model.hands) only."""
        bones = model.hands.bones(hand)
        count = bones.stop - bones.start
        self._set_targets(model, bones.start, np.asarray(poses, dtype=np.float64).reshape(count, 7))

    def set_object_targets(self, model, poses, kx=None, ktheta=None):
        """Engine-copy targets (object_count, 7) COM poses [m, unit quaternion] (Sect. 3.7); optional
        per-object stiffness kx [N/m] / ktheta [N m/rad] (0 releases an object)."""
        nb = model.bone_count
        self._set_targets(model, nb, np.asarray(poses, dtype=np.float64).reshape(model.object_count, 7))
        if kx is not None:
            self.target_kx[nb:] = kx
        if ktheta is not None:
            self.target_ktheta[nb:] = ktheta

