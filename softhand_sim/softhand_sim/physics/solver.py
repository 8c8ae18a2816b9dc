"""The soft-hand step (Sect. 3.1): collide -> assemble terms -> PCG -> advance.

Backward Euler with exactly one Newton iteration (Eq. 4 of the paper):
    (M + dt^2 H) v_new = M v - dt grad U,   q_new = q + dt v_new,  q_rot <- exp(dt w) q_rot
H, grad U from the sum of the terms of Eq. 5. PCG warm-started from the previous velocities.

    stats = solver.step(state, control, dt)

reads the Model (fixed), the Control (this step's inputs: Eq. 14 targets and stiffnesses, node
loads; control.py) and advances the State in place. Its stages, in this order:
  1. collide   the contact systems given to the Solver (contact/detection.ContactSystem for
               objects, contact/self_contact.SelfContactSystem for skin on skin; either may be
               None): detection, anchors, stick/slip -> this step's active contact lists
  2. assemble  gradient and CSR Hessian of every term at the state (`assemble`): tissue, joints,
               bone-tissue, Eq. 14 targets, gravity, node loads, contacts and self contacts
               (Eq. 12-13); the self contacts between two tets, outside the CSR pattern, as
               the rows of a low-rank term (SelfContactSystem.hessian_rows)
  3. PCG       (M + dt^2 H) v = M v - dt grad U, H = the CSR matrix plus that low-rank term
  4. advance   positions and orientations by dt v
Each term is one Python->numba call per step (not per element or CG iteration).
StepStats times the stages (STAGE_FIELDS, wall clock): collision and self_collision (1.), assembly
(2. and the system's finalisation), factor (the factor preconditioner's LDL^T refresh slice, between
2. and 3.), pcg (3.), advance (4.); setup_ms = assembly + factor, solve_ms = pcg + advance.
"""
import os
import time
from dataclasses import dataclass

import numpy as np
from numba import njit

from softhand_sim.physics import parallel, pcg as pcg_mod
from softhand_sim.physics.energies import bone_tissue, gravity, joints, rigid_coupling, tissue
from softhand_sim.physics.embedded import embedded_positions
from softhand_sim.physics.factor_hold import FactorHold
from softhand_sim.physics.energies.inertia import finalize_system, kinetic_energy
from softhand_sim.physics.rotations import integrate_rotation, quat_to_matrix


# tissue_hessian_tolerance: the share of tets that moved on in a step above which the next step
# runs the whole tissue kernel instead of keeping Hessians (the measured break-even, coarse hand:
# the kernel keeping none 0.17 ms, every tet 0.37, the whole kernel 0.35), and the most steps
# the kept Hessians' sums go without being assembled anew (their round-off)
KEEP_WHOLE_SHARE = 0.85
KEEP_RESUM_STEPS = 1000

# The stages of Solver.step in order, as (name, StepStats field): the split `softhand bench
# --profile` and sim_node's /diagnostics report.
STAGE_FIELDS = (("collision", "collision_ms"), ("self_collision", "self_collision_ms"),
                ("assembly", "assembly_ms"), ("factor", "factor_ms"), ("pcg", "pcg_ms"),
                ("advance", "advance_ms"))


@dataclass
class StepStats:
    cg_iters: int = 0
    residual: float = 0.0       # relative CG residual ||r|| / ||b||
    energy: float = 0.0         # potential energy U at the start of the step [J]
    # wall times [ms] of the step's stages (time.perf_counter, contiguous: their sum is the step
    # but for a few microseconds of bookkeeping); STAGE_FIELDS lists the finest split
    setup_ms: float = 0.0       # assembly_ms + factor_ms
    solve_ms: float = 0.0       # pcg_ms + advance_ms
    collision_ms: float = 0.0   # the collide stage: object contacts
    self_collision_ms: float = 0.0  # the collide stage: skin-skin contacts
    assembly_ms: float = 0.0    # rotations + every energy term's gradient and Hessian + finalize_system
    factor_ms: float = 0.0      # the factor preconditioner's LDL^T refresh / advance (~0 without it)
    pcg_ms: float = 0.0         # PCG
    advance_ms: float = 0.0     # positions and orientations by dt v
    hit_cap: bool = False       # CG stopped at cg_max_iterations
    refactored: bool = False    # a new factor preconditioner was published in this step (in setup)
    held: bool = False          # the factor in use was kept and no factorization ran (factor_hold)
    contacts: int = 0
    self_contacts: int = 0


@njit(cache=True)
def _extrapolate_guess(v, v_prev, scratch):
    """v <- 2 v - v_prev (CG's starting point) and v_prev <- the v given, for the next step. v is
    left as it is while v_prev holds anything not finite: the first step (NaN) and the step after
    a diverged one that the runtime's guard rejected (its velocity is kept here all the same)."""
    scratch[:] = v
    usable = True
    for i in range(v.shape[0]):
        if not np.isfinite(v_prev[i]):
            usable = False
            break
    if usable:
        for i in range(v.shape[0]):
            v[i] += v[i] - v_prev[i]
    v_prev[:] = scratch


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


def hand_block_groups(model):
    """The 3x3 blocks of each hand (its nodes, then its bones' two blocks each) for the factor's
    ordering (ldlt.grouped_order), or None for one hand (its ordering stays the one-hand one)."""
    layout = model.hands
    if layout is None or layout.count < 2:
        return None
    b0 = model.body_dof0 // 3
    return [np.concatenate([np.arange(layout.node0[h], layout.node0[h + 1]),
                            b0 + np.arange(2 * layout.bone0[h], 2 * layout.bone0[h + 1])])
            for h in range(layout.count)]


class Solver:
    """One-Newton-step implicit solver of the soft hand and its rigid objects.

    params: sim_node parameters by their schema names (params.SIM; solver keys: cg_tolerance,
    cg_max_iterations, preconditioner) overriding the model's own (model.params).
    contacts: the ContactSystem of the collide stage (contact/detection.build_contact_system), or None
    for a step without contact.
    self_contacts: the SelfContactSystem of skin-skin contact (contact/self_contact.
    build_self_contact_system), or None.
    """

    def __init__(self, model, params=None, contacts=None, self_contacts=None):
        self.model = m = model
        self.contacts = contacts
        self.self_contacts = self_contacts
        p = dict(model.params)
        p.update(params or {})
        self.params = p
        self.cg_tol = float(p["cg_tolerance"])
        self.cg_max_iter = int(p["cg_max_iterations"])
        kinds = {"jacobi": pcg_mod.PRECOND_JACOBI, "block_jacobi": pcg_mod.PRECOND_BLOCK_JACOBI,
                 "factor": pcg_mod.PRECOND_FACTOR, "two_level": pcg_mod.PRECOND_TWO_LEVEL}
        if p["preconditioner"] not in kinds:
            raise ValueError(f"preconditioner={p['preconditioner']!r}: expected one of {sorted(kinds)}")
        self.precond = kinds[p["preconditioner"]]
        # factor preconditioner: symbolic analysis once here; numeric refresh spread over steps
        # (at most factor_refresh_steps slices; 2 slices per step after a CG with more than
        # factor_refresh_iterations iterations, the whole factor of the step's own matrix after
        # more than 4 times that: a spike costs more than a factorization)
        self.refactor_every = int(p["factor_refresh_steps"])
        self.refactor_iters = int(p["factor_refresh_iterations"])
        if self.refactor_every < 1:
            raise ValueError(f"factor_refresh_steps={self.refactor_every}: must be >= 1")
        # the factor in use kept, no factorization started, while CG's iterations on it stay
        # cheaper than one (factor_hold.py)
        self.hold = FactorHold(float(p["factor_hold"]))
        self.threads = int(p["solver_threads"])
        if self.threads > 1:
            import numba
            if self.threads > numba.config.NUMBA_NUM_THREADS:
                raise ValueError(f"solver_threads={self.threads}: numba runs at most "
                                 f"{numba.config.NUMBA_NUM_THREADS} threads in this process "
                                 f"(NUMBA_NUM_THREADS, default the core count)")
        groups = hand_block_groups(m)
        if p["factor_background"] and self.precond == pcg_mod.PRECOND_FACTOR:
            # the factorization's thread beside the step's: on a core the step uses, both would
            # crawl (measured: two fine hands with solver_threads 2 and a third thread on two cores
            # ran 2-3 times slower)
            cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
            busy = self.threads if groups is not None else 1  # one hand: one thread
            if busy >= cores:
                hands = m.hands.count if m.hands is not None else 1
                raise ValueError(
                    f"factor_background=true needs a core beside the step's {busy} "
                    f"(solver_threads={self.threads}, {hands} hand(s)) and this process has "
                    f"{cores}: set factor_background false" + (f" or solver_threads {cores - 1}" if busy > 1 else ""))
        self.factor = (pcg_mod.Factor(model.dof_count, m.indptr, m.indices, max_slices=self.refactor_every,
                                      groups=groups, threads=self.threads,
                                      cost_scale=float(p["factor_cost_scale"]),
                                      background=bool(p["factor_background"]))
                       if self.precond == pcg_mod.PRECOND_FACTOR else pcg_mod.Factor(model.dof_count))
        # on a kept factor CG may take at most a factorization's worth of iterations (step)
        self._held_limit = min(self.cg_max_iter, max(2, int(np.ceil(self.factor.iterations_per_factor))))
        # two-level preconditioner: the coarse hand's mesh as its coarse level (two_level.py), its
        # matrix computed anew over every two_level_refresh_steps steps (whole after a long CG)
        self.coarse = None
        if self.precond == pcg_mod.PRECOND_TWO_LEVEL:
            from softhand_sim.physics.two_level import CoarseLevel
            meshes = m.extra.get("coarse_meshes")
            if meshes is None:
                raise ValueError("preconditioner='two_level' needs the coarse hand's mesh of each hand: "
                                 "build_model(..., coarse_meshes=...) (from hand assets: found by itself)")
            self.coarse = CoarseLevel(m, meshes, refresh_steps=int(p["two_level_refresh_steps"]),
                                      threads=self.threads)
        self._last_iters = 0
        self._v_prev = np.full(model.dof_count, np.nan)  # v_n-1 for CG's start (NaN: none yet)
        self._v_scratch = np.empty(model.dof_count)
        # PCG's absolute floor (pcg.pcg): e^T M e <= m_min v^2 bounds every node's velocity error
        # by v (m_i e_i^2 <= m_min v^2, m_i >= m_min), whatever the other masses (a clamp made of
        # an immovable 1e12 kg node, as tests do, leaves it alone). r^T z bounds e^T A e only for a
        # preconditioner P <= A: the factor of this step's own CSR matrix (one slice; A adds the
        # low-rank term to it), not Jacobi's diagonal nor a factor of an older step (the fine mesh,
        # and a factor held over steps: those steps pass no floor)
        m_min = float(m.node_mass.min()) if m.node_count else 0.0
        exact = self.precond == pcg_mod.PRECOND_FACTOR and self.factor.slices == 1
        self.cg_energy_floor = max(m_min, 0.0) * float(p["cg_velocity_floor"]) ** 2 if exact else 0.0
        n, nnz = m.dof_count, len(m.indices)
        self.grad = np.zeros(n)
        self.values = np.zeros(nnz)
        self.rhs = np.zeros(n)
        self._r, self._z, self._p, self._Ap, self._diag_inv = (np.zeros(n) for _ in range(5))
        self._node_inv = np.zeros((m.node_count, 3, 3))
        self._body_inv = np.zeros((m.body_count, 6, 6))
        self.gravity = np.asarray(p["gravity"], dtype=np.float64).reshape(3)
        self.last_stats = StepStats()
        # fused rotation + tissue kernel when K0 is the isotropic stiffness of the params (always,
        # for build_model's models): the named fast path of the tissue term, tested against the
        # update_rotations + K0 reference kernels in tests/physics/test_fast_paths.py
        self._lame = tissue.lame(float(p["youngs_modulus"]), float(p["poisson_ratio"]))
        self._triplets = pcg_mod.triplet_pattern(m.indptr, m.indices)
        self._fused_tissue = tissue.is_isotropic_K0(m.tet_K0, m.tet_Dm_inv, m.tet_volume, *self._lame)
        self._stress = bool(p["tissue_stress_stiffness"])  # H_rot: the tissue's rotation stiffness
        # tissue_hessian_tolerance: the tissue's Hessian kept per tet between steps (_tissue_term)
        self._hessian_tol = float(p["tissue_hessian_tolerance"])
        if self._hessian_tol > 0.0 and not self._fused_tissue:
            raise ValueError(f"tissue_hessian_tolerance={self._hessian_tol}: needs the isotropic tissue "
                             f"of the params (the fused kernel); this model's K0 is not")
        # the kept Hessians (12 x 12 each) and the states they were built at
        T = len(m.tets) if self._hessian_tol > 0.0 else 0
        self._tissue_values = np.zeros(nnz if T else 0)
        self._used_q, self._used_G = np.zeros((T, 4)), np.full((T, 3, 3), np.nan)
        self._kept_H = np.zeros((T, 12, 12))
        self.tissue_updated = len(m.tets)  # tets whose Hessian the last step rebuilt (or would have)
        self._kept_steps = 0
        self._kept_valid = False  # _tissue_values holds the kept Hessians' sum
        # the hands on the cores (parallel.py): each hand's tets, and the products' rows in chunks
        # (two hands or more; one hand runs on one thread whatever solver_threads says)
        by_hand = self.threads > 1 and groups is not None
        self._tet0 = np.asarray(m.hands.tet0, np.int64) if by_hand and self._fused_tissue else None
        self._row_chunks = (parallel.row_chunks(m.indptr, self.threads) if by_hand and self._triplets
                            else pcg_mod.ONE_CHUNK)

    # ---- the stages of the step
    def collide(self, state):
        """Stage 1: contact detection and anchor update at state (no-op without contacts)."""
        if self.contacts is not None:
            self.contacts.collide(state.node_x, state.body_x, state.body_q, state.v, self.model.body_dof0)
        if self.self_contacts is not None:
            self.self_contacts.collide(state.node_x, state.body_x, state.body_q, state.v,
                                       self.model.body_dof0, state.tet_q)

    def _tissue(self, state, vals, mode=tissue.WHOLE):
        """The tissue term into vals (each hand's tets on its own thread with solver_threads > 1)
        in one of tissue.assemble_tissue's modes; returns (energy [J], tets moved on)."""
        m, p = self.model, self.params
        polar = int(p["polar_iterations"])
        nl_k, nl_wmax = float(p["nonlinear_k"]), float(p["nonlinear_w_max"])
        lam, mu = self._lame
        if self._fused_tissue:
            args = (state.node_x, m.tets, m.tet_Dm_inv, m.tet_volume, lam, mu, state.tet_q, polar, nl_k,
                    nl_wmax, self.grad, m.tet_slots, vals, self._stress, mode, self._hessian_tol,
                    self._used_q, self._used_G, self._kept_H)
            if self._tet0 is not None:
                return parallel.tissue_by_hand(*args, self._tet0)
            return tissue.assemble_tissue(*args)
        tissue.update_rotations(state.node_x, m.tets, m.tet_Dm_inv, state.tet_q, polar)
        e = tissue.add_all(state.node_x, m.node_rest, m.tets, m.tet_K0, m.tet_volume, state.tet_q,
                           nl_k, nl_wmax, self.grad, m.tet_slots, vals)
        if self._stress:  # the isotropic H_rot of the params' material
            tissue.add_stress_hessian(state.node_x, m.tets, m.tet_Dm_inv, m.tet_volume, lam, mu,
                                      state.tet_q, nl_k, nl_wmax, m.tet_slots, vals)
        return e, 0

    def _tissue_term(self, state, vals):
        """The tissue term into vals. Without tissue_hessian_tolerance, and while more than
        KEEP_WHOLE_SHARE of the tets moved on in the last step, the whole kernel writes vals
        directly (with the tolerance only the rotations are compared then, a few flops a tet).
        Otherwise the kept Hessians' sums are in self._tissue_values, into which only the tets
        that moved on add their new Hessian less their kept one (KEEP_MOVED); the step after the
        motion settles keeps every tet anew (KEEP_ALL), as does every KEEP_RESUM_STEPS-th (the
        sums' round-off). Returns the energy [J]."""
        tv, T = self._tissue_values, len(self.model.tets)
        if self._hessian_tol == 0.0 or self.tissue_updated > KEEP_WHOLE_SHARE * T:
            vals[:] = 0.0
            e, _ = self._tissue(state, vals)
            if self._hessian_tol > 0.0:
                self._kept_valid = False
                self.tissue_updated = tissue.rotation_update(state.tet_q, self._hessian_tol,
                                                             self._used_q)
            return e
        if not self._kept_valid or self._kept_steps >= KEEP_RESUM_STEPS:
            tv[:] = 0.0
            e, self.tissue_updated = self._tissue(state, tv, tissue.KEEP_ALL)
            self._kept_valid, self._kept_steps = True, 0
        else:
            e, self.tissue_updated = self._tissue(state, tv, tissue.KEEP_MOVED)
            self._kept_steps += 1
        vals[:] = tv
        return e

    def assemble(self, state, control):
        """Stage 2: fill self.grad and self.values with dU/dq and H at state (rotations refreshed)
        for the inputs in control and the contacts of the last collide; returns U [J].

        One compiled call per term (a fused kernel measured ~4x slower: LLVM handles the single
        huge function badly), i.e. a handful of Python->numba calls per step.
        """
        m, p = self.model, self.params
        g, vals, b0 = self.grad, self.values, m.body_dof0
        g[:] = 0.0
        e = self._tissue_term(state, vals)
        e += joints.add_all(state.body_x, state.body_q, m.joint_parent, m.joint_child,
                            m.joint_r_parent, m.joint_r_child, float(p["joint_stiffness"]),
                            m.joint_rest_rotation, m.jrow_joint, m.jrow_axis, m.jrow_lo, m.jrow_hi,
                            m.jrow_k, b0, g, m.joint_slots, vals, True)
        e += bone_tissue.add_all(state.node_x, state.body_x, state.body_q, m.tets, m.sample_tet,
                                 m.sample_body, m.sample_r, m.sample_bary, m.sample_k, b0, g,
                                 m.sample_slots, vals, True)
        e += rigid_coupling.add_all(state.body_x, state.body_q, control.target_x, control.target_q,
                                    control.target_kx, control.target_ktheta, b0, g, m.body_slots, vals)
        e += gravity.add_all(state.node_x, state.body_x, m.node_mass, m.body_mass,
                             m.node_gravity_scale, m.body_gravity_scale, self.gravity, b0, g)
        e += gravity.add_loads(state.node_x, state.body_x, control.node_force, control.body_force, b0, g)
        if self.contacts is not None:
            e += self.contacts.add_all(state, m, g, vals)
        if self.self_contacts is not None:
            e += self.self_contacts.add_all(state, m, g, vals)
        return e

    def step(self, state, control, dt):
        """Advance state by dt [s] in place under control (this step's inputs); returns StepStats."""
        m = self.model
        clock = time.perf_counter  # a handful of calls per step: ~0.1 us each
        t0 = clock()
        self.collide(state)
        t1 = clock()
        energy = self.assemble(state, control)
        sc = self.self_contacts
        # the skin-skin contacts' Hessian between two tets: outside the CSR pattern, in the products
        low_rank = sc.hessian_rows(state.node_x, dt * dt) if sc is not None else pcg_mod.NO_LOW_RANK
        finalize_system(self.values, self.rhs, self.grad, state.v, dt, m.node_mass, m.body_mass,
                        state.body_q, m.body_inertia_local, m.diag_slot, m.body_slots, m.body_dof0)
        t2 = clock()
        refactored = held = False
        if self.precond == pcg_mod.PRECOND_FACTOR:
            if not self.factor.valid or (self.factor.slices > 1
                                         and self._last_iters > 4 * self.refactor_iters):
                self.factor.refresh(m.indptr, m.indices, self.values)
                refactored = True
            elif (not self.factor.in_progress and not self.factor.threaded
                  and self.hold.keep(self._last_iters, self.factor.iterations_per_factor)):
                held = True
            else:
                # in the background (factor.threaded) a factorization costs this thread nothing, so
                # none is held off, and slices are not counted: it comes into use when it is done
                catch_up = self._last_iters > self.refactor_iters and self.factor.slices > 1
                refactored = self.factor.advance(self.values, 2 if catch_up else 1)
            if refactored:
                self.hold.published()
        elif self.coarse is not None:
            if not self.coarse.valid or self._last_iters > 4 * self.refactor_iters:
                self.coarse.refresh(self.values)
                refactored = True
            else:
                refactored = self.coarse.advance(self.values)
        t3 = clock()
        # CG starts from the velocity extrapolated from the last two steps (2 v_n - v_n-1) rather
        # than from v_n: it stops at a residual relative to the right-hand side, and a hand in
        # smooth motion is nearer the extrapolation (fine hand, open-close: 12.7 -> 10.3 CG
        # iterations). The solution is the same to the CG tolerance; a worse guess after a jump or
        # an impact only costs iterations
        _extrapolate_guess(state.v, self._v_prev, self._v_scratch)
        # on a kept factor CG may take at most a factorization's worth of iterations: a factor too
        # far from this step's matrix (a jump of the tracked hand, an impact: 99 iterations once in
        # leap_roll_pitch) is replaced by the step's own, and CG goes on from where it stopped,
        # rather than spend several factorizations or hand the guard a capped step
        limit = self._held_limit if held else self.cg_max_iter
        iters, res, cap = self._pcg(state, low_rank, 0.0 if held else self.cg_energy_floor, limit)
        self._last_iters = iters
        if held and cap:
            t_refresh = clock()
            self.factor.refresh(m.indptr, m.indices, self.values)
            self.hold.rescued()
            refactored, held = True, False
            t3 += clock() - t_refresh  # counted in the factor stage, not in pcg
            more, res, cap = self._pcg(state, low_rank, self.cg_energy_floor, self.cg_max_iter)
            iters += more
            self._last_iters = more  # what the fresh factor needs: the next step's forecast
        t4 = clock()
        _advance(state.node_x, state.v, state.body_x, state.body_q, state.body_pose,
                 m.body_com_local, dt, m.body_dof0)
        t5 = clock()
        self_ms = sc.collision_ms if sc is not None else 0.0  # timed inside the collide stage
        assembly_ms, factor_ms = (t2 - t1) * 1e3, (t3 - t2) * 1e3
        pcg_ms, advance_ms = (t4 - t3) * 1e3, (t5 - t4) * 1e3
        self.last_stats = StepStats(
            cg_iters=int(iters), residual=float(res), energy=float(energy),
            setup_ms=assembly_ms + factor_ms, solve_ms=pcg_ms + advance_ms,
            collision_ms=max(0.0, (t1 - t0) * 1e3 - self_ms), self_collision_ms=self_ms,
            assembly_ms=assembly_ms, factor_ms=factor_ms, pcg_ms=pcg_ms, advance_ms=advance_ms,
            hit_cap=bool(cap), refactored=refactored, held=held,
            contacts=int(self.contacts.count) if self.contacts is not None else 0,
            self_contacts=int(sc.count) if sc is not None else 0)
        return self.last_stats

    def _pcg(self, state, low_rank, energy_floor, max_iter):
        """PCG on this step's system from state.v (solved in place): (iterations, residual, capped)."""
        m = self.model
        return pcg_mod.pcg(
            m.indptr, m.indices, self.values, self.rhs, state.v, self.cg_tol, max_iter,
            self.precond, m.diag_slot, m.node_slots, m.body_slots, m.body_dof0, self._diag_inv,
            self._node_inv, self._body_inv, self._r, self._z, self._p, self._Ap, self.factor.arrays,
            self._triplets, low_rank, energy_floor, self._row_chunks,
            self.coarse.arrays if self.coarse is not None else pcg_mod.NO_TWO_LEVEL)

    # ---- read-out
    def skin_positions(self, state, out=None):
        m = self.model
        if out is None:
            out = np.empty((len(m.skin_tet), 3))
        embedded_positions(state.node_x, m.tets, m.skin_tet, m.skin_bary, out)  # Sect. 5.1
        return out

    def kinetic_energy(self, state):
        m = self.model
        return kinetic_energy(state.v, m.node_mass, m.body_mass, state.body_q, m.body_inertia_local,
                              m.body_dof0)
