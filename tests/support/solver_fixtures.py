"""Meshes and small rigid scenes built in tests (no hand model needed): boxes of tets, bodies; and
the references the solver's fast paths are checked against (the SVD's polar rotation, the
factor's block-by-block solve)."""
import numpy as np

from softhand_sim.physics import ldlt
from softhand_sim.physics.model import rigid_asset

# Kuhn split of a unit cube into 6 tets sharing the main diagonal (conforming across cubes)
_KUHN = [(0, 1, 3, 7), (0, 3, 2, 7), (0, 2, 6, 7), (0, 6, 4, 7), (0, 4, 5, 7), (0, 5, 1, 7)]


def box_mesh(size, cells):
    """Tet mesh of an axis-aligned box [0, size] with cells (nx, ny, nz): nodes (N,3), tets (T,4)
    all positively oriented."""
    nx, ny, nz = cells
    g = np.stack(np.meshgrid(*[np.linspace(0, s, c + 1) for s, c in zip(size, cells)],
                             indexing="ij"), axis=-1)
    nodes = g.reshape(-1, 3)

    def nid(i, j, k):
        return (i * (ny + 1) + j) * (nz + 1) + k

    tets = []
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                corner = [nid(i + (c >> 0 & 1), j + (c >> 1 & 1), k + (c >> 2 & 1)) for c in range(8)]
                for t in _KUHN:
                    tets.append([corner[v] for v in t])
    tets = np.array(tets, dtype=np.int32)
    X = nodes[tets]
    det = np.linalg.det(np.stack([X[:, 1] - X[:, 0], X[:, 2] - X[:, 0], X[:, 3] - X[:, 0]], axis=2))
    flip = det < 0
    tets[flip, 1], tets[flip, 2] = tets[flip, 2].copy(), tets[flip, 1].copy()
    return nodes, tets


def box_asset(size, cells, **fields):
    nodes, tets = box_mesh(size, cells)
    return rigid_asset(nodes, tets, **fields)


def random_quat(rng):
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def svd_polar(F):
    """The rotation maximising tr(Rᵀ F) by SVD, independent of the solver's iterative update: the
    polar rotation, for an inverted F the one with the smallest singular direction flipped."""
    U, _, Vt = np.linalg.svd(F)
    if np.linalg.det(U @ Vt) < 0:
        U[:, 2] *= -1
    return U @ Vt


def column_solve(sym, L, D_inv, r):
    """z = A⁻¹ r with the factor (ldlt.Symbolic sym, L's blocks, D⁻¹) block column by block column
    (ldlt.ldlt_solve, float64): the reference of the preconditioner's panel solve."""
    z = np.zeros_like(r)
    ldlt.ldlt_solve(sym.Lp, sym.Li, L, D_inv, sym.perm, np.zeros_like(r), r, z)
    return z


def dense_slots(stencils, n):
    """(E, k, k) slots of each stencil's k DOFs (k,) in a dense n x n matrix stored row by row: a
    kernel's Hessian scattered through them lands in np.zeros(n * n)."""
    return np.stack([st[:, None] * n + st[None, :] for st in stencils]).astype(np.int32)


def tet_stencils(tets):
    """Each tet's 12 DOFs (its 4 nodes' x, y, z), (T, 12)."""
    return [(3 * t[:, None] + np.arange(3)).ravel() for t in tets]
