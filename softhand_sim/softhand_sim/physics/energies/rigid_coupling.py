"""Rigid-body coupling energy, Eq. 14 of the paper (Sect. 3.6 elastic tracking, Sect. 3.7 engine copies).

    U = 1/2 kx ||x_a - x_b||^2 + 1/2 k_theta ||dtheta||^2,   dtheta = log(q_a q_b^-1)  (world frame)

kx [N/m], k_theta [N m/rad]; x [m] are the coupled points (the solver couples centres of mass),
q are unit quaternions [x, y, z, w].

Generalized coordinates of one pair, in this order: (x_a, theta_a, x_b, theta_b), 12 entries.
Rotations are perturbed on the left in world coordinates, q <- exp(delta) q, matching the solver's
world-frame angular velocity and `rotations.integrate_rotation`.

Gradient (exact): d dtheta / d delta_a = J_l^-1(dtheta) and J_l^-T(phi) phi = phi, so
    dU/dtheta_a = k_theta dtheta,   dU/dtheta_b = -k_theta dtheta   (likewise for x).
Hessian (Gauss-Newton choice, stated): the rotational blocks are k_theta [[I, -I], [-I, I]].
The exact derivative of the gradient is k_theta J_l^-1(dtheta) (a-a block), -k_theta J_r^-1 (a-b),
not symmetric. The symmetric part of the diagonal blocks has eigenvalues 1 along dtheta and
(t/2)cot(t/2) = 1 - t^2/12 + ... across it (t = ||dtheta||), so k_theta I is exact to O(t^2) there
and never softer than the true stiffness; the cross blocks differ by the skew part 1/2 [dtheta]x,
O(t), which no symmetric Hessian can hold. Symmetric PSD keeps CG and the one-Newton-step
integration well posed.
"""
import numpy as np
from numba import njit

from softhand_sim.physics.rotations import relative_rotvec

PAIR_DOFS = 12  # (x_a, theta_a, x_b, theta_b)


@njit(cache=True)
def pair_energy(xa, qa, xb, qb, kx, ktheta):
    """Eq. 14 value [J] for one pair."""
    d = xa - xb
    dth = relative_rotvec(qa, qb)
    return 0.5 * kx * (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) + 0.5 * ktheta * (
        dth[0] * dth[0] + dth[1] * dth[1] + dth[2] * dth[2])


@njit(cache=True)
def pair_gradient(xa, qa, xb, qb, kx, ktheta):
    """Eq. 14 gradient (12,) w.r.t. (x_a, theta_a, x_b, theta_b) [N, N m]; the negated force/torque."""
    g = np.zeros(PAIR_DOFS)
    dth = relative_rotvec(qa, qb)
    for i in range(3):
        dx = kx * (xa[i] - xb[i])
        g[i] = dx
        g[6 + i] = -dx
        g[3 + i] = ktheta * dth[i]
        g[9 + i] = -ktheta * dth[i]
    return g


@njit(cache=True)
def pair_hessian(kx, ktheta):
    """Gauss-Newton Hessian (12, 12) of Eq. 14: [[K, -K], [-K, K]], K = diag(kx I, k_theta I).

    Independent of the poses (see the module docstring for why this choice); symmetric PSD.
    """
    h = np.zeros((PAIR_DOFS, PAIR_DOFS))
    for i in range(3):
        for a in range(2):
            for b in range(2):
                s = 1.0 if a == b else -1.0
                h[6 * a + i, 6 * b + i] = s * kx
                h[6 * a + 3 + i, 6 * b + 3 + i] = s * ktheta
    return h


@njit(cache=True)
def target_energy_gradient(x, q, x_target, q_target, kx, ktheta, grad6):
    """Eq. 14 between a simulated body (x, q) and a fixed target: energy [J]; ADDS the (6,)
    gradient w.r.t. (x, theta) into grad6. The Hessian is diag(kx I, k_theta I)."""
    dth = relative_rotvec(q, q_target)
    e = 0.0
    for i in range(3):
        d = x[i] - x_target[i]
        e += 0.5 * kx * d * d + 0.5 * ktheta * dth[i] * dth[i]
        grad6[i] += kx * d
        grad6[3 + i] += ktheta * dth[i]
    return e


@njit(cache=True)
def targets_energy(body_x, body_q, target_x, target_q, kx, ktheta):
    """Sum of Eq. 14 over bodies coupled to fixed targets. body_x (B,3) [m], body_q (B,4),
    target_x/target_q alike, kx/ktheta (B,) per body. Returns [J]."""
    e = 0.0
    for b in range(body_x.shape[0]):
        e += pair_energy(body_x[b], body_q[b], target_x[b], target_q[b], kx[b], ktheta[b])
    return e


@njit(cache=True)
def targets_add_gradient(body_x, body_q, target_x, target_q, kx, ktheta, grad, body_dof0):
    """Adds the Eq. 14 gradient of every body-target pair into grad at body_dof0 + 6 b + (0..5)."""
    tmp = np.zeros(6)
    for b in range(body_x.shape[0]):
        tmp[:] = 0.0
        target_energy_gradient(body_x[b], body_q[b], target_x[b], target_q[b], kx[b], ktheta[b], tmp)
        o = body_dof0 + 6 * b
        for i in range(6):
            grad[o + i] += tmp[i]


@njit(cache=True)
def targets_add_hessian(kx, ktheta, diag_slots, values):
    """Adds diag(kx I, k_theta I) per body into CSR values; diag_slots (B, 6) = value index of each
    body's 6 diagonal entries."""
    for b in range(kx.shape[0]):
        for i in range(3):
            values[diag_slots[b, i]] += kx[b]
            values[diag_slots[b, 3 + i]] += ktheta[b]
