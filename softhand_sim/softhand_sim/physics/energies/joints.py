"""Skeletal joints as soft constraints, Eq. 6 of the paper (Sect. 3.2), plus hinge/universal axes
and joint limits ("similar potential energies").

Per joint j between parent p and child c (bodies simulated about their centres of mass):
  spherical (every joint, Eq. 6):  1/2 k ||x_p + R_p r_p - x_c - R_c r_c||^2,  r = anchor - com [m]
  angular rows (hinge: the two axes across the flexion axis locked; universal: the twist axis
  flex x abd locked; limits on flexion / abduction angles):
      s = a_w . phi,   phi = log(q_c q_rest^-1 q_p^-1) (world), a_w = R_p a (a in the parent frame)
      1/2 k_a h(s)^2, h(s) = s - hi if s > hi, s - lo if s < lo, else 0 (locked axis: lo = hi = 0)
Generalized coordinates per joint: (x_p, theta_p, x_c, theta_c), 12 entries, world-frame left
rotation perturbations q <- exp(delta) q. Gradients are exact (they use the SO(3) inverse
Jacobians); Hessians are Gauss-Newton k J^T J (symmetric PSD, the dropped second-order part is
proportional to the joint gap / limit violation, small for stiff joints).
k [N/m], k_a [N m/rad], angles [rad].
"""
import numpy as np
from numba import njit

from softhand_sim.physics.rotations import (quat_conj, quat_mul, quat_to_matrix, relative_rotvec,
                         so3_left_jacobian_inv)

JOINT_SPHERICAL, JOINT_HINGE, JOINT_UNIVERSAL = 0, 1, 2


def angular_rows(joint_type, flex_axis, abd_axis, limits, k_lock, k_limit):
    """Flatten the hinge/universal locks and the limits into rows (joint, axis, lo, hi, k).

    Returns row_joint (R,) i4, row_axis (R,3), row_lo (R,), row_hi (R,), row_k (R,). Numpy, once.
    """
    rows = []
    for j, t in enumerate(joint_type):
        f = np.asarray(flex_axis[j], float)
        a = np.asarray(abd_axis[j], float)
        if t not in (JOINT_SPHERICAL, JOINT_HINGE, JOINT_UNIVERSAL):
            raise ValueError(f"joint_type[{j}] = {t}: expected 0 spherical, 1 hinge, 2 universal")
        if t == JOINT_HINGE:
            n1 = np.cross(f, [1.0, 0.0, 0.0])
            if np.linalg.norm(n1) < 0.3:
                n1 = np.cross(f, [0.0, 1.0, 0.0])
            n1 /= np.linalg.norm(n1)
            n2 = np.cross(f, n1)
            rows += [(j, n1, 0.0, 0.0, k_lock), (j, n2, 0.0, 0.0, k_lock)]
        if t == JOINT_UNIVERSAL:
            tw = np.cross(f, a)
            rows.append((j, tw / np.linalg.norm(tw), 0.0, 0.0, k_lock))
        lim = np.asarray(limits[j], float)
        if k_limit > 0.0 and np.linalg.norm(f) > 0.5 and lim[0, 0] < lim[0, 1]:
            rows.append((j, f, lim[0, 0], lim[0, 1], k_limit))
        if (k_limit > 0.0 and t != JOINT_HINGE and np.linalg.norm(a) > 0.5
                and lim[1, 0] < lim[1, 1]):
            rows.append((j, a, lim[1, 0], lim[1, 1], k_limit))
    n = len(rows)
    return (np.array([r[0] for r in rows], np.int32).reshape(n),
            np.array([r[1] for r in rows], float).reshape(n, 3),
            np.array([r[2] for r in rows], float).reshape(n),
            np.array([r[3] for r in rows], float).reshape(n),
            np.array([r[4] for r in rows], float).reshape(n))


@njit(cache=True)
def _spherical(j, body_x, body_q, parent, child, r_parent, r_child, k, g, H, want_hess, Jm):
    """Eq. 6 for joint j: energy; writes g (12,), H (12,12) over (x_p, th_p, x_c, th_c).
    Jm: (3,12) scratch. The products are written out: as `@` on these small arrays (a BLAS call
    each) they were most of the joints' time."""
    p, c = parent[j], child[j]
    rp = quat_to_matrix(body_q[p]) @ r_parent[j]
    rc = quat_to_matrix(body_q[c]) @ r_child[j]
    d = body_x[p] + rp - body_x[c] - rc
    Jm[:, :] = 0.0
    for i in range(3):
        Jm[i, i] = 1.0
        Jm[i, 6 + i] = -1.0
    # d(R r)/d delta = -[R r]x
    Jm[0, 4], Jm[0, 5] = rp[2], -rp[1]
    Jm[1, 3], Jm[1, 5] = -rp[2], rp[0]
    Jm[2, 3], Jm[2, 4] = rp[1], -rp[0]
    Jm[0, 10], Jm[0, 11] = -rc[2], rc[1]
    Jm[1, 9], Jm[1, 11] = rc[2], -rc[0]
    Jm[2, 9], Jm[2, 10] = -rc[1], rc[0]
    for a in range(12):
        g[a] = k * (Jm[0, a] * d[0] + Jm[1, a] * d[1] + Jm[2, a] * d[2])
    if want_hess:
        for a in range(12):
            for b in range(a, 12):
                h = k * (Jm[0, a] * Jm[0, b] + Jm[1, a] * Jm[1, b] + Jm[2, a] * Jm[2, b])
                H[a, b] = h
                H[b, a] = h
    return 0.5 * k * (d[0] * d[0] + d[1] * d[1] + d[2] * d[2])


@njit(cache=True)
def _angular(r, body_q, parent, child, rest_rot, row_joint, row_axis, row_lo, row_hi, row_k,
             g, H, want_hess):
    """One angular row: (energy, active); writes g (12,), H (12,12) over (x_p, th_p, x_c, th_c)
    when active (a locked axis off its lock, a limit passed); an inactive row writes nothing."""
    j = row_joint[r]
    p, c = parent[j], child[j]
    qa = quat_mul(body_q[c], quat_conj(rest_rot[j]))
    phi = relative_rotvec(qa, body_q[p])
    a_w = quat_to_matrix(body_q[p]) @ row_axis[r]
    s = np.dot(a_w, phi)
    h = 0.0
    if s > row_hi[r]:
        h = s - row_hi[r]
    elif s < row_lo[r]:
        h = s - row_lo[r]
    if h == 0.0:
        return 0.0, False
    ds = np.zeros(12)
    ds[9:12] = so3_left_jacobian_inv(phi).T @ a_w
    cr = np.cross(a_w, phi)
    ds[3:6] = -(so3_left_jacobian_inv(-phi).T @ a_w) + cr
    k = row_k[r]
    g[:] = k * h * ds
    if want_hess:
        for i in range(12):
            for jj in range(12):
                H[i, jj] = k * ds[i] * ds[jj]
    return 0.5 * k * h * h, True


@njit(cache=True)
def add_all(body_x, body_q, parent, child, r_parent, r_child, k_lin, rest_rot, row_joint,
            row_axis, row_lo, row_hi, row_k, body_dof0, grad, slots, values, want_hess):
    """Energy [J] of all joints; adds gradient into grad (body b at body_dof0 + 6b) and, if
    want_hess, the Hessian into CSR values via slots (J,12,12)."""
    g = np.empty(12)
    H = np.empty((12, 12))
    Jm = np.empty((3, 12))
    e_sum = 0.0
    nj = parent.shape[0]
    for step in range(nj + row_joint.shape[0]):
        if step < nj:
            j = step
            e_sum += _spherical(j, body_x, body_q, parent, child, r_parent, r_child, k_lin,
                                g, H, want_hess, Jm)
        else:
            r = step - nj
            j = row_joint[r]
            e, active = _angular(r, body_q, parent, child, rest_rot, row_joint, row_axis, row_lo,
                                 row_hi, row_k, g, H, want_hess)
            if not active:  # a limit not reached: nothing to add (most limit rows, most steps)
                continue
            e_sum += e
        op = body_dof0 + 6 * parent[j]
        oc = body_dof0 + 6 * child[j]
        for i in range(6):
            grad[op + i] += g[i]
            grad[oc + i] += g[6 + i]
        if want_hess:
            for a in range(12):
                for b in range(12):
                    values[slots[j, a, b]] += H[a, b]
    return e_sum
