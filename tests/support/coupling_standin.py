"""Test helpers for the two-simulation coupling tests (test_coupling_*.py, test_world_*.py).

`HandSideObject` is a STAND-IN for the hand solver's instance of one object: a single rigid body
stepped with the same scheme as the solver (backward Euler, one Newton iteration), coupled by
Eq. 14 to the extrapolated engine copy (energies/rigid_coupling through softhand_sim.physics.coupling:
the solver's gradient and Hessian) and,
optionally, gripped by a spring toward a kinematic pose (standing in for the hand's contacts and
the paper's elastic tracking coupling). `Channel` delivers copies with a fixed latency, as the
ROS topics between the nodes would. `run_pair` steps the stand-in and a World at their own rates.
"""
from __future__ import annotations

import numpy as np

from softhand_sim.physics.coupling import ObjectCopy, coupling_wrench
from softhand_sim.physics.energies import rigid_coupling
from softhand_sim.physics.rotations import integrate_rotation, quat_to_matrix, relative_rotvec


class HandSideObject:
    """One rigid body, backward Euler with one Newton step (as the hand solver), Eq. 14 to a copy.

    U = Eq.14(a, copy) + 1/2 kg |x - xg|^2 + 1/2 kgt |dtheta(q, qg)|^2 - m g.x
    (M + dt^2 H) v1 = M v0 - dt dU/dq,   x1 = x0 + dt v1,   q1 = exp(dt w1) q0.
    Gyroscopic terms are neglected (as in a one-Newton-step solver at these spin rates).
    """

    def __init__(self, mass, inertia_local, pose, kx, ktheta, gravity=-9.81, extrapolate=True,
                 copy_timeout=0.25):
        self.mass = float(mass)
        self.inertia_local = np.asarray(inertia_local, dtype=np.float64)
        self.pose = np.asarray(pose, dtype=np.float64).copy()
        self.twist = np.zeros(6)
        self.accel = np.zeros(6)
        self.kx, self.ktheta = kx, ktheta
        self.gravity = np.array([0.0, 0.0, gravity])
        self.copy = ObjectCopy("object", extrapolate=extrapolate, timeout=copy_timeout)
        self.grip_pose = None
        self.grip_kx = 0.0
        self.grip_ktheta = 0.0
        self.grip_damping = 0.0  # [N s/m] on the velocity relative to the grip (hand tissue damping)
        self.grip_twist = np.zeros(6)

    def inertia_world(self):
        r = quat_to_matrix(self.pose[3:])
        return r @ self.inertia_local @ r.T

    def step(self, t, dt):
        """Advance from t to t + dt; the engine copy is the target at t + dt (backward Euler)."""
        force = self.mass * self.gravity
        torque = np.zeros(3)
        hess = np.zeros((6, 6))
        coupled = not self.copy.is_stale(t)
        if coupled:
            target, _ = self.copy.target(t + dt)
            f, tq = coupling_wrench(self.pose, target, self.kx, self.ktheta)
            force, torque = force + f, torque + tq
            hess += rigid_coupling.hessian(self.kx, self.ktheta)
        damp = np.zeros(6)
        if self.grip_pose is not None:
            f, tq = coupling_wrench(self.pose, self.grip_pose, self.grip_kx, self.grip_ktheta)
            force, torque = force + f, torque + tq
            hess += rigid_coupling.hessian(self.grip_kx, self.grip_ktheta)
            damp[:3] = self.grip_damping
            force = force + self.grip_damping * self.grip_twist[:3]
        inertia = self.inertia_world()
        lhs = np.zeros((6, 6))
        lhs[:3, :3] = self.mass * np.eye(3)
        lhs[3:, 3:] = inertia
        lhs += dt * dt * hess + dt * np.diag(damp)
        rhs = np.concatenate([self.mass * self.twist[:3] + dt * force, inertia @ self.twist[3:] + dt * torque])
        new_twist = np.linalg.solve(lhs, rhs)
        self.accel = (new_twist - self.twist) / dt
        self.twist = new_twist
        self.pose[:3] += dt * new_twist[:3]
        self.pose[3:] = integrate_rotation(self.pose[3:], new_twist[3:], dt)
        return coupled

    def kinetic_energy(self):
        w = self.twist[3:]
        return 0.5 * self.mass * self.twist[:3] @ self.twist[:3] + 0.5 * w @ self.inertia_world() @ w


class Channel:
    """Messages delivered `latency` [s] after their stamp; `latest(t)` is what a reader sees at t."""

    def __init__(self, latency):
        self.latency = latency
        self._queue = []
        self._latest = None

    def send(self, stamp, payload):
        self._queue.append((stamp + self.latency, stamp, payload))

    def latest(self, t):
        while self._queue and self._queue[0][0] <= t + 1e-12:
            _, stamp, payload = self._queue.pop(0)
            self._latest = (stamp, payload)
        return self._latest


def run_pair(world, hand, name, duration, hand_dt=0.01, latency=0.004, before_hand_step=None,
             record=None, hand_publishes=lambda t: True):
    """Step `hand` (HandSideObject) at hand_dt and `world` at its rate, exchanging copies.

    Each side, before its step, takes the newest delivered copy of the other; after its step it
    sends its state stamped with its new time, delivered `latency` later. `before_hand_step(t)`
    moves the grip; `hand_publishes(t)` False stops the hand reporting the object (a release).
    `record(t_hand, hand, world)` is called after each hand step.
    """
    to_world, to_hand = Channel(latency), Channel(latency)
    idx = world.object_index(name)
    t_hand = world.time
    t_end = world.time + duration
    while t_hand < t_end - 1e-9:
        # run the engine up to the hand's current time, then the hand one step
        while world.time + world.dt <= t_hand + hand_dt + 1e-12 and world.time < t_end - 1e-9:
            msg = to_world.latest(world.time)
            if msg is not None:
                stamp, (pose, twist, accel) = msg
                world.set_copy(name, pose, twist, accel, stamp)
            world.step()
            s = world.states()
            to_hand.send(s.stamp, (s.pose[idx].copy(), s.twist[idx].copy(), s.accel[idx].copy()))
        msg = to_hand.latest(t_hand)
        if msg is not None:
            stamp, (pose, twist, accel) = msg
            hand.copy.update(pose, twist, accel, stamp)
        if before_hand_step is not None:
            before_hand_step(t_hand)
        hand.step(t_hand, hand_dt)
        t_hand += hand_dt
        if hand_publishes(t_hand):
            to_world.send(t_hand, (hand.pose.copy(), hand.twist.copy(), hand.accel.copy()))
        if record is not None:
            record(t_hand, hand, world)


def pair_energy(hand, world, name, kx, ktheta, gravity=0.0):
    """Kinetic energy of both instances + Eq. 14 spring between them (+ gravity potential) [J]."""
    s = world.states()
    i = world.object_index(name)
    obj = world.scene.object(name)
    r = quat_to_matrix(s.pose[i, 3:])
    w = s.twist[i, 3:]
    ke_world = 0.5 * obj.mass * s.twist[i, :3] @ s.twist[i, :3] + 0.5 * w @ (r @ obj.inertia_local @ r.T) @ w
    spring = rigid_coupling.pose_energy(hand.pose, s.pose[i], kx, ktheta)
    pe = -gravity * obj.mass * (hand.pose[2] + s.pose[i, 2])
    return hand.kinetic_energy() + ke_world + spring + pe


def angle_between(qa, qb):
    return float(np.linalg.norm(relative_rotvec(np.asarray(qa, float), np.asarray(qb, float))))
