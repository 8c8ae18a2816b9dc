"""The factor preconditioner (softhand_sim.physics.ldlt / pcg.Factor): a block LDLᵀ over the model's fixed
pattern that solves M + dt² H to round-off, whether factored at once or in slices over steps (the
solves in panels of L, float32 ones included: tests/physics/test_panels.py)."""
import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

from softhand_sim.physics import ldlt
from softhand_sim.physics import pcg
from softhand_sim.physics.factor_hold import FactorHold
from softhand_sim.scenarios.bench_scenes import box_hand_with_tets
from softhand_sim.physics.model import build_model
from softhand_sim.physics.solver import Solver
from tests.support.solver_fixtures import column_solve


@pytest.fixture(scope="module")
def system():
    """A stepped box hand (900 tets): its CSR pattern and an assembled M + dt² H."""
    m = build_model(box_hand_with_tets(900))
    s = Solver(m, {"preconditioner": "block_jacobi"})
    st, control = m.initial_state(), m.control()
    st.v[:] = np.random.default_rng(1).normal(0.0, 0.05, m.dof_count)  # rotated tets, moved bones
    for _ in range(3):
        s.step(st, control, 0.01)
    return m, s.values.copy()


def _matrix(m, values):
    n = m.dof_count
    return sp.csr_matrix((values, m.indices, m.indptr), shape=(n, n))


def assert_solves(f, m, values, r):
    """The factor is A's to round-off: its L and D column by column and the preconditioner's
    solve in panels (float64: a small model's) against scipy's direct solve, 1e-9."""
    assert f.panels.dtype == np.float64
    ref = spsolve(_matrix(m, values).tocsc(), r)
    z = np.zeros_like(r)
    f.solve(r, z)
    for got in (column_solve(f.sym, f.L, f.D_inv, r), z):
        assert np.linalg.norm(got - ref) <= 1e-9 * np.linalg.norm(ref)


def test_factor_solves_the_system_to_roundoff(system):
    """LDLᵀ solve of M + dt² H against scipy's direct solve (independent reference): rel. error < 1e-9."""
    m, values = system
    f = pcg.Factor(m.dof_count, m.indptr, m.indices)
    f.refresh(m.indptr, m.indices, values)
    assert f.bad_pivots == 0
    assert_solves(f, m, values, np.random.default_rng(2).normal(size=m.dof_count))


def test_sliced_factorization_equals_the_full_one(system):
    """Spreading the numeric factorization over 7 steps gives the same factor as one pass, published
    exactly when the last slice is done, from the snapshot taken at the first slice."""
    m, values = system
    full = pcg.Factor(m.dof_count, m.indptr, m.indices)
    full.refresh(m.indptr, m.indices, values)
    sliced = pcg.Factor(m.dof_count, m.indptr, m.indices, slice_flops=1.0, max_slices=7)
    sliced.refresh(m.indptr, m.indices, 2.0 * values)  # a factor in use (of another matrix)
    assert sliced.slices == 7
    in_use = sliced.D_inv.copy()  # of 2 A: L as A's, D twice A's
    published = [sliced.advance(values if k == 0 else 3.0 * values) for k in range(6)]
    np.testing.assert_array_equal(sliced.D_inv, in_use)  # the solves' factor unchanged until the last slice
    published.append(sliced.advance(3.0 * values))
    assert published == [False] * 6 + [True]
    for a, b in ((full.L, sliced.L), (full.D_inv, sliced.D_inv), (full.arrays[4], sliced.arrays[4])):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=0.0)


def test_one_slice_factor_is_refreshed_in_place_from_the_values(system):
    """A factorization done within one step (one slice: the coarse hand's) reads the values it is
    given, with no snapshot: every advance publishes the factor of exactly those values, in the same
    arrays (L, the panels, D⁻¹)."""
    m, values = system
    f = pcg.Factor(m.dof_count, m.indptr, m.indices)
    assert f.slices == 1 and f._snap is None
    f.refresh(m.indptr, m.indices, 2.0 * values)
    arrays = f.L, f.arrays[4], f.arrays[5]
    for scale in (1.0, 3.0):
        assert f.advance(scale * values)
        fresh = pcg.Factor(m.dof_count, m.indptr, m.indices)
        fresh.refresh(m.indptr, m.indices, scale * values)
        assert all(a is b for a, b in zip(arrays, (f.L, f.arrays[4], f.arrays[5])))
        for a, b in zip((fresh.L,) + fresh.arrays[:7], (f.L,) + f.arrays[:7]):
            np.testing.assert_array_equal(a, b)


def test_fill_reducing_order_beats_the_natural_order(system):
    """The minimum-degree ordering keeps L sparser than the identity ordering of the same pattern."""
    m, _ = system
    nb = m.dof_count // 3
    ordered = ldlt.Symbolic(m.indptr, m.indices, m.dof_count)
    natural = ldlt.Symbolic(m.indptr, m.indices, m.dof_count, perm=np.arange(nb))
    assert ordered.nnz_L < 0.7 * natural.nnz_L
    assert sorted(ordered.perm) == list(range(nb))


def test_block_pattern_rejects_a_dof_count_not_a_multiple_of_three():
    """The 3x3-block factor needs whole blocks; a bad dof count is an error naming it."""
    with pytest.raises(ValueError, match="dof count 4"):
        ldlt.block_pattern(np.array([0, 1, 2, 3, 4]), np.array([0, 1, 2, 3]), 4)


def test_factor_pcg_converges_in_one_iteration_with_a_fresh_factor(system):
    """With the factor of the current matrix, PCG reaches tol 1e-10 in at most 2 iterations."""
    m, values = system
    s = Solver(m)
    f = pcg.Factor(m.dof_count, m.indptr, m.indices)
    f.refresh(m.indptr, m.indices, values)
    b = np.random.default_rng(3).normal(size=m.dof_count)
    x = np.zeros_like(b)
    it, res, cap = pcg.pcg(m.indptr, m.indices, values, b, x, 1e-10, 50, pcg.PRECOND_FACTOR,
                           m.diag_slot, m.node_slots, m.body_slots, m.body_dof0, s._diag_inv,
                           s._node_inv, s._body_inv, s._r, s._z, s._p, s._Ap, f.arrays)
    assert it <= 2 and res <= 1e-10 and not cap
    assert np.linalg.norm(_matrix(m, values) @ x - b) <= 1e-9 * np.linalg.norm(b)


def test_velocity_floor_stops_pcg_with_every_node_within_it(system):
    """A = the CSR matrix plus a stiff low-rank term (skin-skin contact rows, which the factor does
    not see), b small as in a held pose: to the relative tolerance alone PCG iterates on; with the
    energy floor m_min v^2 it stops sooner, and against the exact solution (dense) no node's
    velocity error exceeds v."""
    m, values = system
    s = Solver(m)
    f = pcg.Factor(m.dof_count, m.indptr, m.indices)
    f.refresh(m.indptr, m.indices, values)
    rng = np.random.default_rng(7)
    C = 40
    nodes = rng.integers(0, m.node_count, (C, 8)).astype(np.int32)
    weights = np.concatenate([-rng.dirichlet(np.ones(4), C), rng.dirichlet(np.ones(4), C)], axis=1)
    K = np.array([1e4 * (np.eye(3) + 0.3 * np.outer(v, v)) for v in rng.normal(size=(C, 3))])
    A = _matrix(m, values).toarray()
    for c in range(C):
        L = np.zeros((3, m.dof_count))
        for a in range(8):
            L[:, 3 * nodes[c, a]:3 * nodes[c, a] + 3] += weights[c, a] * np.eye(3)
        A += L.T @ K[c] @ L
    b = 1e-7 * rng.normal(size=m.dof_count)
    exact = np.linalg.solve(A, b)
    v_floor = 1e-5
    floor = m.node_mass.min() * v_floor ** 2
    runs = {}
    for name, e_floor in (("relative only", 0.0), ("floor", floor)):
        x = np.zeros_like(b)
        it, res, cap = pcg.pcg(m.indptr, m.indices, values, b, x, 1e-5, 200, pcg.PRECOND_FACTOR,
                               m.diag_slot, m.node_slots, m.body_slots, m.body_dof0, s._diag_inv,
                               s._node_inv, s._body_inv, s._r, s._z, s._p, s._Ap, f.arrays,
                               low_rank=(C, nodes, weights, K), energy_floor=e_floor)
        err = np.linalg.norm((x - exact)[:m.body_dof0].reshape(-1, 3), axis=1)
        runs[name] = (it, err.max())
    print(runs)
    assert runs["floor"][0] < runs["relative only"][0]
    assert runs["floor"][1] <= v_floor and runs["floor"][1] > runs["relative only"][1]


def test_factor_of_object_rows_with_and_without_contact():
    """Object bodies couple to every surface node through the pattern, but only contacts fill those
    entries: rows (and their reach) left zero are skipped by the numeric factorization. Solves
    against scipy's direct solve with no coupling, with one node-object spring, and again with
    none in the buffer that held the coupled factor (nothing of it may be left in L)."""
    from types import SimpleNamespace
    ball = SimpleNamespace(mass=0.1, inertia_local=np.eye(3) * 4e-5, pose=np.array([0.0, 0.0, 0.1, 0, 0, 0, 1.0]))
    m = build_model(box_hand_with_tets(900), objects=[ball])
    s = Solver(m)
    st, control = m.initial_state(), m.control()
    st.v[:] = np.random.default_rng(4).normal(0.0, 0.05, m.dof_count)
    s.step(st, control, 0.01)
    free = s.values.copy()
    A = _matrix(m, free).tolil()
    o = m.body_dof0 + 6 * m.bone_count  # the ball's first DOF
    assert A[:o, o:].count_nonzero() == 0 and len(_matrix(m, free)[:o, o:].indices) > 0  # reserved, zero
    coupled = free.copy()
    csr = _matrix(m, coupled)
    rows = np.flatnonzero(np.diff(csr[:o, o:].indptr))  # DOFs with a reserved entry in the ball's columns
    n0 = 3 * (rows[0] // 3)
    k = 2e3  # [N/m] x dt^2-scaled spring between that node and the ball's centre, per axis
    for i in range(3):
        for r, c, v in ((n0 + i, n0 + i, k), (o + i, o + i, k), (n0 + i, o + i, -k), (o + i, n0 + i, -k)):
            slot = csr.indptr[r] + np.searchsorted(csr.indices[csr.indptr[r]:csr.indptr[r + 1]], c)
            assert csr.indices[slot] == c
            coupled[slot] += v
    f = pcg.Factor(m.dof_count, m.indptr, m.indices)
    r = np.random.default_rng(5).normal(size=m.dof_count)
    for values in (free, coupled, free):  # the buffers (L, the panels) reused after the coupled factor
        f.refresh(m.indptr, m.indices, values)
        assert_solves(f, m, values, r)
    assert f.bad_pivots == 0


@pytest.mark.parametrize("last_iters, full", [(20, False), (40, True)])
def test_a_cg_far_over_the_refresh_iterations_refactors_at_once(system, last_iters, full):
    """A sliced factor (5 slices) after a CG of more than 4 x factor_refresh_iterations (8): the
    next step factors its own matrix whole (a spike such as the first contact of both hands with
    the big box, 50-59 iterations for 5 steps on a factor taken before it); after one of 9-32
    iterations, two slices of the factorization in progress, as before."""
    m, _ = system
    s = Solver(m)
    s.factor = pcg.Factor(m.dof_count, m.indptr, m.indices, slice_flops=1.0, max_slices=5)
    s.hold = FactorHold(0.0)  # a new factorization as soon as the last is done (no hold)
    assert s.factor.slices == 5
    state, control = m.initial_state(), m.control()
    state.v[:] = np.random.default_rng(5).normal(0.0, 0.05, m.dof_count)
    s.step(state, control, 0.01)          # the first step factors whole (no factor yet)
    s.step(state, control, 0.01)          # then one slice a step: the next factorization under way
    assert s.factor._next == 1
    s._last_iters = last_iters
    stats = s.step(state, control, 0.01)
    if full:
        assert stats.refactored and s.factor._next == 0
        fresh = pcg.Factor(m.dof_count, m.indptr, m.indices, slice_flops=1.0, max_slices=5)
        fresh.refresh(m.indptr, m.indices, s.values)
        np.testing.assert_array_equal(fresh.L, s.factor.L)
    else:
        assert not stats.refactored and s.factor._next == 3
