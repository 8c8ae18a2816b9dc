"""The whole softhand pipeline without ROS, deterministic: bag -> adapter -> loop <-> sim <-> world.

    from softhand_sim.commands.offline import run_pipeline   # or: softhand offline BAG
    result = run_pipeline("grasp_short")            # a bag name / directory, or synth=True
    result.summary()                                # lift, hold, fall, contacts, forces

What runs (the same classes the nodes wrap, with the nodes' default parameters from
config/softhand.yaml, `softhand_sim.params.load_params`):

* tracker frames: the bag's PoseArray messages (softhand_sim.ros.bagio) or `tracker_bags.sample(name)`,
  delivered at their capture (header) time, as play_node replays them;
* tracking_node: `TrackingLoop` stepped at its `rate` (250 Hz); each step's intermediate bones
  become the sim's bone targets at once (sim_node keeps the latest). With hands=[right, left]
  (a two-hand bag) one loop per hand, as one tracking node each, the frames of both on the bag's
  one timeline;
* sim_node: `SimRuntime.step(dt, t)` at `sim_rate` (0: 200 Hz for one hand, 50 for two). Its outputs (state at t + dt) are
  delivered `sim_latency` [s] after the step starts (default: one sim period, the worst case of a
  node whose step takes its whole period): /hand/bones -> loop.on_sim_bones, /hand/object_states
  -> world.set_copy stamped with the state time t + dt (as world_node takes the header stamp);
* world_node: `World.step()` at `engine_rate` (120 Hz), its states stamped with the engine time
  and handed to runtime.set_object_copies with that stamp (sim_node stamps them on receipt,
  which on an idle machine is the same time).

Events are processed in time order (ties: tracker frame, loop step, world step, sim output, sim
step), so a run is a pure function of its inputs. `--realtime` (realtime=True) keeps that order and
only waits for each event's time on the wall clock, so the sim steps after idle time as sim_node's
do: the runtime's step time with and without that wait, in one process, no ROS. Records, per sim
step: engine and hand-side ball pose, the ball in the palm frame, contacts with the ball and their
total force, the lowest skin point near a point of interest, the tracked palm.
"""
from __future__ import annotations

import argparse
import heapq
import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from softhand_sim.topics import SKIN_OBJECT
from softhand_sim.params import ParamError, load_params, safe_load
from softhand_sim.paths import bag_params_file, bag_path
from softhand_sim.ros.bagio import BagError
from softhand_sim.physics.hands import HAND_CODE
from softhand_sim.physics.rotations import quat_to_matrix
from softhand_sim.scene import SceneError, load_scene
from softhand_sim.runtime import SimRuntime
from softhand_tracking.adapter import tracker_adapter
from softhand_tracking.loop import TrackingLoop, loop_config_from
from softhand_world.world import World, WorldConfig

MSGTYPE = "geometry_msgs/msg/PoseArray"
_FRAME, _LOOP, _WORLD, _SIM_OUT, _SIM = range(5)  # tie-break order of simultaneous events


class InputError(ValueError):
    """A name the user gave that the run does not have (an object, a scenario)."""


def read_frames(bag=None, synth=None, side="right"):
    """(times [s] from the first frame, joints (n, 26, 7)) of hand `side` in a bag (name in bags/ or
    directory: its /tracker/{side}/hand_joints, or an old bag's /tracker/hand_joints) or, with
    synth=<scenario name>, of tracker_bags.sample directly (no file)."""
    if synth is not None:
        from softhand_sim.scenarios.tracker_bags import SCENARIOS, SIZED_SCENARIOS, sample
        if synth not in SCENARIOS and synth not in SIZED_SCENARIOS:
            raise InputError(f"unknown scenario {synth!r} (--synth); known: "
                             f"{', '.join([*SCENARIOS, *SIZED_SCENARIOS])}")
        stamps, joints, _ = sample(synth)
    else:
        stamps, joints = tracker_frames_ns(bag, side)
    return (stamps - stamps[0]) * 1e-9, joints


def tracker_frames_ns(bag, side):
    """(header stamps [ns] (n,) int64, joints (n, 26, 7)) of hand `side`'s tracker frames in a bag."""
    from softhand_sim.ros.bagio import deserialize, read_tracker
    data = read_tracker(bag_path(bag), side)
    joints = []
    for raw in data.payloads:
        msg = deserialize(raw, MSGTYPE)
        joints.append([(p.position.x, p.position.y, p.position.z, p.orientation.x, p.orientation.y,
                        p.orientation.z, p.orientation.w) for p in msg.poses])
    return np.asarray(data.stamps_ns, dtype=np.int64), np.asarray(joints, dtype=float)


@dataclass
class PipelineResult:
    """Per sim step records (arrays of equal length) and run counters."""

    t: np.ndarray                # [s] state time of each sim step
    ball_engine: np.ndarray      # (n, 3) engine ball position [m] (latest world state at t)
    ball_hand: np.ndarray        # (n, 3) hand-side ball position [m]
    ball_in_palm: np.ndarray     # (n, 3) engine ball in the simulated palm frame [m]
    palm: np.ndarray             # (n, 3) simulated palm origin [m]
    tracked_palm: np.ndarray     # (n, 3) tracked palm origin [m] (adapter output)
    ball_contacts: np.ndarray    # (n,) active contacts with the ball
    ball_force: np.ndarray       # (n,) |sum of contact forces on the ball| [N]
    ball_force_normal: np.ndarray  # (n,) sum of |normal forces| on the ball [N]
    other_contacts: np.ndarray   # (n,) active contacts with anything else
    other_force: np.ndarray      # (n,) sum of |contact forces| on everything but the ball [N]
    max_point_force: np.ndarray  # (n,) largest single contact force [N]
    skin_min_z: np.ndarray       # (n,) lowest skin vertex [m]
    rejected_steps: int = 0
    cg_iters: np.ndarray = field(default=None)
    step_ms: np.ndarray = field(default=None)  # (n,) wall time of the SimRuntime.step behind each record [ms]
    ball_z0: float = 0.0

    def held_mask(self, min_contacts=3):
        return self.ball_contacts >= min_contacts

    def summary(self, hold_window=None):
        """Lift, hold and fall figures of the engine ball (see the module docstring). The hold
        figures cover the steps with >= 3 ball contacts and over half the top lift, within
        `hold_window` (t0, t1) [s] when given (e.g. the bag's hold phase, so the release is out)."""
        z = self.ball_engine[:, 2]
        lift = z - self.ball_z0
        i_top = int(np.argmax(lift))
        held = self.held_mask()
        out = {"duration_s": float(self.t[-1]), "ball_lift_max_m": float(lift.max()),
               "t_ball_top_s": float(self.t[i_top]), "ball_z_end_m": float(z[-1]),
               "ball_contact_steps": int((self.ball_contacts > 0).sum()),
               "ball_contacts_max": int(self.ball_contacts.max()),
               "ball_force_max_N": float(self.ball_force.max()),
               "ball_force_normal_max_N": float(self.ball_force_normal.max()),
               "max_point_force_N": float(self.max_point_force.max()),
               "other_force_max_N": float(self.other_force.max()),
               "skin_min_z_m": float(self.skin_min_z.min()),
               "rejected_steps": self.rejected_steps}
        hold = held & (lift > 0.5 * lift.max()) if lift.max() > 0.02 else np.zeros_like(held)
        if hold_window is not None:
            hold &= (self.t >= hold_window[0]) & (self.t <= hold_window[1])
        if hold.any():
            rel = self.ball_in_palm[hold]
            out.update(hold_s=float(hold.sum() * np.median(np.diff(self.t))),
                       hold_slip_mm=float(1e3 * np.linalg.norm(rel - np.median(rel, axis=0), axis=1).max()),
                       hold_drift_mm=float(1e3 * np.linalg.norm(rel[-1] - rel[0])))
        return out


def run_pipeline(bag=None, synth=None, until=None, sim_latency=None, sim_overrides=None,
                 world_overrides=None, tracking_overrides=None, params_file=None, progress=None, asset=None,
                 hands=None, track_object="ball", realtime=False):
    """Run the pipeline over a bag (or synth scenario) until `until` [s] (default: end + 2 s).
    asset: the HandAsset to simulate (default: the sim_node parameters' hand). The hand is the
    tracking parameters' `hand` (tracking_overrides={"hand": "left"} runs a left-hand bag): its
    frames are read and the sim simulates that side. hands=["right", "left"] runs both hands of a
    two-hand bag (a bag only; one tracking loop per hand, as one tracking node each, on the bag's
    one timeline). The records' object (the `ball_*` fields, in the first hand's palm frame) is
    `track_object`. Without a params_file, a bag's own params.yaml (the node parameters its scene
    needs, as `softhand demo` passes them) is read when it has one.

    realtime: each event waits for its time on the wall clock (from the run's start), as the
    nodes' timers do, instead of following the one before at once; the run then takes as long
    as the bag, and every sim step comes after the idle time a node's step comes after (the
    step's wall time in `step_ms` is then sim_node's `step_ms`, without the other nodes)."""
    if params_file is None and bag is not None:
        params_file = bag_params_file(bag)
    sp = load_params("sim_node", params_file, sim_overrides)
    wp = load_params("world_node", params_file, world_overrides)
    tp = load_params("tracking_node", params_file, tracking_overrides)
    hands = [tp["hand"]] if not hands else list(hands)
    sp["hand_side"], sp["hands"] = hands[0], hands
    if len(hands) == 1:
        frames = {hands[0]: read_frames(bag, synth, side=hands[0])}
    else:
        if synth is not None:
            raise InputError("two hands run from a bag only (synth is one hand)")
        raw = {side: tracker_frames_ns(bag, side) for side in hands}
        t0_ns = min(stamps[0] for stamps, _ in raw.values())  # the bag's one timeline
        frames = {side: ((stamps - t0_ns) * 1e-9, joints) for side, (stamps, joints) in raw.items()}
    scene = load_scene(sp["scene_file"] or None)
    movable = [o.name for o in scene.dynamic_objects]
    if track_object not in movable:
        raise InputError(f"object {track_object!r} is not among the scene's movable objects "
                         f"({', '.join(movable)})")
    runtime = SimRuntime(sp, scene=scene, asset=asset)
    world = World(load_scene(wp["scene_file"] or None), WorldConfig(
        engine_rate=wp["engine_rate"], coupling_kx=wp["coupling_kx"], coupling_ktheta=wp["coupling_ktheta"],
        copy_timeout=wp["copy_timeout"], extrapolate=wp["extrapolate"], coupling_damping=wp["coupling_damping"],
        coupling_mode=wp["coupling_mode"], coupling_max_omega=wp["coupling_max_omega"], gravity=wp["gravity"]),
        start_time=0.0)
    loops = {}
    for side in hands:  # one tracking node per hand
        adapter = tracker_adapter(tp, side)
        loops[side] = TrackingLoop(loop_config_from(tp), adapter, tracker_timeout=tp["tracker_timeout"],
                                   sim_timeout=tp["sim_timeout"])
    loop = loops[hands[0]]
    sim_dt = 1.0 / runtime.params["sim_rate"]  # sim_rate 0: by hand count
    latency = sim_dt if sim_latency is None else float(sim_latency)
    end = max(times[-1] for times, _ in frames.values()) + 2.0 if until is None else float(until)
    ball = runtime.object_names.index(track_object)                   # solver body index
    ball_contact = list(runtime.contacts.model.object_names).index(track_object)  # contact object index
    wball = world.object_index(track_object)

    events = []
    seq = 0

    def push(t, kind, payload=None):
        nonlocal seq
        heapq.heappush(events, (t, kind, seq, payload))
        seq += 1

    for side, (times, _) in frames.items():
        for i, t in enumerate(times):
            push(float(t), _FRAME, (side, i))
    push(0.0, _LOOP, 0)
    push(world.dt, _WORLD, 1)
    push(0.0, _SIM, 0)
    rec = {k: [] for k in ("t", "be", "bh", "bp", "palm", "tp", "bc", "bf", "bfn", "oc", "of", "mpf", "skz", "cg",
                           "ms")}
    world_state = world.states()
    clock = time.perf_counter
    wall0 = clock()
    while events:
        t, kind, _, payload = heapq.heappop(events)
        if t > end + 1e-9:
            break
        if realtime:
            wait = wall0 + t - clock()
            if wait > 0.0:
                time.sleep(wait)
        if kind == _FRAME:
            side, i = payload
            loops[side].on_tracker(frames[side][1][i], t, t)
        elif kind == _LOOP:
            for side, hand_loop in loops.items():
                poses = hand_loop.step(t)
                if poses is not None:
                    runtime.set_bone_targets(poses, t, hand=side)
            push((payload + 1) / tp["rate"], _LOOP, payload + 1)
        elif kind == _WORLD:
            world.step()
            world_state = world.states()
            runtime.set_object_copies(list(world_state.names), world_state.pose, world_state.twist,
                                      world_state.accel, world_state.stamp)
            push((payload + 1) * world.dt, _WORLD, payload + 1)
        elif kind == _SIM_OUT:
            out_t, bones, names, poses, twists, accels, n_contacts = payload
            for side, hand_loop in loops.items():
                hand_loop.on_sim_bones(bones[side], t)
                hand_loop.on_contacts(n_contacts[side], t)  # /hand/contacts: the feedback acts in contact
            for j, name in enumerate(names):
                world.set_copy(name, poses[j], twists[j], accels[j], out_t)
        elif kind == _SIM:
            t_step = clock()
            out = runtime.step(sim_dt, t)
            step_ms = 1e3 * (clock() - t_step)
            push((payload + 1) * sim_dt, _SIM, payload + 1)
            if out is None:
                continue
            # the feedback gate counts object contacts only, each hand its own (tracking_node)
            objects = out.contacts["objects"] != SKIN_OBJECT
            bones_out = {side: out.hands[side].bone_poses.copy() for side in hands}
            counts = {side: int(np.count_nonzero(objects & (out.contacts["hand"] == HAND_CODE[side])))
                      for side in hands}
            push(t + latency, _SIM_OUT, (out.t, bones_out, list(out.object_names), out.object_poses.copy(),
                                         out.object_twists.copy(), out.object_accels.copy(), counts))
            c = out.contacts
            on_ball = c["objects"] == ball_contact
            palm = out.bone_poses[0]  # the first hand's
            be = world_state.pose[wball, :3]
            rec["t"].append(out.t)
            rec["be"].append(be.copy())
            rec["bh"].append(out.object_poses[ball, :3].copy())
            rec["bp"].append(quat_to_matrix(palm[3:].copy()).T @ (be - palm[:3]))
            rec["palm"].append(palm[:3].copy())
            rec["tp"].append(loop.tracked[0, :3].copy())
            rec["bc"].append(int(on_ball.sum()))
            rec["bf"].append(float(np.linalg.norm(c["forces"][on_ball].sum(axis=0))) if on_ball.any() else 0.0)
            rec["bfn"].append(float(np.linalg.norm(c["force_normal"][on_ball], axis=1).sum()))
            rec["oc"].append(int((~on_ball).sum()))
            rec["of"].append(float(np.linalg.norm(c["forces"][~on_ball], axis=1).sum()))
            rec["mpf"].append(float(np.linalg.norm(c["forces"], axis=1).max()) if len(c["forces"]) else 0.0)
            rec["skz"].append(float(out.skin_vertices[:, 2].min()))
            rec["cg"].append(out.stats.cg_iters)
            rec["ms"].append(step_ms)
            if progress is not None:
                progress(out)
    world.close()
    a = {k: np.asarray(v) for k, v in rec.items()}
    return PipelineResult(t=a["t"], ball_engine=a["be"], ball_hand=a["bh"], ball_in_palm=a["bp"], palm=a["palm"],
                          tracked_palm=a["tp"], ball_contacts=a["bc"], ball_force=a["bf"], ball_force_normal=a["bfn"],
                          other_contacts=a["oc"], other_force=a["of"], max_point_force=a["mpf"], skin_min_z=a["skz"],
                          rejected_steps=runtime.rejected_steps, cg_iters=a["cg"], step_ms=a["ms"],
                          ball_z0=float(scene.objects[[o.name for o in scene.objects].index(track_object)].pose[2]))


def _overrides(items):
    out = {}
    for item in items or ():
        key, _, value = item.partition("=")
        if not _:
            raise SystemExit(f"error: override {item!r} is not key=value")
        out[key] = safe_load(value)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(prog="softhand offline", description="Run the whole pipeline offline (no ROS, deterministic) over a bag and print the ball's (or --object's) lift, hold and fall.")
    ap.add_argument("bag", help="bag name in bags/ or a bag directory (scenario name with --synth)")
    ap.add_argument("--synth", action="store_true", help="sample tracker_bags directly (no bag file)")
    ap.add_argument("--until", type=float, default=None, help="stop at this time [s] (default: end + 2 s)")
    ap.add_argument("--every", type=float, default=0.25, help="print a line every this many seconds")
    ap.add_argument("--latency", type=float, default=None, help="sim output latency [s] (default: 1/sim_rate)")
    ap.add_argument("--sim", nargs="*", help="sim_node parameter overrides key=value")
    ap.add_argument("--world", nargs="*", help="world_node parameter overrides key=value")
    ap.add_argument("--tracking", nargs="*", help="tracking_node parameter overrides key=value")
    ap.add_argument("--hands", nargs="+", choices=("right", "left"), default=None,
                    help="the hands to run (default: tracking_node's `hand`); both for a two-hand bag")
    ap.add_argument("--object", default="ball", help="the object whose lift, hold and slip are reported "
                                                     "(slip in the first hand's palm frame; default ball)")
    ap.add_argument("--params-file", default=None,
                    help="ROS params file of the nodes' parameters (default: the bag's params.yaml if it has one)")
    ap.add_argument("--json", help="write the summary here")
    ap.add_argument("--realtime", action="store_true",
                    help="run at the bag's own speed, each event at its time on the wall clock as the "
                         "nodes run (default: as fast as it computes); the summary's step_ms_p50 / "
                         "_p99 are then the sim step after a node's idle time between steps")
    args = ap.parse_args(argv)
    if args.hands and len(set(args.hands)) != len(args.hands):
        ap.error(f"--hands names a side twice: {args.hands}")
    for flag, value, low in (("--until", args.until, 0.0), ("--every", args.every, 0.0)):
        if value is not None and not value > low:
            ap.error(f"{flag} {value}: must be > 0 [s]")
    if args.latency is not None and not args.latency >= 0.0:
        ap.error(f"--latency {args.latency}: must be >= 0 [s]")
    t0 = time.monotonic()
    try:
        r = run_pipeline(None if args.synth else args.bag, synth=args.bag if args.synth else None,
                         until=args.until, sim_latency=args.latency, sim_overrides=_overrides(args.sim),
                         world_overrides=_overrides(args.world), tracking_overrides=_overrides(args.tracking),
                         hands=args.hands, track_object=args.object, params_file=args.params_file,
                         realtime=args.realtime)
    except (BagError, ParamError, SceneError, InputError) as exc:
        # the user's input (a bag, a parameter, an object or scenario name): its own words, no trace
        raise SystemExit(f"error: {exc}") from None
    print(" t[s]  ball_z[mm] lift  hand_z  palm_z track_z  in_palm(x,y,z)[mm]   nC  F[N]  Fn[N] other skin_min_z")
    next_print = 0.0
    for i, t in enumerate(r.t):
        if t + 1e-9 >= next_print:
            next_print += args.every
            bp = 1e3 * r.ball_in_palm[i]
            print(f"{t:5.2f} {1e3 * r.ball_engine[i, 2]:7.1f} {1e3 * (r.ball_engine[i, 2] - r.ball_z0):6.1f} "
                  f"{1e3 * r.ball_hand[i, 2]:7.1f} {1e3 * r.palm[i, 2]:7.1f} {1e3 * r.tracked_palm[i, 2]:7.1f} "
                  f"({bp[0]:6.1f},{bp[1]:6.1f},{bp[2]:6.1f}) {r.ball_contacts[i]:4d} {r.ball_force[i]:5.2f} "
                  f"{r.ball_force_normal[i]:6.2f} {r.other_contacts[i]:4d} {1e3 * r.skin_min_z[i]:7.1f}")
    s = r.summary()
    s["wall_s"] = round(time.monotonic() - t0, 1)
    # the runtime's step as sim_node times it (`step_ms_p50` in /diagnostics and the demo summary);
    # the first steps compile and fill the caches
    ms = r.step_ms[5:] if len(r.step_ms) > 5 else r.step_ms
    s["step_ms_p50"], s["step_ms_p99"] = round(float(np.median(ms)), 3), round(float(np.percentile(ms, 99)), 3)
    s["realtime"] = bool(args.realtime)
    print(json.dumps(s, indent=1))
    if args.json:
        Path(args.json).write_text(json.dumps(s, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
