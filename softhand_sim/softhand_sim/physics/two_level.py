"""Two-level preconditioner for the fine hand: Gauss-Seidel sweeps on the fine system around a
correction on the coarse hand's mesh (the `two_level` preconditioner of pcg.py).

The factor preconditioner's cost grows with its factor L (the fine hand: 75,708 3x3 blocks, a
full factorization 15-28 ms, spread over 6 steps, and CG iterating on a factor up to 12 steps
old; 12 and 24 when this was built). This one needs no factor of the fine system. One
application is a symmetric V-cycle:

  1. a forward Gauss-Seidel sweep on the fine CSR matrix A from z = 0;
  2. the residual r - A z restricted to the coarse level (Pᵀ), solved there with the coarse
     matrix A_c = Pᵀ A P (the Galerkin product, so that the correction is A's own on the coarse
     space), and prolonged back (z += P z_c);
  3. a backward Gauss-Seidel sweep.

The sweeps damp what varies from node to node, the coarse level what varies over the hand (a
finger turning about its joint, the palm moving under its bones): what neither the smoother
nor CG alone reach in few iterations. The post-sweep is the pre-sweep's adjoint, so the cycle is
a symmetric positive definite preconditioner for CG.

P interpolates the coarse tissue nodes to every fine node with the barycentric coordinates of
the coarse tet holding the fine node at rest (a fine node outside the coarse mesh: the coarse
tet nearest to holding it, its coordinates clamped to [0, 1] and normalized); the bones and
objects are the same bodies on both levels (identity). The coarse mesh is the coarse hand of
the same measures and side (handmodel: `mesh: coarse`). A_c and its LDLᵀ are computed anew
every `two_level_refresh_steps` (K) steps, spread over them as the factor preconditioner's
slices: K - 1 steps each add a slice of the fine rows to Pᵀ A P (of the values of the first
step), the K-th factors it, and the new coarse level replaces the one in use. A coarse matrix
some steps old still corrects the slow modes (fine hand, the benchmark's open-close: 12 CG
iterations a step with K = 6 or 12, 13 with 24 or 48).
"""
import numpy as np
from numba import njit, prange

from softhand_sim.physics.ldlt import block_pattern
from softhand_sim.physics.parallel import factor_solve

WEIGHT_FLOOR = 1e-9  # interpolation weights below it are round-off: none (CoarseLevel)
_U = np.uint64  # unsigned indices: numba tests a signed one for wrap-around at every gather


@njit(cache=True)
def coarse_weights(fine_x, coarse_x, coarse_tets, out_idx, out_w):
    """For each fine node, the 4 coarse nodes and weights that interpolate it: the barycentric
    coordinates in the coarse tet whose smallest coordinate is largest (the tet holding the node,
    or the nearest to holding it), clamped to >= 0 and normalized."""
    T = coarse_tets.shape[0]
    M = np.empty((T, 3, 3))  # inverse edge matrices of the coarse tets
    E = np.empty((3, 3))
    for t in range(T):
        x0 = coarse_x[coarse_tets[t, 0]]
        for c in range(3):
            xc = coarse_x[coarse_tets[t, c + 1]]
            for d in range(3):
                E[d, c] = xc[d] - x0[d]
        M[t] = np.linalg.inv(E)
    lam = np.empty(4)
    for i in range(fine_x.shape[0]):
        best, best_t = -np.inf, 0
        for t in range(T):
            x0 = coarse_x[coarse_tets[t, 0]]
            s = 0.0
            worst = np.inf
            for c in range(3):
                v = 0.0
                for d in range(3):
                    v += M[t, c, d] * (fine_x[i, d] - x0[d])
                s += v
                worst = min(worst, v)
            worst = min(worst, 1.0 - s)
            if worst > best:
                best, best_t = worst, t
        x0 = coarse_x[coarse_tets[best_t, 0]]
        s = 0.0
        for c in range(3):
            v = 0.0
            for d in range(3):
                v += M[best_t, c, d] * (fine_x[i, d] - x0[d])
            lam[c + 1] = max(v, 0.0)
            s += v
        lam[0] = max(1.0 - s, 0.0)
        total = lam.sum()
        for a in range(4):
            out_idx[i, a] = coarse_tets[best_t, a]
            out_w[i, a] = lam[a] / total


@njit(cache=True)
def galerkin_blocks(values, order, q0, q1, bptr, bind, blk_slots, pc, pw, eslot, cslot, out):
    """out += the share of the fine block rows order[q0:q1] in A_c = Pᵀ A P: every 3x3 block
    (I, J) of A adds pw[I,a] pw[J,b] A_IJ to the coarse block (pc[I,a], pc[J,b]) (eslot: its
    index among the coarse blocks; cslot: that block's 9 value indices)."""
    for q in range(q0, q1):
        I = order[q]
        for e in range(bptr[I], bptr[I + 1]):
            J = bind[e]
            for ai in range(4):
                if pc[I, ai] < 0:
                    break
                wa = pw[I, ai]
                for bi in range(4):
                    if pc[J, bi] < 0:
                        break
                    w = wa * pw[J, bi]
                    c = eslot[e, ai, bi]
                    for di in range(3):
                        for dj in range(3):
                            s = blk_slots[e, di, dj]
                            if s >= 0:
                                out[cslot[c, di, dj]] += w * values[s]


@njit(parallel=True, cache=True)
def galerkin_by_hand(values, order, lo, hi, bptr, bind, blk_slots, pc, pw, eslot, cslot, out):
    """galerkin_blocks over order[lo[h]:hi[h]] of every hand h at once: a hand's fine rows add
    only into its own coarse rows (P maps a hand's blocks to its own coarse blocks)."""
    for h in prange(lo.shape[0]):
        galerkin_blocks(values, order, lo[h], hi[h], bptr, bind, blk_slots, pc, pw, eslot, cslot, out)


@njit(cache=True, inline="always")
def _row_dot(values, indices, x, k0, k1):
    """sum of values[k] x[indices[k]] for k in k0..k1-1 (as pcg.csr_matvec)."""
    acc = 0.0
    for k in range(_U(k0), _U(k1)):
        acc += values[k] * x[_U(indices[k])]
    return acc


@njit(cache=True)
def _forward_rows(indptr, indices, values, diag_slot, r, z, i0, i1):
    """Forward Gauss-Seidel over rows i0..i1-1 from z = 0: each row's lower part only (its
    columns are sorted, the diagonal at diag_slot)."""
    for i in range(i0, i1):
        d = diag_slot[i]
        z[i] = (r[i] - _row_dot(values, indices, z, indptr[i], d)) / values[d]


@njit(cache=True)
def _upper_rows(indptr, indices, values, diag_slot, z, t, i0, i1):
    """t = r - A z over rows i0..i1-1 after the forward sweep: each row's lower part and diagonal
    were solved exactly by it, so only the strictly upper part is left (half a product)."""
    for i in range(i0, i1):
        t[i] = -_row_dot(values, indices, z, diag_slot[i] + 1, indptr[i + 1])


@njit(cache=True)
def _backward_rows(indptr, indices, values, diag_slot, r, z, i0, i1):
    """Backward Gauss-Seidel over rows i1-1 down to i0."""
    for i in range(i1 - 1, i0 - 1, -1):
        d = diag_slot[i]
        s = _row_dot(values, indices, z, indptr[i], d) + _row_dot(values, indices, z, d + 1, indptr[i + 1])
        z[i] = (r[i] - s) / values[d]


@njit(cache=True)
def _restrict(t, pc, pw, rc, I0, I1):
    """rc += Pᵀ t over the fine blocks I0..I1-1."""
    for I in range(I0, I1):
        for a in range(4):
            c = pc[I, a]
            if c < 0:
                break
            w = pw[I, a]
            for e in range(3):
                rc[3 * c + e] += w * t[3 * I + e]


@njit(cache=True)
def _prolong(zc, pc, pw, z, I0, I1):
    """z += P z_c over the fine blocks I0..I1-1."""
    for I in range(I0, I1):
        for a in range(4):
            c = pc[I, a]
            if c < 0:
                break
            w = pw[I, a]
            for e in range(3):
                z[3 * I + e] += w * zc[3 * c + e]


@njit(cache=True)
def v_cycle(indptr, indices, values, diag_slot, r, z, pc, pw, fac, t, rc, zc):
    """z <- the two-level preconditioner applied to r (see the module docstring). pc, pw: P by
    blocks (CoarseLevel); fac: the coarse factor (pcg.Factor.arrays, one thread); t: (n,) and
    rc, zc: (nc,) scratch. CoarseLevel.arrays holds pc..zc in this order."""
    n = r.shape[0]
    _forward_rows(indptr, indices, values, diag_slot, r, z, 0, n)
    _upper_rows(indptr, indices, values, diag_slot, z, t, 0, n)
    rc[:] = 0.0
    _restrict(t, pc, pw, rc, 0, pc.shape[0])
    factor_solve(fac, rc, zc)
    _prolong(zc, pc, pw, z, 0, pc.shape[0])
    _backward_rows(indptr, indices, values, diag_slot, r, z, 0, n)


@njit(parallel=True, cache=True)
def v_cycle_by_hand(indptr, indices, values, diag_slot, r, z, pc, pw, fac, t, rc, zc, rows):
    """v_cycle with each hand's part on a core of its own: rows[h] = (first node DOF, end, first
    bone DOF, end) of hand h, the objects' rows from the last hand's bones on (one thread). The
    same result as v_cycle: no matrix entry couples two hands (model.py); a hand's rows see the
    objects' only above the diagonal, which the forward sweep from zero leaves out and the
    backward one reads after the objects' rows are done; a hand's fine blocks restrict to and
    prolong from its own coarse blocks (and the objects'). The coarse factor is grouped by hand
    (fac: a Factor with groups and threads: its panels solve by hand too)."""
    n = r.shape[0]
    H = rows.shape[0]
    shared = rows[H - 1, 3]
    for h in prange(H):
        _forward_rows(indptr, indices, values, diag_slot, r, z, rows[h, 0], rows[h, 1])
        _forward_rows(indptr, indices, values, diag_slot, r, z, rows[h, 2], rows[h, 3])
    _forward_rows(indptr, indices, values, diag_slot, r, z, shared, n)
    rc[:] = 0.0
    for h in prange(H):
        _upper_rows(indptr, indices, values, diag_slot, z, t, rows[h, 0], rows[h, 1])
        _upper_rows(indptr, indices, values, diag_slot, z, t, rows[h, 2], rows[h, 3])
        _restrict(t, pc, pw, rc, rows[h, 0] // 3, rows[h, 1] // 3)
        _restrict(t, pc, pw, rc, rows[h, 2] // 3, rows[h, 3] // 3)
    _upper_rows(indptr, indices, values, diag_slot, z, t, shared, n)
    _restrict(t, pc, pw, rc, shared // 3, n // 3)
    factor_solve(fac, rc, zc)
    for h in prange(H):  # every row corrected before the objects' rows start the backward sweep
        _prolong(zc, pc, pw, z, rows[h, 0] // 3, rows[h, 1] // 3)
        _prolong(zc, pc, pw, z, rows[h, 2] // 3, rows[h, 3] // 3)
    _prolong(zc, pc, pw, z, shared // 3, n // 3)
    _backward_rows(indptr, indices, values, diag_slot, r, z, shared, n)
    for h in prange(H):
        _backward_rows(indptr, indices, values, diag_slot, r, z, rows[h, 2], rows[h, 3])
        _backward_rows(indptr, indices, values, diag_slot, r, z, rows[h, 0], rows[h, 1])


def coarse_mesh_of(asset):
    """(nodes, tets) of the coarse hand with the same measures and side as `asset` (cached,
    morphed or built like any hand: handmodel.cache)."""
    from softhand_sim.handmodel import load_or_build_hand
    from softhand_sim.handmodel.measures import as_measures
    coarse = load_or_build_hand(as_measures(asset.measures), side=asset.side, resolution="coarse")
    return np.asarray(coarse.tet_nodes, np.float64), np.asarray(coarse.tets, np.int32)


class CoarseLevel:
    """The coarse level of the two-level preconditioner for a Model: the prolongation P (by 3x3
    blocks: each fine block's up to 4 coarse blocks and weights), the pattern of A_c = Pᵀ A P,
    and its LDLᵀ (pcg.Factor, one slice: refreshed whole by refresh()).

    coarse_meshes: one (nodes (Nc,3), tets (Tc,4)) per hand of the model, in model.hands order,
    at rest in the same frame as that hand's fine nodes. refresh_steps: K of the sliced refresh
    (advance). threads > 1 with several hands: each hand's part of the V-cycle and of the
    Galerkin product on a core of its own (v_cycle_by_hand, galerkin_by_hand)."""

    def __init__(self, model, coarse_meshes, refresh_steps=12, threads=1):
        from softhand_sim.physics.pcg import Factor
        hands = model.hands
        if len(coarse_meshes) != hands.count:
            raise ValueError(f"{len(coarse_meshes)} coarse mesh(es) for {hands.count} hand(s)")
        N, B, n = model.node_count, model.body_count, model.dof_count
        if model.body_dof0 != 3 * N or n != 3 * N + 6 * B:
            raise ValueError(f"unexpected DOF layout: {n} DOFs for {N} nodes and {B} bodies")
        self.refresh_steps = int(refresh_steps)
        if self.refresh_steps < 1:
            raise ValueError(f"refresh_steps={refresh_steps}: must be >= 1")
        by_hand = threads > 1 and hands.count > 1
        cnode0 = self._prolongation(model, coarse_meshes)
        self._coarse_pattern(model)
        groups = None
        if by_hand:  # each hand's coarse blocks (its coarse nodes, its bones) ordered apart
            Nc = self.coarse_nodes
            groups = [np.concatenate([np.arange(cnode0[h], cnode0[h + 1]),
                                      Nc + np.arange(2 * hands.bone0[h], 2 * hands.bone0[h + 1])])
                      for h in range(hands.count)]
        self.factor = Factor(self.n, self.indptr, self.indices, max_slices=1, groups=groups,
                             threads=threads if by_hand else 1)
        self._slices(model, by_hand)
        self.valid = False
        self._phase = 0
        sliced = self.refresh_steps > 1
        self._snap = np.zeros(len(model.indices)) if sliced else None  # the fine values being sliced
        self._next = np.zeros(len(self.indices)) if sliced else None    # their A_c, slice by slice
        self.scratch = (np.zeros(n), np.zeros(self.n), np.zeros(self.n))
        # each hand's rows for v_cycle_by_hand (node DOFs, bone DOFs); one row of zeros: v_cycle
        self.rows = np.zeros((1, 4), np.int64)
        if by_hand:
            b0 = model.body_dof0
            self.rows = np.array([(3 * hands.node0[h], 3 * hands.node0[h + 1],
                                   b0 + 6 * hands.bone0[h], b0 + 6 * hands.bone0[h + 1])
                                  for h in range(hands.count)], np.int64)

    def _prolongation(self, model, coarse_meshes):
        """P by 3x3 blocks: pc (nb, 4) the coarse blocks of each fine block (-1: none), pw their
        weights. Blocks: fine nodes 0..N-1, then 2 per body; coarse nodes 0..Nc-1 (the hands' in
        turn, those no fine node uses left out), then the same bodies. Returns each hand's first
        coarse node (H + 1,)."""
        hands, N, B = model.hands, model.node_count, model.body_count
        fine_idx = np.full((N, 4), -1, np.int32)
        fine_w = np.zeros((N, 4))
        ends = [0]
        for h, (cx, ct) in enumerate(coarse_meshes):
            nodes = hands.nodes(h)
            idx = np.empty((nodes.stop - nodes.start, 4), np.int32)
            coarse_weights(np.ascontiguousarray(model.node_rest[nodes]), np.ascontiguousarray(cx, np.float64),
                           np.ascontiguousarray(ct, np.int32), idx, fine_w[nodes])
            fine_idx[nodes] = idx + ends[-1]
            ends.append(ends[-1] + len(cx))
        # a weight of round-off size (a fine node on a coarse tet's face or vertex) would make its
        # coarse node a column of P that is all but zero, and A_c singular: such weights are none
        fine_w[fine_w < WEIGHT_FLOOR] = 0.0
        fine_w /= fine_w.sum(1, keepdims=True)
        # coarse nodes no fine node depends on would be empty rows of A_c: leave them out
        used = np.zeros(ends[-1], bool)
        used[fine_idx[fine_w > 0.0]] = True
        renum = np.cumsum(used) - 1
        fine_idx = np.where(fine_w > 0.0, renum[fine_idx], -1).astype(np.int32)
        first = np.argsort(fine_idx < 0, axis=1, kind="stable")  # the used entries first
        self.coarse_nodes = Nc = int(used.sum())
        self.pc = np.full((N + 2 * B, 4), -1, np.int32)
        self.pw = np.zeros((N + 2 * B, 4))
        self.pc[:N] = np.take_along_axis(fine_idx, first, 1)
        self.pw[:N] = np.take_along_axis(fine_w, first, 1)
        self.pc[N:, 0] = Nc + np.arange(2 * B, dtype=np.int32)
        self.pw[N:, 0] = 1.0
        return np.array([int(used[:e].sum()) for e in ends])

    def _coarse_pattern(self, model):
        """The pattern of A_c, every (pc[I,a], pc[J,b]) of every fine block (I, J), as a scalar CSR
        whose 3x3 blocks are complete (row 3a+d holds block row a's blocks, 3 entries each), and
        for galerkin_blocks each fine block's coarse blocks (eslot) and their value indices (cslot)."""
        n, nbf, nbc = model.dof_count, len(self.pc), self.coarse_nodes + 2 * model.body_count
        self.bptr, self.bind, self.blk_slots = block_pattern(model.indptr, model.indices, n)
        rows = np.repeat(np.arange(nbf), np.diff(self.bptr))
        pa = self.pc[rows][:, :, None]
        pb = self.pc[self.bind][:, None, :]
        valid = (pa >= 0) & (pb >= 0)
        keys = np.where(valid, pa.astype(np.int64) * nbc + pb, -1)
        ukeys = np.unique(keys[valid])
        self.eslot = np.where(valid, np.searchsorted(ukeys, keys), -1).astype(np.int32)
        crow, ccol = ukeys // nbc, ukeys % nbc
        cbptr = np.zeros(nbc + 1, np.int64)
        np.add.at(cbptr, crow + 1, 1)
        cbptr = np.cumsum(cbptr)
        self.indptr = np.zeros(3 * nbc + 1, np.int32)
        self.indptr[1:] = np.cumsum(np.repeat(3 * np.diff(cbptr), 3))
        self.indices = np.empty(int(self.indptr[-1]), np.int32)
        self.cslot = np.empty((len(ukeys), 3, 3), np.int32)
        q_in_row = np.arange(len(ukeys)) - cbptr[crow]
        for d in range(3):
            start = self.indptr[3 * crow + d] + 3 * q_in_row
            for e in range(3):
                self.indices[start + e] = 3 * ccol + e
                self.cslot[:, d, e] = start + e
        self.n = 3 * nbc
        self.values = np.zeros(len(self.indices))

    def _slices(self, model, by_hand):
        """The sliced refresh's K - 1 slices of every hand's fine block rows, of equal work: order
        (each hand's node and bone blocks in turn, then the objects' from `shared` on, added with
        the last slice on one thread) and slice_bounds[s, h], positions in order."""
        hands, N, nbf = model.hands, model.node_count, len(self.pc)
        if by_hand:
            bodies = N + 2 * np.asarray(hands.bone0)
            per_hand = [np.r_[hands.node0[h]:hands.node0[h + 1], bodies[h]:bodies[h + 1]]
                        for h in range(hands.count)]
            self.order = np.concatenate(per_hand + [np.arange(bodies[-1], nbf)]).astype(np.int64)
            starts = np.r_[0, np.cumsum([len(blocks) for blocks in per_hand])]
        else:
            self.order, starts = np.arange(nbf, dtype=np.int64), np.array([0, nbf])
        self.shared = int(starts[-1])
        rows = np.repeat(np.arange(nbf), np.diff(self.bptr))
        entries = (self.pc >= 0).sum(1)
        work = np.zeros(nbf)
        np.add.at(work, rows, entries[rows] * entries[self.bind])
        S = max(self.refresh_steps - 1, 1)
        self.slice_bounds = np.empty((S + 1, len(starts) - 1), np.int64)
        for h in range(len(starts) - 1):
            cum = np.cumsum(work[self.order[starts[h]:starts[h + 1]]])
            cuts = np.searchsorted(cum, cum[-1] * np.arange(1, S) / S) if len(cum) else np.zeros(S - 1, int)
            self.slice_bounds[:, h] = np.r_[0, cuts, starts[h + 1] - starts[h]] + starts[h]

    def _galerkin(self, values, s, out):
        """Add slice s of every hand (all of them: s None) and, with the last slice, the objects'."""
        b = self.slice_bounds
        lo, hi = (b[0], b[-1]) if s is None else (b[s], b[s + 1])
        args = (self.bptr, self.bind, self.blk_slots, self.pc, self.pw, self.eslot, self.cslot, out)
        if len(lo) > 1:
            galerkin_by_hand(values, self.order, lo, hi, *args)
        else:
            galerkin_blocks(values, self.order, int(lo[0]), int(hi[0]), *args)
        if s is None or s == len(b) - 2:
            galerkin_blocks(values, self.order, self.shared, len(self.order), *args)

    def refresh(self, values):
        """A_c = Pᵀ A P of the fine values now, and its factor, in use from now on (the first step,
        or on demand); a sliced refresh under way starts over."""
        self.values[:] = 0.0
        self._galerkin(values, None, self.values)
        self.factor.refresh(self.indptr, self.indices, self.values)
        self.valid = True
        self._phase = 0

    def advance(self, values):
        """This step's share of the next coarse level (see the module docstring). Returns True
        when a new one replaced the one in use."""
        K = self.refresh_steps
        if K == 1:
            self.refresh(values)
            return True
        ph = self._phase
        if ph == 0:
            self._snap[:] = values
            self._next[:] = 0.0
        if ph < K - 1:
            self._galerkin(self._snap, ph, self._next)
            self._phase += 1
            return False
        self.values, self._next = self._next, self.values
        self.factor.refresh(self.indptr, self.indices, self.values)
        self._phase = 0
        return True

    @property
    def arrays(self):
        """The tuple pcg passes to v_cycle_by_hand (after the fine matrix): P, the coarse factor's
        arrays, scratch and the hands' rows (v_cycle takes the first 6, one thread: rows has one
        row)."""
        t, rc, zc = self.scratch
        return (self.pc, self.pw, self.factor.arrays, t, rc, zc, self.rows)

    def prolongation(self):
        """P as a scipy CSR matrix (fine DOFs x coarse DOFs), for checks."""
        import scipy.sparse as sp
        rows, cols, vals = [], [], []
        for d in range(3):
            I, a = np.nonzero(self.pc >= 0)
            rows.append(3 * I + d)
            cols.append(3 * self.pc[I, a] + d)
            vals.append(self.pw[I, a])
        return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(3 * len(self.pc), self.n))
