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
from softhand_sim.physics.rotations import quat_to_matrix_into


@njit(cache=True)
def _frame_into(c, node_x, body_x, body_q, contact_nodes, contact_bary, contact_body,
                contact_anchor, contact_normal, R, out):
    """Fills out (9,) with D = x_a - x_n [m] (0:3), the world normal n (3:6) and the world lever
    R r [m] (6:9, zero for a static object) of contact c; R (3,3) is scratch. No allocation:
    it runs per contact per step."""
    x0 = x1 = x2 = 0.0
    for a in range(4):
        nd, w = contact_nodes[c, a], contact_bary[c, a]
        x0 += w * node_x[nd, 0]
        x1 += w * node_x[nd, 1]
        x2 += w * node_x[nd, 2]
    b = contact_body[c]
    if b >= 0:
        quat_to_matrix_into(body_q[b], R)
        for i in range(3):
            out[6 + i] = R[i, 0] * contact_anchor[c, 0] + R[i, 1] * contact_anchor[c, 1] + R[i, 2] * contact_anchor[c, 2]
            out[3 + i] = R[i, 0] * contact_normal[c, 0] + R[i, 1] * contact_normal[c, 1] + R[i, 2] * contact_normal[c, 2]
            out[i] = body_x[b, i] + out[6 + i]
    else:
        for i in range(3):
            out[6 + i] = 0.0
            out[3 + i] = contact_normal[c, i]
            out[i] = contact_anchor[c, i]
    out[0] -= x0
    out[1] -= x1
    out[2] -= x2


@njit(cache=True)
def stiffness_into(n0, n1, n2, d0, d1, d2, w, kn, kf, sliding, K):
    """K (3,3) = w (k_n n n^T + k_f (I - n n^T)) [N/m] for the normal n and the gap D = (d0, d1, d2);
    sliding (the anchor follows the point during the step, Sect. 3.5): less w k_f along D's
    tangential part, the slip direction, so the friction force is constant over the step.
    Shared with the skin-skin term (energies/self_contact.py)."""
    n = (n0, n1, n2)
    for i in range(3):
        for j in range(3):
            K[i, j] = w * ((kn - kf) * n[i] * n[j] + (kf if i == j else 0.0))
    if sliding:
        dn = n0 * d0 + n1 * d1 + n2 * d2
        t0, t1, t2 = d0 - dn * n0, d1 - dn * n1, d2 - dn * n2
        tl2 = t0 * t0 + t1 * t1 + t2 * t2
        if tl2 > 0.0:
            t = (t0, t1, t2)
            for i in range(3):
                for j in range(3):
                    K[i, j] -= w * kf * t[i] * t[j] / tl2


@njit(cache=True)
def _add_rows(indptr, indices, values, row, nrows, col, ncols, M, scale, transpose):
    """values[(row + i, col + j)] += scale * M[i, j] (M[j, i] if transpose) for i < nrows,
    j < ncols (a 3x3, 3x6 or 6x3 block of node or body dofs); returns the count of nonzero
    entries missing from the pattern (skipped). One binary search per block: the model's pattern
    is built from whole node and body stencils (assembly.build_pattern), so the rows of a node
    (3) or a body (6) hold the same columns and col + j sits at the same offset in each; an
    entry found elsewhere is searched on its own."""
    skipped = 0
    k0 = csr_slot(indptr, indices, row, col)
    off = k0 - indptr[row]
    for i in range(nrows):
        r = row + i
        base, end = indptr[r] + off, indptr[r + 1]
        for j in range(ncols):
            h = scale * (M[j, i] if transpose else M[i, j])
            if h == 0.0:
                continue
            k = base + j
            if k0 >= 0 and k < end and indices[k] == col + j:
                values[k] += h
            else:
                k = csr_slot(indptr, indices, r, col + j)
                if k >= 0:
                    values[k] += h
                else:
                    skipped += 1
    return skipped


@njit(cache=True)
def _accumulate(node_x, body_x, body_q, contact_count, contact_nodes, contact_bary, contact_body,
                contact_anchor, contact_normal, contact_area, kn, kf, contact_slip, body_dof0, grad,
                indptr, indices, values, contact_tet, tet_slots, body_slots, want_grad, want_hess):
    """The one loop behind value / add_gradient / add_hessian / add_all: (energy [J], skipped
    Hessian entries). Per contact, with A = w K (K less k_f t t^T for a sliding one, below) and
    J = dD/dq = [-beta_0 I .. -beta_3 I | I | J_theta] (nodes | c | theta), J_theta = -[R r]x,
    the Gauss-Newton Hessian J^T A J in blocks: node-node beta_a beta_b A, node-body
    -beta_a [A, A J_theta], body-body [[A, A J_theta], [., J_theta^T A J_theta]].
    Where they are known the blocks go through precomputed slots: contact_tet (C,) the tet whose
    nodes, in order, are the contact's (-1: search; tet_slots (T,12,12)), body_slots (B,6,6)
    (none given: search); the node-body blocks by one search each (_add_rows). Scalars and a few
    small scratch matrices: nothing is allocated per contact."""
    R, A, NB, BB = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 6)), np.empty((6, 6))
    geo = np.empty(9)
    energy, skipped = 0.0, 0
    for c in range(contact_count):
        _frame_into(c, node_x, body_x, body_q, contact_nodes, contact_bary, contact_body,
                    contact_anchor, contact_normal, R, geo)
        D0, D1, D2, n0, n1, n2, l0, l1, l2 = geo[0], geo[1], geo[2], geo[3], geo[4], geo[5], geo[6], geo[7], geo[8]
        w = contact_area[c]
        nd = n0 * D0 + n1 * D1 + n2 * D2
        # f = w K D = w (k_f D + (k_n - k_f)(n.D) n): the force on the hand, dU/dD
        s = w * (kn - kf) * nd
        f0, f1, f2 = w * kf * D0 + s * n0, w * kf * D1 + s * n1, w * kf * D2 + s * n2
        energy += 0.5 * (f0 * D0 + f1 * D1 + f2 * D2)
        b = contact_body[c]
        o = body_dof0 + 6 * b
        if want_grad:
            for a in range(4):
                beta, r = contact_bary[c, a], 3 * contact_nodes[c, a]
                grad[r] -= beta * f0
                grad[r + 1] -= beta * f1
                grad[r + 2] -= beta * f2
            if b >= 0:  # dU/dc = f, dU/dtheta = (R r) x f + n x (w (k_n - k_f)(n.D) D)
                grad[o] += f0
                grad[o + 1] += f1
                grad[o + 2] += f2
                grad[o + 3] += l1 * f2 - l2 * f1 + s * (n1 * D2 - n2 * D1)
                grad[o + 4] += l2 * f0 - l0 * f2 + s * (n2 * D0 - n0 * D2)
                grad[o + 5] += l0 * f1 - l1 * f0 + s * (n0 * D1 - n1 * D0)
        if not want_hess:
            continue
        stiffness_into(n0, n1, n2, D0, D1, D2, w, kn, kf, contact_slip[c] == 2, A)
        t = contact_tet[c]
        for a in range(4):  # node-node: beta_a beta_b A, from the tet's slots when it has them
            ba = contact_bary[c, a]
            if ba == 0.0:
                continue
            ra = 3 * contact_nodes[c, a]
            for bb in range(4):
                sc = ba * contact_bary[c, bb]
                if sc == 0.0:
                    continue
                if t >= 0:
                    for i in range(3):
                        for j in range(3):
                            values[tet_slots[t, 3 * a + i, 3 * bb + j]] += sc * A[i, j]
                else:
                    skipped += _add_rows(indptr, indices, values, ra, 3, 3 * contact_nodes[c, bb], 3, A,
                                         sc, False)
        if b < 0:
            continue
        for i in range(3):  # NB = [A | A J_theta] with J_theta = -[l]x
            a0, a1, a2 = A[i, 0], A[i, 1], A[i, 2]
            NB[i, 0], NB[i, 1], NB[i, 2] = a0, a1, a2
            NB[i, 3] = a2 * l1 - a1 * l2
            NB[i, 4] = a0 * l2 - a2 * l0
            NB[i, 5] = a1 * l0 - a0 * l1
        for i in range(3):  # BB = [[A, A J], [(A J)^T, J^T A J]], J^T = [l]x
            for j in range(6):
                BB[i, j] = NB[i, j]
                BB[j, i] = NB[i, j]
        for j in range(3, 6):
            c0, c1, c2 = NB[0, j], NB[1, j], NB[2, j]
            BB[3, j] = l1 * c2 - l2 * c1
            BB[4, j] = l2 * c0 - l0 * c2
            BB[5, j] = l0 * c1 - l1 * c0
        for a in range(4):  # node-body: -beta_a NB and its transpose
            ba = contact_bary[c, a]
            if ba == 0.0:
                continue
            ra = 3 * contact_nodes[c, a]
            skipped += _add_rows(indptr, indices, values, ra, 3, o, 6, NB, -ba, False)
            skipped += _add_rows(indptr, indices, values, o, 6, ra, 3, NB, -ba, True)
        if body_slots.shape[0] > 0:
            for i in range(6):
                for j in range(6):
                    values[body_slots[b, i, j]] += BB[i, j]
        else:
            skipped += _add_rows(indptr, indices, values, o, 6, o, 6, BB, 1.0, False)
    return energy, skipped


_NO_TET_SLOTS = np.zeros((0, 12, 12), np.int32)
_NO_BODY_SLOTS = np.zeros((0, 6, 6), np.int32)


def _search_everywhere(contact_count):
    """The slot arguments of _accumulate that make it search every block (no model slots)."""
    return np.full(max(int(contact_count), 1), -1, np.int32), _NO_TET_SLOTS, _NO_BODY_SLOTS


def value(node_x, body_x, body_q, contact_count, contact_nodes, contact_bary, contact_body,
          contact_anchor, contact_normal, contact_area, kn, kf):
    """Sum of Eq. 12 + Eq. 13 over the first contact_count contacts [J].

    node_x (N,3) [m]; body_x (B,3) centres of mass [m]; body_q (B,4) [x,y,z,w];
    contact_nodes (C,4) i4, contact_bary (C,4); contact_body (C,) i4 (-1 static);
    contact_anchor, contact_normal (C,3) (body axes about the COM, or world when static) [m];
    contact_area (C,) [m^2]; kn, kf [N/m^3].
    """
    z, zi = np.zeros(1), np.zeros(1, np.int32)
    return _accumulate(node_x, body_x, body_q, contact_count, contact_nodes, contact_bary, contact_body,
                       contact_anchor, contact_normal, contact_area, kn, kf, np.zeros(1, np.uint8), 0, z,
                       zi, zi, z, *_search_everywhere(contact_count), False, False)[0]


def add_gradient(node_x, body_x, body_q, contact_count, contact_nodes, contact_bary, contact_body,
                 contact_anchor, contact_normal, contact_area, kn, kf, body_dof0, grad):
    """Adds dU/dq into grad (nodes at 3 node + i, body b at body_dof0 + 6 b + (0..5)); returns [J]."""
    z, zi = np.zeros(1), np.zeros(1, np.int32)
    return _accumulate(node_x, body_x, body_q, contact_count, contact_nodes, contact_bary, contact_body,
                       contact_anchor, contact_normal, contact_area, kn, kf, np.zeros(1, np.uint8), body_dof0,
                       grad, zi, zi, z, *_search_everywhere(contact_count), True, False)[0]


def add_hessian(node_x, body_x, body_q, contact_count, contact_nodes, contact_bary, contact_body,
                contact_anchor, contact_normal, contact_area, kn, kf, contact_slip, body_dof0,
                indptr, indices, values, contact_tet=None, tet_slots=None, body_slots=None):
    """Adds the Gauss-Newton Hessian of every contact into the CSR values (full pattern, sorted
    rows): through the model's slots where given (contact_tet (C,) i4, -1 for none, with
    tet_slots (T,12,12); body_slots (B,6,6)), else by binary search (contacts change every step).
    Sliding contacts (contact_slip (C,) u1 == 2, contact.SLIDING) get no stiffness along their
    friction force: their anchor follows the point during the step (Sect. 3.5 slip regime), so
    the friction force is constant over the step. 0 (stick) and 1 (slip, coming to rest) keep
    w K. Entries missing from the pattern (a node-body pair the model did not reserve) are
    skipped: dropping the off-diagonal blocks of a PSD matrix keeps it PSD (block-Jacobi
    coupling, gradient exact). Returns the number of skipped entries."""
    slots = _slots(contact_count, contact_tet, tet_slots, body_slots)
    return _accumulate(node_x, body_x, body_q, contact_count, contact_nodes, contact_bary, contact_body,
                       contact_anchor, contact_normal, contact_area, kn, kf, contact_slip, body_dof0,
                       np.zeros(1), indptr, indices, values, *slots, False, True)[1]


def add_all(node_x, body_x, body_q, contact_count, contact_nodes, contact_bary, contact_body,
            contact_anchor, contact_normal, contact_area, kn, kf, contact_slip, body_dof0, grad,
            indptr, indices, values, contact_tet=None, tet_slots=None, body_slots=None):
    """add_gradient and add_hessian in one pass over the contacts (the solver's assemble stage):
    (energy [J], skipped Hessian entries)."""
    slots = _slots(contact_count, contact_tet, tet_slots, body_slots)
    return _accumulate(node_x, body_x, body_q, contact_count, contact_nodes, contact_bary, contact_body,
                       contact_anchor, contact_normal, contact_area, kn, kf, contact_slip, body_dof0,
                       grad, indptr, indices, values, *slots, True, True)


def _slots(contact_count, contact_tet, tet_slots, body_slots):
    no_tet, no_tet_slots, no_body_slots = _search_everywhere(contact_count)
    if contact_tet is None or tet_slots is None:
        contact_tet, tet_slots = no_tet, no_tet_slots
    return contact_tet, tet_slots, (no_body_slots if body_slots is None else body_slots)


@njit(cache=True)
def contact_forces(node_x, body_x, body_q, contact_count, contact_nodes, contact_bary, contact_body,
                   contact_anchor, contact_normal, contact_area, kn, kf, out_point, out_normal,
                   out_force_n, out_force_f):
    """Per contact: skin point (world) [m], world normal, normal and friction force on the hand [N]."""
    R, geo = np.empty((3, 3)), np.empty(9)
    for c in range(contact_count):
        _frame_into(c, node_x, body_x, body_q, contact_nodes, contact_bary, contact_body,
                    contact_anchor, contact_normal, R, geo)
        w = contact_area[c]
        nd = geo[3] * geo[0] + geo[4] * geo[1] + geo[5] * geo[2]
        for i in range(3):
            xn = 0.0
            for a in range(4):
                xn += contact_bary[c, a] * node_x[contact_nodes[c, a], i]
            out_point[c, i] = xn
            out_normal[c, i] = geo[3 + i]
            out_force_n[c, i] = w * kn * nd * geo[3 + i]
            out_force_f[c, i] = w * kf * (geo[i] - nd * geo[3 + i])
