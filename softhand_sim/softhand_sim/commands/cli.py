"""`softhand`: the project's top-level command (demo, bench, hand, model, params, calibrate, fidelity, offline, lag).

Each subcommand lives in its own module and is imported only when used, so `softhand --help`
is instant and `softhand bench` never loads rclpy.
"""
import argparse
import importlib
import sys

# name -> (module with main(argv), one-line help)
SUBCOMMANDS = {
    "demo": ("softhand_sim.commands.demo", "replay a tracker bag through tracking, sim, world and record nodes; "
                                  "writes runs/<stamp>/ (bag, summary.json, preview)"),
    "bench": ("softhand_sim.commands.bench", "solver benchmark (one thread; --threads 2: two hands on two cores): steps/s, p99, stages"),
    "hand": ("softhand_sim.commands.hand", "build the parametric hand model and render it to a PNG"),
    "model": ("softhand_sim.commands.model_info", "`model info [--json] [--measures FILE]`: the hand model's "
                                                  "figures (skin, tets, quality, embedding, build time) as JSON"),
    "params": ("softhand_sim.commands.params", "print every node parameter with its default, range, unit and meaning; --yaml writes the params file"),
    "calibrate": ("softhand_sim.commands.calibrate", "fit the user's hand measures to a tracker bag; "
                                                    "writes a measures file"),
    "fidelity": ("softhand_sim.commands.fidelity", "palm, knuckle, fingertip and phalanx-direction error of the "
                                                  "simulated vs the tracked hand (recording or --offline)"),
    "view": ("softhand_sim.commands.view", "serve the live topics to the Foxglove app (WebSocket, 127.0.0.1:8765)"),
    "offline": ("softhand_sim.commands.offline", "run the whole pipeline over a bag without ROS, deterministically; "
                                                 "prints the ball's lift, hold and fall"),
    "lag": ("softhand_sim.commands.lag", "lag and error of the intermediate and simulated hand against the "
                                         "tracked hand in a recording (time shift, angles, frame counts)"),
}


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = argparse.ArgumentParser(
        prog="softhand",
        description="softhand: a physics-based soft hand for teleoperation and VR (ROS 2 Jazzy). "
                    "Nodes: softhand-tracking, softhand-sim, softhand-world, softhand-play, softhand-record.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (_, text) in SUBCOMMANDS.items():
        sub.add_parser(name, help=text, add_help=False)
    if not argv or argv[0] in ("-h", "--help"):
        parser.print_help()
        return 0
    name = argv[0]
    if name not in SUBCOMMANDS:
        parser.error(f"unknown command {name!r}; choose from {', '.join(SUBCOMMANDS)}")
    module = importlib.import_module(SUBCOMMANDS[name][0])
    return module.main(argv[1:]) or 0


if __name__ == "__main__":
    sys.exit(main())
