"""Contacts with several objects at once, one of them a dynamic solver body (Sect. 3.1, 3.5)."""
import numpy as np
import pytest

from tests.support.solver_fixtures import box_asset
from softhand_sim.physics.contact import detection as contact
from softhand_sim.physics.model import build_model
from softhand_sim.scene import Scene, SceneObject, shape_inertia
from softhand_sim.physics.solver import Solver

G = 9.81


def _object(name, shape, dims, mass, pose, static):
    inertia = np.zeros((3, 3)) if static else shape_inertia(shape, dims, mass)
    return SceneObject(name, shape, dims, mass, 0.5, np.array(pose, float), static, inertia)


def test_block_between_static_table_and_dynamic_ball():
    """A soft block lies on a static box (SDF grid) and carries a free 0.1 kg ball (a 6-dof body
    of the solver, gravity on, only its rotation held by Eq. 14). At rest the ball's contact
    force equals its weight and the table carries block + ball, each within 2%."""
    table = _object("table", "box", {"size": (0.2, 0.2, 0.1)}, 0.0, [0.02, 0.02, 0.05, 0, 0, 0, 1], True)
    ball = _object("ball", "sphere", {"radius": 0.04}, 0.1, [0.02, 0.02, 0.16, 0, 0, 0, 1], False)
    scene = Scene(0.0, 0.5, (table, ball))
    asset = box_asset((0.04, 0.04, 0.02), (4, 4, 2))
    asset.tet_nodes = asset.tet_nodes + np.array([0.0, 0.0, 0.10])
    model = build_model(asset, {"cg_tolerance": 1e-8, "cg_max_iterations": 500, "gravity_tissue": True}, objects=[ball])
    system = contact.build_contact_system(model, scene)
    solver = Solver(model, contacts=system)
    control = model.control()
    # no pull toward an engine copy, only keep the ball from rolling off the block's apex
    control.set_object_targets(model, np.array([ball.pose]), kx=0.0, ktheta=70.0)
    state = model.initial_state()
    for _ in range(300):
        solver.step(state, control, 1.0 / 200.0)
    out = system.output(state.node_x, state.body_x, state.body_q)
    names = system.model.object_names
    on_table = out["objects"] == names.index("table")
    on_ball = out["objects"] == names.index("ball")
    assert on_table.sum() > 0 and on_ball.sum() > 0
    block_weight = model.node_mass.sum() * G
    ball_weight = 0.1 * G
    # forces on the hand: the table pushes up with both weights, the ball pushes down with its own
    assert out["forces"][on_table, 2].sum() == pytest.approx(block_weight + ball_weight, rel=0.02)
    assert -out["forces"][on_ball, 2].sum() == pytest.approx(ball_weight, rel=0.02)
    assert np.abs(state.body_v[0]).max() < 1e-3
    assert state.body_x[0, 2] == pytest.approx(0.16, abs=2e-3)  # resting on the block's top
