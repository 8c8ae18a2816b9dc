"""Coulomb stick/slip and resting contact of a soft block on the ground (paper Sect. 3.5).

A 4 x 4 x 2 cm block of 24 tets (Kuhn split of 2 x 2 x 1 cubes), tissue defaults of the solver,
rests on the static ground z = 0 with mu = 0.5. The incline is modelled by tilting gravity by
theta about y (equivalent to tilting the plane). Contact points: the tet surface nodes.
"""
import numpy as np
import pytest

from tests.support.solver_fixtures import box_asset
from softhand_sim.physics.contact import detection as contact
from softhand_sim.physics.model import build_model
from softhand_sim.scene import Scene
from softhand_sim.physics.solver import Solver

MU = 0.5
DT = 1.0 / 200.0
G = 9.81


def _block(tan_theta, mu=MU):
    model = build_model(box_asset((0.04, 0.04, 0.02), (2, 2, 1)),
                        {"cg_tolerance": 1e-8, "cg_max_iterations": 500, "gravity_tissue": True})
    system = contact.build_contact_system(model, Scene(0.0, mu, ()), kn=3.0e7, kf=1.5e7)
    solver = Solver(model, contacts=system)
    theta = np.arctan(tan_theta)
    solver.gravity[:] = G * np.array([np.sin(theta), 0.0, -np.cos(theta)])
    return model, solver, system, model.initial_state()


def _com(model, state):
    return (state.node_x * model.node_mass[:, None]).sum(0) / model.node_mass.sum()


def _run(tan_theta, seconds, cone_log=None):
    model, solver, system, state = _block(tan_theta)
    control = model.control()
    com = []
    for _ in range(int(round(seconds / DT))):
        before = state.copy()
        solver.step(state, control, DT)
        com.append(_com(model, state))
        if cone_log is not None:  # the step's anchors (collide stage) at the positions it saw
            out = system.output(before.node_x, before.body_x, before.body_q, cap_friction=False)
            fn = np.linalg.norm(out["force_normal"], axis=1)
            ff = np.linalg.norm(out["force_friction"], axis=1)
            cone_log.append(np.max(ff - MU * fn, initial=0.0))
    return model, system, state, np.array(com)


@pytest.mark.parametrize("tan_theta", [MU - 0.05, MU + 0.05])
def test_incline_sticks_below_and_slides_above_the_cone(tan_theta):
    """The block sticks for tan(theta) = mu - 0.05 (creep < 0.1 mm/s after settling) and slides for
    mu + 0.05 with acceleration within 15% of g (sin theta - mu cos theta)."""
    model, system, state, com = _run(tan_theta, 1.0)
    vel = np.diff(com[:, 0]) / DT
    theta = np.arctan(tan_theta)
    if tan_theta < MU:
        assert abs(vel[-50:]).max() < 1e-4
        assert com[-1, 0] - com[0, 0] < 1e-3
    else:
        t = np.arange(len(vel)) * DT
        half = len(vel) // 2
        accel = np.polyfit(t[half:], vel[half:], 1)[0]
        expected = G * (np.sin(theta) - MU * np.cos(theta))
        assert accel == pytest.approx(expected, rel=0.15)
        assert system.output(state.node_x, state.body_x, state.body_q)["slip"].all()


def test_friction_cone_holds_after_every_anchor_update():
    """Right after each anchor update |f_f| <= mu |f_n| per contact, within 1e-9 N, on the
    sliding incline (where the cone is active at every step)."""
    log = []
    _run(MU + 0.1, 0.3, cone_log=log)
    assert len(log) == 60
    assert max(log) < 1e-9


def test_resting_block_normal_force_equals_weight():
    """A block at rest on the ground: the summed normal force equals its weight within 2%, and
    the penetration is in the millimetre range the stiffness was chosen for."""
    model, system, state, com = _run(0.0, 0.5)
    out = system.output(state.node_x, state.body_x, state.body_q)
    weight = model.node_mass.sum() * G
    assert out["force_normal"][:, 2].sum() == pytest.approx(weight, rel=0.02)
    assert np.linalg.norm(out["force_friction"].sum(0)) < 0.02 * weight  # no net tangential push
    assert -state.node_x[:, 2].min() < 2e-3
    assert (out["objects"] == system.model.object_names.index("ground")).all()
