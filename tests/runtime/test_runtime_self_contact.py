"""Skin-skin contact in SimRuntime (sim parameter self_contact, physics/contact/hand_self_contact.py):
a hand driven into a tip pinch whose tracked tips come closer than the pads are thick. With
self_contact the pads touch and flatten: skin-skin rows in the step's contacts (object SKIN_OBJECT,
the thumb's and the index's distal bones on either side, pushing the pads apart), no pad point more
than 1 mm inside the other; the object contacts carry the bone they touch with. Two hands pressed
palm to palm hold each other apart and separate cleanly."""
import numpy as np
import pytest

from softhand_sim.handmodel.kinematics import forward_kinematics
from softhand_sim.params import load_params
from softhand_sim.topics import NO_BONE, SKIN_OBJECT
from softhand_sim.runtime import SimRuntime
from softhand_sim.scenarios.bimanual import PALM_SURFACE
from softhand_sim.scenarios.self_contact import run_palms_pressed, runtime_tip_pinch
from softhand_sim.scenarios.tracker_bags import OPEN_ANGLES, PALM_DOWN
from softhand_tracking.adapter import TrackerAdapter

DT = 1.0 / 60.0
THUMB_DISTAL, INDEX_DISTAL = 3, 6


def tip_gap(rt, out):
    """Distance [m] between the thumb's and the index's tips (distal bone origin + its length along +x)."""
    from softhand_sim.handmodel.fidelity import simulated_points
    tips = simulated_points(out.bone_poses, rt.asset.bone_length)[2]
    return float(np.linalg.norm(tips[0] - tips[1]))


@pytest.fixture(scope="module")
def runs():
    # open hand above the table, closing into a pinch whose tracked tips are 2 mm apart (the pads,
    # ~2 x 8 mm thick, overlap): (runtime, last step's output) without and with self contact
    return runtime_tip_pinch(False, tip_gap=0.002), runtime_tip_pinch(True, tip_gap=0.002)


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
    # deformed skin (measured 0.98 mm), while the bones keep their places (the tips
    # as far apart as without self contact: the tissue gives, not the skeleton)
    assert np.nanmax(c["depth"][pads]) <= 0.001, np.nanmax(c["depth"][pads])
    # and measured apart from the contacts (physics/contact/penetration.py): no skin point more
    # than 1 mm inside the other digit's deformed skin (0.91 mm), against 2.4 mm without self contact
    from softhand_sim.handmodel.rigid_skin import skin_segments
    from softhand_sim.physics.contact.self_contact import build_self_contact_system
    from softhand_sim.scenarios.self_contact import skin_penetration
    sm = rt.self_contact.system.model
    sm_off = build_self_contact_system(rt_off.model, rt_off.asset, skin_segments(rt_off.asset)).model
    depth_on = skin_penetration(sm, rt.state.node_x, rt.model.tets, rt.asset.skin_triangles)[0]
    depth_off = skin_penetration(sm_off, rt_off.state.node_x, rt_off.model.tets, rt_off.asset.skin_triangles)[0]
    assert depth_on <= 0.001 and depth_off > 0.002, (depth_on, depth_off)
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


def test_self_pinch_picture_shows_the_pads_flatten(runs, tmp_path):
    """tools/self_pinch_picture.py (the README's picture) on this module's two pinches: cut through
    both pads, the outlines overlap over 2 mm without self contact and under 1 mm with it (measured
    2.7 and 0.79 mm), the pads' contact area and force are reported, and the picture is written."""
    from tests.support.tools import load_tool

    tool = load_tool("self_pinch_picture")
    (rt_off, off), (rt, on) = runs
    f = tool.draw({False: (rt_off, off), True: (rt, on)}, tmp_path / "pinch.png", tip_gap=0.002)
    assert f["overlap_off_mm"] > 2.0 and f["overlap_on_mm"] < 1.0, f
    assert f["pad_contacts"] >= 4 and f["deepest_mm"] <= 1.0, f
    # the contact patch on the thumb pad (measured 23 mm^2 carrying 0.51 N): a few mm^2 to a pad's side
    assert 5.0 <= f["area_mm2"] <= 100.0 and 0.05 <= f["force_n"], f
    assert (tmp_path / "pinch.png").stat().st_size > 20_000


def test_two_hands_pressed_palm_to_palm_hold_apart_and_separate():
    """Both hands of sim_node's runtime with self contact, pressed palm to palm with the tracked
    hands ~2.7 cm inside each other (the skin meets with the tracked wrists 51 mm apart, the press
    drives them to 24 mm), then apart (issue #21's acceptance: penetration <= 1.5 mm, no NaN, the
    hands separate cleanly). The penetration is measured apart from the contact list (the skin
    point deepest inside the other hand's closed, deformed skin: physics/contact/penetration.py),
    so a point the contacts miss counts too. Measured: 1.29 mm (the contacts' own deepest 1.08
    mm; 1.31 / 1.31 mm before the skin stiffened past 1 mm deep), up to 23 contacts, 6.5 N between
    the hands, the wrists held 50 mm apart."""
    script, rows = run_palms_pressed()
    assert all(r["finite"] for r in rows) and min(r["min_tet_volume"] for r in rows) > 0.0
    pressed = [r for r in rows if script.T["approach1"] + 0.2 <= r["t"] <= script.T["part0"]]
    assert min(r["between"] for r in pressed) >= 10 and min(r["force"] for r in pressed) > 2.0, pressed[-1]
    assert max(r["depth"] for r in rows) <= 0.0015, max(r["depth"] for r in rows)
    penetration = [r["penetration"] for r in rows if r["penetration"] is not None]
    assert len(penetration) >= 50 and max(penetration) <= 0.0015, max(penetration)
    assert max(r["penetration"] or 0.0 for r in pressed) > 0.0003  # the skins do press into each other
    # the simulated hands hold each other apart: the wrists stay where the skins meet, far from
    # the tracked 24 mm (the bone springs stretch, not the skin)
    assert min(r["wrists"] for r in pressed) > 0.045, min(r["wrists"] for r in pressed)
    assert all(r["within"] == 0 for r in rows)  # open flat hands: nothing of one hand touches itself
    end = [r for r in rows if r["t"] >= script.T["part1"] + 0.1]
    assert all(r["between"] == 0 for r in end) and abs(end[-1]["wrists"] - 2 * (PALM_SURFACE + script.START)) < 0.001, end[-1]
