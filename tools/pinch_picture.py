#!/usr/bin/env python3
"""Draw the thumb-index pinch (contact_scenarios.PinchLift on the coarse hand, sim_node's solver
parameters) as a strip of key frames: open, closed, lifted, held 5 s, released.

    python tools/pinch_picture.py [OUT.png]      # default docs/img/pinch.png
"""
import argparse
import sys

import numpy as np

from softhand_sim.scenarios import contact as cs
from softhand_sim import handmodel
from softhand_sim.handmodel.render import render_frames
from softhand_sim.physics.model import build_model
from softhand_sim.physics.solver import Solver

DT = 0.01


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", nargs="?", default="docs/img/pinch.png", help="PNG to write")
    parser.add_argument("--view", type=float, nargs=2, default=(60.0, -10.0), metavar=("AZ", "EL"),
                        help="camera azimuth and elevation [deg]")
    args = parser.parse_args(argv)
    asset = handmodel.load_or_build_hand()
    script = cs.PinchLift(asset)
    model = build_model(asset, cs.sim_node_solver_params(), objects=[script.ball])
    solver = Solver(model, contacts=script.contact_system(model, asset))
    state, control = model.initial_state(), model.control()
    system = script.attach(solver, state, control)
    keys = {0.0: "open", script.T_CLOSE + 0.2: "pinched", script.T_LIFT: "lifted 10 cm",
            script.T_HOLD - DT: "held 5 s", script.T_HOLD + 0.3: "opening: it falls"}
    key_steps = {int(round(t / DT)): title for t, title in keys.items()}
    skin = np.empty((len(model.skin_tet), 3))
    frames, objects, titles = [], [], []
    for k in range(max(key_steps) + 1):
        if k in key_steps:
            solver.skin_positions(state, skin)
            ball_pose = np.r_[state.body_x[-1], state.body_q[-1]]
            frames.append(skin.copy())
            objects.append([(script.ball.shape, script.ball.dims, ball_pose)])
            titles.append(f"t = {k * DT:.1f} s: {key_steps[k]} ({system.count} contacts)")
        script.drive(model, control, k * DT, DT)
        solver.step(state, control, DT)
    render_frames(frames, asset.skin_triangles, args.out, objects, view=tuple(args.view), titles=titles,
                  panel_px=(320, 300), same_scale=True)  # one scale: the lift and the fall show
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
