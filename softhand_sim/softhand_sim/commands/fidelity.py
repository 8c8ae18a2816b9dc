"""`softhand fidelity BAG`: how closely the simulated hand follows the tracked one.

Two sources:
* a recording (`softhand demo` run bag, or any bag with /tracker/{side}/hand_joints and
  /hand/{side}/bones): the tracked frames and the simulated bones of each hand it holds (--hand:
  one of them), times from their header stamps; the simulated hand's bone lengths are the ones
  sim_node reported in the recording's /diagnostics (`hand_bone_lengths_mm`, whatever the
  measures' source: default, file or auto), unless --measures names others;
* --offline: a tracker bag run through the offline pipeline (softhand_sim.commands.offline,
  deterministic, no ROS) with the default hand or the hand at --measures (a measures file, or
  `auto`: calibrated on the bag's first second, as `softhand calibrate` does).
Prints the figures of softhand_sim.handmodel.fidelity (palm, knuckle, fingertip position error,
phalanx direction error, thumb-index tip gap) as JSON: one object, with the figures of each hand
under "hands" when a recording holds two. A recording's figures also hold what `softhand lag`
measures (softhand_sim.commands.lag): `lag_ms` (the best time shift of the intermediate and the
simulated phalanx directions and palm behind the tracked ones, `sim_free_air`: the simulated
hand's over its states 0.3 s or more from any contact, and `sim_off_dropouts`, in a recording
whose tracker lost the hand: over those free-air states outside each dropout and 0.3 s after it),
`palm_deg` (the simulated palm's orientation error), `frames` (tracker frames recorded, and
received / accepted / rejected by the hand's tracking node, and the tracker's dropouts) and
`skin_contacts` (skin on skin, with sim_node's self_contact: the
most in one step and the steps with any).
"""
import argparse
import json
import sys
import time

import numpy as np

from softhand_sim.handmodel.fidelity import fidelity
from softhand_sim.handmodel.measures import HandMeasures, read_measures_file
from softhand_sim.topics import POSE_ARRAY, SIDES, hand_topic, tracker_topic


def _poses(path, topic):
    """(header times [s], poses (n, m, 7)) of a PoseArray topic."""
    from softhand_sim.ros.bagio import read_topic
    return _decode(read_topic(path, topic, POSE_ARRAY).payloads)


def _decode(payloads):
    """(header times [s], poses (n, m, 7)) of PoseArray CDR payloads (ros.msgs.pose_array_from_cdr)."""
    from softhand_sim.ros.msgs import pose_array_from_cdr
    rows = [pose_array_from_cdr(raw) for raw in payloads]
    return np.array([r[1] * 1e-9 for r in rows]), np.array([r[0] for r in rows], dtype=float)


def measures_for(spec, bag=None, seconds=1.0):
    """HandMeasures for --measures: None -> defaults, 'auto' -> calibrated on `bag`, else a file."""
    if spec is None or spec == "default":
        return HandMeasures()
    if spec == "auto":
        from softhand_sim.commands.offline import read_frames
        from softhand_sim.handmodel.fit import fit_measures
        t, j = read_frames(bag)
        return fit_measures(t, j, seconds=seconds).measures
    return read_measures_file(spec)


def recorded_sides(bag):
    """The hands a recording holds both tracked frames and simulated bones of, in SIDES order
    (by message counts: a recorder lists every hand's topics, messages or not)."""
    from softhand_sim.ros.bagio import topic_counts
    counts = topic_counts(bag)
    return [s for s in SIDES if counts.get(tracker_topic(s)) and counts.get(hand_topic(s, "bones"))]


def recorded_measures(bag):
    """(bone lengths [m] (16,), source) of the hand sim_node simulated in a recording: the last
    sim_node /diagnostics status naming `hand_bone_lengths_mm` (with `auto`, the fitted hand's once
    it runs); (None, None) if no status names them (a recording made before they were reported)."""
    from softhand_sim.hand_sizer import bone_lengths_from_text
    from softhand_sim.ros.bagio import BagError, deserialize, read_topic
    from softhand_sim.ros.msgs import status_node
    try:
        payloads = read_topic(bag, "/diagnostics", "diagnostic_msgs/msg/DiagnosticArray").payloads
    except BagError:
        return None, None
    for raw in reversed(payloads):
        for status in deserialize(raw, "diagnostic_msgs/msg/DiagnosticArray").status:
            values = {kv.key: kv.value for kv in status.values}
            if status_node(status.name) == "sim_node" and "hand_bone_lengths_mm" in values \
                    and "hand_size_state" not in values:  # not while `auto` still sizes
                return bone_lengths_from_text(values["hand_bone_lengths_mm"]), values.get("hand_measures_source", "?")
    return None, None


def bone_lengths_of(bag, spec=None):
    """(bone lengths [m] (16,), label) of the hand to score a recording with: --measures `spec` if
    given, else the lengths sim_node reported in it, else the default hand's."""
    from softhand_sim.handmodel.skeleton import build_skeleton
    if spec is None:
        lengths, source = recorded_measures(bag)
        if lengths is not None:
            return lengths, f"recorded ({source})"
    label = spec or "default (the recording names no bone lengths)"
    return build_skeleton(measures_for(spec, bag))["bone_length"], label


def recorded_fidelity(bag, bone_length, side="right"):
    """The figures of hand `side` in a recording (/tracker/{side}/hand_joints vs /hand/{side}/bones),
    with its lag, palm orientation error and frame counts (module docstring); bone_length: the
    simulated hand's (16,) [m]."""
    from softhand_sim.commands.lag import REPORT_LAYERS, contact_steps, lag_report
    from softhand_sim.ros.bagio import read_tracker
    tt, tj = _decode(read_tracker(bag, side).payloads)
    order = np.argsort(tt, kind="stable")
    st, sb = _poses(bag, hand_topic(side, "bones"))
    figures = fidelity(tt[order], tj[order], st, sb, bone_length)
    contacts = contact_steps(bag, side)  # read once: the free-air lag and the skin counts
    lag = lag_report(bag, hand=side, contacts=contacts)
    def ms(v):  # None where the lag is not defined (that part of the tracked hand hardly moved)
        return round(v, 1) if np.isfinite(v) else None

    figures["lag_ms"] = {layer: {"phalanx": ms(lag[layer]["lag_phalanx_ms"]), "palm": ms(lag[layer]["lag_palm_ms"])}
                         for layer in REPORT_LAYERS if layer in lag}
    figures["lag_time_base"] = lag["time_base"]
    if "palm_deg" in lag.get("sim", {}):
        figures["palm_deg"] = {k: round(v, 2) for k, v in lag["sim"]["palm_deg"].items()}
    figures["frames"] = lag["frames"]
    figures["skin_contacts"] = skin_contact_counts(contacts)
    return figures


def skin_contact_counts(contacts) -> dict:
    """Skin-on-skin contacts of one hand (lag.contact_steps; sim parameter self_contact): the most
    in one step and the steps with any; zeros without /hand/contacts (None)."""
    if contacts is None:
        return {"max": 0, "steps": 0}
    return {"max": int(contacts.skin.max(initial=0)), "steps": int(np.count_nonzero(contacts.skin))}


def offline_fidelity(bag, measures):
    """Run the offline pipeline over tracker bag `bag` with the hand at `measures` (built or taken
    from the cache); returns (figures, hand build/load time [s])."""
    from softhand_sim.commands.offline import read_frames, run_pipeline
    from softhand_sim.handmodel.cache import load_or_build_hand
    t0 = time.perf_counter()
    asset = load_or_build_hand(measures)
    build_s = time.perf_counter() - t0
    st, sb = [], []

    def keep(out):
        st.append(out.t)
        sb.append(out.bone_poses.copy())

    times, joints = read_frames(bag)
    run_pipeline(bag, until=times[-1], progress=keep, asset=asset)
    return fidelity(times, joints, np.asarray(st), np.asarray(sb), asset.bone_length), build_s


def main(argv=None):
    parser = argparse.ArgumentParser(prog="softhand fidelity", description=__doc__.splitlines()[0])
    parser.add_argument("bag", help="a recording with /tracker/{side}/hand_joints and /hand/{side}/bones (or a demo "
                                    "run directory holding one in bag/); with "
                                    "--offline a tracker bag (directory or name in bags/)")
    parser.add_argument("--hand", choices=SIDES, default=None,
                        help="the hand to score (default: every hand the recording holds; right with --offline)")
    parser.add_argument("--offline", action="store_true", help="run the offline pipeline over the tracker bag first")
    parser.add_argument("--measures", default=None, help="the simulated hand: a measures file, 'auto' (calibrate on "
                                                         "the bag's first second) or 'default'; default: on a "
                                                         "recording, the bone lengths sim_node reported in it "
                                                         "(else the default hand), with --offline the default hand")
    args = parser.parse_args(argv)
    from pathlib import Path

    from softhand_sim.ros.bagio import BagError
    if not args.offline and (Path(args.bag) / "bag" / "metadata.yaml").is_file():
        args.bag = str(Path(args.bag) / "bag")  # a run directory (softhand demo's runs/<stamp>)
    measures_used = args.measures or "default"
    try:
        if args.offline:
            figures, build_s = offline_fidelity(args.bag, measures_for(args.measures, args.bag))
            figures["hand_build_or_load_s"] = round(build_s, 2)
            figures = dict(hand="right", **figures)
        else:
            sides = [args.hand] if args.hand else recorded_sides(args.bag)
            if not sides:
                raise ValueError(f"{args.bag} holds no hand with both /tracker/{{side}}/hand_joints and "
                                 "/hand/{side}/bones")
            bone_length, measures_used = bone_lengths_of(args.bag, args.measures)
            per_hand = {side: recorded_fidelity(args.bag, bone_length, side) for side in sides}
            figures = dict(hand=sides[0], **per_hand[sides[0]]) if len(sides) == 1 else {"hands": per_hand}
    except (BagError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    figures = dict(bag=str(args.bag), source="offline pipeline" if args.offline else "recording",
                   measures=measures_used, **figures)
    print(json.dumps(figures))
    return 0
