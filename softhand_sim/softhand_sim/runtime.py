"""The full simulation as sim_node runs it, without ROS: hands + objects + contact + copies + guard.

SimRuntime owns one Solver (one Newton step + PCG per step, physics/solver.py) with its contact
system (physics/contact/detection.py), the step inputs (physics/control.Control), the engine
copies of the dynamic objects (coupling.ObjectCopy, Sect. 3.7) and the divergence guard. sim_node
only converts messages to the arrays this class takes and returns.

This is the input boundary: bone targets are validated and normalised here (set_bone_targets),
object copies in ObjectCopy.update (set_object_copies); the physics below trusts its inputs.

Hands (issue #18): params["hands"] lists the hands to simulate, ["right"], ["left"] or
["right", "left"] (empty: the one hand of params["hand_side"]). All of them are one Model (one
Newton step + PCG, physics/hands.py), so an object held by both is one body. A hand enters the
simulation at its first valid target (placed there, its contacts on from then) and holds its last
target when its tracking stops. Calls without `hand` address the first hand of the list, so a
one-hand caller sees exactly the one-hand runtime.

Timeline of a step at time t: bone targets = the latest intermediate bones (held between
updates, Sect. 3.6); object targets = the engine copies extrapolated to t + dt (the end of the
step, where the implicit step evaluates the coupling); solver.step(state, control, dt); guard;
outputs. StepOutput.stages times each part of it (STAGES, wall clock [ms]).
"""
from __future__ import annotations

from copy import deepcopy
import time
from dataclasses import dataclass, field

import numpy as np

from softhand_sim.physics.contact import detection as contact_mod
from softhand_sim.physics.contact.hand_self_contact import HandSelfContact
from softhand_sim.topics import NO_BONE, SKIN_OBJECT
from softhand_sim.physics.control import Control
from softhand_sim.physics.coupling import ObjectCopy, limit_coupling_stiffness
from softhand_sim.physics.coupling import warm_up as coupling_warm_up
from softhand_sim.handmodel import load_or_build_hand
from softhand_sim.physics.two_level import coarse_mesh_of
from softhand_sim.handmodel.measures import as_measures
from softhand_sim.handmodel.rigid_skin import skin_segments
from softhand_sim.hand_sizer import measures_diagnostics
from softhand_sim.params import ParamError, sim_rate_hz
from softhand_sim.physics.hands import HAND_CODE, SIDES, union_asset
from softhand_sim.physics.model import build_model
from softhand_sim.physics.rotations import quat_mul, quat_conj, quat_to_matrix
from softhand_sim.scene import load_scene
from softhand_sim.physics.solver import STAGE_FIELDS, Solver
from softhand_sim.physics.state import State
from softhand_sim.target_lead import TargetLead, warm_up as lead_warm_up

# Divergence guard (robustness): a step is rejected when its state is not finite, when the
# kinetic energy jumps above this bound [J] (a 0.4 kg hand at 70 m/s: far beyond the ~24 m/s a 1 m
# teleport reaches with the 500 N/m palm coupling), or when CG
# stopped at its cap with a residual this far above its tolerance.
GUARD_MAX_KINETIC_ENERGY = 1000.0
GUARD_CAP_RESIDUAL_FACTOR = 1e3
DISPLAY_TRIANGLES = 3000  # /hand/{side}/skin_marker: a decimated skin keeps 10 Hz markers light

# The stages of SimRuntime.step in order (StepOutput.stages): targets (object copies extrapolated
# into the Control; bone targets enter it on receipt, set_bone_targets), the solver's
# (solver.STAGE_FIELDS), guard (divergence checks + the good-state copy or restore), skin (the
# embedded skin vertices), output (the StepOutput: poses, twists, contact list).
STAGES = ("targets", *(name for name, _ in STAGE_FIELDS), "guard", "skin", "output")


@dataclass
class HandOutput:
    side: str                   # "right" / "left"
    code: int                   # the contacts' `hand` code (0 right, 1 left)
    entered: bool               # the hand has had a target (it is simulated from then on)
    bone_poses: np.ndarray      # (16,7)
    skin_vertices: np.ndarray   # (V,3)


@dataclass
class StepOutput:
    t: float                    # [s] time of the state (end of the step)
    bone_poses: np.ndarray      # (16,7) the first hand's (hands[0]); every hand's in `hands`
    object_names: list
    object_poses: np.ndarray    # (O,7) hand-side instances, COM frames
    object_twists: np.ndarray   # (O,6) [m/s, rad/s] world
    object_accels: np.ndarray   # (O,6) finite differences over the step
    skin_vertices: np.ndarray   # (V,3) the first hand's
    contacts: dict              # contact.ContactSystem.output(...), of every hand (its `hand` field)
    stats: object               # solver.StepStats
    rejected: bool = False      # the guard rejected this step: state is the last good one
    warning: str = ""
    node_x: np.ndarray = field(default=None, repr=False)
    hands: dict = field(default_factory=dict)  # side -> HandOutput, every simulated hand
    stages: dict = field(default_factory=dict)  # STAGES name -> wall time [ms] of this step's stage


def hand_sides(params):
    """The hands to simulate, in model order: params["hands"] without its empty entries, else
    [params["hand_side"]]. ValueError on an unknown or repeated side."""
    sides = [h for h in (params.get("hands") or []) if h] or [params["hand_side"]]
    for h in sides:
        if h not in SIDES:
            raise ValueError(f"sim_node: parameter 'hands' must list 'right' and/or 'left', got {h!r}")
    if len(set(sides)) != len(sides):
        raise ValueError(f"sim_node: parameter 'hands' names a hand twice: {sides}")
    return tuple(sides)


def check_hand_measures(params):
    """ParamError (naming both parameters) when `hand_measures: auto` meets two hands. The sizer
    (hand_sizer) fits one hand from its side's tracker frames and a SimRuntime has one set of
    measures; sizing each hand apart would rebuild the two-hand solver twice, mid-run. Two hands
    take 'default' or a measures file (`softhand calibrate`)."""
    sides = hand_sides(params)
    if params["hand_measures"] == "auto" and len(sides) > 1:
        raise ParamError(f"sim_node: parameter 'hand_measures' = 'auto' sizes one hand, but parameter 'hands' = "
                         f"{list(sides)} simulates two: set hand_measures to 'default' or a measures file "
                         f"(`softhand calibrate`), or simulate one hand")


def _pose_transform(target, rest):
    """(R, p) of the rigid motion taking pose `rest` onto pose `target`."""
    dq = quat_mul(target[3:7], quat_conj(rest[3:7]))
    rot = quat_to_matrix(dq)
    return rot, dq, target[:3] - rot @ rest[:3]


def hand_measures_source(value):
    """'default', 'auto' or 'file': what the `hand_measures` parameter `value` names."""
    return "default" if value in ("", "default") else "auto" if value == "auto" else "file"


def hand_measures(value):
    """HandMeasures of the `hand_measures` parameter: 'default' or a measures file. 'auto' gives
    the default measures: the hand a runtime starts with until softhand_sim.hand_sizer has fitted
    the user's (sim_node simulates nothing with it)."""
    from softhand_sim.handmodel.measures import HandMeasures, read_measures_file
    if hand_measures_source(value) in ("default", "auto"):
        return HandMeasures()
    return read_measures_file(value)


class SimRuntime:
    """The hands and the touched objects in one solver (physics/hands.py for two hands)."""

    def __init__(self, params, scene=None, asset=None, measures=None, measures_source=None):
        """asset: the hand asset (one hand), or a list of assets in the order of hand_sides(params);
        None: each hand cached, morphed or built (handmodel.cache) for its side at params["mesh"] and at
        `measures` if given, else at the `hand_measures` parameter's. measures_source: what the
        diagnostics name as the measures' source (default: the parameter's kind, hand_measures_source)."""
        self.hands = hand_sides(params)
        # a copy: `sim_rate` 0 becomes the rate for this many hands (sim_rate_hz), the rest as given
        self.params = params = {**params, "sim_rate": sim_rate_hz(params, len(self.hands))}
        self.scene = scene if scene is not None else load_scene(params["scene_file"] or None)
        value = params["hand_measures"]
        if asset is None:
            m = measures if measures is not None else hand_measures(value)
            assets = [load_or_build_hand(m, side=h, resolution=params["mesh"]) for h in self.hands]
        else:
            assets = list(asset) if isinstance(asset, (list, tuple)) else [asset]
        if len(assets) != len(self.hands):
            raise ValueError(f"{len(assets)} hand asset(s) for hands {list(self.hands)}")
        self.hand_assets = assets
        self.asset = assets[0]  # the first hand's (single-hand callers)
        self.measures = as_measures(self.asset.measures)
        self.measures_source = measures_source or hand_measures_source(value)
        self.objects = list(self.scene.dynamic_objects)
        self.object_names = [o.name for o in self.objects]
        union = union_asset(assets)  # the one asset itself for one hand
        # two_level: each hand's coarse hand (its measures and side) is the preconditioner's coarse level
        coarse = [coarse_mesh_of(a) for a in assets] if params["preconditioner"] == "two_level" else None
        self.model = build_model(union, params, self.objects, coarse_meshes=coarse)
        self.contacts = contact_mod.build_contact_system(self.model, self.scene, union,
                                                         kn=params["contact_kn"], kf=params["contact_kf"])
        self.contacts.hand_enabled[:] = 0  # no contact before a hand's first target
        # the bone (0-15, of its hand) of every skin point: the `bone` of each object contact
        self._skin_bone = np.concatenate([skin_segments(a)[0] for a in assets]).astype(np.uint8)
        # skin on skin (parameter self_contact): one system over every hand, a hand's skin in once placed
        self.self_contact = HandSelfContact(self.model, union, assets) if params["self_contact"] else None
        self.solver = Solver(self.model, contacts=self.contacts,
                             self_contacts=self.self_contact.system if self.self_contact else None)
        self.state = State.at_rest(self.model)
        self.control = Control.at_rest(self.model)
        self.good_state = self.state.copy()
        nb = self.model.bone_count
        # Same capped stiffness as the world side (both must use identical values, coupling.py).
        caps = [limit_coupling_stiffness(params["object_kx"], params["object_ktheta"], o.mass,
                                         o.inertia_local, params["object_max_omega"]) for o in self.objects]
        self.object_kx = np.array([c[0] for c in caps])
        self.object_ktheta = np.array([c[1] for c in caps])
        self.copies = [ObjectCopy(n, extrapolate=params["extrapolate"], timeout=params["copy_timeout"])
                       for n in self.object_names]
        self.object_targets = np.array([o.pose for o in self.objects]).reshape(-1, 7)
        H = len(self.hands)
        self.hand_targets = [None] * H   # latest validated (16,7) targets per hand
        self.hand_stamps = [None] * H
        self.hand_placed = [False] * H
        # each hand's targets moved to the end of the step, out of contact (target_lead.py)
        self.leads = [TargetLead(params["target_feed_forward"], params["target_acceleration"]) for _ in range(H)]
        self.rejected_steps = 0
        self.steps = 0
        self.last_t = 0.0
        self.last_step_stamp = 0.0  # [s] the state time (stamp) of the last step's output
        self._prev_body_v = self.state.body_v[nb:].copy()
        self._skin = np.empty((len(self.model.skin_tet), 3))
        self._display = [None] * H

    # ---------------------------------------------------------------- hands
    def hand_index(self, hand=None):
        """Index (model.hands order) of side `hand`; None: the first hand."""
        return 0 if hand is None else self.model.hands.index(hand)

    @property
    def bone_targets(self):
        """The first hand's latest targets (16,7), None before its first."""
        return self.hand_targets[0]

    @property
    def bone_target_stamp(self):
        return self.hand_stamps[0]

    @property
    def placed(self):
        """True once any hand has entered the simulation."""
        return any(self.hand_placed)

    # ---------------------------------------------------------------- description and meshes
    def describe(self):
        m = self.model
        tris = sum(len(a.skin_triangles) for a in self.hand_assets)
        return (f"{'+'.join(self.hands)} hand{'s' if len(self.hands) > 1 else ''}, {len(m.tets)} tets, "
                f"{m.node_count} nodes, {m.dof_count} dofs, {tris} skin triangles, objects "
                f"{self.object_names}, contact points {self.contacts.model.point_count}, "
                f"preconditioner {self.params['preconditioner']}, {self.params['sim_rate']:g} Hz, "
                f"solver threads {self.solver.threads}"
                + (", factorizations in the background" if self.solver.factor.threaded else ""))

    def skin_rest_mesh(self, hand=None):
        """(vertices (V,3), triangles) of a hand's skin at its rest pose (default: the first hand)."""
        a = self.hand_assets[self.hand_index(hand)]
        return np.asarray(a.skin_vertices), np.asarray(a.skin_triangles)

    def _display_embedding(self, h=0):
        """A decimated copy of hand h's skin, each vertex embedded in the tet of its nearest skin
        vertex (node indices of the model)."""
        if self._display[h] is None:
            import fast_simplification
            from scipy.spatial import cKDTree

            asset = self.hand_assets[h]
            verts, tris = np.asarray(asset.skin_vertices), np.asarray(asset.skin_triangles)
            ratio = max(0.0, 1.0 - DISPLAY_TRIANGLES / len(tris))
            dv, dt = fast_simplification.simplify(verts.astype(np.float32), tris.astype(np.int32), ratio)
            dv = dv.astype(np.float64)
            _, nearest = cKDTree(verts).query(dv)
            tet = np.asarray(asset.skin_tet)[nearest]
            corners = np.asarray(asset.tet_nodes)[np.asarray(asset.tets)[tet]]  # (D,4,3)
            mat = np.transpose(corners[:, 1:] - corners[:, :1], (0, 2, 1))
            w = np.linalg.solve(mat, (dv - corners[:, 0])[:, :, None])[:, :, 0]
            bary = np.column_stack([1.0 - w.sum(axis=1), w])
            nodes = np.asarray(asset.tets)[tet] + self.model.hands.node0[h]
            self._display[h] = (nodes, bary, np.asarray(dt, dtype=np.int32))
        return self._display[h]

    def display_mesh(self, out=None, hand=None):
        """(vertices (D,3), triangles) of a hand's decimated skin at the current state (default:
        the first hand)."""
        nodes, bary, tris = self._display_embedding(self.hand_index(hand))
        x = self.state.node_x
        return np.einsum("dk,dki->di", bary, x[nodes]), tris

    # ---------------------------------------------------------------- inputs
    def set_bone_targets(self, poses, stamp=None, hand=None):
        """Intermediate bones (16,7) of hand `hand` ("right" / "left"; None: the first hand); the
        hand's first call also places it at the targets' palm (it enters the simulation)."""
        h = self.hand_index(hand)
        poses = np.asarray(poses, dtype=np.float64)
        bones = self.model.hands.bones(h)
        nb = bones.stop - bones.start
        if poses.shape != (nb, 7):
            raise ValueError(f"bone targets must have shape ({nb}, 7), got {poses.shape}")
        if not np.all(np.isfinite(poses)):
            raise ValueError("bone targets contain non-finite values")
        norms = np.linalg.norm(poses[:, 3:], axis=1)
        if np.any(np.abs(norms - 1.0) > 1e-3):
            raise ValueError(f"bone target quaternions are not unit (norms {norms.min():.3g}..{norms.max():.3g})")
        poses = poses.copy()
        poses[:, 3:] /= norms[:, None]
        self.hand_targets[h] = poses
        self.hand_stamps[h] = stamp
        self.leads[h].on_target(poses, stamp)
        if not self.hand_placed[h]:
            self.place_hand(poses[0], self.hands[h])

    def warm_up(self, dt):
        """Run one throwaway step so numba compiles (or loads from its cache) every kernel of the
        step now, not during the first tracked second; the runtime is left exactly as it was.

        On a fresh checkout the first step compiles for about a minute: a node that published
        before this would simulate nothing while its peers ran on.
        """
        saved = (self.state.copy(), self.good_state.copy(), self.control.copy(), list(self.hand_targets),
                 list(self.hand_stamps), list(self.hand_placed), self.steps, self._prev_body_v.copy(),
                 self.object_targets.copy(), self.contacts.hand_enabled.copy(), deepcopy(self.leads))
        for h, side in enumerate(self.hands):
            self.set_bone_targets(self.model.body_rest_pose[self.model.hands.bones(h)], hand=side)
        self.step(dt, 0.0)
        for side in self.hands:
            self.display_mesh(hand=side)
        coupling_warm_up()
        lead_warm_up()
        (self.state, self.good_state, self.control, self.hand_targets, self.hand_stamps,
         self.hand_placed, self.steps, self._prev_body_v, self.object_targets, enabled, self.leads) = saved
        self.contacts.reset()
        self.contacts.hand_enabled[:] = enabled
        if self.self_contact is not None:
            self.self_contact.system.reset()
        self.rejected_steps = 0

    def place_hand(self, palm_pose, hand=None):
        """Teleport a whole hand (default: the first) rigidly so that its palm is at `palm_pose`
        (at rest otherwise), and let it enter the simulation (its contacts on). The other hands
        and the objects keep their state."""
        m, s = self.model, self.state
        h = self.hand_index(hand)
        nodes, bones, tets = m.hands.nodes(h), m.hands.bones(h), m.hands.tets(h)
        rot, dq, shift = _pose_transform(np.asarray(palm_pose, float), m.body_rest_pose[bones.start])
        s.node_x[nodes] = m.node_rest[nodes] @ rot.T + shift
        s.v[3 * nodes.start:3 * nodes.stop] = 0.0
        for b in range(bones.start, bones.stop):
            rest = m.body_rest_pose[b]
            pose = np.concatenate([rot @ rest[:3] + shift, quat_mul(dq, rest[3:])])
            s.set_body_pose(m, b, pose)
            s.body_v[b] = 0.0
        # the tets' co-rotational rotations warm-start at the placement's rotation: from the
        # identity, the few polar iterations of a step do not reach a hand placed turned by
        # ~180 deg (a left hand facing the right one), and its tets fold in the first steps
        s.tet_q[tets] = dq / np.linalg.norm(dq)
        self.contacts.reset(h if len(self.hands) > 1 else None)
        self.contacts.hand_enabled[h] = 1
        if self.self_contact is not None:
            self.self_contact.enter(h)
        self.good_state = s.copy()
        self.hand_placed[h] = True

    def set_object_copies(self, names, poses, twists, accels, stamp):
        """Engine copies of objects; returns a list of rejection messages (unknown names, bad values)."""
        errors = []
        for i, name in enumerate(names):
            if name not in self.object_names:
                errors.append(f"unknown object {name!r}")
                continue
            try:
                self.copies[self.object_names.index(name)].update(poses[i], twists[i], accels[i], stamp)
            except ValueError as exc:
                errors.append(str(exc))
        return errors

    def stale_objects(self, t):
        return [c.name for c in self.copies if c.is_stale(t)]

    # ---------------------------------------------------------------- the step
    def _update_object_targets(self, t, dt):
        for i, copy in enumerate(self.copies):
            if copy.pose is None:
                continue  # no copy yet: keep the scene pose as target
            if copy.is_stale(t):
                self.object_targets[i] = copy.pose  # frozen at the last copy: no extrapolation
            else:
                self.object_targets[i] = copy.target(t + dt)[0]
        if len(self.copies):
            self.control.set_object_targets(self.model, self.object_targets, kx=self.object_kx,
                                            ktheta=self.object_ktheta)

    def _carry_hand(self, h, accel):
        """Hand h's every mass loaded with m accel [m/s^2] (3,): the palm target's acceleration
        (target_lead.TargetLead.acceleration; nil in contact)."""
        nodes, bones = self.model.hands.nodes(h), self.model.hands.bones(h)
        np.multiply(self.model.node_mass[nodes, None], accel, out=self.control.node_force[nodes])
        np.multiply(self.model.body_mass[bones, None], accel, out=self.control.body_force[bones])

    def step(self, dt, t, on_bones=None):
        """Advance by dt from time t; returns StepOutput, or None while no bone target arrived.
        on_bones(t_state, [(side, bone_poses (B, 7))] of the hands that entered): called as soon
        as the state is final, before the skin and the contact rows are computed (sim_node
        publishes the bones there: the latency a user sees)."""
        if not self.placed:
            return None
        nb = self.model.bone_count
        clock = time.perf_counter
        t0 = clock()
        self.last_t = t
        self._update_object_targets(t, dt)
        layout = self.model.hands
        for h, lead in enumerate(self.leads):
            # into the step's inputs once per step, not per message (250 Hz per hand): the latest
            # targets, led to the end of the step (lead off: as they came)
            if self.hand_targets[h] is not None:
                self.control.set_hand_targets(self.model, h, lead.targets_at(t + dt) if lead.enabled
                                              else self.hand_targets[h])
                if lead.accelerate:  # off: the loads stay the zeros they start as
                    self._carry_hand(h, lead.acceleration(t + dt, self.control.target_x[layout.bones(h).start]))
        t1 = clock()
        stats = self.solver.step(self.state, self.control, dt)
        t2 = clock()
        self.steps += 1
        warning = self._guard(stats)
        rejected = bool(warning)
        if rejected:
            self.rejected_steps += 1
            self.state = self.good_state.copy()
            self.contacts.reset()
            if self.self_contact is not None:
                self.self_contact.system.reset()
        else:
            self.good_state = self.state.copy()
        t3 = clock()
        s = self.state
        bone_poses = [s.hand_bone_pose(self.model, h).copy() for h in range(len(self.hands))]
        if on_bones is not None:  # its time is the caller's, in no stage
            on_bones(t + dt, [(side, bone_poses[h]) for h, side in enumerate(self.hands) if self.hand_placed[h]])
        t3b = clock()
        self.solver.skin_positions(self.state, self._skin)
        t4 = clock()
        body_v = self.state.body_v[nb:]
        accels = (body_v - self._prev_body_v) / dt
        self._prev_body_v = body_v.copy()
        layout = self.model.hands
        hands = {side: HandOutput(side=side, code=HAND_CODE[side], entered=self.hand_placed[h],
                                  bone_poses=bone_poses[h], skin_vertices=self._skin[layout.skin(h)])
                 for h, side in enumerate(self.hands)}
        first = hands[self.hands[0]]
        out = StepOutput(
            t=t + dt, bone_poses=first.bone_poses, object_names=self.object_names,
            object_poses=s.object_pose.copy(), object_twists=body_v.copy(), object_accels=accels,
            skin_vertices=first.skin_vertices, contacts=self.contact_rows(s),
            stats=stats, rejected=rejected, warning=warning, node_x=s.node_x, hands=hands)
        for h, side in enumerate(self.hands):  # the lead's contact gate
            if self.leads[h].enabled:
                objects = out.contacts["objects"] != SKIN_OBJECT  # as the tracking node's feedback gate
                self.leads[h].on_contacts(int(np.count_nonzero(objects & (out.contacts["hand"] == HAND_CODE[side]))),
                                          t + dt, float(self.contacts.near[h]))
        t5 = clock()
        # the solver's stages cover its step but for its bookkeeping (a few us): that goes to none
        out.stages = {"targets": 1e3 * (t1 - t0), **{name: getattr(stats, f) for name, f in STAGE_FIELDS},
                      "guard": 1e3 * (t3 - t2), "skin": 1e3 * (t4 - t3b), "output": 1e3 * (t5 - t4)}
        self.last_step_stamp = out.t
        return out

    def contact_rows(self, s) -> dict:
        """The step's contacts (ContactSystem.output's keys, plus bone, other_hand, other_bone:
        docs/INTERFACE.md's /hand/contacts, and depth [m] of skin-skin contacts, NaN for object
        ones): the object contacts, then the skin-skin ones."""
        rows = self.contacts.output(s.node_x, s.body_x, s.body_q)
        n = len(rows["points"])
        rows.update(bone=self._skin_bone[rows["point"]], other_hand=np.full(n, NO_BONE, np.uint8),
                    other_bone=np.full(n, NO_BONE, np.uint8), depth=np.full(n, np.nan))  # depth: skin-skin only
        if self.self_contact is None:
            return rows
        skin = self.self_contact.rows(s.node_x)
        return {key: np.concatenate([value, skin[key]]) for key, value in rows.items()}

    def _guard(self, stats):
        """'' if the new state is acceptable, else why the step is rejected."""
        s = self.state
        if not (np.all(np.isfinite(s.node_x)) and np.all(np.isfinite(s.v)) and np.all(np.isfinite(s.body_pose))):
            return "solver guard: non-finite state, step rejected and last good state restored"
        ke = self.solver.kinetic_energy(s)
        if not np.isfinite(ke) or ke > GUARD_MAX_KINETIC_ENERGY:
            return f"solver guard: kinetic energy {ke:.3g} J exceeds {GUARD_MAX_KINETIC_ENERGY} J, step rejected"
        if stats.hit_cap and stats.residual > GUARD_CAP_RESIDUAL_FACTOR * self.solver.cg_tol:
            return (f"solver guard: CG stopped at its cap ({stats.cg_iters} iterations) with relative "
                    f"residual {stats.residual:.3g}, step rejected")
        return ""

    def diagnostics(self):
        c = self.contacts
        out = {"contacts": int(c.count), "collision_ms": float(c.collision_ms),
                "rejected_steps": self.rejected_steps, "steps": self.steps,
                "last_step_stamp": f"{self.last_step_stamp:.6f}",  # with `steps`: a recorder can count what it missed
                "target_lead_ms": f"{1e3 * self.leads[0].lead:.1f}",  # the first hand's, last step
                "copy_gaps": sum(c.gaps for c in self.copies),
                "stale_objects": ",".join(self.stale_objects(self.last_t)) or "-",
                **measures_diagnostics(self.measures, self.measures_source)}
        if self.self_contact is not None:
            out.update(self.self_contact.diagnostics())
        if len(self.hands) > 1:
            out["hands"] = ",".join(f"{side}:{'in' if placed else 'waiting'}"
                                    for side, placed in zip(self.hands, self.hand_placed))
        return out

