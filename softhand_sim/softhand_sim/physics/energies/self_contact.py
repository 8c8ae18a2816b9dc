"""Skin-skin (self) contact energy: Eq. 12 (normal) and Eq. 13 (friction) between two soft skins.

Each active contact joins a skin point x_p of one segment (its 4 tissue nodes, barycentric
weights beta) to an anchor on the skin of another segment: a skin vertex of that segment, x_v
(4 nodes of its own tet, weights gamma), plus a short offset o (< one skin edge; world frame):

    D = x_v + o - x_p,   U = 1/2 w D^T K D,   K = k_n n n^T + k_f (I - n n^T)      [J]

so both skins carry the force (equal and opposite: f = w K D pushes the point toward the anchor
and the anchor's vertex back). Deeper than d0 the normal part stiffens by k_d (params
self_contact_kn_deep, self_contact_deep_from; k_d = 0 by default):
    U += 1/2 w k_d max(n . D - d0, 0)^2
piecewise quadratic, C1, convex in D: the normal stiffness is k_n + k_d past d0, k_n before.
The normal n (world) and offset o are frozen for the step: the collide stage
(contact/self_contact.py) refreshes them from the anchor tet's rotation, as energies/contact.py
freezes a static object's frame. w [m^2] is the point's skin area (half of
it: every pair of segments is tested both ways), k_n, k_f [N/m^3].

Gradient (exact for the frozen n, o): dU/dx_node(point) = -beta_a f,  dU/dx_node(anchor) = +gamma_a f.

Hessian: the exact Gauss-Newton J^T (w K) J, in two parts. A contact whose two sides lie in one
tet goes into the CSR values (weights gamma - beta, inside the tet's stencil model.tet_slots).
Any other couples two tets of different fingers, which the model's fixed sparsity pattern does
not couple: `gauss_newton_rows` lists it as a row (nodes, weights L = (-beta, gamma), w K) and
the PCG adds sum L K L^T in every product (pcg.pcg's low-rank term), so the linear system is the
exact Gauss-Newton one while the preconditioner (built from the CSR values) never sees these
contacts. Measured on the coarse fist (kn_deep 1e10, 54 contacts), against two alternatives
that put a block-diagonal part of it into the CSR values (and the rest into the rows): CG
13-16 iterations, step 2.5-3.2 ms; with the majorizer 2 w (beta beta^T (x) K) and
2 w (gamma gamma^T (x) K) on the two tets, 26 iterations, 3.3-3.6 ms; with the exact diagonal
blocks, 28-29, 3.5-3.7 ms. The majorizer alone, without the rows (an earlier choice), is not
the exact Hessian: with one Newton step per time step, its stiffness on both sides moving
together acts as a drag toward where the two skins were, so fingers touching each other held
the whole hand back (in a free-air approach of the ball pinch, the palm 12.7 mm behind where it
is without self contact; with kn_deep 1e10, stuck) and momentum was not conserved
(tests/physics/test_self_contact.py). A SLIDING contact (slip == 2) gets no stiffness along its
friction force, as energies/contact.py.

Arrays of the active list (first `count` rows):
    p_tet (C,) i4, p_bary (C,4)    the point's tet and weights
    a_tet (C,) i4, a_bary (C,4)    the anchor vertex's tet and weights
    offset (C,3) [m], normal (C,3), area (C,) [m^2], slip (C,) u1
"""
import numpy as np
from numba import njit

from softhand_sim.physics.embedded import embedded_point
from softhand_sim.physics.energies.contact import stiffness_into


@njit(cache=True)
def _frame(c, x, tets, p_tet, p_bary, a_tet, a_bary, offset):
    """D = x_v + o - x_p (3,) [m] of contact c."""
    D = np.empty(3)
    tp, ta = p_tet[c], a_tet[c]
    for i in range(3):
        acc = offset[c, i]
        for a in range(4):
            acc += a_bary[c, a] * x[tets[ta, a], i] - p_bary[c, a] * x[tets[tp, a], i]
        D[i] = acc
    return D


@njit(cache=True)
def normal_pressure(dn, kn, kd, d0):
    """The normal force per unit weight [N/m^2] at depth dn [m]: kn dn, plus kd (dn - d0) deeper
    than d0, and the normal stiffness there [N/m^3]."""
    if dn > d0:
        return kn * dn + kd * (dn - d0), kn + kd
    return kn * dn, kn


@njit(cache=True)
def _force(D, n, w, kn, kf, kd, d0):
    """f (3,) [N] on the point toward its anchor, its normal part dn = n . D [m] and the energy
    U [J] of the contact."""
    dn = n[0] * D[0] + n[1] * D[1] + n[2] * D[2]
    pn, _ = normal_pressure(dn, kn, kd, d0)
    f = np.empty(3)
    for i in range(3):
        f[i] = w * (kf * (D[i] - dn * n[i]) + pn * n[i])
    tt = D[0] * D[0] + D[1] * D[1] + D[2] * D[2] - dn * dn
    deep = dn - d0 if dn > d0 else 0.0
    return f, dn, 0.5 * w * (kf * tt + kn * dn * dn + kd * deep * deep)


@njit(cache=True)
def value(x, tets, count, p_tet, p_bary, a_tet, a_bary, offset, normal, area, kn, kf, kd, d0):
    """Sum of Eq. 12 + 13 over the active self contacts [J]."""
    e = 0.0
    for c in range(count):
        D = _frame(c, x, tets, p_tet, p_bary, a_tet, a_bary, offset)
        e += _force(D, normal[c], area[c], kn, kf, kd, d0)[2]
    return e


@njit(cache=True)
def add_gradient(x, tets, count, p_tet, p_bary, a_tet, a_bary, offset, normal, area, kn, kf, kd, d0,
                 grad):
    """Adds dU/dx into grad (node n at 3n..3n+2); returns U [J]."""
    e = 0.0
    for c in range(count):
        D = _frame(c, x, tets, p_tet, p_bary, a_tet, a_bary, offset)
        f, dn, u = _force(D, normal[c], area[c], kn, kf, kd, d0)
        e += u
        tp, ta = p_tet[c], a_tet[c]
        for a in range(4):
            npn, nan = 3 * tets[tp, a], 3 * tets[ta, a]
            for i in range(3):
                grad[npn + i] -= p_bary[c, a] * f[i]
                grad[nan + i] += a_bary[c, a] * f[i]
    return e


@njit(cache=True)
def _stiffness(c, x, tets, p_tet, p_bary, a_tet, a_bary, offset, normal, area, kn, kf, kd, d0, slip, K):
    """w K (3,3) [N/m] of contact c into K (the normal stiffness at its depth); a SLIDING contact
    loses k_f along its friction force."""
    n = normal[c]
    D = _frame(c, x, tets, p_tet, p_bary, a_tet, a_bary, offset)
    _, kn_at = normal_pressure(n[0] * D[0] + n[1] * D[1] + n[2] * D[2], kn, kd, d0)
    stiffness_into(n[0], n[1], n[2], D[0], D[1], D[2], area[c], kn_at, kf, slip[c] == 2, K)


@njit(cache=True)
def _scatter(tet_slots, t, w, K, values):
    """values[block (a, b) of tet t] += w_a w_b K."""
    for a in range(4):
        if w[a] == 0.0:
            continue
        for b in range(4):
            s = w[a] * w[b]
            if s == 0.0:
                continue
            for i in range(3):
                for j in range(3):
                    values[np.uint64(tet_slots[t, 3 * a + i, 3 * b + j])] += s * K[i, j]


@njit(cache=True)
def add_hessian(x, tets, count, p_tet, p_bary, a_tet, a_bary, offset, normal, area, kn, kf, kd, d0,
                slip, tet_slots, values):
    """Adds the exact Gauss-Newton Hessian of the contacts whose two sides lie in one tet into
    the CSR values through the tets' stencils tet_slots (T,12,12); `gauss_newton_rows` lists
    the others."""
    K = np.empty((3, 3))
    cw = np.empty(4)
    for c in range(count):
        tp, ta = p_tet[c], a_tet[c]
        if tp != ta:
            continue
        _stiffness(c, x, tets, p_tet, p_bary, a_tet, a_bary, offset, normal, area, kn, kf, kd, d0, slip, K)
        for a in range(4):
            cw[a] = a_bary[c, a] - p_bary[c, a]
        _scatter(tet_slots, tp, cw, K, values)


@njit(cache=True)
def gauss_newton_rows(x, tets, count, p_tet, p_bary, a_tet, a_bary, offset, normal, area, kn, kf, kd,
                      d0, slip, scale, nodes, weights, K):
    """The exact Gauss-Newton Hessian of the contacts whose sides lie in two tets, one row per
    contact: nodes (C,8) (the point's tet, then the anchor's), weights (C,8) = (-beta, gamma)
    (D = L^T x + o) and K (C,3,3) = scale w K. Returns the rows written; the Hessian is the
    sum over rows of (L K L^T), L the weights on the row's nodes (pcg.pcg's low-rank term)."""
    Kc = np.empty((3, 3))
    r = 0
    for c in range(count):
        tp, ta = p_tet[c], a_tet[c]
        if tp == ta:
            continue
        _stiffness(c, x, tets, p_tet, p_bary, a_tet, a_bary, offset, normal, area, kn, kf, kd, d0, slip, Kc)
        for a in range(4):
            nodes[r, a] = tets[tp, a]
            weights[r, a] = -p_bary[c, a]
            nodes[r, 4 + a] = tets[ta, a]
            weights[r, 4 + a] = a_bary[c, a]
        for i in range(3):
            for j in range(3):
                K[r, i, j] = scale * Kc[i, j]
        r += 1
    return r


@njit(cache=True)
def contact_forces(x, tets, count, p_tet, p_bary, a_tet, a_bary, offset, normal, area, kn, kf, kd, d0,
                   out_point, out_force_n, out_force_f, out_depth):
    """Per contact: the skin point (world) [m], normal and friction force on the point's side [N]
    (the anchor's side feels the opposite) and the depth n . D [m]."""
    for c in range(count):
        D = _frame(c, x, tets, p_tet, p_bary, a_tet, a_bary, offset)
        n = normal[c]
        w = area[c]
        dn = n[0] * D[0] + n[1] * D[1] + n[2] * D[2]
        out_depth[c] = dn
        pn, _ = normal_pressure(dn, kn, kd, d0)
        embedded_point(x, tets, p_tet[c], p_bary[c], out_point[c])
        for i in range(3):
            out_force_n[c, i] = w * pn * n[i]
            out_force_f[c, i] = w * kf * (D[i] - dn * n[i])
