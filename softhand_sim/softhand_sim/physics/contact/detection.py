"""Contact detection, anchors and Coulomb stick/slip between skin points and scene objects
(paper Sect. 3.5; energies in energies/contact.py, Eq. 12-13).

Skin points: either the embedded high-resolution skin vertices (each maps to the 4 nodes of its
tet through barycentric weights) or the tet-mesh surface nodes (weights (1, 0, 0, 0)); see
`build_contact_model(points=...)`. Each point carries its skin area w [m^2] (a third of its
adjacent triangles' rest areas).

Objects: every scene object (its SDF grid, sdf.py) and the static ground half-space z = h. A
dynamic object is a solver body (pose from the state); a static one keeps its scene pose. Several
objects can be touched at once, and one point may touch two objects (a fingertip between ball
and table).

Per (object, point) the state keeps an anchor and normal in the object's frame (they move with
the object). Each step, `collide`:
  - releases contacts whose point left the object (SDF >= 0),
  - updates kept anchors with Coulomb's law: stick while k_f |t| <= mu k_n (n.D) (|f_f| <= mu
    |f_n|), else slide the anchor toward the point until the cone holds, re-project it onto the
    surface (SDF) and take the normal there, then clamp once more tangentially so that the cone
    holds exactly after the update,
  - creates anchors for newly penetrating points at the closest surface point x - d n, with the
    normal n = grad d / |grad d| there,
  - writes the compact list of active contacts that energies/contact.py consumes.
A slipping contact whose point moves away from its anchor (SLIDING) lets the anchor follow the
point during the step (the paper's slip regime): its friction force mu |f_n| enters the step as a
constant force, without stiffness along the slip in the Hessian (energies/contact.add_hessian).
Kept there, the spring would act as a viscous damper c = k_f w dt on sliding and stall a sliding
object (terminal speed 0.1 mm/s for a 35 g test block at 200 Hz). A slipping point that moves
toward its anchor (coming to rest) keeps the full spring, which stops it without overshoot.
"""
from __future__ import annotations

import time

import numpy as np
from numba import njit

from softhand_sim.physics.contact import sdf
from softhand_sim.physics.energies import contact as contact_energy
from softhand_sim.physics.rotations import quat_to_matrix
from softhand_sim.physics.contact.contact_model import KIND_GRID, KIND_HALFSPACE, ContactModel, build_contact_model

STICK, SLIP, SLIDING = 0, 1, 2  # SLIDING: slipping and moving away from the anchor
_CONE_SLACK = 1e-9  # relative slack when clamping onto the friction cone
NEAR_CAP = 0.03  # [m] ContactSystem.near: distances beyond this are not measured (inf)


@njit(cache=True)
def _box_gap(lo, hi, x0, x1, x2):
    """Distance [m] from the point (x0, x1, x2) to the box [lo, hi] (0 inside)."""
    e0 = max(lo[0] - x0, 0.0, x0 - hi[0])
    e1 = max(lo[1] - x1, 0.0, x1 - hi[1])
    e2 = max(lo[2] - x2, 0.0, x2 - hi[2])
    return np.sqrt(e0 * e0 + e1 * e1 + e2 * e2)


@njit(cache=True)
def _distance(kind, adr, values, origin, voxel, dims, ground_h, p):
    if kind == KIND_HALFSPACE:
        return p[2] - ground_h
    return sdf.grid_value(values[adr[0]:adr[1]], origin, voxel, dims, p[0], p[1], p[2])


@njit(cache=True)
def _unit_gradient(kind, adr, values, origin, voxel, dims, p):
    g = np.zeros(3)
    if kind == KIND_HALFSPACE:
        g[2] = 1.0
        return g
    gx, gy, gz = sdf.grid_gradient(values[adr[0]:adr[1]], origin, voxel, dims, p[0], p[1], p[2])
    s = np.sqrt(gx * gx + gy * gy + gz * gz)
    if s > 0.0:
        g[0], g[1], g[2] = gx / s, gy / s, gz / s
    else:
        g[2] = 1.0
    return g


@njit(cache=True)
def _project(kind, adr, values, origin, voxel, dims, ground_h, p, anchor, normal):
    """Closest surface point of object-frame p into anchor, surface normal there into normal."""
    d = _distance(kind, adr, values, origin, voxel, dims, ground_h, p)
    g = _unit_gradient(kind, adr, values, origin, voxel, dims, p)
    for i in range(3):
        anchor[i] = p[i] - d * g[i]
    # one more projection step: on curved surfaces the first is off by O(d^2 / radius)
    d2 = _distance(kind, adr, values, origin, voxel, dims, ground_h, anchor)
    g2 = _unit_gradient(kind, adr, values, origin, voxel, dims, anchor)
    for i in range(3):
        anchor[i] -= d2 * g2[i]
    n = _unit_gradient(kind, adr, values, origin, voxel, dims, anchor)
    normal[:] = n


@njit(cache=True)
def _clamp_to_cone(p, anchor, normal, mu, kn, kf):
    """Slide the anchor tangentially toward p until k_f |t| <= mu k_n (n.D); returns True if it slid."""
    # on scalars: every kept contact passes here each step (no temporaries)
    d0, d1, d2 = anchor[0] - p[0], anchor[1] - p[1], anchor[2] - p[2]
    dn = normal[0] * d0 + normal[1] * d1 + normal[2] * d2
    t0, t1, t2 = d0 - dn * normal[0], d1 - dn * normal[1], d2 - dn * normal[2]
    tl = np.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
    limit = mu * kn * max(dn, 0.0) / kf  # largest tangential offset allowed [m]
    if tl <= limit * (1.0 + _CONE_SLACK):
        return False
    scale = 1.0 - limit / tl
    anchor[0] -= scale * t0
    anchor[1] -= scale * t1
    anchor[2] -= scale * t2
    return True


@njit(cache=True)
def _moving_away(p, b, point_nodes, point_bary, v, body_x, body_dof0, point_x, anchor_world):
    """True when point p moves away from its anchor relative to the object (it is sliding)."""
    rel = np.zeros(3)
    for a in range(4):
        nd = point_nodes[p, a]
        for i in range(3):
            rel[i] += point_bary[p, a] * v[3 * nd + i]
    if b >= 0:
        o6 = body_dof0 + 6 * b
        r = point_x[p] - body_x[b]
        rel[0] -= v[o6] + v[o6 + 4] * r[2] - v[o6 + 5] * r[1]
        rel[1] -= v[o6 + 1] + v[o6 + 5] * r[0] - v[o6 + 3] * r[2]
        rel[2] -= v[o6 + 2] + v[o6 + 3] * r[1] - v[o6 + 4] * r[0]
    s = 0.0
    for i in range(3):
        s += rel[i] * (point_x[p, i] - anchor_world[i])
    return s > 0.0


@njit(cache=True)
def collide_kernel(node_x, body_x, body_q, v, body_dof0, point_nodes, point_bary_static,
                   point_bary_body, point_area, hand_point0, hand_enabled,
                   obj_kind, obj_body, obj_pose, obj_com, obj_lo, obj_hi, obj_mu,
                   grid_values, grid_adr, grid_origin, grid_voxel, grid_dims, ground_h, kn, kf,
                   anchor, normal, active, slip, obj_active, point_x_static, point_x_body,
                   c_point, c_object, c_nodes, c_bary, c_body, c_anchor, c_normal, c_area, c_mu, c_slip,
                   near, near_cap):
    """One detection pass; returns (active contact count, contacts dropped for lack of capacity).

    Hands: the points of hand h are hand_point0[h]:hand_point0[h+1]; a hand with hand_enabled[h]
    == 0 (not in the simulation yet) has no contact. The broad phase is per hand (each hand's
    bounding box against each object), so a second hand far away costs a one-hand pass.
    obj_active (O, H): active contacts per object and hand.
    near (H,): written with each hand's skin-to-object distance [m] where it is below near_cap
    (else inf; 0 while the hand touches an object, at this pass or the last, and then not measured:
    in contact it costs nothing): the lowest skin point's height over the ground, else the SDF
    (for points outside an object's box, its field around the box, at least the distance to the
    box; beyond the field's padding an estimate)."""
    H = hand_point0.shape[0] - 1
    for h in range(H):  # a hand that touched an object at the last pass is near: nothing to measure
        near[h] = np.inf
        for o in range(obj_kind.shape[0]):
            if obj_active[o, h] > 0:
                near[h] = 0.0
    lo = np.full((H, 3), np.inf)   # bounding box of each hand's skin points, for the broad phase
    hi = np.full((H, 3), -np.inf)
    for h in range(H):
        if hand_enabled[h] == 0:
            continue
        # on scalars, each node read once for both weightings: 2.2x faster than the loop over
        # (i, a) with array reads (0.08 against 0.18 ms for a hand's 11,822 skin points)
        l0, l1, l2, h0, h1, h2 = np.inf, np.inf, np.inf, -np.inf, -np.inf, -np.inf
        for p in range(hand_point0[h], hand_point0[h + 1]):
            n0, n1, n2, n3 = point_nodes[p, 0], point_nodes[p, 1], point_nodes[p, 2], point_nodes[p, 3]
            w0, w1, w2, w3 = point_bary_static[p, 0], point_bary_static[p, 1], point_bary_static[p, 2], point_bary_static[p, 3]
            u0, u1, u2, u3 = point_bary_body[p, 0], point_bary_body[p, 1], point_bary_body[p, 2], point_bary_body[p, 3]
            for i in range(3):
                x0, x1, x2, x3 = node_x[n0, i], node_x[n1, i], node_x[n2, i], node_x[n3, i]
                s = w0 * x0 + w1 * x1 + w2 * x2 + w3 * x3
                sb = u0 * x0 + u1 * x1 + u2 * x2 + u3 * x3
                point_x_static[p, i] = s
                point_x_body[p, i] = sb
                if i == 0:
                    l0, h0 = min(l0, s, sb), max(h0, s, sb)
                elif i == 1:
                    l1, h1 = min(l1, s, sb), max(h1, s, sb)
                else:
                    l2, h2 = min(l2, s, sb), max(h2, s, sb)
        lo[h, 0], lo[h, 1], lo[h, 2], hi[h, 0], hi[h, 1], hi[h, 2] = l0, l1, l2, h0, h1, h2
    capacity = c_point.shape[0]
    count = 0
    dropped = 0
    local = np.empty(3)
    a_new = np.empty(3)
    n_new = np.empty(3)
    for o in range(obj_kind.shape[0]):
        kind = obj_kind[o]
        b = obj_body[o]
        if b >= 0:
            R = quat_to_matrix(body_q[b])
            origin = body_x[b] - R @ obj_com[o]
        else:
            R = quat_to_matrix(obj_pose[o, 3:])
            origin = obj_pose[o, :3].copy()
        adr = grid_adr[o]
        vals, gorg, gvox, gdim = grid_values, grid_origin[o], grid_voxel[o], grid_dims[o]
        centre = 0.5 * (obj_lo[o] + obj_hi[o])
        half = 0.5 * (obj_hi[o] - obj_lo[o])
        radius2 = half[0] * half[0] + half[1] * half[1] + half[2] * half[2]
        r = np.sqrt(radius2)
        centre_w = origin + R @ centre
        mu = obj_mu[o]
        # dynamic objects see the skin point through the nodes the Hessian pattern couples to
        # object bodies (contact_model.body_weights), static ones through all four
        point_x = point_x_body if b >= 0 else point_x_static
        point_bary = point_bary_body if b >= 0 else point_bary_static
        for h in range(H):
            if hand_enabled[h] == 0:
                continue
            if kind == KIND_HALFSPACE:
                gap = lo[h, 2] - ground_h  # the lowest skin point's height: exact
            else:  # the hand's box to the object's bounding sphere: a lower bound
                gap = _box_gap(lo[h], hi[h], centre_w[0], centre_w[1], centre_w[2]) - r
            cap = min(near[h], near_cap)  # distances at or beyond this change nothing
            if gap >= 0.0 and obj_active[o, h] == 0:  # nothing to release
                if kind == KIND_HALFSPACE or gap >= cap:  # skip objects away from the hand
                    if gap < cap:
                        near[h] = gap
                    continue
            obj_active[o, h] = 0
            reach = r + cap
            for p in range(hand_point0[h], hand_point0[h + 1]):
                was = active[o, p] != 0
                if kind == KIND_GRID and not was:  # broad phase: bounding sphere, then local box
                    dx = point_x[p, 0] - centre_w[0]
                    dy = point_x[p, 1] - centre_w[1]
                    dz = point_x[p, 2] - centre_w[2]
                    if dx * dx + dy * dy + dz * dz > reach * reach:
                        continue
                for i in range(3):
                    local[i] = (R[0, i] * (point_x[p, 0] - origin[0]) + R[1, i] * (point_x[p, 1] - origin[1])
                                + R[2, i] * (point_x[p, 2] - origin[2]))
                if kind == KIND_GRID and not was:  # outside the object's box: no contact
                    e = _box_gap(obj_lo[o], obj_hi[o], local[0], local[1], local[2])
                    if e > 0.0:  # e bounds the distance from below
                        if e < min(near[h], near_cap):  # the field (padded around the box) decides
                            d = max(e, _distance(kind, adr, vals, gorg, gvox, gdim, ground_h, local))
                            if d < near_cap:
                                near[h] = min(near[h], d)
                        continue
                d = _distance(kind, adr, vals, gorg, gvox, gdim, ground_h, local)
                if d >= 0.0:
                    if d < near_cap:
                        near[h] = min(near[h], d)
                    active[o, p] = 0
                    slip[o, p] = 0
                    continue
                near[h] = 0.0
                if not was:
                    _project(kind, adr, vals, gorg, gvox, gdim, ground_h, local, a_new, n_new)
                    anchor[o, p] = a_new
                    normal[o, p] = n_new
                    active[o, p] = 1
                    slip[o, p] = 0
                else:
                    a_new[:] = anchor[o, p]
                    n_new[:] = normal[o, p]
                    if _clamp_to_cone(local, a_new, n_new, mu, kn, kf):
                        # slid: back onto the surface, normal there, then the cone once more
                        _project(kind, adr, vals, gorg, gvox, gdim, ground_h, a_new, a_new, n_new)
                        _clamp_to_cone(local, a_new, n_new, mu, kn, kf)
                        slip[o, p] = SLIP
                        if _moving_away(p, b, point_nodes, point_bary, v, body_x, body_dof0, point_x,
                                        origin + R @ a_new):
                            slip[o, p] = SLIDING
                    else:
                        slip[o, p] = 0
                    anchor[o, p] = a_new
                    normal[o, p] = n_new
                obj_active[o, h] += 1
                if count >= capacity:
                    dropped += 1
                    continue
                c = count
                count += 1
                c_point[c] = p
                c_object[c] = o
                c_nodes[c] = point_nodes[p]
                c_bary[c] = point_bary[p]
                c_area[c] = point_area[p]
                c_mu[c] = mu
                c_slip[c] = slip[o, p]
                c_body[c] = b
                if b >= 0:  # body axes, relative to the COM
                    for i in range(3):
                        c_anchor[c, i] = anchor[o, p, i] - obj_com[o, i]
                        c_normal[c, i] = normal[o, p, i]
                else:  # world frame
                    c_anchor[c] = origin + R @ anchor[o, p]
                    c_normal[c] = R @ normal[o, p]
    return count, dropped


class ContactSystem:
    """Contact state of one simulation plus the calls the solver's step makes.

    collide(node_x, body_x, body_q)            the collide stage: detection, stick/slip, list
    value / add_gradient / add_hessian(...)    the Eq. 12-13 term over the active list
    add_all(state, model, grad, values)        the same, as the assemble stage calls it
    output(node_x, body_x, body_q)             per-contact arrays for /hand/contacts
    Arrays of the active list (first `count` rows): point (C,) skin point index, object (C,)
    index into model.object_names, slip (C,) u1, plus what energies/contact.py reads.
    """

    def __init__(self, cmodel: ContactModel, capacity=4096):
        self.model = cmodel
        O, P = cmodel.object_count, cmodel.point_count
        self.anchor = np.zeros((O, P, 3))
        self.normal = np.zeros((O, P, 3))
        self.active = np.zeros((O, P), np.uint8)
        self.slip_state = np.zeros((O, P), np.uint8)
        self._point_x = np.zeros((P, 3))
        self._point_x_body = np.zeros((P, 3))
        self._obj_active = np.zeros((O, cmodel.hand_count), np.int64)  # active contacts per object and hand
        self.hand_enabled = np.ones(cmodel.hand_count, np.uint8)  # 0: the hand has no contact (not entered)
        # per hand, its skin's distance to the objects at the last collide [m] (inf beyond
        # NEAR_CAP; 0 in contact; collide_kernel says how it is measured): the target lead's gate
        # (target_lead.py)
        self.near = np.full(cmodel.hand_count, np.inf)
        C = int(capacity)
        self.point = np.zeros(C, np.int32)
        self.object = np.zeros(C, np.int32)
        self.nodes = np.zeros((C, 4), np.int32)
        self.bary = np.zeros((C, 4))
        self.body = np.zeros(C, np.int32)
        self.anchor_list = np.zeros((C, 3))
        self.normal_list = np.zeros((C, 3))
        self.area = np.zeros(C)
        self.mu = np.zeros(C)
        self.slip = np.zeros(C, np.uint8)
        self.count = 0
        self.dropped = 0
        self.collision_ms = 0.0
        self.skipped_entries = 0

    def reset(self, hand=None):
        """Forget every contact (hand=None), or only hand `hand`'s (its points' anchors; the next
        collide rebuilds the active list)."""
        if hand is None:
            self.active[:] = 0
            self.slip_state[:] = 0
            self._obj_active[:] = 0
            self.count = 0
            return
        p = slice(int(self.model.hand_point0[hand]), int(self.model.hand_point0[hand + 1]))
        self.active[:, p] = 0
        self.slip_state[:, p] = 0
        self._obj_active[:, hand] = 0

    def collide(self, node_x, body_x, body_q, v=None, body_dof0=None):
        """Detect, update anchors (stick/slip), build the active list; returns the count.
        v: the solver's flat generalized velocities (model dof layout, bodies from body_dof0),
        used to tell a sliding point (moving away from its anchor) from one coming to rest."""
        m = self.model
        if body_dof0 is None:
            body_dof0 = 3 * node_x.shape[0]
        if v is None:
            v = np.zeros(body_dof0 + 6 * body_x.shape[0])
        t0 = time.perf_counter()
        self.count, self.dropped = collide_kernel(
            node_x, body_x, body_q, v, body_dof0, m.point_nodes, m.point_bary, m.point_bary_body,
            m.point_area, m.hand_point0, self.hand_enabled,
            m.obj_kind, m.obj_body, m.obj_pose, m.obj_com, m.obj_lo, m.obj_hi, m.obj_mu,
            m.grid_values, m.grid_adr, m.grid_origin, m.grid_voxel, m.grid_dims, m.ground_height,
            m.kn, m.kf, self.anchor, self.normal, self.active, self.slip_state, self._obj_active,
            self._point_x, self._point_x_body,
            self.point, self.object, self.nodes, self.bary, self.body, self.anchor_list,
            self.normal_list, self.area, self.mu, self.slip, self.near, NEAR_CAP)
        self.collision_ms = 1e3 * (time.perf_counter() - t0)
        return self.count

    def _args(self, node_x, body_x, body_q):
        return (node_x, body_x, body_q, self.count, self.nodes, self.bary, self.body,
                self.anchor_list, self.normal_list, self.area, self.model.kn, self.model.kf)

    def value(self, node_x, body_x, body_q):
        """Eq. 12 + 13 summed over the active contacts [J]."""
        return contact_energy.value(*self._args(node_x, body_x, body_q))

    def add_gradient(self, node_x, body_x, body_q, body_dof0, grad):
        """Adds dU/dq into grad; returns the energy [J]."""
        return contact_energy.add_gradient(*self._args(node_x, body_x, body_q), body_dof0, grad)

    def add_hessian(self, node_x, body_x, body_q, body_dof0, indptr, indices, values):
        """Adds the Hessian into CSR values; returns the number of entries missing from the pattern."""
        return contact_energy.add_hessian(*self._args(node_x, body_x, body_q), self.slip, body_dof0,
                                          indptr, indices, values)

    # ---- the solver's contact term (Solver.assemble, after the collide stage)
    def add_all(self, state, model, grad, values):
        """Adds the gradient and Hessian of Eq. 12-13 at state (model dof layout and CSR pattern);
        returns the energy [J]."""
        tet = self.model.point_tet[self.point[:self.count]]  # the skin point's tet: its slots
        e, self.skipped_entries = contact_energy.add_all(
            *self._args(state.node_x, state.body_x, state.body_q), self.slip, model.body_dof0, grad,
            model.indptr, model.indices, values, tet, model.tet_slots, model.body_slots)
        return e

    def output(self, node_x, body_x, body_q, cap_friction=True):
        """Per active contact: dict of points (C,3) [m], normals (C,3), forces on the hand (C,3) [N]
        = force_normal + force_friction, objects (C,) u4 (index into model.object_names; the
        ground is the last), slip (C,) u1 (1: the anchor slid at the last update), point (C,) i4,
        hand (C,) u1 (0 right, 1 left: docs/INTERFACE.md's `hand` field).
        Called after a step, the friction force is the one the next anchor update leaves (capped
        at mu |f_n|; cap_friction=False gives the raw spring force): the anchors move only in
        collide()."""
        c = self.count
        pts, nrm, fn, ff = (np.zeros((c, 3)) for _ in range(4))
        contact_energy.contact_forces(*self._args(node_x, body_x, body_q), pts, nrm, fn, ff)
        fn_len = np.linalg.norm(fn, axis=1)
        ff_len = np.linalg.norm(ff, axis=1)
        cap = self.mu[:c] * fn_len
        scale = np.where(ff_len > cap, cap / np.maximum(ff_len, 1e-300), 1.0)
        if cap_friction:
            ff *= scale[:, None]
        return {"points": pts, "normals": nrm, "forces": fn + ff, "force_normal": fn,
                "force_friction": ff, "objects": self.object[:c].astype(np.uint32),
                "slip": (self.slip[:c] > 0).astype(np.uint8), "point": self.point[:c].copy(),
                "hand": self.model.hand_code[self.model.point_hand[self.point[:c]]]}


def build_contact_system(model, scene, asset=None, points="auto", kn=None, kf=None, capacity=8192, **kwargs):
    """The ContactSystem of model and scene, for Solver(model, contacts=...) (its collide stage).
    points: "skin", "surface" or "auto" (the embedded skin when the asset has one, else the tet
    surface nodes). kn, kf [N/m^3] default to the config defaults (3e7, 1.5e7). Extra kwargs go to
    build_contact_model (object_bodies, grids)."""
    if points == "auto":
        has_skin = (asset is not None and getattr(asset, "skin_triangles", None) is not None
                    and len(getattr(model, "skin_tet", ())) > 0)
        points = "skin" if has_skin else "surface"
    kn = 3.0e7 if kn is None else kn
    kf = 1.5e7 if kf is None else kf
    cm = build_contact_model(model, scene, asset, points, kn, kf, **kwargs)
    return ContactSystem(cm, capacity)
