"""`softhand fidelity BAG`: how closely the simulated hand follows the tracked one.

Two sources:
* a recording (`softhand demo` run bag, or any bag with /tracker/hand_joints and /hand/bones):
  the tracked frames and the simulated bones it holds, times from their header stamps;
* --offline: a tracker bag run through the offline pipeline (softhand_sim.commands.offline,
  deterministic, no ROS) with the default hand or the hand at --measures (a measures file, or
  `auto`: calibrated on the bag's first second, as `softhand calibrate` does).
Prints the figures of softhand_sim.handmodel.fidelity (palm, knuckle, fingertip position error,
phalanx direction error, thumb-index tip gap) as JSON.
"""
import argparse
import json
import sys
import time

import numpy as np

from softhand_sim.handmodel.fidelity import fidelity
from softhand_sim.handmodel.measures import HandMeasures, read_measures_file

TRACKER = ("/tracker/hand_joints", "geometry_msgs/msg/PoseArray")
BONES = ("/hand/bones", "geometry_msgs/msg/PoseArray")


def _poses(path, topic, msgtype):
    """(header times [s], poses (n, m, 7)) of a PoseArray topic."""
    from softhand_sim.ros.bagio import deserialize, read_topic
    data = read_topic(path, topic, msgtype)
    t, poses = [], []
    for raw in data.payloads:
        msg = deserialize(raw, msgtype)
        t.append(msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec)
        poses.append([(p.position.x, p.position.y, p.position.z, p.orientation.x, p.orientation.y,
                       p.orientation.z, p.orientation.w) for p in msg.poses])
    return np.asarray(t), np.asarray(poses, dtype=float)


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


def recorded_fidelity(bag, measures):
    from softhand_sim.handmodel.skeleton import build_skeleton
    tt, tj = _poses(bag, *TRACKER)
    order = np.argsort(tt, kind="stable")
    st, sb = _poses(bag, *BONES)
    return fidelity(tt[order], tj[order], st, sb, build_skeleton(measures)["bone_length"])


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
    parser.add_argument("bag", help="a recording with /tracker/hand_joints and /hand/bones; with --offline a tracker bag "
                                    "(directory or name in bags/)")
    parser.add_argument("--offline", action="store_true", help="run the offline pipeline over the tracker bag first")
    parser.add_argument("--measures", default=None, help="the simulated hand: a measures file, 'auto' (calibrate on "
                                                         "the bag's first second) or 'default' (default)")
    args = parser.parse_args(argv)
    from softhand_sim.ros.bagio import BagError
    try:
        m = measures_for(args.measures, args.bag)
        if args.offline:
            figures, build_s = offline_fidelity(args.bag, m)
            figures["hand_build_or_load_s"] = round(build_s, 2)
        else:
            figures = recorded_fidelity(args.bag, m)
    except (BagError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    figures = dict(bag=str(args.bag), source="offline pipeline" if args.offline else "recording",
                   measures=args.measures or "default", **figures)
    print(json.dumps(figures))
    return 0
