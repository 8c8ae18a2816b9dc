"""Static contact data (built once): skin points with their areas, and the scene objects with
their signed distance grids packed into flat arrays for the numba kernels of contact.py.

Skin points: "skin" = the embedded high-resolution skin vertices, each mapped to the 4 nodes of
its tet through barycentric weights (paper Sect. 5.1); "surface" = the tet-mesh surface nodes
(weights (1, 0, 0, 0)). Areas w [m^2]: a third of the adjacent triangles' rest areas.
Objects: every scene object (dynamic ones are solver bodies, static ones keep their scene pose),
then the ground half-space, last, named "ground".
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softhand_sim.physics.contact import sdf

KIND_GRID, KIND_HALFSPACE = 0, 1


def vertex_areas(vertices, triangles):
    """A third of the adjacent triangles' areas per vertex (V,) [m^2]."""
    v = np.asarray(vertices, float)
    t = np.asarray(triangles, np.int64)
    area = 0.5 * np.linalg.norm(np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]), axis=1)
    out = np.zeros(len(v))
    np.add.at(out, t.ravel(), np.repeat(area / 3.0, 3))
    return out


@dataclass
class ContactModel:
    """Static contact data: skin points, objects (grids packed flat), stiffness."""
    point_nodes: np.ndarray   # (P,4) i4 tissue nodes of each skin point
    point_bary: np.ndarray    # (P,4) weights
    point_bary_body: np.ndarray  # (P,4) weights used against dynamic objects (see body_weights)
    point_area: np.ndarray    # (P,) [m^2]
    point_hand: np.ndarray    # (P,) i4 hand index (model.hands) of each skin point
    point_tet: np.ndarray     # (P,) i4 the tet whose nodes, in order, are point_nodes (-1: a surface node)
    hand_point0: np.ndarray   # (H+1,) i8 the points of hand h are hand_point0[h]:hand_point0[h+1]
    hand_code: np.ndarray     # (H,) u1 the contacts' `hand` field per hand: 0 right, 1 left
    object_names: list        # (O,) scene object names, then "ground"
    obj_kind: np.ndarray      # (O,) i4 KIND_GRID / KIND_HALFSPACE
    obj_body: np.ndarray      # (O,) i4 solver body, -1 static
    obj_pose: np.ndarray      # (O,7) scene pose (used for static objects)
    obj_com: np.ndarray       # (O,3) [m] COM in the object frame
    obj_lo: np.ndarray        # (O,3) [m] object-frame bounding box
    obj_hi: np.ndarray
    obj_mu: np.ndarray        # (O,) Coulomb coefficient
    grid_values: np.ndarray   # concatenated float32 grids
    grid_adr: np.ndarray      # (O,2) i8 [start, end) in grid_values
    grid_origin: np.ndarray   # (O,3)
    grid_voxel: np.ndarray    # (O,)
    grid_dims: np.ndarray     # (O,3) i4
    ground_height: float
    kn: float                 # [N/m^3]
    kf: float                 # [N/m^3]
    grids: list               # sdf.DistanceGrid per object (None for the ground), for reports

    @property
    def point_count(self):
        return self.point_nodes.shape[0]

    @property
    def hand_count(self):
        return self.hand_point0.shape[0] - 1

    @property
    def object_count(self):
        return self.obj_kind.shape[0]


def body_weights(model, nodes, bary):
    """Barycentric weights (P,4) restricted to the nodes the model's Hessian pattern couples to
    object bodies (model.surface_nodes, see model.py), renormalised. A skin vertex lies at or just
    under its tet's surface face, so the dropped interior-node weight is small; using these
    weights against dynamic objects keeps every node-body Hessian entry of a contact inside the
    pattern (a contact Hessian with some node-body blocks dropped would not stay PSD). Points
    whose tet has no coupled node keep their weights (their node-body entries are skipped)."""
    coupled = np.zeros(model.node_count, bool)
    coupled[np.asarray(model.surface_nodes, np.int64)] = True
    w = np.where(coupled[nodes], bary, 0.0)
    total = w.sum(axis=1, keepdims=True)
    return np.ascontiguousarray(np.where(total > 0.0, w / np.maximum(total, 1e-300), bary))


def hand_of_points(model, nodes):
    """(point_hand (P,) i4, hand_point0 (H+1,) i8): the hand of each skin point (the hand owning
    its tet's nodes, model.hands) and where each hand's points start. The points come hand after
    hand (skin_points keeps the model's node order), which the per-hand broad phase relies on."""
    layout = getattr(model, "hands", None)
    node0 = np.asarray(layout.node0 if layout is not None else [0, model.node_count], np.int64)
    hand = (np.searchsorted(node0, np.asarray(nodes, np.int64)[:, 0], side="right") - 1).astype(np.int32)
    if np.any(np.diff(hand) < 0):
        raise ValueError("skin points are not ordered hand after hand")
    return hand, np.searchsorted(hand, np.arange(len(node0)), side="left").astype(np.int64)


def hand_codes(model, count):
    """(H,) u1 the `hand` code of each hand (physics/hands.HAND_CODE; right when unknown)."""
    layout = getattr(model, "hands", None)
    if layout is None:
        return np.zeros(count, np.uint8)
    return np.array([layout.code(h) for h in range(count)], np.uint8)


def skin_points(model, asset=None, points="surface"):
    """(nodes (P,4), bary (P,4), area (P,), tet (P,)) for points="skin" (embedded skin vertices,
    needs the HandAsset; tet: the tet each is embedded in) or "surface" (tet surface nodes, areas
    from the tet surface triangles; tet -1)."""
    if points == "skin":
        if asset is None:
            raise ValueError("points='skin' needs the HandAsset (skin_vertices, skin_triangles)")
        tet = np.ascontiguousarray(model.skin_tet, np.int32)
        nodes = np.ascontiguousarray(model.tets[tet], np.int32)
        area = vertex_areas(asset.skin_vertices, asset.skin_triangles)
        return nodes, np.ascontiguousarray(model.skin_bary, float), area, tet
    if points == "surface":
        tris = getattr(asset, "tet_surface_triangles", None) if asset is not None else None
        if tris is None:
            tris = tet_boundary_triangles(model.tets)
        area = vertex_areas(model.node_rest, tris)
        sn = np.unique(np.asarray(tris, np.int32))
        nodes = np.repeat(sn[:, None], 4, axis=1).astype(np.int32)
        bary = np.zeros((len(sn), 4))
        bary[:, 0] = 1.0
        return nodes, bary, area[sn], np.full(len(sn), -1, np.int32)
    raise ValueError(f"points={points!r}: expected 'skin' or 'surface'")


def build_contact_model(model, scene, asset=None, points="surface", kn=3.0e7, kf=1.5e7,
                        object_bodies=None, grids=None):
    """ContactModel for a solver Model and a softhand_sim.scene.Scene.

    object_bodies: {object name: solver body index} for dynamic objects; default: the scene's
    dynamic objects in order at bodies bone_count, bone_count + 1, ... (as build_model(objects=
    scene.dynamic_objects) places them). Dynamic objects without a body are treated as static.
    grids: optional {name: sdf.DistanceGrid} to reuse grids already built.
    """
    if kn <= 0 or kf <= 0:
        raise ValueError(f"contact stiffness must be > 0, got kn={kn!r}, kf={kf!r}")
    nodes, bary, area, tet = skin_points(model, asset, points)
    if object_bodies is None:
        object_bodies = {o.name: model.bone_count + i for i, o in enumerate(scene.dynamic_objects)}
    names, kind, body, pose, com, lo, hi, mu, grid_list = [], [], [], [], [], [], [], [], []
    for o in scene.objects:
        g = (grids or {}).get(o.name) or sdf.build_object_grid(o)
        b = -1 if o.static else int(object_bodies.get(o.name, -1))
        if b >= model.body_count:
            raise ValueError(f"object {o.name!r}: body {b} >= model body_count {model.body_count}")
        names.append(o.name)
        kind.append(KIND_GRID)
        body.append(b)
        pose.append(o.pose)
        com.append(model.body_com_local[b] if b >= 0 else np.zeros(3))
        blo, bhi = (g.origin, g.origin + g.voxel * (g.dims - 1))
        band = sdf.GRID_BAND * g.voxel
        lo.append(blo + band)
        hi.append(bhi - band)
        mu.append(o.friction)
        grid_list.append(g)
    names.append("ground")
    kind.append(KIND_HALFSPACE)
    body.append(-1)
    pose.append(np.array([0, 0, 0, 0, 0, 0, 1.0]))
    com.append(np.zeros(3))
    lo.append(np.full(3, -np.inf))
    hi.append(np.full(3, np.inf))
    mu.append(scene.ground_friction)
    grid_list.append(None)
    sizes = [len(g.values) if g is not None else 0 for g in grid_list]
    ends = np.cumsum(sizes)
    adr = np.stack([ends - sizes, ends], axis=1).astype(np.int64)
    values = (np.concatenate([g.values for g in grid_list if g is not None]) if any(sizes)
              else np.zeros(1, np.float32))
    point_hand, hand_point0 = hand_of_points(model, nodes)
    return ContactModel(
        point_nodes=nodes, point_bary=bary, point_bary_body=body_weights(model, nodes, bary),
        point_area=area, point_hand=point_hand, point_tet=tet, hand_point0=hand_point0,
        hand_code=hand_codes(model, len(hand_point0) - 1), object_names=names,
        obj_kind=np.array(kind, np.int32), obj_body=np.array(body, np.int32),
        obj_pose=np.array(pose, float), obj_com=np.array(com, float), obj_lo=np.array(lo, float),
        obj_hi=np.array(hi, float), obj_mu=np.array(mu, float), grid_values=values, grid_adr=adr,
        grid_origin=np.array([g.origin if g is not None else np.zeros(3) for g in grid_list]),
        grid_voxel=np.array([g.voxel if g is not None else 1.0 for g in grid_list]),
        grid_dims=np.array([g.dims if g is not None else np.full(3, 2) for g in grid_list], np.int32),
        ground_height=float(scene.ground_height), kn=float(kn), kf=float(kf), grids=grid_list)


def tet_boundary_triangles(tets):
    """Boundary faces (S,3) of a positively oriented tet mesh, oriented outward."""
    t = np.asarray(tets, np.int64)
    # faces opposite each vertex, ordered so that their normal points away from that vertex
    faces = np.concatenate([t[:, [1, 2, 3]], t[:, [0, 3, 2]], t[:, [0, 1, 3]], t[:, [0, 2, 1]]])
    key = np.sort(faces, axis=1)
    _, idx, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    return faces[idx[counts == 1]].astype(np.int32)
