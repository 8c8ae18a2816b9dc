"""The factor's L in dense panels (softhand_sim.physics.panels): the postordered elimination tree
keeps the fill, the panels hold every entry of L and nothing else, and the panel solve is the
column-by-column solve of the same factor, in float64 to round-off and in float32 exactly that of
L rounded to float32."""
import numpy as np
import pytest
import scipy.sparse as sp

from softhand_sim.physics import ldlt, panels, pcg
from softhand_sim.physics.solver import hand_block_groups
from tests.support.bench_runs import scene_run
from tests.support.solver_fixtures import column_solve


@pytest.fixture(scope="module")
def two_coarse():
    """Two coarse hands after 30 steps of the benchmark's open-close: (model, solver)."""
    return scene_run("free", ["coarse", "coarse"], 30, preconditioner="factor")[:2]


@pytest.fixture(scope="module")
def fine():
    return scene_run("free", ["fine"], 20, preconditioner="factor")[:2]


def test_postorder_keeps_the_fill_and_each_hand_in_its_rows(two_coarse):
    """The default ordering (each hand's minimum degree, then the etree postordered within each
    hand's rows) has the fill and flops of the same ordering unpostordered, each hand's blocks in
    its own rows still, and chains of consecutive columns: most columns' parent is the next one."""
    model, _ = two_coarse
    groups = hand_block_groups(model)
    n = model.dof_count
    post = ldlt.Symbolic(model.indptr, model.indices, n, groups=groups)
    bp, bi, _ = ldlt.block_pattern(model.indptr, model.indices, n)
    plain = ldlt.Symbolic(model.indptr, model.indices, n,
                          perm=ldlt.grouped_order(bp, bi, n // 3, groups))
    assert post.nnz_L == plain.nnz_L and post.flops == plain.flops
    assert not np.array_equal(post.perm, plain.perm)
    for lo, hi in zip(post.ranges[:-1], post.ranges[1:]):
        assert set(post.perm[lo:hi]) == set(plain.perm[lo:hi])
    g0, g1 = len(groups[0]), len(groups[1])
    assert list(post.ranges) == sorted({0, g0, g0 + g1, n // 3})

    def chained(sym):
        parent = sym.Li[sym.Lp[:-1][np.diff(sym.Lp) > 0]]
        cols = np.flatnonzero(np.diff(sym.Lp) > 0)
        return np.mean(parent == cols + 1)
    assert chained(post) > 0.7 > chained(plain)


def test_panels_hold_every_entry_of_l_and_zeros_elsewhere(two_coarse):
    """Rebuilt from the panels (each panel's columns by its rows), L is the factor's L entry for
    entry; no panel spans a hand's rows and the next ones; each panel is at most NARROW columns
    wide or at most ZERO_SHARE zeros; relaxing left fewer panels than fundamental supernodes."""
    model, solver = two_coarse
    f = solver.factor
    f.refresh(model.indptr, model.indices, solver.values)
    pn, sym = f.panels, f.sym
    values = f.arrays[4]
    n = 3 * sym.nb
    rows_, cols_, vals_ = [], [], []
    for s in range(pn.count):
        j0, j1 = pn.starts[s], pn.starts[s + 1]
        block_rows = np.r_[np.arange(j0, j1), pn.rows[pn.rptr[s]:pn.rptr[s + 1]]]
        scalar_rows = (3 * block_rows[:, None] + np.arange(3)).ravel()
        m = len(scalar_rows)
        panel = values[pn.off[s]:pn.off[s + 1]].reshape(3 * (j1 - j0), m).T  # column-major
        for c in range(3 * (j1 - j0)):
            col = 3 * j0 + c
            below = scalar_rows > 3 * (col // 3) + 2  # L is unit block-lower: below the block diagonal
            assert not panel[~below, c].any()
            rows_.append(scalar_rows[below])
            cols_.append(np.full(below.sum(), col))
            vals_.append(panel[below, c])
        widths = j1 - j0
        entries = sym.Lp[j1] - sym.Lp[j0]
        dense = widths * (widths - 1) // 2 + widths * (pn.rptr[s + 1] - pn.rptr[s])
        assert widths <= panels.NARROW or 1.0 - entries / dense <= panels.ZERO_SHARE + 1e-12
    got = sp.csr_matrix((np.concatenate(vals_), (np.concatenate(rows_), np.concatenate(cols_))),
                        shape=(n, n)).toarray()
    expected = np.zeros((n, n))
    for j in range(sym.nb):
        for p in range(sym.Lp[j], sym.Lp[j + 1]):
            i = sym.Li[p]
            expected[3 * i:3 * i + 3, 3 * j:3 * j + 3] = f.L[p]
    np.testing.assert_array_equal(got, expected)
    for bound in sym.ranges:  # every hand's rows start a panel
        assert bound in pn.starts
    count = np.diff(sym.Lp)
    parent = np.where(count > 0, sym.Li[np.minimum(sym.Lp[:-1], len(sym.Li) - 1)], -1)
    continues = (parent[:-1] == np.arange(1, sym.nb)) & (count[:-1] == count[1:] + 1)
    fundamental = sym.nb - int(continues.sum())
    assert pn.count < 0.7 * fundamental


def test_panel_solve_is_the_column_solve(two_coarse):
    """The panels' solve (one thread and by hand) equals ldlt.ldlt_solve with the same L and D:
    to round-off in float64 panels; in float32 ones, to round-off that of L rounded to float32."""
    model, solver = two_coarse
    f = solver.factor
    f.refresh(model.indptr, model.indices, solver.values)
    pn, sym = f.panels, f.sym
    assert pn.dtype == np.float64  # two coarse hands: 150,000 values
    r = np.random.default_rng(1).standard_normal(model.dof_count)
    exact = column_solve(sym, f.L, f.D_inv, r)
    z = np.zeros_like(r)
    f.solve(r, z)
    assert np.abs(z - exact).max() <= 1e-12 * np.abs(exact).max()
    L32 = f.L.astype(np.float32)
    v32 = np.zeros(pn.size, np.float32)
    panels.to_panels(L32, pn.dst, pn.col_len, v32)
    z32 = np.zeros_like(r)
    panels.panel_solve(pn.starts, pn.rptr, pn.rows, pn.off, v32, f.D_inv, sym.perm, np.zeros_like(r),
                       np.zeros(pn.longest), r, z32)
    rounded = column_solve(sym, L32.astype(np.float64), f.D_inv, r)
    assert np.abs(z32 - rounded).max() <= 1e-12 * np.abs(rounded).max()
    assert np.abs(z32 - exact).max() > 1e-10 * np.abs(exact).max()  # float32 panels did round


def test_the_fine_hands_float32_panels_converge_as_the_factor_does(fine):
    """The fine hand's panels are float32 (1.2 million values; two coarse hands' float64: above). With
    a fresh factor of the step's matrix, PCG to the default tolerance 1e-5 takes at most 2
    iterations, and on to 1e-9 at most 5: the rounding leaves a preconditioner close to A⁻¹."""
    model, solver = fine
    f = solver.factor
    assert f.panels.dtype == np.float32 and f.panels.size > panels.F64_PANEL_VALUES
    f.refresh(model.indptr, model.indices, solver.values)
    b = solver.rhs.copy()
    for tol, most in ((1e-5, 2), (1e-9, 3)):
        x = np.zeros_like(b)
        it, res, cap = pcg.pcg(
            model.indptr, model.indices, solver.values, b, x, tol, 50, pcg.PRECOND_FACTOR,
            model.diag_slot, model.node_slots, model.body_slots, model.body_dof0, solver._diag_inv,
            solver._node_inv, solver._body_inv, solver._r, solver._z, solver._p, solver._Ap, f.arrays,
            solver._triplets)
        assert it <= most and res <= tol and not cap, (tol, it, res)
