"""`softhand model info [--json] [--measures FILE]`: the hand model's figures as data.

Builds (or loads from the cache) the coarse and fine hand at the default measures or those of a
measures file (`softhand calibrate`), and prints one JSON object: skin_triangles,
skin_watertight, tets, tets_fine, min_dihedral_deg(_fine), volume_error(_fine),
embedded_fraction (skin vertices within the coarse mesh's stated tolerance,
tissue.COARSE_EMBED_TOLERANCE), inverted tets, build_s (coarse build or cache load [s];
build_s_fine likewise, cached: whether the coarse hand came from the cache) and the measures.
"""
import argparse
import json
import sys
import time

from softhand_sim.handmodel.cache import cache_path, load_or_build_hand
from softhand_sim.handmodel.checks import asset_figures
from softhand_sim.handmodel.fit import hand_length
from softhand_sim.handmodel.measures import HandMeasures, read_measures_file
from softhand_sim.handmodel.tissue import COARSE_EMBED_TOLERANCE


def model_info(measures, side="right", fine=True) -> dict:
    """The figures of the module docstring for `measures` (HandMeasures)."""
    cached = cache_path(measures, side, "coarse").exists()
    t0 = time.perf_counter()
    coarse = load_or_build_hand(measures, side, "coarse")
    build_s = time.perf_counter() - t0
    info = asset_figures(coarse, COARSE_EMBED_TOLERANCE)
    info.update(side=side, cached=cached, build_s=round(build_s, 3), embed_tolerance_mm=COARSE_EMBED_TOLERANCE * 1e3,
                wrist_to_middle_tip_mm=round(hand_length(measures) * 1e3, 1))
    if fine:
        t0 = time.perf_counter()
        f = asset_figures(load_or_build_hand(measures, side, "fine"), COARSE_EMBED_TOLERANCE)
        info.update(tets_fine=f["tets"], inverted_fine=f["inverted"], min_dihedral_deg_fine=f["min_dihedral_deg"],
                    volume_error_fine=f["volume_error"], embedded_fraction_fine=f["embedded_fraction"],
                    build_s_fine=round(time.perf_counter() - t0, 3))
    info["measures"] = measures.to_dict()
    return info


def main(argv=None):
    parser = argparse.ArgumentParser(prog="softhand model", description="the hand model's figures")
    parser.add_argument("action", choices=("info",))
    parser.add_argument("--json", action="store_true", help="one JSON object (default: indented)")
    parser.add_argument("--measures", default=None, help="measures file (softhand calibrate); default: the default hand")
    parser.add_argument("--side", choices=("right", "left"), default="right")
    parser.add_argument("--no-fine", action="store_true", help="skip the fine tissue mesh")
    args = parser.parse_args(argv)
    try:
        m = HandMeasures() if args.measures is None else read_measures_file(args.measures)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    info = model_info(m, args.side, fine=not args.no_fine)
    info["measures_file"] = args.measures
    print(json.dumps(info) if args.json else json.dumps(info, indent=1))
    return 0
