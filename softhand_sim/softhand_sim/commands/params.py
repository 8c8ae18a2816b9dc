"""`softhand params [NODE]`: every parameter with its default, unit and meaning."""
import argparse

from softhand_sim.params import SCHEMA, defaults


def main(argv=None):
    parser = argparse.ArgumentParser(prog="softhand params", description=__doc__)
    parser.add_argument("node", nargs="?", choices=sorted(SCHEMA), help="only this node")
    args = parser.parse_args(argv)
    for node in [args.node] if args.node else SCHEMA:
        print(f"{node}:")
        values = defaults(node)
        for key, p in SCHEMA[node].items():
            print(f"  {key:24s} = {values[key]!r:28} [{p.unit}] {p.doc}")
    return 0
