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

from softhand_sim.physics.rotations import quat_log_scalars, quat_matrix_entries, quat_mul_scalars

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
    Jm: (3,12) scratch. Scalar products throughout: as `@` on these small arrays (a BLAS call
    each) and with a matrix allocated per call they were most of the joints' time."""
    p, c = parent[j], child[j]
    qp, qc = body_q[p], body_q[c]
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = quat_matrix_entries(qp[0], qp[1], qp[2], qp[3])
    b00, b01, b02, b10, b11, b12, b20, b21, b22 = quat_matrix_entries(qc[0], qc[1], qc[2], qc[3])
    u0, u1, u2 = r_parent[j, 0], r_parent[j, 1], r_parent[j, 2]
    w0, w1, w2 = r_child[j, 0], r_child[j, 1], r_child[j, 2]
    rp0, rp1, rp2 = a00 * u0 + a01 * u1 + a02 * u2, a10 * u0 + a11 * u1 + a12 * u2, a20 * u0 + a21 * u1 + a22 * u2
    rc0, rc1, rc2 = b00 * w0 + b01 * w1 + b02 * w2, b10 * w0 + b11 * w1 + b12 * w2, b20 * w0 + b21 * w1 + b22 * w2
    d0 = body_x[p, 0] + rp0 - body_x[c, 0] - rc0
    d1 = body_x[p, 1] + rp1 - body_x[c, 1] - rc1
    d2 = body_x[p, 2] + rp2 - body_x[c, 2] - rc2
    Jm[:, :] = 0.0
    for i in range(3):
        Jm[i, i] = 1.0
        Jm[i, 6 + i] = -1.0
    # d(R r)/d delta = -[R r]x
    Jm[0, 4], Jm[0, 5] = rp2, -rp1
    Jm[1, 3], Jm[1, 5] = -rp2, rp0
    Jm[2, 3], Jm[2, 4] = rp1, -rp0
    Jm[0, 10], Jm[0, 11] = -rc2, rc1
    Jm[1, 9], Jm[1, 11] = rc2, -rc0
    Jm[2, 9], Jm[2, 10] = -rc1, rc0
    for a in range(12):
        g[a] = k * (Jm[0, a] * d0 + Jm[1, a] * d1 + Jm[2, a] * d2)
    if want_hess:
        for a in range(12):
            for b in range(a, 12):
                h = k * (Jm[0, a] * Jm[0, b] + Jm[1, a] * Jm[1, b] + Jm[2, a] * Jm[2, b])
                H[a, b] = h
                H[b, a] = h
    return 0.5 * k * (d0 * d0 + d1 * d1 + d2 * d2)


@njit(cache=True)
def _angular(r, body_q, parent, child, rest_rot, row_joint, row_axis, row_lo, row_hi, row_k, ds):
    """One angular row: (energy, k h); when active (a locked axis off its lock, a limit passed)
    writes ds (3,): ds/d(th_c) (ds/d(th_p) = -ds, ds/dx = 0). An inactive row returns k h = 0.

    s = a_w . phi with phi = log(q_c q_rest^-1 q_p^-1): ds/d(th_c) = J_l^-1(phi)^T a_w,
    ds/d(th_p) = -J_r^-1(phi)^T a_w + a_w x phi, and with J^-1(phi)^T a = a + 1/2 phi x a + c phi x
    (phi x a) (J_r^-1(phi) = J_l^-1(-phi), c even in phi) the two are exact negatives."""
    j = row_joint[r]
    p, c = parent[j], child[j]
    qc, qr, qp = body_q[c], rest_rot[j], body_q[p]
    ax, ay, az, aw = quat_mul_scalars(qc[0], qc[1], qc[2], qc[3], -qr[0], -qr[1], -qr[2], qr[3])
    x, y, z, w = quat_mul_scalars(ax, ay, az, aw, -qp[0], -qp[1], -qp[2], qp[3])
    f0, f1, f2 = quat_log_scalars(x, y, z, w)
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = quat_matrix_entries(qp[0], qp[1], qp[2], qp[3])
    e0, e1, e2 = row_axis[r, 0], row_axis[r, 1], row_axis[r, 2]
    a0 = m00 * e0 + m01 * e1 + m02 * e2
    a1 = m10 * e0 + m11 * e1 + m12 * e2
    a2 = m20 * e0 + m21 * e1 + m22 * e2
    s = a0 * f0 + a1 * f1 + a2 * f2
    h = 0.0
    if s > row_hi[r]:
        h = s - row_hi[r]
    elif s < row_lo[r]:
        h = s - row_lo[r]
    if h == 0.0:
        return 0.0, 0.0
    # J_l^-1(phi) = I - 1/2 [phi]x + c [phi]x^2, c = 1/t^2 - (1 + cos t) / (2 t sin t), t = |phi|
    # (c -> 1/12 for small t)
    t2 = f0 * f0 + f1 * f1 + f2 * f2
    t = np.sqrt(t2)
    if t < 1e-4:
        cc = 1.0 / 12.0 + t2 / 720.0
    else:
        cc = 1.0 / t2 - (1.0 + np.cos(t)) / (2.0 * t * np.sin(t))
    x0, x1, x2 = f1 * a2 - f2 * a1, f2 * a0 - f0 * a2, f0 * a1 - f1 * a0        # phi x a
    y0, y1, y2 = f1 * x2 - f2 * x1, f2 * x0 - f0 * x2, f0 * x1 - f1 * x0        # phi x (phi x a)
    ds[0] = a0 + 0.5 * x0 + cc * y0
    ds[1] = a1 + 0.5 * x1 + cc * y1
    ds[2] = a2 + 0.5 * x2 + cc * y2
    k = row_k[r]
    return 0.5 * k * h * h, k * h


@njit(cache=True)
def add_all(body_x, body_q, parent, child, r_parent, r_child, k_lin, rest_rot, row_joint,
            row_axis, row_lo, row_hi, row_k, body_dof0, grad, slots, values, want_hess):
    """Energy [J] of all joints; adds gradient into grad (body b at body_dof0 + 6b) and, if
    want_hess, the Hessian into CSR values via slots (J,12,12)."""
    g = np.empty(12)
    H = np.empty((12, 12))
    Jm = np.empty((3, 12))
    ds = np.empty(3)
    e_sum = 0.0
    nj = parent.shape[0]
    for j in range(nj):
        e_sum += _spherical(j, body_x, body_q, parent, child, r_parent, r_child, k_lin,
                            g, H, want_hess, Jm)
        op = body_dof0 + 6 * parent[j]
        oc = body_dof0 + 6 * child[j]
        for i in range(6):
            grad[op + i] += g[i]
            grad[oc + i] += g[6 + i]
        if want_hess:
            for a in range(12):
                for b in range(12):
                    values[slots[j, a, b]] += H[a, b]
    for r in range(row_joint.shape[0]):
        e, kh = _angular(r, body_q, parent, child, rest_rot, row_joint, row_axis, row_lo, row_hi,
                         row_k, ds)
        if kh == 0.0:  # a limit not reached: nothing to add (most limit rows, most steps)
            continue
        e_sum += e
        j = row_joint[r]
        op = body_dof0 + 6 * parent[j] + 3  # the rotation entries: ds is 0 on the positions
        oc = body_dof0 + 6 * child[j] + 3
        for i in range(3):
            grad[op + i] -= kh * ds[i]
            grad[oc + i] += kh * ds[i]
        if want_hess:  # k ds ds^T on the (th_p, th_c) entries only: [[D, -D], [-D, D]], D = k ds ds^T
            k = row_k[r]
            for a in range(3):
                for b in range(3):
                    d = k * ds[a] * ds[b]
                    values[slots[j, 3 + a, 3 + b]] += d
                    values[slots[j, 9 + a, 9 + b]] += d
                    values[slots[j, 3 + a, 9 + b]] -= d
                    values[slots[j, 9 + a, 3 + b]] -= d
    return e_sum
