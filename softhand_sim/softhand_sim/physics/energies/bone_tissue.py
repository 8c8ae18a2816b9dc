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


@njit(cache=True)
def add_all(x, body_x, body_q, tets, sample_tet, sample_body, sample_r, sample_bary, sample_k,
            body_dof0, grad, slots, values, want_hess):
    """Energy [J] of Eq. 11 summed over points; adds gradient into grad (node n at 3n, body b at
    body_dof0 + 6b) and, if want_hess, the Hessian into CSR values via slots (P,18,18).

    Written out from the structure of J = [-w_0 I, .., -w_3 I, I, S] (S = -[R r]x, so S^T = [R r]x):
    k J^T J has node-node blocks k w_a w_b I (diagonal), node-body blocks -k w_a [I, S] and the
    body block k [[I, S], [S^T, S^T S]], summed per body over its points and written once. Only
    the nonzero entries are added (120 per point instead of 324); the result is the same matrix
    as the dense k J^T J (the reference stencil of tests/physics/test_fast_paths.py) up to round-off."""
    B = body_x.shape[0]
    acc_k = np.zeros(B)             # sum k
    acc_r = np.zeros((B, 3))        # sum k rw
    acc_rr = np.zeros((B, 3, 3))    # sum k rw rw^T
    rep = np.full(B, -1, np.int64)  # a point of each body (its slots hold the body block)
    e_sum = 0.0
    for s in range(sample_tet.shape[0]):
        t, b = sample_tet[s], sample_body[s]
        q = body_q[b]
        qx, qy, qz, qw = q[0], q[1], q[2], q[3]
        r0, r1, r2 = sample_r[s, 0], sample_r[s, 1], sample_r[s, 2]
        # rw = R(q) r
        rw0 = ((1.0 - 2.0 * (qy * qy + qz * qz)) * r0 + 2.0 * (qx * qy - qz * qw) * r1
               + 2.0 * (qx * qz + qy * qw) * r2)
        rw1 = (2.0 * (qx * qy + qz * qw) * r0 + (1.0 - 2.0 * (qx * qx + qz * qz)) * r1
               + 2.0 * (qy * qz - qx * qw) * r2)
        rw2 = (2.0 * (qx * qz - qy * qw) * r0 + 2.0 * (qy * qz + qx * qw) * r1
               + (1.0 - 2.0 * (qx * qx + qy * qy)) * r2)
        d0 = body_x[b, 0] + rw0
        d1 = body_x[b, 1] + rw1
        d2 = body_x[b, 2] + rw2
        for a in range(4):
            n = tets[t, a]
            w = sample_bary[s, a]
            d0 -= w * x[n, 0]
            d1 -= w * x[n, 1]
            d2 -= w * x[n, 2]
        k = sample_k[s]
        e_sum += 0.5 * k * (d0 * d0 + d1 * d1 + d2 * d2)
        f0, f1, f2 = k * d0, k * d1, k * d2
        for a in range(4):
            n = tets[t, a]
            w = sample_bary[s, a]
            grad[3 * n] -= w * f0
            grad[3 * n + 1] -= w * f1
            grad[3 * n + 2] -= w * f2
        ob = body_dof0 + 6 * b
        grad[ob] += f0
        grad[ob + 1] += f1
        grad[ob + 2] += f2
        grad[ob + 3] += rw1 * f2 - rw2 * f1  # S^T f = rw x f
        grad[ob + 4] += rw2 * f0 - rw0 * f2
        grad[ob + 5] += rw0 * f1 - rw1 * f0
        if not want_hess:
            continue
        # S = -[rw]x: S[0,1] = rw2, S[0,2] = -rw1, S[1,0] = -rw2, S[1,2] = rw0, S[2,0] = rw1, S[2,1] = -rw0
        for a in range(4):
            ka = k * sample_bary[s, a]
            for c in range(4):
                kac = ka * sample_bary[s, c]
                for i in range(3):
                    values[slots[s, 3 * a + i, 3 * c + i]] += kac
            ra = 3 * a
            for i in range(3):  # -k w_a I against the body position, both triangles
                values[slots[s, ra + i, 12 + i]] -= ka
                values[slots[s, 12 + i, ra + i]] -= ka
            # -k w_a S (node rows, body rotation columns) and its transpose
            s01, s02, s12 = ka * rw2, -ka * rw1, ka * rw0
            values[slots[s, ra, 16]] -= s01
            values[slots[s, ra, 17]] -= s02
            values[slots[s, ra + 1, 15]] += s01
            values[slots[s, ra + 1, 17]] -= s12
            values[slots[s, ra + 2, 15]] += s02
            values[slots[s, ra + 2, 16]] += s12
            values[slots[s, 16, ra]] -= s01
            values[slots[s, 17, ra]] -= s02
            values[slots[s, 15, ra + 1]] += s01
            values[slots[s, 17, ra + 1]] -= s12
            values[slots[s, 15, ra + 2]] += s02
            values[slots[s, 16, ra + 2]] += s12
        rep[b] = s
        acc_k[b] += k
        acc_r[b, 0] += k * rw0
        acc_r[b, 1] += k * rw1
        acc_r[b, 2] += k * rw2
        acc_rr[b, 0, 0] += k * rw0 * rw0
        acc_rr[b, 0, 1] += k * rw0 * rw1
        acc_rr[b, 0, 2] += k * rw0 * rw2
        acc_rr[b, 1, 1] += k * rw1 * rw1
        acc_rr[b, 1, 2] += k * rw1 * rw2
        acc_rr[b, 2, 2] += k * rw2 * rw2
    if want_hess:
        Bb = np.empty((6, 6))
        for b in range(B):
            s = rep[b]
            if s < 0:
                continue
            kk = acc_k[b]
            c0, c1, c2 = acc_r[b, 0], acc_r[b, 1], acc_r[b, 2]
            for i in range(6):
                for j in range(6):
                    Bb[i, j] = 0.0
            for i in range(3):
                Bb[i, i] = kk
            # k S (position rows, rotation columns) with S = -[c]x, and S^T below
            Bb[0, 4], Bb[0, 5] = c2, -c1
            Bb[1, 3], Bb[1, 5] = -c2, c0
            Bb[2, 3], Bb[2, 4] = c1, -c0
            for i in range(3):
                for j in range(3):
                    Bb[3 + j, i] = Bb[i, 3 + j]
            # S^T S = [r]x^T [r]x = |r|^2 I - r r^T, summed with weights k
            xx, yy, zz = acc_rr[b, 0, 0], acc_rr[b, 1, 1], acc_rr[b, 2, 2]
            xy, xz, yz = acc_rr[b, 0, 1], acc_rr[b, 0, 2], acc_rr[b, 1, 2]
            Bb[3, 3], Bb[4, 4], Bb[5, 5] = yy + zz, xx + zz, xx + yy
            Bb[3, 4] = Bb[4, 3] = -xy
            Bb[3, 5] = Bb[5, 3] = -xz
            Bb[4, 5] = Bb[5, 4] = -yz
            for i in range(6):
                for j in range(6):
                    values[slots[s, 12 + i, 12 + j]] += Bb[i, j]
    return e_sum
