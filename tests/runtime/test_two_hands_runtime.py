"""SimRuntime with both hands (issue #18): each hand enters at its own first target, holds its last
target, per-hand outputs, contacts carry their hand; the hands parameter is checked."""
import numpy as np
import pytest

from softhand_sim.params import ParamError, load_params
from softhand_sim.runtime import SimRuntime, check_hand_measures, hand_sides
from softhand_sim.scenarios.bimanual import mirror_poses

DT = 1.0 / 60.0


@pytest.fixture(scope="module")
def runtime():
    return SimRuntime(load_params("sim_node", overrides={"hands": ["right", "left"]}))


def right_hover(rt, z=0.95, y=0.0):
    poses = rt.model.body_rest_pose[:16].copy()
    poses[:, 2] += z
    poses[:, 1] += y
    return poses


def test_hands_parameter():
    """Empty `hands` means the one hand of hand_side; unknown or repeated sides are refused."""
    assert hand_sides(load_params("sim_node")) == ("right",)
    assert hand_sides(load_params("sim_node", overrides={"hand_side": "left"})) == ("left",)
    assert hand_sides(load_params("sim_node", overrides={"hands": ["", "left", "right"]})) == ("left", "right")
    for bad in (["middle"], ["right", "right"]):
        with pytest.raises(ValueError, match="hands"):
            hand_sides(load_params("sim_node", overrides={"hands": bad}))


def test_auto_size_is_refused_with_two_hands():
    """`hand_measures: auto` sizes one hand: with one hand (either side) or fixed measures it passes;
    with two hands it is a ParamError naming both parameters (sim_node reports it and exits 1)."""
    for overrides in ({"hand_measures": "auto"}, {"hand_measures": "auto", "hands": ["left"]},
                      {"hands": ["right", "left"]}):
        check_hand_measures(load_params("sim_node", overrides=overrides))
    with pytest.raises(ParamError, match=r"'hand_measures' = 'auto'.*'hands' = \['right', 'left'\]"):
        check_hand_measures(load_params("sim_node", overrides={"hands": ["right", "left"], "hand_measures": "auto"}))


def test_each_hand_enters_at_its_first_target_and_holds_its_last(runtime):
    rt = runtime
    assert rt.hands == ("right", "left") and rt.model.bone_count == 32
    assert rt.step(DT, 0.0) is None
    right = right_hover(rt, y=0.2)
    rt.set_bone_targets(right)  # no hand given: the first hand, the right one
    assert rt.hand_placed == [True, False]
    assert np.allclose(rt.state.hand_bone_pose(rt.model, 0)[0], right[0], atol=1e-9)
    out = rt.step(DT, 0.0)
    assert out.hands["right"].entered and not out.hands["left"].entered
    assert np.array_equal(out.bone_poses, out.hands["right"].bone_poses)
    assert out.hands["right"].skin_vertices[:, 2].min() > 0.85
    left_rest = rt.state.hand_bone_pose(rt.model, 1).copy()
    for k in range(1, 5):  # the left hand waits where it was built, untouched by the right's motion
        rt.step(DT, k * DT)
    assert np.allclose(rt.state.hand_bone_pose(rt.model, 1), left_rest, atol=1e-9)
    left = mirror_poses(right)  # the left hand at -y, mirror of the right
    rt.set_bone_targets(left, 0.1, hand="left")
    assert rt.hand_placed == [True, True]
    assert np.allclose(rt.state.hand_bone_pose(rt.model, 1)[0], left[0], atol=1e-9)
    assert rt.diagnostics()["hands"] == "right:in,left:in"
    # the right hand's tracking stops; the left's goes on (moves 5 cm along x): the right holds
    for k in range(5, 65):
        moved = left.copy()
        moved[:, 0] += 0.05 * min(1.0, (k - 5) / 30)
        rt.set_bone_targets(moved, k * DT, hand="left")
        out = rt.step(DT, k * DT)
        assert not out.rejected
    assert np.abs(out.hands["right"].bone_poses[0, :3] - right[0, :3]).max() < 2e-3
    assert np.abs(out.hands["left"].bone_poses[0, :3] - moved[0, :3]).max() < 2e-3
    # mirror images: the two skins are mirrored up to the left hand's 5 cm move
    sr, sl = out.hands["right"].skin_vertices, out.hands["left"].skin_vertices
    assert sr.shape == sl.shape
    assert np.abs((sl - [0.05, 0, 0]) * [1, -1, 1] - sr).max() < 2e-3
    verts, tris = rt.display_mesh(hand="left")
    assert np.all(np.isfinite(verts)) and verts[:, 1].max() < -0.1


def test_contacts_carry_their_hand(runtime):
    """The left hand pressed onto the table top: its contacts have hand == 1 (left), none 0."""
    rt = runtime
    left = mirror_poses(right_hover(rt, z=0.75 + 0.015, y=-0.2))  # at +y, palm skin ~1 cm into the table
    rt.set_bone_targets(right_hover(rt, y=0.2), 2.0)
    rt.set_bone_targets(left, 2.0, hand="left")
    for k in range(30):
        out = rt.step(DT, 2.0 + k * DT)
    c = out.contacts
    assert len(c["hand"]) > 10
    assert set(np.unique(c["hand"]).tolist()) == {1}
    assert c["forces"][:, 2].sum() > 0.5  # the table pushes the hand up


def test_left_hand_alone():
    """hands = [left]: a one-hand runtime of the left hand; its contacts are marked left."""
    rt = SimRuntime(load_params("sim_node", overrides={"hands": ["left"]}))
    assert rt.hands == ("left",) and rt.asset.side == "left" and rt.model.bone_count == 16
    poses = rt.model.body_rest_pose[:16].copy()  # the left hand's own rest skeleton
    poses[:, 1] += 0.2
    poses[:, 2] += 0.765
    rt.set_bone_targets(poses)
    for k in range(20):
        out = rt.step(DT, k * DT)
    assert len(out.contacts["hand"]) > 0 and np.all(out.contacts["hand"] == 1)


def test_hand_placed_turned_around_keeps_its_tets():
    """A hand whose first target is turned 180 deg about z (a left hand facing the right one)
    is placed with its tets' rotations warm-started there: no tet folds in the first steps."""
    from softhand_sim.physics.rotations import quat_mul, quat_to_matrix
    rt = SimRuntime(load_params("sim_node"))
    turn = np.array([0.0, 0.0, 1.0, 0.0])
    R = quat_to_matrix(turn)
    poses = rt.model.body_rest_pose[:16].copy()
    poses[:, :3] = poses[:, :3] @ R.T + [0.1, 0.2, 1.0]
    poses[:, 3:] = [quat_mul(turn, q) for q in poses[:, 3:]]
    rt.set_bone_targets(poses)
    tets = rt.model.tets
    for k in range(6):
        rt.step(DT, k * DT)
        x = rt.state.node_x
        a, b, c = (x[tets[:, i]] - x[tets[:, 0]] for i in (1, 2, 3))
        assert np.einsum("ij,ij->i", a, np.cross(b, c)).min() > 0.0, k
