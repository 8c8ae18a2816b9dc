"""Skin-skin contact of the hands a SimRuntime simulates (sim parameter `self_contact`), and the
rows it adds to /hand/contacts.

    hsc = HandSelfContact(model, union, assets)      # one SelfContactSystem over every hand's skin
    Solver(model, contacts=..., self_contacts=hsc.system)
    hsc.enter(h)                                     # hand h placed: its skin may touch from now on
    rows = hsc.rows(node_x)                          # the contacts of the step, as ContactSystem.output's

Segments are bones (handmodel.rigid_skin.skin_segments), hand h's at segment h*16 + bone and solver
bodies model.hands.bones(h). A hand that has not entered (sim_node places each hand at its first
target) sits at the model's rest pose, where the two hands may overlap: its segments are kept out of
every pair (the SelfContactModel's pair_ok) until it enters. The method and what it misses:
physics/contact/self_contact.py.
"""
from __future__ import annotations

import numpy as np

from softhand_sim.handmodel.rigid_skin import skin_segments
from softhand_sim.physics.contact.self_contact import build_self_contact_system
from softhand_sim.topics import SKIN_OBJECT  # the contract's value of `object` on /hand/contacts

BONES = 16


def union_skin_segments(assets, layout):
    """(point_segment, segment_body, adjacent pairs) of every hand's skin, in union order."""
    seg, body, pairs = [], [], []
    for h, asset in enumerate(assets):
        s, b, adjacent = skin_segments(asset, body_offset=layout.bones(h).start)
        seg.append(s + BONES * h)
        body.append(b)
        pairs += [(i + BONES * h, j + BONES * h) for i, j in adjacent]
    return np.concatenate(seg).astype(np.int32), np.concatenate(body).astype(np.int32), pairs


class HandSelfContact:
    """One SelfContactSystem over every hand's skin, gated per hand (module doc)."""

    def __init__(self, model, union, assets, **kwargs):
        self.layout = model.hands
        self.system = build_self_contact_system(model, union, union_skin_segments(assets, self.layout), **kwargs)
        self.pair_ok = self.system.model.pair_ok.copy()  # the rule's pairs; gated by the hands placed
        self.segment_hand = np.repeat(np.arange(len(assets)), BONES)
        self.entered = np.zeros(len(assets), dtype=bool)
        self._gate()

    def _gate(self):
        on = self.entered[self.segment_hand]
        self.system.model.pair_ok[:] = self.pair_ok & on[:, None] & on[None, :]

    def enter(self, h: int) -> None:
        """Hand h is placed: its skin takes part from the next step (its old contacts dropped)."""
        self.entered[h] = True
        self.system.reset()
        self._gate()

    def rows(self, node_x) -> dict:
        """The step's skin-skin contacts as ContactSystem.output's keys (points, normals, forces on
        the point's hand, force_normal, force_friction, objects = SKIN_OBJECT, slip, point, hand)
        plus bone, other_hand, other_bone and depth [m] (under the deformed other skin)."""
        out = self.system.output(node_x)
        seg, other = out["segment"], out["other"]
        code = np.asarray([self.layout.code(h) for h in range(len(self.entered))], dtype=np.uint8)
        n = len(seg)
        return {"points": out["points"], "normals": out["normals"], "forces": out["forces"],
                "force_normal": out["force_normal"], "force_friction": out["force_friction"],
                "objects": np.full(n, SKIN_OBJECT, np.uint32), "slip": out["slip"], "point": out["point"],
                "hand": code[self.segment_hand[seg]], "bone": (seg % BONES).astype(np.uint8),
                "other_hand": code[self.segment_hand[other]], "other_bone": (other % BONES).astype(np.uint8),
                "depth": out["depth"]}

    def diagnostics(self) -> dict:
        s = self.system
        return {"self_contacts": int(s.count), "self_collision_ms": round(float(s.collision_ms), 3),
                "self_contacts_dropped": int(s.dropped)}
