"""The factor's L in dense panels for the preconditioner's triangular solves (pcg.Factor).

Applying the factor preconditioner, z = Pᵀ L⁻ᵀ D⁻¹ L⁻¹ P r, is most of a CG iteration (the fine
hand: 0.31 of 0.42 ms). Column by column (ldlt.ldlt_solve) every 3x3 block of L costs an index
load, a gather of three entries of the vector and nine scalar multiply-adds: the loop runs at
about a block per 4 ns whatever the memory does. Columns of L that share their rows below
(supernodes: an elimination-tree chain whose columns each have the next one's rows plus that
column) form a dense panel: rows = the supernode's own block columns (a unit lower triangle)
then the rows R below, stored column-major. The forward pass then updates R with three columns
at a time in a contiguous, vectorized loop and scatters into the vector once per panel row,
not once per block; the backward pass gathers R once and takes three dot products per block
column. Measured on the fine hand: 0.31 -> 0.15 ms per solve (float32 panels; 0.20 in float64).

The supernodes come from the ordering (ldlt.Symbolic postorders the elimination tree, which
makes chains consecutive columns: 1,133 fundamental supernodes of the fine hand's 1,971 block
columns in MMD order, then fewer after) and are relaxed: a supernode takes in the next one
(its last column's parent) while the panel stays mostly entries of L (at most ZERO_SHARE
explicit zeros, or any share up to NARROW block columns), so few single-column panels are left.
No supernode crosses a range boundary (a hand's rows, the shared rows of the objects): the
hands' panels solve on their own cores (parallel.panel_solve_by_group).

Panels hold L in float32 when they are large (more than F64_PANEL_VALUES values: the fine
hand's, 1.2 million): float32 halves the bytes streamed per solve, 0.20 -> 0.15 ms, and the fine
hand's open-close runs at 203-210 steps/s against 172-175 with float64 panels. The products and
sums run in float64; the preconditioner is then the exact inverse of L' D L'ᵀ, L' = L rounded to
float32 (relative 6e-8 per entry): symmetric positive definite as before. It is a little less
exact: a step that converges in one CG iteration on a fresh float64 factor takes two (the fine
press: 663-671 steps/s against 717-748). Small panels (the coarse hand's, 70,000 values, two
coarse hands' 150,000) stay float64: they sit in the second-level caches, where float32 saves
no time and would cost the coarse press and grasp that second iteration. The factorization
itself is float64 (ldlt.ldlt_numeric_rows).
"""
import numpy as np
from numba import njit

from softhand_sim.physics.ldlt import gather_rows, scale_by_dinv, scatter_rows

F64_PANEL_VALUES = 500_000  # panels up to this many values (4 MB in float64) stay float64
ZERO_SHARE = 0.2   # a relaxed supernode's panel: at most this share explicit zeros ...
NARROW = 4         # ... or any share while it is at most this many block columns wide
# the vectorized loops' floating-point freedoms: reassociate sums (vector partial sums) and fuse
# multiply-adds; NaN and infinity keep their meaning (the guard downstream tests for them)
_FAST = {"reassoc", "contract", "nsz"}
_U = np.uint64  # unsigned indices: numba tests a signed one for wrap-around at every gather


def relaxed_supernodes(Lp, Li, ranges):
    """Block column bounds (S+1,) int64 of the supernodes of L (columns by Lp/Li, strictly lower,
    rows ascending): fundamental supernodes, then each merged with the next while the next starts
    at its last column's parent and the merged panel holds at most ZERO_SHARE zeros or is at most
    NARROW columns wide. ranges: block-row bounds no supernode may span (a hand's rows)."""
    Lp = np.asarray(Lp, np.int64)
    nb = len(Lp) - 1
    count = np.diff(Lp)
    cut = np.zeros(nb + 1, bool)
    cut[np.asarray(ranges, np.int64)] = True
    parent = np.full(nb, -1, np.int64)
    has = count > 0
    parent[has] = np.asarray(Li, np.int64)[Lp[:-1][has]]
    # column j+1 continues j's fundamental supernode: j's rows are j+1 and j+1's rows
    chain = np.zeros(nb, bool)
    chain[1:] = (parent[:-1] == np.arange(1, nb)) & (count[:-1] == count[1:] + 1)
    fundamental = np.flatnonzero(~chain[:nb] | cut[:nb])
    starts = [0]
    for k in range(1, len(fundamental)):
        b = int(fundamental[k])
        c = int(fundamental[k + 1]) if k + 1 < len(fundamental) else nb
        a = starts[-1]
        merge = not cut[b] and parent[b - 1] == b
        if merge:
            w = c - a
            dense = w * (w - 1) // 2 + w * int(count[c - 1])
            zeros = 1.0 - float(Lp[c] - Lp[a]) / max(dense, 1)
            merge = w <= NARROW or zeros <= ZERO_SHARE
        if not merge:
            starts.append(b)
    starts.append(nb)
    return np.asarray(starts, np.int64)


@njit(cache=True)
def _layout(Lp, Li, starts, rptr, rows, off, dst, col_len, pos):
    """rows (the R part of every panel, by rptr), off (each panel's first value), dst (each block
    of L: the index of its (0, 0) entry in the panels) and col_len (its panel's column length:
    entry (a, b) at dst + b col_len + a). pos: (nb,) scratch."""
    S = starts.shape[0] - 1
    for s in range(S):
        j0, j1 = starts[s], starts[s + 1]
        w = j1 - j0
        q0 = rptr[s]
        for k in range(Lp[j1 - 1], Lp[j1]):  # the last column's rows: every column's below the panel
            rows[q0 + k - Lp[j1 - 1]] = Li[k]
            pos[Li[k]] = w + k - Lp[j1 - 1]
        for j in range(j0, j1):
            pos[j] = j - j0
        n = 3 * (w + rptr[s + 1] - q0)
        off[s + 1] = off[s] + n * 3 * w
        for j in range(j0, j1):
            for p in range(Lp[j], Lp[j + 1]):
                dst[p] = off[s] + 3 * (j - j0) * n + 3 * pos[Li[p]]
                col_len[p] = n


class Panels:
    """The panel layout of one factor's L (computed once per pattern, with the symbolic
    factorization): starts (S+1) block-column bounds of the supernodes, rptr/rows their rows
    below, off their offsets into the panel values, size the values' count and dtype their type,
    longest the longest panel column (the solves' scratch), dst/col_len where each block of L goes
    (to_panels)."""

    def __init__(self, Lp, Li, ranges):
        self.starts = relaxed_supernodes(Lp, Li, ranges)
        Lp = np.asarray(Lp, np.int64)
        S = len(self.starts) - 1
        last = self.starts[1:] - 1
        self.rptr = np.zeros(S + 1, np.int64)
        np.cumsum(Lp[last + 1] - Lp[last], out=self.rptr[1:])
        self.rows = np.zeros(int(self.rptr[-1]), np.int64)
        self.off = np.zeros(S + 1, np.int64)
        self.dst = np.zeros(int(Lp[-1]), np.int64)
        self.col_len = np.zeros(int(Lp[-1]), np.int64)
        _layout(Lp, np.asarray(Li, np.int64), self.starts, self.rptr, self.rows, self.off, self.dst,
                self.col_len, np.zeros(len(Lp) - 1, np.int64))
        self.size = int(self.off[-1])
        self.dtype = np.float64 if self.size <= F64_PANEL_VALUES else np.float32
        widths = np.diff(self.starts)
        self.longest = int(3 * (widths + np.diff(self.rptr)).max()) if S else 0
        self.count = S

    def supernode_at(self, block_row):
        """The index of the supernode starting at block_row (a range bound)."""
        s = int(np.searchsorted(self.starts, block_row))
        if self.starts[s] != block_row:
            raise ValueError(f"block row {block_row} does not start a supernode")
        return s


@njit(cache=True)
def to_panels(Lx, dst, col_len, values):
    """values <- L (Lx: (nnzL, 3, 3) blocks by columns) in the panels' layout (entries not in L
    stay as they are: zero)."""
    for p in range(Lx.shape[0]):
        d, n = dst[p], col_len[p]
        for b in range(3):
            for a in range(3):
                values[d + b * n + a] = Lx[p, a, b]


@njit(cache=True, inline="always")
def _panel(s, starts, rptr, off):
    """Panel s: its first block column j0, first vector entry o, width W and column length n in
    scalars, first row index q0 into rows, first value base."""
    j0 = starts[s]
    W = _U(3 * (starts[s + 1] - j0))
    q0 = rptr[s]
    return j0, _U(3 * j0), W, q0, W + _U(3 * (rptr[s + 1] - q0)), _U(off[s])


@njit(cache=True, fastmath=_FAST)
def panel_forward(s0, s1, starts, rptr, rows, off, values, Dinv, tmp, u, shared, acc):
    """The forward pass over supernodes s0..s1-1: L w = tmp in place, then tmp_j = D_j⁻¹ w_j.
    Each panel's columns are copied into u with zeros for its rows below, updated three columns
    (one block column) at a time down the panel, and the rows below added into tmp, or into acc
    (acc[3 (row - shared) + a]) for rows >= shared: rows another core's panels write too."""
    one, two, three = _U(1), _U(2), _U(3)
    for s in range(s0, s1):
        j0, o, W, q0, n, base = _panel(s, starts, rptr, off)
        for i in range(W):
            u[i] = tmp[o + i]
        for i in range(W, n):
            u[i] = 0.0
        for c in range(0, W, 3):
            c = _U(c)
            v0, v1, v2 = u[c], u[c + one], u[c + two]
            f0 = base + c * n
            f1 = f0 + n
            f2 = f1 + n
            for i in range(c + three, n):
                u[i] -= values[f0 + i] * v0 + values[f1 + i] * v1 + values[f2 + i] * v2
        for i in range(W):
            tmp[o + i] = u[i]
        for q in range(q0, rptr[s + 1]):
            k = W + _U(3 * (q - q0))
            row = rows[q]
            if row < shared:
                t = _U(3 * row)
                tmp[t] += u[k]
                tmp[t + one] += u[k + one]
                tmp[t + two] += u[k + two]
            else:
                t = _U(3 * (row - shared))
                acc[t] += u[k]
                acc[t + one] += u[k + one]
                acc[t + two] += u[k + two]
        for j in range(j0, starts[s + 1]):
            scale_by_dinv(j, Dinv, tmp)


@njit(cache=True, fastmath=_FAST)
def panel_backward(s0, s1, starts, rptr, rows, off, values, tmp, u):
    """The backward pass Lᵀ x = tmp in place over supernodes s1-1 down to s0 (the rows below
    each panel already final): x_c = u_c - (column c of the panel below c) . x."""
    one, two, three = _U(1), _U(2), _U(3)
    for s in range(s1 - 1, s0 - 1, -1):
        j0, o, W, q0, n, base = _panel(s, starts, rptr, off)
        for i in range(W):
            u[i] = tmp[o + i]
        for q in range(q0, rptr[s + 1]):
            t = _U(3 * rows[q])
            k = W + _U(3 * (q - q0))
            u[k] = tmp[t]
            u[k + one] = tmp[t + one]
            u[k + two] = tmp[t + two]
        c = W
        while c > 0:
            c -= three
            f0 = base + c * n
            f1 = f0 + n
            f2 = f1 + n
            a0 = 0.0
            a1 = 0.0
            a2 = 0.0
            for i in range(c + three, n):
                ui = u[i]
                a0 += values[f0 + i] * ui
                a1 += values[f1 + i] * ui
                a2 += values[f2 + i] * ui
            u[c] -= a0
            u[c + one] -= a1
            u[c + two] -= a2
        for i in range(W):
            tmp[o + i] = u[i]


@njit(cache=True)
def panel_solve(starts, rptr, rows, off, values, Dinv, perm, tmp, u, r, z):
    """z = A⁻¹ r with P A Pᵀ = L D Lᵀ, L in panels (one thread). tmp: (3 nb,), u: (longest,)
    scratch."""
    nb = perm.shape[0]
    S = starts.shape[0] - 1
    gather_rows(0, nb, perm, r, tmp)
    # every row is below nb: nothing goes to an accumulator (u stands in for one, never written)
    panel_forward(0, S, starts, rptr, rows, off, values, Dinv, tmp, u, nb, u)
    panel_backward(0, S, starts, rptr, rows, off, values, tmp, u)
    scatter_rows(0, nb, perm, tmp, z)
