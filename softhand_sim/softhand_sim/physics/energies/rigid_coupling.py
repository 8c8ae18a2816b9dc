"""Rigid-body coupling energy, Eq. 14 of the paper (Sect. 3.6 elastic tracking, Sect. 3.7 engine copies).

    U = 1/2 kx ||x - x_t||^2 + 1/2 k_theta ||dtheta||^2,   dtheta = log(q q_t^-1)  (world frame)

between a simulated body (x, q) and a target (x_t, q_t) that is fixed during the step: the
intermediate bone (Sect. 3.6) or the extrapolated copy of the other simulation's instance of an
object (Sect. 3.7). kx [N/m], k_theta [N m/rad]; x [m] are centres of mass, q unit quaternions
[x, y, z, w]. This module is the one implementation of Eq. 14: the hand solver sums it over its
bodies (`add_all`), the pybullet world applies it to its instances through physics/coupling.py
(`pose_gradient`, `HESSIAN` form), the tracking loop calls `target_energy_gradient`.

Generalized coordinates of the body, 6 entries: (x, theta), rotations perturbed on the left in
world coordinates, q <- exp(delta) q (the solver's world-frame angular velocity and
`rotations.integrate_rotation`).

Gradient (exact): d dtheta / d delta = J_l^-1(dtheta) and J_l^-T(phi) phi = phi, so
    dU/dx = kx (x - x_t),   dU/dtheta = k_theta dtheta.
Hessian (Gauss-Newton choice, stated): diag(kx I, k_theta I), independent of the poses. The exact
derivative of the gradient is k_theta J_l^-1(dtheta) in the rotation block, not symmetric; its
symmetric part has eigenvalues 1 along dtheta and (t/2)cot(t/2) = 1 - t^2/12 + ... across it
(t = ||dtheta||), so k_theta I is exact to O(t^2) and never softer than the true stiffness.
Symmetric positive definite keeps CG and the one-Newton-step integration well posed.
"""
import numpy as np
from numba import njit

from softhand_sim.physics.rotations import relative_rotvec


@njit(cache=True)
def target_energy_gradient(x, q, x_target, q_target, kx, ktheta, grad6):
    """The local stencil of Eq. 14: energy [J] of one body (x (3,) [m], q (4,)) and its target;
    ADDS the (6,) gradient w.r.t. (x, theta) [N, N m] into grad6. The Hessian is
    diag(kx I, k_theta I) (module docstring)."""
    dth = relative_rotvec(q, q_target)
    e = 0.0
    for i in range(3):
        d = x[i] - x_target[i]
        e += 0.5 * kx * d * d + 0.5 * ktheta * dth[i] * dth[i]
        grad6[i] += kx * d
        grad6[3 + i] += ktheta * dth[i]
    return e


@njit(cache=True)
def pose_energy(pose, pose_target, kx, ktheta):
    """Eq. 14 [J] between a body at COM pose (7,) [px py pz qx qy qz qw] and a target pose (7,)."""
    g = np.zeros(6)
    return target_energy_gradient(pose[0:3], pose[3:7].copy(), pose_target[0:3],
                                  pose_target[3:7].copy(), kx, ktheta, g)


@njit(cache=True)
def pose_gradient(pose, pose_target, kx, ktheta):
    """Eq. 14 gradient (6,) [N, N m] w.r.t. (x, theta) of the body at COM pose (7,): the negated
    wrench that pulls the body toward the target."""
    g = np.zeros(6)
    target_energy_gradient(pose[0:3], pose[3:7].copy(), pose_target[0:3], pose_target[3:7].copy(),
                           kx, ktheta, g)
    return g


@njit(cache=True)
def hessian(kx, ktheta):
    """Eq. 14 Hessian (6, 6) w.r.t. (x, theta): diag(kx I, k_theta I) (module docstring)."""
    h = np.zeros((6, 6))
    for i in range(3):
        h[i, i] = kx
        h[3 + i, 3 + i] = ktheta
    return h


@njit(cache=True)
def value(body_x, body_q, target_x, target_q, kx, ktheta):
    """Sum of Eq. 14 over bodies coupled to fixed targets [J]. body_x (B,3) [m], body_q (B,4),
    target_x/target_q alike, kx/ktheta (B,) per body."""
    g = np.zeros(6)
    e = 0.0
    for b in range(body_x.shape[0]):
        e += target_energy_gradient(body_x[b], body_q[b], target_x[b], target_q[b], kx[b], ktheta[b], g)
    return e


@njit(cache=True)
def add_gradient(body_x, body_q, target_x, target_q, kx, ktheta, body_dof0, grad):
    """Adds the Eq. 14 gradient of every body into grad at body_dof0 + 6 b + (0..5); returns [J]."""
    tmp = np.zeros(6)
    e = 0.0
    for b in range(body_x.shape[0]):
        tmp[:] = 0.0
        e += target_energy_gradient(body_x[b], body_q[b], target_x[b], target_q[b], kx[b], ktheta[b], tmp)
        o = body_dof0 + 6 * b
        for i in range(6):
            grad[o + i] += tmp[i]
    return e


@njit(cache=True)
def add_hessian(kx, ktheta, body_slots, values):
    """Adds diag(kx I, k_theta I) per body into the CSR values; body_slots (B,6,6) = value index
    of each body's diagonal block (model.body_slots)."""
    for b in range(kx.shape[0]):
        for i in range(3):
            values[body_slots[b, i, i]] += kx[b]
            values[body_slots[b, 3 + i, 3 + i]] += ktheta[b]


@njit(cache=True)
def add_all(body_x, body_q, target_x, target_q, kx, ktheta, body_dof0, grad, body_slots, values):
    """Eq. 14 of every body: adds gradient and Hessian (as add_gradient, add_hessian); returns [J]."""
    e = add_gradient(body_x, body_q, target_x, target_q, kx, ktheta, body_dof0, grad)
    add_hessian(kx, ktheta, body_slots, values)
    return e
