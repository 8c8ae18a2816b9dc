"""Quaternion and rotation helpers shared by the hand solver, the tracking loop and the world.

Quaternions are [x, y, z, w] (the ROS order), unit norm. Rotation vectors (axis * angle) are the
exponential coordinates used for angular velocities and for Eq. 14's relative rotation.
Every function works on single float64 arrays and is numba-compiled so kernels can call it.
"""
import numpy as np
from numba import njit

_SMALL_ANGLE = 1e-8  # below this angle [rad] the series forms of exp/log are exact to fp64
# The polar decomposition's iterations stop once an update would turn the rotation by less than
# this [rad]: forces then change by < 1e-8 relative, far under PCG's tolerance (1e-5). Each
# iteration is a Newton step (polar_update_scalars), so the error squares: in the open-close one
# iteration from the last step's rotation leaves at most 3e-4 rad (the tets turn up to 0.1 rad a
# step), two leave round-off.
POLAR_TOLERANCE = 1e-8


@njit(cache=True, inline="always")
def quat_mul_scalars(ax, ay, az, aw, bx, by, bz, bw):
    """quat_mul on scalars, for allocation-free kernels: the four entries of a * b."""
    return (aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz)


@njit(cache=True)
def quat_mul(a, b):
    """Hamilton product a * b (apply b first, then a)."""
    out = np.empty(4)
    out[0], out[1], out[2], out[3] = quat_mul_scalars(a[0], a[1], a[2], a[3], b[0], b[1], b[2], b[3])
    return out


@njit(cache=True)
def quat_conj(q):
    out = np.empty(4)
    out[0] = -q[0]
    out[1] = -q[1]
    out[2] = -q[2]
    out[3] = q[3]
    return out


@njit(cache=True)
def quat_normalize(q):
    n = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if n == 0.0:
        out = np.zeros(4)
        out[3] = 1.0
        return out
    return q / n


@njit(cache=True, inline="always")
def quat_matrix_entries(x, y, z, w):
    """The nine entries (row major) of the rotation matrix of unit quaternion [x, y, z, w], as
    scalars: allocation-free kernels (the fused tissue kernel) use this; quat_to_matrix fills them."""
    return (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - z * w), 2.0 * (x * z + y * w),
            2.0 * (x * y + z * w), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - x * w),
            2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y))


@njit(cache=True)
def quat_to_matrix_into(q, m):
    """m (3,3) = the rotation matrix of unit quaternion q, in place (loops that run per contact)."""
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = quat_matrix_entries(q[0], q[1], q[2], q[3])
    m[0, 0], m[0, 1], m[0, 2] = m00, m01, m02
    m[1, 0], m[1, 1], m[1, 2] = m10, m11, m12
    m[2, 0], m[2, 1], m[2, 2] = m20, m21, m22
    return m


@njit(cache=True)
def quat_to_matrix(q):
    return quat_to_matrix_into(q, np.empty((3, 3)))


@njit(cache=True)
def matrix_to_quat(m):
    """Rotation matrix -> unit quaternion (Shepperd's method, stable for every rotation)."""
    out = np.empty(4)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0.0:
        s = np.sqrt(tr + 1.0) * 2.0
        out[3] = 0.25 * s
        out[0] = (m[2, 1] - m[1, 2]) / s
        out[1] = (m[0, 2] - m[2, 0]) / s
        out[2] = (m[1, 0] - m[0, 1]) / s
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2.0
        out[3] = (m[2, 1] - m[1, 2]) / s
        out[0] = 0.25 * s
        out[1] = (m[0, 1] + m[1, 0]) / s
        out[2] = (m[0, 2] + m[2, 0]) / s
    elif m[1, 1] > m[2, 2]:
        s = np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2.0
        out[3] = (m[0, 2] - m[2, 0]) / s
        out[0] = (m[0, 1] + m[1, 0]) / s
        out[1] = 0.25 * s
        out[2] = (m[1, 2] + m[2, 1]) / s
    else:
        s = np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2.0
        out[3] = (m[1, 0] - m[0, 1]) / s
        out[0] = (m[0, 2] + m[2, 0]) / s
        out[1] = (m[1, 2] + m[2, 1]) / s
        out[2] = 0.25 * s
    if out[3] < 0.0:
        out = -out
    return quat_normalize(out)


@njit(cache=True)
def quat_rotate(q, v):
    """Rotate vector v by q."""
    return quat_to_matrix(q) @ v


@njit(cache=True)
def quat_exp(rotvec):
    """Rotation vector (axis * angle) [rad] -> quaternion."""
    angle = np.sqrt(rotvec[0] ** 2 + rotvec[1] ** 2 + rotvec[2] ** 2)
    out = np.empty(4)
    if angle < _SMALL_ANGLE:
        out[0] = 0.5 * rotvec[0]
        out[1] = 0.5 * rotvec[1]
        out[2] = 0.5 * rotvec[2]
        out[3] = 1.0
        return quat_normalize(out)
    s = np.sin(0.5 * angle) / angle
    out[0] = s * rotvec[0]
    out[1] = s * rotvec[1]
    out[2] = s * rotvec[2]
    out[3] = np.cos(0.5 * angle)
    return out


@njit(cache=True, inline="always")
def quat_log_scalars(x, y, z, w):
    """quat_log on scalars, for allocation-free kernels: the rotation vector's three entries."""
    if w < 0.0:
        x, y, z, w = -x, -y, -z, -w
    s = np.sqrt(x * x + y * y + z * z)
    if s < _SMALL_ANGLE:
        return 2.0 * x, 2.0 * y, 2.0 * z
    f = 2.0 * np.arctan2(s, w) / s
    return f * x, f * y, f * z


@njit(cache=True)
def quat_log(q):
    """Quaternion -> rotation vector with angle in [0, pi] (shortest arc)."""
    out = np.empty(3)
    out[0], out[1], out[2] = quat_log_scalars(q[0], q[1], q[2], q[3])
    return out


@njit(cache=True)
def integrate_rotation(q, omega_world, dt):
    """Advance orientation q by world-frame angular velocity omega over dt: exp(dt*omega) * q."""
    return quat_normalize(quat_mul(quat_exp(omega_world * dt), q))


@njit(cache=True)
def relative_rotvec(qa, qb):
    """Rotation vector of qa * qb^-1 in world coordinates: the Δθ of Eq. 14 taking b onto a."""
    return quat_log(quat_mul(qa, quat_conj(qb)))


@njit(cache=True)
def cross(a, b):
    """a x b of two 3-vectors, for compiled code (cross3 is the one to call from Python)."""
    out = np.empty(3)
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]
    return out


def cross3(a, b) -> np.ndarray:
    """a x b of two 3-vectors: the same as np.cross, ~20x faster on single vectors (np.cross moves
    axes and normalises them per call: 36 calls were 12 ms of every tracker frame's adapter work)."""
    a0, a1, a2 = float(a[0]), float(a[1]), float(a[2])
    b0, b1, b2 = float(b[0]), float(b[1]), float(b[2])
    return np.array((a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0))


def quat_from_axes(x_axis, z_hint):
    """Quaternion of the frame whose x is `x_axis` and whose z is `z_hint` made orthogonal to x.

    y = z × x (a right-handed frame), as the bone frames of docs/INTERFACE.md are defined. Plain
    numpy (not jitted): used when building frames from tracker joints and hand measures.
    """
    x = np.asarray(x_axis, dtype=np.float64)
    x = x / np.linalg.norm(x)
    z = np.asarray(z_hint, dtype=np.float64)
    z = z - np.dot(z, x) * x
    z = z / np.linalg.norm(z)
    y = np.cross(z, x)
    return matrix_to_quat(np.column_stack((x, y, z)))


@njit(cache=True)
def polar_rotation_update(F, q, iterations):
    """The rotation part of F (3,3), warm-started from q [x,y,z,w]; returns the improved unit
    quaternion (polar_update_scalars on arrays)."""
    out = np.empty(4)
    out[0], out[1], out[2], out[3] = polar_update_scalars(F, q[0], q[1], q[2], q[3], iterations)
    return out


# Newton's step is taken where it is at most this many times Mueller's in length: 1.5x near rest,
# 2x for a tet stretched to twice its length in one axis; past 10x (H nearly singular, far from
# the solution) Newton's quadratic model overshoots. From random starts 10 converged in fewer
# iterations than 3 for inverted tets (median 9 against 22) and as fast otherwise (5-6)
_NEWTON_STEP_RATIO = 10.0


@njit(cache=True)
def polar_update_scalars(F, qx, qy, qz, qw, iterations):
    """The rotation R maximising tr(R^T F) (the polar rotation; for an inverted F the one with the
    smallest singular value's sign flipped, never a reflection), by `iterations` Newton steps
    warm-started from the quaternion (qx, qy, qz, qw); returns the updated quaternion's four
    entries. F (3,3); no allocation (the fused tissue kernel calls it per tet).

    A step turns R by exp([w]) in world axes. With A = F R^T, the objective tr(exp([w])^T A) is to
    second order tr A + g.w - 1/2 w^T H w, g = (A21 - A12, A02 - A20, A10 - A01), H = tr(A) I -
    sym(A), and Newton's step is w = H^-1 g: the error squares each step. Mueller et al. 2016 ("A
    robust method to extract the rotational part of deformations") take w = g / tr A, H replaced
    by tr(A) I: near rest H ~ 2 I, so their step is 2/3 of Newton's and each takes a third off
    the error (three of theirs left 3.6e-3 rad in the open-close where one of these leaves 3e-4,
    at a third of the time). Where H is not positive definite (an inverted or collapsed tet) or
    Newton's step is over _NEWTON_STEP_RATIO times theirs, theirs is taken: it converges from
    anywhere. The exponential map uses its Taylor series below 0.1 rad (truncation < 1e-19)."""
    for _ in range(iterations):
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = quat_matrix_entries(qx, qy, qz, qw)
        a00 = F[0, 0] * r00 + F[0, 1] * r01 + F[0, 2] * r02   # A = F R^T
        a01 = F[0, 0] * r10 + F[0, 1] * r11 + F[0, 2] * r12
        a02 = F[0, 0] * r20 + F[0, 1] * r21 + F[0, 2] * r22
        a10 = F[1, 0] * r00 + F[1, 1] * r01 + F[1, 2] * r02
        a11 = F[1, 0] * r10 + F[1, 1] * r11 + F[1, 2] * r12
        a12 = F[1, 0] * r20 + F[1, 1] * r21 + F[1, 2] * r22
        a20 = F[2, 0] * r00 + F[2, 1] * r01 + F[2, 2] * r02
        a21 = F[2, 0] * r10 + F[2, 1] * r11 + F[2, 2] * r12
        a22 = F[2, 0] * r20 + F[2, 1] * r21 + F[2, 2] * r22
        gx, gy, gz = a21 - a12, a02 - a20, a10 - a01
        tr = a00 + a11 + a22
        s = 1.0 / (abs(tr) + 1e-9)
        wx, wy, wz = gx * s, gy * s, gz * s   # Mueller's step
        h00, h11, h22 = tr - a00, tr - a11, tr - a22
        h01, h02, h12 = -0.5 * (a01 + a10), -0.5 * (a02 + a20), -0.5 * (a12 + a21)
        c00 = h11 * h22 - h12 * h12   # cofactors of the symmetric H
        c01 = h02 * h12 - h01 * h22
        c02 = h01 * h12 - h02 * h11
        c22 = h00 * h11 - h01 * h01
        det = h00 * c00 + h01 * c01 + h02 * c02
        if h00 > 0.0 and c22 > 0.0 and det > 0.0:   # Sylvester: H positive definite
            c11 = h00 * h22 - h02 * h02
            c12 = h01 * h02 - h00 * h12
            inv = 1.0 / det
            nx = (c00 * gx + c01 * gy + c02 * gz) * inv
            ny = (c01 * gx + c11 * gy + c12 * gz) * inv
            nz = (c02 * gx + c12 * gy + c22 * gz) * inv
            if nx * nx + ny * ny + nz * nz <= _NEWTON_STEP_RATIO ** 2 * (wx * wx + wy * wy + wz * wz):
                wx, wy, wz = nx, ny, nz
        a2 = wx * wx + wy * wy + wz * wz
        if a2 < POLAR_TOLERANCE * POLAR_TOLERANCE:
            break
        if a2 < 1e-2:
            h2 = 0.25 * a2  # (angle / 2)^2
            ew = 1.0 - h2 / 2.0 * (1.0 - h2 / 12.0 * (1.0 - h2 / 30.0 * (1.0 - h2 / 56.0)))
            sh = 0.5 * (1.0 - h2 / 6.0 * (1.0 - h2 / 20.0 * (1.0 - h2 / 42.0 * (1.0 - h2 / 72.0))))
            ex, ey, ez = sh * wx, sh * wy, sh * wz
        else:
            angle = np.sqrt(a2)
            sh = np.sin(0.5 * angle) / angle
            ex, ey, ez, ew = sh * wx, sh * wy, sh * wz, np.cos(0.5 * angle)
        nx, ny, nz, nw = quat_mul_scalars(ex, ey, ez, ew, qx, qy, qz, qw)  # q <- normalize(e * q)
        n = np.sqrt(nx * nx + ny * ny + nz * nz + nw * nw)
        if n == 0.0:
            qx, qy, qz, qw = 0.0, 0.0, 0.0, 1.0
        else:
            qx, qy, qz, qw = nx / n, ny / n, nz / n, nw / n
    return qx, qy, qz, qw
