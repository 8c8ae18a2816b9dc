"""The benchmark's scenes (`softhand bench`) stepped in tests: a model of the benchmark's hands
with a scene's objects, a solver, and the scene's steps from the initial state."""
from softhand_sim.commands import bench
from softhand_sim.physics.model import build_model
from softhand_sim.physics.solver import Solver


def run_scene(scene, model, solver, steps, stats=None):
    """`steps` of a benchmark scene from the model's initial state: (state, CG iterations per step);
    each step's StepStats appended to the list `stats` when one is given."""
    state, control = model.initial_state(), model.control()
    update = scene(solver, state, control)
    iterations = []
    for k in range(steps):
        update(k, k * bench.DT)
        step = solver.step(state, control, bench.DT)
        iterations.append(step.cg_iters)
        if stats is not None:
            stats.append(step)
    return state, iterations


def scene_run(scenario, meshes, steps, stats=None, **params):
    """The benchmark's `scenario` with one hand per mesh (right, then left) and solver `params`,
    stepped `steps` times: (model, solver, state, CG iterations per step); `stats` as run_scene's."""
    sides = ("right", "left")
    assets = [bench._asset(mesh, sides[h])[0] for h, mesh in enumerate(meshes)]
    scene = bench.check_case(scenario, len(assets))[scenario]
    asset = assets[0] if len(assets) == 1 else assets
    model = build_model(asset, params, objects=scene.objects(asset))
    solver = Solver(model)
    return (model, solver) + run_scene(scene, model, solver, steps, stats)
