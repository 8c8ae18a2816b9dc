"""Soft tissue: co-rotational linear FEM with the paper's nonlinear extension (Sect. 3.3, Eq. 7-10).

Per tet e with rest nodes X (4,3), current nodes x, rotation R_e (polar part of F = Ds Dm^-1):
    u = R^T x - X  (12,),   E_lin = 1/2 u^T K0 u  [J],   K0 = V B^T C B  (computed once, Eq. 7)
    W = E_lin / V  [J/m^3]; if W > Wmax:  E += V * 1/2 k (W/Wmax - 1)^2               (Eq. 8)
Gradient: g = s * R K0 u,  s = 1 + k/Wmax (W/Wmax - 1) (s = 1 below Wmax)            (Eq. 9)
Hessian:  s * (R K0 R^T + H_rot) + k/(Wmax^2 V) (R K0 u)(R K0 u)^T                   (Eq. 10)
R K0 R^T is the standard co-rotational stiffness: it drops dR/dx (exact at R = const). H_rot
(`stress_stiffness`, the solver's default; params tissue_stress_stiffness) adds that part back,
kept positive semidefinite: for an isotropic material the energy is V psi(F),
psi = mu |F - R|^2 + lam/2 (tr S - 3)^2 (S = R^T F), and the Hessian it misses is
    H_rot = V sum_i max(q_i, 0) y_i y_i^T,  q_i = 4 (mu (m_i - 2) + lam (tr S - 3)) / m_i,
    m_i = tr S - sigma_i,  y_i (12,) = 1/2 R (v_i x grad N_a) per node a,
(sigma_i, v_i) the eigenpairs of S: the three "twist" modes of the rotation. Stretched tets
(m_i > 2) get the stress stiffening of a taut string (q_i > 0: without it one Newton step per
time step overshoots stretched modes and a bar stretched 20-40 % rings); compressed ones would
get q_i < 0, clamped to 0 (the fixed-R Hessian there). Exact wherever every q_i >= 0.
The solver's fused kernel builds the same H_rot block-wise from one 3x3 matrix per tet
(`twist_matrix`: Q = sum_i max(q_i, 0) v_i v_i^T in closed form, an eigen solve only where that
is ill conditioned), a third of the reference's per-tet cost; `add_stress_hessian` keeps the
mode-by-mode form as the reference (tests/physics/test_tissue_stress.py holds them equal).
The gradient is exact when R is the exact polar rotation
(R^T F symmetric), including inverted tets where R flips the smallest singular direction.

Units: youngs [Pa], poisson [-], Wmax and k [J/m^3], positions [m].
Rotations are kept per tet as quaternions tet_q (T,4) [x,y,z,w], warm-started each step
(`update_rotations`: Newton steps of rotations.polar_update_scalars, one by default, each squaring
the error), so the decomposition costs a few flops per tet.
"""
import numpy as np
from numba import literally, njit

from softhand_sim.physics.rotations import (polar_rotation_update, polar_update_scalars,
                                            quat_matrix_entries, quat_to_matrix)


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


# ---------------------------------------------------------------- rotation (stress) stiffness
_TWIST_MIN = 1e-6  # [-] m_i below this (a tet flattened or inverted across two axes): no H_rot


@njit(cache=True)
def _jacobi_angle(app, aqq, apq):
    """(t, c, s) of the Jacobi rotation that zeroes apq of a symmetric matrix (t = tan)."""
    theta = (aqq - app) / (2.0 * apq)
    t = (1.0 if theta >= 0.0 else -1.0) / (abs(theta) + np.sqrt(theta * theta + 1.0))
    c = 1.0 / np.sqrt(t * t + 1.0)
    return t, c, t * c


@njit(cache=True)
def sym_eig3(S, w, V):
    """Eigenvalues w (3,) and eigenvectors (columns of V (3,3)) of the symmetric part of the 3x3 S
    (cyclic Jacobi; S is not modified). Round-off in a few sweeps for any S. On scalars, the three
    rotations of a sweep written out: array writes per rotation cost 3x the time (measured on the
    coarse hand, where the stress stiffness solved one per tet)."""
    a00, a01, a02, a11, a12, a22 = S[0, 0], 0.5 * (S[0, 1] + S[1, 0]), 0.5 * (S[0, 2] + S[2, 0]), \
        S[1, 1], 0.5 * (S[1, 2] + S[2, 1]), S[2, 2]
    v00, v01, v02, v10, v11, v12, v20, v21, v22 = 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0
    scale = abs(a00) + abs(a11) + abs(a22) + 1e-300
    for _ in range(12):
        if a01 * a01 + a02 * a02 + a12 * a12 <= 1e-30 * scale * scale:
            break
        if a01 != 0.0:  # (p, q) = (0, 1), the third index 2
            t, c, s = _jacobi_angle(a00, a11, a01)
            a00 -= t * a01
            a11 += t * a01
            a01 = 0.0
            a02, a12 = c * a02 - s * a12, s * a02 + c * a12
            v00, v01 = c * v00 - s * v01, s * v00 + c * v01
            v10, v11 = c * v10 - s * v11, s * v10 + c * v11
            v20, v21 = c * v20 - s * v21, s * v20 + c * v21
        if a02 != 0.0:  # (0, 2), the third index 1
            t, c, s = _jacobi_angle(a00, a22, a02)
            a00 -= t * a02
            a22 += t * a02
            a02 = 0.0
            a01, a12 = c * a01 - s * a12, s * a01 + c * a12
            v00, v02 = c * v00 - s * v02, s * v00 + c * v02
            v10, v12 = c * v10 - s * v12, s * v10 + c * v12
            v20, v22 = c * v20 - s * v22, s * v20 + c * v22
        if a12 != 0.0:  # (1, 2), the third index 0
            t, c, s = _jacobi_angle(a11, a22, a12)
            a11 -= t * a12
            a22 += t * a12
            a12 = 0.0
            a01, a02 = c * a01 - s * a02, s * a01 + c * a02
            v01, v02 = c * v01 - s * v02, s * v01 + c * v02
            v11, v12 = c * v11 - s * v12, s * v11 + c * v12
            v21, v22 = c * v21 - s * v22, s * v21 + c * v22
    w[0], w[1], w[2] = a00, a11, a22
    V[0, 0], V[0, 1], V[0, 2] = v00, v01, v02
    V[1, 0], V[1, 1], V[1, 2] = v10, v11, v12
    V[2, 0], V[2, 1], V[2, 2] = v20, v21, v22


@njit(cache=True)
def _twist_q(m, tr, lam, mu):
    """The twist stiffness q [Pa] of a mode with m = tr S - sigma (module docstring), unclamped."""
    return 4.0 * (mu * (m - 2.0) + lam * (tr - 3.0)) / m


@njit(cache=True)
def twist_modes(R, S, gr, lam, mu, y, q, scratch):
    """The rotation (stress) stiffness of one tet, see the module docstring: writes the three
    twist modes y (3,4,3) [1/m] (mode i, node a) and their clamped stiffness q (3,) [Pa]
    (max(q_i, 0); 0 where m_i < _TWIST_MIN). R (3,3) rotation, S (3,3) ~ R^T F (its symmetric
    part is used), gr (4,3) grad N_a [1/m]; lam, mu [Pa]; scratch (7,3). Returns the number of
    modes with q > 0."""
    # cheap exit (most tets: compressed or barely strained): Gershgorin bounds the smallest
    # eigenvalue from below, hence every m_i from above; no q_i > 0 possible -> no eigen solve
    s01, s02, s12 = 0.5 * (S[0, 1] + S[1, 0]), 0.5 * (S[0, 2] + S[2, 0]), 0.5 * (S[1, 2] + S[2, 1])
    tr = S[0, 0] + S[1, 1] + S[2, 2]
    low = min(S[0, 0] - abs(s01) - abs(s02), S[1, 1] - abs(s01) - abs(s12), S[2, 2] - abs(s02) - abs(s12))
    if mu * (tr - low - 2.0) + lam * (tr - 3.0) <= 0.0:
        q[0], q[1], q[2] = 0.0, 0.0, 0.0
        return 0
    w = scratch[0]
    V = scratch[1:4]
    sym_eig3(S, w, V)
    tr = w[0] + w[1] + w[2]
    active = 0
    for i in range(3):
        m = tr - w[i]
        qi = 0.0
        if m > _TWIST_MIN:
            qi = _twist_q(m, tr, lam, mu)
        if qi <= 0.0:
            q[i] = 0.0
            continue
        q[i] = qi
        active += 1
        v0, v1, v2 = V[0, i], V[1, i], V[2, i]
        for a in range(4):
            c0 = v1 * gr[a, 2] - v2 * gr[a, 1]   # v_i x grad N_a (rest axes)
            c1 = v2 * gr[a, 0] - v0 * gr[a, 2]
            c2 = v0 * gr[a, 1] - v1 * gr[a, 0]
            for r in range(3):
                y[i, a, r] = 0.5 * (R[r, 0] * c0 + R[r, 1] * c1 + R[r, 2] * c2)
    return active


_TWO_PI_3 = 2.0 * np.pi / 3.0


@njit(cache=True)
def _twist_one(qv, v0, v1, v2, Q):
    """Q = qv v v^T: one mode."""
    Q[0, 0], Q[1, 1], Q[2, 2] = qv * v0 * v0, qv * v1 * v1, qv * v2 * v2
    Q[0, 1] = Q[1, 0] = qv * v0 * v1
    Q[0, 2] = Q[2, 0] = qv * v0 * v2
    Q[1, 2] = Q[2, 1] = qv * v1 * v2


@njit(cache=True)
def _twist_all(s00, s11, s22, s01, s02, s12, tr, lam, mu, qv, v0, v1, v2, Q):
    """Q = f(S) - qv v v^T with f(S) = sum over all modes of q_i v_i v_i^T
    = 4 mu I + 4 (lam (tr S - 3) - 2 mu) (tr S I - S)^-1 (every m_i > 0 needed); qv = 0: all modes."""
    m00, m11, m22 = tr - s00, tr - s11, tr - s22   # M = tr I - S; its off-diagonals are -s_ij
    c00 = m11 * m22 - s12 * s12
    c01 = s12 * s02 + s01 * m22
    c02 = s01 * s12 + s02 * m11
    c11 = m00 * m22 - s02 * s02
    c12 = s01 * s02 + s12 * m00
    c22 = m00 * m11 - s01 * s01
    det = m00 * c00 - s01 * c01 - s02 * c02
    k = 4.0 * (lam * (tr - 3.0) - 2.0 * mu) / det   # M^-1 = cofactors / det (M symmetric)
    c = qv
    Q[0, 0] = 4.0 * mu + k * c00 - c * v0 * v0
    Q[1, 1] = 4.0 * mu + k * c11 - c * v1 * v1
    Q[2, 2] = 4.0 * mu + k * c22 - c * v2 * v2
    Q[0, 1] = Q[1, 0] = k * c01 - c * v0 * v1
    Q[0, 2] = Q[2, 0] = k * c02 - c * v0 * v2
    Q[1, 2] = Q[2, 1] = k * c12 - c * v1 * v2


@njit(cache=True)
def _twist_mixed(s00, s11, s22, s01, s02, s12, tr, lam, mu, Q):
    """twist_matrix's common mixed case without a Jacobi solve: the eigenvalues in closed form
    (trigonometric solution of the characteristic cubic), and only the eigenvector of the one
    mode whose sign differs from the other two's, by cross products of the rows of S - sigma I.
    q(sigma) is monotone, so that mode is the largest or smallest sigma. Returns the number of
    modes with q > 0 (Q written when > 0), or -1 where this is ill conditioned (an m_i <= 0.1,
    or S - sigma I of rank < 2 to round-off): the caller then solves with Jacobi.
    A nearly degenerate odd mode needs no Jacobi: its eigenvector is off by ~eps / gap, but q
    changes sign between it and its neighbour, so |q_odd| <= |dq/dsigma| gap and Q's error
    stays ~ |dq/dsigma| eps (measured: 3e-15 of 4 mu for gaps down to 1e-8 of the spread).
    Nearly undeformed tets are such cases (314 of the coarse hand's 848 in the bench's free motion)."""
    qm = tr / 3.0
    p1 = s01 * s01 + s02 * s02 + s12 * s12
    p2 = (s00 - qm) ** 2 + (s11 - qm) ** 2 + (s22 - qm) ** 2 + 2.0 * p1
    if p2 <= 1e-24 * (qm * qm + 1e-300):  # S ~ s I: all modes equal, Q = max(q, 0) I
        m = tr - qm
        if m <= 0.1:
            return -1
        q = _twist_q(m, tr, lam, mu)
        if q <= 0.0:
            return 0
        for r in range(3):
            for c in range(3):
                Q[r, c] = q if r == c else 0.0
        return 3
    pp = np.sqrt(p2 / 6.0)
    b00, b11, b22 = (s00 - qm) / pp, (s11 - qm) / pp, (s22 - qm) / pp
    b01, b02, b12 = s01 / pp, s02 / pp, s12 / pp
    r = 0.5 * (b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02))
    r = min(1.0, max(-1.0, r))
    phi = np.arccos(r) / 3.0
    w_hi = qm + 2.0 * pp * np.cos(phi)
    w_lo = qm + 2.0 * pp * np.cos(phi + _TWO_PI_3)
    w_mid = tr - w_hi - w_lo
    m_hi, m_mid, m_lo = tr - w_hi, tr - w_mid, tr - w_lo  # m of each mode (m_hi smallest)
    if m_hi <= 0.1:
        return -1
    q_hi, q_mid, q_lo = _twist_q(m_hi, tr, lam, mu), _twist_q(m_mid, tr, lam, mu), _twist_q(m_lo, tr, lam, mu)
    pos = (q_hi > 0.0) + (q_mid > 0.0) + (q_lo > 0.0)
    if pos == 0:
        return 0
    if pos == 3:
        _twist_all(s00, s11, s22, s01, s02, s12, tr, lam, mu, 0.0, 0.0, 0.0, 0.0, Q)
        return 3
    # the odd mode: alone on its side of q = 0, at an end of the spectrum
    if (q_hi > 0.0) != (q_mid > 0.0):
        w_odd, q_odd = w_hi, q_hi
    else:
        w_odd, q_odd = w_lo, q_lo
    # eigenvector of w_odd: the longest cross product of two rows of S - w_odd I
    a00, a11, a22 = s00 - w_odd, s11 - w_odd, s22 - w_odd
    x0, x1, x2 = s01 * s12 - s02 * a11, s02 * s01 - a00 * s12, a00 * a11 - s01 * s01   # row0 x row1
    y0, y1, y2 = s01 * a22 - s02 * s12, s02 * s02 - a00 * a22, a00 * s12 - s01 * s02   # row0 x row2
    z0, z1, z2 = a11 * a22 - s12 * s12, s12 * s02 - s01 * a22, s01 * s12 - a11 * s02   # row1 x row2
    nx, ny, nz = x0 * x0 + x1 * x1 + x2 * x2, y0 * y0 + y1 * y1 + y2 * y2, z0 * z0 + z1 * z1 + z2 * z2
    if nx >= ny and nx >= nz:
        v0, v1, v2, n = x0, x1, x2, nx
    elif ny >= nz:
        v0, v1, v2, n = y0, y1, y2, ny
    else:
        v0, v1, v2, n = z0, z1, z2, nz
    if n <= 0.0:
        return -1
    inv = 1.0 / np.sqrt(n)
    v0, v1, v2 = v0 * inv, v1 * inv, v2 * inv
    if q_odd > 0.0:  # one mode: Q = q v v^T
        _twist_one(q_odd, v0, v1, v2, Q)
        return 1
    # two modes: every mode's f(S), less the odd one's
    _twist_all(s00, s11, s22, s01, s02, s12, tr, lam, mu, q_odd, v0, v1, v2, Q)
    return 2


@njit(cache=True)
def twist_matrix(S, lam, mu, Q, scratch):
    """The same stiffness as twist_modes in the rest axes as one 3x3 matrix: writes
    Q = sum_i max(q_i, 0) v_i v_i^T [Pa] (so that H_rot's block of nodes a, b is
    V/4 [h_a]x R Q R^T [h_b]x^T, h_a = R grad N_a) and returns the number of modes with q > 0.
    q(sigma) = 4 mu + 4 (lam (tr S - 3) - 2 mu) / (tr S - sigma), so where every q_i > 0
    Q = 4 mu I + 4 (lam (tr S - 3) - 2 mu) (tr S I - S)^-1, no eigen solve. In order: Gershgorin's
    bounds (no mode, or every mode, stretched); else the closed-form eigenvalues and one
    eigenvector (_twist_mixed); else, where that is ill conditioned, Jacobi (sym_eig3).
    S (3,3) (its symmetric part is used), scratch (7,3)."""
    s00, s11, s22 = S[0, 0], S[1, 1], S[2, 2]
    s01, s02, s12 = 0.5 * (S[0, 1] + S[1, 0]), 0.5 * (S[0, 2] + S[2, 0]), 0.5 * (S[1, 2] + S[2, 1])
    tr = s00 + s11 + s22
    r0, r1, r2 = abs(s01) + abs(s02), abs(s01) + abs(s12), abs(s02) + abs(s12)
    low = min(s00 - r0, s11 - r1, s22 - r2)
    if mu * (tr - low - 2.0) + lam * (tr - 3.0) <= 0.0:  # every q_i <= 0
        return 0
    high = max(s00 + r0, s11 + r1, s22 + r2)
    if tr - high > _TWIST_MIN and mu * (tr - high - 2.0) + lam * (tr - 3.0) > 0.0:  # every q_i > 0
        # M = tr I - S is symmetric positive definite here (eigenvalues m_i >= tr - high > 0)
        _twist_all(s00, s11, s22, s01, s02, s12, tr, lam, mu, 0.0, 0.0, 0.0, 0.0, Q)
        return 3
    active = _twist_mixed(s00, s11, s22, s01, s02, s12, tr, lam, mu, Q)
    if active >= 0:
        return active
    w = scratch[0]
    V = scratch[1:4]
    sym_eig3(S, w, V)
    for r in range(3):
        for c in range(3):
            Q[r, c] = 0.0
    active = 0
    for i in range(3):
        m = tr - w[i]
        if m <= _TWIST_MIN:
            continue
        qi = _twist_q(m, tr, lam, mu)
        if qi <= 0.0:
            continue
        active += 1
        for r in range(3):
            for c in range(3):
                Q[r, c] += qi * V[r, i] * V[c, i]
    return active


@njit(cache=True)
def add_stress_hessian(x, tets, Dm_inv, vol, lam, mu, tet_q, nl_k, nl_wmax, slots, values):
    """Adds H_rot (module docstring; times the Eq. 9 scale s where W > Wmax) of every tet at the
    rotations tet_q into CSR values through slots (T,12,12): the reference kernels' (add_all /
    add_hessian) complement, isotropic material (lam, mu [Pa])."""
    F = np.empty((3, 3))
    G = np.empty((3, 3))
    gr = np.empty((4, 3))
    y = np.empty((3, 4, 3))
    q = np.empty(3)
    scratch = np.empty((7, 3))
    for e in range(tets.shape[0]):
        for k in range(3):
            for c in range(3):
                gr[k + 1, c] = Dm_inv[e, k, c]
        for c in range(3):
            gr[0, c] = -(gr[1, c] + gr[2, c] + gr[3, c])
        for r in range(3):
            for c in range(3):
                acc = 0.0
                for a in range(4):
                    acc += x[tets[e, a], r] * gr[a, c]
                F[r, c] = acc
        R = quat_to_matrix(tet_q[e])
        for r in range(3):
            for c in range(3):
                G[r, c] = R[0, r] * F[0, c] + R[1, r] * F[1, c] + R[2, r] * F[2, c]
        if twist_modes(R, G, gr, lam, mu, y, q, scratch) == 0:
            continue
        V = vol[e]
        scale = 1.0
        if nl_k > 0.0:
            e00, e11, e22 = G[0, 0] - 1.0, G[1, 1] - 1.0, G[2, 2] - 1.0
            e01, e02, e12 = 0.5 * (G[0, 1] + G[1, 0]), 0.5 * (G[0, 2] + G[2, 0]), 0.5 * (G[1, 2] + G[2, 1])
            tr = e00 + e11 + e22
            W = mu * (e00 * e00 + e11 * e11 + e22 * e22 + 2.0 * (e01 * e01 + e02 * e02 + e12 * e12)) \
                + 0.5 * lam * tr * tr
            if W > nl_wmax:
                scale = 1.0 + nl_k / nl_wmax * (W / nl_wmax - 1.0)
        for i in range(3):
            if q[i] == 0.0:
                continue
            c = scale * V * q[i]
            for a in range(4):
                for r in range(3):
                    ya = c * y[i, a, r]
                    for b in range(4):
                        for s in range(3):
                            values[np.uint64(slots[e, 3 * a + r, 3 * b + s])] += ya * y[i, b, s]


# ---------------------------------------------------------------- fast path used by the solver
# The solver's per-step kernel fuses the rotation update with the assembly and uses the closed form
# of K0 for a linear tet of an isotropic material (no K0 read, ~1/4 of the flops):
#   K0_ab = V (lam g_a g_b^T + mu g_b g_a^T + mu (g_a . g_b) I),  g_a = grad N_a (rows of Dm^-1)
# so K0 u = V sigma g_a per node (sigma = lam tr(eps) I + 2 mu eps, eps = sym(R^T F) - I) and
#   R K0_ab R^T = V (lam h_a h_b^T + mu h_b h_a^T + mu (g_a . g_b) I),  h_a = R g_a.
# Same energy, gradient and Hessian as `add_all` up to round-off (tests/physics/test_fast_paths.py).

def lame(youngs, poisson):
    """(lambda, mu) [Pa] of an isotropic material (the C of rest_data)."""
    lam = youngs * poisson / ((1.0 + poisson) * (1.0 - 2.0 * poisson))
    return lam, youngs / (2.0 * (1.0 + poisson))


def is_isotropic_K0(K0, Dm_inv, vol, lam, mu, rtol=1e-9):
    """True when every K0 (T,12,12) is the isotropic linear-tet stiffness with (lam, mu): the
    condition for `add_all_fused` to reproduce `add_all`."""
    T = len(K0)
    if T == 0:
        return True
    g = np.zeros((T, 4, 3))
    g[:, 1:] = Dm_inv
    g[:, 0] = -Dm_inv.sum(axis=1)
    gg = np.einsum("tai,tbi->tab", g, g)
    K = (lam * np.einsum("tai,tbj->taibj", g, g) + mu * np.einsum("taj,tbi->taibj", g, g)
         + mu * gg[:, :, None, :, None] * np.eye(3)[None, None, :, None, :])
    K = vol[:, None, None] * K.reshape(T, 12, 12)
    return bool(np.abs(K - K0).max() <= rtol * np.abs(K0).max())


# assemble_tissue's modes: every tet into values (WHOLE); every tet into values, each one's Hessian
# and state kept (KEEP_ALL); only the tets that moved on past the tolerance, as the difference of
# their new and kept Hessians (KEEP_MOVED)
WHOLE, KEEP_ALL, KEEP_MOVED = 0, 1, 2


@njit(cache=True)
def add_all_fused(x, tets, Dm_inv, vol, lam, mu, tet_q, iterations, nl_k, nl_wmax, grad, slots,
                  values, stress_stiffness=False):
    """update_rotations + add_all in one pass for an isotropic material (lam, mu [Pa]; K0 not
    read): refreshes tet_q, returns the energy [J] (Eq. 7-8), adds the gradient (Eq. 9) into grad
    and the Hessian (Eq. 10) into CSR values through slots (T,12,12); with stress_stiffness also
    H_rot (= add_all + add_stress_hessian)."""
    return _tissue_kernel(x, tets, Dm_inv, vol, lam, mu, tet_q, iterations, nl_k, nl_wmax, grad,
                          slots, values, stress_stiffness, WHOLE, 0.0, np.zeros((0, 4)),
                          np.zeros((0, 3, 3)), np.zeros((0, 12, 12)))[0]


@njit(cache=True)
def assemble_tissue(x, tets, Dm_inv, vol, lam, mu, tet_q, iterations, nl_k, nl_wmax, grad, slots,
                    values, stress_stiffness, mode, tolerance, used_q, used_G, kept_H):
    """_tissue_kernel in `mode` given at run time (WHOLE, KEEP_ALL, KEEP_MOVED): each mode is its
    own machine code (a compile-time mode; requested from Python, numba.literally re-dispatches
    every call, ~0.2 s)."""
    if mode == WHOLE:
        return _tissue_kernel(x, tets, Dm_inv, vol, lam, mu, tet_q, iterations, nl_k, nl_wmax, grad,
                              slots, values, stress_stiffness, WHOLE, tolerance, used_q, used_G, kept_H)
    if mode == KEEP_ALL:
        return _tissue_kernel(x, tets, Dm_inv, vol, lam, mu, tet_q, iterations, nl_k, nl_wmax, grad,
                              slots, values, stress_stiffness, KEEP_ALL, tolerance, used_q, used_G,
                              kept_H)
    return _tissue_kernel(x, tets, Dm_inv, vol, lam, mu, tet_q, iterations, nl_k, nl_wmax, grad,
                          slots, values, stress_stiffness, KEEP_MOVED, tolerance, used_q, used_G, kept_H)


@njit(cache=True)
def _tissue_kernel(x, tets, Dm_inv, vol, lam, mu, tet_q, iterations, nl_k, nl_wmax, grad, slots,
                   values, stress_stiffness, mode, tolerance, used_q, used_G, kept_H):
    """add_all_fused's term, with each tet's Hessian kept between calls (params
    tissue_hessian_tolerance). A tet's Hessian depends only on its rotation R and stretch
    G = R^T F: used_q, used_G (T,4), (T,3,3) hold those it was last assembled at (used_G[e, 0, 0]
    NaN: never), kept_H (T,12,12) the Hessian itself. mode WHOLE: as add_all_fused (the arrays
    not read); KEEP_ALL: every tet into values and kept; KEEP_MOVED: values holds the kept sums
    from earlier calls and only a tet whose rotation turned, or an entry of whose stretch changed,
    by more than `tolerance` [rad] adds its new Hessian less its kept one. The energy and the
    gradient are exact at every tet in every mode. Returns (energy [J], the tets that had moved
    on past the tolerance: re-assembled in KEEP_MOVED, counted in KEEP_ALL).

    mode is compiled in (numba.literally: one machine code per mode; assemble_tissue chooses):
    as a run-time value its branches made the WHOLE kernel 20-30 % slower than the kernel
    without them (measured)."""
    literally(mode)
    F = np.empty((3, 3))
    D = np.empty((3, 3))
    gr = np.empty((4, 3))   # grad N_a [1/m]
    h = np.empty((4, 3))    # R grad N_a
    f = np.empty((4, 3))    # R K0 u per node [N]
    gg = np.empty((4, 4))
    Qt = np.empty((3, 3))    # twist stiffness in the rest axes (stress_stiffness)
    QRt = np.empty((3, 3))
    Qr = np.empty((3, 3))    # ... rotated: R Q R^T
    Ax = np.empty((4, 3, 3))
    scratch = np.empty((7, 3))
    Hl = np.empty((12, 12))  # the element Hessian before its scatter
    e_sum = 0.0
    cos_half = np.cos(0.5 * tolerance)  # |q . u| below this: turned by more than the tolerance
    moved = 0
    for e in range(tets.shape[0]):
        i0, i1, i2, i3 = tets[e, 0], tets[e, 1], tets[e, 2], tets[e, 3]
        for r in range(3):
            D[r, 0] = x[i1, r] - x[i0, r]
            D[r, 1] = x[i2, r] - x[i0, r]
            D[r, 2] = x[i3, r] - x[i0, r]
        for k in range(3):
            for c in range(3):
                gr[k + 1, c] = Dm_inv[e, k, c]
        for c in range(3):
            gr[0, c] = -(gr[1, c] + gr[2, c] + gr[3, c])
        for r in range(3):
            for c in range(3):
                F[r, c] = D[r, 0] * gr[1, c] + D[r, 1] * gr[2, c] + D[r, 2] * gr[3, c]
        qx, qy, qz, qw = polar_update_scalars(F, tet_q[e, 0], tet_q[e, 1], tet_q[e, 2], tet_q[e, 3], iterations)
        tet_q[e, 0], tet_q[e, 1], tet_q[e, 2], tet_q[e, 3] = qx, qy, qz, qw
        R00, R01, R02, R10, R11, R12, R20, R21, R22 = quat_matrix_entries(qx, qy, qz, qw)
        # G = R^T F, eps = sym(G) - I, sigma = lam tr(eps) I + 2 mu eps
        G = D  # Ds is no longer needed: reuse its storage for G
        for c in range(3):
            f0, f1, f2 = F[0, c], F[1, c], F[2, c]
            G[0, c] = R00 * f0 + R10 * f1 + R20 * f2
            G[1, c] = R01 * f0 + R11 * f1 + R21 * f2
            G[2, c] = R02 * f0 + R12 * f1 + R22 * f2
        e00, e11, e22 = G[0, 0] - 1.0, G[1, 1] - 1.0, G[2, 2] - 1.0
        e01 = 0.5 * (G[0, 1] + G[1, 0])
        e02 = 0.5 * (G[0, 2] + G[2, 0])
        e12 = 0.5 * (G[1, 2] + G[2, 1])
        ltr = lam * (e00 + e11 + e22)
        s00, s11, s22 = ltr + 2.0 * mu * e00, ltr + 2.0 * mu * e11, ltr + 2.0 * mu * e22
        s01, s02, s12 = 2.0 * mu * e01, 2.0 * mu * e02, 2.0 * mu * e12
        W = 0.5 * (s00 * e00 + s11 * e11 + s22 * e22) + s01 * e01 + s02 * e02 + s12 * e12
        V = vol[e]
        energy = V * W
        # P = V R sigma; f_a = P g_a
        P00 = V * (R00 * s00 + R01 * s01 + R02 * s02)
        P01 = V * (R00 * s01 + R01 * s11 + R02 * s12)
        P02 = V * (R00 * s02 + R01 * s12 + R02 * s22)
        P10 = V * (R10 * s00 + R11 * s01 + R12 * s02)
        P11 = V * (R10 * s01 + R11 * s11 + R12 * s12)
        P12 = V * (R10 * s02 + R11 * s12 + R12 * s22)
        P20 = V * (R20 * s00 + R21 * s01 + R22 * s02)
        P21 = V * (R20 * s01 + R21 * s11 + R22 * s12)
        P22 = V * (R20 * s02 + R21 * s12 + R22 * s22)
        for a in range(4):
            g0, g1, g2 = gr[a, 0], gr[a, 1], gr[a, 2]
            f[a, 0] = P00 * g0 + P01 * g1 + P02 * g2
            f[a, 1] = P10 * g0 + P11 * g1 + P12 * g2
            f[a, 2] = P20 * g0 + P21 * g1 + P22 * g2
        scale = 1.0
        c_over = 0.0
        if nl_k > 0.0 and W > nl_wmax:
            r = W / nl_wmax - 1.0
            energy += V * 0.5 * nl_k * r * r
            scale = 1.0 + nl_k / nl_wmax * r
            c_over = nl_k / (nl_wmax * nl_wmax * V)
        e_sum += energy
        sl = scale * lam * V
        sm = scale * mu * V
        for a in range(4):
            na = 3 * tets[e, a]
            for i in range(3):
                grad[na + i] += scale * f[a, i]
        if mode != WHOLE:
            u, Gu = used_q[e], used_G[e]
            far = np.isnan(Gu[0, 0]) or abs(qx * u[0] + qy * u[1] + qz * u[2] + qw * u[3]) < cos_half
            for r in range(3):
                for c in range(3):
                    far = far or abs(G[r, c] - Gu[r, c]) > tolerance
            moved += far
            if mode == KEEP_MOVED and not far:
                continue  # its kept Hessian stays in values
            u[0], u[1], u[2], u[3] = qx, qy, qz, qw
            for r in range(3):
                for c in range(3):
                    Gu[r, c] = G[r, c]
        # h and gg serve the Hessian only: not computed for a tet whose kept Hessian stays
        for a in range(4):
            g0, g1, g2 = gr[a, 0], gr[a, 1], gr[a, 2]
            h[a, 0] = R00 * g0 + R01 * g1 + R02 * g2
            h[a, 1] = R10 * g0 + R11 * g1 + R12 * g2
            h[a, 2] = R20 * g0 + R21 * g1 + R22 * g2
            for b in range(a, 4):
                gg[a, b] = g0 * gr[b, 0] + g1 * gr[b, 1] + g2 * gr[b, 2]
        # the element's 12x12 Hessian in a local buffer, then one scatter of its 144 entries: the
        # rotation (stress) stiffness adds up to three rank-1 terms to the same entries, and the
        # scattered writes into the CSR values, not the flops, are what the kernel's time goes on
        for a in range(4):
            for b in range(a, 4):
                dg = sm * gg[a, b]
                for i in range(3):
                    hai = h[a, i]
                    hbi = h[b, i]
                    fai = c_over * f[a, i]
                    for j in range(3):
                        v = sl * hai * h[b, j] + sm * h[a, j] * hbi + fai * f[b, j]
                        if i == j:
                            v += dg
                        Hl[3 * a + i, 3 * b + j] = v
                        Hl[3 * b + j, 3 * a + i] = v
        if stress_stiffness and twist_matrix(G, lam, mu, Qt, scratch) > 0:
            # H_rot's block (a, b) = V/4 [h_a]x Q' [h_b]x^T with Q' = R Q R^T (twist_matrix):
            # row i of [h_a]x Q' is h_a x (column i of Q'), row i of A [k]x^T is k x (row i of A)
            for r in range(3):
                t0 = Qt[r, 0] * R00 + Qt[r, 1] * R01 + Qt[r, 2] * R02   # (Q R^T)[r, 0]
                t1 = Qt[r, 0] * R10 + Qt[r, 1] * R11 + Qt[r, 2] * R12
                t2 = Qt[r, 0] * R20 + Qt[r, 1] * R21 + Qt[r, 2] * R22
                QRt[r, 0], QRt[r, 1], QRt[r, 2] = t0, t1, t2
            for c in range(3):
                Qr[0, c] = R00 * QRt[0, c] + R01 * QRt[1, c] + R02 * QRt[2, c]
                Qr[1, c] = R10 * QRt[0, c] + R11 * QRt[1, c] + R12 * QRt[2, c]
                Qr[2, c] = R20 * QRt[0, c] + R21 * QRt[1, c] + R22 * QRt[2, c]
            cs = 0.25 * scale * V
            for a in range(4):
                h0, h1, h2 = h[a, 0], h[a, 1], h[a, 2]
                for c in range(3):  # A_a = cs [h_a]x Q' (Q' symmetric: column c = row c)
                    q0, q1, q2 = Qr[0, c], Qr[1, c], Qr[2, c]
                    Ax[a, 0, c] = cs * (h1 * q2 - h2 * q1)
                    Ax[a, 1, c] = cs * (h2 * q0 - h0 * q2)
                    Ax[a, 2, c] = cs * (h0 * q1 - h1 * q0)
            for a in range(4):
                for b in range(a, 4):
                    k0, k1, k2 = h[b, 0], h[b, 1], h[b, 2]
                    for i in range(3):
                        a0, a1, a2 = Ax[a, i, 0], Ax[a, i, 1], Ax[a, i, 2]
                        v0 = k1 * a2 - k2 * a1
                        v1 = k2 * a0 - k0 * a2
                        v2 = k0 * a1 - k1 * a0
                        Hl[3 * a + i, 3 * b] += v0
                        Hl[3 * a + i, 3 * b + 1] += v1
                        Hl[3 * a + i, 3 * b + 2] += v2
                        if a != b:
                            Hl[3 * b, 3 * a + i] += v0
                            Hl[3 * b + 1, 3 * a + i] += v1
                            Hl[3 * b + 2, 3 * a + i] += v2
        if mode == KEEP_MOVED:  # take the kept Hessian out as the new one goes in
            He = kept_H[e]
            for r in range(12):
                for c in range(12):
                    v = Hl[r, c]
                    values[np.uint64(slots[e, r, c])] += v - He[r, c]
                    He[r, c] = v
            continue
        for r in range(12):
            for c in range(12):
                # unsigned index: no wrap-around test per scatter
                values[np.uint64(slots[e, r, c])] += Hl[r, c]
        if mode == KEEP_ALL:
            kept_H[e] = Hl
    return e_sum, moved


@njit(cache=True)
def rotation_update(tet_q, tolerance, used_q):
    """used_q <- tet_q; returns how many tets had turned by more than `tolerance` [rad] from it
    (the count of KEEP_ALL from the rotations alone, a few flops a tet: the solver's measure of
    motion while it runs the whole kernel)."""
    cos_half = np.cos(0.5 * tolerance)
    moved = 0
    for e in range(tet_q.shape[0]):
        c = 0.0
        for k in range(4):
            c += tet_q[e, k] * used_q[e, k]
            used_q[e, k] = tet_q[e, k]
        moved += abs(c) < cos_half
    return moved
