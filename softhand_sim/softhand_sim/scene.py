"""The scene file (config/scene.yaml): ground plane and objects, read by sim_node and world_node.

Shapes and their dimensions (SI units):
    sphere   radius
    box      size [sx, sy, sz] (full edge lengths)
    capsule  radius, length (cylinder part along the object's z; caps add 2 * radius)
    cylinder radius, length (along the object's z)
    mesh     file (watertight triangle mesh, relative to the scene file), scale (default 1)
Inertia is computed from the shape and the mass, about the centre of mass, in the object frame.

Friction lives here only: each object's and the ground's Coulomb `friction` (DEFAULT_FRICTION when
the entry has none) is what both the hand side (contact) and the engine (pybullet) use, so the two
cannot disagree; no node parameter overrides it.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from softhand_sim.params import safe_load

from softhand_sim.paths import default_config_file

SHAPES = ("sphere", "box", "capsule", "cylinder", "mesh")
_REQUIRED_DIMS = {
    "sphere": ("radius",),
    "box": ("size",),
    "capsule": ("radius", "length"),
    "cylinder": ("radius", "length"),
    "mesh": ("file",),
}
DEFAULT_FRICTION = 0.5  # [-] Coulomb mu of an object or ground without `friction` (paper Sect. 5.1)
DEFAULT_MASS = 0.1      # [kg] of a dynamic object without `mass`
_OBJECT_KEYS = {"name", "shape", "radius", "size", "length", "file", "scale", "mass", "friction",
                "position", "orientation", "static"}


class SceneError(ValueError):
    """A scene file that cannot be used; the message names the object, key and bad value."""


@dataclass(frozen=True)
class SceneObject:
    name: str
    shape: str
    dims: dict            # shape dimensions, see module docstring [m]
    mass: float           # [kg]; 0 for static objects
    friction: float       # Coulomb coefficient [-]
    pose: np.ndarray      # (7,) initial [px py pz qx qy qz qw] in world
    static: bool
    inertia_local: np.ndarray = field(repr=False)  # (3,3) about the COM, object axes [kg m^2]
    mesh_path: Path | None = None


@dataclass(frozen=True)
class Scene:
    ground_height: float   # z of the static ground plane [m]
    ground_friction: float
    objects: tuple         # SceneObject, in file order
    path: Path | None = None

    @property
    def dynamic_objects(self):
        return tuple(o for o in self.objects if not o.static)

    @property
    def static_objects(self):
        return tuple(o for o in self.objects if o.static)

    def object(self, name):
        for o in self.objects:
            if o.name == name:
                return o
        raise KeyError(f"scene has no object named {name!r}")


def shape_inertia(shape, dims, mass, mesh=None):
    """Inertia tensor (3,3) of a solid of uniform density about its COM [kg m^2]."""
    if shape == "sphere":
        i = 0.4 * mass * dims["radius"] ** 2
        return np.diag([i, i, i])
    if shape == "box":
        sx, sy, sz = dims["size"]
        return mass / 12.0 * np.diag([sy * sy + sz * sz, sx * sx + sz * sz, sx * sx + sy * sy])
    if shape == "cylinder":
        r, h = dims["radius"], dims["length"]
        ixx = mass * (3 * r * r + h * h) / 12.0
        return np.diag([ixx, ixx, 0.5 * mass * r * r])
    if shape == "capsule":
        r, h = dims["radius"], dims["length"]
        v_cyl, v_caps = np.pi * r * r * h, 4.0 / 3.0 * np.pi * r ** 3
        m_cyl = mass * v_cyl / (v_cyl + v_caps)
        m_caps = mass - m_cyl
        izz = 0.5 * m_cyl * r * r + 0.4 * m_caps * r * r
        # the two hemispheres, each offset from the centre (parallel-axis theorem)
        ixx = (m_cyl * (3 * r * r + h * h) / 12.0
               + m_caps * (0.4 * r * r + h * h / 4.0 + 3.0 * h * r / 8.0))
        return np.diag([ixx, ixx, izz])
    if shape == "mesh":
        if mesh is None or mesh.volume <= 0:
            raise SceneError("mesh inertia needs a watertight mesh with positive volume")
        return np.asarray(mesh.moment_inertia, dtype=np.float64) * (mass / (mesh.volume * mesh.density))
    raise SceneError(f"unknown shape {shape!r}")


def _number(obj_name, key, value, positive=False, nonneg=False):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SceneError(f"object {obj_name!r}: {key} must be a number, got {value!r}")
    value = float(value)
    if not np.isfinite(value):
        raise SceneError(f"object {obj_name!r}: {key} must be finite, got {value!r}")
    if positive and value <= 0:
        raise SceneError(f"object {obj_name!r}: {key} must be > 0, got {value!r}")
    if nonneg and value < 0:
        raise SceneError(f"object {obj_name!r}: {key} must be >= 0, got {value!r}")
    return value


def _vector(obj_name, key, value, length):
    if not isinstance(value, (list, tuple)) or len(value) != length:
        raise SceneError(f"object {obj_name!r}: {key} must be a list of {length} numbers, got {value!r}")
    return np.array([_number(obj_name, f"{key}[{i}]", v) for i, v in enumerate(value)])


def _parse_object(raw, base_dir):
    if not isinstance(raw, dict):
        raise SceneError(f"each object must be a mapping, got {raw!r}")
    name = raw.get("name")
    if not isinstance(name, str) or not name:
        raise SceneError(f"object without a valid name: {raw!r}")
    unknown = sorted(set(raw) - _OBJECT_KEYS)
    if unknown:
        raise SceneError(f"object {name!r}: unknown key(s) {unknown}")
    shape = raw.get("shape")
    if shape not in SHAPES:
        raise SceneError(f"object {name!r}: shape must be one of {SHAPES}, got {shape!r}")
    for key in _REQUIRED_DIMS[shape]:
        if key not in raw:
            raise SceneError(f"object {name!r}: shape {shape} needs {key!r}")
    static = raw.get("static", False)
    if not isinstance(static, bool):
        raise SceneError(f"object {name!r}: static must be true or false, got {static!r}")
    dims = {}
    mesh = None
    mesh_path = None
    if shape in ("sphere", "capsule", "cylinder"):
        dims["radius"] = _number(name, "radius", raw["radius"], positive=True)
    if shape in ("capsule", "cylinder"):
        dims["length"] = _number(name, "length", raw["length"], positive=True)
    if shape == "box":
        size = _vector(name, "size", raw["size"], 3)
        if np.any(size <= 0):
            raise SceneError(f"object {name!r}: size must be > 0, got {raw['size']!r}")
        dims["size"] = tuple(size)
    if shape == "mesh":
        mesh_path = (base_dir / str(raw["file"])).resolve()
        if not mesh_path.is_file():
            raise SceneError(f"object {name!r}: mesh file not found: {mesh_path}")
        dims["file"] = str(mesh_path)
        dims["scale"] = _number(name, "scale", raw.get("scale", 1.0), positive=True)
        import trimesh  # only needed for mesh objects

        mesh = trimesh.load(mesh_path, force="mesh")
        mesh.apply_scale(dims["scale"])
        if not mesh.is_watertight:
            raise SceneError(f"object {name!r}: mesh {mesh_path} is not watertight")
    mass = 0.0 if static else _number(name, "mass", raw.get("mass", DEFAULT_MASS), positive=True)
    friction = _number(name, "friction", raw.get("friction", DEFAULT_FRICTION), nonneg=True)
    position = _vector(name, "position", raw.get("position", [0.0, 0.0, 0.0]), 3)
    orientation = _vector(name, "orientation", raw.get("orientation", [0.0, 0.0, 0.0, 1.0]), 4)
    norm = np.linalg.norm(orientation)
    if abs(norm - 1.0) > 1e-3:
        raise SceneError(f"object {name!r}: orientation must be a unit quaternion [x y z w], got {raw.get('orientation')!r}")
    pose = np.concatenate([position, orientation / norm])
    inertia = np.zeros((3, 3)) if static else shape_inertia(shape, dims, mass, mesh)
    return SceneObject(name, shape, dims, mass, friction, pose, static, inertia, mesh_path)


def load_scene(path=None) -> Scene:
    """Read and validate a scene file (default: the project's config/scene.yaml)."""
    path = Path(path) if path is not None else default_config_file("scene.yaml")
    if not path.is_file():
        raise SceneError(f"scene file not found: {path}")
    try:
        raw = safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise SceneError(f"scene file {path} is not valid YAML: {exc}") from None
    if not isinstance(raw, dict):
        raise SceneError(f"scene file {path} must be a mapping with 'ground' and 'objects'")
    unknown = sorted(set(raw) - {"ground", "objects"})
    if unknown:
        raise SceneError(f"scene file {path}: unknown top-level key(s) {unknown}")
    ground = raw.get("ground") or {}
    ground_height = _number("ground", "height", ground.get("height", 0.0))
    ground_friction = _number("ground", "friction", ground.get("friction", DEFAULT_FRICTION), nonneg=True)
    objects = tuple(_parse_object(o, path.parent) for o in (raw.get("objects") or []))
    names = [o.name for o in objects]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise SceneError(f"scene file {path}: duplicate object name(s) {dup}")
    return Scene(ground_height, ground_friction, objects, path)
