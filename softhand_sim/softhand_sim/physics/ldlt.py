"""Sparse LDLᵀ of the SPD system matrix A = M + dt² H over its fixed CSR pattern (the "factor"
preconditioner of pcg.py).

The pattern never changes after model build, so everything structural is done once:
  * a fill-reducing symmetric ordering P (multiple minimum degree on A + Aᵀ, taken from SuperLU's
    column ordering; reverse Cuthill-McKee as a fallback), its elimination tree then postordered
    (the same fill; chains of the tree become consecutive columns, the panels of panels.py),
  * the elimination tree, the column pointers of L and, for every row k of L, its nonzero columns
    in topological order with the slot each entry goes to (Davis' up-looking LDL, "LDL: a concise
    sparse Cholesky package", ACM TOMS 2005, done symbolically once),
  * row chunks of equal flop count, so a numeric factorization can be spread over several steps.
A numeric factorization is then a straight pass over precomputed index arrays (no searching, no
allocation): rows k0..k1 of L and D from a snapshot of the matrix values. The pattern reserves a
dense block between every surface node and every object body (model.py), which only contacts
fill: a block of row k's triangular solve that is exactly zero (outside the reach of the row's
nonzero entries) gives a zero block of L and no update, and is skipped, so an object without
contact costs its diagonal block and one with a few contact nodes the reach of those.

Solve: z = Pᵀ L⁻ᵀ D⁻¹ L⁻¹ P r with L unit lower triangular stored by columns (CSC, diagonal not
stored) and D⁻¹ stored. The preconditioner solves with L copied into dense panels (panels.py,
2.2x faster on the fine hand); ldlt_solve here, block by block, is the reference it is tested
against.
"""
import numpy as np
from numba import njit


def fill_reducing_order(indptr, indices, n):
    """Symmetric permutation perm (new -> old) that keeps L sparse: minimum degree on A + Aᵀ
    (SuperLU's MMD_AT_PLUS_A, computed on the pattern only), else reverse Cuthill-McKee."""
    import scipy.sparse as sp
    pattern = sp.csr_matrix((np.ones(len(indices)), indices, indptr), shape=(n, n))
    try:
        from scipy.sparse.linalg import splu
        # a strongly diagonal matrix with A's pattern: SuperLU keeps the diagonal pivots and its
        # column ordering is the minimum-degree ordering of the pattern
        A = (pattern + sp.identity(n) * (np.diff(indptr).max() + 1.0)).tocsc()
        lu = splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                  options={"SymmetricMode": True})
        perm = np.empty(n, np.int64)
        perm[lu.perm_c] = np.arange(n)  # perm_c maps old column -> new position
        return perm.astype(np.int32)
    except Exception:  # noqa: BLE001  (ordering only: RCM is always available)
        from scipy.sparse.csgraph import reverse_cuthill_mckee
        return reverse_cuthill_mckee(pattern, symmetric_mode=True).astype(np.int32)


@njit(cache=True)
def _symbolic_counts(n, indptr, indices, perm, pinv, parent, lnz, flag):
    """Elimination tree parent (n,) and column counts lnz (n,) of L (strictly lower) of P A Pᵀ."""
    for k in range(n):
        parent[k] = -1
        flag[k] = k
        lnz[k] = 0
        row = perm[k]
        for p in range(indptr[row], indptr[row + 1]):
            i = pinv[indices[p]]
            if i < k:
                while flag[i] != k:
                    if parent[i] == -1:
                        parent[i] = k
                    lnz[i] += 1
                    flag[i] = k
                    i = parent[i]


@njit(cache=True)
def _symbolic_rows(n, indptr, indices, perm, pinv, parent, Lp, Li, row_ptr, row_col, row_slot,
                   up_ptr, up_row, up_slot, row_flops, flag, stack, fill):
    """Li (the row indices of every column of L), the per-row patterns of L in topological order
    (row_col, with row_slot = the entry's index in Li/Lx), the upper-triangle gather lists of
    P A Pᵀ by column (up_row, up_slot = index into the CSR values) and flops per row."""
    t = 0
    u = 0
    for k in range(n):
        flag[k] = k
        up_ptr[k] = u
        row_ptr[k] = t
        top = n
        row = perm[k]
        for p in range(indptr[row], indptr[row + 1]):
            i = pinv[indices[p]]
            if i > k:
                continue
            up_row[u] = i
            up_slot[u] = p
            u += 1
            ln = 0
            while flag[i] != k:  # walk up the etree until a node already in the pattern
                stack[ln] = i
                ln += 1
                flag[i] = k
                i = parent[i]
            while ln > 0:
                top -= 1
                ln -= 1
                stack[top] = stack[ln]
        flops = 0
        for q in range(top, n):
            i = stack[q]
            if i == k:
                continue
            slot = Lp[i] + fill[i]
            Li[slot] = k
            fill[i] += 1
            row_col[t] = i
            row_slot[t] = slot
            flops += slot - Lp[i] + 1
            t += 1
        row_flops[k] = flops
    up_ptr[n] = u
    row_ptr[n] = t


def grouped_order(indptr, indices, n, groups):
    """Fill-reducing ordering (new -> old) of the blocks of an n x n block pattern that never
    mixes the given groups: each group (an array of block indices, e.g. one hand's node and bone
    blocks) is ordered on its own sub-pattern, groups one after the other, then every block in
    no group (the object bodies, which couple to every group) last. With no coupling between the
    groups but through those last blocks, L is block-diagonal per group plus the last rows: a
    model of H hands factors in H times one hand's flops (one ordering of the union does not
    see the blocks and can fill across them)."""
    import scipy.sparse as sp
    pattern = sp.csr_matrix((np.ones(len(indices)), indices, indptr), shape=(n, n))
    seen = np.zeros(n, bool)
    parts = []
    for g in groups:
        g = np.asarray(g, np.int64)
        sub = pattern[g][:, g].tocsr()
        parts.append(g[fill_reducing_order(sub.indptr, sub.indices, len(g))])
        seen[g] = True
    rest = np.flatnonzero(~seen)
    if len(rest):
        sub = pattern[rest][:, rest].tocsr()
        parts.append(rest[fill_reducing_order(sub.indptr, sub.indices, len(rest))])
    return np.concatenate(parts).astype(np.int32)


def postorder(parent, ranges):
    """Positions (new -> old) that put the elimination tree (parent: (nb,), -1 at a root) in
    postorder within each range ranges[g]:ranges[g+1] (a node whose parent is past its range is a
    root there): children before their parent, every subtree consecutive, so a chain of single
    children takes consecutive columns. Children are visited in their old order."""
    nb = len(parent)
    order = []
    for lo, hi in zip(ranges[:-1], ranges[1:]):
        lo, hi = int(lo), int(hi)
        children = [[] for _ in range(hi - lo)]
        roots = []
        for j in range(lo, hi):
            p = int(parent[j])
            (roots if p < 0 or p >= hi else children[p - lo]).append(j)
        for root in roots:
            stack = [(root, 0)]
            while stack:
                node, k = stack.pop()
                kids = children[node - lo]
                if k < len(kids):
                    stack.append((node, k + 1))
                    stack.append((kids[k], 0))
                else:
                    order.append(node)
    if len(order) != nb:
        raise ValueError(f"postorder: {len(order)} of {nb} nodes reached (parent is not a forest "
                         f"within the ranges {list(ranges)})")
    return np.asarray(order, np.int64)


def block_pattern(indptr, indices, n, bs=3):
    """CSR pattern of the bs x bs blocks of an n x n CSR pattern (n divisible by bs) and
    blk_slots (nnzB, bs, bs) int32: the value index of each scalar entry of each block (-1: absent)."""
    if n % bs:
        raise ValueError(f"dof count {n} is not a multiple of the block size {bs}")
    nb = n // bs
    rows = np.repeat(np.arange(n, dtype=np.int64), np.diff(indptr))
    keys = (rows // bs) * nb + np.asarray(indices, np.int64) // bs
    ukeys, inv = np.unique(keys, return_inverse=True)
    bindptr = np.zeros(nb + 1, np.int64)
    np.add.at(bindptr, ukeys // nb + 1, 1)
    slots = np.full((len(ukeys), bs, bs), -1, np.int32)
    slots[inv, rows % bs, np.asarray(indices) % bs] = np.arange(len(indices), dtype=np.int32)
    return np.cumsum(bindptr).astype(np.int32), (ukeys % nb).astype(np.int32), slots


@njit(cache=True)
def _inv3_spd(A, out):
    """out = A^-1 for a symmetric 3x3 block; returns False (and out = inverse |diagonal|) when A
    is not positive definite."""
    a, b, c = A[0, 0], A[0, 1], A[0, 2]
    d, e, f = A[1, 1], A[1, 2], A[2, 2]
    c00 = d * f - e * e
    c01 = c * e - b * f
    c02 = b * e - c * d
    det = a * c00 + b * c01 + c * c02
    if a > 0.0 and a * d - b * b > 0.0 and det > 0.0:
        s = 1.0 / det
        out[0, 0] = c00 * s
        out[0, 1] = out[1, 0] = c01 * s
        out[0, 2] = out[2, 0] = c02 * s
        out[1, 1] = (a * f - c * c) * s
        out[1, 2] = out[2, 1] = (b * c - a * e) * s
        out[2, 2] = (a * d - b * b) * s
        return True
    for i in range(3):
        for j in range(3):
            out[i, j] = 0.0
        out[i, i] = 1.0 / max(abs(A[i, i]), 1e-300)
    return False


@njit(cache=True, nogil=True)  # nogil: pcg.Factor may run it on a thread of its own
def ldlt_numeric_rows(k0, k1, values, blk_slots, up_ptr, up_row, up_slot, row_ptr, row_col,
                      row_slot, Lp, Li, Lx, Dinv, Y):
    """Block rows k0..k1-1 of the block LDLᵀ (3x3 blocks, up-looking): P A Pᵀ = L D Lᵀ with L unit
    block-lower, D block-diagonal SPD. Rows < k0 must be done (they are read). With y_i = D_i L_kiᵀ
    from L y = A[:k, k]:  L_ki = y_iᵀ D_i⁻¹,  D_k = A_kk - sum_i L_ki y_i.
    L goes to Lx (by columns, (nnzL,3,3)); Dinv (nb,3,3)
    holds D_k⁻¹. Y (nb,3,3) is zero scratch and is left zero. Returns the count of D_k blocks that
    were not positive definite (replaced by their inverse |diagonal|; 0 for an SPD matrix)."""
    bad = 0
    Dk = np.empty((3, 3))
    for k in range(k0, k1):
        for q in range(up_ptr[k], up_ptr[k + 1]):  # column k of the upper triangle: block (perm k, perm i)ᵀ
            i = up_row[q]
            e = up_slot[q]
            for a in range(3):
                for b in range(3):
                    s = blk_slots[e, b, a]
                    if s >= 0:
                        Y[i, a, b] += values[s]
        for a in range(3):
            for b in range(3):
                Dk[a, b] = Y[k, a, b]
                Y[k, a, b] = 0.0
        for t in range(row_ptr[k], row_ptr[k + 1]):
            i = row_col[t]
            pe = row_slot[t]
            y00, y01, y02 = Y[i, 0, 0], Y[i, 0, 1], Y[i, 0, 2]
            y10, y11, y12 = Y[i, 1, 0], Y[i, 1, 1], Y[i, 1, 2]
            y20, y21, y22 = Y[i, 2, 0], Y[i, 2, 1], Y[i, 2, 2]
            if (y00 == 0.0 and y01 == 0.0 and y02 == 0.0 and y10 == 0.0 and y11 == 0.0
                    and y12 == 0.0 and y20 == 0.0 and y21 == 0.0 and y22 == 0.0):
                # numerically outside the reach of row k's entries (an object row without
                # contact, or only a few contact nodes): L_ki = 0 and nothing to update
                for a in range(3):
                    for b in range(3):
                        Lx[pe, a, b] = 0.0
                continue
            for a in range(3):
                for b in range(3):
                    Y[i, a, b] = 0.0
            for p in range(Lp[i], pe):  # Y_r -= L_ri y_i
                r = Li[p]
                for a in range(3):
                    l0, l1, l2 = Lx[p, a, 0], Lx[p, a, 1], Lx[p, a, 2]
                    Y[r, a, 0] -= l0 * y00 + l1 * y10 + l2 * y20
                    Y[r, a, 1] -= l0 * y01 + l1 * y11 + l2 * y21
                    Y[r, a, 2] -= l0 * y02 + l1 * y12 + l2 * y22
            Di = Dinv[i]
            for a in range(3):  # L_ki = y_iᵀ D_i⁻¹ (row a of L_ki = column a of y_i times D_i⁻¹)
                ya0, ya1, ya2 = (y00, y01, y02)[a], (y10, y11, y12)[a], (y20, y21, y22)[a]
                for b in range(3):
                    Lx[pe, a, b] = ya0 * Di[0, b] + ya1 * Di[1, b] + ya2 * Di[2, b]
            for a in range(3):  # D_k -= L_ki y_i
                l0, l1, l2 = Lx[pe, a, 0], Lx[pe, a, 1], Lx[pe, a, 2]
                Dk[a, 0] -= l0 * y00 + l1 * y10 + l2 * y20
                Dk[a, 1] -= l0 * y01 + l1 * y11 + l2 * y21
                Dk[a, 2] -= l0 * y02 + l1 * y12 + l2 * y22
        if not _inv3_spd(Dk, Dinv[k]):
            bad += 1
    return bad


@njit(cache=True)
def gather_rows(k0, k1, perm, r, tmp):
    """tmp's block rows k0..k1-1 <- P r (the solves' permutation into the factor's order)."""
    for k in range(k0, k1):
        o = 3 * perm[k]
        tmp[3 * k] = r[o]
        tmp[3 * k + 1] = r[o + 1]
        tmp[3 * k + 2] = r[o + 2]


@njit(cache=True)
def scatter_rows(k0, k1, perm, tmp, z):
    """z <- Pᵀ tmp for tmp's block rows k0..k1-1 (back into the model's order)."""
    for k in range(k0, k1):
        o = 3 * perm[k]
        z[o] = tmp[3 * k]
        z[o + 1] = tmp[3 * k + 1]
        z[o + 2] = tmp[3 * k + 2]


@njit(cache=True)
def forward_column(i, p0, p1, Li, Lx, w, tmp):
    """w_r -= L_ri w_i for the entries p0..p1-1 of column i of L (the forward pass of
    ldlt_solve), w_i read from w's block i (tmp itself, or a copy kept for later rows)."""
    o = 3 * i
    w0, w1, w2 = w[o], w[o + 1], w[o + 2]
    for p in range(p0, p1):
        c = 3 * Li[p]
        tmp[c] -= Lx[p, 0, 0] * w0 + Lx[p, 0, 1] * w1 + Lx[p, 0, 2] * w2
        tmp[c + 1] -= Lx[p, 1, 0] * w0 + Lx[p, 1, 1] * w1 + Lx[p, 1, 2] * w2
        tmp[c + 2] -= Lx[p, 2, 0] * w0 + Lx[p, 2, 1] * w1 + Lx[p, 2, 2] * w2


@njit(cache=True)
def scale_by_dinv(i, Dinv, tmp):
    """u_i = D_i⁻¹ w_i in place."""
    o = 3 * i
    w0, w1, w2 = tmp[o], tmp[o + 1], tmp[o + 2]
    for a in range(3):
        tmp[o + a] = Dinv[i, a, 0] * w0 + Dinv[i, a, 1] * w1 + Dinv[i, a, 2] * w2


@njit(cache=True)
def backward_column(i, Lp, Li, Lx, tmp):
    """x_i = u_i - sum_r L_riᵀ x_r over column i (the backward pass of ldlt_solve)."""
    o = 3 * i
    u0, u1, u2 = tmp[o], tmp[o + 1], tmp[o + 2]
    for p in range(Lp[i], Lp[i + 1]):
        c = 3 * Li[p]
        x0, x1, x2 = tmp[c], tmp[c + 1], tmp[c + 2]
        u0 -= Lx[p, 0, 0] * x0 + Lx[p, 1, 0] * x1 + Lx[p, 2, 0] * x2
        u1 -= Lx[p, 0, 1] * x0 + Lx[p, 1, 1] * x1 + Lx[p, 2, 1] * x2
        u2 -= Lx[p, 0, 2] * x0 + Lx[p, 1, 2] * x1 + Lx[p, 2, 2] * x2
    tmp[o] = u0
    tmp[o + 1] = u1
    tmp[o + 2] = u2


@njit(cache=True)
def ldlt_solve(Lp, Li, Lx, Dinv, perm, tmp, r, z):
    """z = A⁻¹ r with P A Pᵀ = L D Lᵀ in 3x3 blocks (L unit block-lower without its diagonal, by
    block columns: the forward pass scatters each finished block of w down its column, the
    backward one gathers; one copy of L serves both, so each pass streams L once). The reference
    of the panels' solve (panels.panel_solve, what the preconditioner runs). tmp: (3 nb,) scratch."""
    nb = perm.shape[0]
    gather_rows(0, nb, perm, r, tmp)
    for i in range(nb):  # L w = P r, then u_i = D_i⁻¹ w_i as soon as w_i is final
        forward_column(i, Lp[i], Lp[i + 1], Li, Lx, tmp, tmp)
        scale_by_dinv(i, Dinv, tmp)
    for i in range(nb - 1, -1, -1):  # Lᵀ x = u: x_i = u_i - sum_r L_riᵀ x_r
        backward_column(i, Lp, Li, Lx, tmp)
    scatter_rows(0, nb, perm, tmp, z)


class Symbolic:
    """Everything structural about the 3x3-block LDLᵀ of a fixed CSR pattern (computed once):
    the block pattern, its ordering perm (new -> old block), L's block structure (Lp, Li), the
    per-row patterns and gather lists of ldlt_numeric_rows, flops per block row.
    groups: optional lists of 3x3-block indices ordered apart (grouped_order: one per hand)."""

    def __init__(self, indptr, indices, n, perm=None, groups=None):
        bindptr, bindices, self.blk_slots = block_pattern(indptr, indices, n)
        self.n = n
        self.nb = nb = n // 3
        # the block-row ranges factored apart (each group's, then the rest): no supernode of the
        # panels spans two (panels.py), and the postorder below stays inside each
        sizes = [len(g) for g in groups] if groups is not None and perm is None else []
        self.ranges = np.unique(np.r_[0, np.cumsum(sizes, dtype=np.int64), nb]).astype(np.int64)
        parent = np.empty(nb, np.int32)
        lnz = np.empty(nb, np.int32)
        flag = np.empty(nb, np.int32)
        if perm is not None:
            self.perm = np.asarray(perm, np.int32)
        else:
            self.perm = (grouped_order(bindptr, bindices, nb, groups) if groups is not None
                         else fill_reducing_order(bindptr, bindices, nb))
            # the same fill in an order whose elimination-tree chains are consecutive columns:
            # the panels' supernodes (any topological order of the tree factors alike)
            self.pinv = np.empty(nb, np.int32)
            self.pinv[self.perm] = np.arange(nb, dtype=np.int32)
            _symbolic_counts(nb, bindptr, bindices, self.perm, self.pinv, parent, lnz, flag)
            self.perm = self.perm[postorder(parent, self.ranges)]
        self.pinv = np.empty(nb, np.int32)
        self.pinv[self.perm] = np.arange(nb, dtype=np.int32)
        _symbolic_counts(nb, bindptr, bindices, self.perm, self.pinv, parent, lnz, flag)
        self.Lp = np.zeros(nb + 1, np.int32)
        np.cumsum(lnz, out=self.Lp[1:])
        self.nnz_L = int(self.Lp[-1])  # 3x3 blocks
        self.Li = np.zeros(self.nnz_L, np.int32)
        self.row_ptr = np.zeros(nb + 1, np.int32)
        self.row_col = np.zeros(self.nnz_L, np.int32)
        self.row_slot = np.zeros(self.nnz_L, np.int32)
        nup = (len(bindices) + nb) // 2
        self.up_ptr = np.zeros(nb + 1, np.int32)
        self.up_row = np.zeros(nup, np.int32)
        self.up_slot = np.zeros(nup, np.int32)
        self.row_flops = np.zeros(nb, np.int64)
        _symbolic_rows(nb, bindptr, bindices, self.perm, self.pinv, parent, self.Lp, self.Li,
                       self.row_ptr, self.row_col, self.row_slot, self.up_ptr, self.up_row,
                       self.up_slot, self.row_flops, flag, np.zeros(nb, np.int32),
                       np.zeros(nb, np.int32))
        self.row_flops *= 54  # one 3x3 block multiply-subtract = 27 multiply-adds
        self.flops = int(self.row_flops.sum())

    def chunks(self, count, lo=0, hi=None, keep_empty=False):
        """Row boundaries splitting rows lo..hi-1 (all by default) of the numeric factorization
        into count chunks of equal flops; empty chunks are dropped unless keep_empty (then there
        are always count + 1 boundaries: one group's share of each of count slices)."""
        hi = self.nb if hi is None else hi
        cum = np.cumsum(self.row_flops[lo:hi] + 1)
        cuts = lo + np.searchsorted(cum, cum[-1] * np.arange(1, count) / count)
        bounds = np.r_[lo, cuts, hi].astype(np.int64)
        return bounds if keep_empty else np.unique(bounds)
