#!/usr/bin/env python3
"""Draw the default hand and the hand fitted to a real recording side by side, each simulated over
the recording (the offline pipeline, as `softhand fidelity --offline`) and seen at the same moment
from one fixed camera, with the tracked joints drawn on both and the fingertip error in each title.

    python tools/fit_picture.py [OUT.png]      # default docs/img/fit_side_by_side.png

Prints one JSON line of figures per hand (hand length, the pictured state and tracked frame,
fingertip error there and over the run).

The fitted hand has the measures `softhand calibrate BAG` writes (fit on the bag's first second),
or those of a measures file (--measures). Fingertip error: the distance between the simulated and
the tracked fingertips [mm], the mean of the five at the pictured moment, and the median over
every simulated state of the run (softhand_sim.handmodel.fidelity, so the pipeline's lag counts).
"""
import argparse
import json
import sys

import numpy as np

from softhand_sim.commands.offline import read_frames, run_pipeline
from softhand_sim.handmodel import HandMeasures, load_or_build_hand
from softhand_sim.handmodel.fidelity import fidelity, simulated_points
from softhand_sim.handmodel.fit import fit_measures, hand_length
from softhand_sim.handmodel.measures import read_measures_file
from softhand_sim.handmodel.render import render_panels
from softhand_sim.handmodel.skeleton_names import JOINT_INDEX

TIPS = [JOINT_INDEX[d + "_TIP"] for d in ("THUMB", "INDEX", "MIDDLE", "RING", "LITTLE")]
# leap_grab at 1.56 s: the hand open and still between its two fists (tips move ~5 cm/s)
DEFAULT_BAG, DEFAULT_TIME = "leap_grab", 1.56
DEFAULT_VIEW = "dorsal"  # from above: the Leap hand is palm down, fingers spread, 30-45 deg up


def simulate(bag, measures, t_picture, until):
    """Run the offline pipeline over `bag` with the hand at `measures` until `until` [s]. Returns
    the asset, the state times (k,) [s] and bone poses (k, 16, 7), and the skin vertices and bone
    poses of the first state at or after t_picture [s]."""
    asset = load_or_build_hand(measures)
    t, bones, picture = [], [], {}

    def keep(out):
        t.append(out.t)
        bones.append(out.bone_poses.copy())
        if not picture and out.t >= t_picture:
            picture.update(t=out.t, skin=out.skin_vertices.copy(), bones=out.bone_poses.copy())

    run_pipeline(bag, until=until, progress=keep, asset=asset)
    if not picture:
        raise ValueError(f"no simulated state at or after t = {t_picture} s (the run ends at {until} s)")
    return asset, np.asarray(t), np.asarray(bones), picture


def fingertip_error_mm(bones, bone_length, joints):
    """(mean distance [mm] of the simulated fingertips to the tracked ones, the simulated fingertips
    (5, 3) [m]) for one state's bone poses (16, 7) and one tracked frame's joints (26, 3+)."""
    tips = simulated_points(np.asarray(bones, dtype=np.float64), np.asarray(bone_length, dtype=np.float64))[2]
    return float(np.mean(np.linalg.norm(tips - np.asarray(joints)[TIPS, :3], axis=1)) * 1e3), tips


def panels(bag, hands, t_picture, until):
    """One panel dict per (label, measures) of `hands` (see render_panels), and the figures."""
    times, joints = read_frames(bag)
    out, figures = [], []
    for label, measures in hands:
        asset, st, sb, pic = simulate(bag, measures, t_picture, until)
        frame = int(np.searchsorted(times, pic["t"] + 1e-9, side="right") - 1)  # as fidelity() pairs them
        here, tips = fingertip_error_mm(pic["bones"], asset.bone_length, joints[frame])
        run = fidelity(times, joints, st, sb, asset.bone_length)["fingertip_mm"]["median"]
        length = hand_length(measures) * 1e3
        figures.append(dict(hand=label, hand_length_mm=round(length, 1), state_t_s=round(pic["t"], 3),
                            tracked_frame=frame, tracked_t_s=round(float(times[frame]), 3), fingertip_error_here_mm=round(here, 1), fingertip_error_median_mm=run))
        out.append(dict(skin_vertices=pic["skin"], skin_triangles=asset.skin_triangles, joints=joints[frame, :, :3],
                        marks=tips, title=f"{label}: {length:.0f} mm wrist to middle tip\n"
                                          f"fingertip error {here:.1f} mm here, median {run:.1f} mm over the run"))
    return out, figures


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", nargs="?", default="docs/img/fit_side_by_side.png", help="PNG to write")
    parser.add_argument("--bag", default=DEFAULT_BAG, help=f"tracker bag, name in bags/ or directory ({DEFAULT_BAG})")
    parser.add_argument("--time", type=float, default=DEFAULT_TIME, help=f"the pictured moment [s] ({DEFAULT_TIME})")
    parser.add_argument("--until", type=float, default=None, help="simulate until [s] (default: the bag's end)")
    parser.add_argument("--measures", default=None, help="the fitted hand's measures file (default: fit them on the "
                                                         "bag's first second, as `softhand calibrate` does)")
    parser.add_argument("--view", nargs="+", default=[DEFAULT_VIEW], metavar="VIEW",
                        help=f"camera: a view name (dorsal, palmar, side, front) or azimuth and elevation [deg] "
                             f"({DEFAULT_VIEW})")
    args = parser.parse_args(argv)
    view = args.view[0] if len(args.view) == 1 else tuple(float(v) for v in args.view)
    times, joints = read_frames(args.bag)
    fitted = read_measures_file(args.measures) if args.measures else fit_measures(times, joints, seconds=1.0).measures
    until = float(times[-1]) if args.until is None else args.until
    hands = (("default hand", HandMeasures()), ("fitted hand (softhand calibrate)", fitted))
    drawn, figures = panels(args.bag, hands, args.time, until)
    render_panels(drawn, args.out, view=view, panel_px=(440, 420),
                  legend=(f"tracked joints ({args.bag}, frame at t = {figures[0]['tracked_t_s']:.2f} s)",
                          "simulated fingertips"))
    for f in figures:
        print(json.dumps(f))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
