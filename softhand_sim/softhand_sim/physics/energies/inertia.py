"""Kinetic (inertia) term of the one-Newton-step backward Euler system, Eq. 4 of the paper:

    (M + dt^2 H) v_new = M v - dt grad U

M is diagonal for tissue nodes (lumped mass [kg]) and per rigid body diag(m I, R I_c R^T)
(linear mass [kg], world inertia about the centre of mass [kg m^2], R the body rotation). The
gyroscopic term w x (I w) is ignored (stated choice: at hand speeds it is far below the coupling
torques, and dropping it keeps the system symmetric).
"""
import numpy as np
from numba import njit

from softhand_sim.physics.rotations import quat_to_matrix


@njit(cache=True)
def body_world_inertia(body_q, body_inertia_local, b):
    R = quat_to_matrix(body_q[b])
    return R @ body_inertia_local[b] @ R.T


@njit(cache=True)
def finalize_system(values, rhs, grad, v, dt, node_mass, body_mass, body_q, body_inertia_local,
                    diag_slot, body_slots, body_dof0):
    """values <- M + dt^2 values (values holds H on entry); rhs <- M v - dt grad."""
    dt2 = dt * dt
    for i in range(values.shape[0]):
        values[i] *= dt2
    for n in range(node_mass.shape[0]):
        for i in range(3):
            d = 3 * n + i
            values[diag_slot[d]] += node_mass[n]
            rhs[d] = node_mass[n] * v[d] - dt * grad[d]
    for b in range(body_mass.shape[0]):
        I = body_world_inertia(body_q, body_inertia_local, b)
        o = body_dof0 + 6 * b
        for i in range(3):
            values[body_slots[b, i, i]] += body_mass[b]
            rhs[o + i] = body_mass[b] * v[o + i] - dt * grad[o + i]
            acc = 0.0
            for j in range(3):
                values[body_slots[b, 3 + i, 3 + j]] += I[i, j]
                acc += I[i, j] * v[o + 3 + j]
            rhs[o + 3 + i] = acc - dt * grad[o + 3 + i]


@njit(cache=True)
def kinetic_energy(v, node_mass, body_mass, body_q, body_inertia_local, body_dof0):
    """1/2 v^T M v [J]."""
    e = 0.0
    for n in range(node_mass.shape[0]):
        for i in range(3):
            e += 0.5 * node_mass[n] * v[3 * n + i] ** 2
    for b in range(body_mass.shape[0]):
        o = body_dof0 + 6 * b
        I = body_world_inertia(body_q, body_inertia_local, b)
        w = v[o + 3:o + 6]
        e += 0.5 * body_mass[b] * (v[o] ** 2 + v[o + 1] ** 2 + v[o + 2] ** 2)
        e += 0.5 * np.dot(w, I @ w)
    return e
