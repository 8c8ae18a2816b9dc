"""`softhand params [NODE]`: every parameter with its default, range, unit and meaning.

`softhand params --yaml [FILE]` writes the ROS 2 params file of these defaults (stdout without
FILE); config/softhand.yaml is this output: `softhand params --yaml config/softhand.yaml`.
"""
import argparse
import sys
from pathlib import Path

from softhand_sim.params import SCHEMA, defaults, params_yaml


def _range(p):
    if p.choices is not None:
        return " | ".join(p.choices)
    if p.kind not in (int, float):
        return f"{p.size} values" if p.size else ""
    low = "(0" if p.positive and (p.low is None or p.low <= 0) else f"[{p.low:g}" if p.low is not None else "(-inf"
    high = f"{p.high:g}]" if p.high is not None else "inf)"
    return f"{low}, {high}"


def main(argv=None):
    parser = argparse.ArgumentParser(prog="softhand params", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("node", nargs="?", choices=sorted(SCHEMA), help="only this node")
    parser.add_argument("--yaml", nargs="?", const="-", metavar="FILE",
                        help="write the params file of every node's defaults to FILE (stdout: -)")
    args = parser.parse_args(argv)
    if args.yaml is not None:
        if args.node:
            parser.error("--yaml writes every node's section: give no NODE")
        text = params_yaml()
        if args.yaml == "-":
            sys.stdout.write(text)
        else:
            Path(args.yaml).write_text(text)
            print(f"wrote {args.yaml}")
        return 0
    for node in [args.node] if args.node else SCHEMA:
        print(f"{node}:")
        values = defaults(node)
        for key, p in SCHEMA[node].items():
            print(f"  {key:26s} = {values[key]!r:28} {_range(p):20s} [{p.unit}] {p.doc}")
    return 0
