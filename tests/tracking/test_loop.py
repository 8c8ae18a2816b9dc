"""Intermediate-bone loop (paper Sect. 3.6): step response, equilibria, large jumps, dropouts, cost."""

import numpy as np
import pytest

from softhand_sim.physics.rotations import quat_exp, quat_mul, quat_to_matrix, relative_rotvec
from softhand_sim.scenarios import tracker_bags
from softhand_tracking.adapter import bone_frames
from softhand_sim.handmodel.kinematics import forward_kinematics
from softhand_tracking.loop import IntermediateBones, LoopConfig, TrackingLoop, default_bone_inertia

DT = 1.0 / 250.0


def _rest_bones(z=0.9):
    joints, _ = forward_kinematics(np.array([0, 0, z, 0, 0, 0, 1.0]), np.full((5, 4), 0.2))
    return bone_frames(joints[:, :3])


def _com(poses, com_local):
    return np.array([p[:3] + quat_to_matrix(p[3:].copy()) @ c for p, c in zip(poses, com_local)])


def _moved(poses, com_local, shift, rotvec):
    """Poses whose COMs move by `shift` and whose frames turn by `rotvec` (world) about the COM."""
    out = poses.copy()
    dq = quat_exp(rotvec)
    for b in range(poses.shape[0]):
        c = poses[b, :3] + quat_to_matrix(poses[b, 3:].copy()) @ com_local[b]
        q = quat_mul(dq, poses[b, 3:].copy())
        out[b, 3:] = q
        out[b, :3] = c + shift - quat_to_matrix(q) @ com_local[b]
    return out


def _angles(a, b):
    return np.array([np.linalg.norm(relative_rotvec(a[i, 3:].copy(), b[i, 3:].copy())) for i in range(a.shape[0])])


def test_step_response_2cm_20deg_no_overshoot_and_settles():
    """A 2 cm / 20 deg jump of every tracked bone: COMs and orientations reach it with < 10 %
    overshoot and settle to 1 % within 1 s, standalone (no sim copy), paper stiffnesses."""
    bones = IntermediateBones(LoopConfig())
    start = _rest_bones()
    bones.reset(start)
    com_local = bones.com_local
    shift, rotvec = np.array([0.02, 0.0, 0.0]), np.array([0.0, 0.0, np.deg2rad(20.0)])
    target = _moved(start, com_local, shift, rotvec)
    bones.set_tracked(target)
    c0 = _com(start, com_local)
    progress, turned = [], []
    for _ in range(250):
        pose = bones.step().copy()
        progress.append((_com(pose, com_local) - c0) @ shift / (shift @ shift))
        turned.append(1.0 - _angles(pose, target) / np.deg2rad(20.0))
    progress, turned = np.array(progress), np.array(turned)
    assert progress.max() < 1.10 and turned.max() < 1.10
    assert np.all(np.abs(progress[-1] - 1.0) < 0.01) and np.all(np.abs(turned[-1] - 1.0) < 0.01)
    assert progress[:, 0].max() > 0.5  # it did move (palm halfway within the second)


def test_palm_matches_backward_euler_recurrence():
    """The palm's COM follows, to round-off, the independent scalar backward-Euler recurrence of a
    mass m on spring k with damper c = 2 zeta sqrt(k m) (docs/DESIGN.md's one-Newton-step scheme, exact
    for a linear spring): (m + dt c + dt^2 k) v+ = m v - dt k (x - x_t);  x+ = x + dt v+."""
    cfg = LoopConfig(damping_ratio=0.5)
    bones = IntermediateBones(cfg)
    start = _rest_bones()
    bones.reset(start)
    target = _moved(start, bones.com_local, np.array([0.0, 0.03, -0.01]), np.zeros(3))
    bones.set_tracked(target)
    m, k = bones.mass[0], cfg.tracked_kx
    c = 2 * cfg.damping_ratio * np.sqrt(k * m)
    x = _com(start, bones.com_local)[0]
    xt = _com(target, bones.com_local)[0]
    v = np.zeros(3)
    for _ in range(200):
        v = (m * v - DT * k * (x - xt)) / (m + DT * c + DT * DT * k)
        x = x + DT * v
        np.testing.assert_allclose(_com(bones.step(), bones.com_local)[0], x, atol=1e-12)


def test_equilibrium_with_sim_copy_is_stiffness_weighted():
    """With a sim copy, the palm settles at the stiffness-weighted mean of tracked and simulated
    COMs (kx_t x_t + kx_s x_s) / (kx_t + kx_s); the phalanxes (kx = 0 to the copy, Sect. 3.6) at the
    tracked position; orientations at the k_theta-weighted mean angle about the common axis."""
    cfg = LoopConfig(tracked_kx=50, sim_kx=150, tracked_ktheta=200, sim_ktheta=600)
    bones = IntermediateBones(cfg)
    start = _rest_bones()
    bones.reset(start)
    sim = _moved(start, bones.com_local, np.array([0.04, 0.0, 0.0]), np.array([0.0, 0.0, 0.4]))
    bones.set_tracked(start)
    bones.set_sim(sim)
    for _ in range(1500):
        pose = bones.step()
    com = _com(pose, bones.com_local)
    c_start, c_sim = _com(start, bones.com_local), _com(sim, bones.com_local)
    np.testing.assert_allclose(com[0], (50 * c_start[0] + 150 * c_sim[0]) / 200, atol=1e-6)
    np.testing.assert_allclose(com[1:], c_start[1:], atol=1e-6)
    np.testing.assert_allclose(_angles(pose, start), 0.4 * 600 / 800, atol=1e-6)


def test_one_metre_jump_stays_bounded():
    """A 1 m jump (and a 180 deg flip) of the tracked hand: the bones stay finite, never leave the
    segment between start and target by more than 1 cm, and arrive without overshoot."""
    bones = IntermediateBones(LoopConfig())
    start = _rest_bones()
    bones.reset(start)
    shift = np.array([1.0, 0.0, 0.0])
    target = _moved(start, bones.com_local, shift, np.array([0.0, np.pi * 0.999, 0.0]))
    bones.set_tracked(target)
    c0 = _com(start, bones.com_local)
    for _ in range(750):
        pose = bones.step()
        assert np.all(np.isfinite(pose)) and np.all(np.isfinite(bones.vel))
        d = _com(pose, bones.com_local) - c0
        assert d[:, 0].min() > -0.01 and d[:, 0].max() < 1.01
        assert np.abs(d[:, 1:]).max() < 0.01
    assert np.abs(_com(pose, bones.com_local) - _com(target, bones.com_local)).max() < 0.01


def test_rejected_frames_never_reach_the_bones():
    """A NaN tracker frame is rejected and counted; the targets stay those of the last good frame."""
    loop = TrackingLoop()
    joints, _ = forward_kinematics(np.array([0, 0, 0.9, 0, 0, 0, 1.0]), np.full((5, 4), 0.2))
    assert loop.on_tracker(joints, 0.0)
    before = loop.tracked.copy()
    bad = joints.copy()
    bad[3, 0] = np.nan
    assert not loop.on_tracker(bad, 0.01)
    assert loop.adapter.rejected["non_finite"] == 1
    np.testing.assert_array_equal(loop.tracked, before)
    assert np.all(np.isfinite(loop.step(0.012)))


def test_nothing_before_the_first_frame():
    """Before any valid tracker frame the loop returns nothing to publish."""
    loop = TrackingLoop()
    assert loop.step(0.0) is None
    loop.on_sim_bones(_rest_bones(), 0.0)
    assert loop.step(0.004) is None


def test_sim_copy_dropped_after_timeout_is_counted():
    """/hand/bones silent for longer than sim_timeout: the sim copy is dropped once and counted."""
    loop = TrackingLoop(sim_timeout=0.5)
    stamps, joints, _ = tracker_bags.sample("grasp_short")
    loop.on_tracker(joints[0], 0.0)
    loop.on_sim_bones(_rest_bones(), 0.0)
    loop.step(0.4)
    assert loop.bones.sim_active and loop.sim_drops == 0
    loop.step(0.6)
    loop.step(0.7)
    assert not loop.bones.sim_active and loop.sim_drops == 1
    loop.on_sim_bones(_rest_bones(), 0.8)
    loop.step(0.8)
    assert loop.bones.sim_active and loop.sim_drops == 1


def _run_bag(name, dt=DT, extra=0.0):
    """Replays a synthetic scenario into TrackingLoop at 250 Hz; rows (t, palm error [m], holding)."""
    stamps, joints, _ = tracker_bags.sample(name)
    tf = (stamps - stamps[0]) * 1e-9
    loop = TrackingLoop()
    rows, k, t = [], 0, 0.0
    while t <= tf[-1] + extra:
        while k < len(tf) and tf[k] <= t:
            loop.on_tracker(joints[k], tf[k])
            k += 1
        out = loop.step(t)
        rows.append((t, np.linalg.norm(out[0, :3] - loop.tracked[0, :3]), loop.holding, out[0, :3].copy()))
        t += dt
    return loop, rows


def test_fast_motion_lag_and_dropout_hold():
    """fast_dropout (2 m/s peak, 300 ms gap): while tracked, the intermediate palm stays within
    5 cm of the tracked palm (paper's soft 50 N/m coupling on a 28 g palm: inertial lag m a / k
    plus damping); during the gap the loop reports holding and the palm converges onto the last
    target (error never grows, ends < 5 mm); after the gap it resumes (holding False) and is back
    within 5 cm in 0.5 s."""
    loop, rows = _run_bag("fast_dropout")
    t = np.array([r[0] for r in rows])
    err = np.array([r[1] for r in rows])
    hold = np.array([r[2] for r in rows])
    gap0, gap1 = tracker_bags.FAST_GAP
    tracking = (t < gap0) | (t > gap1 + 0.5)
    assert err[tracking].max() < 0.05
    in_gap = (t > gap0 + 0.12) & (t < gap1 - 0.01)
    assert hold[in_gap].all() and not hold[tracking].any()
    assert np.all(np.diff(err[in_gap]) <= 1e-9) and err[in_gap][-1] < 0.005
    assert loop.holds == 1 and loop.adapter.accepted > 500


def test_slow_grasp_lag_is_small():
    """grasp_lift (hand speeds below ~0.3 m/s): palm within 1 cm of the tracked palm throughout."""
    _, rows = _run_bag("grasp_lift")
    assert max(r[1] for r in rows) < 0.01


def test_bad_parameters_name_the_key():
    """Bad loop parameters raise errors naming the parameter."""
    with pytest.raises(ValueError, match="rate"):
        LoopConfig(rate=0)
    with pytest.raises(ValueError, match="damping_ratio"):
        LoopConfig(damping_ratio=-1)
    with pytest.raises(ValueError, match="tracker_timeout"):
        TrackingLoop(tracker_timeout=0)


def _held_with_sim(feedback, contact_from=None, steps=500):
    """A held tracked pose and a sim copy 4 cm / 0.4 rad away; palm COM per step. With contact_from
    (a step index) the loop is told of contacts from then on."""
    cfg = LoopConfig(tracked_kx=50, sim_kx=150, tracked_ktheta=200, sim_ktheta=600, feedback=feedback)
    loop = TrackingLoop(cfg)
    start = _rest_bones()
    sim = _moved(start, loop.bones.com_local, np.array([0.04, 0.0, 0.0]), np.array([0.0, 0.0, 0.4]))
    joints, _ = forward_kinematics(np.array([0, 0, 0.9, 0, 0, 0, 1.0]), np.full((5, 4), 0.2))
    com = []
    for k in range(steps):
        t = k * DT
        if k % 3 == 0:
            assert loop.on_tracker(joints, t, t)
        loop.on_sim_bones(sim, t)
        if contact_from is not None and k >= contact_from:
            loop.on_contacts(12, t)
        com.append(_com(loop.step(t), loop.bones.com_local)[0])
    return np.array(com), _com(start, loop.bones.com_local)[0], _com(sim, loop.bones.com_local)[0]


def test_feedback_acts_only_in_contact():
    """feedback "contact": in free air the palm settles on the tracked palm (no pull toward the sim copy);
    once the simulated hand touches something it settles at the stiffness-weighted mean as with the
    paper's "always", reached without a jump (the gain ramps: no step moves the palm over a tenth of the way)."""
    com, c_track, c_sim = _held_with_sim("contact", contact_from=250)
    weighted = (50 * c_track + 150 * c_sim) / 200
    np.testing.assert_allclose(com[249], c_track, atol=2e-4)
    np.testing.assert_allclose(com[-1], weighted, atol=2e-4)
    assert np.linalg.norm(np.diff(com[250:], axis=0), axis=1).max() < 0.1 * np.linalg.norm(weighted - c_track)
    always, _, _ = _held_with_sim("always")
    np.testing.assert_allclose(always[249], weighted, atol=2e-4)


def test_extrapolation_removes_the_frame_hold_lag():
    """A palm moving at 0.5 m/s, frames at 50 Hz: with the targets extrapolated to each step's time the
    intermediate palm trails the true palm by < 1 mm in steady motion; holding each frame it trails by
    about half a frame period more (10 ms: >= 2 mm)."""
    errs = {}
    for extrapolate in (True, False):
        loop = TrackingLoop(LoopConfig(extrapolate=extrapolate))
        err = []
        for k in range(250):
            t = k * DT
            x = lambda tt: np.array([0.5 * tt, 0.0, 0.9])
            if k % 5 == 0:  # a frame every 20 ms
                joints, _ = forward_kinematics(np.r_[x(t), 0, 0, 0, 1.0], np.full((5, 4), 0.2))
                assert loop.on_tracker(joints, t, t)
            out = loop.step(t)
            ref, _ = forward_kinematics(np.r_[x(t), 0, 0, 0, 1.0], np.full((5, 4), 0.2))
            err.append(np.linalg.norm(out[0, :3] - bone_frames(ref[:, :3])[0, :3]))
        errs[extrapolate] = np.median(err[150:])
    assert errs[True] < 0.001 and errs[False] > 0.002, errs


def test_coupling_changed_while_running_is_used_by_the_next_step():
    """set_coupling (what tracking_node's live parameters call) changes the stiffness the next step uses:
    a stiffer tracked coupling pulls a displaced bone further in one step; bad values are refused."""
    def one_step(kx):
        bones = IntermediateBones(LoopConfig(), default_bone_inertia())
        start = _rest_bones()
        bones.reset(start)
        bones.set_coupling(tracked_kx=kx)
        bones.set_tracked(_moved(start, bones.com_local, np.array([0.01, 0, 0]), np.zeros(3)))
        bones.set_sim(None)
        return bones.step()[0, 0] - start[0, 0]
    soft, stiff = one_step(50.0), one_step(5000.0)
    assert 0 < soft < stiff < 0.01
    bones = IntermediateBones(LoopConfig(), default_bone_inertia())
    with pytest.raises(ValueError, match="tracked_ktheta"):
        bones.set_coupling(tracked_ktheta=0.0)
    with pytest.raises(ValueError, match="not a coupling parameter"):
        bones.set_coupling(rate=10.0)


def test_bones_of_a_fitted_hand_replace_the_defaults():
    """hand_measures (file or auto): the loop takes a small hand's bones (lighter, centres of mass
    nearer their joints) in place of the default's, keeps its poses, and still steps to its targets."""
    from softhand_sim.scenarios.tracker_bags import SMALL_HAND
    from softhand_tracking.loop import bone_inertia_for, default_bone_inertia

    small, default = bone_inertia_for(SMALL_HAND), default_bone_inertia()
    assert np.all(small.mass < default.mass)
    assert np.all(np.linalg.norm(small.com_local, axis=1) < np.linalg.norm(default.com_local, axis=1))
    loop = TrackingLoop()
    frame, _ = forward_kinematics(np.array([0, 0, 0.9, 0, 0, 0, 1.0]), np.full((5, 4), 0.2))
    assert loop.on_tracker(frame, 0.0)
    for k in range(50):
        loop.step(k / 250.0)
    pose = loop.bones.pose.copy()
    loop.bones.set_inertia(small)
    np.testing.assert_array_equal(loop.bones.pose, pose)
    np.testing.assert_array_equal(loop.bones.mass, small.mass)
    for k in range(50, 150):
        loop.step(k / 250.0)
    assert np.all(np.isfinite(loop.bones.pose))
