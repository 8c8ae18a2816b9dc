"""`softhand demo`: the main job. Replays a tracker bag through the whole node set and records it.

Starts world_node, sim_node, one tracking_node per hand and record_node as separate processes
(loopback-only discovery, a ROS domain of their own), waits until they are up, plays the bag with
play_node, stops everything when the bag ends, then writes runs/<stamp>/:
    bag/            the recording (rosbag2, mcap storage)
    summary.json    rates per node, sim step p50/p99, latency, contacts, ball lift (and every object's), hand measures in use
    preview.png     key frames drawn from the recording (CPU renderer), preview.gif
    logs/           each node's output

A bag directory may hold a params.yaml (ROS params file) with the node parameters its scene needs:
the demo passes it to the nodes before --params-file (the two-hand lift's stiffer object coupling).

The hands come from the bag (bag_sides): a side whose tracker topic /tracker/{side}/hand_joints is
in it, and an old single-hand bag's /tracker/hand_joints as the right hand (`--hand left` plays it
as the left). sim_node simulates them all in one solve (`hands`); each has its own tracking node
(one process per hand: the two 250 Hz loops on the two cores), the first side's named
tracking_node, a second one tracking_node_left.
"""
from __future__ import annotations

import argparse
import copy
import json
import math
import signal
import subprocess
import sys
import time
from datetime import datetime
from pathlib import Path

from softhand_sim.params import ParamError, read_params_file
from softhand_sim.paths import REPO_ROOT, bag_params_file, bag_path, bags_dir
from softhand_sim.ros.env import apply_isolated_env, isolated_env
from softhand_sim.ros.probe import wait_for_topics
from softhand_sim.topics import LEGACY_TRACKER, SIDES, hand_topic, side_of, tracker_topic

DEFAULT_BAG = "grasp_lift"
# (package, executable) of every process, in start order; the launch file starts the same set
# (softhand_sim/launch/softhand.launch.py), tracking_node once per hand. Console scripts:
# softhand-<name without _node>.
NODE_SET = (
    ("softhand_world", "world_node"),
    ("softhand_sim", "sim_node"),
    ("softhand_tracking", "tracking_node"),
    ("softhand_sim", "record_node"),
    ("softhand_tracking", "play_node"),
)


def tracking_node_name(sides, side):
    """The tracking node of hand `side` in a run of `sides`: tracking_node for the first hand,
    tracking_node_<side> for a second one (two nodes cannot share a name)."""
    return "tracking_node" if side == sides[0] else f"tracking_node_{side}"


def ready_topics(sides):
    """The topics whose publishers must exist before the bag plays: the world's and every hand's
    simulated and intermediate bones."""
    return ("/world/object_states", *(hand_topic(s, n) for s in sides for n in ("bones", "intermediate_bones")))


def tracker_subscribers(sides):
    """play_node starts only once these have subscribed to the tracker topics and been matched: no
    frame of the bag is lost to a subscriber that joined late (issue #17)."""
    return (*(tracking_node_name(sides, s) for s in sides), "record_node")


def params_file_for_hands(params_file, sides, out_dir):
    """The params file to give every node: `params_file` itself, or with two hands a copy (in
    out_dir) whose tracking_node section also applies to tracking_node_left (a params file is keyed
    by node name, and the second hand's node has its own); None stays None."""
    if params_file is None or len(sides) < 2:
        return params_file
    import yaml

    data = yaml.safe_load(Path(params_file).read_text()) or {}
    for side in sides[1:]:
        name = tracking_node_name(sides, side)
        if "tracking_node" in data and name not in data:
            # a copy, not the same dict: PyYAML writes a shared one as an anchor and an alias,
            # which rcl's params-file parser refuses ("Will not support aliasing")
            data[name] = copy.deepcopy(data["tracking_node"])
    out = Path(out_dir) / "params.yaml"
    out.write_text(yaml.safe_dump(data, sort_keys=False))
    return out


def bag_sides(bag, legacy_side="right"):
    """The hands a tracker bag drives, in SIDES order: the sides of its /tracker/{side}/hand_joints
    topics, and legacy_side for an old bag's /tracker/hand_joints. SystemExit naming the bag's
    topics when it has no tracker topic."""
    from softhand_sim.ros.bagio import BagError, topic_counts

    try:
        topics = sorted(topic_counts(bag))
    except BagError as exc:
        raise SystemExit(f"error: {exc}") from None
    found = {legacy_side if t == LEGACY_TRACKER else side_of(t) for t in topics
             if t == LEGACY_TRACKER or t in (tracker_topic(s) for s in SIDES)}
    if not found:
        raise SystemExit(f"error: bag {bag} has no tracker topic (/tracker/{{right,left}}/hand_joints or "
                         f"{LEGACY_TRACKER}); its topics: {', '.join(topics) or 'none'}")
    return tuple(s for s in SIDES if s in found)
# after the last frame: its answers travel tracking -> sim -> world -> record, and tracking_node's
# /diagnostics (1 Hz) reports its final frame counts before the recorder stops
DRAIN_S = 1.6


def console_script(name):
    exe = Path(sys.executable).parent / name
    if not exe.exists():
        raise SystemExit(f"error: {exe} not found: install the project (make demo does) first")
    return str(exe)


def resolve_bag(bag):
    path = bag_path(bag)
    if not path.exists():
        known = sorted(p.name for p in bags_dir().iterdir() if p.is_dir()) if bags_dir().is_dir() else []
        raise SystemExit(f"error: bag {bag!r} not found (sample bags in {bags_dir()}: {', '.join(known)})")
    return path.resolve()


class ProcessSet:
    """Child processes with their logs; stopped with SIGINT, then SIGKILL after a grace period."""

    def __init__(self, env, log_dir):
        self.env = env
        self.log_dir = Path(log_dir)
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.procs = {}

    def start(self, name, argv):
        log = open(self.log_dir / f"{name}.log", "w")
        self.procs[name] = (subprocess.Popen(argv, env=self.env, stdout=log, stderr=subprocess.STDOUT,
                                             start_new_session=True), log)
        return self.procs[name][0]

    def alive(self, name):
        return self.procs[name][0].poll() is None

    def exited(self, skip=()):
        """The children (but those in `skip`) that have exited, in the order they were started."""
        return [name for name, (proc, _) in self.procs.items() if name not in skip and proc.poll() is not None]

    def returncode(self, name):
        return self.procs[name][0].returncode

    def stop(self, name, grace=10.0):
        self.interrupt(name)
        return self.reap(name, grace)

    def interrupt(self, name):
        proc = self.procs[name][0]
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)

    def reap(self, name, grace=10.0):
        """Wait for an interrupted process (SIGKILL after `grace` s); its exit code."""
        proc, log = self.procs[name]
        try:
            proc.wait(grace)
        except subprocess.TimeoutExpired:
            # the node's Python stacks into its log (run_node registers SIGUSR1), then SIGKILL
            proc.send_signal(signal.SIGUSR1)
            time.sleep(0.5)
            log.write(f"[demo] {name} did not stop within {grace:.0f} s of SIGINT: killed\n")
            log.flush()
            proc.kill()
            proc.wait()
        log.close()
        return proc.returncode

    def stop_all(self, first=("play", "record")):
        """Stop `first` one by one (the recorder ends before the nodes it records), then every
        other process at once: each takes about a second to shut rclpy down."""
        codes = {name: self.stop(name) for name in first if name in self.procs}
        rest = [name for name in reversed(list(self.procs)) if name not in codes]
        for name in rest:
            self.interrupt(name)
        codes.update({name: self.reap(name) for name in rest})
        return codes

    def tail(self, name, lines=15):
        path = self.log_dir / f"{name}.log"
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:]) if path.exists() else ""


def wait_watching(procs, name, skip=(), what="the run went on", poll_s=0.2):
    """Wait for child `name` of procs to exit (its exit code); SystemExit with the log of any other
    child (but those in `skip`) that exits first. A node that dies mid-run (the recorder refusing
    its output, a crash) ends the run with its own words at once, rather than when the player gives
    up waiting for its subscription (30 s) and blames itself."""
    while procs.alive(name):
        dead = procs.exited((name, *skip))
        if dead:
            raise SystemExit(f"error: {dead[0]} exited (code {procs.returncode(dead[0])}) while {what}:\n"
                             f"{procs.tail(dead[0])}")
        time.sleep(poll_s)
    return procs.returncode(name)


def run_demo(bag, out_dir, rate=1.0, params_file=None, preview=True, startup_timeout=600.0, quiet=False, view=False,
             legacy_side="right", repeat=1):
    """Run the node set over `bag`; returns the summary dict (also written to out_dir/summary.json).

    view: also run `softhand view` in the demo's domain (the live topics for the Foxglove app);
    legacy_side: the hand an old single-hand bag (/tracker/hand_joints) is played as."""
    say = (lambda *a: None) if quiet else (lambda *a: print(*a, flush=True))
    out_dir = Path(out_dir)
    if params_file is not None:  # missing or not a params file: said now, not by every node at start
        try:
            read_params_file(params_file)
        except ParamError as exc:
            raise SystemExit(f"error: --params-file: {exc}") from None
    if (out_dir / "bag").exists():  # the recorder would refuse it only once every node is up
        raise SystemExit(f"error: --out {out_dir} holds a recording already ({out_dir / 'bag'}); choose a new "
                         f"directory (without --out each run gets its own runs/<stamp>)")
    out_dir.mkdir(parents=True, exist_ok=True)
    env = isolated_env()
    apply_isolated_env(env["ROS_DOMAIN_ID"])  # this process watches the same (private) domain
    # numba's default thread count (the cores): only solver_threads > 1 starts threads (in sim_node)
    sides = bag_sides(bag, legacy_side)
    say(f"softhand demo: bag {bag.name} ({' + '.join(sides)} hand{'s' if len(sides) > 1 else ''}) -> {out_dir} "
        f"(ROS_DOMAIN_ID={env['ROS_DOMAIN_ID']}, discovery LOCALHOST)")
    procs = ProcessSet(env, out_dir / "logs")
    params_file = params_file_for_hands(params_file, sides, out_dir)
    # a bag may carry the node parameters its scene needs (tools/make_bags.py: params.yaml beside
    # it); the user's file comes after it, so it wins
    bag_params = bag_params_file(bag)
    ros = ["--ros-args"] + [arg for f in (bag_params, params_file) if f for arg in ("--params-file", str(f))]
    if bag_params:
        say(f"  the bag's parameters: {bag_params}")
    t0 = time.monotonic()
    try:
        if view:  # first, so the Foxglove app can connect while the nodes start
            procs.start("view", [console_script("softhand"), "view"])
            say("  live view: in the Foxglove app, Open connection -> Foxglove WebSocket -> ws://localhost:8765")
        hands = "[" + ", ".join(sides) + "]"
        procs.start("world", [console_script("softhand-world"), *ros])
        procs.start("sim", [console_script("softhand-sim"), *ros, "-p", f"hands:={hands}"])
        for side in sides:  # one process per hand
            node = tracking_node_name(sides, side)
            procs.start(node.replace("_node", ""), [console_script("softhand-tracking"), *ros, "-p", f"hand:={side}",
                                                    *(["-r", f"__node:={node}"] if node != "tracking_node" else [])])
        say("  starting world, sim and tracking nodes (first start compiles the solver: up to a few minutes)...")
        missing = wait_for_topics(ready_topics(sides), startup_timeout, procs)
        if missing:
            raise SystemExit(f"error: no publisher on {missing} after {startup_timeout:.0f} s; see {out_dir / 'logs'}")
        procs.start("record", [console_script("softhand-record"), *ros, "-p", f"output:={out_dir / 'bag'}"])
        time.sleep(1.0)  # let the recorder discover the nodes' publishers (the tracker's is waited for below)
        say(f"  nodes up after {time.monotonic() - t0:.1f} s; playing {bag.name} at rate {rate}")
        procs.start("play", [console_script("softhand-play"), str(bag), "--rate", str(rate), "--repeat", str(repeat),
                             "--hand", legacy_side, "--wait-for-nodes", *tracker_subscribers(sides), *ros])
        if wait_watching(procs, "play", skip=("view",), what=f"{bag.name} played") != 0:
            raise SystemExit(f"error: play_node failed:\n{procs.tail('play')}")
        time.sleep(DRAIN_S)
    finally:
        codes = procs.stop_all()
    say(f"  stopped: {codes}")
    from softhand_sim.commands.run_summary import summarize_run

    summary = summarize_run(out_dir / "bag", bag_name=bag.name, exit_codes=codes, input_bag=bag,
                            play_log=out_dir / "logs" / "play.log", legacy_side=legacy_side, repeat=repeat)
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2))
    if preview:
        from softhand_sim.commands.preview import render_preview

        summary["preview"] = render_preview(out_dir / "bag", out_dir)
        (out_dir / "summary.json").write_text(json.dumps(summary, indent=2))
    say(format_summary(summary, out_dir))
    silent = [t for t in ready_topics(sides) if not summary.get("messages_per_topic", {}).get(t)]
    if silent:
        raise SystemExit(f"error: nothing was recorded on {silent}; see the node logs in {out_dir / 'logs'}")
    return summary


FIDELITY_LABELS = {"palm_mm": ("palm", "mm"), "palm_deg": ("palm", "deg"), "knuckle_mm": ("knuckles", "mm"),
                   "fingertip_mm": ("fingertips", "mm"), "phalanx_direction_deg": ("phalanx directions", "deg"),
                   "held_phalanx_deg": ("phalanxes in held poses", "deg"),
                   "pinch_gap_error_mm": ("pinch gap", "mm")}


def fidelity_line(f: dict) -> str:
    """The printed summary's errors of one hand (run_summary's `fidelity`)."""
    line = ", ".join(f"{FIDELITY_LABELS[k][0]} {v['median']:.1f} / {v['p95']:.1f} {FIDELITY_LABELS[k][1]}"
                     for k, v in f.items() if k in FIDELITY_LABELS)
    if f.get("tracker_noise_mm") is not None:  # what part of those errors the input's own noise is
        line += f" (tracker noise {f['tracker_noise_mm']:.2f} mm per coordinate)"
    return line


def format_summary(s, out_dir):
    from softhand_sim.commands.lag import LAYER_NAMES, lag_text
    from softhand_sim.commands.run_summary import hand_measures_line

    r = s.get("rates_hz", {})
    others = [(n, z) for n, z in s.get("object_lift_m", {}).items() if n != "ball" and z >= 0.01]
    moved = [(n, [100 * v for v in d]) for n, d in s.get("object_moved_m", {}).items() if math.hypot(*d) >= 0.01]
    lines = [
        f"run {out_dir}",
        "  rates [Hz]: " + ", ".join(f"{k} {v:.1f}" for k, v in r.items()),
        f"  sim step: p50 {s.get('sim_step_ms_p50', float('nan')):.2f} ms, p99 {s.get('sim_step_ms_p99', float('nan')):.2f} ms",
        f"  tracker -> bones latency: p50 {s.get('latency_ms_p50', float('nan')):.1f} ms, "
        f"p99 {s.get('latency_ms_p99', float('nan')):.1f} ms (first bones "
        f"{s.get('startup_s', float('nan')):.2f} s after the first tracker frame)",
        "  tracker frames: " + ", ".join(f"{k} {v}" for k, v in s.get("tracker_frames", {}).items()),
        *(f"    {side} hand: frames " + ", ".join(f"{k} {v}" for k, v in h["tracker_frames"].items())
          + f"; latency p50 {h['latency_ms_p50']:.1f} ms, p99 {h['latency_ms_p99']:.1f} ms; "
            f"max contacts {h['max_contacts']}"
          for side, h in s.get("hands", {}).items() if len(s.get("hands", {})) > 1),
        *(f"  {side} hand lag behind the tracked one (phalanx / palm): "
          + ", ".join(f"{LAYER_NAMES.get(layer, layer)} {lag_text(v['phalanx'])} / {lag_text(v['palm'])} ms"
                      for layer, v in h["lag_ms"].items())
          for side, h in s.get("hands", {}).items() if h.get("lag_ms")),
        *(f"  {side} hand vs the tracked one (median / p95): " + fidelity_line(h["fidelity"])
          for side, h in s.get("hands", {}).items() if h.get("fidelity")),
        hand_measures_line(s.get("hand_measures", {})),
        f"  max active contacts: {s.get('max_contacts', 0)} (skin on skin: {s.get('max_skin_contacts', 0)})",
        f"  ball: lifted {100 * s.get('ball_lift_m', 0.0):.1f} cm (lifted >= 8 cm: {s.get('ball_lifted', False)})",
        *(["  other objects lifted: " + ", ".join(f"{n} {100 * z:.1f} cm" for n, z in others)] if others else []),
        *(["  objects moved, end against start: " + ", ".join(
            f"{n} {math.hypot(*d):.1f} cm (x {d[0]:+.1f}, y {d[1]:+.1f}, z {d[2]:+.1f})" for n, d in moved)]
          if moved else []),
        f"  recording: {s.get('bag_messages', 0)} messages, {s.get('bag_mb', 0.0):.1f} MB, all values finite: "
        f"{s.get('all_finite', False)}",
    ]
    if s.get("preview"):
        lines.append(f"  preview: {', '.join(str(p) for p in s['preview'])}")
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(
        prog="softhand demo",
        description="Replay a tracker bag through tracking, sim and world nodes, record everything to "
                    "runs/<stamp>/ (rosbag2 mcap), and write summary.json and a rendered preview.",
    )
    parser.add_argument("--bag", default=DEFAULT_BAG,
                        help=f"tracker bag directory or a sample name in bags/ (default {DEFAULT_BAG})")
    parser.add_argument("--out", default=None, help="run directory (default runs/<stamp>)")
    parser.add_argument("--rate", type=float, default=1.0, help="playback speed factor (default 1)")
    parser.add_argument("--repeat", type=int, default=1, metavar="N",
                        help="play the bag N times in a row (default 1): e.g. a short recording with sim_node's "
                             "hand_measures: auto, which sizes the hand from the first tracked second")
    parser.add_argument("--hand", choices=SIDES, default="right",
                        help="the hand an old single-hand bag (/tracker/hand_joints) drives (default right); "
                             "two-hand bags name their sides themselves")
    parser.add_argument("--params-file", default=None, help="ROS 2 params file for the nodes")
    parser.add_argument("--no-preview", action="store_true", help="skip rendering the preview")
    parser.add_argument("--view", action="store_true",
                        help="serve the live topics to the Foxglove app on ws://127.0.0.1:8765 (softhand view)")
    args = parser.parse_args(argv)
    if args.rate <= 0:
        parser.error(f"--rate must be > 0, got {args.rate}")
    if args.repeat < 1:
        parser.error(f"--repeat must be >= 1, got {args.repeat}")
    bag = resolve_bag(args.bag)
    out = Path(args.out) if args.out else REPO_ROOT / "runs" / datetime.now().strftime("%Y%m%d-%H%M%S")
    run_demo(bag, out, rate=args.rate, params_file=args.params_file, preview=not args.no_preview, view=args.view,
             legacy_side=args.hand, repeat=args.repeat)
    return 0


if __name__ == "__main__":
    sys.exit(main())
