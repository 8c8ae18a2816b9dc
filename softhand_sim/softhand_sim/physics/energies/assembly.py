"""Shared assembly helpers: the fixed CSR sparsity pattern and per-term `slots`.

Every term adds its local Hessian (k x k over a stencil of k global dofs) into the CSR values
through slots[e, a, b] = index of entry (stencil[e, a], stencil[e, b]) in the values array, built
once at model build so no term searches the pattern during a step. The pattern is full (both
triangles), rows sorted, so `csr_slot` can binary-search it for per-step terms (contacts).
"""
import numpy as np
from numba import njit


def build_pattern(dof_count, stencils):
    """CSR pattern (indptr (n+1,) i4, indices (nnz,) i4) holding every (a, b) pair of every
    stencil. stencils: list of int arrays (E, k) of global dofs."""
    keys = [np.arange(dof_count, dtype=np.int64) * (dof_count + 1)]  # the diagonal, always
    for st in stencils:
        st = np.asarray(st, dtype=np.int64)
        if st.size == 0:
            continue
        keys.append((st[:, :, None] * dof_count + st[:, None, :]).ravel())
    keys = np.unique(np.concatenate(keys))
    rows = keys // dof_count
    indices = (keys % dof_count).astype(np.int32)
    indptr = np.zeros(dof_count + 1, dtype=np.int32)
    np.add.at(indptr, rows + 1, 1)
    return np.cumsum(indptr).astype(np.int32), indices


def stencil_slots(indptr, indices, stencil):
    """slots (E, k, k) i4: value index of each local entry of each stencil (E, k)."""
    n = len(indptr) - 1
    st = np.asarray(stencil, dtype=np.int64)
    if st.size == 0:
        k = st.shape[1] if st.ndim == 2 else 0
        return np.zeros((0, k, k), np.int32)
    keys_all = np.repeat(np.arange(n, dtype=np.int64), np.diff(indptr)) * n + indices
    keys = st[:, :, None] * n + st[:, None, :]
    slots = np.searchsorted(keys_all, keys)
    if not np.array_equal(keys_all[slots], keys):
        raise ValueError("stencil entry missing from the sparsity pattern")
    return slots.astype(np.int32)


@njit(cache=True)
def csr_slot(indptr, indices, i, j):
    """Value index of entry (i, j), or -1 when it is not in the pattern (binary search)."""
    lo = indptr[i]
    hi = indptr[i + 1]
    while lo < hi:
        mid = (lo + hi) // 2
        c = indices[mid]
        if c == j:
            return mid
        if c < j:
            lo = mid + 1
        else:
            hi = mid
    return -1
