"""`softhand bench`: single-thread step timing of the soft-hand solver (compile time excluded).

    python -m softhand_sim.bench [--scenario free|press] [--mesh coarse|fine] [--steps N]
                                 [--preconditioner factor|block_jacobi|jacobi] [--json]

Scenarios live in SCENARIOS (name -> setup(solver, state) returning a per-step callback
update(k, t)); the contact helper adds `grasp` there and may report contacts/collision columns.
Meshes: the hand model when `softhand_sim.handmodel.load_or_build_hand` is available, else the
voxel box hand of bench_scenes (coarse ~850 tets, fine ~8.5k).
"""
import argparse
import json
import os
import sys
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

PAPER_STEPS_PER_S = 55.0
MESH_TETS = {"coarse": 850, "fine": 8500}
DT = 0.01


def _asset(mesh):
    from .bench_scenes import box_hand_with_tets
    return box_hand_with_tets(MESH_TETS[mesh]), "box_hand"


def _free(solver, state):
    """Bones track an open-close cycle of the fingers (1 Hz) with a wandering palm."""
    from .rotations import quat_exp, quat_mul
    rest = solver.model.body_rest_pose[:16].copy()

    def update(k, t):
        tgt = rest.copy()
        tgt[0, :3] += 0.02 * np.array([np.sin(t), np.cos(1.3 * t) - 1, 0.0])
        flex = 0.7 * (1 - np.cos(2 * np.pi * t))
        for b in range(1, 16):
            depth = (b - 1) % 3 + 1
            tgt[b, 3:] = quat_mul(quat_exp(np.array([0.0, flex * depth / 3, 0.0])), rest[b, 3:])
        solver.set_bone_targets(tgt)
    return update


class _FingertipLoad:
    """Dead load on the five distal bones (thumb, index..little): the `press` scenario."""

    def __init__(self, model, force):
        self.dofs = np.array([model.body_dof0 + 6 * b + 2 for b in (3, 6, 9, 12, 15)])
        self.force = force

    def add_all(self, solver, state, grad, values):
        grad[self.dofs] += self.force
        return 0.0


def _press(solver, state):
    """Open hand held by its targets, 5 N pressing down on each fingertip, ramped over 0.2 s."""
    term = _FingertipLoad(solver.model, 0.0)
    solver.terms.append(term)

    def update(k, t):
        term.force = 5.0 * min(1.0, t / 0.2)
    return update


SCENARIOS = {"free": _free, "press": _press}


def run(scenario, mesh, steps, preconditioner):
    from .model import build_model
    from .solver import Solver
    asset, source = _asset(mesh)
    model = build_model(asset, {"preconditioner": preconditioner})
    t0 = time.perf_counter()
    warm = Solver(model)  # compile every kernel once on a throwaway state
    ws = model.initial_state()
    SCENARIOS[scenario](warm, ws)(0, 0.0)
    warm.step(ws, DT)
    compile_s = time.perf_counter() - t0
    solver = Solver(model)
    state = model.initial_state()
    update = SCENARIOS[scenario](solver, state)
    ms, setup, solve, iters, contacts, coll, caps = [], [], [], [], [], [], 0
    for k in range(steps):
        update(k, k * DT)
        t = time.perf_counter()
        st = solver.step(state, DT)
        ms.append((time.perf_counter() - t) * 1e3)
        setup.append(st.setup_ms)
        solve.append(st.solve_ms)
        iters.append(st.cg_iters)
        contacts.append(st.contacts)
        coll.append(st.collision_ms)
        caps += st.hit_cap
    ms = np.array(ms)
    return {
        "mesh": mesh, "source": source, "tets": int(len(model.tets)), "dofs": int(model.dof_count),
        "scenario": scenario, "preconditioner": preconditioner, "steps": steps,
        "median_ms": float(np.median(ms)), "p99_ms": float(np.percentile(ms, 99)),
        "steps_per_s": float(1e3 / np.median(ms)), "setup_ms": float(np.median(setup)),
        "solve_ms": float(np.median(solve)), "cg_iters_median": float(np.median(iters)),
        "cg_iters_max": int(max(iters)), "cg_hit_cap": int(caps),
        "contacts_median": float(np.median(contacts)), "collision_ms": float(np.median(coll)),
        "compile_s": compile_s, "finite": bool(np.all(np.isfinite(state.node_x))),
        "paper_steps_per_s": PAPER_STEPS_PER_S,
    }


def main(argv=None):
    ap = argparse.ArgumentParser(prog="softhand bench", description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", choices=sorted(SCENARIOS), action="append")
    ap.add_argument("--mesh", choices=sorted(MESH_TETS), action="append")
    ap.add_argument("--preconditioner", choices=["factor", "block_jacobi", "jacobi"], action="append")
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    rows = [run(s, m, a.steps, p) for m in (a.mesh or ["coarse", "fine"])
            for s in (a.scenario or ["free", "press"]) for p in (a.preconditioner or ["factor"])]
    if a.json:
        print(json.dumps(rows, indent=1))
        return 0
    cols = ["scenario", "mesh", "tets", "dofs", "preconditioner", "median_ms", "p99_ms",
            "steps_per_s", "setup_ms", "solve_ms", "cg_iters_median", "cg_hit_cap", "compile_s"]
    print(" ".join(f"{c:>14}" for c in cols))
    for r in rows:
        print(" ".join(f"{r[c]:>14.3f}" if isinstance(r[c], float) else f"{r[c]!s:>14}" for c in cols))
    print(f"paper: {PAPER_STEPS_PER_S} steps/s (856 tets, one i7-5820K core)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
