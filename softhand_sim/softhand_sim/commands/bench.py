"""`softhand bench`: single-thread step timing of the soft-hand solver (compile time excluded).

    python -m softhand_sim.commands.bench [--scenario free|press|grasp] [--mesh coarse|fine|box]
                                 [--steps N] [--preconditioner factor|two_level|block_jacobi|jacobi]
                                 [--all-preconditioners] [--hands 1|2|1,2] [--profile] [--plot FILE.png] [--json]
                                 [--set KEY=VALUE ...]

Meshes: coarse / fine = the parametric hand model (handmodel.load_or_build_hand(resolution=...));
box = the voxel box hand of bench_scenes (~850 tets, the paper's size; no hand builder needed).
Scenarios live in SCENARIOS (name -> setup(solver, state) returning a per-step callback
update(k, t)); `grasp` is the thumb-index pinch of contact_scenarios (PinchScenario).
contacts_median: active skin contacts per step; collision_ms: median object collision-detection
time; self_contacts_median / self_collision_ms: the same for skin-skin contact (scenarios
free_self: `free` with self contact on; fist: the tight fist of scenarios/self_contact.py).
Timings: median and p99 of the whole step (wall clock; one thread unless --threads);
setup = rotations + assembly (+ the preconditioner's refactorization), solve = PCG + advance.

--profile (issue #20) splits the step into the solver's stages (solver.STAGE_FIELDS: collision,
self_collision, assembly, factor, pcg, advance) plus `other` (the step's own bookkeeping and call
overhead: the whole step minus its stages): per stage the median and p99 [ms] over the steps and
its share of the total step time (sum over the steps; the shares add up to 1). In --json each
row gets `stages`: {name: {median_ms, p99_ms, share}}.

--hands 2: both hands in one model (issue #18; the left mirrored, 30 cm to the right hand's -y
side): `free` moves both, `press` loads both hands' pads, `grasp` is both palms pressing and
lifting the scene's big box (scenarios/bimanual.TwoHandLift on the solver, the box's engine copy
held at its scene pose: the world's resting box). `--hands 1,2` runs both counts.

--threads 2 (with --hands 2): solver_threads 2, the two hands on the two cores (physics/parallel.py);
the one-core figures are --threads 1, the default. `--threads 1,2` runs both, one after the other.

--preconditioner two_level: Gauss-Seidel sweeps around a correction on the coarse hand's mesh
(physics/two_level.py; its `factor` stage is the coarse level's refresh). Meant for the fine
mesh; on the coarse one its coarse level is the hand's own mesh, a whole factor every
two_level_refresh_steps steps.

--plot FILE.png draws the cases (bench_plot.py): each mean step split into its stages with the
median and p99 step, and every step in run order (a scene that moves and then holds shows as two
levels). It implies --profile; with --json the rows then also carry `step_ms`, every step's time.

With the factor preconditioner --profile also times a whole factorization and a CG iteration
after the run (`factor_cost`: factor_ms, iteration_ms, their ratio `measured` and the cost model's
`estimated` ratio, which factor_hold's budget and the slice count read: pcg.Factor.analyse; and
`matching_scale`, the factor_cost_scale that would make them agree on this machine).

--set KEY=VALUE: a sim_node solver parameter for every case (`softhand params sim_node`), e.g.
`--set factor_hold=0` for the factor preconditioner with a new factorization as soon as the last
is done, as before factor_hold (physics/factor_hold.py); `factor_held` counts the steps that kept
the factor in use, `refactors` those that put a new one in use.
"""
import argparse
import json
import sys
import time

import numpy as np

from softhand_sim.scenarios.bench_scenes import fingertip_pad_nodes, flexed_pose

PAPER_STEPS_PER_S = 55.0
MESHES = ("coarse", "fine", "box")
PRECONDITIONERS = ("factor", "two_level", "block_jacobi", "jacobi")
BOX_TETS = 850
DT = 0.01
_ASSETS = {}


def _asset(mesh, side="right"):
    """(asset, source) for a mesh name (and hand side); cached per process."""
    if side != "right":
        if mesh == "box":
            raise ValueError("--hands 2 needs the hand model (--mesh coarse or fine), not the box hand")
        key = (mesh, side)
        if key not in _ASSETS:
            from softhand_sim.handmodel import load_or_build_hand
            _ASSETS[key] = (load_or_build_hand(side=side, resolution=mesh), "hand_model")
        return _ASSETS[key]
    if mesh not in _ASSETS:
        if mesh == "box":
            from softhand_sim.scenarios.bench_scenes import box_hand_with_tets
            _ASSETS[mesh] = (box_hand_with_tets(BOX_TETS), "box_hand")
        elif mesh in ("coarse", "fine"):
            from softhand_sim.handmodel import load_or_build_hand
            _ASSETS[mesh] = (load_or_build_hand(resolution=mesh), "hand_model")
        else:
            raise ValueError(f"mesh={mesh!r}: expected one of {MESHES}")
    return _ASSETS[mesh]


class _Free:
    """Open-close cycle of all fingers (1 Hz) through the bone targets, by forward kinematics
    about each joint's flexion axis up to 70% of its flexion limit (hinge joints) / 40% (the
    finger bases), while the palm wanders by +-2 cm."""

    def __init__(self):
        self.asset = None

    def objects(self, asset):  # remembers the asset (joint axes, limits) for the targets
        self.asset = asset
        return ()

    def __call__(self, solver, state, control):
        a = self.asset
        lim = np.asarray(a.joint_limits, float)[:, 0, 1]
        amp = np.where(np.asarray(a.joint_type) == 1, 0.7, 0.4) * np.maximum(lim, 0.0)

        def update(k, t):
            s = 0.5 * (1.0 - np.cos(2.0 * np.pi * t))
            off = 0.02 * np.array([np.sin(t), np.cos(1.3 * t) - 1.0, 0.0])
            control.set_bone_targets(solver.model, flexed_pose(a, s * amp, off))
        return update


class _Press:
    """Open hand held by its targets; 5 N on each fingertip pad pushing up (+z, a surface under
    the palm-down hand), ramped over 0.2 s."""

    def __init__(self):
        self.asset = None

    def objects(self, asset):
        self.asset = asset
        return ()

    def __call__(self, solver, state, control):
        pads = fingertip_pad_nodes(self.asset)
        nodes = np.concatenate(pads)
        share = np.concatenate([np.full(len(p), 1.0 / len(p)) for p in pads])

        def update(k, t):  # the dead load (U = -f . x) on the pads, through the step's Control
            control.node_force[nodes, 2] = 5.0 * min(1.0, t / 0.2) * share
        return update


class _SelfContact:
    """Skin-skin contact for a scenario (the hand model only): one SelfContactModel per asset,
    a fresh system per solver. The scenario objects live as long as the process (SCENARIOS), and
    one `softhand bench` runs the coarse hand, then the fine one: the model is kept per asset, as
    the skin points are embedded in that asset's tets (reused for the fine hand, the coarse
    embedding put thousands of skin points inside other segments)."""

    def __init__(self):
        self._smodels = {}  # id(asset) -> (asset, SelfContactModel); the asset kept so its id stays its own

    def self_contacts(self, model):
        from softhand_sim.handmodel.rigid_skin import skin_segments
        from softhand_sim.physics.contact import self_contact
        if getattr(self.asset, "skin_triangles", None) is None:
            raise ValueError("self contact needs the hand model (--mesh coarse or fine)")
        if id(self.asset) not in self._smodels:
            built = self_contact.build_self_contact_system(model, self.asset, skin_segments(self.asset)).model
            self._smodels[id(self.asset)] = (self.asset, built)
        smodel = self._smodels[id(self.asset)][1]
        return self_contact.SelfContactSystem(smodel, model, int(model.params["self_contact_capacity"]))


class _FreeSelf(_SelfContact, _Free):
    """`free` with skin-skin contact on."""

    def __init__(self):
        _Free.__init__(self)
        _SelfContact.__init__(self)


class _Fist(_SelfContact):
    """The tight fist (scenarios/self_contact.Fist): the fingers close over 0.6 s to 1 cm beyond
    touching the palm and hold."""

    def __init__(self):
        super().__init__()
        self.asset = None

    def objects(self, asset):
        self.asset = asset
        return ()

    def __call__(self, solver, state, control):
        from softhand_sim.scenarios.self_contact import Fist
        script = Fist(self.asset, solver.self_contacts.model)

        def update(k, t):
            control.set_bone_targets(solver.model, script.bone_targets(t))
        return update


SCENARIOS = {"free": _Free(), "press": _Press(), "free_self": _FreeSelf(), "fist": _Fist()}
from softhand_sim.scenarios.contact import PinchScenario  # noqa: E402
SCENARIOS["grasp"] = PinchScenario()  # thumb-index pinch of the ball, lifted (contact_scenarios.py)

LEFT_SHIFT = np.array([0.0, -0.30, 0.0])  # [m] the left hand of --hands 2, beside the right one


def _shift_hand(model, state, h, d):
    """Translate hand h of the state rigidly by d (3,) [m] (nodes and bones)."""
    state.node_x[model.hands.nodes(h)] += d
    for b in range(*model.hands.bones(h).indices(model.body_count)):
        state.body_x[b] += d
        state.body_pose[b, :3] += d


class _TwoHands:
    """A one-hand scenario (free, press) run on both hands: the right as in the one-hand bench,
    the left (its own asset: mirrored joints) by the same recipe, shifted LEFT_SHIFT."""

    def __init__(self, one):
        self.one = one
        self.assets = None

    def objects(self, assets):
        self.assets = assets
        return ()

    def __call__(self, solver, state, control):
        model = solver.model
        _shift_hand(model, state, 1, LEFT_SHIFT)
        updates = []
        for h, asset in enumerate(self.assets):
            sub = type(self.one)()
            sub.objects(asset)
            updates.append(self._per_hand(sub, asset, model, h, state, control))

        def update(k, t):
            for u in updates:
                u(k, t)
        return update

    @staticmethod
    def _per_hand(sub, asset, model, h, state, control):
        if isinstance(sub, _Free):
            a = asset
            lim = np.asarray(a.joint_limits, float)[:, 0, 1]
            amp = np.where(np.asarray(a.joint_type) == 1, 0.7, 0.4) * np.maximum(lim, 0.0)
            shift = LEFT_SHIFT if h else np.zeros(3)

            def update(k, t):
                s = 0.5 * (1.0 - np.cos(2.0 * np.pi * t))
                off = 0.02 * np.array([np.sin(t), np.cos(1.3 * t) - 1.0, 0.0]) + shift
                control.set_hand_targets(model, h, flexed_pose(a, s * amp, off))
            pose = flexed_pose(asset, np.zeros(len(asset.joint_parent)), LEFT_SHIFT if h else np.zeros(3))
            control.set_hand_targets(model, h, pose)
            return update
        pads = fingertip_pad_nodes(asset)
        nodes = np.concatenate(pads) + model.hands.node0[h]
        share = np.concatenate([np.full(len(p), 1.0 / len(p)) for p in pads])
        if h:
            control.set_hand_targets(model, h, np.asarray(asset.bone_rest_pose) + np.r_[LEFT_SHIFT, np.zeros(4)])

        def update(k, t):
            control.node_force[nodes, 2] = 5.0 * min(1.0, t / 0.2) * share
        return update


class _TwoHandGrasp:
    """Both palms press the scene's big box from its y ends and lift it (TwoHandLift on the
    solver): from T0 (hands 1 cm off the faces) on; the box's engine copy stays at its scene pose."""

    T0 = 0.6  # [s] into the TwoHandLift script: the palms 1-2 cm from the faces

    def __init__(self):
        self.script = None

    def params(self):
        from softhand_sim.params import load_params
        return load_params("sim_node")

    def objects(self, assets):
        from softhand_sim.scenarios.bimanual import TwoHandLift
        from softhand_sim.scene import load_scene
        self.assets = assets
        self.scene = load_scene()
        self.script = TwoHandLift(self.scene)
        return [self.scene.object(self.script.box)]

    def contacts(self, model):
        from softhand_sim.physics.contact import detection as contact
        from softhand_sim.physics.hands import union_asset
        from softhand_sim.scene import Scene
        box = self.scene.object(self.script.box)
        return contact.build_contact_system(model, Scene(-1.0, 0.5, (box,)), union_asset(self.assets))

    def __call__(self, solver, state, control):
        from softhand_sim.runtime import _pose_transform
        model = solver.model
        first = self.script.targets(self.T0)
        for h, side in enumerate(("right", "left")):  # place each hand at its first targets
            bones = model.hands.bones(h)
            rot, dq, shift = _pose_transform(first[side][0], model.body_rest_pose[bones.start])
            nodes = model.hands.nodes(h)
            state.node_x[nodes] = model.node_rest[nodes] @ rot.T + shift
            for b, pose in zip(range(bones.start, bones.stop), first[side]):
                state.set_body_pose(model, b, pose)

        def update(k, t):
            for h, (side, poses) in enumerate(self.script.targets(self.T0 + t).items()):
                control.set_hand_targets(model, h, poses)
        return update


SCENARIOS_TWO_HANDS = {"free": _TwoHands(_Free()), "press": _TwoHands(_Press()), "grasp": _TwoHandGrasp()}


def stage_profile(step_ms, stage_ms):
    """{stage: {median_ms, p99_ms, share}} from the per-step totals step_ms (S,) [ms] and
    stage_ms {name: (S,)} [ms]; `other` = step - the stages' sum, share = stage total / step total."""
    step_ms = np.asarray(step_ms, float)
    cols = {name: np.asarray(v, float) for name, v in stage_ms.items()}
    cols["other"] = step_ms - sum(cols.values())
    total = float(step_ms.sum())
    return {name: {"median_ms": float(np.median(v)), "p99_ms": float(np.percentile(v, 99)),
                   "share": float(v.sum() / total) if total > 0 else float("nan")}
            for name, v in cols.items()}


def check_case(scenario, hands):
    """The scenario table for `hands` hands (SCENARIOS or SCENARIOS_TWO_HANDS); ValueError naming
    the bad value unless it has `scenario`."""
    if hands not in (1, 2):
        raise ValueError(f"--hands {hands}: expected 1 or 2")
    scenes = SCENARIOS if hands == 1 else SCENARIOS_TWO_HANDS
    if scenario not in scenes:
        raise ValueError(f"--scenario {scenario} with --hands {hands}: the {hands}-hand scenarios are "
                         f"{', '.join(sorted(scenes))}")
    return scenes


def parse_settings(items):
    """--set KEY=VALUE items -> {key: value}, each checked as a sim_node parameter (ValueError
    naming the bad item); preconditioner and solver_threads have options of their own."""
    from softhand_sim.params import check_value, safe_load
    out = {}
    for item in items or ():
        key, eq, text = item.partition("=")
        if not eq:
            raise ValueError(f"--set {item!r}: expected KEY=VALUE, e.g. --set factor_hold=0")
        own = {"preconditioner": "--preconditioner", "solver_threads": "--threads"}
        if key in own:
            raise ValueError(f"--set {item!r}: use {own[key]}")
        out[key] = check_value("sim_node", key, safe_load(text))
    return out


def run(scenario, mesh, steps, preconditioner, hands=1, profile=False, threads=1, settings=None, series=False):
    """One case: `steps` steps after a compiling warm-up; its row (COLUMNS and more; with profile
    `stages` and `factor_cost`, with series every step's time `step_ms`)."""
    from softhand_sim.physics.model import build_model
    from softhand_sim.physics.solver import STAGE_FIELDS, Solver
    scenes = check_case(scenario, hands)
    asset, source = _asset(mesh)
    if hands == 2:
        asset = [asset, _asset(mesh, "left")[0]]
    objects = getattr(scenes[scenario], "objects", None)  # scenarios may add rigid objects
    params = getattr(scenes[scenario], "params", dict)()   # ... and their own solver parameters
    model = build_model(asset, {**params, **(settings or {}), "preconditioner": preconditioner,
                                "solver_threads": threads},
                        objects=objects(asset) if objects else ())
    t0 = time.perf_counter()
    contacts = getattr(scenes[scenario], "contacts", lambda model: None)  # ... and contact
    self_contacts = getattr(scenes[scenario], "self_contacts", lambda model: None)  # ... and skin on skin
    warm = Solver(model, contacts=contacts(model), self_contacts=self_contacts(model))  # compile once
    ws, wc = model.initial_state(), model.control()
    scenes[scenario](warm, ws, wc)(0, 0.0)
    warm.step(ws, wc, DT)
    compile_s = time.perf_counter() - t0
    solver = Solver(model, contacts=contacts(model), self_contacts=self_contacts(model))
    state, control = model.initial_state(), model.control()
    update = scenes[scenario](solver, state, control)
    ms, setup, solve, iters, contacts, coll, caps, refac, held = [], [], [], [], [], [], 0, 0, 0
    self_n, self_ms = [], []
    stage_ms = {name: [] for name, _ in STAGE_FIELDS}
    for k in range(steps):
        update(k, k * DT)
        t = time.perf_counter()
        st = solver.step(state, control, DT)
        ms.append((time.perf_counter() - t) * 1e3)
        setup.append(st.setup_ms)
        solve.append(st.solve_ms)
        iters.append(st.cg_iters)
        contacts.append(st.contacts)
        coll.append(st.collision_ms)
        self_n.append(st.self_contacts)
        self_ms.append(st.self_collision_ms)
        caps += st.hit_cap
        refac += st.refactored
        held += st.held
        for name, f in STAGE_FIELDS:
            stage_ms[name].append(getattr(st, f))
    ms = np.array(ms)
    row = {
        "hands": hands, "threads": threads, "mesh": mesh, "source": source, "tets": int(len(model.tets)),
        "dofs": int(model.dof_count),
        "nnz": int(len(model.indices)), "scenario": scenario, "preconditioner": preconditioner,
        "steps": steps, "median_ms": float(np.median(ms)), "mean_ms": float(ms.mean()), "p99_ms": float(np.percentile(ms, 99)),
        "max_ms": float(ms.max()), "steps_per_s": float(1e3 / np.median(ms)),
        "setup_ms": float(np.median(setup)), "solve_ms": float(np.median(solve)),
        "cg_iters_median": float(np.median(iters)), "cg_iters_max": int(max(iters)),
        "cg_hit_cap": int(caps), "refactors": int(refac), "factor_held": int(held),
        "contacts_median": float(np.median(contacts)), "collision_ms": float(np.median(coll)),
        "self_contacts_median": float(np.median(self_n)), "self_collision_ms": float(np.median(self_ms)),
        "compile_s": compile_s, "finite": bool(np.all(np.isfinite(state.node_x))),
        "paper_steps_per_s": PAPER_STEPS_PER_S, "settings": dict(settings or {}),
    }
    if series:
        row["step_ms"] = ms.tolist()
    if profile:
        row["stages"] = stage_profile(ms, stage_ms)
        if preconditioner == "factor":
            row["factor_cost"] = factor_cost(solver, state)
    return row


def factor_cost(solver, state, repeats=7):
    """The factor preconditioner's cost model (pcg.Factor.analyse) against this machine: a whole
    factorization of the last step's matrix and one CG iteration on it, timed after the run (medians
    of `repeats`; an iteration = the difference between CG runs capped at 12 and 2 iterations at
    tolerance 0, over the difference of the iterations they ran). {factor_ms, iteration_ms,
    measured: their ratio, estimated: the model's, slices, matching_scale: the factor_cost_scale
    that would make the estimate the measured ratio}.
    factor_hold's budget, the kept factor's iteration limit and the slice count all read the
    estimate: far from the measured ratio, they are off by as much."""
    from softhand_sim.physics.pcg import NO_LOW_RANK
    m, f, clock = solver.model, solver.factor, time.perf_counter
    v0, tol = state.v.copy(), solver.cg_tol

    def timed(call):
        t = []
        for _ in range(repeats):
            t0 = clock()
            out = call()
            t.append(clock() - t0)
        return float(np.median(t)) * 1e3, out

    def cg(n):
        state.v[:] = v0
        return solver._pcg(state, NO_LOW_RANK, 0.0, n)[0]

    factor_ms = timed(lambda: f.refresh(m.indptr, m.indices, solver.values))[0]
    solver.cg_tol = 0.0  # every run to its cap (unless the residual vanishes exactly)
    try:
        (long_ms, n_long), (short_ms, n_short) = timed(lambda: cg(12)), timed(lambda: cg(2))
        iteration_ms = (long_ms - short_ms) / (n_long - n_short) if n_long > n_short else float("nan")
    finally:
        solver.cg_tol = tol
        state.v[:] = v0
    measured = factor_ms / iteration_ms if iteration_ms > 0 else float("nan")
    return {"factor_ms": factor_ms, "iteration_ms": iteration_ms, "measured": measured,
            "estimated": float(f.iterations_per_factor), "slices": int(f.slices),
            "matching_scale": f.cost_scale * measured / f.iterations_per_factor}


COLUMNS = ["hands", "threads", "scenario", "mesh", "tets", "dofs", "preconditioner", "median_ms", "p99_ms",
           "steps_per_s", "setup_ms", "solve_ms", "cg_iters_median", "cg_hit_cap", "refactors", "factor_held",
           "contacts_median", "collision_ms", "self_contacts_median", "self_collision_ms", "compile_s"]


def format_table(rows):
    lines = [" ".join(f"{c:>15}" for c in COLUMNS)]
    for r in rows:
        lines.append(" ".join(f"{r[c]:>15.3f}" if isinstance(r[c], float) else f"{r[c]!s:>15}"
                              for c in COLUMNS))
    lines.append(f"paper: {PAPER_STEPS_PER_S} steps/s (856 tets, one i7-5820K core; "
                 "Fig. 9: setup ~ solve ~ 10 ms)")
    for r in rows:
        if "stages" in r:
            lines.append(format_profile(r))
    return "\n".join(lines)


def format_profile(row):
    """The --profile block of one row: median, p99 and share of the step per stage."""
    lines = [f"\nprofile: {row['scenario']}, {row['mesh']} ({row['tets']} tets), {row['hands']} hand(s), "
             f"{row['preconditioner']}, {row['threads']} thread(s): step median {row['median_ms']:.3f} ms, "
             f"p99 {row['p99_ms']:.3f} ms",
             f"{'stage':>15} {'median_ms':>10} {'p99_ms':>10} {'share':>7}"]
    for name, s in row["stages"].items():
        lines.append(f"{name:>15} {s['median_ms']:>10.3f} {s['p99_ms']:>10.3f} {100 * s['share']:>6.1f}%")
    c = row.get("factor_cost")
    if c:
        lines.append(f"factor: {c['factor_ms']:.3f} ms = {c['measured']:.1f} CG iterations of "
                     f"{c['iteration_ms']:.4f} ms (estimated: {c['estimated']:.1f}; "
                     f"{c['slices']} slice(s); --set factor_cost_scale={c['matching_scale']:.2f} "
                     f"would match)")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(prog="softhand bench", description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", choices=sorted(SCENARIOS), action="append")
    ap.add_argument("--mesh", choices=MESHES, action="append")
    ap.add_argument("--preconditioner", choices=PRECONDITIONERS, action="append",
                    help="PCG preconditioner (repeat for several; default factor); two_level: for the "
                         "fine mesh")
    ap.add_argument("--all-preconditioners", action="store_true",
                    help="run every preconditioner (the default factor, two_level, block_jacobi, the "
                         "paper's jacobi)")
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--hands", default="1",
                    help="hands in the model: 1, 2 or 1,2 (both counts); two hands run "
                         f"{', '.join(sorted(SCENARIOS_TWO_HANDS))}")
    ap.add_argument("--threads", default="1",
                    help="solver_threads: 1, 2 or 1,2 (both); 2 runs the two hands' tissue, "
                         "factorization and solves on two cores (--hands 2 only; the default 1 is the "
                         "one-core figure)")
    ap.add_argument("--profile", action="store_true",
                    help="split the step into its stages (median, p99, share of the step per stage); "
                         "with the factor preconditioner also time a factorization against a CG "
                         "iteration (the factor_hold unit; factor_cost_scale to match)")
    ap.add_argument("--set", action="append", metavar="KEY=VALUE", dest="settings",
                    help="a sim_node solver parameter for every case (repeat for several), e.g. "
                         "--set factor_hold=0 (`softhand params sim_node` lists them)")
    ap.add_argument("--plot", metavar="FILE.png",
                    help="also draw the cases (implies --profile): each mean step split by stage with "
                         "its median and p99, and every step in run order")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    if a.plot:
        a.profile = True
        if not a.plot.lower().endswith(".png"):
            ap.error(f"--plot {a.plot}: a .png file")
    if a.steps < 1:
        ap.error(f"--steps={a.steps}: must be >= 1")
    precs = list(PRECONDITIONERS) if a.all_preconditioners else (a.preconditioner or ["factor"])
    try:
        counts = [int(h) for h in a.hands.split(",")]
    except ValueError:
        ap.error(f"--hands {a.hands!r}: expected 1, 2 or 1,2")
    try:
        threads = [int(t) for t in a.threads.split(",")]
    except ValueError:
        ap.error(f"--threads {a.threads!r}: expected 1, 2 or 1,2")
    if any(t < 1 for t in threads):
        ap.error(f"--threads {a.threads!r}: must be >= 1")
    if max(threads) > 1 and counts != [2]:
        ap.error(f"--threads {a.threads} needs --hands 2 (one hand runs on one thread)")
    scenarios = a.scenario or ["free", "press"]
    try:
        settings = parse_settings(a.settings)
        for h in counts:  # every case checked before the first one runs (a minute each)
            for s in scenarios:
                check_case(s, h)
        rows = [run(s, m, a.steps, p, h, a.profile, t, settings, series=bool(a.plot)) for h in counts
                for m in (a.mesh or ["coarse", "fine"]) for s in scenarios for p in precs for t in threads]
    except ValueError as e:
        ap.error(str(e))
    print(json.dumps(rows, indent=1) if a.json else format_table(rows))
    if a.plot:
        from softhand_sim.commands.bench_plot import plot_profile
        plot_profile(rows, a.plot)
        print(f"wrote {a.plot}", file=sys.stderr if a.json else sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
