#!/usr/bin/env python3
"""Write the sample tracker bags of bags/ (deterministic: seeded noise and jitter, fixed stamps).

    .venv/bin/python tools/make_bags.py [--out bags] [--only grasp_short ...]

Each bag is a rosbag2 directory with mcap storage, one topic /tracker/hand_joints of
geometry_msgs/msg/PoseArray (26 OpenXR joints, header.frame_id "world", header.stamp = capture
time = bag time). The motions are described in softhand_sim/scenarios/tracker_bags.py.
"""
import argparse
import shutil
import sys
from pathlib import Path

from softhand_sim.scenarios.tracker_bags import SCENARIOS, sample
from softhand_sim.ros.bagio import TYPESTORE, serialize, write_bag

TOPIC = "/tracker/hand_joints"
MSGTYPE = "geometry_msgs/msg/PoseArray"


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


def make_bag(name, out_dir: Path) -> Path:
    path = out_dir / name
    if path.exists():
        shutil.rmtree(path)
    stamps, joints, _ = sample(name)
    records = ((TOPIC, MSGTYPE, int(s), serialize(pose_array(int(s), j), MSGTYPE)) for s, j in zip(stamps, joints))
    return write_bag(path, records, storage="mcap")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "bags"))
    parser.add_argument("--only", nargs="*", choices=sorted(SCENARIOS), help="bags to write (default: all)")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name in args.only or SCENARIOS:
        path = make_bag(name, out)
        size = sum(f.stat().st_size for f in path.iterdir())
        print(f"{path}: {size / 1e6:.2f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
