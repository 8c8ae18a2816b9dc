"""`softhand hand`: build (or load from the cache) the parametric hand and render it to a PNG."""
import argparse
import json
import time

from softhand_sim.handmodel.cache import load_or_build_hand
from softhand_sim.handmodel.render import VIEWS, render_hand_png


def main(argv=None):
    parser = argparse.ArgumentParser(
        prog="softhand hand",
        description="Build the parametric hand model (skin, tissue tets, skeleton, bone-tissue samples; "
                    "cached in $SOFTHAND_CACHE or ~/.cache/softhand) and render it from the dorsal and "
                    "palmar sides. Prints the builder's figures.")
    parser.add_argument("--out", default="hand.png", help="PNG to write (default hand.png)")
    parser.add_argument("--side", choices=("right", "left"), default="right")
    parser.add_argument("--mesh", choices=("coarse", "fine"), default="coarse", help="tissue resolution")
    parser.add_argument("--show-tets", action="store_true", help="overlay the tissue tet mesh surface")
    parser.add_argument("--views", default="dorsal,palmar", help="comma-separated: dorsal, palmar, side, front")
    args = parser.parse_args(argv)
    views = tuple(v.strip() for v in args.views.split(","))
    unknown = [v for v in views if v not in VIEWS]
    if unknown:  # before the build, which can take a minute
        parser.error(f"--views {args.views}: unknown view(s) {', '.join(map(repr, unknown))}; "
                     f"known: {', '.join(VIEWS)}")
    t0 = time.perf_counter()
    print(f"building or loading the {args.side} hand ({args.mesh} tissue)...", flush=True)
    asset = load_or_build_hand(side=args.side, resolution=args.mesh)
    print(f"  ready in {time.perf_counter() - t0:.1f} s")
    info = {k: v for k, v in dict(asset.build_info).items() if not isinstance(v, (list, dict))}
    print(json.dumps(info, indent=2, default=str))
    render_hand_png(asset, args.out, views=views, show_tets=args.show_tets)
    print(f"wrote {args.out}")
    return 0
