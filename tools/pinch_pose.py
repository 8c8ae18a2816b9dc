#!/usr/bin/env python3
"""Find (or check) the thumb-index pinch pose of softhand_sim.scenarios.contact (PINCH_*).

Search: differential evolution (scipy) over the thumb's and the index's (abduction, flex_1,
flex_2, flex_3) within DIGIT_LIMITS and the ball centre in the palm frame, on the default hand
model's skin carried rigidly by its bones. Cost, from cs.pinch_report:
  (depth_thumb - d)^2 + (depth_index - d)^2        both distal pads d [m] into the ball
  + 0.01 (1 + grip_cos)^2                          pads at opposite ends of a diameter
  + 0.01 sum (1 - facing)^2                        the pads, not the nails, face the ball
  + 0.01 sum lift^2                                a level grip line (palm down): the squeeze
                                                   pushes the ball neither up nor down
  + 10 (min(others_gap - 3 mm, 0))^2               nothing else touches it
It prints the constants to paste into cs.py. About 6 minutes on one core.

    python tools/pinch_pose.py            # search (seed 1) and print the constants
    python tools/pinch_pose.py --check    # report the constants in cs.py
"""
import argparse
import sys

import numpy as np

from softhand_sim import handmodel
from softhand_sim.handmodel.rigid_skin import RigidSkin
from softhand_sim.scenarios import contact as cs
from softhand_sim.handmodel.kinematics import DIGIT_LIMITS

OTHERS_CLEARANCE = 0.003  # [m]


def _angles(x):
    angles = np.zeros((5, 4))
    angles[0], angles[1] = x[:4], x[4:8]
    return angles


def _print_report(report):
    print(f"pad depth thumb {1e3 * report['depth'][0]:.2f} mm, index {1e3 * report['depth'][1]:.2f} mm; "
          f"grip line cos {report['grip_cos']:.4f} (-1: a diameter); pads facing the ball "
          f"{report['facing'][0]:.3f} / {report['facing'][1]:.3f}; upward part of the pushes "
          f"{report['lift'][0]:.3f} / {report['lift'][1]:.3f}; other skin clear by "
          f"{1e3 * report['others_gap']:.2f} mm")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--depth", type=float, default=cs.PINCH_DEPTH, help="pad depth into the ball [m]")
    parser.add_argument("--seed", type=int, default=1, help="differential evolution seed")
    parser.add_argument("--maxiter", type=int, default=400, help="generations at most")
    parser.add_argument("--check", action="store_true", help="only report the constants in cs.py")
    args = parser.parse_args(argv)
    asset = handmodel.load_or_build_hand()
    skin = RigidSkin(asset)
    palm = np.asarray(asset.bone_rest_pose[0], dtype=np.float64)
    if args.check:
        _print_report(cs.pinch_report(skin, palm, cs.pinch_angles()[1], cs.PINCH_BALL_IN_PALM))
        return 0

    from scipy.optimize import differential_evolution

    def cost(x):
        r = cs.pinch_report(skin, palm, _angles(x), x[8:11])
        return (np.sum((r["depth"] - args.depth) ** 2) + 0.01 * (1.0 + r["grip_cos"]) ** 2
                + 0.01 * np.sum((1.0 - r["facing"]) ** 2) + 0.01 * np.sum(r["lift"] ** 2)
                + 10.0 * min(r["others_gap"] - OTHERS_CLEARANCE, 0.0) ** 2)

    generation = [0]

    def progress(xk, convergence):
        generation[0] += 1
        if generation[0] % 25 == 0:
            print(f"generation {generation[0]}: cost {cost(xk):.3e}", file=sys.stderr, flush=True)

    limits = DIGIT_LIMITS[:2].reshape(-1, 2)
    bounds = [tuple(b) for b in limits] + [(0.0, 0.25), (-0.05, 0.15), (-0.15, 0.05)]
    result = differential_evolution(cost, bounds, seed=args.seed, maxiter=args.maxiter, popsize=30,
                                    tol=1e-12, polish=True, callback=progress)
    x = result.x
    print(f"cost {result.fun:.3e}")
    _print_report(cs.pinch_report(skin, palm, _angles(x), x[8:11]))
    deg = np.rad2deg(x[:8]).round(2)
    print("PINCH_TOUCH_DEG = np.array([")
    print(f"    [{', '.join(f'{v:.2f}' for v in deg[:4])}],  # thumb")
    print(f"    [{', '.join(f'{v:.2f}' for v in deg[4:])}]])  # index")
    print(f"PINCH_BALL_IN_PALM = np.array([{', '.join(f'{v:.4f}' for v in x[8:11])}])")
    return 0


if __name__ == "__main__":
    sys.exit(main())
