"""Scripted contact scenarios on the hand model: used by `softhand bench --scenario grasp` and
the contact tests.

The hand starts in its rest pose (right hand, palm down, dorsal +z, fingers along +x, thumb
toward +y, wrist at the origin). A 0.1 kg ball (r = 4 cm) is the model's rigid object; its
hand-side body is coupled by Eq. 14 to an engine copy scripted here (the world node's role).

- `PinchLift`: the issue's grasp. Thumb and index pads pinch the ball (pose PINCH_*, found by
  tools/pinch_pose.py), the copy lets go, the hand lifts 10 cm, holds 5 s and opens.
  `PinchScenario` runs it for the bench (`--scenario grasp`).
- `ball_under_palm` / `flexed_targets`: the ball against the palm, every joint flexed by one
  angle about its flexion axis (bone y, positive curls toward the palm, -z).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from softhand_sim.physics.contact import detection as contact
from softhand_sim.handmodel.kinematics import DIGIT_LIMITS, forward_kinematics
from softhand_sim.physics.rotations import quat_exp, quat_mul, quat_to_matrix
from softhand_sim.scene import Scene, SceneObject, shape_inertia

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


# ---------------------------------------------------------------------------- thumb-index pinch
#
# A precision pinch of the ball between the pads of the thumb and the index finger, the other
# fingers straight. The pose was found by tools/pinch_pose.py: a differential-evolution search
# over the thumb's and the index's four angles (within DIGIT_LIMITS) and the ball centre, on the
# hand model's skin carried rigidly by its bones (softhand_sim.handmodel.rigid_skin), asking
# that the distal pads of both digits reach PINCH_DEPTH into the ball, face it, and meet it at
# opposite ends of a line through its centre (the only two-finger grip in which the squeeze
# itself puts no torque on the ball), that line level with the palm (palm down, the squeeze
# pushes the ball neither up nor down: it hangs between the pads on friction alone), and that
# every other skin point stay clear of it. `pinch_report` checks it.
PINCH_TOUCH_DEG = np.array([               # (abduction, flex_1, flex_2, flex_3) [deg]
    [33.00, -1.15, -5.93, 33.46],          # thumb
    [-16.23, 23.22, 48.45, 47.03]])        # index
PINCH_BALL_IN_PALM = np.array([0.0970, 0.0472, -0.0533])   # [m] ball centre, palm frame
PINCH_DEPTH = 0.004       # [m] pads into the ball at PINCH_TOUCH_DEG (rigid skin)
PINCH_OPEN = 0.6          # [-] open pre-shape: flexions this fraction of the way back to their lower limit
PINCH_SQUEEZE = 0.1       # [-] squeeze: touch plus this fraction of (touch - open)
PINCH_DIGITS = ((1, 2, 3), (4, 5, 6))      # the bones of the thumb and of the index


def pinch_angles():
    """(open, touch, squeeze) digit angles (5, 4) [rad] of the thumb-index pinch; the middle,
    ring and little fingers straight (all zero) in all three."""
    lo, hi = DIGIT_LIMITS[:, :, 0], DIGIT_LIMITS[:, :, 1]
    touch = np.zeros((5, 4))
    touch[:2] = np.deg2rad(PINCH_TOUCH_DEG)
    opened = touch.copy()
    opened[:2, 1:] = touch[:2, 1:] - PINCH_OPEN * (touch[:2, 1:] - lo[:2, 1:])
    squeeze = np.clip(touch + PINCH_SQUEEZE * (touch - opened), lo, hi)
    return opened, touch, squeeze


def pinch_report(skin, palm_pose, angles, center, radius=BALL_RADIUS):
    """How the skin (a softhand_sim.handmodel.rigid_skin.RigidSkin) of the kinematic hand at
    palm_pose / angles (5, 4) meets a ball: dict of
    depth (2,) [m] deepest thumb / index distal-pad point inside the ball (negative: a gap);
    push (2, 3) unit direction from that point to the ball centre;
    facing (2,) cosine between that point's outward skin normal and its push direction;
    lift (2,): the push directions' part along the palm's dorsal axis (palm down: positive pushes
    the ball up, the pad is below its equator);
    grip_cos: cosine between the two push directions (-1: opposite ends of a diameter);
    others_gap [m]: smallest gap of every skin point off the thumb's and index's last two bones."""
    _, bones = forward_kinematics(palm_pose, angles)
    points, normals = skin.pose(bones)
    center = np.asarray(center, dtype=np.float64)
    gap = np.linalg.norm(points - center, axis=1) - radius
    depth, push, facing = np.empty(2), np.empty((2, 3)), np.empty(2)
    for k, digit in enumerate(PINCH_DIGITS):
        pad = skin.on_bones(digit[-1:])
        i = np.flatnonzero(pad)[np.argmin(gap[pad])]
        depth[k] = -gap[i]
        push[k] = (center - points[i]) / np.linalg.norm(center - points[i])
        facing[k] = normals[i] @ push[k]
    others = ~skin.on_bones(PINCH_DIGITS[0][1:] + PINCH_DIGITS[1][1:])
    dorsal = quat_to_matrix(np.asarray(palm_pose, dtype=np.float64)[3:])[:, 2]
    return {"depth": depth, "push": push, "facing": facing, "lift": push @ dorsal,
            "grip_cos": float(push[0] @ push[1]),
            "others_gap": float(gap[others].min())}


def smoothstep(u):
    """C1 ease 0 -> 1 of u clipped to [0, 1], zero slope at both ends (ramps of scripted motions)."""
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


class PinchLift:
    """The thumb-index pinch as a timed script [s] on the hand at rest (palm = world frame):

    0 .. T_CLOSE        the pads close from the open pre-shape to the squeeze;
    T_RELEASE           the ball's engine copy lets go (Eq. 14 stiffness to 0): the pads carry it;
    T_START .. T_LIFT   the palm rises LIFT [m] (smoothstep);
    T_LIFT .. T_HOLD    hold (5 s);
    T_HOLD .. T_OPEN    the pads open back to the pre-shape: the ball falls.
    """

    T_CLOSE, T_RELEASE, T_START, T_LIFT, T_HOLD, T_OPEN = 0.6, 1.0, 1.3, 2.3, 7.3, 7.8
    LIFT = 0.10  # [m]
    SETTLE_STEPS = 40

    def __init__(self, asset, squeeze=PINCH_SQUEEZE, friction=0.5):
        self.palm = np.asarray(asset.bone_rest_pose[0], dtype=np.float64)
        self.opened, touch, _ = pinch_angles()
        lo, hi = DIGIT_LIMITS[:, :, 0], DIGIT_LIMITS[:, :, 1]
        self.squeezed = np.clip(touch + squeeze * (touch - self.opened), lo, hi)
        centre = self.palm[:3] + quat_to_matrix(self.palm[3:]) @ PINCH_BALL_IN_PALM
        self.ball = dataclasses.replace(ball_object(centre), friction=float(friction))

    def digit_angles(self, t):
        """(5, 4) digit angles [rad] at time t."""
        if t < self.T_HOLD:
            return self.opened + smoothstep(t / self.T_CLOSE) * (self.squeezed - self.opened)
        return self.squeezed + smoothstep((t - self.T_HOLD) / (self.T_OPEN - self.T_HOLD)) * (self.opened - self.squeezed)

    def bone_targets(self, t):
        """(16, 7) intermediate-bone targets at time t."""
        palm = self.palm.copy()
        palm[2] += self.LIFT * smoothstep((t - self.T_START) / (self.T_LIFT - self.T_START))
        return forward_kinematics(palm, self.digit_angles(t))[1]

    def contact_system(self, model, asset):
        """The ContactSystem of the hand's skin and the ball, for Solver(model, contacts=...)."""
        return contact.build_contact_system(model, Scene(-1.0, self.ball.friction, (self.ball,)), asset)

    def attach(self, solver, state, control):
        """Settles the soft hand (solver built with `contact_system`) into the open pre-shape with
        the ball parked 0.5 m below, then puts the ball and its copy between the pads; returns the
        solver's ContactSystem."""
        model = solver.model
        ball_body = model.bone_count
        parked = self.ball.pose.copy()
        parked[2] -= 0.5
        state.set_body_pose(model, ball_body, parked)
        control.set_object_targets(model, parked[None])
        control.set_bone_targets(model, self.bone_targets(0.0))
        for _ in range(self.SETTLE_STEPS):
            solver.step(state, control, 0.01)
        state.set_body_pose(model, ball_body, self.ball.pose.copy())
        # the copy holds the ball m g / kx higher, so that the hand-side ball hangs where planned
        self.copy_pose = self.ball.pose.copy()
        gravity = np.asarray(model.params["gravity"], dtype=np.float64)
        self.copy_pose[:3] -= self.ball.mass * gravity / model.body_target_kx[ball_body]
        control.set_object_targets(model, self.copy_pose[None])
        return solver.contacts

    def drive(self, model, control, t, dt):
        """Set the targets of the step that starts at t (and let the ball go at T_RELEASE)."""
        if t <= self.T_RELEASE < t + dt:
            control.set_object_targets(model, self.copy_pose[None], kx=0.0, ktheta=0.0)
        control.set_bone_targets(model, self.bone_targets(t))


def sim_node_solver_params():
    """The solver parameters sim_node runs with (config/softhand.yaml): hand gravity off, the
    palm coupled at tracking_kx 500 N/m (see the yaml for why these depart from the paper)."""
    from softhand_sim.params import load_params
    return load_params("sim_node")


class PinchScenario:
    """`softhand bench --scenario grasp`: the PinchLift script from its first step, with
    sim_node's solver parameters (a firm grasp: ~240 skin contacts on the two pads once closed;
    300 steps reach the hold)."""

    def __init__(self):
        self.asset, self.script, self.system = None, None, None

    def params(self):
        return sim_node_solver_params()

    def objects(self, asset):
        """The model's rigid objects for this hand (remembers the asset for the skin points)."""
        if getattr(asset, "skin_triangles", None) is None:
            raise ValueError("the grasp scenario needs the hand model (--mesh coarse or fine), "
                             "not the box hand: its pinch pose is planned on the hand's skin")
        self.asset = asset
        self.script = PinchLift(asset)
        return [self.script.ball]

    def contacts(self, model):
        return self.script.contact_system(model, self.asset)

    def __call__(self, solver, state, control):
        self.system = self.script.attach(solver, state, control)

        def update(k, t):
            self.script.drive(solver.model, control, t, 0.01)
        return update
