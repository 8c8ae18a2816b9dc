"""Both hands in one model (issue #18): the union's structure, no coupling between the hands but
through objects, mirror symmetry of the left hand, and one object body touched by both hands."""
import numpy as np
import pytest

from softhand_sim.handmodel import load_or_build_hand
from softhand_sim.physics.contact import detection as contact
from softhand_sim.physics.model import build_model
from softhand_sim.physics.solver import Solver
from softhand_sim.physics.state import State
from softhand_sim.physics.control import Control
from softhand_sim.physics.rotations import quat_exp, quat_mul, quat_to_matrix
from softhand_sim.scene import Scene
from softhand_sim.scenarios.contact import ball_object, ball_under_palm, flexed_targets

DT = 0.01
SHIFT = 0.25  # [m] right hand at +y, left hand at -y: mirror images through the xz plane


@pytest.fixture(scope="module")
def assets():
    return load_or_build_hand(side="right"), load_or_build_hand(side="left")


def mirror(poses):
    """Poses (n,7) mirrored through the xz plane: y -> -y, R -> S R S (q -> (-x, y, -z, w))."""
    out = np.array(poses, float, copy=True)
    out[:, 1] *= -1.0
    out[:, 3] *= -1.0
    out[:, 5] *= -1.0
    return out


def shifted(poses, dy):
    out = np.array(poses, float, copy=True)
    out[:, 1] += dy
    return out


def place(model, state, h, poses):
    for i, b in enumerate(range(*model.hands.bones(h).indices(model.body_count))):
        state.set_body_pose(model, b, poses[i])


def test_union_layout_and_block_structure(assets):
    """The two-hand model is the two hands side by side: counts add up, and no entry of the
    system matrix couples a dof of one hand to a dof of the other (only objects meet both)."""
    right, left = assets
    ball = ball_object([0.1, 0.0, -0.06])
    one = build_model(right, objects=[ball])
    two = build_model([right, left], objects=[ball])
    assert two.hands.sides == ("right", "left")
    assert two.node_count == 2 * one.node_count and len(two.tets) == 2 * len(one.tets)
    assert two.bone_count == 32 and two.object_count == 1
    assert len(two.skin_tet) == 2 * len(one.skin_tet)
    # palm couplings at each hand's palm (bones 0 and 16)
    assert two.body_target_kx[0] == two.body_target_kx[16] == two.params["tracking_kx"]
    hand_of_dof = np.full(two.dof_count, -1)
    for h in range(2):
        n = two.hands.nodes(h)
        hand_of_dof[3 * n.start:3 * n.stop] = h
        b = two.hands.bones(h)
        hand_of_dof[two.body_dof0 + 6 * b.start:two.body_dof0 + 6 * b.stop] = h
    rows = np.repeat(np.arange(two.dof_count), np.diff(two.indptr))
    hr, hc = hand_of_dof[rows], hand_of_dof[two.indices]
    assert not np.any((hr >= 0) & (hc >= 0) & (hr != hc))
    # one hand's block is the one-hand pattern (nnz of hand 0 rows, objects excluded alike)
    assert np.sum((hr == 0) & (hc == 0)) == np.sum(
        (np.repeat(np.arange(one.dof_count), np.diff(one.indptr)) < one.body_dof0 + 6 * 16)
        & (one.indices < one.body_dof0 + 6 * 16))


def test_left_hand_is_the_mirror_of_the_right_in_motion(assets):
    """Right hand driven through flexion plus a thumb abduction beyond its joint limit, the left
    hand by the mirrored targets, in one solver: every left bone stays the mirror image of its
    right bone (the left asset's joints, limits and tissue are the right's mirrored)."""
    right, left = assets
    model = build_model([right, left])
    solver = Solver(model)
    state, control = State.at_rest(model), Control.at_rest(model)
    rest_r = shifted(right.bone_rest_pose, SHIFT)
    place(model, state, 0, rest_r)
    place(model, state, 1, mirror(rest_r))
    rest0 = np.asarray(right.bone_rest_pose)
    state.node_x[model.hands.nodes(0)] = right.tet_nodes + [0, SHIFT, 0]
    state.node_x[model.hands.nodes(1)] = left.tet_nodes + [0, -SHIFT, 0]
    for k in range(60):
        tgt = flexed_targets(rest0, 0.5 * np.sin(np.pi * k / 60))
        # thumb CMC abduction 0.9 rad about the thumb metacarpal's z: past the 0.6 rad limit
        R = quat_to_matrix(rest0[1, 3:])
        turn = quat_exp(R[:, 2] * 0.9 * min(1.0, k / 30))
        for b in (1, 2, 3):
            tgt[b, 3:] = quat_mul(turn, tgt[b, 3:])
            tgt[b, :3] = rest0[1, :3] + quat_to_matrix(turn) @ (tgt[b, :3] - rest0[1, :3])
        tr = shifted(tgt, SHIFT)
        control.set_hand_targets(model, 0, tr)
        control.set_hand_targets(model, 1, mirror(tr))
        solver.step(state, control, DT)
    pr = state.hand_bone_pose(model, 0)
    pl = state.hand_bone_pose(model, 1)
    assert np.all(np.isfinite(state.node_x))
    assert np.abs(mirror(pr)[:, :3] - pl[:, :3]).max() < 2e-5
    # quaternions up to sign
    dots = np.abs(np.einsum("ij,ij->i", mirror(pr)[:, 3:], pl[:, 3:]))
    assert dots.min() > 1 - 1e-8
    xr = state.node_x[model.hands.nodes(0)]
    xl = state.node_x[model.hands.nodes(1)]
    assert np.abs(xr * [1, -1, 1] - xl).max() < 2e-5
    # and the thumb did abduct (the limit held it, it did not stay at rest)
    assert np.linalg.norm(pr[3, :3] - rest_r[3, :3]) > 0.01


def test_second_hand_does_not_change_the_first(assets):
    """The right hand in a two-hand model (left idle far away) moves as in the one-hand model:
    no term couples the hands (equal to the CG tolerance)."""
    right, left = assets
    one, two = build_model(right), build_model([right, left])
    s1, s2 = State.at_rest(one), State.at_rest(two)
    c1, c2 = Control.at_rest(one), Control.at_rest(two)
    far = shifted(left.bone_rest_pose, -1.0)
    place(two, s2, 1, far)
    s2.node_x[two.hands.nodes(1)] = left.tet_nodes + [0, -1.0, 0]
    c2.set_hand_targets(two, 1, far)
    solver1, solver2 = Solver(one), Solver(two)
    rest = np.asarray(right.bone_rest_pose)
    for k in range(40):
        tgt = flexed_targets(rest, 0.6 * np.sin(np.pi * k / 40))
        c1.set_bone_targets(one, tgt)
        c2.set_hand_targets(two, 0, tgt)
        solver1.step(s1, c1, DT)
        solver2.step(s2, c2, DT)
    assert np.abs(s1.bone_pose - s2.hand_bone_pose(two, 0)).max() < 1e-4
    assert np.abs(s1.node_x - s2.node_x[two.hands.nodes(0)]).max() < 1e-4


def test_one_ball_touched_by_both_hands(assets):
    """A ball pressed from above by the right palm and from below by the left palm (left hand
    turned palm up): one body, contacts of both hands (hand codes 0 and 1) in the same solve,
    the ball squeezed between them stays put while both push."""
    right, left = assets
    ball = ball_object(ball_under_palm(right, press=0.001))
    model = build_model([right, left], objects=[ball])
    scene = Scene(-5.0, 0.5, (ball,))
    from softhand_sim.physics.hands import union_asset
    system = contact.build_contact_system(model, scene, union_asset([right, left]))
    solver = Solver(model, contacts=system)
    state, control = State.at_rest(model), Control.at_rest(model)
    # left hand: turned 180 deg about x (palm up), under the ball
    flip = np.array([1.0, 0.0, 0.0, 0.0])  # quaternion of 180 deg about x
    R = quat_to_matrix(flip)
    flipped = left.tet_nodes @ R.T
    c = ball.pose[:3]
    near = np.linalg.norm(flipped[:, :2] - c[:2], axis=1) < 0.015
    drop = np.array([0.0, 0.0, (c[2] - 0.04 + 0.001) - flipped[near, 2].max()])  # 1 mm into the ball
    lp = np.array(left.bone_rest_pose, float)
    lp[:, :3] = lp[:, :3] @ R.T + drop
    lp[:, 3:] = np.array([quat_mul(flip, q) for q in lp[:, 3:]])
    place(model, state, 1, lp)
    state.node_x[model.hands.nodes(1)] = flipped + drop
    state.tet_q[model.hands.tets(1)] = flip  # the co-rotational warm start of a turned hand
    control.set_hand_targets(model, 1, lp)
    control.set_object_targets(model, ball.pose[None], kx=0.0, ktheta=0.0)
    codes = set()
    for k in range(60):
        press = 0.01 * min(1.0, k / 20)
        tr = np.array(right.bone_rest_pose, float)
        tr[:, 2] -= press
        tl = lp.copy()
        tl[:, 2] += press
        control.set_hand_targets(model, 0, tr)
        control.set_hand_targets(model, 1, tl)
        st = solver.step(state, control, DT)
        out = system.output(state.node_x, state.body_x, state.body_q)
        codes |= set(np.unique(out["hand"]).tolist())
    assert np.all(np.isfinite(state.node_x))
    assert codes == {0, 1}
    assert st.contacts > 20
    f = system.output(state.node_x, state.body_x, state.body_q)
    up = f["forces"][f["hand"] == 1][:, 2].sum()    # force on the left hand (from the ball): down
    down = f["forces"][f["hand"] == 0][:, 2].sum()  # on the right hand: up
    assert down > 0.5 and up < -0.5
    assert np.linalg.norm(state.body_x[model.bone_count] - ball.pose[:3]) < 0.02
