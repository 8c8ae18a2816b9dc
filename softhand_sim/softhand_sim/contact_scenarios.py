"""Scripted contact scenarios on a hand (HandAsset or the bench's box hand): used by
`softhand bench --scenario grasp` and the contact tests.

The hand is in its rest pose (right hand, palm down, dorsal +z, fingers along +x, thumb toward
+y). A 0.1 kg ball (r = 4 cm) is placed under the palm; its hand-side body is coupled by Eq. 14
to an engine copy that stays where the ball started (the world node's role, scripted here). The
fingers flex by a ramp of their bone targets around the ball: flexion is a rotation about the
joint's flex axis (bone y, positive curls toward the palm, -z).
"""
import numpy as np

from . import contact
from .rotations import quat_exp, quat_mul, quat_to_matrix
from .scene import Scene, SceneObject, shape_inertia

BALL_RADIUS = 0.04   # [m]
BALL_MASS = 0.1      # [kg] (paper Sect. 5.1)
FINGER_BONES = tuple(range(1, 16))


def ball_object(centre, name="ball"):
    dims = {"radius": BALL_RADIUS}
    pose = np.r_[np.asarray(centre, float), 0.0, 0.0, 0.0, 1.0]
    return SceneObject(name, "sphere", dims, BALL_MASS, 0.5, pose, False,
                       shape_inertia("sphere", dims, BALL_MASS))


def ball_under_palm(asset, press=0.003):
    """Ball centre [m] under the palm bone's middle, its top `press` [m] into the palm's underside."""
    palm = np.asarray(asset.bone_rest_pose[0])
    length = float(np.asarray(asset.bone_length)[0]) if hasattr(asset, "bone_length") else 0.09
    mid = palm[:3] + quat_to_matrix(palm[3:]) @ np.array([0.7 * length, 0.0, 0.0])
    nodes = np.asarray(asset.tet_nodes)
    near = np.linalg.norm(nodes[:, :2] - mid[:2], axis=1) < 0.015
    bottom = nodes[near, 2].min() if near.any() else mid[2] - 0.0125
    return np.array([mid[0], mid[1], bottom - BALL_RADIUS + press])


def flexed_targets(rest, flex, bones=FINGER_BONES):
    """Bone targets (16,7): palm at rest, the joints of `bones` (default: every finger and the
    thumb) flexed by `flex` [rad] about their bone's y axis (positive curls toward the palm),
    accumulated down each finger."""
    tgt = rest.copy()
    for b in bones:
        depth = (b - 1) % 3 + 1  # 1 proximal, 2 intermediate, 3 distal: angles add up the chain
        R = quat_to_matrix(rest[b, 3:])
        axis_world = R @ np.array([0.0, 1.0, 0.0])
        tgt[b, 3:] = quat_mul(quat_exp(axis_world * flex * depth), rest[b, 3:])
    return tgt


class GraspScenario:
    """setup(solver, state) -> update(k, t), for bench.SCENARIOS; `objects(asset)` gives the ball
    as the model's rigid object. Over `close_time` [s] the fingers close to `flex` [rad] per joint
    and the tracked hand moves `squeeze` [m] down into the ball (a firm grasp: the ball's engine
    copy, 170 N/m, holds it against the palm; ~100 skin contacts on the hand model)."""

    def __init__(self, flex=0.8, close_time=0.5, press=0.004, squeeze=0.05):
        self.flex, self.close_time, self.press, self.squeeze = flex, close_time, press, squeeze
        self.system = None
        self.asset = None

    def objects(self, asset):
        """The model's rigid objects for this hand (remembers the asset for the skin points)."""
        self.asset = asset
        return [ball_object(ball_under_palm(asset, self.press))]

    def __call__(self, solver, state, asset=None):
        model = solver.model
        asset = self.asset if asset is None else asset
        ball_pose = model.body_rest_pose[model.bone_count].copy()
        ball = ball_object(ball_pose[:3])
        scene = Scene(-1.0, 0.5, (ball,))  # the hand floats at the origin: ground out of reach
        self.system = contact.attach(solver, scene, asset)
        solver.set_object_targets(ball_pose[None, :])
        rest = model.body_rest_pose[:model.bone_count].copy()

        def update(k, t):
            ramp = min(1.0, t / self.close_time)
            tgt = flexed_targets(rest, self.flex * ramp)
            tgt[:, 2] -= self.squeeze * ramp  # the tracked hand presses down into the ball
            solver.set_bone_targets(tgt)
        return update
