"""Coupling two instances of one rigid object across simulations (paper Sect. 3.7, Eq. 14).

Both the hand solver and the pybullet world simulate their own instance `a` of a grasped object
and keep a *copy* `b` of the other side's instance: its pose, twist and acceleration at the stamp
of the other side's state. This module is the one shared implementation of

* the copy extrapolation of Sect. 3.7: before a step, the copy is moved from its stamp to the
  current time assuming constant linear and angular acceleration (`extrapolate_pose`);
* the wrench that the Eq. 14 coupling U = 1/2 kx |xa - xb|^2 + 1/2 ktheta |dtheta|^2 puts on `a`
  (`coupling_wrench`), and its backward-Euler form for an explicit engine
  (`implicit_coupling_wrench`); both from energies/rigid_coupling.py, the one Eq. 14 of the hand
  solver (gradient, and Hessian diag(kx I, ktheta I));
* `ObjectCopy`, the latest copy of one object with its stamp, staleness check and extrapolation.

Conventions: pose (7,) = [px py pz qx qy qz qw] [m, unit quaternion x y z w]; twist (6,) =
[vx vy vz wx wy wz] [m/s, rad/s]; accel (6,) = [ax ay az alphax alphay alphaz] [m/s^2, rad/s^2];
everything in world coordinates. Positions are those of the centre of mass (the scene's object
frames are at their COM). dtheta is the rotation vector of qa * qb^-1 (rotations.relative_rotvec),
the rotation that takes b onto a.

Gravity: the paper gives both instances the same mass. Gravity then acts on both instances too,
so that a copy moving freely (falling, sliding) has exactly the motion of the original and the
spring stays relaxed; the coupling transmits only what the other world adds (contacts with the
hand, collisions in the engine). The price, inherent in the two-instance scheme, is that while the
hand holds an object it carries the weight of both instances (2 m g) and the engine instance hangs
m g / kx below the hand instance (5.8 mm for 0.1 kg at 170 N/m); with gravity on one side only,
a freely moving coupled pair would fall with g / 2 instead. tests/world/test_world.py measures both.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from softhand_sim.physics.energies import rigid_coupling
from softhand_sim.physics.rotations import quat_exp, quat_mul, quat_normalize

# Paper Sect. 5.1: hand <-> engine object coupling stiffness.
PAPER_KX = 170.0       # [N/m]
PAPER_KTHETA = 70.0    # [N m/rad]


@njit(cache=True)
def extrapolate_pose(pose, twist, accel, stamp, t):
    """Copy of a body moved from `stamp` to time `t` [s] with constant acceleration (Sect. 3.7).

    x(t) = x + v dt + 1/2 a dt^2;  v(t) = v + a dt;  w(t) = w + alpha dt;
    q(t) = exp(w dt + 1/2 alpha dt^2) * q  (world-frame rotation vector integrated over dt; exact
    when w and alpha are parallel, second order otherwise).
    Returns (pose (7,), twist (6,)) at t. dt may be negative (a copy newer than t).
    """
    dt = t - stamp
    out_pose = np.empty(7)
    out_twist = np.empty(6)
    for i in range(3):
        out_pose[i] = pose[i] + twist[i] * dt + 0.5 * accel[i] * dt * dt
        out_twist[i] = twist[i] + accel[i] * dt
        out_twist[3 + i] = twist[3 + i] + accel[3 + i] * dt
    rotvec = np.empty(3)
    for i in range(3):
        rotvec[i] = twist[3 + i] * dt + 0.5 * accel[3 + i] * dt * dt
    q = quat_normalize(quat_mul(quat_exp(rotvec), pose[3:7].copy()))
    out_pose[3:7] = q
    return out_pose, out_twist


@njit(cache=True)
def coupling_wrench(pose_a, pose_b, kx, ktheta):
    """Force [N] and torque [N m] of Eq. 14 on body a, pulling it toward b (world frame, about a's COM).

    The negated gradient of energies/rigid_coupling (the one Eq. 14, as the hand solver uses it):
    force = -kx (xa - xb); torque = -ktheta dtheta, the exact negative gradient for a world-frame
    rotation of a (qa <- exp(delta) qa). The reaction on b is the opposite wrench.
    """
    g = rigid_coupling.pose_gradient(pose_a, pose_b, kx, ktheta)
    return -g[0:3], -g[3:6]


def _finite(name, arr, shape):
    arr = np.asarray(arr, dtype=np.float64)
    if arr.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} has non-finite values: {arr}")
    return arr


class ObjectCopy:
    """The latest copy of the other simulation's instance of one object (Sect. 3.7).

    `update` stores pose (7,), twist (6,), accel (6,) stamped at `stamp` [s]; `target(t)` returns
    the pose and twist at time t: extrapolated with constant acceleration, or the plain copy when
    `extrapolate` is False (the explicit copy the paper warns about, kept for comparison).
    `is_stale(t)` is True when no copy arrived or the newest is older than `timeout` [s]: a stale
    copy must not be coupled to (the object is left to its own simulation). `gaps` counts the
    decouplings that ended (a lost link, a stopped peer): a copy that arrives fresh (as of the last
    time `is_stale` was asked) after the step had seen the copy stale. A reliable stream that
    resends what a dead link held back delivers every stamp, late: the lapse shows only against
    the step's time. Without a step time (no `is_stale` call yet) a copy stamped more than
    `timeout` after the one before counts.

    Both simulations advance positions with the END-of-step velocity (backward Euler on the hand
    side, symplectic Euler in pybullet), so under constant acceleration a their sampled positions
    lie on x_n + (v_n + a h / 2) tau + a tau^2 / 2, h being the source's step, not on the Taylor
    curve through v_n: extrapolating with v_n alone lags by a h tau / 2 (~1 mm for g, h = 10 ms,
    tau = 20 ms) and the two instances drag each other. `source_dt` h [s] is given, or, when
    None, taken from the spacing of the last two stamps (one copy per source step).
    """

    def __init__(self, name, extrapolate=True, timeout=0.25, source_dt=None):
        if timeout <= 0:
            raise ValueError(f"copy timeout must be > 0 s, got {timeout!r}")
        self.name = name
        self.extrapolate = bool(extrapolate)
        self.timeout = float(timeout)
        self.pose = None
        self.twist = np.zeros(6)
        self.accel = np.zeros(6)
        self.stamp = -np.inf
        self.source_dt = source_dt
        self._stamp_step = 0.0  # spacing of the last two stamps [s]
        self.gaps = 0  # decouplings that ended (see the class's doc)
        self._seen_t = None  # the latest time is_stale was asked at (the step's time)
        self._lapsed = False  # the step saw this copy stale since the last fresh one

    def update(self, pose, twist, accel, stamp):
        """Store a copy; raises ValueError naming the object on bad shapes or non-finite values."""
        pose = _finite(f"{self.name}: pose", pose, (7,))
        twist = _finite(f"{self.name}: twist", twist, (6,))
        accel = _finite(f"{self.name}: accel", accel, (6,))
        if not math.isfinite(stamp):
            raise ValueError(f"{self.name}: stamp must be finite, got {stamp!r}")
        qn = np.linalg.norm(pose[3:7])
        if qn < 1e-6:
            raise ValueError(f"{self.name}: quaternion has zero norm: {pose[3:7]}")
        pose = pose.copy()
        pose[3:7] /= qn
        gap = float(stamp) - self.stamp
        if self.pose is not None:
            if self._seen_t is None:
                self.gaps += gap > self.timeout
            elif (self._lapsed or gap > self.timeout) and self._seen_t - float(stamp) <= self.timeout:
                self.gaps += 1  # this copy ends the lapse (older resent ones do not)
                self._lapsed = False
        self._stamp_step = gap if 0.0 < gap <= self.timeout else 0.0
        self.pose, self.twist, self.accel, self.stamp = pose, twist.copy(), accel.copy(), float(stamp)

    def is_stale(self, t):
        stale = self.pose is None or (t - self.stamp) > self.timeout
        self._seen_t = t
        self._lapsed |= stale and self.pose is not None
        return stale

    def age(self, t):
        return t - self.stamp

    def target(self, t):
        """(pose (7,), twist (6,)) of the copy at time t [s]."""
        if self.pose is None:
            raise RuntimeError(f"{self.name}: no copy received yet")
        if not self.extrapolate:
            return self.pose.copy(), self.twist.copy()
        h = self._stamp_step if self.source_dt is None else self.source_dt
        pose, twist = extrapolate_pose(self.pose, self.twist + 0.5 * h * self.accel, self.accel,
                                       self.stamp, float(t))
        return pose, twist - 0.5 * h * self.accel


class AccelerationEstimator:
    """Accelerations by backward finite differences of velocities, for engines that give none.

    `update(twist (n,6), t)` returns accel (n,6) [m/s^2, rad/s^2]; zero on the first call.
    """

    def __init__(self, count):
        self._prev = np.zeros((count, 6))
        self._prev_t = None

    def update(self, twist, t):
        twist = np.asarray(twist, dtype=np.float64)
        if self._prev_t is None or t <= self._prev_t:
            accel = np.zeros_like(twist)
        else:
            accel = (twist - self._prev) / (t - self._prev_t)
        self._prev = twist.copy()
        self._prev_t = t
        return accel


@njit(cache=True)
def implicit_coupling_wrench(pose_a, twist_a, free_accel_a, pose_b_end, twist_b_end, mass, inertia_world,
                             kx, ktheta, damping_tau, dt):
    """Eq. 14 wrench on a for an explicit engine, made linearly implicit (backward Euler).

    An engine that integrates v1 = v0 + dt (g + F / m), x1 = x0 + dt v1 with a constant applied F
    is unstable for a stiff spring once omega dt > 2 (e.g. 70 N m/rad on a 4 cm, 0.1 kg ball at
    120 Hz: omega dt ~ 8.7). Applying instead the F that makes the step backward Euler for the
    coupling, i.e. F = -k (x1 - xb_end) - c (v1 - vb_end) evaluated at the END of the step,
        (m + dt^2 k + dt c) v1 = m v0 + dt m g - dt k (x0 - xb_end) + dt c vb_end,
        F = m (v1 - v0) / dt - m g,
    gives the engine side the same implicit treatment as the hand side. pose_b_end, twist_b_end:
    the copy at the end of the step t + dt (extrapolated, Sect. 3.7). free_accel_a (6,): what the
    engine adds by itself (gravity) [m/s^2, rad/s^2], so the spring does not fight it.
    c = k * damping_tau [s] (optional, 0 = the paper's undamped spring). The angular part is the same
    with the inertia tensor (3,3, world axes) [kg m^2] and dtheta(q0, qb_end) + dt w1.
    Returns (force (3,) [N], torque (3,) [N m]) on a; twists are [v, w] (6,).
    """
    grad = rigid_coupling.pose_gradient(pose_a, pose_b_end, kx, ktheta)  # [kx (xa - xb), ktheta dtheta]
    hess = rigid_coupling.hessian(kx, ktheta)                               # diag(kx I, ktheta I)
    force = np.empty(3)
    cx = kx * damping_tau
    for i in range(3):
        denom = mass + dt * dt * hess[i, i] + dt * cx
        v1 = (mass * twist_a[i] + dt * mass * free_accel_a[i] - dt * grad[i]
              + dt * cx * twist_b_end[i]) / denom
        force[i] = mass * (v1 - twist_a[i]) / dt - mass * free_accel_a[i]
    ct = ktheta * damping_tau
    lhs = inertia_world + dt * dt * hess[3:6, 3:6] + dt * ct * np.eye(3)
    rhs = (inertia_world @ (twist_a[3:6] + dt * free_accel_a[3:6]) - dt * grad[3:6]
           + dt * ct * twist_b_end[3:6])
    w1 = np.linalg.solve(lhs, rhs)
    torque = inertia_world @ (w1 - twist_a[3:6]) / dt - inertia_world @ free_accel_a[3:6]
    return force, torque


@njit(cache=True)
def explicit_coupling_wrench(pose_a, twist_a, pose_b, twist_b, kx, ktheta, damping_tau):
    """Eq. 14 wrench on a plus optional damping c = k * damping_tau [s] on the relative twist.

    The plain spring force of the paper; stable on an explicit engine only while omega dt < 2.
    """
    force, torque = coupling_wrench(pose_a, pose_b, kx, ktheta)
    force -= kx * damping_tau * (twist_a[0:3] - twist_b[0:3])
    torque -= ktheta * damping_tau * (twist_a[3:6] - twist_b[3:6])
    return force, torque


# Highest coupling frequency sqrt(k / m) (and sqrt(ktheta / I_min)) that the copy exchange can
# carry: measured on the stand-in pair (hand 100 Hz, engine 120 Hz, 4 ms latency), the coupled
# pair keeps its energy up to ~60 rad/s and diverges at ~77 rad/s with extrapolation. The paper's
# kx = 170 N/m on 0.1 kg is 41 rad/s; its ktheta = 70 N m/rad on the scene's 4-5 cm objects
# (I ~ 5e-5 kg m^2) would be ~1200 rad/s. (70 reads as kg cm^2/s^2 in Unreal's centimetre units,
# i.e. 0.007 N m/rad, which gives ~12 rad/s: a plausible reading that this limit agrees with.)
DEFAULT_MAX_OMEGA = 45.0  # [rad/s]


def warm_up():
    """Compile (or load from numba's cache) every coupling kernel now: called at node start so the
    first copy of a grasped object does not stall a real-time loop for seconds on a fresh checkout."""
    pose = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
    twist = np.zeros(6)
    extrapolate_pose(pose, twist, twist, 0.0, 0.01)
    coupling_wrench(pose, pose, 1.0, 1.0)
    implicit_coupling_wrench(pose, twist, np.zeros(6), pose, twist, 1.0, np.eye(3), 1.0, 1.0, 0.0, 0.01)
    explicit_coupling_wrench(pose, twist, pose, twist, 1.0, 1.0, 0.0)


def limit_coupling_stiffness(kx, ktheta, mass, inertia_local, max_omega=DEFAULT_MAX_OMEGA):
    """(kx, ktheta) of one object capped so that neither coupling oscillates above max_omega.

    kx <= mass * max_omega^2; ktheta <= I_min * max_omega^2 with I_min the smallest principal
    moment of inertia_local (3,3) [kg m^2]. max_omega <= 0 disables the cap. Both sides of the
    coupling must use the same capped values so that the pair's Eq. 14 energy is one energy.
    """
    if max_omega is None or max_omega <= 0:
        return float(kx), float(ktheta)
    i_min = float(np.linalg.eigvalsh(np.asarray(inertia_local, dtype=np.float64)).min())
    w2 = float(max_omega) ** 2
    return min(float(kx), float(mass) * w2), min(float(ktheta), i_min * w2)
