"""Two-hand scenarios offline (issue #18): both hands and the objects in one solver, the pybullet
world of the scene as the engine side, deterministic (scenarios/bimanual.py).

handover: the ball ends within 3 cm of its target spot on the table and never drops in between;
two_hand_lift: the big box lifted >= 8 cm, held 3 s with < 5 mm slip relative to the palms, set
down; no NaN, no inverted tet, no rejected step in either. The two_hand_lift bag through both
hands' tracking loops (the offline pipeline): lifted and held; with 30 times the noise it slips,
and the one_euro joint filter holds it."""
import numpy as np
import pytest

from softhand_sim.scenarios import bimanual
from softhand_tracking.adapter import AdapterConfig, TrackerAdapter


@pytest.mark.parametrize("script", [bimanual.TwoHandLift, bimanual.Handover])
def test_tracked_joints_give_the_scripted_bones(script):
    """The two-hand bags' tracker frames (bimanual.hand_joints) run through each side's tracker
    adapter give the bones the offline scenarios script for that side (left = the mirrored right
    hand): a bag drives the nodes as the script drives the runtime. Orientations within 0.5 deg,
    positions within 0.1 mm, at 40 times over the script."""
    from softhand_sim.scene import load_scene
    from softhand_sim.physics.rotations import quat_to_matrix

    s = script(load_scene())
    if script is bimanual.Handover:
        s.aim(s.ball0 + [0.0, 0.0, 0.08])  # any aim: the check is kinematic
    adapters = {side: TrackerAdapter(AdapterConfig(hand=side)) for side in ("right", "left")}
    for t in np.linspace(0.0, s.duration, 40):
        for side, (palm, angles) in s.poses(t).items():
            bones = adapters[side].convert(bimanual.hand_joints(side, palm, angles)[:, :3])
            want = bimanual.bone_targets(side, palm, angles)
            assert bones is not None, (side, t)
            np.testing.assert_allclose(bones[:, :3], want[:, :3], atol=1e-4, err_msg=f"{side} t={t:.2f}")
            for a, b in zip(bones, want):
                cos = (np.trace(quat_to_matrix(a[3:]).T @ quat_to_matrix(b[3:])) - 1.0) / 2.0
                assert np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))) < 0.5, (side, t)


@pytest.fixture(scope="module")
def handover():
    return bimanual.run(bimanual.Handover, "ball")


@pytest.fixture(scope="module")
def lift():
    return bimanual.run(bimanual.TwoHandLift, "big_box")


@pytest.mark.slow
def test_handover(handover):
    r = handover
    T = bimanual.Handover.T
    assert r.finite and r.rejected_steps == 0
    assert r.min_tet_volume.min() > 0.0
    from softhand_sim.scene import load_scene
    ball0 = load_scene().object("ball").pose[:3]
    target = ball0 + bimanual.HANDOVER_CARRY
    # ends on the table at the target spot
    assert np.linalg.norm(r.obj_engine[-1] - target) < 0.03
    assert abs(r.obj_engine[-1, 2] - ball0[2]) < 0.005
    # lifted by the right hand; both hands hold it at the exchange; the left alone carries it
    t = r.t
    lifted = (t > T["r_lift1"]) & (t < T["l_carry0"])
    assert r.obj_engine[lifted, 2].min() > ball0[2] + 0.08
    both = (t > T["l_squeeze"]) & (t < T["r_open0"])
    assert (r.contacts["right"][both] > 20).all() and (r.contacts["left"][both] > 20).all()
    carry = (t > T["r_away"]) & (t < T["l_open0"])
    assert (r.contacts["left"][carry] > 20).all() and (r.contacts["right"][carry] == 0).all()
    # never drops: from the right's lift to the left's set-down the ball stays in its holder's
    # grip (within 1 cm of where it sat in that palm when the grip closed)
    held_r = (t > T["r_lift1"]) & (t < T["r_open0"])
    held_l = (t > T["r_open1"]) & (t < T["l_open0"])
    for side, mask in (("right", held_r), ("left", held_l)):
        rel = r.obj_in_palm[side][mask]
        assert np.linalg.norm(rel - rel[0], axis=1).max() < 0.01, side


@pytest.mark.slow
def test_two_hand_lift(lift):
    r = lift
    T = bimanual.TwoHandLift.T
    assert r.finite and r.rejected_steps == 0
    assert r.min_tet_volume.min() > 0.0
    z0 = r.obj_engine[0, 2]
    t = r.t
    hold = (t > T["lift1"]) & (t < T["hold1"])
    assert t[hold][-1] - t[hold][0] >= 2.9
    assert r.obj_engine[hold, 2].min() - z0 >= 0.08
    for side in ("right", "left"):
        rel = r.obj_in_palm[side][hold]
        assert np.linalg.norm(rel - rel[0], axis=1).max() < 0.005, side
        assert (r.contacts[side][hold] > 20).all()
    # set down: back on the table, let go
    assert abs(r.obj_engine[-1, 2] - z0) < 0.005
    assert r.contacts["right"][-1] == 0 and r.contacts["left"][-1] == 0


def _hold_slip(bag, tracking=None):
    """(lift [m] through the hold, slip [m] of the big box relative to the right palm in the
    hold) of a two_hand_lift bag through the offline pipeline with both hands."""
    from softhand_sim.commands.offline import run_pipeline

    r = run_pipeline(str(bag), hands=["right", "left"], track_object="big_box", until=6.6,
                     tracking_overrides=tracking)
    assert r.rejected_steps == 0 and np.all(np.isfinite(r.ball_engine))
    hold = (r.t >= 3.6) & (r.t <= 6.5)
    assert np.all(r.ball_contacts[hold] > 50), r.ball_contacts[hold].min()
    lift = (r.ball_engine[:, 2] - r.ball_z0)[hold]
    return lift.min(), np.linalg.norm(r.ball_in_palm[hold] - r.ball_in_palm[hold][0], axis=1).max()


@pytest.fixture(scope="module")
def noisy_lift_bag(tmp_path_factory):
    """two_hand_lift made with 1.5 mm of tracker noise (30 times the shipped bag's, fast_dropout's):
    tools/make_bags.py with --position-noise 1.5."""
    from tests.support.tools import load_tool

    out = tmp_path_factory.mktemp("noisy")
    load_tool("make_bags").main(["--out", str(out), "--only", "two_hand_lift", "--position-noise", "1.5"])
    return out / "two_hand_lift"


def test_two_hand_bag_through_both_tracking_loops_offline(noisy_lift_bag):
    """The two_hand_lift bag through the offline pipeline with both hands (commands/offline.py,
    hands=[right, left]: one tracking loop per hand on the bag's one timeline, its params.yaml
    read as `softhand demo` reads it): both palms lift the big box and hold it, as through the
    nodes (8.2 cm). The box moves relative to the right palm during the hold by 0.44 mm (the
    acceptance: < 5 mm). The same motion with 1.5 mm of tracker noise (30 times the shipped bag's
    0.05 mm) lets it move 10.3 mm: the slip comes with the tracker noise, not with the nodes'
    timing."""
    lift, slip = _hold_slip("two_hand_lift")
    assert lift > 0.07 and slip < 0.002, (lift, slip)
    lift_noisy, slip_noisy = _hold_slip(noisy_lift_bag)
    assert lift_noisy > 0.07 and slip_noisy > 0.005, (lift_noisy, slip_noisy)


def test_joint_filter_holds_the_noisy_lift_within_the_slip_bound(noisy_lift_bag):
    """The two_hand_lift motion with 1.5 mm of tracker noise and tracking_node's `joint_filter:
    one_euro` (its defaults, 1 Hz and 30 s/m, relative to the wrist): the box moves under 5 mm
    relative to the right palm in the hold (measured 4.8 mm; 3.9 mm relative to the left palm;
    10.3 / 13.1 mm unfiltered)."""
    lift, slip = _hold_slip(noisy_lift_bag, {"joint_filter": "one_euro"})
    assert lift > 0.07 and slip < 0.005, (lift, slip)
