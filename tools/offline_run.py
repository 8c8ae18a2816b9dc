#!/usr/bin/env python3
"""Run the softhand pipeline offline (no ROS) over a bag and print the ball's lift, hold and fall.

    .venv/bin/python tools/offline_run.py grasp_lift [--synth] [--until 12] [--every 0.25]
        [--sim key=value ...] [--world key=value ...] [--tracking key=value ...]

The harness is tests/pipeline_offline.py (the same classes the nodes wrap, deterministic).
--synth samples softhand_tracking.bag_synth directly instead of reading bags/<name>.
"""
import argparse
import json
import sys
import time
from pathlib import Path



sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from pipeline_offline import run_pipeline  # noqa: E402
from softhand_sim.params import safe_load  # noqa: E402  (YAML 1.2 numbers: 1.0e8)


def _overrides(items):
    out = {}
    for item in items or ():
        key, _, value = item.partition("=")
        if not _:
            raise SystemExit(f"error: override {item!r} is not key=value")
        out[key] = safe_load(value)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bag", help="bag name in bags/ or a bag directory (scenario name with --synth)")
    ap.add_argument("--synth", action="store_true", help="sample bag_synth directly (no bag file)")
    ap.add_argument("--until", type=float, default=None, help="stop at this time [s] (default: end + 2 s)")
    ap.add_argument("--every", type=float, default=0.25, help="print a line every this many seconds")
    ap.add_argument("--latency", type=float, default=None, help="sim output latency [s] (default: 1/sim_rate)")
    ap.add_argument("--sim", nargs="*", help="sim_node parameter overrides key=value")
    ap.add_argument("--world", nargs="*", help="world_node parameter overrides key=value")
    ap.add_argument("--tracking", nargs="*", help="tracking_node parameter overrides key=value")
    ap.add_argument("--json", help="write the summary here")
    args = ap.parse_args(argv)
    t0 = time.monotonic()
    r = run_pipeline(None if args.synth else args.bag, synth=args.bag if args.synth else None, until=args.until,
                     sim_latency=args.latency, sim_overrides=_overrides(args.sim),
                     world_overrides=_overrides(args.world), tracking_overrides=_overrides(args.tracking))
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
    print(json.dumps(s, indent=1))
    if args.json:
        Path(args.json).write_text(json.dumps(s, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
