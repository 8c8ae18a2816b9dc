"""Energy terms of Eq. 5, one module per term: inertia, tissue (Eq. 7-10), joints (Eq. 6),
bone_tissue (Eq. 11), contact (Eq. 12-13, contact helper), rigid_coupling (Eq. 14), gravity.

Each term gives value / add_gradient / add_hessian over flat float64/int32 arrays (numba).
The solver (physics/solver.py) calls them in its assemble stage.
"""
