"""Gravity potential U_g = - sum m g . x [J] over tissue nodes and rigid bodies (centres of mass).

g [m/s^2] (default (0, 0, -9.81)); switched per body class through the masks the model builds
(node_gravity_scale (N,), body_gravity_scale (B,), 1 on / 0 off). Linear in x: no Hessian.
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
