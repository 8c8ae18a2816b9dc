"""The pybullet world: the rest of the scene, coupled two-way to the hand through copies (Sect. 3.7).

`World` owns one pybullet client in DIRECT mode stepped at a fixed `engine_rate` [Hz]. It holds the
ground plane, the static objects (fixed) and the dynamic objects of a `softhand_sim.scene.Scene`,
with the scene's masses, inertias and friction. For every dynamic object the hand side reports,
it keeps an `ObjectCopy` (the hand instance's pose, twist and acceleration at its stamp) and, before
each engine step, applies to the engine instance the Eq. 14 wrench toward the copy extrapolated to
the current engine time (`softhand_sim.physics.coupling`). Copies older than `copy_timeout` are stale: the
object is decoupled and left to pybullet alone.

The engine time starts at `start_time` and advances by exactly 1 / engine_rate per step; states
read after a step are stamped with the new engine time. pybullet gives velocities but no
accelerations, so accelerations are backward finite differences of the velocities over one step.

Gravity acts on the engine instances (and, with the same mass, on the hand instances as well):
see softhand_sim.physics.coupling's module docstring for why, and for what it costs while holding.
No ROS here: world_node.py is the thin node around this class.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import pybullet
from pybullet_utils.bullet_client import BulletClient

from softhand_sim.physics.coupling import (DEFAULT_MAX_OMEGA, PAPER_KTHETA, PAPER_KX, AccelerationEstimator,
                                   ObjectCopy, explicit_coupling_wrench, implicit_coupling_wrench,
                                   warm_up as coupling_warm_up,
                                   limit_coupling_stiffness)
from softhand_sim.physics.rotations import quat_to_matrix

log = logging.getLogger(__name__)

ENGINE_RATE_RANGE = (60.0, 120.0)  # [Hz] the paper's engine rates (Sect. 5.1)
COUPLING_MODES = ("implicit", "explicit")


@dataclass
class WorldConfig:
    """Parameters of the world (the world_node parameters of the same names). The defaults here are
    the paper's scheme; world_node's (config/softhand.yaml) depart where measured: no copy
    extrapolation, a critically damped spring (coupling_damping 1), copy_timeout 0.5 s."""

    engine_rate: float = 120.0          # [Hz], 60..120
    coupling_kx: float = PAPER_KX       # [N/m] Eq. 14 linear stiffness
    coupling_ktheta: float = PAPER_KTHETA  # [N m/rad] Eq. 14 angular stiffness
    copy_timeout: float = 0.25          # [s] a hand copy older than this decouples its object
    extrapolate: bool = True            # constant-acceleration extrapolation of copies (Sect. 3.7)
    coupling_mode: str = "implicit"     # "implicit" (backward-Euler wrench) or "explicit" (plain)
    coupling_damping: float = 0.0       # [-] damping ratio zeta of the engine-side spring (0: paper; world_node: 1)
    coupling_max_omega: float = DEFAULT_MAX_OMEGA  # [rad/s] cap on sqrt(k/m), sqrt(ktheta/I); 0: off
    gravity: float = 9.81               # [m/s^2] magnitude, along -z
    solver_iterations: int = 50         # pybullet constraint solver iterations per step

    def validate(self):
        lo, hi = ENGINE_RATE_RANGE
        if not lo <= self.engine_rate <= hi:
            raise ValueError(f"engine_rate must be in [{lo}, {hi}] Hz, got {self.engine_rate!r}")
        for key in ("coupling_kx", "coupling_ktheta", "coupling_damping", "coupling_max_omega"):
            value = getattr(self, key)
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"{key} must be finite and >= 0, got {value!r}")
        if not np.isfinite(self.copy_timeout) or self.copy_timeout <= 0:
            raise ValueError(f"copy_timeout must be > 0 s, got {self.copy_timeout!r}")
        if self.coupling_mode not in COUPLING_MODES:
            raise ValueError(f"coupling_mode must be one of {COUPLING_MODES}, got {self.coupling_mode!r}")
        if not np.isfinite(self.gravity):
            raise ValueError(f"gravity must be finite, got {self.gravity!r}")
        if self.extrapolate and self.coupling_damping > 0:
            # measured on the stand-in pair (tests/world/test_world.py): damping toward an
            # extrapolated copy's twist pumps energy into a released pair (0.02 J -> 1100 J)
            raise ValueError(f"extrapolate=True needs coupling_damping=0 (got {self.coupling_damping!r}): "
                             "the damped spring on extrapolated copies is unstable")
        return self


@dataclass
class ObjectStates:
    """Engine-side states of the dynamic objects at `stamp` [s] (engine time)."""

    names: tuple
    pose: np.ndarray    # (n, 7) [m, quaternion x y z w], COM frame
    twist: np.ndarray   # (n, 6) [m/s, rad/s] world frame
    accel: np.ndarray   # (n, 6) [m/s^2, rad/s^2] world frame (finite differences)
    stamp: float


def _collision_shape(client, obj, static):
    """pybullet collision shape of a scene object (see softhand_sim.scene for the dims)."""
    d = obj.dims
    if obj.shape == "sphere":
        return client.createCollisionShape(pybullet.GEOM_SPHERE, radius=d["radius"])
    if obj.shape == "box":
        return client.createCollisionShape(pybullet.GEOM_BOX, halfExtents=[0.5 * s for s in d["size"]])
    if obj.shape == "cylinder":
        return client.createCollisionShape(pybullet.GEOM_CYLINDER, radius=d["radius"], height=d["length"])
    if obj.shape == "capsule":
        return client.createCollisionShape(pybullet.GEOM_CAPSULE, radius=d["radius"], height=d["length"])
    if obj.shape == "mesh":
        flags = pybullet.GEOM_FORCE_CONCAVE_TRIMESH if static else 0
        return client.createCollisionShape(pybullet.GEOM_MESH, fileName=str(d["file"]),
                                           meshScale=[d.get("scale", 1.0)] * 3, flags=flags)
    raise ValueError(f"object {obj.name!r}: unsupported shape {obj.shape!r}")


class World:
    """pybullet world of one scene with Eq. 14 coupling of its dynamic objects to hand copies."""

    def __init__(self, scene, config: WorldConfig | None = None, start_time=0.0):
        self.config = (config or WorldConfig()).validate()
        self.scene = scene
        self.dt = 1.0 / self.config.engine_rate
        self._start_time = float(start_time)
        self._step_count = 0
        self._client = BulletClient(connection_mode=pybullet.DIRECT)
        c = self._client
        c.setTimeStep(self.dt)
        c.setGravity(0.0, 0.0, -self.config.gravity)
        c.setPhysicsEngineParameter(numSolverIterations=int(self.config.solver_iterations))
        plane = c.createCollisionShape(pybullet.GEOM_PLANE)
        self._ground = c.createMultiBody(0.0, plane, -1, [0.0, 0.0, scene.ground_height])
        c.changeDynamics(self._ground, -1, lateralFriction=scene.ground_friction)
        self.body_ids = {}
        for obj in scene.objects:
            self.body_ids[obj.name] = self._add_object(obj)
        dyn = scene.dynamic_objects
        self.names = tuple(o.name for o in dyn)
        self._index = {n: i for i, n in enumerate(self.names)}
        self._mass = np.array([o.mass for o in dyn])
        self._inertia_local = np.array([np.diag(np.diag(o.inertia_local)) for o in dyn]).reshape(-1, 3, 3)
        # per-object Eq. 14 stiffness after the frequency cap (the hand side must use the same)
        self.stiffness = np.array([limit_coupling_stiffness(self.config.coupling_kx, self.config.coupling_ktheta,
                                                            o.mass, o.inertia_local, self.config.coupling_max_omega)
                                   for o in dyn]).reshape(-1, 2)
        for o, (kx, kt) in zip(dyn, self.stiffness):
            if kt < self.config.coupling_ktheta or kx < self.config.coupling_kx:
                log.info("object %r: coupling capped at kx %.4g N/m, ktheta %.4g N m/rad (max_omega %.0f rad/s)",
                         o.name, kx, kt, self.config.coupling_max_omega)
        self.copies = [ObjectCopy(n, self.config.extrapolate, self.config.copy_timeout) for n in self.names]
        self._accel = AccelerationEstimator(len(self.names))
        self._pose = np.zeros((len(self.names), 7))
        self._twist = np.zeros((len(self.names), 6))
        self._read_states()
        self._acc = self._accel.update(self._twist, self.time)
        self._free_accel = np.array([0.0, 0.0, -self.config.gravity, 0.0, 0.0, 0.0])
        coupling_warm_up()  # compile the coupling kernels now, not at the first grasp
        # damping ratio zeta -> c = k tau with tau = 2 zeta / omega, omega = sqrt(kx / m) per object
        self._damping_tau = 2.0 * self.config.coupling_damping / np.sqrt(
            np.maximum(self.stiffness[:, 0], 1e-12) / np.maximum(self._mass, 1e-12)) if len(dyn) else np.zeros(0)
        self.last_wrench = np.zeros((len(self.names), 6))  # applied coupling [N, N m], for tests/diag

    # ----------------------------------------------------------------------------- construction
    def _add_object(self, obj):
        c = self._client
        shape = _collision_shape(c, obj, obj.static)
        mass = 0.0 if obj.static else obj.mass
        body = c.createMultiBody(mass, shape, -1, list(obj.pose[:3]), list(obj.pose[3:]))
        c.changeDynamics(body, -1, lateralFriction=obj.friction, restitution=0.0)
        if not obj.static:
            inertia = np.asarray(obj.inertia_local)
            off = inertia - np.diag(np.diag(inertia))
            if np.abs(off).max() > 1e-6 * np.abs(inertia).max():
                # the object frame is not the principal frame (a mesh): pybullet takes a diagonal
                log.warning("object %r: inertia not diagonal in its frame; using the diagonal only", obj.name)
            # no artificial damping or sleeping: the coupling needs every force to act every step
            c.changeDynamics(body, -1, localInertiaDiagonal=list(np.diag(inertia)), linearDamping=0.0,
                             angularDamping=0.0, activationState=pybullet.ACTIVATION_STATE_DISABLE_SLEEPING)
        return body

    def close(self):
        if self._client is not None:
            self._client.disconnect()
            self._client = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # ----------------------------------------------------------------------------- time and copies
    @property
    def time(self):
        """Engine time [s] of the current state."""
        return self._start_time + self._step_count * self.dt

    def set_time(self, t):
        """Re-base the engine clock so the current state is at time t [s] (node start, /clock jumps)."""
        self._start_time = float(t) - self._step_count * self.dt
        self._accel._prev_t = self.time

    def set_copy(self, name, pose, twist, accel, stamp):
        """Store the hand instance of `name` at `stamp` [s]; KeyError/ValueError on bad input."""
        i = self._index.get(name)
        if i is None:
            raise KeyError(f"unknown dynamic object {name!r} (known: {list(self.names)})")
        self.copies[i].update(pose, twist, accel, stamp)

    def copy_status(self):
        """{name: 'free' (no copy yet) | 'coupled' | 'stale'} at the current engine time."""
        t = self.time
        out = {}
        for copy in self.copies:
            if copy.pose is None:
                out[copy.name] = "free"
            else:
                out[copy.name] = "stale" if copy.is_stale(t) else "coupled"
        return out

    # ----------------------------------------------------------------------------- stepping
    def _apply_coupling(self):
        cfg = self.config
        t = self.time
        c = self._client
        self.last_wrench[:] = 0.0
        for i, copy in enumerate(self.copies):
            if copy.is_stale(t):
                continue
            kx, ktheta = self.stiffness[i]
            if cfg.coupling_mode == "implicit":
                # backward Euler: the spring is evaluated at the end of the step, t + dt
                target_pose, target_twist = copy.target(t + self.dt)
                rot = quat_to_matrix(self._pose[i, 3:])
                inertia_world = rot @ self._inertia_local[i] @ rot.T
                force, torque = implicit_coupling_wrench(
                    self._pose[i], self._twist[i], self._free_accel, target_pose, target_twist,
                    self._mass[i], inertia_world, kx, ktheta, self._damping_tau[i], self.dt)
            else:
                # the paper's plain spring force at the current engine time
                target_pose, target_twist = copy.target(t)
                force, torque = explicit_coupling_wrench(
                    self._pose[i], self._twist[i], target_pose, target_twist, kx, ktheta,
                    self._damping_tau[i])
            body = self.body_ids[self.names[i]]
            c.applyExternalForce(body, -1, force.tolist(), self._pose[i, :3].tolist(), pybullet.WORLD_FRAME)
            c.applyExternalTorque(body, -1, torque.tolist(), pybullet.WORLD_FRAME)
            self.last_wrench[i, :3] = force
            self.last_wrench[i, 3:] = torque

    def _read_states(self):
        c = self._client
        for i, name in enumerate(self.names):
            body = self.body_ids[name]
            pos, orn = c.getBasePositionAndOrientation(body)
            lin, ang = c.getBaseVelocity(body)
            self._pose[i, :3] = pos
            self._pose[i, 3:] = orn
            self._twist[i, :3] = lin
            self._twist[i, 3:] = ang

    def step(self):
        """One engine step: couple to the copies at the current time, step pybullet, read states."""
        self._apply_coupling()
        self._client.stepSimulation()
        self._step_count += 1
        self._read_states()
        self._acc = self._accel.update(self._twist, self.time)

    def states(self) -> ObjectStates:
        return ObjectStates(self.names, self._pose.copy(), self._twist.copy(), self._acc.copy(), self.time)

    # ----------------------------------------------------------------------------- direct access
    def reset_object(self, name, pose, twist=None):
        """Place a dynamic or static object (tests, resets); twist (6,) for dynamic ones."""
        body = self.body_ids[name]
        self._client.resetBasePositionAndOrientation(body, list(pose[:3]), list(pose[3:]))
        if twist is not None:
            self._client.resetBaseVelocity(body, list(twist[:3]), list(twist[3:]))
        self._read_states()

    def object_index(self, name):
        return self._index[name]
