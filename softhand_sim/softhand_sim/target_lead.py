"""Bone targets moved to the end of the step they are used in (feed-forward), out of contact.

The intermediate bones arrive stamped with the time they describe (tracking_node steps at 250 Hz);
sim_node uses the latest one for a step from t to t + dt and stamps its state t + dt. Held as they
are, the targets are t + dt - stamp old when the state is compared with them: 17-21 ms at 60 Hz,
most of the simulated hand's lag behind the tracked one (the springs of Eq. 14 add the rest). So
each hand's targets are moved forward to t + dt with their own velocity, at most MAX_LEAD. The
velocity is the difference over the last VELOCITY_WINDOW of targets, low-pass filtered: between two
messages 4 ms apart the noise of a tracker (~1 mm and ~1 deg: fast_dropout's, the noisy sample bag)
made up to 30 rad/s of a fingertip's angular velocity, and a 20 ms lead doubled the free-air error.
What noise is left in the filtered velocity is estimated on line (the mean square of each new
difference against the filtered velocity, over NOISE_TIME), and each bone's linear and angular lead
is scaled by v^2 / (v^2 + NOISE_GAIN noise^2): a hand moving well above its tracker's noise gets the
whole lead, a still or noisy one little. Offline, the fitted hands of the synthetic bags when they
carried 1.5 mm of noise per joint had their fingertip error's median rise from 4.73 / 4.85 mm
without the lead to 5.83 / 5.71 mm with it unscaled, and 4.88 / 4.95 mm scaled; on the Leap
recordings the scaling costs ~1 ms of the phalanxes' lag and lowers their error. No target is moved
further than MAX_SHIFT or turned further than MAX_TURN: after a jump of the tracked hand the
intermediate bones race to it at metres per second, and led they would overshoot by centimetres (the
caps never bind on the Leap recordings: their lag and error are the same with and without them).

In contact the paper's behaviour is kept: the springs pull toward the targets as they came, not
toward where the hand would be if nothing stopped it (a moved target would press harder into
what the hand holds). The lead drops to zero at once (faded over a ramp, a hand coming down on
the table with a 20 ms lead pressed its skin 6.8 mm into it; the press test allows 5 mm) the step
after the hand's skin comes within NEAR_GATE of an object, so that the step that makes the first
contact is not led either (gated on contact alone, that step pressed the table ~5 N harder),
stays off for CONTACT_HOLD after the hand was last that near and comes back over RAMP. It comes
back only while targets come: targets older than MAX_GAP (the tracking stopped, a link went down)
are held with the gain they had, not led anew by their last velocity.

The lead puts each target where the tracked bone is at the end of the step, but the palm's spring
only follows it by stretching: the whole hand (bones and tissue, 0.37 kg) hangs on the palm's
500 N/m (Eq. 14), 6 Hz, so a palm target that speeds up or turns back is trailed by what the spring
must stretch to carry that mass. `acceleration` gives the palm target's acceleration, which the
runtime applies to every mass of the hand as a dead load m a (an accelerating frame's inertial
load, Control.node_force / body_force): the second difference of the palm's centre-of-mass targets
of this step and the last two, the discrete acceleration with which implicit Euler follows them
exactly (m (x+ - 2x + x-) / h^2 = k (r+ - x+) + m (r+ - 2r + r-) / h^2 leaves the error homogeneous).
It is scaled by the lead's contact gate (in contact the paper's springs act alone), capped at
MAX_ACCEL, and nil across a gap. Offline on leap_grab (a real recording) the simulated palm's lag
fell from 27.5 to 18.6 ms, its position error p95 from 10.8 to 6.5 mm; turning the whole hand with
the target's angular acceleration as well changed neither the phalanxes' lag nor the palm's (14.6,
19.6 ms), so only the linear part is applied. The cap was 100 m/s^2 (10 g) until the answer to a
tracker's jump was measured: leap_grab's palm comes back 24.6 mm from where it was after a 26 ms
dropout, and the hand followed that at the cap. Offline with the node set's transport delays,
averaged over six phases of the frames: 100 -> 300 m/s^2 took leap_grab's palm error p95 over the
run from 8.5 to 6.0 mm (lag 16.2 -> 15.9 ms), fast_dropout's (a 309 ms gap) from 26.8 to 21.9 mm,
leap_roll_pitch's 6.1 -> 5.9 mm; 1000 m/s^2 gave leap_grab the same as 300.

The palm's linear lead uses its own velocity: the least-squares slope of the palm's positions over
the velocity window, unfiltered. The filtered difference (the other bones' velocity) trails a palm
that speeds up or turns back by about the filter's time constant, and the palm carries the hand.
It is scaled by the same noise gain as the filtered velocity would be (the filtered speed against
the noise of the raw difference): scaled by the slope's own speed, a still palm's noise passed
through (a still hand with 1 mm of noise: the led targets' error 14-18 % over the noise, against
the 10 % test_target_lead allows). Offline, as above: leap_grab's palm lag over the run 15.9 ->
14.2 ms (13.5-15.1 over the phases; off the dropouts 4.3 -> 3.3 ms), its palm error p95 6.0 ->
6.1 mm; fast_dropout 3.8 -> 3.3 ms, 21.9 -> 19.8 mm; leap_roll_pitch 0.8 -> 0.0 ms, 5.9 -> 5.8 mm.
"""
from __future__ import annotations

from collections import deque

import numpy as np
from numba import njit

from softhand_sim.physics.rotations import integrate_rotation, quat_conj, quat_log, quat_mul

MAX_LEAD = 0.04        # [s] targets are never moved further than this past their stamp
MAX_SHIFT = 0.02       # [m] no target is moved further than this (1 m/s for 20 ms) ...
MAX_TURN = 0.6         # [rad] ... nor turned further (30 rad/s for 20 ms)
MAX_REACH = np.array([MAX_SHIFT, MAX_TURN])
MAX_GAP = 0.05         # [s] two targets further apart give no velocity (a gap, a restart)
VELOCITY_WINDOW = 0.02  # [s] the velocity is the change over (at least) this long
SMOOTHING = 0.02       # [s] time constant of the low-pass filter on the targets' velocity
CONTACT_HOLD = 0.2     # [s] no lead this long after the hand last touched something
RAMP = 0.05            # [s] the lead's gain goes 0 <-> 1 over this time
NOISE_TIME = 0.3       # [s] time constant of the velocity noise estimate
NOISE_GAIN = 1.0       # each bone's lead scaled by v^2 / (v^2 + NOISE_GAIN noise^2), linear and angular
STILL2 = np.array([1e-8, 1e-6])  # [(m/s)^2, (rad/s)^2] below 0.1 mm/s, 1 mrad/s a bone leads no more
MAX_ACCEL = 300.0      # [m/s^2] the feed-forward acceleration's cap (a jump of the tracked hand
                       # races the intermediate bones at hundreds of m/s^2; module docstring)
NEAR_GATE = 0.02       # [m] no lead while the skin is nearer than this to an object (a 40 ms lead
                       # moves a target 2 cm at 0.5 m/s)


def pose_velocity(prev, cur, dt):
    """(n, 6) velocity of the bone-frame origins [m/s] and world angular velocity [rad/s] taking
    poses prev -> cur (n, 7) over dt [s]."""
    out = np.empty((len(cur), 6))
    _pose_velocity(np.ascontiguousarray(prev, dtype=np.float64), np.ascontiguousarray(cur, dtype=np.float64),
                   float(dt), out)
    return out


@njit(cache=True)
def _pose_velocity(prev, cur, dt, out):
    """pose_velocity compiled: it runs on every target message (250 Hz per hand in sim_node), where
    a Python loop of per-bone kernel calls took ~3 % of the node's samples."""
    for b in range(cur.shape[0]):
        w = quat_log(quat_mul(cur[b, 3:].copy(), quat_conj(prev[b, 3:].copy())))
        for i in range(3):
            out[b, i] = (cur[b, i] - prev[b, i]) / dt
            out[b, 3 + i] = w[i] / dt


def _squared_norms(vel):
    """(n, 2) squared norms of the linear and the angular part of each row of vel (n, 6)."""
    return np.sum(vel.reshape(-1, 2, 3) ** 2, axis=2)


def extrapolate(poses, vel, tau):
    """Poses (n, 7) moved forward by tau [s] with vel (n, 6) (origins straight, orientations by
    the world angular velocity)."""
    out = np.empty((len(poses), 7))
    _extrapolate(np.ascontiguousarray(poses, dtype=np.float64), np.ascontiguousarray(vel, dtype=np.float64),
                 float(tau), out)
    return out


@njit(cache=True)
def _extrapolate(poses, vel, tau, out):
    """extrapolate compiled: it runs every step for every bone (a Python loop of per-bone kernel
    calls took ~0.2 ms of the node's tick)."""
    for b in range(poses.shape[0]):
        for i in range(3):
            out[b, i] = poses[b, i] + tau * vel[b, i]
        q = integrate_rotation(poses[b, 3:].copy(), vel[b, 3:].copy(), tau)
        for i in range(4):
            out[b, 3 + i] = q[i]


def _palm_slope(history, stamp, poses):
    """(3,) least-squares slope [m/s] of the palm origin (bone 0) over the history's targets and
    the new ones (poses at stamp). Plain numpy: ~11 us a message over the window's ~6 targets,
    0.3 % of a core at 250 Hz (pose_velocity is compiled because it loops over every bone)."""
    t = np.array([h[0] for h in history] + [stamp]) - stamp
    x = np.array([h[1][0, :3] for h in history] + [poses[0, :3]])
    tc = t - t.mean()
    return tc @ (x - x.mean(axis=0)) / (tc @ tc)


def warm_up():
    """Compile (or load from numba's cache) the rotation kernels of the lead now: called by the
    runtime's warm-up step, which leads nothing (its targets have no velocity yet). Left to the
    first lead, their compile stalled sim_node's loop for seconds in the middle of a run on a
    fresh checkout."""
    poses = np.tile([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], (2, 1))
    extrapolate(poses, pose_velocity(poses, poses, 0.01), 0.01)


class TargetLead:
    """One hand's targets, their velocity and the contact gate (module docstring)."""

    def __init__(self, enabled: bool = True, accelerate: bool = True):
        self.enabled = bool(enabled)
        self.accelerate = bool(accelerate)  # acceleration() gives the palm target's acceleration (else nil)
        self.poses = None
        self.stamp = None
        self.vel = None
        self.palm_vel = None  # (3,) [m/s] the palm origin's least-squares velocity over the history
        self.noise2 = None  # (n, 2) the velocity's noise power per bone: linear, angular
        self._history = deque()  # (stamp, poses) of the last VELOCITY_WINDOW
        self.gain = 1.0
        self.last_contact_t = -np.inf
        self._last_t = None
        self.lead = 0.0  # [s] the lead of the last targets_at (for diagnostics)
        self._palm = deque(maxlen=3)  # (t_end, palm centre-of-mass target) of the last steps

    def on_target(self, poses, stamp) -> None:
        """New targets (n, 7) stamped `stamp` [s] (None: unstamped, never moved)."""
        poses = np.asarray(poses, dtype=np.float64).copy()
        if stamp is None or self.stamp is None or not 0.0 < stamp - self.stamp <= MAX_GAP \
                or self.poses.shape != poses.shape:
            self.vel = None  # first targets, unstamped, reordered or after a gap: no velocity across it
            self.palm_vel = None
            self._history.clear()
        elif self._history:
            while len(self._history) > 1 and stamp - self._history[1][0] >= VELOCITY_WINDOW:
                self._history.popleft()
            t0, p0 = self._history[0]
            if stamp - t0 >= VELOCITY_WINDOW:
                raw = pose_velocity(p0, poses, stamp - t0)
                alpha = 1.0 - np.exp(-(stamp - self.stamp) / SMOOTHING)
                if self.vel is not None:
                    dev2 = _squared_norms(raw - self.vel)
                    beta = 1.0 - np.exp(-(stamp - self.stamp) / NOISE_TIME)
                    self.noise2 = dev2 if self.noise2 is None else self.noise2 + beta * (dev2 - self.noise2)
                self.vel = raw if self.vel is None else self.vel + alpha * (raw - self.vel)
                self.palm_vel = _palm_slope(self._history, stamp, poses)
        if stamp is not None:
            self._history.append((stamp, poses))
        self.poses, self.stamp = poses, stamp

    def on_contacts(self, count: int, t: float, near: float = np.inf) -> None:
        """The hand's active contacts after the step that ended at t [s], and its skin's
        distance to the objects [m] (ContactSystem.near; inf: farther than it measures)."""
        if count > 0 or near < NEAR_GATE:
            self.last_contact_t = t

    def targets_at(self, t_end: float):
        """The targets to use for a step ending at t_end [s]: moved forward to it (at most
        MAX_LEAD past their stamp), scaled by the contact gate; None before the first targets."""
        if self.poses is None:
            return None
        stale = self.stamp is not None and t_end - self.stamp > MAX_GAP
        if t_end - self.last_contact_t <= CONTACT_HOLD:
            self.gain = 0.0
        elif self._last_t is not None and not stale:
            self.gain = min(1.0, self.gain + max(t_end - self._last_t, 0.0) / RAMP)
        # stale targets (none for MAX_GAP: the tracking stopped, a link went down) keep the gain
        # they had: held, not led anew. A hand lifting the ball when its link went down let go of
        # the ball's copy when that went stale, and the lead coming back then moved its held
        # target 11 mm up (by the last velocity, 40 ms) halfway through the outage
        self._last_t = t_end
        if not self.enabled or self.vel is None or self.stamp is None:
            self.lead = 0.0
            return self.poses
        self.lead = self.gain * min(max(t_end - self.stamp, 0.0), MAX_LEAD)
        if self.lead <= 0.0:
            return self.poses
        vel = self.vel.copy()
        if self.palm_vel is not None:
            vel[0, :3] = self.palm_vel
        if self.noise2 is not None and NOISE_GAIN > 0.0:
            speed2 = _squared_norms(self.vel)
            # the floor keeps a still bone's ratio of two round-off-sized numbers out (its lead is nil)
            vel = vel * np.repeat(speed2 / (speed2 + NOISE_GAIN * self.noise2 + STILL2), 3, axis=1)
        # a jump of the tracked hand (a tracker re-acquiring it, a replay restarting) is followed
        # by the intermediate bones at metres per second: led, it would overshoot by centimetres
        reach = self.lead * np.sqrt(_squared_norms(vel))  # (n, 2): shift [m], turn [rad]
        if np.any(reach > MAX_REACH):
            vel = vel * np.repeat(np.minimum(1.0, MAX_REACH / np.maximum(reach, 1e-300)), 3, axis=1)
        return extrapolate(self.poses, vel, self.lead)

    def acceleration(self, t_end: float, palm_com) -> np.ndarray:
        """The palm target's acceleration [m/s^2] (3,) for the step ending at t_end [s] whose palm
        centre-of-mass target is palm_com (3,) [m] (module docstring): the second difference of
        this step's target and the last two, times the contact gate of the last targets_at, at
        most MAX_ACCEL; nil before three steps, after a gap of the targets and with the lead off."""
        palm = self._palm
        if self.vel is None or (palm and t_end <= palm[-1][0]):
            palm.clear()  # no velocity across a gap; time went back: a warm-up step, a restarted replay
        palm.append((float(t_end), np.array(palm_com, dtype=np.float64)))
        if not (self.enabled and self.accelerate) or len(palm) < 3 or self.gain <= 0.0:
            return np.zeros(3)
        (t0, x0), (t1, x1), (t2, x2) = palm
        a = ((x2 - x1) / (t2 - t1) - (x1 - x0) / (t1 - t0)) / (0.5 * (t2 - t0)) * self.gain
        norm = float(np.linalg.norm(a))
        return a * (MAX_ACCEL / norm) if norm > MAX_ACCEL else a
