"""Parametric hand model: measures -> HandAsset (skin, tissue tets, embedding, skeleton, samples)."""
from softhand_sim.handmodel.asset import HandAsset
from softhand_sim.handmodel.build import build_hand
from softhand_sim.handmodel.cache import cache_path, load_or_build_hand
from softhand_sim.handmodel.measures import HandMeasures

__all__ = ["HandAsset", "HandMeasures", "build_hand", "cache_path", "load_or_build_hand"]
