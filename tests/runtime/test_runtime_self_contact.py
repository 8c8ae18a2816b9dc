"""Skin-skin contact in SimRuntime (sim parameter self_contact, physics/contact/hand_self_contact.py):
a hand driven into a tip pinch whose tracked tips come closer than the pads are thick. With
self_contact the pads touch and flatten: skin-skin rows in the step's contacts (object SKIN_OBJECT,
the thumb's and the index's distal bones on either side, pushing the pads apart), no pad point more
than 1 mm inside the other; the object contacts carry the bone they touch with."""
import numpy as np
import pytest

from softhand_sim.handmodel.kinematics import forward_kinematics
from softhand_sim.params import load_params
from softhand_sim.topics import NO_BONE, SKIN_OBJECT
from softhand_sim.runtime import SimRuntime
from softhand_sim.scenarios.tracker_bags import OPEN_ANGLES, PALM_DOWN, tip_pinch_angles
from softhand_tracking.adapter import TrackerAdapter

DT = 1.0 / 60.0
THUMB_DISTAL, INDEX_DISTAL = 3, 6


def pinch_run(self_contact: bool, steps: int = 90):
    """Open hand above the table, closing into a pinch whose tracked tips are 2 mm apart (the pads,
    ~2 x 8 mm thick, overlap); returns the runtime and the last step's output."""
    from softhand_sim.handmodel.measures import HandMeasures
    from softhand_sim.scenarios import tracker_bags
    rt = SimRuntime(load_params("sim_node", overrides={"self_contact": self_contact}))
    adapter = TrackerAdapter()
    old_gap = tracker_bags.TIP_PINCH_GAP
    tracker_bags.TIP_PINCH_GAP = 0.002
    try:
        pinch = tip_pinch_angles(HandMeasures())
    finally:
        tracker_bags.TIP_PINCH_GAP = old_gap
    palm = np.r_[0.1, 0.2, 0.95, PALM_DOWN]
    out = None
    for k in range(steps):
        u = min(1.0, k / 45.0)
        joints, _ = forward_kinematics(palm, OPEN_ANGLES + u * (pinch - OPEN_ANGLES))
        rt.set_bone_targets(adapter.convert(joints[:, :3]), k * DT)
        out = rt.step(DT, k * DT)
        assert out is not None and not out.rejected, out.warning if out else "no step"
    return rt, out


def tip_gap(rt, out):
    """Distance [m] between the thumb's and the index's tips (distal bone origin + its length along +x)."""
    from softhand_sim.handmodel.fidelity import simulated_points
    tips = simulated_points(out.bone_poses, rt.asset.bone_length)[2]
    return float(np.linalg.norm(tips[0] - tips[1]))


@pytest.fixture(scope="module")
def runs():
    return pinch_run(False), pinch_run(True)


def test_pinched_pads_touch_each_other(runs):
    (rt_off, off), (rt, on) = runs
    c = on.contacts
    skin = c["objects"] == SKIN_OBJECT
    assert not np.any(off.contacts["objects"] == SKIN_OBJECT)
    pads = skin & np.isin(c["bone"], [THUMB_DISTAL, INDEX_DISTAL]) & np.isin(c["other_bone"], [THUMB_DISTAL, INDEX_DISTAL])
    assert pads.sum() >= 4, (skin.sum(), list(zip(c["bone"][skin], c["other_bone"][skin])))
    assert np.all(c["hand"][skin] == 0) and np.all(c["other_hand"][skin] == 0)
    assert np.all(c["bone"][pads] != c["other_bone"][pads])
    # each contact's force acts on the point's skin, its reaction on the other's: the pads push apart
    thumb_push = c["forces"][pads & (c["bone"] == THUMB_DISTAL)].sum(axis=0)
    index_push = c["forces"][pads & (c["bone"] == INDEX_DISTAL)].sum(axis=0)
    assert np.linalg.norm(thumb_push) > 0.05 and np.dot(thumb_push, index_push) < 0.0
    assert np.all(np.isfinite(c["depth"][skin])) and np.all(np.isnan(c["depth"][~skin]))
    # the pads flatten against each other: no skin point more than 1 mm under the other pad's
    # deformed skin (measured 0.95 mm, median 0.39), while the bones keep their places (the tips
    # as far apart as without self contact: the tissue gives, not the skeleton)
    assert np.nanmax(c["depth"][pads]) <= 0.001, np.nanmax(c["depth"][pads])
    assert abs(tip_gap(rt, on) - tip_gap(rt_off, off)) < 0.001, (tip_gap(rt, on), tip_gap(rt_off, off))
    d = rt.diagnostics()
    assert d["self_contacts"] == int(skin.sum()) and d["self_collision_ms"] >= 0.0


def test_object_contacts_name_their_bone():
    """The flat hand on the table: every object contact names a bone of the hand (0-15), the one
    whose axis its skin point lies nearest at rest, and no other side."""
    rt = SimRuntime(load_params("sim_node"))
    adapter = TrackerAdapter()
    joints, _ = forward_kinematics(np.r_[0.1, 0.2, 0.75 + 0.012, PALM_DOWN], OPEN_ANGLES)
    for k in range(30):
        rt.set_bone_targets(adapter.convert(joints[:, :3]), k * DT)
        out = rt.step(DT, k * DT)
    c = out.contacts
    assert len(c["points"]) > 10
    assert np.all(c["bone"] < 16) and np.all(c["other_bone"] == NO_BONE) and np.all(c["other_hand"] == NO_BONE)
    assert len(set(c["bone"].tolist())) >= 2
    from softhand_sim.handmodel.rigid_skin import skin_segments
    np.testing.assert_array_equal(c["bone"], skin_segments(rt.asset)[0][c["point"]])
