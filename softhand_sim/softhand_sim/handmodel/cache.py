"""Cached hand assets: .npz files under $SOFTHAND_CACHE (default ~/.cache/softhand), keyed by a
hash of the measures, side, resolution and the builder version."""
import os
from pathlib import Path

from softhand_sim.handmodel.asset import HandAsset
from softhand_sim.handmodel.build import build_hand
from softhand_sim.handmodel.measures import as_measures

BUILDER_VERSION = "2"  # bump when the builder's output changes, to invalidate old caches
# per side on top: the left hand's abduction limits were fixed (mirrored) in left version 1, which
# left the right hand's arrays, and so its cached files, unchanged
SIDE_VERSION = {"right": "", "left": "l1"}


def cache_dir():
    return Path(os.environ.get("SOFTHAND_CACHE", Path.home() / ".cache" / "softhand"))


def cache_path(measures=None, side="right", resolution="coarse"):
    m = as_measures(measures)
    return cache_dir() / f"hand_v{BUILDER_VERSION}{SIDE_VERSION.get(side, '')}_{side}_{resolution}_{m.digest()}.npz"


def load_or_build_hand(measures=None, side="right", resolution="coarse"):
    """The cached asset if present, else build it and store it (atomically) in the cache."""
    path = cache_path(measures, side, resolution)
    if path.exists():
        return HandAsset.load(path)
    asset = build_hand(measures, side, resolution)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{os.getpid()}.tmp.npz")
    asset.save(tmp)
    os.replace(tmp, path)
    return asset
