"""Contact energies, Eq. 12 (normal) and Eq. 13 (friction) of the paper (Sect. 3.5).

For each active contact between a skin point x_n and an anchor x_a on the touched object:

    U_n = 1/2 w k_n (n n^T (x_a - x_n))^2              (Eq. 12)
    U_f = 1/2 w k_f ((I - n n^T)(x_a - x_n))^2         (Eq. 13)

so with D = x_a - x_n and K = k_n n n^T + k_f (I - n n^T):  U = 1/2 w D^T K D.
w [m^2] is the skin area of the point, k_n and k_f [N/m^3] (pressure per unit depth), so w k [N/m].

The skin point is x_n = sum_a beta_a x[node_a] (4 tissue nodes and barycentric weights; a tissue
node itself uses weights (1, 0, 0, 0)). The anchor and normal live in the object's frame: for a
dynamic object (body b >= 0 of the solver) x_a = c_b + R_b r and n = R_b m, with r the anchor
relative to the body's centre of mass c_b and m the normal, both in body axes; rotations perturb
on the left in world coordinates, R <- exp(theta) R (the solver's convention). For a static
object (body -1) r and m are world-frame anchor and normal.

Local generalized coordinates of one contact, 18 entries: the 4 nodes (12), then (c, theta) (6).
Gradient (exact):
    dU/dx_node_a = -beta_a g,   dU/dc = g,   dU/dtheta = (R r) x g + n x (w (k_n - k_f)(n.D) D)
with g = w K D. The force on the hand is f = w K D (the same g), pushing the point toward the
anchor; its normal part w k_n n n^T D is f_n, the tangential part f_f.
Hessian (stated choice): Gauss-Newton J^T (w K) J with J = dD/dq. Exact for the node blocks and
whenever the object is static; for a dynamic object it drops the terms from the rotation of n and
the second derivative of R, which vanish at D = 0 (the moment of first contact) and are
O(|D| / |r|) relative otherwise. Symmetric PSD, like the Eq. 14 coupling.
"""
import numpy as np
from numba import njit

from softhand_sim.physics.energies.assembly import csr_slot
from softhand_sim.physics.rotations import quat_to_matrix

CONTACT_DOFS = 18  # 4 nodes x 3 + body (c, theta)


@njit(cache=True)
def _frame(c, node_x, body_x, body_q, contact_nodes, contact_bary, contact_body,
           contact_anchor, contact_normal):
    """(D, n, lever) of contact c: D = x_a - x_n [m], world normal n, world lever R r [m]."""
    xn = np.zeros(3)
    for a in range(4):
        nd = contact_nodes[c, a]
        for i in range(3):
            xn[i] += contact_bary[c, a] * node_x[nd, i]
    b = contact_body[c]
    if b >= 0:
        R = quat_to_matrix(body_q[b])
        lever = R @ contact_anchor[c]
        n = R @ contact_normal[c]
        xa = body_x[b] + lever
    else:
        lever = np.zeros(3)
        n = contact_normal[c].copy()
        xa = contact_anchor[c].copy()
    return xa - xn, n, lever


@njit(cache=True)
def _stiffness(n, kn, kf):
    """K = k_n n n^T + k_f (I - n n^T) (3,3) [N/m^3]."""
    K = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            K[i, j] = (kn - kf) * n[i] * n[j] + (kf if i == j else 0.0)
    return K


@njit(cache=True)
def _local(c, node_x, body_x, body_q, contact_nodes, contact_bary, contact_body, contact_anchor,
           contact_normal, contact_area, kn, kf, g, H, want_hess, slipping=False):
    """Energy [J] of contact c; writes gradient g (18,) and, if want_hess, Hessian H (18, 18)."""
    D, n, lever = _frame(c, node_x, body_x, body_q, contact_nodes, contact_bary, contact_body,
                         contact_anchor, contact_normal)
    w = contact_area[c]
    K = _stiffness(n, kn, kf)
    f = w * (K @ D)  # force on the hand = dU/dD
    energy = 0.5 * (f[0] * D[0] + f[1] * D[1] + f[2] * D[2])
    for a in range(4):
        for i in range(3):
            g[3 * a + i] = -contact_bary[c, a] * f[i]
    dyn = contact_body[c] >= 0
    for i in range(6):
        g[12 + i] = 0.0
    if dyn:
        nd = n[0] * D[0] + n[1] * D[1] + n[2] * D[2]
        s = w * (kn - kf) * nd
        t = np.cross(lever, f) + s * np.cross(n, D)
        for i in range(3):
            g[12 + i] = f[i]
            g[15 + i] = t[i]
    if not want_hess:
        return energy
    # J = dD/dq (3, 18): nodes -beta_a I, c: I, theta: -[lever]x
    J = np.zeros((3, CONTACT_DOFS))
    for a in range(4):
        for i in range(3):
            J[i, 3 * a + i] = -contact_bary[c, a]
    if dyn:
        for i in range(3):
            J[i, 12 + i] = 1.0
        # -[r]x : row i of (theta x r) derivative -> d(theta x r)/dtheta = -[r]x
        J[0, 16], J[0, 17] = lever[2], -lever[1]
        J[1, 15], J[1, 17] = -lever[2], lever[0]
        J[2, 15], J[2, 16] = lever[1], -lever[0]
    if slipping:  # the anchor follows the point along the slip: no stiffness along the slip
        t = f - (f[0] * n[0] + f[1] * n[1] + f[2] * n[2]) * n
        tl = np.sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2])
        if tl > 0.0:
            for i in range(3):
                for j in range(3):
                    K[i, j] -= kf * t[i] * t[j] / (tl * tl)
    KJ = w * (K @ J)
    H[:, :] = J.T @ KJ
    return energy


@njit(cache=True)
def value(node_x, body_x, body_q, contact_count, contact_nodes, contact_bary, contact_body,
          contact_anchor, contact_normal, contact_area, kn, kf):
    """Sum of Eq. 12 + Eq. 13 over the first contact_count contacts [J].

    node_x (N,3) [m]; body_x (B,3) centres of mass [m]; body_q (B,4) [x,y,z,w];
    contact_nodes (C,4) i4, contact_bary (C,4); contact_body (C,) i4 (-1 static);
    contact_anchor, contact_normal (C,3) (body axes about the COM, or world when static) [m];
    contact_area (C,) [m^2]; kn, kf [N/m^3].
    """
    g = np.empty(CONTACT_DOFS)
    H = np.empty((1, 1))
    e = 0.0
    for c in range(contact_count):
        e += _local(c, node_x, body_x, body_q, contact_nodes, contact_bary, contact_body,
                    contact_anchor, contact_normal, contact_area, kn, kf, g, H, False)
    return e


@njit(cache=True)
def add_gradient(node_x, body_x, body_q, contact_count, contact_nodes, contact_bary, contact_body,
                 contact_anchor, contact_normal, contact_area, kn, kf, body_dof0, grad):
    """Adds dU/dq into grad (nodes at 3 node + i, body b at body_dof0 + 6 b + (0..5)); returns [J]."""
    g = np.empty(CONTACT_DOFS)
    H = np.empty((1, 1))
    e = 0.0
    for c in range(contact_count):
        e += _local(c, node_x, body_x, body_q, contact_nodes, contact_bary, contact_body,
                    contact_anchor, contact_normal, contact_area, kn, kf, g, H, False)
        for a in range(4):
            nd = contact_nodes[c, a]
            for i in range(3):
                grad[3 * nd + i] += g[3 * a + i]
        b = contact_body[c]
        if b >= 0:
            for i in range(6):
                grad[body_dof0 + 6 * b + i] += g[12 + i]
    return e


@njit(cache=True)
def _local_dofs(c, contact_nodes, contact_body, body_dof0, dofs):
    for a in range(4):
        for i in range(3):
            dofs[3 * a + i] = 3 * contact_nodes[c, a] + i
    b = contact_body[c]
    for i in range(6):
        dofs[12 + i] = body_dof0 + 6 * b + i if b >= 0 else -1


@njit(cache=True)
def add_hessian(node_x, body_x, body_q, contact_count, contact_nodes, contact_bary, contact_body,
                contact_anchor, contact_normal, contact_area, kn, kf, contact_slip, body_dof0,
                indptr, indices, values):
    """Adds the Gauss-Newton Hessian of every contact into the CSR values (full pattern, sorted
    rows), locating entries with assembly.csr_slot (contacts change every step). Sliding contacts
    (contact_slip (C,) u1 == 2, contact.SLIDING) get no stiffness along their friction force:
    their anchor follows the point during the step (Sect. 3.5 slip regime), so the friction
    force is constant over the step. 0 (stick) and 1 (slip, coming to rest) keep w K. Entries missing from
    the pattern (a node-body pair the model did not reserve) are skipped: dropping the
    off-diagonal blocks of a PSD matrix keeps it PSD (block-Jacobi coupling, gradient exact).
    Returns the number of skipped entries."""
    g = np.empty(CONTACT_DOFS)
    H = np.empty((CONTACT_DOFS, CONTACT_DOFS))
    dofs = np.empty(CONTACT_DOFS, np.int64)
    skipped = 0
    for c in range(contact_count):
        _local(c, node_x, body_x, body_q, contact_nodes, contact_bary, contact_body,
               contact_anchor, contact_normal, contact_area, kn, kf, g, H, True, contact_slip[c] == 2)
        _local_dofs(c, contact_nodes, contact_body, body_dof0, dofs)
        for p in range(CONTACT_DOFS):
            row = dofs[p]
            if row < 0 or (p < 12 and contact_bary[c, p // 3] == 0.0):
                continue
            end = indptr[row + 1]
            for q0 in range(0, CONTACT_DOFS, 3):  # column triplets: one search per node / body part
                col = dofs[q0]
                if col < 0 or (H[p, q0] == 0.0 and H[p, q0 + 1] == 0.0 and H[p, q0 + 2] == 0.0):
                    continue
                # the pattern holds whole triplets, so col + j sits at k + j when col is at k
                k = csr_slot(indptr, indices, row, col)
                for j in range(3):
                    h = H[p, q0 + j]
                    if h == 0.0:
                        continue
                    if k >= 0 and k + j < end and indices[k + j] == col + j:
                        values[k + j] += h
                    else:  # not laid out as a triplet: search it on its own
                        k2 = csr_slot(indptr, indices, row, col + j)
                        if k2 >= 0:
                            values[k2] += h
                        else:
                            skipped += 1
    return skipped


@njit(cache=True)
def contact_forces(node_x, body_x, body_q, contact_count, contact_nodes, contact_bary, contact_body,
                   contact_anchor, contact_normal, contact_area, kn, kf, out_point, out_normal,
                   out_force_n, out_force_f):
    """Per contact: skin point (world) [m], world normal, normal and friction force on the hand [N]."""
    for c in range(contact_count):
        D, n, lever = _frame(c, node_x, body_x, body_q, contact_nodes, contact_bary, contact_body,
                             contact_anchor, contact_normal)
        w = contact_area[c]
        nd = n[0] * D[0] + n[1] * D[1] + n[2] * D[2]
        for i in range(3):
            xn = 0.0
            for a in range(4):
                xn += contact_bary[c, a] * node_x[contact_nodes[c, a], i]
            out_point[c, i] = xn
            out_normal[c, i] = n[i]
            out_force_n[c, i] = w * kn * nd * n[i]
            out_force_f[c, i] = w * kf * (D[i] - nd * n[i])
