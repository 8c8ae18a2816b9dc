"""Preconditioned conjugate gradient over the fixed CSR pattern (Sect. 3.1: warm start, tol 1e-5,
iteration cap). All compiled; scratch arrays are owned by the caller and reused every step.

Preconditioners:
  PRECOND_JACOBI        the paper's: inverse diagonal
  PRECOND_BLOCK_JACOBI  inverse 3x3 node blocks and 6x6 rigid-body blocks
  PRECOND_FACTOR        a sparse LDLᵀ of a recent M + dt^2 H (default; ldlt.py, its solves in dense
                        panels: panels.py), refreshed in equal slices every step: the stiff
                        bone-tissue and joint springs couple bones and nodes, which only a
                        factorization captures (Jacobi hits the iteration cap)
  PRECOND_TWO_LEVEL     Gauss-Seidel sweeps around a Galerkin correction on the coarse hand's mesh
                        (two_level.py): no factor of the fine system, for the fine hand
"""
import numpy as np
from numba import njit, prange

from softhand_sim.physics.panels import Panels, to_panels
from softhand_sim.physics.parallel import factor_rows_by_group, factor_solve
from softhand_sim.physics.two_level import v_cycle, v_cycle_by_hand

PRECOND_JACOBI = 0
PRECOND_BLOCK_JACOBI = 1
PRECOND_FACTOR = 2
PRECOND_TWO_LEVEL = 3
SLICES_PER_ITERATION = 0.095  # a factorization's slices per CG iteration it costs (Factor.analyse)


class Factor:
    """LDLᵀ of M + dt² H (ldlt.py: ordering and symbolic analysis once per pattern) used as the
    PCG preconditioner, refreshed in equal slices: each step factors 1/K of the
    rows of a snapshot of the matrix (K from a cost model, or so a slice is `slice_flops`), and when the
    last slice is done the new factor replaces the one in use. Every slice costs the same small
    time (no refactorization spikes). The solver starts the next factorization when the last is
    done, or keeps the factor in use for a while first when CG still converges fast on it
    (factor_hold.py; without that, the factor in use is at most 2K steps old, and K = 1 is the
    factor of the current matrix, every step); it runs two slices per step after a CG that needed
    many iterations, and a whole factorization (refresh) after one that needed very many.

    With threads > 1 and groups (one per hand), each slice factors every group's share of it
    in parallel and the solves run the groups in parallel (parallel.py); the shared rows (the
    objects) stay on one thread, at the end of the last slice and between the solves' passes.

    With background (factor_background) and K > 1, the factorizations run whole, one after the
    other, on a thread of their own (the kernel releases the GIL): a step never factors, and
    each factor comes into use at the first step after it is done, on the step's core. The hold
    and the two slices a step do not apply there.

    arrays: the tuple pcg() passes to the triangular solves (the factor in use; its last three
    entries are empty on one thread)."""

    def __init__(self, n, indptr=None, indices=None, slice_flops=None, max_slices=50, groups=None,
                 threads=1, cost_scale=1.0, background=False):
        self.n = n
        self.background = bool(background)  # factorizations on a thread of their own (analyse)
        self._threaded = False  # ... when there is a factorization spread over steps (analyse)
        self._next = 0
        self._job = self._pool = self._started = None
        self.valid = False
        self.sym = None
        nb = n // 3
        # no factor yet: arrays of the types factor_solve takes (pcg compiles once for them)
        self._serial = (np.zeros(0, np.int64), np.zeros((1, 0)), np.zeros((1, 0)))
        i0 = np.zeros(1, np.int64)
        self.arrays = (i0, i0, np.zeros(0, np.int64), i0, np.zeros(0),
                       np.tile(np.eye(3), (nb, 1, 1)), np.arange(nb, dtype=np.int32), np.zeros(n),
                       np.zeros(0)) + self._serial
        self.slice_flops, self.max_slices = slice_flops, max_slices
        self.iterations_per_factor = 0.0  # a factorization's cost in CG iterations (analyse)
        self.cost_scale = float(cost_scale)  # ... times the estimate (factor_cost_scale)
        if not self.cost_scale > 0.0:
            raise ValueError(f"cost_scale={cost_scale}: must be > 0")
        self.groups = groups  # block groups ordered apart (ldlt.grouped_order): one per hand
        self.threads = int(threads)
        if self.threads < 1:
            raise ValueError(f"threads={threads}: must be >= 1")
        if indptr is not None:
            self.analyse(indptr, indices)

    def analyse(self, indptr, indices):
        """Ordering, symbolic factorization and the slice boundaries (once per pattern)."""
        from softhand_sim.physics.ldlt import Symbolic
        self.indptr, self.indices = indptr, indices
        self.sym = sym = Symbolic(indptr, indices, self.n, groups=self.groups)
        self.nnz = sym.nnz_L
        self.panels = pn = Panels(sym.Lp, sym.Li, sym.ranges)  # L as the solves read it (panels.py)
        # the factor F and one CG iteration c (the panels' solve + the matvec) estimated from
        # their sizes and the speeds these kernels run at (the factor 11.6 GFlop/s after ~50 µs of
        # its own; the solves stream 12 panel values per ns plus ~37 ns per panel; the
        # matvec 4 GFlop/s): F / c is what a factorization costs in iterations, the factor_hold
        # rule's unit (factor_hold.py) and the slices' count below. Fitted to `softhand bench
        # --profile`'s factor_cost on this machine (one and two hands, coarse and fine, free,
        # press and grasp: the estimate 0.88-1.10 times the measured ratio): a factorization 9
        # iterations of the coarse hand, 58-66 of the fine one (docs/MEASUREMENTS.md, "The
        # factor's cost measured", "Triangular solves in panels")
        t_factor = 5e-5 + sym.flops / 11.6e9
        t_iter = 0.081e-9 * pn.size + 37e-9 * pn.count + 2.0 * len(indices) / 4e9
        # (on a machine whose kernels run at other speeds, factor_cost_scale corrects it)
        self.iterations_per_factor = self.cost_scale * t_factor / t_iter
        if self.slice_flops is None:
            # K slices: a factor at most 2K steps old and CG's iterations on it growing with K,
            # against F/K a step. Measured on the fine hand (free, press, grasp; K = 4, 5, 6, 8,
            # 11; two runs each): K = 6 the lowest mean step over both runs (free: 5.8-5.9 ms; K =
            # 4 5.7-6.5 with a p99 of 15-18 ms against 12-13), and the rule puts the fine hand
            # there and the coarse one at K = 1 (9 iterations: 0.86)
            want = int(SLICES_PER_ITERATION * self.iterations_per_factor)  # rounded down
        else:
            want = int(np.ceil(sym.flops / self.slice_flops))
        self.slices = int(np.clip(want, 1, self.max_slices))
        self.bounds = sym.chunks(self.slices)
        self.slices = len(self.bounds) - 1
        self.by_group = self.threads > 1 and self.groups is not None and len(self.groups) > 1
        if self.by_group:
            gb = np.cumsum([0] + [len(g) for g in self.groups]).astype(np.int64)
            # slice s factors rows group_bounds[s, h]:group_bounds[s + 1, h] of every group h
            self.group_bounds = np.stack([sym.chunks(self.slices, int(gb[h]), int(gb[h + 1]),
                                                     keep_empty=True)
                                          for h in range(len(gb) - 1)], axis=1)
            self.shared_rows = int(gb[-1])
            # the solves: each group's supernodes, then the shared rows' (panels never span two)
            sb = np.array([pn.supernode_at(int(b)) for b in gb] + [pn.count], np.int64)
            groups = len(gb) - 1
            self._by_group = (sb, np.zeros((groups, 3 * (sym.nb - self.shared_rows))),
                              np.zeros((groups, pn.longest)))
        # the factorization writes L and D into its own buffers (over several steps when it is
        # sliced, from a snapshot of the values); the solves read the factor published last: L
        # copied into the panels and D⁻¹ into their own array. One factored within a step (one
        # slice: the coarse hand's) reads the values themselves, no snapshot
        self._L = np.zeros((sym.nnz_L, 3, 3))
        self._D = np.tile(np.eye(3), (sym.nb, 1, 1))
        self._snap = np.zeros(len(indices)) if self.slices > 1 else None
        self._panel_values = np.zeros(pn.size, pn.dtype)
        self._panel_dinv = np.tile(np.eye(3), (sym.nb, 1, 1))
        self._y = np.zeros((sym.nb, 3, 3))
        self._tmp = np.zeros(self.n)
        self._u = np.zeros(pn.longest)
        self._next = 0          # next slice of the factorization in progress (0: none started)
        self.bad_pivots = 0
        # in the background (a factorization that would be spread over several steps only): the
        # whole factorization runs on a thread while the steps go on, and its factor comes into
        # use at the first step after it is done, when the next one starts. So the factor in use
        # depends on the thread's timing: a run is no longer repeatable to the bit (to CG's
        # tolerance it is). Waiting for it at a fixed step instead would be: measured, the fine
        # press's steps in contact (2.2 ms) waited 14 ms for it every 6 steps
        self._threaded = self.background and self.slices > 1

    def _rows_args(self, values):
        """The arguments of ldlt_numeric_rows (and factor_rows_by_group) after the row bounds."""
        sym = self.sym
        return (values, sym.blk_slots, sym.up_ptr, sym.up_row, sym.up_slot, sym.row_ptr, sym.row_col,
                sym.row_slot, sym.Lp, sym.Li, self._L, self._D, self._y)

    def _run_slice(self, s, values):
        from softhand_sim.physics.ldlt import ldlt_numeric_rows
        sym = self.sym
        rows = self._rows_args(values)
        if not self.by_group:
            self.bad_pivots += ldlt_numeric_rows(int(self.bounds[s]), int(self.bounds[s + 1]), *rows)
            return
        gb = self.group_bounds
        self.bad_pivots += factor_rows_by_group(gb[s], gb[s + 1], *rows)
        if s == self.slices - 1 and self.shared_rows < sym.nb:
            self.bad_pivots += ldlt_numeric_rows(self.shared_rows, sym.nb, *rows)

    def _source(self, values):
        """The values a new factorization reads: a snapshot when it spans several steps."""
        if self._snap is None:
            return values
        self._snap[:] = values
        return self._snap

    def _publish(self):
        pn = self.panels
        to_panels(self._L, pn.dst, pn.col_len, self._panel_values)
        self._panel_dinv[:] = self._D
        self.arrays = (pn.starts, pn.rptr, pn.rows, pn.off, self._panel_values, self._panel_dinv,
                       self.sym.perm, self._tmp, self._u) + (self._by_group if self.by_group
                                                             else self._serial)
        self.valid = True

    @property
    def L(self):
        """L's blocks by columns ((nnzL, 3, 3), float64) as the factorization wrote them: the
        factor in use while no sliced factorization is under way."""
        return self._L

    @property
    def D_inv(self):
        """D⁻¹ of the factor in use ((nb, 3, 3))."""
        return self._panel_dinv

    def solve(self, r, z):
        """z = A⁻¹ r with the factor in use (what the preconditioner applies)."""
        factor_solve(self.arrays, r, z)

    @property
    def threaded(self):
        """True when factorizations run on a thread of their own (`background`, several slices)."""
        return self._threaded

    @property
    def in_progress(self):
        """True while a factorization spread over steps has slices left to run (or runs in the
        background)."""
        return self._next > 0 or self._job is not None

    def refresh(self, indptr, indices, values):
        """A complete factorization of values now (the first step, or on demand)."""
        if self.sym is None:
            self.analyse(indptr, indices)
        self._join()  # one in the background is waited for, then overwritten (the same buffers)
        src = self._source(values)
        for s in range(self.slices):
            self._run_slice(s, src)
        self._next = 0
        self._publish()

    def advance(self, values, slices=1):
        """Factor the next `slices` slices; a new snapshot of values starts each factorization.
        Returns True when a new factor was published in this call. In the background (`threaded`)
        `slices` is not read: the finished factorization, if the thread has one, is published and
        the next one started."""
        if self._threaded:
            return self._advance_background(values)
        published = False
        for _ in range(slices):
            src = self._source(values) if self._next == 0 else self._snap
            self._run_slice(self._next, src)
            self._next += 1
            if self._next == self.slices:
                self._next = 0
                self._publish()
                published = True
        return published

    def _advance_background(self, values):
        """`background`: publish the factorization the thread has finished, if it has, and start
        the next one on a snapshot of values; never waits for the thread."""
        if self._job is not None and not self._job.done():
            return False
        published = self._job is not None
        if published:
            self._join()
            self._publish()
        self._start(self._source(values))
        return published

    def _start(self, values):
        """The whole factorization of values on the factor's thread (`background`)."""
        if self._pool is None:
            import threading
            from concurrent.futures import ThreadPoolExecutor
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="softhand-factor")
            self._started = threading.Event()
        self._started.clear()
        self._job = self._pool.submit(self._factor_all, values)
        # wait (GIL released) until the thread is inside the kernel, which releases the GIL: else
        # it would wait for this thread's next switch interval (5 ms) to start
        self._started.wait()

    def _factor_all(self, values):
        from softhand_sim.physics.ldlt import ldlt_numeric_rows
        self._started.set()
        # all rows in order: each row's arithmetic is the same as in slices or by group (a group's
        # rows read only its own; the shared rows come last either way)
        return ldlt_numeric_rows(0, self.sym.nb, *self._rows_args(values))

    def wait(self):
        """Wait for the factorization running in the background, if one is: it comes into use at
        the next advance (for tests and tools; the solver never waits)."""
        if self._job is not None:
            self._job.result()

    def _join(self):
        """Wait for the factorization in the background, if one runs, and count its bad pivots."""
        if self._job is not None:
            job, self._job = self._job, None
            self.bad_pivots += job.result()


def triplet_pattern(indptr, indices):
    """True when every row of the CSR pattern is a run of column triplets (3c, 3c+1, 3c+2): the
    model's patterns are (whole node and body blocks), and csr_matvec3 relies on it."""
    indptr = np.asarray(indptr, np.int64)
    c = np.asarray(indices, np.int64)
    if np.any(np.diff(indptr) % 3) or len(c) % 3:
        return False
    return bool(np.all(c[0::3] % 3 == 0) and np.all(c[1::3] == c[0::3] + 1)
                and np.all(c[2::3] == c[0::3] + 2))


_U = np.uint64


@njit(cache=True)
def csr_matvec(indptr, indices, values, x, out):
    """out = A x (any CSR pattern). Indices are cast to unsigned: a signed index makes numba test
    it for negative (wrap-around) values at every gather."""
    for i in range(indptr.shape[0] - 1):
        acc = 0.0
        for k in range(_U(indptr[i]), _U(indptr[i + 1])):
            acc += values[k] * x[_U(indices[k])]
        out[i] = acc


@njit(cache=True)
def csr_matvec3(indptr, indices, values, x, out):
    """out = A x for a pattern made of column triplets (triplet_pattern): one index read per
    triplet and three independent partial sums (a single running sum is latency-bound)."""
    csr_matvec3_rows(indptr, indices, values, x, out, 0, indptr.shape[0] - 1)


@njit(cache=True)
def csr_matvec3_rows(indptr, indices, values, x, out, r0, r1):
    """Rows r0..r1-1 of csr_matvec3."""
    one, two, three = _U(1), _U(2), _U(3)
    for i in range(r0, r1):
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        for k in range(_U(indptr[i]), _U(indptr[i + 1]), three):
            c = _U(indices[k])
            a0 += values[k] * x[c]
            a1 += values[k + one] * x[c + one]
            a2 += values[k + two] * x[c + two]
        out[i] = (a0 + a1) + a2


@njit(parallel=True, cache=True)
def csr_matvec3_by_rows(indptr, indices, values, x, out, row0):
    """csr_matvec3 with the rows row0[c]:row0[c+1] of each chunk c in parallel (solver_threads)."""
    for c in prange(row0.shape[0] - 1):
        csr_matvec3_rows(indptr, indices, values, x, out, row0[c], row0[c + 1])


@njit(cache=True)
def _invert_spd(A):
    """Inverse of a small SPD block by Cholesky; falls back to the inverse diagonal when the block
    is not positive definite (cannot happen for M + dt^2 H with PSD H; kept as a guard)."""
    n = A.shape[0]
    L = np.zeros((n, n))
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if s <= 0.0:
            out = np.zeros((n, n))
            for i in range(n):
                out[i, i] = 1.0 / A[i, i] if A[i, i] > 0.0 else 0.0
            return out
        L[j, j] = np.sqrt(s)
        for i in range(j + 1, n):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]
    Linv = np.zeros((n, n))
    for j in range(n):
        Linv[j, j] = 1.0 / L[j, j]
        for i in range(j + 1, n):
            s = 0.0
            for k in range(j, i):
                s -= L[i, k] * Linv[k, j]
            Linv[i, j] = s / L[i, i]
    return Linv.T @ Linv


@njit(cache=True)
def build_block_jacobi(values, node_slots, body_slots, node_inv, body_inv):
    """node_inv (N,3,3), body_inv (B,6,6) <- inverses of the diagonal blocks of the matrix."""
    A3 = np.empty((3, 3))
    for n in range(node_slots.shape[0]):
        for i in range(3):
            for j in range(3):
                A3[i, j] = values[node_slots[n, i, j]]
        node_inv[n] = _invert_spd(A3)
    A6 = np.empty((6, 6))
    for b in range(body_slots.shape[0]):
        for i in range(6):
            for j in range(6):
                A6[i, j] = values[body_slots[b, i, j]]
        body_inv[b] = _invert_spd(A6)


@njit(cache=True)
def _apply_precond(kind, r, z, diag_inv, node_inv, body_inv, body_dof0, fac, indptr, indices, values,
                   diag_slot, tl):
    if kind == PRECOND_TWO_LEVEL:
        if tl[6].shape[0] > 1:  # the hands' sweeps on the cores (CoarseLevel threads)
            v_cycle_by_hand(indptr, indices, values, diag_slot, r, z, tl[0], tl[1], tl[2], tl[3], tl[4],
                            tl[5], tl[6])
        else:
            v_cycle(indptr, indices, values, diag_slot, r, z, tl[0], tl[1], tl[2], tl[3], tl[4], tl[5])
        return
    if kind == PRECOND_FACTOR:
        factor_solve(fac, r, z)  # the hands' panels on the cores with Factor.threads
        return
    if kind == PRECOND_JACOBI:
        for i in range(r.shape[0]):
            z[i] = diag_inv[i] * r[i]
        return
    for n in range(node_inv.shape[0]):
        o = 3 * n
        for i in range(3):
            z[o + i] = (node_inv[n, i, 0] * r[o] + node_inv[n, i, 1] * r[o + 1]
                        + node_inv[n, i, 2] * r[o + 2])
    for b in range(body_inv.shape[0]):
        o = body_dof0 + 6 * b
        for i in range(6):
            acc = 0.0
            for j in range(6):
                acc += body_inv[b, i, j] * r[o + j]
            z[o + i] = acc


ONE_CHUNK = np.zeros(2, np.int64)  # row_chunks of a product on one thread
NO_LOW_RANK = (0, np.zeros((0, 8), np.int32), np.zeros((0, 8)), np.zeros((0, 3, 3)))
# two_level.CoarseLevel.arrays' types, empty: what the other preconditioners pass
NO_TWO_LEVEL = (np.zeros((0, 4), np.int32), np.zeros((0, 4)), Factor(0).arrays, np.zeros(0), np.zeros(0),
                np.zeros(0), np.zeros((1, 4), np.int64))


def pcg(indptr, indices, values, b, x, tol, max_iter, kind, diag_slot, node_slots, body_slots,
        body_dof0, diag_inv, node_inv, body_inv, r, z, p, Ap, fac, triplets=False, low_rank=NO_LOW_RANK,
        energy_floor=0.0, row_chunks=None, two_level=NO_TWO_LEVEL):
    """Solve A x = b in place from the warm start x, A = the CSR matrix plus the low-rank term
    low_rank = (rows, nodes (C,8), weights (C,8), K (C,3,3)): sum over its first `rows` rows of
    L K L^T, L (3 x n) the row's weights on its nodes' 3 DOFs each (energies/self_contact.
    gauss_newton_rows: skin-skin contacts coupling two tets, outside the CSR pattern; the
    preconditioner is built from the CSR matrix alone). Stops when ||r|| <= tol ||b||, or when
    r^T z <= energy_floor (z = P^-1 r: the error e = A^-1 r in A's energy norm, e^T A e, which
    P <= A overestimates; A = M + dt^2 H >= M, so e^T M e <= energy_floor: with energy_floor =
    m v^2 the velocity error's mass-weighted RMS is below v), or after max_iter iterations.
    fac: Factor.arrays (used by PRECOND_FACTOR); two_level: CoarseLevel.arrays (PRECOND_TWO_LEVEL,
    whose sweeps run on the CSR matrix). triplets: the pattern is made of column triplets
    (triplet_pattern; faster products). row_chunks: row bounds of the product's chunks run in
    parallel (parallel.row_chunks; solver_threads > 1, triplet patterns). Returns (iterations,
    relative residual ||r||/||b||, hit_cap)."""
    return _pcg(indptr, indices, values, b, x, tol, max_iter, kind, diag_slot, node_slots, body_slots,
                body_dof0, diag_inv, node_inv, body_inv, r, z, p, Ap, fac, triplets,
                ONE_CHUNK if row_chunks is None else row_chunks, *low_rank, float(energy_floor), two_level)


@njit(cache=True)
def _add_low_rank(rows, nodes, weights, K, x, out):
    """out += sum over rows of L K L^T x (pcg's low-rank term)."""
    y = np.empty(3)
    for c in range(rows):
        y[:] = 0.0
        for a in range(8):
            w, o = weights[c, a], 3 * nodes[c, a]
            for i in range(3):
                y[i] += w * x[o + i]
        for i in range(3):
            f = K[c, i, 0] * y[0] + K[c, i, 1] * y[1] + K[c, i, 2] * y[2]
            for a in range(8):
                out[3 * nodes[c, a] + i] += weights[c, a] * f


@njit(cache=True)
def _matvec(indptr, indices, values, x, out, triplets, row0, rows, nodes, weights, K):
    if triplets and row0.shape[0] > 2:
        csr_matvec3_by_rows(indptr, indices, values, x, out, row0)
    elif triplets:
        csr_matvec3(indptr, indices, values, x, out)
    else:
        csr_matvec(indptr, indices, values, x, out)
    if rows > 0:
        _add_low_rank(rows, nodes, weights, K, x, out)


@njit(cache=True)
def _dot(a, b):
    """a . b in a plain loop: numba's np.dot calls BLAS, whose own threads (OpenBLAS threads a
    dot product of 10,000 entries and more: two fine hands) then fight the solver's threads and
    the other nodes for the cores; measured 10-20 ms per PCG iteration with solver_threads 2."""
    acc0 = 0.0
    acc1 = 0.0
    n = a.shape[0]
    for i in range(0, n - 1, 2):
        acc0 += a[i] * b[i]
        acc1 += a[i + 1] * b[i + 1]
    if n % 2:
        acc0 += a[n - 1] * b[n - 1]
    return acc0 + acc1


@njit(cache=True)
def _pcg(indptr, indices, values, b, x, tol, max_iter, kind, diag_slot, node_slots, body_slots,
         body_dof0, diag_inv, node_inv, body_inv, r, z, p, Ap, fac, triplets, row0, lr_rows, lr_nodes,
         lr_weights, lr_K, energy_floor, tl):
    n = b.shape[0]
    if kind == PRECOND_JACOBI:
        for i in range(n):
            d = values[diag_slot[i]]
            diag_inv[i] = 1.0 / d if d > 0.0 else 0.0
    elif kind == PRECOND_BLOCK_JACOBI:
        build_block_jacobi(values, node_slots, body_slots, node_inv, body_inv)
    bnorm = np.sqrt(_dot(b, b))
    if bnorm == 0.0:
        bnorm = 1.0
    _matvec(indptr, indices, values, x, Ap, triplets, row0, lr_rows, lr_nodes, lr_weights, lr_K)
    for i in range(n):
        r[i] = b[i] - Ap[i]
    rnorm = np.sqrt(_dot(r, r))
    if rnorm <= tol * bnorm:
        return 0, rnorm / bnorm, False
    _apply_precond(kind, r, z, diag_inv, node_inv, body_inv, body_dof0, fac, indptr, indices, values,
                   diag_slot, tl)
    p[:] = z
    rz = _dot(r, z)
    if rz <= energy_floor:
        return 0, rnorm / bnorm, False
    it = 0
    while it < max_iter:
        _matvec(indptr, indices, values, p, Ap, triplets, row0, lr_rows, lr_nodes, lr_weights, lr_K)
        pAp = _dot(p, Ap)
        if pAp <= 0.0:
            break
        alpha = rz / pAp
        rr = 0.0
        for i in range(n):
            x[i] += alpha * p[i]
            r[i] -= alpha * Ap[i]
            rr += r[i] * r[i]
        it += 1
        rnorm = np.sqrt(rr)
        if rnorm <= tol * bnorm:
            return it, rnorm / bnorm, False
        _apply_precond(kind, r, z, diag_inv, node_inv, body_inv, body_dof0, fac, indptr, indices, values,
                       diag_slot, tl)
        rz_new = _dot(r, z)
        if rz_new <= energy_floor:
            return it, rnorm / bnorm, False
        beta = rz_new / rz
        rz = rz_new
        for i in range(n):
            p[i] = z[i] + beta * p[i]
    return it, rnorm / bnorm, it >= max_iter
