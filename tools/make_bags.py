#!/usr/bin/env python3
"""Write the sample tracker bags of bags/ (deterministic: seeded noise and jitter, fixed stamps).

    .venv/bin/python tools/make_bags.py [--out bags] [--only grasp_short ...] [--position-noise MM]

Each bag is a rosbag2 directory with mcap storage, of geometry_msgs/msg/PoseArray (26 OpenXR
joints, header.frame_id "world", header.stamp = capture time = bag time). The one-hand bags have one
topic, /tracker/hand_joints (the single-hand name of older bags, played as the right hand); their
motions are described in softhand_sim/scenarios/tracker_bags.py. The two-hand bags (handover,
two_hand_lift: softhand_sim/scenarios/bimanual.py) have /tracker/right/hand_joints and
/tracker/left/hand_joints, and a params.yaml beside them with the node parameters their scene needs
(`softhand demo` passes it to the nodes). The handover's left hand is aimed at the ball where an
offline run of the script has it hang (about a minute). `grasp_short_left` is grasp_short mirrored
through the xz plane (the ball sits on it), a left hand on /tracker/left/hand_joints.
"""
import argparse
import shutil
import sys
from pathlib import Path

import yaml

from softhand_sim.scenarios.bimanual import TWO_HAND_BAGS, mirror_poses, tracker_frames
from softhand_sim.scenarios import tracker_bags
from softhand_sim.scenarios.tracker_bags import SCENARIOS, sample
from softhand_sim.paths import BAG_PARAMS
from softhand_sim.ros.bagio import TYPESTORE, serialize, write_bag
from softhand_sim.topics import LEGACY_TRACKER, tracker_topic

TOPIC = LEGACY_TRACKER
MSGTYPE = "geometry_msgs/msg/PoseArray"
MIRRORED = {"grasp_short_left": "grasp_short"}  # left-hand bag -> the right-hand sample it mirrors


def pose_array(stamp_ns, joints):
    """A rosbags PoseArray message from joint poses (26, 7)."""
    t = TYPESTORE.types
    header = t["std_msgs/msg/Header"](
        stamp=t["builtin_interfaces/msg/Time"](sec=int(stamp_ns // 10**9), nanosec=int(stamp_ns % 10**9)),
        frame_id="world")
    poses = [t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=float(p[0]), y=float(p[1]), z=float(p[2])),
        orientation=t["geometry_msgs/msg/Quaternion"](x=float(p[3]), y=float(p[4]), z=float(p[5]), w=float(p[6])))
        for p in joints]
    return t[MSGTYPE](header=header, poses=poses)


def make_bag(name, out_dir: Path, position_noise=None) -> Path:
    """A one-hand bag of scenario `name` (position_noise [m]: instead of the bags' POSITION_NOISE)."""
    path = out_dir / name
    if path.exists():
        shutil.rmtree(path)
    stamps, joints, _ = sample(name, position_noise=position_noise)
    records = ((TOPIC, MSGTYPE, int(s), serialize(pose_array(int(s), j), MSGTYPE)) for s, j in zip(stamps, joints))
    return write_bag(path, records, storage="mcap")


def make_mirrored_bag(name, out_dir: Path, position_noise=None) -> Path:
    """A left-hand bag: the frames of a right-hand sample mirrored through the xz plane (y -> -y,
    each joint pose mirrored as bimanual.mirror_poses does), on /tracker/left/hand_joints."""
    path = out_dir / name
    if path.exists():
        shutil.rmtree(path)
    stamps, joints, _ = sample(MIRRORED[name], position_noise=position_noise)
    topic = tracker_topic("left")
    records = ((topic, MSGTYPE, int(s), serialize(pose_array(int(s), mirror_poses(j)), MSGTYPE))
               for s, j in zip(stamps, joints))
    return write_bag(path, records, storage="mcap")


def make_two_hand_bag(name, out_dir: Path, position_noise=None) -> Path:
    """A two-hand bag: both sides' tracker topics, interleaved by capture time, and params.yaml."""
    path = out_dir / name
    if path.exists():
        shutil.rmtree(path)
    frames = tracker_frames(name, position_noise=position_noise)
    records = sorted(((tracker_topic(side), MSGTYPE, int(s), j) for side, (stamps, joints) in frames.items()
                      for s, j in zip(stamps, joints)), key=lambda r: (r[2], r[0]))
    write_bag(path, ((topic, t, s, serialize(pose_array(s, j), MSGTYPE)) for topic, t, s, j in records),
              storage="mcap")
    write_params(path, name)
    return path


def write_params(path: Path, name: str):
    """params.yaml beside bag `name` at path: the node parameters its scene needs (if any)."""
    params = {node: {"ros__parameters": values} for node, values in TWO_HAND_BAGS.get(name, {}).items()}
    if params:
        (path / BAG_PARAMS).write_text(f"# parameters the scene of bag {name} needs (tools/make_bags.py)\n"
                                        + yaml.safe_dump(params, sort_keys=False))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "bags"))
    names = [*SCENARIOS, *MIRRORED, *TWO_HAND_BAGS]
    parser.add_argument("--only", nargs="*", choices=sorted(names), help="bags to write (default: all)")
    parser.add_argument("--position-noise", type=float, default=None, metavar="MM",
                        help="std of the white noise added to every joint coordinate of every frame [mm] "
                             f"(default {tracker_bags.POSITION_NOISE * 1e3:g}, the shipped bags': the Leap "
                             "recordings carry 0.02-0.05 mm frame to frame; fast_dropout keeps its own "
                             f"{tracker_bags.NOISY_TRACKER * 1e3:g} mm)")
    args = parser.parse_args(argv)
    noise = None
    if args.position_noise is not None:
        if not args.position_noise >= 0.0:
            parser.error(f"--position-noise {args.position_noise}: must be >= 0 [mm]")
        noise = args.position_noise * 1e-3
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name in args.only or names:
        make = make_two_hand_bag if name in TWO_HAND_BAGS else make_mirrored_bag if name in MIRRORED else make_bag
        path = make(name, out, position_noise=noise)
        size = sum(f.stat().st_size for f in path.iterdir())
        print(f"{path}: {size / 1e6:.2f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
