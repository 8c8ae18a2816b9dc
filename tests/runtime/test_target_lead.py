"""softhand_sim.target_lead: bone targets moved to the end of the step with their velocity, out of
contact (sim_node parameter target_feed_forward), the palm target's acceleration carried by the
hand's masses (target_acceleration), and their effect on a real recording's lag."""
import functools

import numpy as np
import pytest

from softhand_sim.target_lead import (CONTACT_HOLD, MAX_ACCEL, MAX_LEAD, MAX_SHIFT, NEAR_GATE, RAMP, TargetLead,
                                      extrapolate, pose_velocity)


def _axis_angle_quat(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.concatenate([np.sin(0.5 * angle) * axis, [np.cos(0.5 * angle)]])


def _motion(t, n=3):
    """n bones moving at constant velocity: origins at 0.3 m/s along a fixed direction, each
    turning at its own constant rate about its own fixed world axis."""
    axes = np.array([[0.0, 0.0, 1.0], [1.0, 1.0, 0.0], [0.2, -1.0, 0.5]])[:n]
    rates = np.array([2.0, -5.0, 9.0])[:n]
    out = np.empty((n, 7))
    for b in range(n):
        out[b, :3] = np.array([0.01 * b, 0.0, 0.8]) + t * np.array([0.3, -0.1, 0.05])
        out[b, 3:] = _axis_angle_quat(axes[b], rates[b] * t)
    return out, axes / np.linalg.norm(axes, axis=1, keepdims=True) * rates[:, None]


def _quat_angle(a, b):
    return 2.0 * np.arccos(np.clip(np.abs(np.sum(a * b, axis=-1)), 0.0, 1.0))


def test_velocity_and_extrapolation_are_exact_for_constant_velocity():
    p0, w = _motion(0.0)
    p1, _ = _motion(0.02)
    v = pose_velocity(p0, p1, 0.02)
    np.testing.assert_allclose(v[:, :3], np.tile([0.3, -0.1, 0.05], (3, 1)), atol=1e-12)
    np.testing.assert_allclose(v[:, 3:], w, atol=1e-9)
    ahead = extrapolate(p1, v, 0.03)
    want, _ = _motion(0.05)
    np.testing.assert_allclose(ahead[:, :3], want[:, :3], atol=1e-12)
    assert _quat_angle(ahead[:, 3:], want[:, 3:]).max() < 1e-9


def test_targets_reach_the_end_of_the_step_in_free_air():
    """Targets every 4 ms of a constant-velocity motion: the ones for a step ending at t_end are
    the motion at t_end (to 1e-9), the lead is t_end - stamp, never more than MAX_LEAD."""
    lead = TargetLead()
    for k in range(20):
        lead.on_target(_motion(0.004 * k)[0], 0.004 * k)
    stamp = 0.004 * 19
    for ahead in (0.01, 0.02, 0.1):
        got = lead.targets_at(stamp + ahead)
        want = _motion(stamp + min(ahead, MAX_LEAD))[0]
        assert lead.lead == pytest.approx(min(ahead, MAX_LEAD))
        np.testing.assert_allclose(got[:, :3], want[:, :3], atol=1e-9)
        assert _quat_angle(got[:, 3:], want[:, 3:]).max() < 1e-9


def _feed(lead, until, k0=0):
    """Targets of _motion every 4 ms (250 Hz, as tracking_node sends them) from step k0 up to
    time `until` [s]; returns the next step."""
    k = k0
    while 0.004 * k <= until + 1e-12:
        lead.on_target(_motion(0.004 * k)[0], 0.004 * k)
        k += 1
    return k


def test_contact_drops_the_lead_at_once_and_it_returns_after_the_hold():
    lead = TargetLead()
    k = _feed(lead, 0.036)
    t = 0.036
    assert lead.targets_at(t + 0.01) is not None and lead.lead > 0
    lead.on_contacts(5, t + 0.01)
    np.testing.assert_array_equal(lead.targets_at(t + 0.02), lead.poses)  # the step right after: none
    assert lead.lead == 0.0
    k = _feed(lead, t + CONTACT_HOLD, k)
    assert lead.targets_at(t + 0.01 + CONTACT_HOLD) is lead.poses       # held off
    k = _feed(lead, t + CONTACT_HOLD + 0.5 * RAMP, k)
    lead.targets_at(t + 0.01 + CONTACT_HOLD + 0.5 * RAMP)               # ramping back
    assert 0.0 < lead.gain < 1.0
    k = _feed(lead, t + CONTACT_HOLD + 2 * RAMP, k)
    lead.targets_at(t + 0.01 + CONTACT_HOLD + 2 * RAMP)
    assert lead.gain == 1.0


def test_stale_targets_are_held_not_led_anew():
    """Targets stop coming (a link down, the tracking stopped) while the hand touches something,
    and the contact ends while none come: the held targets stay as they came, however long (the
    lead does not come back by the last velocity: across hosts it moved a held hand 11 mm in the
    middle of an outage). Targets coming again bring it back."""
    lead = TargetLead()
    _feed(lead, 0.2)
    lead.on_contacts(5, 0.2)
    held = lead.poses
    for t in np.arange(0.21, 1.5, 1 / 150):  # contact gone at 0.2 s, no target after it
        np.testing.assert_array_equal(lead.targets_at(t), held)
        assert lead.lead == 0.0
    _feed(lead, 1.6, int(round(1.5 / 0.004)))  # tracking again: the gate's hold, then the ramp
    lead.targets_at(1.6 + 0.004)
    assert lead.gain == 1.0 and lead.lead > 0.0


def test_an_object_within_the_near_gate_drops_the_lead_before_contact():
    """The skin nearer than NEAR_GATE to an object (no contact yet) drops the lead as a contact
    does; farther, or with the distance unknown (inf), it stays."""
    lead = TargetLead()
    for k in range(10):
        lead.on_target(_motion(0.004 * k)[0], 0.004 * k)
    t = 0.036
    lead.on_contacts(0, t, near=1.5 * NEAR_GATE)
    lead.on_contacts(0, t, near=np.inf)
    assert lead.targets_at(t + 0.01) is not None and lead.lead > 0
    lead.on_contacts(0, t + 0.01, near=0.5 * NEAR_GATE)
    np.testing.assert_array_equal(lead.targets_at(t + 0.02), lead.poses)
    assert lead.lead == 0.0


def test_no_velocity_across_a_gap_unstamped_or_disabled_targets():
    lead = TargetLead()
    for k in range(10):
        lead.on_target(_motion(0.004 * k)[0], 0.004 * k)
    assert lead.vel is not None
    lead.on_target(_motion(1.0)[0], 1.0)          # 1 s later: a gap
    assert lead.vel is None
    np.testing.assert_array_equal(lead.targets_at(1.02), lead.poses)
    lead.on_target(_motion(1.004)[0], None)       # unstamped
    assert lead.vel is None and lead.targets_at(1.02) is lead.poses
    off = TargetLead(enabled=False)
    for k in range(10):
        off.on_target(_motion(0.004 * k)[0], 0.004 * k)
    assert off.targets_at(0.06) is off.poses and off.lead == 0.0


def _moving_lead():
    lead = TargetLead()
    for k in range(10):
        lead.on_target(_motion(0.004 * k)[0], 0.004 * k)
    return lead


def test_acceleration_is_the_second_difference_of_the_palm_targets():
    """Palm targets x(t) = x0 + v t + a t^2 / 2 at uneven step ends: the acceleration is a (to
    round-off) from the third step on, nil before; the contact gate scales it; it is capped at
    MAX_ACCEL, nil after a gap of the targets, after time going back and with the option off."""
    a = np.array([2.0, -1.0, 0.5])

    def palm(t):
        return np.array([0.1, 0.0, 0.9]) + t * np.array([0.3, 0.0, 0.0]) + 0.5 * a * t * t

    lead = _moving_lead()
    ends = [0.05, 0.0667, 0.08, 0.1, 0.115]
    got = []
    for t in ends:
        lead.targets_at(t)
        got.append(lead.acceleration(t, palm(t)))
    np.testing.assert_array_equal(got[0], 0.0)
    np.testing.assert_array_equal(got[1], 0.0)
    for g in got[2:]:
        np.testing.assert_allclose(g, a, atol=1e-9)
    lead.on_contacts(3, 0.115)                              # in contact: the gate closes
    lead.targets_at(0.13)
    np.testing.assert_array_equal(lead.acceleration(0.13, palm(0.13)), 0.0)
    t = 0.115 + CONTACT_HOLD                                # the hold's end: still nil
    k = _feed(lead, t, 10)                                  # (targets keep coming: stale ones are held)
    lead.targets_at(t)
    np.testing.assert_array_equal(lead.acceleration(t, palm(t)), 0.0)
    t += 0.2 * RAMP                                         # ramping back
    _feed(lead, t, k)
    lead.targets_at(t)
    g = lead.acceleration(t, palm(t))
    assert 0.0 < lead.gain < 1.0
    np.testing.assert_allclose(g, lead.gain * a, atol=1e-8)
    jump = lead.acceleration(t + 0.016, palm(t + 0.016) + [0.5, 0.0, 0.0])  # 50 cm in one step
    assert np.linalg.norm(jump) == pytest.approx(MAX_ACCEL)
    np.testing.assert_array_equal(lead.acceleration(t - 0.1, palm(t - 0.1)), 0.0)  # time went back
    lead.on_target(_motion(2.0)[0], 2.0)                    # a gap: no velocity, no acceleration
    np.testing.assert_array_equal(lead.acceleration(2.02, palm(2.02)), 0.0)
    off = _moving_lead()
    off.accelerate = False  # as TargetLead(accelerate=False)
    for t in ends:
        off.targets_at(t)
        np.testing.assert_array_equal(off.acceleration(t, palm(t)), 0.0)


@pytest.mark.parametrize("accelerate", [False, True])
def test_the_hand_is_carried_without_stretching_the_palm_spring(accelerate):
    """The whole hand, hovering far from every object, follows palm targets that accelerate
    upward at 2 m/s^2 (targets every 4 ms, steps at 60 Hz). Without the feed-forward the palm's
    spring stretches to carry the hand: the palm trails its target by M a / k (M the hand's mass,
    k the palm's 500 N/m; 1.5 mm) within 10 %; with it, by under 5 % of that."""
    from softhand_sim.params import load_params
    from softhand_sim.runtime import SimRuntime

    rt = SimRuntime(load_params("sim_node", overrides={"target_acceleration": accelerate}))
    rest = rt.model.body_rest_pose[:16].copy()
    rest[:, 2] += 0.9
    accel, dt = 2.0, 1.0 / 60.0
    stretch, t_msg, t = [], 0.0, 0.0
    while t < 0.5:
        while t_msg <= t + 1e-9:
            poses = rest.copy()
            poses[:, 2] += 0.5 * accel * t_msg ** 2
            rt.set_bone_targets(poses, t_msg)
            t_msg += 0.004
        out = rt.step(dt, t)
        assert not out.rejected and len(out.contacts["forces"]) == 0
        t += dt
        stretch.append(rt.control.target_x[0, 2] - rt.state.body_x[0, 2])
    hand = rt.model.hands
    mass = rt.model.node_mass[hand.nodes(0)].sum() + rt.model.body_mass[hand.bones(0)].sum()
    expected = mass * accel / rt.model.body_target_kx[0]
    late = np.array(stretch[-8:])
    print(f"accelerate={accelerate}: stretch {1e3 * late.mean():.3f} mm, M a / k = {1e3 * expected:.3f} mm")
    if accelerate:
        assert np.abs(late).max() < 0.05 * expected
    else:
        assert late.mean() == pytest.approx(expected, rel=0.10)


def test_tracker_noise_is_not_amplified_into_the_targets():
    """A still hand with 1 mm / 1 deg of noise on each target: the lead adds at most 10 % to the
    noise (the velocity is a 20 ms difference, low-pass filtered, and scaled down where it is not
    above its own noise; measured 1.6 %), not the ~5x of 4 ms steps."""
    rng = np.random.default_rng(0)
    lead = TargetLead()
    base = _motion(0.0)[0]
    err_in, err_out = [], []
    for k in range(400):
        p = base.copy()
        p[:, :3] += rng.normal(scale=1e-3, size=(3, 3))
        p[:, 3:] = [_axis_angle_quat(rng.normal(size=3), np.radians(1.0)) for _ in range(3)]
        p[:, 3:] = [np.array([*(q[3] * b[:3] + b[3] * q[:3] + np.cross(q[:3], b[:3])), q[3] * b[3] - q[:3] @ b[:3]])
                    for q, b in zip(p[:, 3:], base[:, 3:])]
        lead.on_target(p, 0.004 * k)
        out = lead.targets_at(0.004 * k + 0.018)
        if k > 50:
            err_in.append(np.linalg.norm(p[:, :3] - base[:, :3], axis=1))
            err_out.append(np.linalg.norm(out[:, :3] - base[:, :3], axis=1))
    assert np.sqrt(np.mean(np.square(err_out))) < 1.1 * np.sqrt(np.mean(np.square(err_in)))


def test_a_moving_hand_keeps_its_lead_through_small_noise():
    """The constant-velocity motion with 0.2 mm of noise on each target: led 18 ms ahead, the
    targets' positional error at the step's end is under a quarter of the unled targets' (the noise
    scaling leaves a motion well above its noise its lead)."""
    rng = np.random.default_rng(1)
    lead = TargetLead()
    led, held = [], []
    for k in range(200):
        t = 0.004 * k
        p = _motion(t)[0]
        p[:, :3] += rng.normal(scale=2e-4, size=(3, 3))
        lead.on_target(p, t)
        if k > 50:
            want = _motion(t + 0.018)[0][:, :3]
            led.append(np.linalg.norm(lead.targets_at(t + 0.018)[:, :3] - want, axis=1))
            held.append(np.linalg.norm(p[:, :3] - want, axis=1))
    assert np.mean(led) < 0.25 * np.mean(held)


def test_the_palm_leads_with_its_own_velocity_through_a_turn():
    """The palm (bone 0) and a second bone swinging together, 4 cm at 2 Hz along x, targets every 4
    ms led 17 ms ahead: the palm, led with the least-squares slope of its last 20 ms, is nearer to
    where it will be than the second bone, led with the low-pass filtered 20 ms difference, which
    trails the turns (measured: 1.87 against 2.73 mm RMS; before the palm had its own velocity the
    two were the same); both are nearer than the targets as they came (6.02 mm)."""
    def poses(t):
        p = np.tile([0.0, 0.0, 0.8, 0.0, 0.0, 0.0, 1.0], (2, 1))
        p[:, 0] += 0.04 * np.sin(2.0 * np.pi * 2.0 * t)
        p[1, 1] += 0.05
        return p

    lead = TargetLead()
    palm, other, held = [], [], []
    for k in range(300):
        t = 0.004 * k
        lead.on_target(poses(t), t)
        if k > 50:
            want = poses(t + 0.017)[:, 0]
            got = lead.targets_at(t + 0.017)[:, 0]
            palm.append(got[0] - want[0])
            other.append(got[1] - want[1])
            held.append(poses(t)[0, 0] - want[0])
    rms = [1e3 * np.sqrt(np.mean(np.square(e))) for e in (palm, other, held)]
    print("led palm, led second bone, unled [mm RMS]:", np.round(rms, 2))
    assert rms[0] < 0.75 * rms[1] and rms[1] < rms[2]


def test_a_jump_of_the_targets_is_not_led_further_than_max_shift():
    """Targets that race 10 cm in 8 ms (the intermediate bones catching up with a tracker jump):
    the led targets stay within MAX_SHIFT of the targets as they came."""
    lead = TargetLead()
    for k in range(20):
        lead.on_target(_motion(0.004 * k)[0], 0.004 * k)
    for k in range(20, 23):
        p = _motion(0.004 * k)[0]
        p[:, 0] += 0.05 * (k - 19)
        lead.on_target(p, 0.004 * k)
        got = lead.targets_at(0.004 * k + 0.018)
        assert np.linalg.norm(got[:, :3] - p[:, :3], axis=1).max() <= MAX_SHIFT + 1e-12


def test_warm_up_compiles_every_kernel_the_lead_calls():
    """In a fresh process: after target_lead.warm_up (the runtime's warm-up step calls it), a hand
    that is led compiles nothing more (left to the first lead, the compile stalled sim_node for
    seconds in the middle of a run on a fresh checkout)."""
    from tests.support.compiles import compiled_by
    compiled = compiled_by("""
        import numpy as np
        from softhand_sim import target_lead
        from softhand_sim.physics import rotations
        target_lead.warm_up()
        """, "[getattr(rotations, n) for n in dir(rotations) if hasattr(getattr(rotations, n), 'signatures')]", """
        lead = target_lead.TargetLead()
        q = np.array([0.0, 0.0, np.sin(0.1), np.cos(0.1)])
        for k in range(30):
            poses = np.tile(np.r_[0.001 * k, 0.0, 0.8, q], (16, 1))
            poses[:, 3:] = [np.r_[0.0, 0.0, np.sin(0.01 * k), np.cos(0.01 * k)]] * 16
            lead.on_target(poses, 0.004 * k)
            out = lead.targets_at(0.004 * k + 0.017)
        assert lead.lead > 0.0
        """)
    assert compiled == "{}", f"compiled during the lead: {compiled}"


@functools.lru_cache(maxsize=None)
def _leap_grab_lag(**sim_overrides):
    """layer_lag of the simulated hand against the tracked one on leap_grab (a real Leap
    recording) through the offline pipeline with these sim_node parameters (each run once)."""
    from softhand_sim.commands.lag import _sorted, layer_lag, tracked_bones
    from softhand_sim.commands.offline import read_frames, run_pipeline

    times, joints = read_frames("leap_grab", None, side="right")
    outs = []
    run_pipeline(bag="leap_grab", sim_overrides=sim_overrides, progress=lambda o: outs.append((o.t, o.bone_poses.copy())))
    t = np.array([o[0] for o in outs])
    keep = t <= times[-1] + 0.2
    result = layer_lag(tracked_bones(joints, times, "right"), _sorted(t[keep], np.array([o[1] for o in outs])[keep]))
    print(sim_overrides, {k: result[k] for k in ("lag_phalanx_ms", "lag_palm_ms")}, result["phalanx_deg"],
          result["palm_mm"])
    return result


@pytest.mark.slow
def test_feed_forward_halves_the_simulated_lag_on_a_real_recording():
    """leap_grab through the offline pipeline at the default rate (one hand: 200 Hz): the
    simulated phalanxes trail the tracked ones by 12.0 ms without the lead and by 8.7 ms with it,
    the palm by 24.4 ms and, with the lead and the palm target's acceleration, 11.4 ms: within
    #17's 15 ms (at 150 Hz 12.5 / 24.6 and 8.5 / 11.9 ms; at 60 Hz, before the palm's own velocity,
    23 / 32 ms without, 14.6 / 18.6 ms with); the phalanx error's median drops too."""
    off, on = _leap_grab_lag(target_feed_forward=False), _leap_grab_lag()
    assert off["lag_phalanx_ms"] > 11.0 and on["lag_phalanx_ms"] < 10.0
    assert off["lag_palm_ms"] > 20.0 and on["lag_palm_ms"] < 15.0
    assert on["phalanx_deg"]["median"] < off["phalanx_deg"]["median"]


@pytest.mark.slow
def test_the_palm_target_acceleration_cuts_the_palm_lag_on_a_real_recording():
    """leap_grab through the offline pipeline with the lead, without and with the palm target's
    acceleration on the hand's masses (target_acceleration), at the default rate (200 Hz): the
    simulated palm's lag 20.1 -> 11.4 ms, its position error p95 18.1 -> 6.5 mm (at 150 Hz 19.2 ->
    11.9 ms, 14.9 -> 5.7 mm; at 60 Hz, before the palm's own velocity, 27.5 -> 18.6 ms, 10.8 -> 6.5
    mm); the phalanxes' lag and error stay (the load is the same on every mass: it moves the hand,
    it does not bend it)."""
    off, on = _leap_grab_lag(target_acceleration=False), _leap_grab_lag()
    assert off["lag_palm_ms"] > 18.0 and on["lag_palm_ms"] < 15.0
    assert on["palm_mm"]["p95"] < 0.75 * off["palm_mm"]["p95"]
    assert on["lag_phalanx_ms"] == pytest.approx(off["lag_phalanx_ms"], abs=0.5)
    assert on["phalanx_deg"]["median"] == pytest.approx(off["phalanx_deg"]["median"], abs=0.05)
