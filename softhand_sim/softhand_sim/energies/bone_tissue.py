"""Bone-tissue coupling, Eq. 11 of the paper (Sect. 3.4).

Per (tet, bone) representative point s:
    U_s = 1/2 k N || x_b + R_b r_s - sum_i w_i x_i ||^2,   k = k_total / N_total(bone)
k_total [N/m] (paper 3.2e6), N = capsule samples inside the tet, N_total = samples on the capsule,
r_s [m] = the point relative to the bone's centre of mass in the bone frame, w (4,) barycentric.
Generalized coordinates per point: the tet's 4 nodes (12) then the body (x_b, theta_b) (6), 18.
Gradient exact; Hessian Gauss-Newton k N J^T J (symmetric PSD; the dropped part is proportional
to the gap times k, small because the coupling is stiff). Rotation perturbation q <- exp(d) q.
"""
import numpy as np
from numba import njit

from ..rotations import quat_to_matrix


@njit(cache=True)
def _local(s, x, body_x, body_q, tets, sample_tet, sample_body, sample_r, sample_bary,
           sample_k, g, H, want_hess):
    """Energy of point s; writes g (18,), H (18,18)."""
    t, b = sample_tet[s], sample_body[s]
    rw = quat_to_matrix(body_q[b]) @ sample_r[s]
    d = body_x[b] + rw
    for a in range(4):
        d = d - sample_bary[s, a] * x[tets[t, a]]
    Jm = np.zeros((3, 18))
    for a in range(4):
        for i in range(3):
            Jm[i, 3 * a + i] = -sample_bary[s, a]
    for i in range(3):
        Jm[i, 12 + i] = 1.0
    Jm[0, 16], Jm[0, 17] = rw[2], -rw[1]
    Jm[1, 15], Jm[1, 17] = -rw[2], rw[0]
    Jm[2, 15], Jm[2, 16] = rw[1], -rw[0]
    k = sample_k[s]
    g[:] = k * (Jm.T @ d)
    if want_hess:
        H[:, :] = k * (Jm.T @ Jm)
    return 0.5 * k * np.dot(d, d)


@njit(cache=True)
def add_all(x, body_x, body_q, tets, sample_tet, sample_body, sample_r, sample_bary, sample_k,
            body_dof0, grad, slots, values, want_hess):
    """Energy [J] of Eq. 11 summed over points; adds gradient into grad (node n at 3n, body b at
    body_dof0 + 6b) and, if want_hess, the Hessian into CSR values via slots (P,18,18)."""
    g = np.empty(18)
    H = np.empty((18, 18))
    e_sum = 0.0
    for s in range(sample_tet.shape[0]):
        e_sum += _local(s, x, body_x, body_q, tets, sample_tet, sample_body, sample_r,
                        sample_bary, sample_k, g, H, want_hess)
        t = sample_tet[s]
        for a in range(4):
            for i in range(3):
                grad[3 * tets[t, a] + i] += g[3 * a + i]
        ob = body_dof0 + 6 * sample_body[s]
        for i in range(6):
            grad[ob + i] += g[12 + i]
        if want_hess:
            for p in range(18):
                for q in range(18):
                    values[slots[s, p, q]] += H[p, q]
    return e_sum
