"""Parameters of every node: the one schema (type, default, range, unit, meaning) and a validating loader.

SCHEMA is the single source of every parameter: each node declares it (ros/params.py), the plain
library loads it (`load_params`), the solver model reads its sim_node names unchanged
(physics/model.py), `softhand params` prints it and config/softhand.yaml (ROS 2 params-file
format, one section per node) is written from it (`softhand params --yaml FILE`; a test fails
when the two disagree). The loader refuses unknown keys, wrong types and out-of-range values with
a message naming the key and the value.
"""
from __future__ import annotations

import math
from decimal import Decimal
import re
from dataclasses import dataclass
from pathlib import Path

import yaml



class _Loader(yaml.SafeLoader):
    """YAML 1.2 floats: PyYAML (YAML 1.1) reads `1.0e5` and `1e5` as strings, rcl_yaml reads numbers."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
    |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
    |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
    |[-+]?\.(?:inf|Inf|INF)
    |\.(?:nan|NaN|NAN))$""", re.X),
    list("-+0123456789."),
)


def safe_load(text):
    return yaml.load(text, Loader=_Loader)


class ParamError(ValueError):
    """A parameter that cannot be used; the message names the node, the key and the value."""


@dataclass(frozen=True)
class Param:
    kind: type                 # float, int, bool, str, list
    default: object            # the one default of the project (config/softhand.yaml is written from it)
    unit: str                  # SI unit or "-"
    doc: str                   # meaning and source (the ROS parameter description)
    low: float | None = None   # inclusive lower bound (numbers)
    high: float | None = None  # inclusive upper bound (numbers)
    positive: bool = False     # strictly > 0 (stiffness, rates, masses)
    choices: tuple | None = None
    size: int | None = None    # exact length (lists)


P = Param
_PAPER = "paper Sect. 5.1"

# sim_node: SimRuntime and the solver model (physics/model.py, physics/solver.py) read these
# names as they are; build_model(asset, {key: value}) takes any of them.
SIM = {
    "sim_rate": P(float, 0.0, "Hz", "full-simulation step rate; dt = 1/sim_rate (the paper reaches 45-65 steps/s); "
                  "0 = by hand count: 200 Hz for one hand (lag and latency, README 'Following without lag'), "
                  "50 Hz for two (what two hands keep on two cores beside the other nodes); else 10-2000", 0, 2000),
    "max_step": P(float, 0.05, "s", "keep real time when the machine cannot keep sim_rate: a late tick steps the "
                  "time since the previous one, up to this long (0 or <= 1/sim_rate: always 1/sim_rate, and an "
                  "overloaded node falls behind real time while it reads the hand's targets and the world's "
                  "objects at the clock's time: the fine hand at 200 Hz stepping at 134-144 Hz threw its gripped "
                  "ball; sim_node warns then)", 0.0, 0.2),
    "hand_side": P(str, "right", "-", "which hand to simulate when `hands` is empty", choices=("right", "left")),
    "hand_measures": P(str, "default", "-", "the simulated hand's size: 'default' (19 cm), a measures file written by "
                       "`softhand calibrate`, or 'auto': the first second of tracker frames (/tracker/{side}/hand_joints) "
                       "is fitted and nothing is simulated until the hand at that size is ready (a few seconds); "
                       "auto sizes one hand: refused with two `hands`"),
    # [""], not []: ROS cannot type an empty list; empty entries are ignored
    "hands": P(list, [""], "-", "hands to simulate in one solver: [right], [left] or [right, left] "
               "(empty: the one hand of hand_side)"),
    "mesh": P(str, "coarse", "-", "tissue resolution: coarse (~850 tets, paper 856) or fine (~8.5k)",
              choices=("coarse", "fine")),
    "youngs_modulus": P(float, 1.0e5, "Pa", f"tissue Young's modulus ({_PAPER}: 1e5)", positive=True),
    "poisson_ratio": P(float, 0.33, "-", f"tissue Poisson ratio ({_PAPER}: 0.33)", 0.0, 0.49),
    "tissue_density": P(float, 1000.0, "kg/m^3", "soft tissue density, lumped onto the nodes (water-like; not in the paper)",
                        positive=True),
    "nonlinear_w_max": P(float, 2500.0, "J/m^3", f"energy density threshold W_max of Eq. 8 ({_PAPER}: 2500)", positive=True),
    "nonlinear_k": P(float, 1000.0, "J/m^3", f"nonlinear stiffness k of Eq. 8 ({_PAPER}: 1000); 0 = linear co-rotational", 0.0),
    "tissue_stress_stiffness": P(bool, True, "-", "add the rotation (stress) stiffness the co-rotational tissue Hessian "
                                 "leaves out, kept PSD (energies/tissue.py): stretched tissue stays stable with one "
                                 "Newton step per time step; off = the fixed-rotation Hessian of Eq. 10"),
    "tissue_hessian_tolerance": P(float, 0.01, "rad", "keep a tet's tissue Hessian from the state it was last assembled "
                                  "at until its rotation turns (or its stretch R^T F changes) by more than this; the "
                                  "energy and gradient stay exact; 0 = every tet every step", 0.0, 0.5),
    "polar_iterations": P(int, 1, "-", "Newton iterations per step of the warm-started polar decomposition giving "
                          "each tet's rotation (each squares its error)", 1, 100),
    "bone_tissue_k_total": P(float, 3.2e6, "N/m", f"bone-tissue total coupling stiffness k_total of Eq. 11 ({_PAPER}: 3.2e6)",
                             positive=True),
    "joint_stiffness": P(float, 2.0e5, "N/m", f"skeletal joint stiffness of Eq. 6 ({_PAPER}: 2e5)", positive=True),
    "joint_axis_stiffness": P(float, 20.0, "N*m/rad", "stiffness locking the fixed axes of hinge and universal joints "
                              "(not in the paper: 2e5 N/m x (1 cm)^2)", 0.0),
    "joint_limit_stiffness": P(float, 200.0, "N*m/rad", "stiffness of the joint-limit penalty; 0 = no limits (not in the paper)",
                               0.0),
    "tracking_kx": P(float, 500.0, "N/m", f"palm linear coupling to the intermediate palm, Eq. 14 ({_PAPER}: 50). 10x the "
                     "paper: the palm carries a held object twice (both ball instances feel gravity); in series with "
                     "tracking_node's sim_kx 500 that is 250 N/m, 8 mm sag for 2 N", positive=True),
    "tracking_kx_phalanx": P(float, 0.0, "N/m", "phalanx linear coupling to the intermediate bones, Eq. 14 "
                             "(paper Sect. 3.6: 0, the joints carry the phalanxes)", 0.0),
    "tracking_ktheta": P(float, 200.0, "N*m/rad", f"angular coupling of every bone to its intermediate bone, Eq. 14 "
                         f"({_PAPER}: 200)", positive=True),
    "object_kx": P(float, 170.0, "N/m", f"hand<->engine object linear coupling, Eq. 14 ({_PAPER}: 170)", positive=True),
    "object_ktheta": P(float, 70.0, "N*m/rad", f"hand<->engine object angular coupling, Eq. 14 ({_PAPER}: 70)", positive=True),
    "object_max_omega": P(float, 45.0, "rad/s", "cap on sqrt(k/m), sqrt(ktheta/I) of the object coupling "
                          "(same as world_node's coupling_max_omega)", positive=True),
    "contact_kn": P(float, 3.0e7, "N/m^3", "normal contact stiffness k_n of Eq. 12 per unit vertex area (not in the paper)",
                    positive=True),
    "contact_kf": P(float, 1.5e7, "N/m^3", "tangential (friction) stiffness k_f of Eq. 13 per unit vertex area "
                    "(not in the paper); the Coulomb mu of each contact is the scene's friction", positive=True),
    "self_contact": P(bool, False, "-", "skin-skin contact of the hands (fingers, palm, hand on hand) in the same "
                      "Newton step as the rest (physics/contact/self_contact.py; one coarse hand on the benchmark: "
                      "free motion 2.2 ms a step against 1.3 ms without, a tight fist 2.8-3.0 ms); off: the skins "
                      "pass through each other"),
    "self_contact_kn": P(float, 1.0e8, "N/m^3", "normal stiffness k_n of skin-skin contact within one hand per unit vertex "
                         "area (Eq. 12 between two skins; 3x contact_kn: pinched pads stay within 1 mm)", positive=True),
    "self_contact_kn_hands": P(float, 3.0e8, "N/m^3", "normal stiffness of skin-skin contact between the two hands (k_f "
                               "scaled alike): palms pressed together stay within 1.5 mm", positive=True),
    "self_contact_kn_deep": P(float, 1.0e10, "N/m^3", "normal stiffness added to self_contact_kn (and to "
                              "self_contact_kn_hands, in proportion) where skin lies deeper than "
                              "self_contact_deep_from inside another segment (0: the tight fist 3.00 mm deep, "
                              "1e10: 1.32 mm; README)", 0.0),
    "self_contact_deep_from": P(float, 0.0009, "m", "depth beyond which skin-skin contact stiffens by "
                                "self_contact_kn_deep (1 mm: the tight fist 1.53 mm deep with exact tet "
                                "rotations)", 0.0),
    "self_contact_kf": P(float, 5.0e7, "N/m^3", "friction stiffness k_f of skin-skin contact per unit vertex area (Eq. 13)",
                         positive=True),
    "self_contact_friction": P(float, 0.5, "-", "Coulomb mu of skin on skin (self contact, physics/contact/self_contact.py)",
                               0.0),
    "self_contact_capacity": P(int, 4096, "-", "cap on active skin-skin contacts per step (bounds the cost; the rest "
                               "are counted as dropped)", 0, 1000000),
    "self_contact_rest_clearance": P(float, 0.0015, "m", "a skin point never touches a segment whose skin lies this "
                                     "close at rest (finger webs, the thumb's base): the self-contact rule besides "
                                     "'adjacent bones never touch'", 0.0),
    "self_contact_margin": P(float, 0.0005, "m", "self contact: points closer than this to the other segment's rest "
                             "field are checked against its deformed skin", 0.0),
    "gravity": P(list, [0.0, 0.0, -9.81], "m/s^2", "gravity vector of the hand side, world frame "
                 "(world_node's gravity is its magnitude along -z: keep the two equal)", size=3),
    "gravity_bones": P(bool, False, "-", "apply gravity to the bones (off: the user's arm carries the hand; with "
                       "gravity the palm coupling lets it sag)"),
    "gravity_tissue": P(bool, False, "-", "apply gravity to the tissue nodes (off: same reason; objects keep gravity)"),
    "gravity_objects": P(bool, True, "-", "apply gravity to the hand-side object instances"),
    "cg_tolerance": P(float, 1.0e-5, "-", "relative residual tolerance of PCG (paper: 1e-5)", 1e-12, 1e-1),
    "cg_velocity_floor": P(float, 1.0e-5, "m/s", "PCG also stops once no node's velocity error can exceed this "
                           "(its energy-norm bound, pcg.pcg): the relative tolerance alone asks 1e-5 of a "
                           "right-hand side that vanishes in a held pose (12 iterations per step of a held fist "
                           "for residuals of 1e-15 N s); 1e-5 m/s is 0.17 um per 60 Hz step; 0: off", 0.0),
    "cg_max_iterations": P(int, 200, "-", "PCG iteration cap: bounds the cost of a step", 1, 100000),
    "preconditioner": P(str, "factor", "-", "PCG preconditioner: factor (sparse block LDL^T of the system matrix, "
                        "refreshed over several steps), two_level (Gauss-Seidel sweeps around a correction on the "
                        "coarse hand's mesh: no factor of the fine system; for mesh fine in free motion), jacobi (the "
                        "paper's) or block_jacobi (3x3 node, 6x6 body blocks)",
                        choices=("factor", "two_level", "jacobi", "block_jacobi")),
    "factor_refresh_steps": P(int, 50, "-", "factor preconditioner: a new factorization at least every this many steps "
                              "(computed in as many slices, one per step)", 1, 100000),
    "factor_refresh_iterations": P(int, 8, "-", "factor preconditioner: refresh twice as fast after a CG that took "
                                   "more iterations than this, and factor the next step's matrix whole after one "
                                   "that took more than 4 times this", 0, 100000),
    "factor_hold": P(float, 1.0, "-", "factor preconditioner: keep the factor in use, and start no new "
                     "factorization, while the CG iterations it costs beyond one a step, summed since it "
                     "came into use, stay under this fraction of a factorization's cost (counted in "
                     "iterations, estimated from their sizes; physics/factor_hold.py): a hand that holds still or "
                     "moves little reuses its factor for many steps; 1: until the held steps have cost "
                     "one factorization; 0: a new factorization as soon as the last is done", 0.0, 100.0),
    "factor_cost_scale": P(float, 1.0, "-", "factor preconditioner: multiplies the estimated cost of a "
                           "factorization in CG iterations (from its flops, the size of the solves' panels and kernel speeds measured on "
                           "the project's 2-core test machine), factor_hold's unit and what sets the slice count; "
                           "`softhand bench --profile` measures the ratio on your machine and prints the value "
                           "that matches it", 0.01, 100.0),
    "factor_background": P(bool, False, "-", "factor preconditioner: run the factorizations that are spread "
                           "over several steps (the fine hand's) whole on a thread of its own while the steps go "
                           "on, instead of a slice in each step: each factor comes into use at the first step "
                           "after it is done and the next one starts, none is held; a lower p99 step, but a "
                           "second core busy and a run that repeats only to CG's tolerance (the factor a step "
                           "uses depends on the thread's timing); for a core to spare (one hand on two cores; "
                           "refused when solver_threads takes every core)"),
    "two_level_refresh_steps": P(int, 12, "-", "two_level preconditioner: its coarse matrix P^T A P and that matrix's "
                                 "factor computed anew every this many steps, spread over them (the whole of it "
                                 "after a CG that took more than 4 times factor_refresh_iterations)", 1, 100000),
    "solver_threads": P(int, 1, "-", "threads of the step with two hands: 2 runs the hands' tissue, "
                        "factorization and triangular solves and the matrix products on two cores "
                        "(physics/parallel.py; the same results to round-off; OpenMP threads spin briefly "
                        "between the step's parallel parts); 1: one thread, leaving the other core to the "
                        "tracking, world and recording nodes; one hand always runs on one thread", 1, 64),
    "scene_file": P(str, "", "-", "scene file (empty: config/scene.yaml)"),
    "copy_timeout": P(float, 0.5, "s", "an engine copy older than this decouples its object", positive=True),
    "target_feed_forward": P(bool, True, "-", "move each hand's bone targets to the end of the step with their "
                             "velocity (at most 40 ms past their stamp), only while the skin is 2 cm or more from "
                             "every object (target_lead.py): leap_grab's simulated lag 23.5 / 32.3 -> 13.2 / 22.4 "
                             "ms (phalanx / palm); false: the paper's targets as they came"),
    "target_acceleration": P(bool, True, "-", "with target_feed_forward: load every mass of a hand with its palm "
                             "target's acceleration (the inertial load of an accelerating frame), so the palm's "
                             "spring need not stretch to carry the hand; off where the lead is off, near objects "
                             "(target_lead.py): leap_grab's simulated palm lag 27.5 -> 18.6 ms"),
    "extrapolate": P(bool, False, "-", "extrapolate engine copies with constant acceleration (Sect. 3.7): off, measured "
                     "to throw a held ball once copies arrive >= 50 ms late (a loaded machine); plain copies held it"),
    "skin_marker_rate": P(float, 10.0, "Hz", "rate of /hand/{side}/skin_marker and /hand/contact_markers",
                          positive=True),
    "publish_skin_vertices": P(bool, True, "-", "publish /hand/{side}/skin_vertices (only while someone "
                               "subscribes)"),
    "skin_vertices_rate": P(float, 0.0, "Hz", "rate of /hand/{side}/skin_vertices; 0 = every step (sim_rate). "
                            "~142 kB per message: 8.5 MB/s per hand at 60 Hz on a remote viewer's link",
                            0.0, 2000.0),
    "diagnostics_rate": P(float, 1.0, "Hz", "rate of /diagnostics", positive=True),
}

TRACKING = {
    "rate": P(float, 250.0, "Hz", "intermediate-bone loop rate (paper Sect. 5.1: 250)", 10, 2000, positive=True),
    "hand": P(str, "right", "-", "tracked hand: its topics /tracker/{hand}/hand_joints, /hand/{hand}/bones "
              "-> /hand/{hand}/intermediate_bones (a second hand: a second node, -r __node:=tracking_node_left)",
              choices=("right", "left")),
    "tracked_kx": P(float, 500.0, "N/m", "coupling of each intermediate bone to its tracked bone, linear "
                    "(paper: 50; 500 as sim_node's tracking_kx)", positive=True),
    "tracked_ktheta": P(float, 200.0, "N*m/rad", "coupling to the tracked bone, angular (paper: 200)", positive=True),
    "sim_kx": P(float, 500.0, "N/m", "palm coupling to the full-simulation copy, linear (paper: 50; phalanxes 0)",
                positive=True),
    "sim_ktheta": P(float, 200.0, "N*m/rad", "coupling to the full-simulation copy, angular (paper: 200)", positive=True),
    "damping_ratio": P(float, 1.0, "-", "critical-damping fraction of each tracked coupling "
                       "(0: the paper's plain springs overshoot 67%)", 0.0, 5.0),
    "feedback": P(str, "contact", "-", "coupling of the intermediate bones to the simulated ones (sim_kx, sim_ktheta): "
                  "always (the paper) or contact (only while the simulated hand touches something: no lag from "
                  "it in free air)", choices=("always", "contact")),
    "extrapolate": P(bool, True, "-", "move the tracked targets forward to each step's time with the tracked "
                     "velocity (at most 30 ms): no lag from holding a frame until the next"),
    "lead": P(float, 0.0, "s", "publish the intermediate bones moved this far ahead with their own velocity, "
              "stamped with that time (sim_node steps to t + 1/sim_rate with the latest ones)", 0.0, 0.05),
    "ref_smoothing": P(float, 0.015, "s", "time constant of the low-pass filter on the tracked velocity "
                       "(damping reference and extrapolation); 0: none", 0.0, 1.0),
    "joint_filter": P(str, "none", "-", "filter on the tracked joint positions before the loop: none, or one_euro "
                      "(a low-pass, relative to the wrist, whose cutoff rises with each joint's speed: "
                      "removes the tracker's jitter from a still hand; costs the fingers 6-7 ms of lag in motion)",
                      choices=("none", "one_euro")),
    "joint_filter_min_cutoff": P(float, 1.0, "Hz", "one_euro: cutoff of a still joint", positive=True),
    "joint_filter_beta": P(float, 30.0, "s/m", "one_euro: cutoff [Hz] added per m/s of joint speed", 0.0),
    "tracker_timeout": P(float, 0.1, "s", "hold the last target when no valid frame arrived for this long", positive=True),
    "sim_timeout": P(float, 0.5, "s", "forget the full-simulation copy when /hand/{hand}/bones is older than this",
                     positive=True),
    "tracker_to_world": P(list, [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], "m, quaternion",
                          "tracker->world transform [px py pz qx qy qz qw]", size=7),
    "hand_measures": P(str, "default", "-", "the intermediate bones' masses and centres of mass: 'default' (the "
                       "19 cm hand), a measures file written by `softhand calibrate` (as sim_node's), or 'auto': "
                       "the first second of valid tracker frames is fitted (as sim_node's auto) and the loop "
                       "takes that hand's bones from then on"),
    "min_bone_length": P(float, 0.005, "m", "shorter tracked bones reject the frame", 0.0),
    "max_bone_length": P(float, 0.15, "m", "longer tracked bones reject the frame", positive=True),
    "diagnostics_rate": P(float, 1.0, "Hz", "rate of /diagnostics", positive=True),
}

WORLD = {
    "engine_rate": P(float, 120.0, "Hz", "pybullet step rate (paper: 60-120)", 60, 120),
    "scene_file": P(str, "", "-", "scene file (empty: config/scene.yaml)"),
    "coupling_kx": P(float, 170.0, "N/m", "engine<->hand object coupling, linear, Eq. 14 (paper: 170)", positive=True),
    "coupling_ktheta": P(float, 70.0, "N*m/rad", "engine<->hand object coupling, angular, Eq. 14 (paper: 70)",
                         positive=True),
    "coupling_damping": P(float, 1.0, "-", "damping ratio of the engine-side coupling spring (0: the paper's plain "
                          "spring, which a copy older than ~60 ms drives unstable; 1: critical, stable to ~100 ms)",
                          0.0, 2.0),
    "coupling_mode": P(str, "implicit", "-", "implicit: backward-Euler coupling force (stable); explicit: the paper's "
                       "plain spring at t", choices=("implicit", "explicit")),
    "coupling_max_omega": P(float, 45.0, "rad/s", "cap on sqrt(k/m) and sqrt(ktheta/I) of the coupling: keeps the copy "
                            "exchange stable for light objects (the paper's 70 N*m/rad on a 4 cm ball is ~1200 rad/s)",
                            positive=True),
    "copy_timeout": P(float, 0.5, "s", "a hand copy older than this decouples its object", positive=True),
    "extrapolate": P(bool, False, "-", "extrapolate hand copies with constant acceleration (Sect. 3.7): off, "
                     "as sim_node's"),
    "gravity": P(float, 9.81, "m/s^2", "gravity along -z", 0.0),
    "marker_rate": P(float, 10.0, "Hz", "rate of /world/markers", positive=True),
    "diagnostics_rate": P(float, 1.0, "Hz", "rate of /diagnostics", positive=True),
}

PLAY = {
    "bag": P(str, "", "-", "tracker rosbag2 directory (mcap or sqlite3) to replay"),
    "rate": P(float, 1.0, "-", "playback speed factor (1 = recorded timing)", positive=True),
    "loop": P(bool, False, "-", "start again at the end"),
    "repeat": P(int, 1, "-", "play the bag this many times, each after the last on the same timeline (loop: "
                "forever); e.g. to give hand_measures auto, which sizes the hand from the first tracked "
                "second, a short recording to follow afterwards", 1, 1000),
    "start": P(float, 0.0, "s", "skip this much of the bag", 0.0),
    "topic": P(str, "", "-", "tracker topic of the bag to play (empty: every tracker topic in it, "
               "/tracker/{right,left}/hand_joints interleaved in time and the legacy /tracker/hand_joints)"),
    "hand": P(str, "right", "-", "the side the legacy /tracker/hand_joints of an older bag is played as "
              "(/tracker/{hand}/hand_joints); side topics keep their names", choices=("right", "left")),
    "publish_clock": P(bool, True, "-", "publish /clock with the bag time"),
    "clock_rate": P(float, 250.0, "Hz", "/clock ticks per second between messages (0: only with messages)", 0.0, 1e4),
    "wait_subscribers": P(int, 0, "-", "wait until this many subscriptions match the replayed topics (all "
                          "together) before playing", 0, 1000),
    # [""], not []: ROS cannot type an empty list; empty entries are ignored
    "wait_for_nodes": P(list, [""], "-", "wait until each of these nodes subscribes to a replayed topic and is "
                        "matched on every replayed topic it subscribes to before playing (the demo names its "
                        "tracking nodes and record_node)"),
    "wait_timeout": P(float, 30.0, "s", "give up waiting for subscribers after this long", 0.0),
    "stamps": P(str, "publish", "-", "header stamps of the replayed frames: publish = their publish time on the "
                "run's clock, as a live tracker stamps its capture; recorded = as in the bag",
                choices=("publish", "recorded")),
    # [""], not []: ROS cannot type an empty list; empty entries are ignored
    "replay_topics": P(list, [""], "-", "replay these topics of any type raw with their recorded QoS (empty: the tracker topics)"),
    "replay_all": P(bool, False, "-", "replay every topic of the recording raw with its recorded QoS"),
}

RECORD = {
    "output": P(str, "", "-", "rosbag2 directory to create (empty: runs/<stamp>/bag)"),
    # [""], not []: ROS cannot type an empty list; empty entries are ignored
    "topics": P(list, [""], "-", "topics to record (empty: every softhand topic of both hands but "
                 "/hand/{side}/skin_vertices)"),
    "record_skin_vertices": P(bool, False, "-", "also record /hand/right/skin_vertices and "
                              "/hand/left/skin_vertices (large)"),
    "progress_period": P(float, 5.0, "s", "how often to log messages/MB written", 0.1, 3600.0),
    "flush_period": P(float, 1.0, "s", "write the pending mcap chunk this often (bounds what a SIGKILL loses)",
                      0.05, 3600.0),
    "discovery_period": P(float, 0.2, "s", "look for newly published wanted topics this often", 0.01, 60.0),
    "stamp_source": P(str, "receive", "-", "bag timestamp of each message", choices=("receive", "header")),
    "diagnostics_rate": P(float, 1.0, "Hz", "how often /diagnostics reports what is recorded and each hand's "
                          "live lag behind the tracked hand (softhand_sim/live_lag.py)", 0.01, 100.0),
    "live_lag": P(bool, True, "-", "measure each hand's lag from the tracker, intermediate and bones topics "
                  "recorded (about 50 ms of CPU per report; with two hands they take turns, each hand's "
                  "figures refreshed every second report)"),
}

SCHEMA = {
    "sim_node": SIM,
    "tracking_node": TRACKING,
    "world_node": WORLD,
    "play_node": PLAY,
    "record_node": RECORD,
}


def check_value(node: str, key: str, value, schema=None):
    """Validate one value; returns it converted (int -> float where a float is expected)."""
    schema = SCHEMA[node] if schema is None else schema
    if key not in schema:
        raise ParamError(f"{node}: unknown parameter {key!r} (known: {', '.join(sorted(schema))})")
    p = schema[key]
    where = f"{node}: parameter {key!r}"
    if p.kind is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ParamError(f"{where} must be a number [{p.unit}], got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise ParamError(f"{where} must be finite, got {value!r}")
    elif p.kind is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ParamError(f"{where} must be an integer, got {value!r}")
    elif p.kind is bool:
        if not isinstance(value, bool):
            raise ParamError(f"{where} must be true or false, got {value!r}")
    elif p.kind is str:
        if not isinstance(value, str):
            raise ParamError(f"{where} must be a string, got {value!r}")
    elif p.kind is list:
        if not isinstance(value, (list, tuple)):
            raise ParamError(f"{where} must be a list, got {value!r}")
        value = list(value)
        if p.size is not None and len(value) != p.size:
            raise ParamError(f"{where} must be a list of {p.size} values [{p.unit}], got {value!r}")
    if p.kind in (int, float):
        if p.positive and value <= 0:
            raise ParamError(f"{where} must be > 0 [{p.unit}], got {value!r}")
        if p.low is not None and value < p.low:
            raise ParamError(f"{where} must be >= {p.low} [{p.unit}], got {value!r}")
        if p.high is not None and value > p.high:
            raise ParamError(f"{where} must be <= {p.high} [{p.unit}], got {value!r}")
    if p.choices is not None and value not in p.choices:
        raise ParamError(f"{where} must be one of {list(p.choices)}, got {value!r}")
    return value


# sim_rate 0: the rate by hand count. One hand steps at 200 Hz: through the node set its step is
# shorter than at 150 (1.5-2.3 ms p50 against 1.9-2.7: smaller steps leave CG less to do) and a
# tracker frame waits at most 5 ms for the next one, so the tracker -> bones latency p99 was 5.5-9.9
# ms in nine demos (150 Hz: 7.6-15.2 ms, over 10 in 4 of 11 bags) and leap_grab's palm lag 11.7-11.9
# ms (150 Hz: 12.7-14.2; the goal is 15); README, "Following without lag". Two hands at these rates
# do not fit on two cores. They stepped at 60 Hz until the machine ran slower: then the two-hand
# demos overran 6-12 % of their ticks at 60 Hz (52-55 steps/s) and 0.5-5.8 % at 50 (README, "Two
# hands"), so two hands keep 50.
AUTO_SIM_RATE = {1: 200.0, 2: 50.0}  # hands -> Hz


def sim_rate_hz(params, n_hands: int) -> float:
    """The step rate [Hz] of sim_node's `sim_rate` for `n_hands` hands: the parameter's value, or
    with 0 the rate by hand count (AUTO_SIM_RATE). ParamError on a rate between 0 and 10 Hz."""
    rate = float(params["sim_rate"])
    if rate == 0.0:
        return AUTO_SIM_RATE[n_hands]
    if rate < 10.0:
        raise ParamError(f"sim_node: parameter 'sim_rate' must be 0 (by hand count) or 10-2000 [Hz], got {rate!r}")
    return rate


def read_params_file(path) -> dict:
    """The raw {node: {key: value}} of a ROS 2 params file (node: ros__parameters: {...})."""
    path = Path(path)
    if not path.is_file():
        raise ParamError(f"parameter file not found: {path}")
    try:
        raw = safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise ParamError(f"parameter file {path} is not valid YAML: {exc}") from None
    out = {}
    for node, section in raw.items():
        node_name = node.lstrip("/").split("/")[-1]  # "/**", "/ns/node" -> node name
        if not isinstance(section, dict) or not isinstance(section.get("ros__parameters"), dict):
            raise ParamError(f"parameter file {path}: section {node!r} needs a 'ros__parameters' mapping")
        out.setdefault(node_name, {}).update(section["ros__parameters"])
    return out


def defaults(node: str) -> dict:
    """The default parameters of `node` (fresh copies: callers may change lists)."""
    if node not in SCHEMA:
        raise ParamError(f"unknown node {node!r} (known: {', '.join(SCHEMA)})")
    return {k: list(p.default) if p.kind is list else p.default for k, p in SCHEMA[node].items()}


def descriptions(node: str) -> dict:
    """{key: (description, (low, high))} for ROS parameter descriptors: the meaning with its unit,
    and the inclusive numeric range (None where a side is open or the key is not a number).

    `positive` keys (> 0) report low None: a ROS range is inclusive; check_value enforces them.
    """
    out = {}
    for key, p in SCHEMA[node].items():
        text = f"{p.doc} [{p.unit}]"
        if p.choices is not None:
            text += f"; one of {', '.join(p.choices)}"
        out[key] = (text, (p.low, p.high) if p.kind in (int, float) else (None, None))
    return out


def _yaml_value(value) -> str:
    """One value as the params file writes it (floats always with a point or exponent: rcl types them)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if value == 0.0 or 1e-3 <= abs(value) < 1e5 or not math.isfinite(value):
            return repr(value)
        mant, exp = format(Decimal(repr(value)).normalize(), "e").split("e")  # shortest digits
        return f"{mant if '.' in mant else mant + '.0'}e{int(exp)}"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str):
        return '""' if value == "" else value if re.fullmatch(r"[A-Za-z_/][A-Za-z0-9_/.-]*", value) else repr(value)
    return "[" + ", ".join(_yaml_value(v) for v in value) + "]"


_HEADER = """\
# softhand parameters, ROS 2 params-file format: one section per node name.
# GENERATED from the schema in softhand_sim/softhand_sim/params.py (`softhand params --yaml FILE`);
# edit the schema, not this file (tests/config/test_params.py fails when the two disagree).
# Units are SI; "paper" = the paper's Sect. 5.1 values. Every key is checked at start: unknown
# keys, wrong types and out-of-range values are refused with a message naming the key and the
# value. Use with
#   ros2 run softhand_sim sim_node --ros-args --params-file config/softhand.yaml
# or any copy of it (only the keys you change are needed in your own file).
"""


def params_yaml(width: int = 110) -> str:
    """The text of config/softhand.yaml: every node's defaults, each with its unit and meaning."""
    lines = [_HEADER.rstrip("\n")]
    for node, schema in SCHEMA.items():
        lines += ["", f"{node}:", "  ros__parameters:"]
        for key, p in schema.items():
            head = f"    {key}: {_yaml_value(p.default)}"
            words = ((f"[{p.unit}] " if p.unit != "-" else "") + (" | ".join(p.choices) + ": " if p.choices else "")
                     + p.doc)
            col = max(len(head) + 1, 34)
            comment = []
            for word in words.split():
                if comment and col + 2 + len(comment[-1]) + 1 + len(word) <= width:
                    comment[-1] += " " + word
                else:
                    comment.append(word)
            lines.append(f"{head:{col}s}# {comment[0]}")
            lines += [f"{'':{col}s}# {c}" for c in comment[1:]]
    return "\n".join(lines) + "\n"


def load_params(node: str, params_file=None, overrides=None) -> dict:
    """Defaults, then a user params file's section for `node`, then overrides; all validated."""
    if node not in SCHEMA:
        raise ParamError(f"unknown node {node!r} (known: {', '.join(SCHEMA)})")
    values = defaults(node)
    if params_file is not None:
        for k, v in read_params_file(params_file).get(node, {}).items():
            values[k] = check_value(node, k, v)
    for k, v in (overrides or {}).items():
        values[k] = check_value(node, k, v)
    return values
