"""softhand_sim.physics.coupling: the Eq. 14 wrench (energies/rigid_coupling, the solver's Eq. 14) against
finite differences, its backward-Euler form, Sect. 3.7 extrapolation and copies."""
import numpy as np
import pytest

from softhand_sim.physics.coupling import (ObjectCopy, coupling_wrench, explicit_coupling_wrench, extrapolate_pose,
                                           implicit_coupling_wrench, limit_coupling_stiffness)
from softhand_sim.physics.energies.rigid_coupling import pose_energy
from softhand_sim.physics.rotations import quat_exp, quat_mul, quat_to_matrix

RNG = np.random.default_rng(7)


def random_pose(scale=0.2, angle=1.0):
    axis = RNG.normal(size=3)
    q = quat_exp(axis / np.linalg.norm(axis) * RNG.uniform(0.1, angle))
    return np.concatenate([RNG.normal(size=3) * scale, q])


def perturb(pose, delta):
    """Translate by delta[:3], rotate in world axes by exp(delta[3:])."""
    out = pose.copy()
    out[:3] += delta[:3]
    out[3:] = quat_mul(quat_exp(delta[3:]), pose[3:])
    return out


@pytest.mark.parametrize("trial", range(5))
def test_wrench_is_negative_gradient_of_eq14(trial):
    """Force and torque on a equal minus the central-difference gradient of Eq. 14 (world-frame rotation)."""
    a, b = random_pose(), random_pose()
    kx, kt = 170.0, 70.0
    force, torque = coupling_wrench(a, b, kx, kt)
    wrench = np.concatenate([force, torque])
    assert np.linalg.norm(wrench) > 1.0
    h = 1e-6
    grad = np.zeros(6)
    for k in range(6):
        d = np.zeros(6)
        d[k] = h
        grad[k] = (pose_energy(perturb(a, d), b, kx, kt) - pose_energy(perturb(a, -d), b, kx, kt)) / (2 * h)
    np.testing.assert_allclose(wrench, -grad, rtol=1e-6, atol=1e-6)


def test_extrapolation_exact_for_constant_acceleration():
    """A copy with constant linear acceleration and parallel angular velocity/acceleration lands on the analytic state."""
    pose = random_pose()
    axis = np.array([0.3, -0.2, 0.9]) / np.linalg.norm([0.3, -0.2, 0.9])
    twist = np.concatenate([[0.5, -0.1, 0.2], 2.0 * axis])
    accel = np.concatenate([[0.0, 0.0, -9.81], -1.5 * axis])
    dt = 0.037
    out_pose, out_twist = extrapolate_pose(pose, twist, accel, 10.0, 10.0 + dt)
    expect_x = pose[:3] + twist[:3] * dt + 0.5 * accel[:3] * dt * dt
    angle = 2.0 * dt - 0.5 * 1.5 * dt * dt
    expect_q = quat_mul(quat_exp(axis * angle), pose[3:])
    np.testing.assert_allclose(out_pose[:3], expect_x, atol=1e-14)
    np.testing.assert_allclose(out_pose[3:], expect_q, atol=1e-12)
    np.testing.assert_allclose(out_twist, twist + accel * dt, atol=1e-14)


def test_implicit_wrench_is_backward_euler_of_the_spring():
    """With the implicit wrench and gravity, the engine's symplectic step satisfies the backward-Euler
    equations of the spring at the step's end, linearised with the solver's Eq. 14 Hessian diag(kx, kt)."""
    m, kx, kt, dt = 0.1, 170.0, 70.0, 1 / 120
    inertia = np.diag([4e-5, 5e-5, 6e-5])
    a, b_end = random_pose(0.05, 0.3), random_pose(0.05, 0.3)
    ta, tb = RNG.normal(size=6), RNG.normal(size=6)
    g = np.array([0.0, 0.0, -9.81, 0.0, 0.0, 0.0])
    tau = 0.01
    force, torque = implicit_coupling_wrench(a, ta, g, b_end, tb, m, inertia, kx, kt, tau, dt)
    v1 = ta[:3] + dt * (g[:3] + force / m)   # what the engine integrates
    x1 = a[:3] + dt * v1
    np.testing.assert_allclose(force, -kx * (x1 - b_end[:3]) - kx * tau * (v1 - tb[:3]), atol=1e-10)
    w1 = ta[3:] + dt * np.linalg.solve(inertia, torque)
    _, t0 = coupling_wrench(a, b_end, kt, kt)  # -kt dtheta(q0, qb_end)
    np.testing.assert_allclose(torque, t0 - kt * dt * w1 - kt * tau * (w1 - tb[3:]), atol=1e-9)
    f2, t2 = explicit_coupling_wrench(a, ta, b_end, tb, kx, kt, 0.0)
    np.testing.assert_allclose(np.concatenate([f2, t2]), np.concatenate(coupling_wrench(a, b_end, kx, kt)))


def test_object_copy_staleness_and_plain_mode():
    """A copy is stale before any update and after the timeout; plain mode returns the copy unmoved."""
    copy = ObjectCopy("ball", extrapolate=True, timeout=0.1)
    assert copy.is_stale(0.0)
    pose = np.array([0, 0, 1.0, 0, 0, 0, 1.0])
    copy.update(pose, [1.0, 0, 0, 0, 0, 0], np.zeros(6), 5.0)
    assert not copy.is_stale(5.05) and copy.is_stale(5.11)
    np.testing.assert_allclose(copy.target(5.05)[0][:3], [0.05, 0, 1.0])
    copy.extrapolate = False
    np.testing.assert_allclose(copy.target(5.05)[0], pose)


def test_object_copy_counts_gaps():
    """A copy stamped more than `timeout` after the one before counts one gap (a decoupling that
    ended); the first copy and copies on time count none."""
    copy = ObjectCopy("ball", timeout=0.1)
    pose = [0, 0, 1.0, 0, 0, 0, 1.0]
    for stamp in (1.0, 1.05, 1.1, 1.3, 1.35, 2.0):
        copy.update(pose, np.zeros(6), np.zeros(6), stamp)
    assert copy.gaps == 2


def test_object_copy_counts_a_link_outage_once_when_the_stream_resends_it():
    """A step every 10 ms, a copy every 10 ms; the link is down from t = 1.0 to 2.0 s and the
    reliable stream then delivers the copies it held back, every stamp, in a burst: the step saw
    the copy stale (decoupled) and the outage counts one gap, though no two stamps are more than
    `timeout` apart. The burst's older copies, stale as they come, do not count again."""
    copy = ObjectCopy("ball", timeout=0.25)
    pose = [0, 0, 1.0, 0, 0, 0, 1.0]
    stamps = np.round(np.arange(0.0, 3.0, 0.01), 6)
    held = []
    stale_steps = 0
    for t in stamps:
        if 1.0 <= t < 2.0:
            held.append(t)  # sent while the link is down: resent when it is back
        else:
            for s in held + [t]:
                copy.update(pose, np.zeros(6), np.zeros(6), s)
            held = []
        stale_steps += copy.is_stale(t + 0.005)  # the step between two copies
    assert stale_steps > 50  # decoupled for most of the outage
    assert copy.gaps == 1


@pytest.mark.parametrize("bad", [
    dict(pose=[0, 0, np.nan, 0, 0, 0, 1]), dict(twist=[0, 0, 0, np.inf, 0, 0]), dict(pose=[0, 0, 0, 0, 0, 0, 0]),
    dict(accel=[0, 0, 0]), dict(stamp=float("nan"))])
def test_object_copy_rejects_bad_values(bad):
    """Non-finite values, zero quaternions and wrong shapes raise ValueError naming the object."""
    args = dict(pose=[0, 0, 0, 0, 0, 0, 1], twist=np.zeros(6), accel=np.zeros(6), stamp=0.0)
    args.update(bad)
    copy = ObjectCopy("mug")
    with pytest.raises(ValueError, match="mug"):
        copy.update(**args)
    assert copy.pose is None


def test_stiffness_cap():
    """The cap limits sqrt(k/m) and sqrt(ktheta/I_min) to max_omega and leaves softer springs alone."""
    inertia = np.diag([6.4e-5, 6.4e-5, 6.4e-5])
    kx, kt = limit_coupling_stiffness(170.0, 70.0, 0.1, inertia, 45.0)
    assert kx == 170.0
    assert kt == pytest.approx(6.4e-5 * 45.0 ** 2)
    assert limit_coupling_stiffness(170.0, 70.0, 0.1, inertia, 0.0) == (170.0, 70.0)
    r = quat_to_matrix(quat_exp(np.array([0.3, 0.4, 0.1])))
    _, kt_rot = limit_coupling_stiffness(170.0, 70.0, 0.1, r @ np.diag([1e-4, 2e-4, 3e-4]) @ r.T, 10.0)
    assert kt_rot == pytest.approx(1e-2)
