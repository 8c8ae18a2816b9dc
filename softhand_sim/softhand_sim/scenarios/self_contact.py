"""Scripted self-contact scenarios on the hand model (issue #21): a thumb-index pinch of the pads
pressed 5 mm beyond contact and a tight fist (the fingers curl 1 cm beyond touching the palm);
on sim_node's runtime, a tight tip pinch (`runtime_tip_pinch`) and two hands pressed palm to palm
(`PalmsPressed`, `run_palms_pressed`).

Poses are found on the kinematic hand (handmodel.kinematics.forward_kinematics) with each skin
point carried rigidly by its segment's bone and measured against the other segment's rest field
(the SelfContactModel's grids): `rigid_overlap` is how deep [m] the skin of one group of segments
would sink into another if nothing gave. `press` finds, along a one-parameter closing motion, the
parameter where that overlap first reaches a depth (0 = touching). The soft hand is then driven
there through its bone targets (Control.set_bone_targets) and held.
"""
from __future__ import annotations

import numpy as np

from softhand_sim.handmodel.kinematics import DIGIT_LIMITS, forward_kinematics
from softhand_sim.physics.contact import sdf
from softhand_sim.physics.rotations import quat_to_matrix
from softhand_sim.scenarios.contact import pinch_angles, smoothstep

THUMB_DISTAL, INDEX_DISTAL, PALM = 3, 6, 0
FINGER_SEGMENTS = tuple(range(4, 16))   # index .. little, all three phalanxes
PINCH_PRESS = 0.005   # [m] pads pressed beyond touching (rigid overlap)
FIST_PRESS = 0.010    # [m] fingers curled beyond touching the palm


def rigid_overlap(smodel, bone_poses, points_from, into):
    """Deepest [m] rigid overlap of the skin points of segments `points_from` inside the rest
    field of any segment in `into` (positive: inside; negative: the smallest gap) with the bones
    at bone_poses (16,7), each point carried rigidly by its own bone."""
    R = np.array([quat_to_matrix(q) for q in bone_poses[:, 3:]])
    deepest = -np.inf
    for s in points_from:
        own = np.flatnonzero(smodel.point_segment == s)
        local = (smodel.point_rest[own] - smodel.seg_rest_o[s]) @ smodel.seg_rest_R[s]
        world = local @ R[s].T + bone_poses[s, :3]
        for t in into:
            if t == s or not smodel.pair_ok[s, t]:
                continue
            a0, a1 = smodel.grid_adr[t]
            g = sdf.DistanceGrid(smodel.grid_origin[t], smodel.grid_voxel[t], smodel.grid_dims[t],
                                 smodel.grid_values[a0:a1])
            d, _ = g.query((world - bone_poses[t, :3]) @ R[t])
            deepest = max(deepest, float(-d.min()))
    return deepest


def press(smodel, palm_pose, angles_of, points_from, into, depth, lo=0.0, hi=1.0, iters=30):
    """The parameter u in [lo, hi] where rigid_overlap of angles_of(u) reaches depth [m]
    (bisection; the overlap grows with u). Returns hi when it never does."""
    def overlap(u):
        return rigid_overlap(smodel, forward_kinematics(palm_pose, angles_of(u))[1], points_from, into)
    if overlap(hi) < depth:
        return hi
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        if overlap(mid) < depth:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def pad_centre(smodel, segment, bone_pose):
    """World centre [m] of a distal segment's pad (its palmar, -z, skin in the distal half) with
    the bone at bone_pose (7,)."""
    own = np.flatnonzero(smodel.point_segment == segment)
    local = (smodel.point_rest[own] - smodel.seg_rest_o[segment]) @ smodel.seg_rest_R[segment]
    pad = local[(local[:, 2] < local[:, 2].min() + 0.003) & (local[:, 0] > np.median(local[:, 0]))]
    return bone_pose[:3] + quat_to_matrix(bone_pose[3:]) @ pad.mean(axis=0)


def pads_meeting_angles(smodel, palm_pose):
    """Thumb and index angles (5, 4) [rad] (others straight) that bring the two distal pads'
    centres together: a bounded least-squares search from the ball pinch's touch pose
    (contact.pinch_angles), penalising every other pair of the two digits' segments overlapping."""
    from scipy.optimize import minimize
    _, touch, _ = pinch_angles()
    lo, hi = DIGIT_LIMITS[:2, :, 0].ravel(), DIGIT_LIMITS[:2, :, 1].ravel()

    def angles(z):
        a = np.zeros((5, 4))
        a[:2] = z.reshape(2, 4)
        return a

    def cost(z):
        bones = forward_kinematics(palm_pose, angles(z))[1]
        d = pad_centre(smodel, THUMB_DISTAL, bones[THUMB_DISTAL]) - pad_centre(smodel, INDEX_DISTAL, bones[INDEX_DISTAL])
        return float(d @ d)
    z = minimize(cost, touch[:2].ravel(), bounds=list(zip(lo, hi)), method="L-BFGS-B").x
    return angles(z)


class PadPinch:
    """Thumb and index pads pressed together (no object): from the open pre-shape of the ball
    pinch (contact.pinch_angles) toward the pose whose pad centres meet (pads_meeting_angles),
    angles = open + u (meet - open), stopped where the distal pads' rigid overlap reaches
    `depth` [m] (PINCH_PRESS: 5 mm beyond touching). The script closes over T_CLOSE [s] and holds."""

    T_CLOSE = 0.5

    def __init__(self, asset, smodel, depth=PINCH_PRESS):
        self.palm = np.asarray(asset.bone_rest_pose[0], dtype=np.float64)
        self.opened = pinch_angles()[0]
        meet = pads_meeting_angles(smodel, self.palm)

        def angles(u):
            return self.opened + u * (meet - self.opened)
        self.angles_of = angles
        pads, into = (THUMB_DISTAL,), (INDEX_DISTAL,)
        self.u_touch = press(smodel, self.palm, angles, pads, into, 0.0)
        self.u_press = press(smodel, self.palm, angles, pads, into, depth)
        self.pressed = angles(self.u_press)
        self.overlap = rigid_overlap(smodel, forward_kinematics(self.palm, self.pressed)[1], pads, into)

    def digit_angles(self, t):
        return self.opened + smoothstep(t / self.T_CLOSE) * (self.pressed - self.opened)

    def bone_targets(self, t):
        return forward_kinematics(self.palm, self.digit_angles(t))[1]


class Fist:
    """The four fingers curl together (every flexion of index..little at u times its upper
    limit, thumb straight) until they touch the palm (u_touch ~ 0.98), then the knuckles (MCP
    flexion of the four fingers) turn on by `extra` [rad] until the fingers' rigid overlap with
    the palm reaches `depth` [m] (FIST_PRESS): 1 cm beyond touching. Those targets lie beyond the
    knuckles' DIGIT_LIMITS (the tracked hand may ask that; the joint-limit penalty and the
    contact resist). Closes over T_CLOSE [s] and holds."""

    T_CLOSE = 0.6

    def __init__(self, asset, smodel, depth=FIST_PRESS):
        self.palm = np.asarray(asset.bone_rest_pose[0], dtype=np.float64)
        hi = DIGIT_LIMITS[:, :, 1]

        def curl(u):
            a = np.zeros((5, 4))
            a[1:, 1:] = u * hi[1:, 1:]
            return a
        self.u_touch = press(smodel, self.palm, curl, FINGER_SEGMENTS, (PALM,), 0.0)
        touch = curl(self.u_touch)

        def angles(extra):
            a = touch.copy()
            a[1:, 1] += extra
            return a
        self.angles_of = angles
        self.u_press = press(smodel, self.palm, angles, FINGER_SEGMENTS, (PALM,), depth, 0.0, 1.0)
        self.pressed = angles(self.u_press)
        self.overlap = rigid_overlap(smodel, forward_kinematics(self.palm, self.pressed)[1],
                                     FINGER_SEGMENTS, (PALM,))

    def digit_angles(self, t):
        return smoothstep(t / self.T_CLOSE) * self.pressed

    def bone_targets(self, t):
        return forward_kinematics(self.palm, self.digit_angles(t))[1]


def run(solver, state, control, script, seconds, dt=1.0 / 60.0, on_step=None):
    """Drives the solver with script.bone_targets for `seconds`; returns the last StepStats and
    the largest self-contact force seen [N] (sum over contacts of |f|)."""
    model = solver.model
    steps = int(round(seconds / dt))
    stats = None
    for k in range(steps):
        control.set_bone_targets(model, script.bone_targets(k * dt))
        stats = solver.step(state, control, dt)
        if on_step is not None:
            on_step(k, stats)
    return stats


def _surfaces_and_points(smodel, node_x, tets, triangles, surfaces=None):
    """(SegmentSurfaces, skin points (P,3) embedded in the current tets) for the measures below."""
    from softhand_sim.physics.contact.penetration import SegmentSurfaces
    from softhand_sim.physics.embedded import embedded_positions
    surfaces = surfaces or SegmentSurfaces(smodel, triangles)
    x = np.zeros((smodel.point_count, 3))
    embedded_positions(node_x, tets, smodel.point_tet, smodel.point_bary, x)
    return surfaces, x


def skin_penetration(smodel, node_x, tets, triangles, surfaces=None):
    """Deepest [m] skin point inside another segment it may touch, measured on the deformed skin
    without the contact list (physics/contact/penetration.py: inside by the winding number of the
    other segment's closed skin, depth = distance to the nearest skin it may touch). Returns
    (depth, point, segment, points inside); surfaces: a SegmentSurfaces to reuse."""
    surfaces, x = _surfaces_and_points(smodel, node_x, tets, triangles, surfaces)
    return surfaces.deepest(x)


def uncaught_penetration(smodel, node_x, tets, triangles, contact_points, surfaces=None):
    """Deepest [m] skin point inside another segment it may touch (as skin_penetration) that is
    not among contact_points (the points of the self-contact system's contact list, its
    output()["point"]): skin the method has not caught at this moment (0.0 when none). The rest
    field decides which points are candidates, so skin that bulged out is caught late."""
    surfaces, x = _surfaces_and_points(smodel, node_x, tets, triangles, surfaces)
    points, depths, _nearest = surfaces.inside(x)
    missed = depths[~np.isin(points, np.asarray(contact_points))]
    return float(missed.max()) if len(missed) else 0.0


def runtime_tip_pinch(self_contact: bool, tip_gap: float = 0.002, steps: int = 90, dt: float = 1.0 / 60.0):
    """sim_node's runtime (SimRuntime, the default hand, sim_node's parameters with
    `self_contact`) driven through its bone targets from the open hand above the table into a tip
    pinch whose tracked tips are `tip_gap` [m] apart (2 mm: the pads, ~2 x 8 mm thick, overlap),
    over 45 steps, then held. Returns (runtime, the last step's output)."""
    from softhand_sim.handmodel.measures import HandMeasures
    from softhand_sim.params import load_params
    from softhand_sim.runtime import SimRuntime
    from softhand_sim.scenarios.tracker_bags import OPEN_ANGLES, PALM_DOWN, tip_pinch_angles
    from softhand_tracking.adapter import TrackerAdapter

    rt = SimRuntime(load_params("sim_node", overrides={"self_contact": self_contact}))
    adapter = TrackerAdapter()
    pinch = tip_pinch_angles(HandMeasures(), tip_gap)
    palm = np.r_[0.1, 0.2, 0.95, PALM_DOWN]
    out = None
    for k in range(steps):
        u = min(1.0, k / 45.0)
        joints, _ = forward_kinematics(palm, OPEN_ANGLES + u * (pinch - OPEN_ANGLES))
        rt.set_bone_targets(adapter.convert(joints[:, :3]), k * dt)
        out = rt.step(dt, k * dt)
        if out is None or out.rejected:
            raise RuntimeError(f"pinch step {k} not taken: {out.warning if out else 'no output'}")
    return rt, out


class PalmsPressed:
    """Two hands pressed palm to palm in the air (as in prayer), the tracked hands driven about
    2.7 cm into each other (issue #21 asks for 2 cm), then apart: both hands upright (fingers along +x, thumbs up and in the palm plane), mirror
    images through the plane y = centre's y. `gap` [m] is each tracked palm surface's distance
    outside that plane (bimanual.PALM_SURFACE below the wrist): START apart, PRESS inside, START
    again. The skin meets at a gap of about +3.5 mm (the palms' padding), so PRESS = -10 mm
    drives the tracked hands about 2.7 cm into each other. Times [s] in T."""

    T = dict(approach0=0.3, approach1=1.3, part0=2.3, part1=3.3, end=4.0)
    START, PRESS = 0.015, -0.010
    FLAT = np.zeros((5, 4))  # open hands, thumbs in the palm plane (abducted thumbs would cross each other)

    def __init__(self, centre):
        self.centre = np.asarray(centre, dtype=np.float64)

    @property
    def duration(self):
        return self.T["end"]

    def gap(self, t):
        T, travel = self.T, self.START - self.PRESS
        return (self.START - travel * smoothstep((t - T["approach0"]) / (T["approach1"] - T["approach0"]))
                + travel * smoothstep((t - T["part0"]) / (T["part1"] - T["part0"])))

    def palms(self, t):
        """{side: palm (wrist) pose (7,)} at time t."""
        from softhand_sim.scenarios.bimanual import LEFT_PALM_TO_MINUS_Y, PALM_SURFACE, RIGHT_PALM_TO_PLUS_Y
        x, y, z = self.centre
        off = PALM_SURFACE + self.gap(t)
        return {"right": np.r_[x, y - off, z, RIGHT_PALM_TO_PLUS_Y], "left": np.r_[x, y + off, z, LEFT_PALM_TO_MINUS_Y]}

    def targets(self, t, runtime=None):
        from softhand_sim.scenarios.bimanual import bone_targets
        return {side: bone_targets(side, palm, self.FLAT) for side, palm in self.palms(t).items()}


def run_palms_pressed(dt: float = 1.0 / 60.0, height: float = 0.30):
    """PalmsPressed on sim_node's two-hand runtime with self contact, `height` [m] above the
    scene's table (clear of its objects). Per step: {t, gap (tracked), contacts between the hands,
    within one hand, deepest [m] skin point under the other hand's skin, force [N] the left hand
    pushes the right with, wrist distance [m], smallest signed tet volume [m^3], finite,
    penetration [m] (skin_penetration, every 4th step, else None)}."""
    from softhand_sim.params import load_params
    from softhand_sim.runtime import SimRuntime
    from softhand_sim.scenarios.bimanual import _signed_volumes, _table_top
    from softhand_sim.topics import SKIN_OBJECT

    from softhand_sim.physics.contact.penetration import SegmentSurfaces
    from softhand_sim.physics.hands import union_asset

    rt = SimRuntime(load_params("sim_node", overrides={"hands": ["right", "left"], "self_contact": True}))
    script = PalmsPressed([0.0, 0.0, _table_top(rt.scene) + height])
    smodel = rt.self_contact.system.model
    surfaces = SegmentSurfaces(smodel, union_asset(rt.hand_assets).skin_triangles)
    rows = []
    for k in range(int(round(script.duration / dt))):
        t = k * dt
        for side, poses in script.targets(t).items():
            rt.set_bone_targets(poses, t, hand=side)
        out = rt.step(dt, t)
        if out is None or out.rejected:
            raise RuntimeError(f"palms pressed: step {k} not taken: {out.warning if out else 'no output'}")
        c = out.contacts
        skin = c["objects"] == SKIN_OBJECT
        between = skin & (c["other_hand"] != c["hand"])
        # a contact's force acts on its point's skin, its reaction on the other hand's: the net push
        # on the right hand (at -y) from the left
        push = c["forces"][between & (c["hand"] == 0)].sum(axis=0) - c["forces"][between & (c["hand"] == 1)].sum(axis=0)
        rows.append({"t": t, "gap": script.gap(t), "between": int(between.sum()), "within": int((skin & ~between).sum()),
                     "depth": float(np.max(c["depth"][between])) if between.any() else 0.0,
                     "force": float(-push[1]),
                     "wrists": float(np.linalg.norm(out.hands["left"].bone_poses[0, :3] - out.hands["right"].bone_poses[0, :3])),
                     "min_tet_volume": float(_signed_volumes(out.node_x, rt.model.tets).min()),
                     "finite": bool(np.all(np.isfinite(out.node_x))),
                     # every 4th step (0.1 s each): the deepest skin point under any skin it may touch
                     "penetration": (skin_penetration(smodel, out.node_x, rt.model.tets, None, surfaces)[0]
                                     if k % 4 == 0 else None)})
    return script, rows
