"""A kinematic right hand: palm pose + digit angles -> 26 OpenXR joints and 16 bone poses.

Used to synthesise the sample tracker bags (softhand_sim.scenarios.tracker_bags), to script bone targets
of grasps on the solver (contact_scenarios: the thumb-index pinch) and, independently of the
tracking adapter's inverse, as ground truth for the adapter tests. Rest pose as the hand model's (ARCHITECTURE.md):
palm down (dorsal +z), fingers along +x, thumb toward +y, wrist joint at the palm frame origin.

Joint model (the one `adapter` assumes when it reads the twist of the fingers):
  digit base (finger MCP, thumb CMC): R_base * Rz(abduction) * Ry(flex_1)
  middle and distal joints: hinges Ry(flex_2), Ry(flex_3) about the same (flexed) y axis (thumb:
  after its rest turn, `HandDims.rest_rel`). Thumb bone frames follow the hand model's rule
  (`thumb_frame`), as the adapter's do.
Positive flexion curls the digit toward the palm (-z), as ARCHITECTURE.md fixes.

Dimensions: those of the hand model's defaults (softhand_sim.handmodel.measures.HandMeasures:
wrist to middle fingertip 0.19 m, palm width 0.085 m). `DIGIT_LIMITS` are the angle ranges the
bags respect (within the hand model's joint limits).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from numba import njit

from softhand_sim.physics.rotations import cross, matrix_to_quat, quat_to_matrix
from softhand_sim.handmodel.skeleton import THUMB_PRONATION_DEG
from softhand_sim.handmodel.skeleton_names import BONE_COUNT, JOINT_INDEX, OPENXR_JOINT_COUNT

# Thumb frames follow the hand model's own rule (thumb_frame): its pronation angle.
_COS_PRONATION = float(np.cos(np.deg2rad(THUMB_PRONATION_DEG)))
_SIN_PRONATION = float(np.sin(np.deg2rad(THUMB_PRONATION_DEG)))
_THUMB_RADIAL_BLEND = 0.3  # |z_palm × x| below this: bone within 17° of the palm normal
DIGITS = ("THUMB", "INDEX", "MIDDLE", "RING", "LITTLE")
# Joint limits [rad] of (abduction, flex_1, flex_2, flex_3) per digit: rows (min, max); inside
# the hand model's (softhand_sim.handmodel.skeleton LIMITS_*).
DIGIT_LIMITS = np.deg2rad(np.array([
    [[-28, 34], [-20, 45], [-8, 57], [-20, 80]],      # thumb: CMC abd / CMC flex / MCP / IP
    [[-20, 20], [-20, 90], [0, 100], [0, 80]],        # fingers: MCP abd / MCP / PIP / DIP
    [[-20, 20], [-20, 90], [0, 100], [0, 80]],
    [[-20, 20], [-20, 90], [0, 100], [0, 80]],
    [[-20, 20], [-20, 90], [0, 100], [0, 80]],
]))


def _rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rot_y(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


@njit(cache=True)
def thumb_frame(x, z_palm, flex_axis, s=1.0):
    """Thumb bone frame (3, 3) with x (unit) along the bone: the hand model's rule (skeleton.thumb_layout),
    z = cos(b) z_palm + sin(b) r, r = unit(side * z_palm × x) the radial direction, b the thumb's
    pronation, made orthogonal to x. Exact for the hand model's rest thumb. Where the bone points
    along the palm normal (|z_palm × x| < _THUMB_RADIAL_BLEND) the hint of the digit's flexion
    axis, x × a, is blended in so the frame stays defined. s: +1 right hand, -1 left (mirrored).
    Shared by the adapter (frames from tracked joints) and this kinematic hand (ground truth)."""
    radial = s * cross(z_palm, x)
    rn = np.linalg.norm(radial)
    hint = _COS_PRONATION * z_palm + _SIN_PRONATION * radial / max(rn, _THUMB_RADIAL_BLEND)
    if rn < _THUMB_RADIAL_BLEND:
        fallback = cross(x, flex_axis)
        hint = hint + (_THUMB_RADIAL_BLEND - rn) / _THUMB_RADIAL_BLEND * fallback / max(np.linalg.norm(fallback), 1e-12)
    z = hint - np.dot(hint, x) * x
    z /= np.linalg.norm(z)
    frame = np.empty((3, 3))
    frame[:, 0] = x
    frame[:, 1] = cross(z, x)
    frame[:, 2] = z
    return frame



@dataclass(frozen=True)
class HandDims:
    """Bone lengths and digit bases of the kinematic hand [m].

    palm_length: wrist -> middle knuckle. digit_base (5, 3): base joint of each digit in the palm
    frame (thumb: CMC = THUMB_METACARPAL joint; fingers: knuckle = F_PROXIMAL joint).
    digit_base_rot (5, 3, 3): rest orientation of each digit's first bone in the palm frame.
    phalanx_length (5, 3): the digit's three bones (thumb: metacarpal, proximal, distal).
    rest_rel (5, 2, 3, 3): rest rotation of bone k+1 relative to bone k (the hand model's thumb
    turns a little at its MCP and IP at rest; identity for the fingers).
    """

    palm_length: float
    digit_base: np.ndarray
    digit_base_rot: np.ndarray
    phalanx_length: np.ndarray
    rest_rel: np.ndarray

    @classmethod
    def from_measures(cls, measures=None):
        """The hand model's rest skeleton (softhand_sim.handmodel, default HandMeasures): same
        palm length, knuckle layout and finger fan, thumb CMC and rest thumb frames, bone lengths."""
        from softhand_sim.handmodel.measures import HandMeasures
        from softhand_sim.handmodel.skeleton import finger_base_layout, thumb_layout
        from softhand_sim.physics.rotations import quat_from_axes
        m = HandMeasures() if measures is None else measures
        layout = finger_base_layout(m)
        cmc, thumb_dirs = thumb_layout(m)
        bases = [cmc] + [layout[f][0] for f in ("index", "middle", "ring", "little")]
        thumb_rots = [quat_to_matrix(quat_from_axes(d, z)) for d, z in thumb_dirs]
        rots = [thumb_rots[0]]
        rest_rel = np.tile(np.eye(3), (5, 2, 1, 1))
        rest_rel[0, 0] = thumb_rots[0].T @ thumb_rots[1]
        rest_rel[0, 1] = thumb_rots[1].T @ thumb_rots[2]
        for f in ("index", "middle", "ring", "little"):
            d = layout[f][1]
            rots.append(_rot_z(np.arctan2(d[1], d[0])))
        lengths = [m.finger_lengths(f) for f in ("thumb", "index", "middle", "ring", "little")]
        return cls(float(m.palm_length), np.array(bases, dtype=float), np.array(rots),
                   np.array(lengths, dtype=float), rest_rel)

    def digit_base_rotation(self, d: int) -> np.ndarray:
        """Rest orientation of digit d's first bone in the palm frame (3, 3)."""
        return self.digit_base_rot[d]

    def abduction_axes(self) -> np.ndarray:
        """(5, 3) unit abduction axis of each digit's base joint in the palm frame (R_base z)."""
        return np.stack([self.digit_base_rotation(d)[:, 2] for d in range(5)])


@functools.cache
def default_dims() -> HandDims:
    """The default hand model's dimensions, built on first use (building them takes ~1 s)."""
    return HandDims.from_measures()


def digit_rotations(dims: HandDims, d: int, angles) -> np.ndarray:
    """Orientations (3, 3, 3) in the palm frame of digit d's three bones for angles (4,) [rad]."""
    abd, f1, f2, f3 = angles
    r1 = dims.digit_base_rotation(d) @ _rot_z(abd) @ _rot_y(f1)
    r2 = r1 @ dims.rest_rel[d, 0] @ _rot_y(f2)
    r3 = r2 @ dims.rest_rel[d, 1] @ _rot_y(f3)
    return np.stack((r1, r2, r3))


def forward_kinematics(palm_pose, digit_angles, dims: HandDims | None = None):
    """Joint poses (26, 7) and bone poses (16, 7) of the hand, world frame.

    palm_pose (7,): world pose of the palm frame (origin at the wrist joint) [m, quat x y z w].
    digit_angles (5, 4): per digit (thumb..little) abduction, flex_1, flex_2, flex_3 [rad].
    Joint orientations are those of the bone that starts at the joint (tips: the distal bone's;
    WRIST, PALM and the metacarpal joints of the fingers: the palm's).
    """
    dims = default_dims() if dims is None else dims
    palm_pose = np.asarray(palm_pose, dtype=np.float64)
    angles = np.asarray(digit_angles, dtype=np.float64).reshape(5, 4)
    r_palm = quat_to_matrix(palm_pose[3:].copy())
    origin = palm_pose[:3]
    joint_pos = np.zeros((OPENXR_JOINT_COUNT, 3))
    joint_rot = np.zeros((OPENXR_JOINT_COUNT, 3, 3))
    bone_pos = np.zeros((BONE_COUNT, 3))
    bone_rot = np.zeros((BONE_COUNT, 3, 3))

    def world(p_local):
        return origin + r_palm @ p_local

    bone_pos[0], bone_rot[0] = origin, r_palm
    for name, local in (("WRIST", np.zeros(3)), ("PALM", np.array([0.5 * dims.palm_length, 0.0, 0.0]))):
        joint_pos[JOINT_INDEX[name]], joint_rot[JOINT_INDEX[name]] = world(local), r_palm
    for d, digit in enumerate(DIGITS):
        rots = r_palm @ digit_rotations(dims, d, angles[d])
        lengths = dims.phalanx_length[d]
        p = world(dims.digit_base[d])
        names = (["METACARPAL", "PROXIMAL", "DISTAL", "TIP"] if d == 0
                 else ["PROXIMAL", "INTERMEDIATE", "DISTAL", "TIP"])
        first_bone = 1 + 3 * d
        for k in range(3):
            frame = thumb_frame(rots[k][:, 0], r_palm[:, 2], rots[k][:, 1]) if d == 0 else rots[k]
            bone_pos[first_bone + k], bone_rot[first_bone + k] = p, frame
            joint_pos[JOINT_INDEX[f"{digit}_{names[k]}"]] = p
            joint_rot[JOINT_INDEX[f"{digit}_{names[k]}"]] = frame
            p = p + lengths[k] * rots[k][:, 0]
        joint_pos[JOINT_INDEX[f"{digit}_TIP"]], joint_rot[JOINT_INDEX[f"{digit}_TIP"]] = p, frame
        if d > 0:  # finger metacarpal joint: on the wrist side, a third of the way to the knuckle
            base = dims.digit_base[d]
            joint_pos[JOINT_INDEX[f"{digit}_METACARPAL"]] = world(np.array([0.3 * base[0], 0.6 * base[1], 0.0]))
            joint_rot[JOINT_INDEX[f"{digit}_METACARPAL"]] = r_palm

    joints = np.empty((OPENXR_JOINT_COUNT, 7))
    bones = np.empty((BONE_COUNT, 7))
    joints[:, :3], bones[:, :3] = joint_pos, bone_pos
    for j in range(OPENXR_JOINT_COUNT):
        joints[j, 3:] = matrix_to_quat(joint_rot[j])
    for b in range(BONE_COUNT):
        bones[b, 3:] = matrix_to_quat(bone_rot[b])
    return joints, bones
