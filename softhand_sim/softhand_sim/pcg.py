"""Preconditioned conjugate gradient over the fixed CSR pattern (Sect. 3.1: warm start, tol 1e-5,
iteration cap). All compiled; scratch arrays are owned by the caller and reused every step.

Preconditioners:
  PRECOND_JACOBI        the paper's: inverse diagonal
  PRECOND_BLOCK_JACOBI  inverse 3x3 node blocks and 6x6 rigid-body blocks
  PRECOND_FACTOR        a sparse LU of an earlier M + dt^2 H (default): the stiff bone-tissue and
                        joint springs couple bones and nodes, which only a factorization captures
"""
import numpy as np
from numba import njit

PRECOND_JACOBI = 0
PRECOND_BLOCK_JACOBI = 1
PRECOND_FACTOR = 2


class Factor:
    """Sparse LU (scipy SuperLU, symmetric mode, diagonal pivots) of M + dt^2 H kept as flat CSC
    arrays for the compiled triangular solves; reused as a preconditioner across steps and
    refreshed by the solver every few steps or when CG iterations grow."""

    def __init__(self, n):
        self.n = n
        self.valid = False
        e_i, e_f = np.zeros(1, np.int32), np.zeros(1)
        self.arrays = (np.zeros(n + 1, np.int32), e_i, e_f, np.zeros(n + 1, np.int32), e_i, e_f,
                       np.arange(n, dtype=np.int32), np.arange(n, dtype=np.int32), np.zeros(n))

    def refresh(self, indptr, indices, values):
        import scipy.sparse as sp
        from scipy.sparse.linalg import splu
        n = self.n
        A = sp.csr_matrix((values, indices, indptr), shape=(n, n)).tocsc()
        lu = splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                  options={"SymmetricMode": True})
        L, U = lu.L.tocsc(), lu.U.tocsc()
        self.arrays = (L.indptr.astype(np.int32), L.indices.astype(np.int32), L.data.copy(),
                       U.indptr.astype(np.int32), U.indices.astype(np.int32), U.data.copy(),
                       lu.perm_r.astype(np.int32), lu.perm_c.astype(np.int32), np.zeros(n))
        self.valid = True
        self.nnz = L.nnz + U.nnz


@njit(cache=True)
def factor_solve(Lp, Li, Lx, Up, Ui, Ux, perm_r, perm_c, tmp, r, z):
    """z = A^-1 r with Pr A Pc = L U (SuperLU conventions), L and U in CSC."""
    n = r.shape[0]
    for i in range(n):
        tmp[perm_r[i]] = r[i]
    for j in range(n):  # L y = Pr r
        d = 1.0
        for k in range(Lp[j], Lp[j + 1]):
            if Li[k] == j:
                d = Lx[k]
        tmp[j] /= d
        xj = tmp[j]
        for k in range(Lp[j], Lp[j + 1]):
            if Li[k] > j:
                tmp[Li[k]] -= Lx[k] * xj
    for j in range(n - 1, -1, -1):  # U u = y
        d = 1.0
        for k in range(Up[j], Up[j + 1]):
            if Ui[k] == j:
                d = Ux[k]
        tmp[j] /= d
        xj = tmp[j]
        for k in range(Up[j], Up[j + 1]):
            if Ui[k] < j:
                tmp[Ui[k]] -= Ux[k] * xj
    for i in range(n):
        z[i] = tmp[perm_c[i]]


@njit(cache=True)
def csr_matvec(indptr, indices, values, x, out):
    for i in range(indptr.shape[0] - 1):
        acc = 0.0
        for k in range(indptr[i], indptr[i + 1]):
            acc += values[k] * x[indices[k]]
        out[i] = acc


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
def _apply_precond(kind, r, z, diag_inv, node_inv, body_inv, body_dof0, fac):
    if kind == PRECOND_FACTOR:
        factor_solve(fac[0], fac[1], fac[2], fac[3], fac[4], fac[5], fac[6], fac[7], fac[8], r, z)
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


@njit(cache=True)
def pcg(indptr, indices, values, b, x, tol, max_iter, kind, diag_slot, node_slots, body_slots,
        body_dof0, diag_inv, node_inv, body_inv, r, z, p, Ap, fac):
    """Solve A x = b in place from the warm start x. Stops when ||r|| <= tol ||b|| or after
    max_iter iterations. fac: Factor.arrays (used by PRECOND_FACTOR). Returns (iterations, relative residual ||r||/||b||, hit_cap)."""
    n = b.shape[0]
    if kind == PRECOND_JACOBI:
        for i in range(n):
            d = values[diag_slot[i]]
            diag_inv[i] = 1.0 / d if d > 0.0 else 0.0
    elif kind == PRECOND_BLOCK_JACOBI:
        build_block_jacobi(values, node_slots, body_slots, node_inv, body_inv)
    bnorm = np.sqrt(np.dot(b, b))
    if bnorm == 0.0:
        bnorm = 1.0
    csr_matvec(indptr, indices, values, x, Ap)
    for i in range(n):
        r[i] = b[i] - Ap[i]
    rnorm = np.sqrt(np.dot(r, r))
    if rnorm <= tol * bnorm:
        return 0, rnorm / bnorm, False
    _apply_precond(kind, r, z, diag_inv, node_inv, body_inv, body_dof0, fac)
    p[:] = z
    rz = np.dot(r, z)
    it = 0
    while it < max_iter:
        csr_matvec(indptr, indices, values, p, Ap)
        pAp = np.dot(p, Ap)
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
        _apply_precond(kind, r, z, diag_inv, node_inv, body_inv, body_dof0, fac)
        rz_new = np.dot(r, z)
        beta = rz_new / rz
        rz = rz_new
        for i in range(n):
            p[i] = z[i] + beta * p[i]
    return it, rnorm / bnorm, it >= max_iter
