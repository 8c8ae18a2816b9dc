"""Teleport and dropout through the whole hand chain (issue #10 item 2), without ROS: tracker frames
-> TrackingLoop (250 Hz intermediate bones, paper Sect. 3.6) -> SimRuntime (60 Hz full simulation),
with the simulated skeleton fed back to the loop, exactly as tracking_node and sim_node wire them.

Script: 1 s hovering, the tracked hand jumps 1 m along x and stays 2 s, a 2 s dropout (no frames),
then frames return 0.3 m further along y. Elastic tracking bounds what follows: the intermediate
palm is a critically damped spring-mass pulled toward its target, so its speed never exceeds the
step-response peak d * omega / e (omega = sqrt(k / m) of the paper's 50 N/m on the palm's mass),
and the force on the simulated palm is the Eq. 14 spring, k * |x_intermediate - x_sim|.
"""
import numpy as np
import pytest

from softhand_sim.params import load_params
from softhand_sim.runtime import SimRuntime
from softhand_sim.scenarios.tracker_bags import PALM_DOWN, digit_angles
from softhand_sim.handmodel.kinematics import forward_kinematics
from softhand_tracking.loop import TrackingLoop, default_bone_inertia, loop_config_from

LOOP_DT, SIM_DT, FRAME_DT = 1.0 / 250.0, 1.0 / 60.0, 0.01
START = np.array([-0.05, 0.10, 1.00])      # [m] wrist, in the air above the table
JUMP = np.array([1.0, 0.0, 0.0])           # the teleport
AFTER = JUMP + np.array([0.0, 0.3, 0.0])   # where frames come back after the dropout
PHASES = {"hover": (0.0, 1.0), "jump": (1.0, 3.0), "dropout": (3.0, 5.0), "back": (5.0, 7.0)}


def tracked_at(t):
    """Wrist position of the frame due at t, or None during the dropout."""
    if t < 1.0:
        return START
    if t < 3.0:
        return START + JUMP
    if t < 5.0:
        return None
    return START + AFTER


@pytest.fixture(scope="module")
def run():
    params = load_params("sim_node")
    tp = load_params("tracking_node")  # the loop as tracking_node configures it
    rt = SimRuntime(params)
    loop = TrackingLoop(loop_config_from(tp), tracker_timeout=tp["tracker_timeout"], sim_timeout=tp["sim_timeout"])
    assert tp["rate"] == 250.0
    angles = digit_angles(np.full(5, 0.3))
    rows, next_frame, next_sim, frames = [], 0.0, 0.0, 0
    sim_palm, sim_v, rejected = None, 0.0, 0
    for k in range(int(7.0 / LOOP_DT)):
        t = k * LOOP_DT
        if t >= next_frame - 1e-9:
            next_frame += FRAME_DT
            pos = tracked_at(t)
            if pos is not None:
                assert loop.on_tracker(forward_kinematics(np.r_[pos, PALM_DOWN], angles)[0], t, t)
                frames += 1
        inter = loop.step(t)
        assert np.all(np.isfinite(inter))
        if t >= next_sim - 1e-9:
            next_sim += SIM_DT
            rt.set_bone_targets(inter)
            out = rt.step(SIM_DT, t)
            assert np.all(np.isfinite(out.bone_poses)) and np.all(np.isfinite(out.skin_vertices))
            loop.on_sim_bones(out.bone_poses, t)
            sim_palm = out.bone_poses[0, :3].copy()
            sim_v = float(np.linalg.norm(rt.state.body_v[0, :3]))
            rejected += out.rejected
        rows.append((t, *inter[0, :3], *sim_palm, sim_v))
    a = np.array(rows)
    return {"t": a[:, 0], "inter": a[:, 1:4], "sim": a[:, 4:7], "sim_speed": a[:, 7], "rejected": rejected,
            "frames": frames, "params": params, "tracking": tp, "holds": loop.holds}


def phase(r, name, skip=0.0):
    lo, hi = PHASES[name]
    return (r["t"] >= lo + skip) & (r["t"] < hi)


def peak_speed_bound(distance, run):
    """Step-response peak speed of the intermediate palm as a critically damped spring-mass pulled by
    its tracked spring alone: d * sqrt(k / m) / e (the spring to the lagging sim palm only slows it)."""
    omega = np.sqrt(run["tracking"]["tracked_kx"] / default_bone_inertia().mass[0])
    return distance * omega / np.e


def test_teleport_bounded_speed_and_force(run):
    """The 1 m jump: intermediate palm speed <= the critically damped peak 1 m * omega / e (15.5 m/s at 50 N/m),
    the Eq. 14 force on the simulated palm <= k * 1 m (50 N at the paper's k), the simulated palm
    no faster than that bound, no
    guard rejection, and both palms reach the new target within 1 cm / 2 cm in 2 s."""
    r, k = run, run["params"]["tracking_kx"]
    speed = np.linalg.norm(np.diff(r["inter"], axis=0), axis=1) / LOOP_DT
    m = phase(r, "jump")
    bound = peak_speed_bound(1.0, r)
    force = k * np.linalg.norm(r["inter"] - r["sim"], axis=1)
    print(f"jump: intermediate palm peak {speed[m[1:]].max():.2f} m/s (bound {bound:.2f}), sim palm peak "
          f"{r['sim_speed'][m].max():.2f} m/s, palm coupling force peak {force[m].max():.1f} N")
    assert speed[m[1:]].max() <= bound
    assert force[m].max() <= k * 1.0
    assert r["sim_speed"][m].max() <= bound  # the simulated palm, pulled by it, never outruns it
    assert r["rejected"] == 0
    end = np.searchsorted(r["t"], PHASES["jump"][1]) - 1
    assert np.linalg.norm(r["inter"][end] - (START + JUMP)) < 0.01
    assert np.linalg.norm(r["sim"][end] - (START + JUMP)) < 0.02


def test_dropout_holds_then_recovers_smoothly(run):
    """The 2 s dropout: the loop enters a hold, both palms stay within 1 cm (after 0.2 s); when frames
    come back 0.3 m away the intermediate palm moves there no faster than the 0.3 m peak d * omega / e
    (no jump), the force stays <= k * 0.3 m, and after 2 s both palms are within 1 cm of the target."""
    r, k = run, run["params"]["tracking_kx"]
    held = phase(r, "dropout", skip=0.2)
    drift_i = np.abs(r["inter"][held] - r["inter"][held][0]).max()
    drift_s = np.abs(r["sim"][held] - r["sim"][held][0]).max()
    back = phase(r, "back")
    speed = np.linalg.norm(np.diff(r["inter"], axis=0), axis=1) / LOOP_DT
    bound = peak_speed_bound(0.3, r)
    force = k * np.linalg.norm(r["inter"] - r["sim"], axis=1)
    print(f"dropout drift: intermediate {1e3 * drift_i:.1f} mm, sim {1e3 * drift_s:.1f} mm; back: peak "
          f"{speed[back[1:]].max():.2f} m/s (bound {bound:.2f}), force peak {force[back].max():.1f} N; "
          f"final error {1e3 * np.linalg.norm(r['inter'][-1] - START - AFTER):.1f} / "
          f"{1e3 * np.linalg.norm(r['sim'][-1] - START - AFTER):.1f} mm")
    assert r["holds"] >= 1
    assert drift_i < 0.01 and drift_s < 0.01
    assert speed[back[1:]].max() <= bound
    assert force[back].max() <= k * 0.3
    assert np.linalg.norm(r["inter"][-1] - (START + AFTER)) < 0.01
    assert np.linalg.norm(r["sim"][-1] - (START + AFTER)) < 0.01
