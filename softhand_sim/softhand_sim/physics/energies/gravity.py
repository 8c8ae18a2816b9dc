"""Gravity potential U_g = - sum m g . x [J] over tissue nodes and rigid bodies (centres of mass).

g [m/s^2] (default (0, 0, -9.81)); switched per body class through the masks the model builds
(node_gravity_scale (N,), body_gravity_scale (B,), 1 on / 0 off). Linear in x: no Hessian.
The dead loads of the Control (node_force, body_force; U = -f . x) are the same kind of potential:
`add_loads`.
"""
from numba import njit


@njit(cache=True)
def add_all(x, body_x, node_mass, body_mass, node_scale, body_scale, g, body_dof0, grad):
    """Energy [J]; adds dU_g/dq into grad."""
    e = 0.0
    for n in range(node_mass.shape[0]):
        m = node_mass[n] * node_scale[n]
        for i in range(3):
            e -= m * g[i] * x[n, i]
            grad[3 * n + i] -= m * g[i]
    for b in range(body_mass.shape[0]):
        m = body_mass[b] * body_scale[b]
        for i in range(3):
            e -= m * g[i] * body_x[b, i]
            grad[body_dof0 + 6 * b + i] -= m * g[i]
    return e


@njit(cache=True)
def add_loads(x, body_x, node_force, body_force, body_dof0, grad):
    """Dead loads U = - sum f_n . x_n - sum f_b . x_b [J] of node forces (N,3) and body forces at
    the centres of mass (B,3) [N]; adds dU/dq = -f into grad."""
    e = 0.0
    for n in range(node_force.shape[0]):
        for i in range(3):
            e -= node_force[n, i] * x[n, i]
            grad[3 * n + i] -= node_force[n, i]
    for b in range(body_force.shape[0]):
        for i in range(3):
            e -= body_force[b, i] * body_x[b, i]
            grad[body_dof0 + 6 * b + i] -= body_force[b, i]
    return e
