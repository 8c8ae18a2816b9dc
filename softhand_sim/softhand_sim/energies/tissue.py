"""Soft tissue: co-rotational linear FEM with the paper's nonlinear extension (Sect. 3.3, Eq. 7-10).

Per tet e with rest nodes X (4,3), current nodes x, rotation R_e (polar part of F = Ds Dm^-1):
    u = R^T x - X  (12,),   E_lin = 1/2 u^T K0 u  [J],   K0 = V B^T C B  (computed once, Eq. 7)
    W = E_lin / V  [J/m^3]; if W > Wmax:  E += V * 1/2 k (W/Wmax - 1)^2               (Eq. 8)
Gradient: g = s * R K0 u,  s = 1 + k/Wmax (W/Wmax - 1) (s = 1 below Wmax)            (Eq. 9)
Hessian:  s * R K0 R^T + k/(Wmax^2 V) (R K0 u)(R K0 u)^T                             (Eq. 10)
The R K0 R^T block drops dR/dx (the standard co-rotational stiffness): symmetric PSD, exact at
R = const, off by O(strain) otherwise. The gradient is exact when R is the exact polar rotation
(R^T F symmetric), including inverted tets where R flips the smallest singular direction.

Units: youngs [Pa], poisson [-], Wmax and k [J/m^3], positions [m].
Rotations are kept per tet as quaternions tet_q (T,4) [x,y,z,w], warm-started each step
(`update_rotations`, Mueller et al. 2016), so the decomposition costs a few flops per tet.
"""
import numpy as np
from numba import njit

from ..rotations import polar_rotation_update, quat_to_matrix


def rest_data(tet_nodes, tets, youngs, poisson):
    """Per-tet rest volume (T,) [m^3], Dm^-1 (T,3,3) [1/m] and K0 (T,12,12) [N/m]. Numpy, once."""
    X = tet_nodes[tets]  # (T,4,3)
    Dm = np.stack([X[:, 1] - X[:, 0], X[:, 2] - X[:, 0], X[:, 3] - X[:, 0]], axis=2)  # columns
    det = np.linalg.det(Dm)
    if np.any(det <= 0.0):
        bad = np.flatnonzero(det <= 0.0)[:5]
        raise ValueError(f"tets must have positive rest volume; tets {bad.tolist()} do not")
    vol = det / 6.0
    Dm_inv = np.linalg.inv(Dm)
    grads = np.zeros((len(tets), 4, 3))
    grads[:, 1:] = Dm_inv  # row a-1 of Dm^-1 is grad N_a
    grads[:, 0] = -Dm_inv.sum(axis=1)
    lam = youngs * poisson / ((1.0 + poisson) * (1.0 - 2.0 * poisson))
    mu = youngs / (2.0 * (1.0 + poisson))
    C = np.zeros((6, 6))
    C[:3, :3] = lam
    C[[0, 1, 2], [0, 1, 2]] += 2.0 * mu
    C[[3, 4, 5], [3, 4, 5]] = mu
    B = np.zeros((len(tets), 6, 12))
    for a in range(4):
        g = grads[:, a]
        c = 3 * a
        B[:, 0, c] = g[:, 0]
        B[:, 1, c + 1] = g[:, 1]
        B[:, 2, c + 2] = g[:, 2]
        B[:, 3, c], B[:, 3, c + 1] = g[:, 1], g[:, 0]
        B[:, 4, c + 1], B[:, 4, c + 2] = g[:, 2], g[:, 1]
        B[:, 5, c], B[:, 5, c + 2] = g[:, 2], g[:, 0]
    K0 = vol[:, None, None] * np.einsum("tki,kl,tlj->tij", B, C, B)
    return vol, Dm_inv, np.ascontiguousarray(K0)


@njit(cache=True)
def update_rotations(x, tets, Dm_inv, tet_q, iterations):
    """Refresh the per-tet rotation tet_q (T,4) in place from the current positions x (N,3)."""
    F = np.empty((3, 3))
    for e in range(tets.shape[0]):
        i0 = tets[e, 0]
        for c in range(3):
            ic = tets[e, c + 1]
            for r in range(3):
                F[r, c] = x[ic, r] - x[i0, r]
        tet_q[e] = polar_rotation_update(F @ Dm_inv[e], tet_q[e], iterations)


@njit(cache=True)
def _local(e, x, X, tets, K0, vol, tet_q, nl_k, nl_wmax, g, H, want_hess, u, Ku):
    """Energy [J] of tet e; writes its gradient g (12,) and (if want_hess) Hessian H (12,12).
    u, Ku: (12,) scratch."""
    R = quat_to_matrix(tet_q[e])
    for a in range(4):
        n = tets[e, a]
        for i in range(3):
            u[3 * a + i] = R[0, i] * x[n, 0] + R[1, i] * x[n, 1] + R[2, i] * x[n, 2] - X[n, i]
    energy = 0.0
    for p in range(12):
        acc = 0.0
        for q in range(12):
            acc += K0[e, p, q] * u[q]
        Ku[p] = acc
        energy += 0.5 * u[p] * acc
    for a in range(4):
        for i in range(3):
            g[3 * a + i] = R[i, 0] * Ku[3 * a] + R[i, 1] * Ku[3 * a + 1] + R[i, 2] * Ku[3 * a + 2]
    scale = 1.0
    V = vol[e]
    W = energy / V
    over = nl_k > 0.0 and W > nl_wmax
    if over:
        r = W / nl_wmax - 1.0
        energy += V * 0.5 * nl_k * r * r
        scale = 1.0 + nl_k / nl_wmax * r
    if want_hess:
        # H_ab = s R K0_ab R^T, written out: no temporaries per block
        for a in range(4):
            for b in range(4):
                for i in range(3):
                    t0 = 0.0
                    t1 = 0.0
                    t2 = 0.0
                    for k in range(3):
                        rik = R[i, k]
                        t0 += rik * K0[e, 3 * a + k, 3 * b]
                        t1 += rik * K0[e, 3 * a + k, 3 * b + 1]
                        t2 += rik * K0[e, 3 * a + k, 3 * b + 2]
                    for j in range(3):
                        H[3 * a + i, 3 * b + j] = scale * (t0 * R[j, 0] + t1 * R[j, 1] + t2 * R[j, 2])
        if over:
            c = nl_k / (nl_wmax * nl_wmax * V)
            for p in range(12):
                for q in range(12):
                    H[p, q] += c * g[p] * g[q]
    if over:
        for p in range(12):
            g[p] *= scale
    return energy


@njit(cache=True)
def value(x, X, tets, K0, vol, tet_q, nl_k, nl_wmax):
    """Tissue energy U_t [J] (Eq. 7-8) for rotations tet_q."""
    g = np.empty(12)
    H = np.empty((12, 12))
    u = np.empty(12)
    Ku = np.empty(12)
    e_sum = 0.0
    for e in range(tets.shape[0]):
        e_sum += _local(e, x, X, tets, K0, vol, tet_q, nl_k, nl_wmax, g, H, False, u, Ku)
    return e_sum


@njit(cache=True)
def add_gradient(x, X, tets, K0, vol, tet_q, nl_k, nl_wmax, grad):
    """Adds dU_t/dx (Eq. 9) into grad (flat, node n at 3n..3n+2)."""
    g = np.empty(12)
    H = np.empty((12, 12))
    u = np.empty(12)
    Ku = np.empty(12)
    for e in range(tets.shape[0]):
        _local(e, x, X, tets, K0, vol, tet_q, nl_k, nl_wmax, g, H, False, u, Ku)
        for a in range(4):
            for i in range(3):
                grad[3 * tets[e, a] + i] += g[3 * a + i]


@njit(cache=True)
def add_all(x, X, tets, K0, vol, tet_q, nl_k, nl_wmax, grad, slots, values):
    """Energy [J]; adds gradient (Eq. 9) into grad and Hessian (Eq. 10) into CSR values through
    slots (T,12,12) (local entry -> value index)."""
    g = np.empty(12)
    H = np.empty((12, 12))
    u = np.empty(12)
    Ku = np.empty(12)
    e_sum = 0.0
    for e in range(tets.shape[0]):
        e_sum += _local(e, x, X, tets, K0, vol, tet_q, nl_k, nl_wmax, g, H, True, u, Ku)
        for a in range(4):
            for i in range(3):
                grad[3 * tets[e, a] + i] += g[3 * a + i]
        for p in range(12):
            for q in range(12):
                values[slots[e, p, q]] += H[p, q]
    return e_sum


@njit(cache=True)
def add_hessian(x, X, tets, K0, vol, tet_q, nl_k, nl_wmax, slots, values):
    """Adds the Hessian (Eq. 10) into CSR values through slots (T,12,12)."""
    g = np.empty(12)
    H = np.empty((12, 12))
    u = np.empty(12)
    Ku = np.empty(12)
    for e in range(tets.shape[0]):
        _local(e, x, X, tets, K0, vol, tet_q, nl_k, nl_wmax, g, H, True, u, Ku)
        for p in range(12):
            for q in range(12):
                values[slots[e, p, q]] += H[p, q]
