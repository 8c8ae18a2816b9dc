"""The hands of a model on the cores in parallel (`solver_threads` > 1): the stages of the step
that split by hand without changing a single operation.

With two hands and no coupling between them but through the object bodies, every expensive stage
falls apart by hand (docs/ARCHITECTURE.md, "Two hands on two cores"):
  * the tissue term: each hand's tets write only their own nodes' gradient and matrix entries;
  * the factorization: the factor's ordering (ldlt.grouped_order) puts each hand's blocks apart
    and the shared rows (the objects) last, so L is block-diagonal per hand plus the last rows
    and a hand's rows read only that hand's rows;
  * the triangular solves of the preconditioner, by the same structure (the panels of a hand's
    rows, panels.py); and the matrix-vector product, by rows.
Each function here runs the one-thread kernel on each hand's part in a `prange` over the hands
(or row chunks). Every matrix entry, factor entry and product row is computed by the same
arithmetic in the same order as one thread does, so results are identical but for the shared
rows' sums in the triangular solve (a different order of the same terms: round-off).

numba's OpenMP threading layer is the one that pays here (its threads spin briefly between the
parallel regions of a step); its workqueue layer wakes its workers too slowly for a 1 ms step and
measured slower than one thread.
"""
import numpy as np
from numba import njit, prange

from softhand_sim.physics.energies import tissue
from softhand_sim.physics.ldlt import gather_rows, ldlt_numeric_rows, scatter_rows
from softhand_sim.physics.panels import panel_backward, panel_forward, panel_solve


@njit(parallel=True, cache=True)
def tissue_by_hand(x, tets, Dm_inv, vol, lam, mu, tet_q, iterations, nl_k, nl_wmax, grad, slots,
                   values, stress_stiffness, mode, tolerance, used_q, used_G, kept_H, tet0):
    """tissue.assemble_tissue on each hand's tets tet0[h]:tet0[h+1] in parallel (the kept arrays
    per tet, or empty without tissue_hessian_tolerance: not read in mode WHOLE); returns
    (U [J], tets moved on)."""
    hands = tet0.shape[0] - 1
    energy = np.zeros(hands)
    moved = np.zeros(hands, np.int64)
    for h in prange(hands):
        a, b = tet0[h], tet0[h + 1]
        energy[h], moved[h] = tissue.assemble_tissue(
            x, tets[a:b], Dm_inv[a:b], vol[a:b], lam, mu, tet_q[a:b], iterations, nl_k, nl_wmax,
            grad, slots[a:b], values, stress_stiffness, mode, tolerance, used_q[a:b], used_G[a:b],
            kept_H[a:b])
    return energy.sum(), moved.sum()


@njit(parallel=True, cache=True)
def factor_rows_by_group(lo, hi, values, blk_slots, up_ptr, up_row, up_slot, row_ptr, row_col,
                         row_slot, Lp, Li, Lx, Dinv, Y):
    """ldlt_numeric_rows(lo[h], hi[h]) for every group h in parallel (rows of different groups
    never read each other; Y's rows are the group's own); returns the count of bad pivots."""
    groups = lo.shape[0]
    bad = np.zeros(groups, np.int64)
    for h in prange(groups):
        bad[h] = ldlt_numeric_rows(lo[h], hi[h], values, blk_slots, up_ptr, up_row, up_slot,
                                   row_ptr, row_col, row_slot, Lp, Li, Lx, Dinv, Y)
    return bad.sum()


@njit(parallel=True, cache=True)
def panel_solve_by_group(starts, rptr, rows, off, values, Dinv, perm, tmp, r, z, sb, acc, ug):
    """panels.panel_solve with each group's supernodes sb[h]:sb[h+1] in parallel and the shared
    ones sb[-2]:sb[-1] (the objects' rows) on one thread between the passes. A group's panels
    reach the shared rows too: each group adds those into its own acc[h] (3 (nb - first shared
    row),), summed into the shared rows before their forward pass (the sum's order differs from
    one thread's: round-off). ug: (groups, longest) scratch, one per core."""
    nb = perm.shape[0]
    groups = sb.shape[0] - 2
    shared = starts[sb[groups]]
    for h in prange(groups):
        gather_rows(starts[sb[h]], starts[sb[h + 1]], perm, r, tmp)
        acc[h, :] = 0.0
        panel_forward(sb[h], sb[h + 1], starts, rptr, rows, off, values, Dinv, tmp, ug[h], shared, acc[h])
    gather_rows(shared, nb, perm, r, tmp)
    for h in range(groups):
        for i in range(acc.shape[1]):
            tmp[3 * shared + i] += acc[h, i]
    panel_forward(sb[groups], sb[groups + 1], starts, rptr, rows, off, values, Dinv, tmp, ug[0], nb,
                  acc[0])
    panel_backward(sb[groups], sb[groups + 1], starts, rptr, rows, off, values, tmp, ug[0])
    scatter_rows(shared, nb, perm, tmp, z)
    for h in prange(groups):
        panel_backward(sb[h], sb[h + 1], starts, rptr, rows, off, values, tmp, ug[h])
        scatter_rows(starts[sb[h]], starts[sb[h + 1]], perm, tmp, z)


@njit(cache=True)
def factor_solve(fac, r, z):
    """z = A⁻¹ r with the factor in use (pcg.Factor.arrays): its groups on the cores when it has
    them (sb, the groups' supernode bounds, not empty), else on one thread."""
    starts, rptr, rows, off, values, Dinv, perm, tmp, u, sb, acc, ug = fac
    if sb.shape[0] > 0:
        panel_solve_by_group(starts, rptr, rows, off, values, Dinv, perm, tmp, r, z, sb, acc, ug)
    else:
        panel_solve(starts, rptr, rows, off, values, Dinv, perm, tmp, u, r, z)


def row_chunks(indptr, count):
    """count + 1 row bounds splitting a CSR matrix into chunks of about equal entries."""
    nnz = np.asarray(indptr, np.int64)
    cuts = np.searchsorted(nnz, nnz[-1] * np.arange(1, count) / count)
    return np.r_[0, cuts, len(indptr) - 1].astype(np.int64)
