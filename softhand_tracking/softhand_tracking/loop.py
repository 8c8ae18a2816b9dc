"""High-rate intermediate-bone loop, paper Sect. 3.6 "Layered setup".

16 disconnected rigid bodies (the intermediate bones). Each is coupled by Eq. 14
(`softhand_sim.physics.energies.rigid_coupling`, the sim's own implementation) to

* its tracked bone (from the tracker adapter): kx = tracked_kx, k_theta = tracked_ktheta, and
* its copy of the full-simulation bone (/hand/{hand}/bones), held constant between updates:
  palm kx = sim_kx and k_theta = sim_ktheta; phalanxes kx = 0 (paper: "only orientations for the
  phalanxes"). Without a copy (no sim running) only the tracked coupling acts.

The feedback (the coupling to the simulation's copy) is what keeps the layers stable in contact:
when contact stops the simulated hand, it pulls the intermediate bones back toward it, so they do
not run ahead into the object (the two springs act in series on the simulated hand). In free air it
only costs: with equal stiffnesses a held intermediate bone sits halfway between the tracked and
the simulated bone, and in motion it is dragged back toward the lagging simulation (issue #17:
38 -> 22 ms of lag without it on a real recording). `feedback` chooses: "always" (the paper) or
"contact" (the default): the feedback acts, at full stiffness, while the simulated hand touches
something (`on_contacts`, /hand/contacts) and for FEEDBACK_HOLD after; its gain ramps over
FEEDBACK_RAMP, so switching it is no jolt. Contact behaviour is the paper's; free air follows the
tracked hand alone.

Tracked targets: the tracked pose is held between frames, so on average it is half a frame period
old (plus transport). With `extrapolate` the target of each step is moved forward to the step
time with the tracked bones' reference velocity (below), at most MAX_EXTRAPOLATION past the frame,
scaled by (1 - feedback gain): in contact the targets are the paper's, not pushed into the object.

Integration: backward Euler with one Newton step (docs/DESIGN.md "The step"), per body about its centre
of mass (the coupled points of Eq. 14 are the COMs, as in the solver), angular velocity in world
coordinates, q <- exp(dt w) q:

    (m + dt c + dt^2 kx) v+ = m v - dt dU/dx + dt c v_ref
    (I + dt D + dt^2 k_theta) w+ = I w - dt dU/dtheta + dt D w_ref

Damping (c, D) is added because it is needed: with the paper's 50 N/m on a 28 g palm, w dt = 0.17
at 250 Hz, and backward Euler's own numerical damping (ratio ~ w dt / 2 ~ 0.08) leaves a 2 cm step
ringing with ~65 % overshoot (measured: 67 %). c = 2 zeta sqrt(kx m), D = 2 zeta sqrt(k_theta) I^(1/2) (per
principal axis: critical for zeta = 1). It acts on the velocity relative to the tracked bone's
(v_ref, w_ref, finite differences of the tracker frames), so it brakes oscillation about the
target without making the bones lag a hand that moves at constant speed; while the tracker is
lost the reference is zero (hold).

Masses and inertias: the hand model's bones (softhand_sim.handmodel: capsules of bone density
1900 kg/m^3; palm 28 g) when it imports, else `default_bone_inertia` (same formula, documented).
Gyroscopic terms w x I w are left out: bodies this small under springs this stiff never spin
fast enough for them to matter at 250 Hz.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from softhand_sim.physics.energies.rigid_coupling import target_energy_gradient
from softhand_sim.physics.rotations import integrate_rotation, quat_log, quat_mul, quat_conj, quat_to_matrix
from softhand_sim.handmodel.skeleton_names import BONE_COUNT

MAX_REF_SPEED = 5.0      # [m/s] cap on the tracked bones' estimated speed (a glitch is no velocity)
MAX_REF_RATE = 40.0      # [rad/s] cap on their estimated angular rate
REF_STALE = 0.03         # [s] a reference velocity older than this is dropped (the target stopped)
REF_SMOOTHING = 0.015    # [s] time constant of the low-pass filter on the reference velocity
FEEDBACK_HOLD = 0.2      # [s] the feedback stays on this long after the last contact
FEEDBACK_RAMP = 0.02     # [s] the feedback gain goes 0 <-> 1 over this time (0.05: the press_table skin
                         # went 5.0 mm into the table, the bound of its test)
MAX_EXTRAPOLATION = 0.03  # [s] tracked targets are never extrapolated further past their frame


@dataclass
class LoopConfig:
    """Loop parameters: rate [Hz]; Eq. 14 stiffnesses [N/m], [N m/rad]; damping ratio zeta [-]."""

    rate: float = 250.0
    tracked_kx: float = 50.0
    tracked_ktheta: float = 200.0
    sim_kx: float = 50.0
    sim_ktheta: float = 200.0
    damping_ratio: float = 1.0
    feedback: str = "contact"          # "always" (paper) | "contact" (module docstring)
    extrapolate: bool = True           # move tracked targets forward to the step time
    ref_smoothing: float = REF_SMOOTHING  # [s] low-pass time constant of the reference velocity

    def __post_init__(self):
        if self.feedback not in ("always", "contact"):
            raise ValueError(f"loop parameter feedback must be 'always' or 'contact', got {self.feedback!r}")
        if not (np.isfinite(self.ref_smoothing) and self.ref_smoothing >= 0):
            raise ValueError(f"loop parameter ref_smoothing must be >= 0 s, got {self.ref_smoothing!r}")
        for name in ("rate", "tracked_kx", "tracked_ktheta", "sim_kx", "sim_ktheta", "damping_ratio"):
            value = float(getattr(self, name))
            if not np.isfinite(value) or value < 0 or (name in ("rate", "tracked_ktheta") and value == 0):
                raise ValueError(f"loop parameter {name} must be finite and {'> 0' if name in ('rate', 'tracked_ktheta') else '>= 0'}, got {value!r}")
            setattr(self, name, value)

    @property
    def dt(self) -> float:
        return 1.0 / self.rate


@dataclass
class BoneInertia:
    """Per-bone rigid-body data: mass (16,) [kg], com_local (16, 3) [m] in the bone frame,
    inertia_local (16, 3, 3) [kg m^2] about the COM in bone-frame axes."""

    mass: np.ndarray
    com_local: np.ndarray
    inertia_local: np.ndarray
    source: str = "handmodel"


def loop_config_from(p: dict) -> LoopConfig:
    """The loop's settings from tracking_node's parameters `p` (softhand_sim.params.TRACKING): as
    tracking_node and `softhand offline` configure it."""
    return LoopConfig(rate=p["rate"], tracked_kx=p["tracked_kx"], tracked_ktheta=p["tracked_ktheta"],
                      sim_kx=p["sim_kx"], sim_ktheta=p["sim_ktheta"], damping_ratio=p["damping_ratio"],
                      feedback=p["feedback"], extrapolate=p["extrapolate"], ref_smoothing=p["ref_smoothing"])


def bone_inertia_for(measures) -> BoneInertia:
    """Masses and inertias of the hand model's skeleton at `measures` (HandMeasures): the bones
    of a user's hand (parameter hand_measures)."""
    from softhand_sim.handmodel.skeleton import build_skeleton
    sk = build_skeleton(measures)
    return BoneInertia(sk["bone_mass"].copy(), sk["bone_com_local"].copy(), sk["bone_inertia_local"].copy(),
                       source="measures")


def default_bone_inertia() -> BoneInertia:
    """Masses and inertias of the hand model's default skeleton, or, when the hand model cannot
    be imported, solid capsules (density 1900 kg/m^3, radius 8 mm, along the bone from its origin,
    length: palm 9 cm, phalanxes 3 cm, thumb metacarpal 4.4 cm)."""
    try:
        from softhand_sim.handmodel.measures import HandMeasures
        from softhand_sim.handmodel.skeleton import build_skeleton
        sk = build_skeleton(HandMeasures())
        return BoneInertia(sk["bone_mass"].copy(), sk["bone_com_local"].copy(), sk["bone_inertia_local"].copy())
    except ImportError:
        lengths = np.array([0.09, 0.044] + [0.03] * 14)
        r, rho = 0.008, 1900.0
        mass = rho * np.pi * r * r * lengths
        inertia = np.zeros((BONE_COUNT, 3, 3))
        for b in range(BONE_COUNT):
            ia = 0.5 * mass[b] * r * r
            ip = mass[b] * (3 * r * r + lengths[b] ** 2) / 12.0
            inertia[b] = np.diag([ia, ip, ip])
        com = np.zeros((BONE_COUNT, 3))
        com[:, 0] = 0.5 * lengths
        return BoneInertia(mass, com, inertia, source="default capsules")


def _sqrt_spd(m):
    w, v = np.linalg.eigh(m)
    return (v * np.sqrt(np.maximum(w, 0.0))) @ v.T


@njit(cache=True)
def _com_world(pose, com_local):
    rot = quat_to_matrix(pose[3:7].copy())
    return pose[0:3] + rot @ com_local, rot


@njit(cache=True)
def step_bodies(pose, vel, mass, com_local, inertia_local, inertia_sqrt_local,
                tracked_pose, ref_vel, tracked_kx, tracked_ktheta,
                sim_pose, sim_kx, sim_ktheta, sim_active, zeta, dt):
    """One backward-Euler step of the 16 intermediate bones, in place (module docstring).

    pose (B, 7) bone-frame poses [m, quat x y z w]; vel (B, 6) COM velocity [m/s] and world angular
    velocity [rad/s]; tracked_pose / sim_pose (B, 7) targets; ref_vel (B, 6) tracked bones' velocity;
    *_kx (B,) [N/m], *_ktheta (B,) [N m/rad]; sim_active: couple to sim_pose; zeta damping ratio.
    Returns the total Eq. 14 energy [J] before the step.
    """
    energy = 0.0
    grad = np.zeros(6)
    eye = np.eye(3)
    for b in range(pose.shape[0]):
        xc, rot = _com_world(pose[b], com_local[b])
        q = pose[b, 3:7].copy()
        xt, _ = _com_world(tracked_pose[b], com_local[b])
        grad[:] = 0.0
        energy += target_energy_gradient(xc, q, xt, tracked_pose[b, 3:7].copy(), tracked_kx[b], tracked_ktheta[b], grad)
        klin = tracked_kx[b]
        krot = tracked_ktheta[b]
        if sim_active:
            xs, _ = _com_world(sim_pose[b], com_local[b])
            energy += target_energy_gradient(xc, q, xs, sim_pose[b, 3:7].copy(), sim_kx[b], sim_ktheta[b], grad)
            klin += sim_kx[b]
            krot += sim_ktheta[b]
        m = mass[b]
        c = 2.0 * zeta * np.sqrt(klin * m)
        denom = m + dt * c + dt * dt * klin
        for i in range(3):
            vel[b, i] = (m * vel[b, i] - dt * grad[i] + dt * c * ref_vel[b, i]) / denom
        inertia = rot @ inertia_local[b] @ rot.T
        damp = (2.0 * zeta * np.sqrt(krot)) * (rot @ inertia_sqrt_local[b] @ rot.T)
        lhs = inertia + dt * damp + (dt * dt * krot) * eye
        rhs = inertia @ vel[b, 3:6] - dt * grad[3:6] + dt * (damp @ ref_vel[b, 3:6])
        w = np.linalg.solve(lhs, rhs)
        for i in range(3):
            vel[b, 3 + i] = w[i]
        q_new = integrate_rotation(q, w, dt)
        rot_new = quat_to_matrix(q_new)
        x_new = xc + dt * vel[b, 0:3]
        pose[b, 0:3] = x_new - rot_new @ com_local[b]
        pose[b, 3:7] = q_new
    return energy


@njit(cache=True)
def extrapolate_poses(poses, vel, com_local, tau):
    """(B, 7) poses moved forward by tau [s] with COM velocities and world angular velocities vel (B, 6)."""
    out = np.empty_like(poses)
    for b in range(poses.shape[0]):
        xc, _ = _com_world(poses[b], com_local[b])
        q = integrate_rotation(poses[b, 3:7].copy(), vel[b, 3:6].copy(), tau)
        rot = quat_to_matrix(q)
        out[b, 0:3] = xc + tau * vel[b, 0:3] - rot @ com_local[b]
        out[b, 3:7] = q
    return out


@njit(cache=True)
def pose_velocity(prev, cur, com_local, dt):
    """(B, 6) COM velocity and world angular velocity taking poses prev -> cur over dt [s]."""
    out = np.empty((prev.shape[0], 6))
    for b in range(prev.shape[0]):
        x0, _ = _com_world(prev[b], com_local[b])
        x1, _ = _com_world(cur[b], com_local[b])
        w = quat_log(quat_mul(cur[b, 3:7].copy(), quat_conj(prev[b, 3:7].copy())))
        for i in range(3):
            out[b, i] = (x1[i] - x0[i]) / dt
            out[b, 3 + i] = w[i] / dt
    return out


class IntermediateBones:
    """State and step of the 16 intermediate bones (no ROS, no tracker bookkeeping).

    `reset(poses)` places the bodies at rest on poses (16, 7); `set_tracked(poses, ref_vel)` and
    `set_sim(poses | None)` set the coupling targets (held until the next call); `step()` advances
    one period 1/rate. `pose` (16, 7) and `vel` (16, 6) are the state.
    """

    def __init__(self, config: LoopConfig | None = None, inertia: BoneInertia | None = None):
        self.config = config if config is not None else LoopConfig()
        self.set_inertia(inertia if inertia is not None else default_bone_inertia())
        c = self.config
        self.tracked_kx = np.full(BONE_COUNT, c.tracked_kx)
        self.tracked_ktheta = np.full(BONE_COUNT, c.tracked_ktheta)
        self.sim_kx = np.zeros(BONE_COUNT)
        self.sim_kx[0] = c.sim_kx                      # palm only; phalanxes kx = 0 (Sect. 3.6)
        self.sim_ktheta = np.full(BONE_COUNT, c.sim_ktheta)
        self.pose = np.zeros((BONE_COUNT, 7))
        self.pose[:, 6] = 1.0
        self.vel = np.zeros((BONE_COUNT, 6))
        self.tracked = self.pose.copy()
        self.ref_vel = np.zeros((BONE_COUNT, 6))
        self.sim = self.pose.copy()
        self.sim_active = False
        self.sim_gain = 1.0            # [0, 1] scale of the feedback stiffnesses (contact gating)
        self.last_energy = 0.0

    def set_inertia(self, inertia: BoneInertia) -> None:
        """The bones' masses, centres of mass and inertias (e.g. a fitted hand's, hand_measures auto);
        the poses stay, the next step uses them."""
        if inertia.mass.shape != (BONE_COUNT,) or np.any(~np.isfinite(inertia.mass)) or np.any(inertia.mass <= 0):
            raise ValueError(f"bone masses must be 16 finite values > 0 kg, got {inertia.mass}")
        self.inertia = inertia
        self.mass = np.ascontiguousarray(inertia.mass, dtype=np.float64)
        self.com_local = np.ascontiguousarray(inertia.com_local, dtype=np.float64)
        self.inertia_local = np.ascontiguousarray(inertia.inertia_local, dtype=np.float64)
        self.inertia_sqrt_local = np.ascontiguousarray(np.stack([_sqrt_spd(i) for i in self.inertia_local]))

    def set_coupling(self, **values):
        """Change Eq. 14 stiffnesses or the damping ratio while running (tracked_kx, tracked_ktheta,
        sim_kx, sim_ktheta [N/m, N m/rad], damping_ratio [-]); the next step uses them."""
        for name, value in values.items():
            if name not in ("tracked_kx", "tracked_ktheta", "sim_kx", "sim_ktheta", "damping_ratio"):
                raise ValueError(f"not a coupling parameter of the loop: {name}")
            value = float(value)
            if not np.isfinite(value) or value < 0 or (name == "tracked_ktheta" and value == 0):
                raise ValueError(f"loop parameter {name} must be finite and {'> 0' if name == 'tracked_ktheta' else '>= 0'}, got {value!r}")
            setattr(self.config, name, value)
        c = self.config
        self.tracked_kx[:] = c.tracked_kx
        self.tracked_ktheta[:] = c.tracked_ktheta
        self.sim_kx[0] = c.sim_kx                      # palm only (Sect. 3.6)
        self.sim_ktheta[:] = c.sim_ktheta

    def reset(self, poses):
        self.pose[:] = poses
        self.tracked[:] = poses
        self.vel[:] = 0.0
        self.ref_vel[:] = 0.0

    def set_tracked(self, poses, ref_vel=None):
        self.tracked[:] = poses
        self.ref_vel[:] = 0.0 if ref_vel is None else ref_vel

    def set_sim(self, poses):
        if poses is None:
            self.sim_active = False
        else:
            self.sim[:] = poses
            self.sim_active = True

    def step(self):
        c = self.config
        self.last_energy = step_bodies(self.pose, self.vel, self.mass, self.com_local, self.inertia_local,
                                       self.inertia_sqrt_local, self.tracked, self.ref_vel, self.tracked_kx,
                                       self.tracked_ktheta, self.sim, self.sim_gain * self.sim_kx,
                                       self.sim_gain * self.sim_ktheta, self.sim_active and self.sim_gain > 0.0,
                                       c.damping_ratio, c.dt)
        return self.pose


class TrackingLoop:
    """The intermediate-bone loop with its inputs: tracker frames, sim copies, dropouts.

    * `on_tracker(joints, t, capture_t=None)`: a tracker frame (26 joints) received at t [s]; the
      adapter validates and converts it (rejected frames are counted, never used). The tracked
      bones' velocity (damping reference) is the filtered finite difference of consecutive
      accepted frames at their capture times. A frame whose capture time (header stamp; 0 =
      unstamped, the receive time is used) is not after the last accepted one's is rejected as
      "stamp_order" while tracking; during a hold any stamp is taken (a restarted tracker resyncs).
    * `on_sim_bones(poses, t)`: the latest full-simulation skeleton (16, 7), held constant until
      the next one; dropped after `sim_timeout` [s] without an update (a stopped sim must not
      hold the hand).
    * `step(t)`: one period; returns the intermediate bones (16, 7), or None before the first
      valid frame (nothing is published before there is a hand). The bodies start at rest on the
      first tracked frame.
    * `on_contacts(count, t)`: the number of active contacts of this simulated hand (its points of
      /hand/contacts); with feedback "contact" the feedback acts while there are any (module docstring).
    * Dropout: REF_STALE after the last valid frame the damping reference drops to zero (the held
      target no longer moves); `tracker_timeout` [s] after it the loop holds the last target
      and `holding` is True; the next valid frame resumes tracking, the
      springs pulling the bones to it as to any target (no jump).
    """

    def __init__(self, loop_config: LoopConfig | None = None, adapter=None, tracker_timeout: float = 0.1,
                 sim_timeout: float = 0.5, inertia: BoneInertia | None = None):
        from softhand_tracking.adapter import TrackerAdapter
        for name, value in (("tracker_timeout", tracker_timeout), ("sim_timeout", sim_timeout)):
            if not np.isfinite(value) or value <= 0:
                raise ValueError(f"{name} must be > 0 s, got {value!r}")
        self.bones = IntermediateBones(loop_config, inertia)
        self.adapter = adapter if adapter is not None else TrackerAdapter()
        self.tracker_timeout = float(tracker_timeout)
        self.sim_timeout = float(sim_timeout)
        self.initialized = False
        self.holding = False
        self.holds = 0                 # dropouts entered
        self.last_frame_t = -np.inf    # receive time of the last valid frame [s]
        self._prev_capture = None
        self._prev_tracked = None
        self._ref = np.zeros((BONE_COUNT, 6))
        self._frame_age0 = 0.0         # [s] age of the last frame when it was received
        self.sim_t = -np.inf
        self.last_contact_t = -np.inf  # [s] last time the simulated hand touched something
        self._last_step_t = None
        self.sim_drops = 0             # sim copies dropped after sim_timeout without /hand/{hand}/bones

    @property
    def tracked(self) -> np.ndarray:
        return self.bones.tracked

    def on_tracker(self, joints, t: float, capture_t: float | None = None) -> bool:
        from softhand_tracking.adapter import RejectedFrame
        capture_t = t if capture_t is None or capture_t == 0.0 else capture_t  # stamp 0: unstamped
        # A frame captured no later than the last accepted one (duplicate, reordered) would move the
        # target back in time. After a dropout (holding) any stamp is taken: a restarted tracker
        # whose clock went back resynchronises instead of being refused forever.
        if self._prev_capture is not None and not self.holding and capture_t <= self._prev_capture:
            self.adapter.reject(RejectedFrame("stamp_order", f"capture time {capture_t:.6f} s not after "
                                              f"the last accepted frame's {self._prev_capture:.6f} s"))
            return False
        if self.holding and self.adapter.joint_filter is not None:
            self.adapter.joint_filter.reset()  # after a dropout: no blend with the hand before it
        poses = self.adapter.convert(joints, capture_t)
        if poses is None:
            return False
        if not self.initialized:
            self.bones.reset(poses)
            self.initialized = True
            self._ref[:] = 0.0
        elif self._prev_capture is not None and 0.0 < capture_t - self._prev_capture <= self.tracker_timeout \
                and not self.holding:
            raw = pose_velocity(self._prev_tracked, poses, self.bones.com_local, capture_t - self._prev_capture)
            lin = np.linalg.norm(raw[:, :3], axis=1, keepdims=True)
            ang = np.linalg.norm(raw[:, 3:], axis=1, keepdims=True)
            raw[:, :3] *= np.minimum(1.0, MAX_REF_SPEED / np.maximum(lin, 1e-12))
            raw[:, 3:] *= np.minimum(1.0, MAX_REF_RATE / np.maximum(ang, 1e-12))
            smoothing = self.bones.config.ref_smoothing
            alpha = 1.0 - np.exp(-(capture_t - self._prev_capture) / smoothing) if smoothing > 0 else 1.0
            self._ref += alpha * (raw - self._ref)
        else:
            self._ref[:] = 0.0         # first frame after a gap: no velocity across it
        self._prev_capture, self._prev_tracked = capture_t, poses
        self.bones.set_tracked(poses, self._ref)
        # the frame's age at receipt, when its stamp is on this clock (one timeline); else 0 (the
        # receive time stands in for the capture)
        age = t - capture_t
        self._frame_age0 = age if 0.0 <= age <= MAX_EXTRAPOLATION else 0.0
        self.last_frame_t = t
        self.holding = False
        return True

    def on_sim_bones(self, poses, t: float) -> None:
        p = np.asarray(poses, dtype=np.float64)
        if p.shape != (BONE_COUNT, 7) or not np.all(np.isfinite(p)):
            raise ValueError(f"sim bones must be 16 finite poses (16, 7), got shape {p.shape}")
        self.bones.set_sim(p)
        self.sim_t = t

    def on_contacts(self, count: int, t: float) -> None:
        if count > 0:
            self.last_contact_t = t

    def time_since_tracker(self, t: float) -> float:
        return t - self.last_frame_t

    def step(self, t: float):
        if not self.initialized:
            return None
        if self.time_since_tracker(t) > REF_STALE:
            # The held target no longer moves: damping toward its old velocity would carry the
            # bones past it (a late or lost frame), so damp toward rest from here on.
            self.bones.ref_vel[:] = 0.0
        if not self.holding and self.time_since_tracker(t) > self.tracker_timeout:
            self.holding = True
            self.holds += 1
            self.bones.ref_vel[:] = 0.0
            self._ref[:] = 0.0
        if self.bones.sim_active and t - self.sim_t > self.sim_timeout:
            self.bones.set_sim(None)
            self.sim_drops += 1
        self._update_feedback_gain(t)
        cfg = self.bones.config
        since = self.time_since_tracker(t)
        if cfg.extrapolate and not self.holding and self._prev_tracked is not None and since <= REF_STALE:
            # in contact (gain 1) the paper's loop: the targets are not moved into what stops the hand
            tau = (1.0 - self.bones.sim_gain) * min(self._frame_age0 + max(since, 0.0), MAX_EXTRAPOLATION)
            self.bones.tracked[:] = extrapolate_poses(self._prev_tracked, self.bones.ref_vel,
                                                      self.bones.com_local, tau)
        elif cfg.extrapolate and self._prev_tracked is not None:
            self.bones.tracked[:] = self._prev_tracked  # stale: the last frame as it was
        return self.bones.step()

    def _update_feedback_gain(self, t: float) -> None:
        """Gain of the feedback: 1 with feedback "always"; with "contact" 1 while the hand touched
        something within FEEDBACK_HOLD, else 0, reached by a ramp over FEEDBACK_RAMP."""
        if self.bones.config.feedback == "always":
            self.bones.sim_gain = 1.0
            return
        want = 1.0 if t - self.last_contact_t <= FEEDBACK_HOLD else 0.0
        dt = self.bones.config.dt if self._last_step_t is None else max(t - self._last_step_t, 0.0)
        self._last_step_t = t
        g = self.bones.sim_gain
        step = dt / FEEDBACK_RAMP
        self.bones.sim_gain = min(want, g + step) if want > g else max(want, g - step)


def warm_up(loop_config: LoopConfig | None = None, adapter_config=None) -> None:
    """Compile (or load from numba's cache) every kernel a tracking node calls, now: the bones'
    step, velocities and extrapolation, the adapter's bone frames (both sides), and a throwaway
    TrackingLoop of the node's configuration driven through tracked frames, sim bones and
    contacts (the feedback path). Anything left to the first call compiles mid-run: on a fresh
    checkout the first contact of the first demo held the hand for over 0.1 s and kicked the ball
    out of the grasp."""
    from softhand_sim.handmodel.kinematics import forward_kinematics
    from softhand_tracking.adapter import AdapterConfig, TrackerAdapter, bone_frames
    from softhand_sim.physics.rotations import quat_to_matrix

    bones = IntermediateBones(LoopConfig())
    poses = np.zeros((BONE_COUNT, 7))
    poses[:, 6] = 1.0
    bones.reset(poses)
    bones.set_sim(poses)
    bones.step()
    pose_velocity(poses, poses, bones.com_local, 0.01)
    extrapolate_poses(poses, bones.vel, bones.com_local, 0.01)

    adapter_config = adapter_config if adapter_config is not None else AdapterConfig()
    joints, sim_bones = forward_kinematics(np.array([0.0, 0.0, 0.15, 0.0, 0.0, 0.0, 1.0]), np.full((5, 4), 0.2))
    for hand in ("right", "left"):
        bone_frames(joints[:, :3], hand)
    # the frame in the tracker's coordinates, so that the adapter maps it back onto the hand above
    w = np.asarray(adapter_config.world_from_tracker, dtype=np.float64)
    r = quat_to_matrix(w[3:].copy())
    tracked = joints.copy()
    tracked[:, :3] = (joints[:, :3] - w[:3]) @ r
    loop = TrackingLoop(loop_config, TrackerAdapter(adapter_config))
    for k in range(4):
        t = 0.01 * k
        loop.on_tracker(tracked, t, t)
        loop.on_sim_bones(sim_bones, t)
        loop.on_contacts(3 if k > 1 else 0, t)
        loop.step(t + 0.004)
