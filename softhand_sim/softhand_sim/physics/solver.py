"""The soft-hand step (Sect. 3.1): collide -> assemble terms -> PCG -> advance.

Backward Euler with exactly one Newton iteration (Eq. 4 of the paper):
    (M + dt^2 H) v_new = M v - dt grad U,   q_new = q + dt v_new,  q_rot <- exp(dt w) q_rot
H, grad U from the sum of the terms of Eq. 5. PCG warm-started from the previous velocities.

Extension points (the contact helper uses them):
  solver.pre_step_hooks: callables hook(solver, state, dt) run first in each step (collision
      detection); they may fill solver.step_terms.
  solver.terms / solver.step_terms: objects with add_all(solver, state, grad, values) -> energy [J]
      that ADD their gradient into grad (flat, model dof layout) and Hessian into the CSR values
      (model.indptr / model.indices; use energies.assembly.csr_slot or the model's reserved
      node-object blocks). `terms` persist; `step_terms` are cleared at the start of each step.
      Each is one Python call per step (not per element or CG iteration).
"""
import time
from dataclasses import dataclass

import numpy as np
from numba import njit

from softhand_sim.physics import pcg as pcg_mod
from softhand_sim.physics.energies import bone_tissue, gravity, joints, rigid_coupling, tissue
from softhand_sim.physics.energies.inertia import finalize_system, kinetic_energy
from softhand_sim.physics.model import Model, build_model  # noqa: F401  (re-export for the documented API)
from softhand_sim.physics.rotations import integrate_rotation, quat_to_matrix


@dataclass
class StepStats:
    cg_iters: int = 0
    residual: float = 0.0       # relative CG residual ||r|| / ||b||
    energy: float = 0.0         # potential energy U at the start of the step [J]
    setup_ms: float = 0.0       # rotations + assembly of gradient and M + dt^2 H
    solve_ms: float = 0.0       # PCG + advance
    collision_ms: float = 0.0   # pre-step hooks
    hit_cap: bool = False       # CG stopped at cg_max_iterations
    refactored: bool = False    # a new factor preconditioner was published in this step (in setup)
    contacts: int = 0


@njit(cache=True)
def _add_targets(body_x, body_q, target_x, target_q, kx, kth, body_slots, body_dof0, grad, values):
    """Eq. 14 between every body and its fixed target (bones: intermediate bones; objects: engine
    copies): energy [J], gradient, Hessian diag(kx I, k_theta I)."""
    e = rigid_coupling.targets_energy(body_x, body_q, target_x, target_q, kx, kth)
    rigid_coupling.targets_add_gradient(body_x, body_q, target_x, target_q, kx, kth, grad, body_dof0)
    for b in range(body_x.shape[0]):
        for i in range(3):
            values[body_slots[b, i, i]] += kx[b]
            values[body_slots[b, 3 + i, 3 + i]] += kth[b]
    return e


@njit(cache=True)
def _advance(x, v, body_x, body_q, body_pose, body_com_local, dt, body_dof0):
    """q <- q + dt v for nodes and COMs; orientations by the exponential map of dt * w (world)."""
    N = x.shape[0]
    for n in range(N):
        for i in range(3):
            x[n, i] += dt * v[3 * n + i]
    for b in range(body_x.shape[0]):
        o = body_dof0 + 6 * b
        for i in range(3):
            body_x[b, i] += dt * v[o + i]
        body_q[b] = integrate_rotation(body_q[b], v[o + 3:o + 6], dt)
        R = quat_to_matrix(body_q[b])
        origin = body_x[b] - R @ body_com_local[b]
        for i in range(3):
            body_pose[b, i] = origin[i]
        for i in range(4):
            body_pose[b, 3 + i] = body_q[b, i]


@njit(cache=True)
def skin_positions_kernel(x, tets, skin_tet, skin_bary, out):
    """Embedded skin vertices (V,3) [m] by barycentric interpolation (Sect. 5.1)."""
    for s in range(skin_tet.shape[0]):
        t = skin_tet[s]
        for i in range(3):
            acc = 0.0
            for a in range(4):
                acc += skin_bary[s, a] * x[tets[t, a], i]
            out[s, i] = acc


class Solver:
    """One-Newton-step implicit solver of the soft hand and its rigid objects.

    params: sim_node parameters by their schema names (params.SIM; solver keys: cg_tolerance,
    cg_max_iterations, preconditioner) overriding the model's own (model.params).
    """

    def __init__(self, model, params=None):
        self.model = m = model
        p = dict(model.params)
        p.update(params or {})
        self.params = p
        self.cg_tol = float(p["cg_tolerance"])
        self.cg_max_iter = int(p["cg_max_iterations"])
        kinds = {"jacobi": pcg_mod.PRECOND_JACOBI, "block_jacobi": pcg_mod.PRECOND_BLOCK_JACOBI,
                 "factor": pcg_mod.PRECOND_FACTOR}
        if p["preconditioner"] not in kinds:
            raise ValueError(f"preconditioner={p['preconditioner']!r}: expected one of {sorted(kinds)}")
        self.precond = kinds[p["preconditioner"]]
        # factor preconditioner: symbolic analysis once here; numeric refresh spread over steps
        # (at most factor_refresh_steps slices; 2 slices per step after a CG with more than
        # factor_refresh_iterations iterations)
        self.refactor_every = int(p["factor_refresh_steps"])
        self.refactor_iters = int(p["factor_refresh_iterations"])
        if self.refactor_every < 1:
            raise ValueError(f"factor_refresh_steps={self.refactor_every}: must be >= 1")
        self.factor = (pcg_mod.Factor(model.dof_count, m.indptr, m.indices, max_slices=self.refactor_every)
                       if self.precond == pcg_mod.PRECOND_FACTOR else pcg_mod.Factor(model.dof_count))
        self._last_iters = 0
        n, nnz = m.dof_count, len(m.indices)
        self.grad = np.zeros(n)
        self.values = np.zeros(nnz)
        self.rhs = np.zeros(n)
        self._r, self._z, self._p, self._Ap, self._diag_inv = (np.zeros(n) for _ in range(5))
        self._node_inv = np.zeros((m.node_count, 3, 3))
        self._body_inv = np.zeros((m.body_count, 6, 6))
        self.gravity = np.asarray(p["gravity"], dtype=np.float64).reshape(3)
        self.target_x = np.zeros((m.body_count, 3))
        self.target_q = np.zeros((m.body_count, 4))
        self.target_kx = m.body_target_kx.copy()
        self.target_ktheta = m.body_target_ktheta.copy()
        self._set_targets(0, m.body_rest_pose)
        self.pre_step_hooks = []
        self.terms = []
        self.step_terms = []
        self.last_stats = StepStats()
        # fused rotation + tissue kernel when K0 is the isotropic stiffness of the params (always,
        # for build_model's models); the K0 kernels otherwise
        self._lame = tissue.lame(float(p["youngs_modulus"]), float(p["poisson_ratio"]))
        self._triplets = pcg_mod.triplet_pattern(m.indptr, m.indices)
        self._fused_tissue = tissue.is_isotropic_K0(m.tet_K0, m.tet_Dm_inv, m.tet_volume, *self._lame)

    # ---- targets (Eq. 14)
    def _set_targets(self, first, poses):
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 7)
        for i, pose in enumerate(poses):
            b = first + i
            q = pose[3:] / np.linalg.norm(pose[3:])
            self.target_q[b] = q
            self.target_x[b] = pose[:3] + quat_to_matrix(q) @ self.model.body_com_local[b]

    def set_bone_targets(self, poses):
        """Intermediate-bone targets (bone_count, 7) bone-frame poses (Sect. 3.6)."""
        poses = np.asarray(poses, dtype=np.float64)
        if poses.shape != (self.model.bone_count, 7) or not np.all(np.isfinite(poses)):
            raise ValueError(f"bone targets must be finite ({self.model.bone_count}, 7), got {poses.shape}")
        self._set_targets(0, poses)

    def set_object_targets(self, poses, kx=None, ktheta=None):
        """Engine-copy targets of the rigid objects (object_count, 7) (Sect. 3.7); optional per-object
        stiffness kx [N/m] / ktheta [N m/rad] (0 releases an object)."""
        m = self.model
        poses = np.asarray(poses, dtype=np.float64)
        if poses.shape != (m.object_count, 7) or not np.all(np.isfinite(poses)):
            raise ValueError(f"object targets must be finite ({m.object_count}, 7), got {poses.shape}")
        self._set_targets(m.bone_count, poses)
        if kx is not None:
            self.target_kx[m.bone_count:] = kx
        if ktheta is not None:
            self.target_ktheta[m.bone_count:] = ktheta

    # ---- the step
    def assemble(self, state):
        """Fill self.grad and self.values with dU/dq and H at state (rotations refreshed); returns U.

        One compiled call per term (a fused kernel measured ~4x slower: LLVM handles the single
        huge function badly), i.e. a handful of Python->numba calls per step.
        """
        m, p = self.model, self.params
        g, vals, b0 = self.grad, self.values, m.body_dof0
        g[:] = 0.0
        vals[:] = 0.0
        if self._fused_tissue:
            e = tissue.add_all_fused(state.node_x, m.tets, m.tet_Dm_inv, m.tet_volume, self._lame[0],
                                     self._lame[1], state.tet_q, int(p["polar_iterations"]),
                                     float(p["nonlinear_k"]), float(p["nonlinear_w_max"]), g,
                                     m.tet_slots, vals)
        else:
            tissue.update_rotations(state.node_x, m.tets, m.tet_Dm_inv, state.tet_q, int(p["polar_iterations"]))
            e = tissue.add_all(state.node_x, m.node_rest, m.tets, m.tet_K0, m.tet_volume, state.tet_q,
                               float(p["nonlinear_k"]), float(p["nonlinear_w_max"]), g, m.tet_slots, vals)
        e += joints.add_all(state.body_x, state.body_q, m.joint_parent, m.joint_child,
                            m.joint_r_parent, m.joint_r_child, float(p["joint_stiffness"]),
                            m.joint_rest_rotation, m.jrow_joint, m.jrow_axis, m.jrow_lo, m.jrow_hi,
                            m.jrow_k, b0, g, m.joint_slots, vals, True)
        e += bone_tissue.add_all(state.node_x, state.body_x, state.body_q, m.tets, m.sample_tet,
                                 m.sample_body, m.sample_r, m.sample_bary, m.sample_k, b0, g,
                                 m.sample_slots, vals, True)
        e += _add_targets(state.body_x, state.body_q, self.target_x, self.target_q, self.target_kx,
                          self.target_ktheta, m.body_slots, b0, g, vals)
        e += gravity.add_all(state.node_x, state.body_x, m.node_mass, m.body_mass,
                             m.node_gravity_scale, m.body_gravity_scale, self.gravity, b0, g)
        for term in self.terms + self.step_terms:
            e += term.add_all(self, state, self.grad, self.values)
        return e

    def step(self, state, dt):
        """Advance state by dt [s] in place; returns StepStats."""
        m = self.model
        t0 = time.perf_counter()
        self.step_terms = []
        for hook in self.pre_step_hooks:
            hook(self, state, dt)
        t1 = time.perf_counter()
        energy = self.assemble(state)
        finalize_system(self.values, self.rhs, self.grad, state.v, dt, m.node_mass, m.body_mass,
                        state.body_q, m.body_inertia_local, m.diag_slot, m.body_slots, m.body_dof0)
        refactored = False
        if self.precond == pcg_mod.PRECOND_FACTOR:
            if not self.factor.valid:
                self.factor.refresh(m.indptr, m.indices, self.values)
                refactored = True
            else:
                catch_up = self._last_iters > self.refactor_iters and self.factor.slices > 1
                refactored = self.factor.advance(self.values, 2 if catch_up else 1)
        t2 = time.perf_counter()
        iters, res, cap = pcg_mod.pcg(
            m.indptr, m.indices, self.values, self.rhs, state.v, self.cg_tol, self.cg_max_iter,
            self.precond, m.diag_slot, m.node_slots, m.body_slots, m.body_dof0, self._diag_inv,
            self._node_inv, self._body_inv, self._r, self._z, self._p, self._Ap, self.factor.arrays,
            self._triplets)
        self._last_iters = iters
        _advance(state.node_x, state.v, state.body_x, state.body_q, state.body_pose,
                 m.body_com_local, dt, m.body_dof0)
        t3 = time.perf_counter()
        self.last_stats = StepStats(
            cg_iters=int(iters), residual=float(res), energy=float(energy),
            setup_ms=(t2 - t1) * 1e3, solve_ms=(t3 - t2) * 1e3, collision_ms=(t1 - t0) * 1e3,
            hit_cap=bool(cap), refactored=refactored, contacts=sum(getattr(t, "count", 0) for t in self.step_terms))
        return self.last_stats

    # ---- read-out
    def skin_positions(self, state, out=None):
        m = self.model
        if out is None:
            out = np.empty((len(m.skin_tet), 3))
        skin_positions_kernel(state.node_x, m.tets, m.skin_tet, m.skin_bary, out)
        return out

    def kinetic_energy(self, state):
        m = self.model
        return kinetic_energy(state.v, m.node_mass, m.body_mass, state.body_q, m.body_inertia_local,
                              m.body_dof0)
