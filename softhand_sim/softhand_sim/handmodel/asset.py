"""HandAsset: the built hand (skin, tissue tets, embedding, skeleton, coupling samples).

Fields and conventions are the table in docs/ARCHITECTURE.md: SI units, quaternions [x, y, z, w],
poses (n, 7), float64 positions, int32 indices. Saved and loaded as one .npz.
"""
import json
from dataclasses import dataclass, fields

import numpy as np


@dataclass(frozen=True)
class HandAsset:
    side: str
    skin_vertices: np.ndarray  # (V,3) [m]
    skin_triangles: np.ndarray  # (F,3) i4, outward
    tet_nodes: np.ndarray  # (N,3) [m]
    tets: np.ndarray  # (T,4) i4, positive volume
    tet_surface_triangles: np.ndarray  # (S,3) i4, outward boundary faces of the tet mesh
    skin_tet: np.ndarray  # (V,) i4
    skin_bary: np.ndarray  # (V,4)
    bone_rest_pose: np.ndarray  # (16,7)
    bone_length: np.ndarray  # (16,) [m]
    bone_mass: np.ndarray  # (16,) [kg]
    bone_com_local: np.ndarray  # (16,3) [m]
    bone_inertia_local: np.ndarray  # (16,3,3) [kg m^2]
    bone_capsule_a: np.ndarray  # (16,3) [m], bone frame
    bone_capsule_b: np.ndarray  # (16,3) [m], bone frame
    bone_capsule_radius: np.ndarray  # (16,) [m]
    joint_parent: np.ndarray  # (15,) i4
    joint_child: np.ndarray  # (15,) i4
    joint_type: np.ndarray  # (15,) i4: 0 spherical, 1 hinge, 2 universal
    joint_anchor_parent: np.ndarray  # (15,3) [m]
    joint_anchor_child: np.ndarray  # (15,3) [m]
    joint_flex_axis: np.ndarray  # (15,3) parent frame
    joint_abd_axis: np.ndarray  # (15,3) parent frame
    joint_rest_rotation: np.ndarray  # (15,4)
    joint_limits: np.ndarray  # (15,2,2) [rad]
    sample_tet: np.ndarray  # (P,) i4
    sample_bone: np.ndarray  # (P,) i4
    sample_count: np.ndarray  # (P,) i4
    sample_local: np.ndarray  # (P,3) [m]
    sample_bary: np.ndarray  # (P,4)
    bone_sample_total: np.ndarray  # (16,) i4
    skin_embed_distance: np.ndarray  # (V,) [m] distance of each skin vertex to skin_tet (0 inside)
    measures: dict  # the build parameters
    build_info: dict  # figures of the build: counts, min dihedral, volume error, timings

    def save(self, path):
        arrays = {f.name: getattr(self, f.name) for f in fields(self)
                  if isinstance(getattr(self, f.name), np.ndarray)}
        meta = dict(side=self.side, measures=self.measures, build_info=self.build_info)
        np.savez(path, __meta__=np.array(json.dumps(meta)), **arrays)

    @classmethod
    def load(cls, path):
        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(str(data["__meta__"]))
            kwargs = {f.name: data[f.name] for f in fields(cls) if f.name in data.files}
        missing = {f.name for f in fields(cls)} - set(kwargs) - set(meta)
        if missing:
            raise ValueError(f"hand asset file {path} lacks field(s) {sorted(missing)}")
        return cls(**kwargs, **meta)
