"""Scripted two-hand scenarios on the whole simulation (issue #18), offline and deterministic.

Both hands are one SimRuntime (one Model, one Newton step + PCG per step: an object touched by
both hands is one body); the objects' engine side is the pybullet World of the same scene
(softhand_world.world, the world_node's class), exchanged in lockstep like commands/offline.py's
pipeline: after each sim step its object states become the world's copies (stamped with the
state time), after each world step its states become the sim's copies. The bone targets are
scripted (the tracking loop is left out), so a run is a pure function of the script.

- `Handover`: the right hand pinches the ball on the table (the pinch of scenarios/contact.py),
  lifts it, the left hand, coming from the other side, pinches it too, the right hand lets go,
  the left hand carries it HANDOVER_CARRY along +y and sets it down on the table.
- `TwoHandLift`: both palms (hands upright, fingers along +x, thumbs up) press the big box of
  the scene from its y ends, lift it LIFT, hold it HOLD, set it down and let go.

Left-hand targets are the mirror images (through the xz plane, docs/INTERFACE.md) of the right
kinematic hand's (handmodel.kinematics) at the mirrored palm pose: `left_bone_targets`.

`run(script)` returns a `BimanualResult` of per-step records; `two_hand_bench_scene` is the
two-hand grasp of `softhand bench --hands 2`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softhand_sim.handmodel.kinematics import forward_kinematics
from softhand_sim.physics.rotations import quat_to_matrix
from softhand_sim.scenarios.contact import PINCH_BALL_IN_PALM, pinch_angles
from softhand_sim.scenarios.tracker_bags import CAGE_SAG, Keyframes

S = np.diag([1.0, -1.0, 1.0])  # the mirror through the xz plane
S45 = float(np.sqrt(0.5))
PALM_DOWN = np.array([0.0, 0.0, 0.0, 1.0])
PALM_DOWN_FACING_BACK = np.array([0.0, 0.0, 1.0, 0.0])   # palm down, turned 180 deg about z
RIGHT_PALM_TO_PLUS_Y = np.array([S45, 0.0, 0.0, S45])    # +90 deg about x: palm faces +y, thumb up
LEFT_PALM_TO_MINUS_Y = np.array([-S45, 0.0, 0.0, S45])   # -90 deg about x: palm faces -y, thumb up


def mirror_poses(poses):
    """Poses (n,7) mirrored through the xz plane: y -> -y, R -> S R S, i.e. q -> (-x, y, -z, w)."""
    out = np.array(poses, dtype=np.float64, copy=True).reshape(-1, 7)
    out[:, 1] *= -1.0
    out[:, 3] *= -1.0
    out[:, 5] *= -1.0
    return out


def right_bone_targets(palm_pose, angles):
    """(16,7) right-hand bone targets: the kinematic hand at palm_pose (7,) with digit angles (5,4)."""
    return forward_kinematics(np.asarray(palm_pose, float), angles)[1]


def left_bone_targets(palm_pose, angles):
    """(16,7) left-hand bone targets at palm_pose (7,): the mirror of the right kinematic hand at
    the mirrored palm pose, with the same digit angles (flexion keeps its sign under the mirror)."""
    return mirror_poses(forward_kinematics(mirror_poses(palm_pose)[0], angles)[1])


def hand_joints(side, palm_pose, angles):
    """(26,7) OpenXR joint poses of the kinematic hand `side` at palm_pose (7,) with digit angles
    (5,4): what a tracker would report (the left hand mirrored as in left_bone_targets)."""
    if side == "right":
        return forward_kinematics(np.asarray(palm_pose, float), angles)[0]
    return mirror_poses(forward_kinematics(mirror_poses(palm_pose)[0], angles)[0])


def bone_targets(side, palm_pose, angles):
    """(16,7) bone targets of hand `side` (right_bone_targets / left_bone_targets)."""
    return (right_bone_targets if side == "right" else left_bone_targets)(palm_pose, angles)


def _smooth(u):
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


# ---------------------------------------------------------------------------- handover
HANDOVER_LIFT = 0.12      # [m] right wrist lift (the ball rises ~2 cm less: it hangs on the pads)
HANDOVER_CARRY = np.array([0.0, 0.20, 0.0])  # [m] where the left hand sets the ball down, from its start
LEFT_GRIP_BELOW = CAGE_SAG  # [m] the left grip aimed this far below the ball's centre, as the right
                            # hand's wrist is placed CAGE_SAG low: the pads close a little under the
                            # equator, and the ball settles onto them as the left hand takes its weight


class Handover:
    """Right pinch -> lift -> left pinch from the other side -> right opens -> left carries the
    ball HANDOVER_CARRY at the height it took it and lowers it onto the table -> opens. Times [s]
    in T; the left hand's grip is aimed at the ball where it actually hangs at T["left_aim"] (the
    script looks, as a user would).

    The carry is level, then straight down (l_carry0 -> l_over -> l_down), as a person sets a
    thing down, and the left grip is aimed LEFT_GRIP_BELOW under the ball's centre. The ball
    drops 1.3-1.7 cm when the left hand takes its weight (offline and through the nodes alike);
    with the grip aimed at the centre and a diagonal path down it slipped out of the left grip
    or met the table short of its spot and was dragged (through the nodes: 4.8-20.8 cm from the
    spot in 6 of 29 runs); lowered on the spot, hanging lower only sets it down sooner."""

    T = dict(r_down=1.5, r_touch=2.5, r_squeeze=3.0, r_lift0=3.3, r_lift1=4.8, left_aim=4.9,
             l_reach=6.2, l_touch=7.0, l_squeeze=7.4, r_open0=7.8, r_open1=8.6, r_away=9.6,
             l_carry0=9.0, l_over=10.8, l_down=11.6, l_open0=12.0, l_open1=12.8, l_away=13.8, end=14.3)

    def __init__(self, scene):
        self.ball0 = np.array(scene.object("ball").pose[:3], float)
        self.table_top = _table_top(scene)
        self.target = self.ball0 + HANDOVER_CARRY
        self.opened, self.touch, self.squeeze = pinch_angles()
        T = self.T
        wrist = self.ball0 - [0.0, 0.0, CAGE_SAG] - PINCH_BALL_IN_PALM
        up = wrist + [0.0, 0.0, HANDOVER_LIFT]
        away = up + [-0.10, 0.0, 0.05]
        o, t, s = self.opened, self.touch, self.squeeze
        rest = np.zeros((5, 4))  # the hand enters at rest; opening it at once would fold a tet
        self.right = (Keyframes().add(0.0, wrist + [0, 0, 0.08], rest).add(0.6, wrist + [0, 0, 0.08], o)
                      .add(T["r_down"], wrist, o)
                      .add(T["r_touch"], wrist, t).add(T["r_squeeze"], wrist, s).add(T["r_lift0"], wrist, s)
                      .add(T["r_lift1"], up, s).add(T["r_open0"], up, s).add(T["r_open1"], up, o)
                      .add(T["r_away"], away, o))
        self.left = None  # set by aim() at T["left_aim"]
        # until then the left hand waits, open, above the far side of the ball
        self._left_wait = self._left_palm(self.ball0 + [0.0, 0.0, HANDOVER_LIFT]) + [0.12, 0.0, 0.10]

    @staticmethod
    def _left_palm(centre):
        """Left wrist position that puts the ball centre at the mirrored pinch spot of its palm,
        the hand palm down and turned 180 deg about z (it comes from +x)."""
        in_palm = S @ PINCH_BALL_IN_PALM
        return np.asarray(centre, float) - quat_to_matrix(PALM_DOWN_FACING_BACK) @ in_palm

    def aim(self, ball_centre):
        """Plan the left hand's motion onto the ball hanging at ball_centre (3,) [m]."""
        T = self.T
        o, t, s = self.opened, self.touch, self.squeeze
        q = PALM_DOWN_FACING_BACK
        grip = self._left_palm(np.asarray(ball_centre, float) - [0.0, 0.0, LEFT_GRIP_BELOW])
        # set down: the ball centre one radius (+ the pads' sag) above the table at the target
        down = self._left_palm(self.target[:2].tolist() + [self.table_top + 0.04 + CAGE_SAG])
        self.left = (Keyframes().add(T["left_aim"], self._left_wait, o, q).add(T["l_reach"], grip, o, q)
                     .add(T["l_touch"], grip, t, q).add(T["l_squeeze"], grip, s, q)
                     .add(T["l_carry0"], grip, s, q).add(T["l_over"], np.r_[down[:2], grip[2]], s, q)
                     .add(T["l_down"], down, s, q)
                     .add(T["l_open0"], down, s, q).add(T["l_open1"], down, o, q)
                     .add(T["l_away"], down + [0.0, 0.0, 0.06], o, q))

    @property
    def duration(self):
        return self.T["end"]

    def poses(self, t):
        """{side: (palm pose (7,), digit angles (5,4))} of the hands at t (the left hand waits
        until it is aimed and T["left_aim"] has come)."""
        out = {"right": self.right(t)}
        if self.left is None or t < self.T["left_aim"]:
            out["left"] = (np.r_[self._left_wait, PALM_DOWN_FACING_BACK], self.opened * _smooth(t / 0.6))
        else:
            out["left"] = self.left(t)
        return out

    def targets(self, t, runtime):
        """{side: (16,7)} bone targets of the step starting at t."""
        if self.left is None and t >= self.T["left_aim"]:
            self.aim(runtime.state.object_pose[runtime.object_names.index("ball"), :3])
        return {side: bone_targets(side, *pose) for side, pose in self.poses(t).items()}


# ---------------------------------------------------------------------------- two-hand lift
LIFT = 0.12    # [m] palm lift; the box rises ~2.5 cm less: the palms' couplings sag under its
               # weight, carried twice (Sect. 3.7), and the grip settles ~1 cm as it takes the load
HOLD = 3.0     # [s]
PRESS = 0.10   # [m] each palm target this far inside the box face


class TwoHandLift:
    """Both hands upright (fingers along +x, thumbs up), palms toward the big box's y ends:
    approach, press PRESS, lift LIFT, hold HOLD, lower, let go. Times [s] in T."""

    T = dict(touch=1.0, press=1.6, lift0=2.0, lift1=3.5, hold1=6.5, lower1=8.0, release=8.8, end=9.5)
    # The paper's 170 N/m object coupling (sim_node object_kx = world_node coupling_kx) lets a
    # 0.6 kg box hang m g / kx = 3.5 cm below its engine copy and lag the palms by as much in a
    # lift; 1000 N/m (sqrt(k/m) = 41 rad/s, under the 45 rad/s cap) gives the ball's 6 mm sag.
    # Both sides must use the same value.
    SIM_OVERRIDES = {"object_kx": 1000.0}
    WORLD_OVERRIDES = {"coupling_kx": 1000.0}

    def __init__(self, scene, box="big_box", press=PRESS):
        o = scene.object(box)
        self.box = box
        self.centre = np.array(o.pose[:3], float)
        half = 0.5 * np.asarray(o.dims["size"], float)
        self.half = half
        self.press = press
        self.flat = np.zeros((5, 4))
        self.flat[0, 0] = np.deg2rad(20.0)   # thumb a little off the palm, along the face

    def _palms(self, gap, lift):
        """(right, left) palm poses (7,) with the palm surfaces `gap` [m] outside the box faces
        (negative: inside), the box lifted by `lift` [m]. The wrist is PALM_SURFACE below the
        palmar skin; fingers along +x with the palms' contact centre on the box's centre of mass
        (off it, the weight's torque about the palm normal turns the box between the palms: 31
        deg with the grip 7 cm off centre); the palm's middle at the box's mid height."""
        c = self.centre + [0.0, 0.0, lift]
        x0 = c[0] - PALM_GRIP_CENTRE
        z = c[2] + PALM_MID_OFFSET
        right = np.r_[x0, c[1] - self.half[1] - PALM_SURFACE - gap, z, RIGHT_PALM_TO_PLUS_Y]
        left = np.r_[x0, c[1] + self.half[1] + PALM_SURFACE + gap, z, LEFT_PALM_TO_MINUS_Y]
        return right, left

    @property
    def duration(self):
        return self.T["end"]

    def profile(self, t):
        """(gap [m], lift [m]) at time t."""
        T = self.T
        gap = 0.04 - (0.04 + self.press) * _smooth(t / T["press"]) \
            + (0.04 + self.press) * _smooth((t - T["lower1"]) / (T["release"] - T["lower1"]))
        lift = LIFT * (_smooth((t - T["lift0"]) / (T["lift1"] - T["lift0"]))
                       - _smooth((t - T["hold1"]) / (T["lower1"] - T["hold1"])))
        return gap, lift

    def poses(self, t):
        """{side: (palm pose (7,), digit angles (5,4))} of the hands at t."""
        gap, lift = self.profile(t)
        r, l = self._palms(gap, lift)
        return {"right": (r, self.flat), "left": (l, self.flat)}

    def targets(self, t, runtime=None):
        return {side: bone_targets(side, *pose) for side, pose in self.poses(t).items()}


PALM_GRIP_CENTRE = 0.03  # [m] the pressed palm's contact centre ahead of the wrist (measured)
PALM_SURFACE = 0.022     # [m] palmar skin below the wrist frame's origin (hand model, palm middle)
PALM_MID_OFFSET = 0.012  # [m] wrist above the box's mid height: the palm's ulnar edge clears the table


def _table_top(scene):
    table = scene.object("table")
    return float(table.pose[2] + 0.5 * table.dims["size"][2])


# ---------------------------------------------------------------------------- running
@dataclass
class BimanualResult:
    t: np.ndarray              # (n,) [s] state time
    obj_engine: np.ndarray     # (n,3) engine position of the scenario's object [m]
    obj_hand: np.ndarray       # (n,3) hand-side position [m]
    obj_in_palm: dict          # side -> (n,3) the engine object in that hand's palm frame [m]
    contacts: dict             # side -> (n,) active contacts of that hand with the object
    min_tet_volume: np.ndarray  # (n,) smallest signed tet volume over both hands [m^3]
    finite: bool
    rejected_steps: int
    cg_iters: np.ndarray


def _signed_volumes(x, tets):
    a = x[tets[:, 1]] - x[tets[:, 0]]
    b = x[tets[:, 2]] - x[tets[:, 0]]
    c = x[tets[:, 3]] - x[tets[:, 0]]
    return np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0


def make_runtime(sim_overrides=None, scene=None, world_overrides=None):
    """The two-hand SimRuntime and pybullet World of the scene with the nodes' default parameters."""
    from softhand_sim.params import load_params
    from softhand_sim.runtime import SimRuntime
    from softhand_sim.scene import load_scene
    from softhand_world.world import World, WorldConfig

    sp = load_params("sim_node", overrides={"hands": ["right", "left"], **(sim_overrides or {})})
    wp = load_params("world_node", overrides=world_overrides)
    scene = scene if scene is not None else load_scene(sp["scene_file"] or None)
    runtime = SimRuntime(sp, scene=scene)
    world = World(scene, WorldConfig(
        engine_rate=wp["engine_rate"], coupling_kx=wp["coupling_kx"], coupling_ktheta=wp["coupling_ktheta"],
        copy_timeout=wp["copy_timeout"], extrapolate=wp["extrapolate"], coupling_damping=wp["coupling_damping"],
        coupling_mode=wp["coupling_mode"], coupling_max_omega=wp["coupling_max_omega"], gravity=wp["gravity"]),
        start_time=0.0)
    return runtime, world


def run(script_cls, obj, sim_overrides=None, until=None, progress=None, world_overrides=None):
    """Run a script (Handover / TwoHandLift class) on the two-hand runtime + world in lockstep;
    records the object `obj` (a dynamic object name). The script's SIM_OVERRIDES /
    WORLD_OVERRIDES (if any) come first. Returns BimanualResult."""
    runtime, world = make_runtime({**getattr(script_cls, "SIM_OVERRIDES", {}), **(sim_overrides or {})},
                                  world_overrides={**getattr(script_cls, "WORLD_OVERRIDES", {}),
                                                   **(world_overrides or {})})
    script = script_cls(runtime.scene)
    dt = 1.0 / runtime.params["sim_rate"]
    end = script.duration if until is None else float(until)
    body = runtime.object_names.index(obj)
    cobj = list(runtime.contacts.model.object_names).index(obj)
    wobj = world.object_index(obj)
    tets = runtime.model.tets
    rec = {k: [] for k in ("t", "oe", "oh", "pr", "pl", "cr", "cl", "vol", "cg")}
    finite = True
    k = 0
    try:
        while k * dt < end - 1e-9:
            t = k * dt
            for side, poses in script.targets(t, runtime).items():
                runtime.set_bone_targets(poses, t, hand=side)
            out = runtime.step(dt, t)
            for j, name in enumerate(out.object_names):
                world.set_copy(name, out.object_poses[j], out.object_twists[j], out.object_accels[j], out.t)
            while world.time < out.t - 1e-9:
                world.step()
                ws = world.states()
                runtime.set_object_copies(list(ws.names), ws.pose, ws.twist, ws.accel, ws.stamp)
            ws = world.states()
            finite &= bool(np.all(np.isfinite(out.node_x)))
            rec["t"].append(out.t)
            rec["oe"].append(ws.pose[wobj, :3].copy())
            rec["oh"].append(out.object_poses[body, :3].copy())
            for side, key in (("right", "pr"), ("left", "pl")):
                palm = out.hands[side].bone_poses[0]
                rec[key].append(quat_to_matrix(palm[3:]).T @ (ws.pose[wobj, :3] - palm[:3]))
            c = out.contacts
            on = c["objects"] == cobj
            rec["cr"].append(int(np.sum(on & (c["hand"] == 0))))
            rec["cl"].append(int(np.sum(on & (c["hand"] == 1))))
            rec["vol"].append(float(_signed_volumes(out.node_x, tets).min()))
            rec["cg"].append(out.stats.cg_iters)
            if progress is not None:
                progress(out, rec)
            k += 1
    finally:
        world.close()
    a = {key: np.asarray(v) for key, v in rec.items()}
    return BimanualResult(t=a["t"], obj_engine=a["oe"], obj_hand=a["oh"],
                          obj_in_palm={"right": a["pr"], "left": a["pl"]},
                          contacts={"right": a["cr"], "left": a["cl"]}, min_tet_volume=a["vol"],
                          finite=finite, rejected_steps=runtime.rejected_steps, cg_iters=a["cg"])


# ---------------------------------------------------------------------------- tracker bags
BAG_RATE = 100.0  # [Hz] tracker frames of the two-hand bags (both hands, like the sample bags)


def handover_aim(progress=None):
    """Where the ball hangs in the right hand at Handover.T["left_aim"], from an offline run of the
    script up to then (the left hand of a bag cannot look: its motion is planned on this)."""
    seen = []
    run(Handover, "ball", until=Handover.T["left_aim"] + 1e-6,
        progress=lambda out, rec: (seen.append(rec["oh"][-1].copy()), progress and progress(out)))
    return seen[-1]


def tracker_frames(name, noise=True, aim=None, position_noise=None):
    """{side: (stamps_ns (n,) int64, joints (n, 26, 7))} of the two-hand bag `name` ('handover',
    'two_hand_lift'): each hand's joints at BAG_RATE with the sample bags' timing jitter and
    position noise (tracker_bags.sample's, seeded per hand; `position_noise` [m] instead of
    POSITION_NOISE when given). aim: the handover's ball position for the left grip
    (handover_aim() when None)."""
    from softhand_sim.scenarios.tracker_bags import STAMP0_NS, TIMING_JITTER, noise_of
    from softhand_sim.scene import load_scene

    scene = load_scene()
    if name == "handover":
        script = Handover(scene)
        script.aim(handover_aim() if aim is None else np.asarray(aim, float))
    elif name == "two_hand_lift":
        script = TwoHandLift(scene)
    else:
        raise ValueError(f"unknown two-hand bag {name!r}; known: {', '.join(TWO_HAND_BAGS)}")
    out = {}
    for k, side in enumerate(("right", "left")):
        rng = np.random.default_rng(100 + 10 * list(TWO_HAND_BAGS).index(name) + k)
        count = int(np.floor(script.duration * BAG_RATE)) + 1
        times = np.arange(count) / BAG_RATE + rng.uniform(-TIMING_JITTER, TIMING_JITTER, count)
        times[0] = 0.0
        times = np.clip(times, 0.0, script.duration)
        joints = np.stack([hand_joints(side, *script.poses(t)[side]) for t in times])
        if noise:
            joints[:, :, :3] += rng.normal(0.0, noise_of(None, position_noise), size=joints[:, :, :3].shape)
        out[side] = (STAMP0_NS + np.round(times * 1e9).astype(np.int64), joints)
    return out


#: The longest step two hands take to keep real time (sim_node max_step): one sim_node steps two
#: coarse hands in 16-30 ms on two shared cores, so 60 Hz is out of reach in the demo; both scenes
#: hold offline down to 12 steps/s (handover: ball 2.4 mm from its spot; lift: 0.6 mm slip).
TWO_HAND_MAX_STEP = 1.0 / 15.0

#: two-hand bags of bags/ (tools/make_bags.py) -> the sim_node / world_node parameters they need
#: (written beside the bag as params.yaml; `softhand demo` uses it): both keep real time with
#: longer steps; the big box needs the stiffer object coupling of TwoHandLift.
TWO_HAND_BAGS = {
    "handover": {"sim_node": {"max_step": TWO_HAND_MAX_STEP}},
    "two_hand_lift": {"sim_node": {**TwoHandLift.SIM_OVERRIDES, "max_step": TWO_HAND_MAX_STEP},
                      "world_node": TwoHandLift.WORLD_OVERRIDES},
}
