"""Solver Model: everything fixed after build (rest shape, K0, masses, joints, samples, pattern).

Generalized coordinates (flat, `dof_count` = 3 N + 6 B):
  [0, 3N)            tissue node positions, node n at 3n..3n+2 [m]
  [3N, 3N + 6B)      rigid body b at body_dof0 + 6b: centre-of-mass position (3) [m], then the
                     rotation (3) [rad] as a world-frame left perturbation q <- exp(d) q.
Bodies: the hands' bones first (bone_count, 16 per hand), then rigid objects (object_count).
Several hands: their union (physics/hands.py), hand after hand in nodes, tets and bones;
model.hands (HandLayout) says where each lies. No term couples two hands.
Public poses are bone-frame poses (n,7) [px,py,pz,qx,qy,qz,qw]; internally bodies live at their
centre of mass: com_world = p + R com_local.

Reserved pattern for contact (documented in docs/ARCHITECTURE.md): every tet surface node is
coupled to every object body by a dense 3x6 block, so node-object contact terms add into the
fixed pattern; skin-vertex contacts only touch the 4 nodes of one tet (already coupled).
"""
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np

from softhand_sim.physics.energies import tissue, joints
from softhand_sim.physics.energies.assembly import build_pattern, stencil_slots
from softhand_sim.physics.hands import HandLayout, layout_of, union_asset
from softhand_sim.physics.rotations import quat_to_matrix
from softhand_sim.params import load_params


def model_params(params=None):
    """sim_node's parameters (params.SIM, the one schema) updated with `params`, every value checked.

    build_model and Solver read the schema's names unchanged; an unknown key or a bad value raises
    params.ParamError naming it.
    """
    return load_params("sim_node", overrides=params)


@dataclass
class Model:
    """Static solver data. Arrays: float64 / int32, shapes in comments."""
    params: dict                   # sim_node parameters by their schema names (model_params)
    node_rest: np.ndarray          # (N,3) [m]
    node_mass: np.ndarray          # (N,) [kg]
    tets: np.ndarray               # (T,4)
    tet_volume: np.ndarray         # (T,) [m^3]
    tet_Dm_inv: np.ndarray         # (T,3,3) [1/m]
    tet_K0: np.ndarray             # (T,12,12) [N/m]
    surface_nodes: np.ndarray      # (S,) nodes on the tet boundary
    skin_tet: np.ndarray           # (V,)
    skin_bary: np.ndarray          # (V,4)
    bone_count: int
    object_count: int
    body_mass: np.ndarray          # (B,) [kg]
    body_com_local: np.ndarray     # (B,3) [m] COM in the body (bone) frame
    body_inertia_local: np.ndarray  # (B,3,3) [kg m^2] about the COM, body-frame axes
    body_rest_pose: np.ndarray     # (B,7) bone-frame poses at rest
    body_target_kx: np.ndarray     # (B,) [N/m]
    body_target_ktheta: np.ndarray  # (B,) [N m/rad]
    node_gravity_scale: np.ndarray  # (N,)
    body_gravity_scale: np.ndarray  # (B,)
    joint_parent: np.ndarray       # (J,)
    joint_child: np.ndarray        # (J,)
    joint_r_parent: np.ndarray     # (J,3) [m] anchor - COM, parent frame
    joint_r_child: np.ndarray      # (J,3) [m]
    joint_rest_rotation: np.ndarray  # (J,4)
    jrow_joint: np.ndarray         # (R,) angular rows (hinge/universal locks, limits)
    jrow_axis: np.ndarray          # (R,3)
    jrow_lo: np.ndarray            # (R,) [rad]
    jrow_hi: np.ndarray            # (R,) [rad]
    jrow_k: np.ndarray             # (R,) [N m/rad]
    sample_tet: np.ndarray         # (P,)
    sample_body: np.ndarray        # (P,)
    sample_r: np.ndarray           # (P,3) [m] point - COM, body frame
    sample_bary: np.ndarray        # (P,4)
    sample_k: np.ndarray           # (P,) [N/m] k_total / N_total * N
    indptr: np.ndarray             # (n+1,) CSR pattern of M + dt^2 H
    indices: np.ndarray            # (nnz,)
    diag_slot: np.ndarray          # (n,) value index of each diagonal entry
    tet_slots: np.ndarray          # (T,12,12)
    joint_slots: np.ndarray        # (J,12,12)
    sample_slots: np.ndarray       # (P,18,18)
    node_slots: np.ndarray         # (N,3,3) node diagonal blocks
    body_slots: np.ndarray         # (B,6,6) body diagonal blocks
    extra: dict = field(default_factory=dict)
    hands: HandLayout = None       # where each hand's nodes, tets, bones, skin lie (physics/hands.py)

    @property
    def node_count(self):
        return self.node_rest.shape[0]

    @property
    def body_count(self):
        return self.body_mass.shape[0]

    @property
    def body_dof0(self):
        return 3 * self.node_count

    @property
    def dof_count(self):
        return 3 * self.node_count + 6 * self.body_count

    def initial_state(self):
        from softhand_sim.physics.state import State
        return State.at_rest(self)

    def control(self):
        """The step inputs (control.Control) holding every body at its rest pose."""
        from softhand_sim.physics.control import Control
        return Control.at_rest(self)


def _get(asset, name, default):
    v = getattr(asset, name, None)
    return default if v is None else v


def build_model(asset, params=None, objects=(), coarse_meshes=None):
    """Model from a HandAsset (or any object with its fields) + parameters + rigid objects.

    asset: one hand, or a list of hands (e.g. [right, left]): their union (physics/hands.py) is
    one model, one energy; model.hands says where each hand lies.

    params: {sim_node key: value} overriding the schema's defaults (model_params), e.g.
    {"gravity_bones": True, "tracking_kx": 50.0}; Model.params keeps the full checked dict.

    objects: sequence with .mass [kg], .inertia_local (3,3) [kg m^2] and .pose (7,) (e.g.
    scene.SceneObject); each becomes a body coupled by Eq. 14 to a target pose.

    coarse_meshes: with `preconditioner: two_level`, one (nodes, tets) per hand: its coarse level
    (physics/two_level.py; model.extra["coarse_meshes"]). None: the coarse hand of each hand
    asset's measures and side (HandAssets only; a union of hands comes as the list of its hands).
    """
    p = model_params(params)
    if p["preconditioner"] == "two_level" and coarse_meshes is None:
        from softhand_sim.physics.two_level import coarse_mesh_of
        hands = list(asset) if isinstance(asset, (list, tuple)) else [asset]
        if not all(hasattr(a, "measures") and hasattr(a, "side") for a in hands):
            raise ValueError("preconditioner='two_level': pass coarse_meshes (the asset is not a hand "
                             "asset with measures and a side, whose coarse hand could be found)")
        coarse_meshes = [coarse_mesh_of(a) for a in hands]
    if isinstance(asset, (list, tuple)):
        asset = union_asset(asset)
    layout = layout_of(asset)
    X = np.ascontiguousarray(asset.tet_nodes, dtype=np.float64)
    tets = np.ascontiguousarray(asset.tets, dtype=np.int32)
    N, T = len(X), len(tets)
    vol, Dm_inv, K0 = tissue.rest_data(X, tets, p["youngs_modulus"], p["poisson_ratio"])
    node_mass = np.zeros(N)
    np.add.at(node_mass, tets.ravel(), np.repeat(p["tissue_density"] * vol / 4.0, 4))

    bone_pose = np.asarray(_get(asset, "bone_rest_pose", np.zeros((0, 7))), float).reshape(-1, 7)
    nb = len(bone_pose)
    objects = list(objects)
    B = nb + len(objects)
    body_mass = np.concatenate([np.asarray(_get(asset, "bone_mass", np.zeros(0)), float),
                                [float(o.mass) for o in objects]])
    com = np.concatenate([np.asarray(_get(asset, "bone_com_local", np.zeros((0, 3))), float).reshape(-1, 3),
                          np.zeros((len(objects), 3))])
    inertia = np.concatenate([np.asarray(_get(asset, "bone_inertia_local", np.zeros((0, 3, 3))), float).reshape(-1, 3, 3),
                              np.array([np.asarray(o.inertia_local, float) for o in objects]).reshape(-1, 3, 3)])
    rest_pose = np.concatenate([bone_pose, np.array([np.asarray(o.pose, float) for o in objects]).reshape(-1, 7)])
    kx = np.full(B, p["object_kx"])
    kth = np.full(B, p["object_ktheta"])
    kx[:nb] = p["tracking_kx_phalanx"]
    palms = layout.bone0[:-1][np.diff(layout.bone0) > 0]  # each hand's first bone
    kx[palms] = p["tracking_kx"]
    kth[:nb] = p["tracking_ktheta"]
    gb = np.ones(B) * float(bool(p["gravity_objects"]))
    gb[:nb] = float(bool(p["gravity_bones"]))
    gn = np.full(N, float(bool(p["gravity_tissue"])))

    jp = np.asarray(_get(asset, "joint_parent", np.zeros(0)), np.int32)
    jc = np.asarray(_get(asset, "joint_child", np.zeros(0)), np.int32)
    J = len(jp)
    jap = np.asarray(_get(asset, "joint_anchor_parent", np.zeros((J, 3))), float).reshape(J, 3)
    jac = np.asarray(_get(asset, "joint_anchor_child", np.zeros((J, 3))), float).reshape(J, 3)
    jtype = np.asarray(_get(asset, "joint_type", np.zeros(J)), np.int32)
    jflex = np.asarray(_get(asset, "joint_flex_axis", np.zeros((J, 3))), float).reshape(J, 3)
    jabd = np.asarray(_get(asset, "joint_abd_axis", np.zeros((J, 3))), float).reshape(J, 3)
    jlim = np.asarray(_get(asset, "joint_limits", np.zeros((J, 2, 2))), float).reshape(J, 2, 2)
    jrest = np.asarray(_get(asset, "joint_rest_rotation", np.tile([0, 0, 0, 1.0], (J, 1))), float).reshape(J, 4)
    rows = joints.angular_rows(jtype, jflex, jabd, jlim, p["joint_axis_stiffness"], p["joint_limit_stiffness"])

    st = np.asarray(_get(asset, "sample_tet", np.zeros(0)), np.int32)
    P = len(st)
    sb = np.asarray(_get(asset, "sample_bone", np.zeros(0)), np.int32)
    s_local = np.asarray(_get(asset, "sample_local", np.zeros((P, 3))), float).reshape(P, 3)
    s_bary = np.asarray(_get(asset, "sample_bary", np.zeros((P, 4))), float).reshape(P, 4)
    s_count = np.asarray(_get(asset, "sample_count", np.ones(P)), float)
    n_total = np.asarray(_get(asset, "bone_sample_total", np.ones(nb)), float)
    sample_k = p["bone_tissue_k_total"] / np.maximum(n_total[sb], 1.0) * s_count if P else np.zeros(0)

    surf_tris = _get(asset, "tet_surface_triangles", None)
    surface_nodes = (np.unique(np.asarray(surf_tris, np.int32)) if surf_tris is not None
                     else np.arange(N, dtype=np.int32))

    # ---- sparsity pattern and slots, once
    n = 3 * N + 6 * B
    b0 = 3 * N
    node_dofs = (3 * np.arange(N)[:, None] + np.arange(3)).astype(np.int64)
    body_dofs = (b0 + 6 * np.arange(B)[:, None] + np.arange(6)).astype(np.int64)
    tet_st = node_dofs[tets].reshape(T, 12)
    joint_st = np.concatenate([body_dofs[jp], body_dofs[jc]], axis=1).reshape(J, 12)
    sample_st = np.concatenate([node_dofs[tets[st]].reshape(P, 12), body_dofs[sb]], axis=1).reshape(P, 18)
    obj = np.arange(nb, B)
    contact_st = np.concatenate([np.repeat(node_dofs[surface_nodes], len(obj), axis=0),
                                 np.tile(body_dofs[obj], (len(surface_nodes), 1))], axis=1).reshape(-1, 9)
    indptr, indices = build_pattern(n, [tet_st, joint_st, sample_st, body_dofs, contact_st])
    diag_slot = stencil_slots(indptr, indices, np.arange(n)[:, None])[:, 0, 0]

    def to_com(v, body):  # a bone-frame point -> relative to the COM, body frame
        return v - com[body]

    model = Model(
        params=p, node_rest=X, node_mass=node_mass, tets=tets, tet_volume=vol, tet_Dm_inv=Dm_inv,
        tet_K0=K0, surface_nodes=surface_nodes.astype(np.int32),
        skin_tet=np.asarray(_get(asset, "skin_tet", np.zeros(0)), np.int32),
        skin_bary=np.asarray(_get(asset, "skin_bary", np.zeros((0, 4))), float).reshape(-1, 4),
        bone_count=nb, object_count=len(objects), body_mass=body_mass, body_com_local=com,
        body_inertia_local=np.ascontiguousarray(inertia), body_rest_pose=rest_pose,
        body_target_kx=kx, body_target_ktheta=kth, node_gravity_scale=gn, body_gravity_scale=gb,
        joint_parent=jp, joint_child=jc, joint_r_parent=to_com(jap, jp), joint_r_child=to_com(jac, jc),
        joint_rest_rotation=jrest, jrow_joint=rows[0], jrow_axis=rows[1], jrow_lo=rows[2],
        jrow_hi=rows[3], jrow_k=rows[4], sample_tet=st, sample_body=sb,
        sample_r=to_com(s_local, sb) if P else np.zeros((0, 3)), sample_bary=s_bary, sample_k=sample_k,
        indptr=indptr, indices=indices, diag_slot=diag_slot.astype(np.int32),
        tet_slots=stencil_slots(indptr, indices, tet_st),
        joint_slots=stencil_slots(indptr, indices, joint_st),
        sample_slots=stencil_slots(indptr, indices, sample_st),
        node_slots=stencil_slots(indptr, indices, node_dofs),
        body_slots=stencil_slots(indptr, indices, body_dofs), hands=layout,
    )
    if coarse_meshes is not None:
        model.extra["coarse_meshes"] = [(np.asarray(x, np.float64), np.asarray(t, np.int32))
                                        for x, t in coarse_meshes]
    return model


def rigid_asset(tet_nodes, tets, **fields):
    """A minimal asset-like namespace for tests and scenarios (any HandAsset field optional)."""
    return SimpleNamespace(tet_nodes=tet_nodes, tets=tets, **fields)


def com_from_pose(pose, com_local):
    """Centre of mass [m] (3,) of a body with bone-frame pose (7,)."""
    return pose[:3] + quat_to_matrix(pose[3:]) @ com_local
