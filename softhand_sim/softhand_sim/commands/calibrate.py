"""`softhand calibrate BAG`: the user's hand measures from a tracker recording (no ROS).

Reads /tracker/{hand}/hand_joints (or an old bag's /tracker/hand_joints) of BAG (a rosbag2 directory, or a name in bags/), fits the measures
on the first --seconds of valid frames (softhand_sim.handmodel.fit: median over the frames, outlier
frames rejected), prints them and writes a measures file that `softhand model info --measures`
and the nodes' `hand_measures` parameter read.
"""
import argparse
import json
import sys

from softhand_sim.handmodel.fit import fit_measures
from softhand_sim.handmodel.measures import write_measures_file


def main(argv=None):
    parser = argparse.ArgumentParser(prog="softhand calibrate", description=__doc__.splitlines()[0])
    parser.add_argument("bag", help="tracker bag: a rosbag2 directory or the name of one in bags/")
    parser.add_argument("--out", default="measures.yaml", help="measures file to write (default measures.yaml)")
    parser.add_argument("--seconds", type=float, default=1.0, help="calibration window [s] (default 1)")
    parser.add_argument("--hand", choices=("right", "left"), default="right",
                        help="the hand to calibrate: its /tracker/{hand}/hand_joints in a two-hand bag, or the one "
                             "hand of an old bag's /tracker/hand_joints (default right)")
    parser.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    args = parser.parse_args(argv)
    from softhand_sim.commands.offline import read_frames
    from softhand_sim.ros.bagio import BagError
    try:
        times, joints = read_frames(args.bag, side=args.hand)
        result = fit_measures(times, joints, seconds=args.seconds, hand=args.hand)
    except (BagError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    figures = result.summary()
    write_measures_file(args.out, result.measures,
                        f"hand measures of {args.bag}, calibrated by `softhand calibrate` on {figures['frames_used']} "
                        f"frames over {figures['window_s']} s\n[m]; finger widths and palm thickness are scaled "
                        "defaults (a PoseArray carries no joint radii)")
    figures["out"] = args.out
    if args.json:
        print(json.dumps(dict(figures, measures=result.measures.to_dict())))
        return 0
    names = ("palm", "thumb metacarpal", "thumb proximal", "thumb distal") + tuple(
        f"{f} {b}" for f in ("index", "middle", "ring", "little") for b in ("proximal", "intermediate", "distal"))
    print(f"hand measures of {args.bag}: {figures['frames_used']} of {figures['frames_window']} frames in the "
          f"first {figures['window_s']} s ({figures['frames_valid']} valid of {figures['frames_total']})")
    print(f"  wrist to middle tip {figures['wrist_to_middle_tip_mm']} mm, palm length {figures['palm_length_mm']} mm, "
          f"palm width {figures['palm_width_mm']} mm (knuckle span + scaled finger widths)")
    for name, length, spread in zip(names, figures["bone_lengths_mm"], figures["bone_length_spread_mm"]):
        print(f"  {name:20s} {length:6.1f} mm  (spread {spread:.2f} mm)")
    for name, p in zip(("index", "middle", "ring", "little"), figures["knuckles_mm"]):
        print(f"  {name} knuckle in the palm frame  {p} mm")
    print(f"  thumb CMC in the palm frame {figures['thumb_cmc_mm']} mm")
    for note in figures["notes"]:
        print(f"  note: {note}")
    print(f"wrote {args.out}")
    return 0
