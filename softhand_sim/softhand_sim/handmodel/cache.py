"""Cached hand assets: .npz files under $SOFTHAND_CACHE (default ~/.cache/softhand), keyed by a
hash of the measures, side, resolution and the builder version (morphed hands: also the morph's).

The default hand is built (build.py). A hand at other measures is, by default, the default right
hand morphed per bone (morph.py, about a second) and checked (checks.morph_problems); if the
check fails, it is built in full (40-160 s coarse, ~450 s fine) and the log says why.
"""
import logging
import os
import threading
import time
from pathlib import Path

from softhand_sim.handmodel.asset import HandAsset
from softhand_sim.handmodel.build import build_hand
from softhand_sim.handmodel.checks import morph_problems
from softhand_sim.handmodel.measures import HandMeasures, as_measures
from softhand_sim.handmodel.morph import MORPH_VERSION, morph_hand
from softhand_sim.handmodel.tissue import COARSE_EMBED_TOLERANCE

BUILDER_VERSION = "3"  # bump when the builder's output changes, to invalidate old caches
METHODS = ("auto", "morph", "build")
log = logging.getLogger("softhand_sim.handmodel")
# per side on top: the left hand's abduction limits were fixed (mirrored) in left version 1, which
# left the right hand's arrays, and so its cached files, unchanged
SIDE_VERSION = {"right": "", "left": "l1"}


def cache_dir():
    return Path(os.environ.get("SOFTHAND_CACHE", Path.home() / ".cache" / "softhand"))


def _morphs(m, method):
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    return method == "morph" or (method == "auto" and m != HandMeasures())


def cache_path(measures=None, side="right", resolution="coarse", method="auto"):
    """Where the hand of `measures` is cached: built (default hand, method 'build') or morphed."""
    m = as_measures(measures)
    kind = f"m{MORPH_VERSION}" if _morphs(m, method) else ""
    return cache_dir() / f"hand_v{BUILDER_VERSION}{kind}_{side}_{resolution}_{m.digest()}.npz"


def morph_or_build(measures, side="right", resolution="coarse"):
    """The default right hand (cached) morphed to `measures`; built in full if the morph fails
    checks.morph_problems (logged as a warning; build_info['morph_fallback'] says why)."""
    m = as_measures(measures)
    base = load_or_build_hand(None, "right", resolution, method="build")
    asset = morph_hand(base, m, side)
    t0 = time.perf_counter()
    problems = morph_problems(asset, COARSE_EMBED_TOLERANCE)
    asset.build_info["time_check_s"] = time.perf_counter() - t0
    if not problems:
        return asset
    reason = "; ".join(problems)
    log.warning("the morphed %s %s hand (measures %s) fails its checks (%s): building it in full instead, "
                "which takes minutes", side, resolution, m.digest(), reason)
    asset = build_hand(m, side, resolution)
    asset.build_info.update(method="build", morph_fallback=reason)
    return asset


def load_or_build_hand(measures=None, side="right", resolution="coarse", method="auto"):
    """The cached asset if present, else make it and store it (atomically) in the cache.

    method: 'auto' (the default hand built, others morphed, built if the morph fails its checks),
    'morph' (morphed, built if it fails; the default hand too) or 'build' (full build)."""
    m = as_measures(measures)
    path = cache_path(m, side, resolution, method)
    if path.exists():
        return HandAsset.load(path)
    if _morphs(m, method):
        asset = morph_or_build(m, side, resolution)
    else:
        asset = build_hand(m, side, resolution)
        asset.build_info.setdefault("method", "build")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{os.getpid()}.{threading.get_ident()}.tmp.npz")  # per process and thread
    asset.save(tmp)
    os.replace(tmp, path)
    return asset
