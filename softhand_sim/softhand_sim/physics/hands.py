"""Several hands in one solver Model (issue #18): the union of their assets, and where each lies.

One Model holds every simulated hand and every object, so that one Newton step + PCG solves
them together and an object touched by two hands is one body. The union concatenates the hands'
arrays in hand order and shifts their indices:

  tissue nodes   hand 0's, then hand 1's, ...      (tets, surface triangles shifted by node0)
  bodies         hand 0's 16 bones, hand 1's, ..., then the objects (as for one hand)
  skin vertices  hand 0's, then hand 1's, ...      (skin triangles shifted by skin0, skin_tet by tet0)
  joints, bone-tissue samples: shifted by bone0 / tet0

No term of the CSR pattern couples two hands: the system matrix is block-diagonal per hand, the
hands meeting only in the object bodies' rows (the reserved node-object contact blocks, model.py).
Skin-skin contact between the hands couples them outside the pattern, in the PCG's products
(pcg.pcg's low-rank term). A single asset gives exactly today's one-hand model.
"""
from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

SIDES = ("right", "left")
HAND_CODE = {"right": 0, "left": 1}  # the `hand` field of /hand/contacts (docs/INTERFACE.md)


@dataclass(frozen=True)
class HandLayout:
    """Where each hand of a Model lies: hand h owns nodes node0[h]:node0[h+1], tets tet0[h]:...,
    bodies bone0[h]:bone0[h+1] (its bones, palm first), skin vertices skin0[h]:..."""
    sides: tuple
    node0: np.ndarray    # (H+1,) i8
    tet0: np.ndarray     # (H+1,)
    bone0: np.ndarray    # (H+1,)
    skin0: np.ndarray    # (H+1,)

    @property
    def count(self):
        return len(self.sides)

    def index(self, side):
        """Hand index of `side` ("right" / "left"); ValueError when the model does not hold it."""
        if side not in self.sides:
            raise ValueError(f"hand {side!r} is not simulated (hands: {list(self.sides)})")
        return self.sides.index(side)

    def nodes(self, h):
        return slice(int(self.node0[h]), int(self.node0[h + 1]))

    def tets(self, h):
        return slice(int(self.tet0[h]), int(self.tet0[h + 1]))

    def bones(self, h):
        return slice(int(self.bone0[h]), int(self.bone0[h + 1]))

    def skin(self, h):
        return slice(int(self.skin0[h]), int(self.skin0[h + 1]))

    def code(self, h):
        """The contacts' `hand` code of hand h (0 right, 1 left)."""
        return HAND_CODE.get(self.sides[h], h)


def _field(asset, name):
    v = getattr(asset, name, None)
    return None if v is None else np.asarray(v)


def _offsets(counts):
    return np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)


def layout_of(asset):
    """The HandLayout of one asset (one hand) or of a union built by union_asset."""
    layout = getattr(asset, "hand_layout", None)
    if layout is not None:
        return layout
    n = len(np.asarray(asset.tet_nodes))
    t = len(np.asarray(asset.tets))
    b = len(np.asarray(_field(asset, "bone_rest_pose") if _field(asset, "bone_rest_pose") is not None
                       else np.zeros((0, 7))).reshape(-1, 7))
    sv = _field(asset, "skin_tet")
    s = 0 if sv is None else len(sv)
    return HandLayout((getattr(asset, "side", "right"),), np.array([0, n]), np.array([0, t]),
                      np.array([0, b]), np.array([0, s]))


def union_asset(assets):
    """One asset-like namespace holding every hand of `assets` (HandAssets or asset-likes with their
    fields), indices shifted as the module docstring says, with `hand_layout` (HandLayout). One
    asset is returned unchanged."""
    assets = list(assets)
    if len(assets) == 1:
        return assets[0]
    sides = tuple(getattr(a, "side", "right") for a in assets)
    if len(set(sides)) != len(sides):
        raise ValueError(f"each hand once: got sides {list(sides)}")
    node0 = _offsets([len(a.tet_nodes) for a in assets])
    tet0 = _offsets([len(a.tets) for a in assets])
    bone0 = _offsets([len(a.bone_rest_pose) for a in assets])
    skin0 = _offsets([len(_field(a, "skin_tet")) if _field(a, "skin_tet") is not None else 0 for a in assets])
    sv0 = _offsets([len(_field(a, "skin_vertices")) if _field(a, "skin_vertices") is not None else 0
                    for a in assets])

    def cat(name, shift=None):
        parts = [_field(a, name) for a in assets]
        if any(p is None for p in parts):
            return None
        if shift is not None:
            parts = [p + (shift[h] if p.dtype.kind in "iu" else 0) for h, p in enumerate(parts)]
        return np.concatenate(parts)

    out = SimpleNamespace(
        side="+".join(sides), hand_layout=HandLayout(sides, node0, tet0, bone0, skin0),
        tet_nodes=cat("tet_nodes"), tets=cat("tets", node0).astype(np.int32),
        tet_surface_triangles=cat("tet_surface_triangles", node0),
        skin_vertices=cat("skin_vertices"), skin_triangles=cat("skin_triangles", sv0),
        skin_tet=cat("skin_tet", tet0), skin_bary=cat("skin_bary"),
        joint_parent=cat("joint_parent", bone0), joint_child=cat("joint_child", bone0),
        sample_tet=cat("sample_tet", tet0), sample_bone=cat("sample_bone", bone0))
    for name in ("bone_rest_pose", "bone_length", "bone_mass", "bone_com_local", "bone_inertia_local",
                 "joint_type", "joint_anchor_parent", "joint_anchor_child", "joint_flex_axis",
                 "joint_abd_axis", "joint_rest_rotation", "joint_limits", "sample_count",
                 "sample_local", "sample_bary", "bone_sample_total"):
        setattr(out, name, cat(name))
    for name in ("skin_triangles", "tet_surface_triangles", "joint_parent", "joint_child",
                 "sample_tet", "sample_bone", "skin_tet"):
        v = getattr(out, name)
        if v is not None:
            setattr(out, name, v.astype(np.int32))
    out.hands = assets
    return out
