"""The hands of a model on the cores in parallel (`solver_threads` > 1): the stages of the step
that split by hand without changing a single operation.

With two hands and no coupling between them but through the object bodies, every expensive stage
falls apart by hand (docs/ARCHITECTURE.md, "Two hands on two cores"):
  * the tissue term: each hand's tets write only their own nodes' gradient and matrix entries;
  * the factorization: the factor's ordering (ldlt.grouped_order) puts each hand's blocks apart
    and the shared rows (the objects) last, so L is block-diagonal per hand plus the last rows
    and a hand's rows read only that hand's rows;
  * the triangular solves of the preconditioner, by the same structure; and the matrix-vector
    product, by rows.
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
from softhand_sim.physics.ldlt import (backward_column, forward_column, gather_rows, ldlt_numeric_rows,
                                       scale_by_dinv, scatter_rows)


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
def ldlt_solve_by_group(Lp, Li, Lx, Dinv, perm, tmp, r, z, gb, split, w):
    """ldlt.ldlt_solve with the groups' block rows gb[h]:gb[h+1] in parallel and the shared rows
    gb[-1]:nb after them. split[i]: the first entry of column i in a shared row (a column's rows
    ascend); w (3 nb,) scratch keeps the groups' w_i for the shared rows' updates, which run on
    one thread (groups would write the same shared rows)."""
    nb = perm.shape[0]
    groups = gb.shape[0] - 1
    shared = gb[groups]
    for h in prange(groups):
        gather_rows(gb[h], gb[h + 1], perm, r, tmp)
        for i in range(gb[h], gb[h + 1]):
            forward_column(i, Lp[i], split[i], Li, Lx, tmp, tmp)
            if split[i] < Lp[i + 1]:
                w[3 * i], w[3 * i + 1], w[3 * i + 2] = tmp[3 * i], tmp[3 * i + 1], tmp[3 * i + 2]
            scale_by_dinv(i, Dinv, tmp)
    if shared < nb:
        gather_rows(shared, nb, perm, r, tmp)
        for i in range(shared):  # the groups' columns into the shared rows
            if split[i] < Lp[i + 1]:
                forward_column(i, split[i], Lp[i + 1], Li, Lx, w, tmp)
        for i in range(shared, nb):
            forward_column(i, Lp[i], Lp[i + 1], Li, Lx, tmp, tmp)
            scale_by_dinv(i, Dinv, tmp)
        for i in range(nb - 1, shared - 1, -1):
            backward_column(i, Lp, Li, Lx, tmp)
        scatter_rows(shared, nb, perm, tmp, z)
    for h in prange(groups):
        for i in range(gb[h + 1] - 1, gb[h] - 1, -1):
            backward_column(i, Lp, Li, Lx, tmp)
        scatter_rows(gb[h], gb[h + 1], perm, tmp, z)


def shared_split(Lp, Li, first_shared):
    """split (nb,) int32 for ldlt_solve_by_group: the index of column i's first entry in a row >=
    first_shared (Lp[i + 1] when it has none)."""
    nb = len(Lp) - 1
    split = np.empty(nb, np.int32)
    for i in range(nb):
        col = Li[Lp[i]:Lp[i + 1]]
        split[i] = Lp[i] + int(np.searchsorted(col, first_shared))
    return split


def row_chunks(indptr, count):
    """count + 1 row bounds splitting a CSR matrix into chunks of about equal entries."""
    nnz = np.asarray(indptr, np.int64)
    cuts = np.searchsorted(nnz, nnz[-1] * np.arange(1, count) / count)
    return np.r_[0, cuts, len(indptr) - 1].astype(np.int64)
