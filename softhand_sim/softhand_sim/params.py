"""Parameters of every node: schema (type, range, unit, meaning, source) and a validating loader.

Default values live in one place, config/softhand.yaml (ROS 2 params-file format, one section
per node name). This module knows what each key means and which values are allowed; the loader
refuses unknown keys, wrong types and out-of-range values with a message naming the key and the
value. The nodes and the plain library both load parameters through `load_params`.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import yaml

from softhand_sim.paths import default_config_file


class _Loader(yaml.SafeLoader):
    """YAML 1.2 floats: PyYAML (YAML 1.1) reads `1.0e5` and `1e5` as strings, rcl_yaml reads numbers."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
    |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
    |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
    |[-+]?\.(?:inf|Inf|INF)
    |\.(?:nan|NaN|NAN))$""", re.X),
    list("-+0123456789."),
)


def safe_load(text):
    return yaml.load(text, Loader=_Loader)


class ParamError(ValueError):
    """A parameter that cannot be used; the message names the node, the key and the value."""


@dataclass(frozen=True)
class Param:
    kind: type                 # float, int, bool, str, list
    unit: str                  # SI unit or "-"
    doc: str                   # meaning and source
    low: float | None = None   # inclusive lower bound (numbers)
    high: float | None = None  # inclusive upper bound (numbers)
    positive: bool = False     # strictly > 0 (stiffness, rates, masses)
    choices: tuple | None = None


P = Param
_PAPER = "paper Sect. 5.1"

# Parameters shared by the solver library and sim_node.
SIM = {
    "sim_rate": P(float, "Hz", "full-simulation step rate; dt = 1/sim_rate", 10, 2000, positive=True),
    "hand_side": P(str, "-", "which hand to simulate", choices=("right", "left")),
    "hand_measures": P(str, "-", "the simulated hand's size: 'default' (19 cm) or a measures file written by "
                                 "`softhand calibrate` ('auto' is not implemented yet)"),
    "mesh": P(str, "-", "tissue resolution: coarse (~850 tets, paper 856) or fine (~8.5k)", choices=("coarse", "fine")),
    "youngs_modulus": P(float, "Pa", f"tissue Young's modulus ({_PAPER}: 1e5)", positive=True),
    "poisson_ratio": P(float, "-", f"tissue Poisson ratio ({_PAPER}: 0.33)", 0.0, 0.49),
    "tissue_density": P(float, "kg/m^3", "soft tissue density (water-like)", positive=True),
    "nonlinear_w_max": P(float, "J/m^3", f"energy density threshold W_max of Eq. 8 ({_PAPER}: 2500)", positive=True),
    "nonlinear_k": P(float, "J/m^3", f"nonlinear stiffness k of Eq. 8 ({_PAPER}: 1000); 0 = linear co-rotational", 0.0),
    "bone_tissue_k_total": P(float, "N/m", f"bone-tissue total coupling stiffness k_total of Eq. 11 ({_PAPER}: 3.2e6)", positive=True),
    "joint_stiffness": P(float, "N/m", f"skeletal joint stiffness of Eq. 6 ({_PAPER}: 2e5)", positive=True),
    "joint_limit_stiffness": P(float, "N*m/rad", "stiffness of the joint-limit penalty (not in the paper)", 0.0),
    "tracking_kx": P(float, "N/m", f"palm linear coupling to the intermediate bones, Eq. 14 ({_PAPER}: 50)", positive=True),
    "tracking_ktheta": P(float, "N*m/rad", f"angular coupling to the intermediate bones, Eq. 14 ({_PAPER}: 200)", positive=True),
    "object_kx": P(float, "N/m", f"hand<->engine object linear coupling, Eq. 14 ({_PAPER}: 170)", positive=True),
    "object_ktheta": P(float, "N*m/rad", f"hand<->engine object angular coupling, Eq. 14 ({_PAPER}: 70)", positive=True),
    "object_max_omega": P(float, "rad/s", "cap on sqrt(k/m), sqrt(ktheta/I) of the object coupling (same as world_node's)", positive=True),
    "contact_kn": P(float, "N/m^3", "normal contact stiffness k_n of Eq. 12 per unit vertex area (not in the paper)", positive=True),
    "contact_kf": P(float, "N/m^3", "tangential (friction) stiffness k_f of Eq. 13 per unit vertex area (not in the paper)", positive=True),
    "friction": P(float, "-", f"Coulomb coefficient mu for hand contacts when the scene gives none ({_PAPER}: 0.5)", 0.0),
    "gravity_bones": P(bool, "-", "apply gravity to the bones"),
    "gravity_tissue": P(bool, "-", "apply gravity to the tissue nodes"),
    "gravity_objects": P(bool, "-", "apply gravity to the hand-side object instances"),
    "cg_tolerance": P(float, "-", "relative residual tolerance of PCG (paper: 1e-5)", 1e-12, 1e-1),
    "cg_max_iterations": P(int, "-", "PCG iteration cap: bounds the cost of a step", 1, 100000),
    "preconditioner": P(str, "-", "PCG preconditioner: jacobi (the paper's), block_jacobi (3x3 node, 6x6 body blocks) or factor (sparse factorization reused across steps)", choices=("jacobi", "block_jacobi", "factor")),
    "scene_file": P(str, "-", "scene file (empty: config/scene.yaml)"),
    "copy_timeout": P(float, "s", "an engine copy older than this decouples its object", positive=True),
    "extrapolate": P(bool, "-", "extrapolate engine copies with constant acceleration (Sect. 3.7)"),
    "skin_marker_rate": P(float, "Hz", "rate of /hand/skin_marker", positive=True),
    "publish_skin_vertices": P(bool, "-", "publish /hand/skin_vertices every step"),
    "diagnostics_rate": P(float, "Hz", "rate of /diagnostics", positive=True),
}

TRACKING = {
    "rate": P(float, "Hz", "intermediate-bone loop rate (paper Sect. 5.1: 250)", 10, 2000, positive=True),
    "hand": P(str, "-", "tracked hand", choices=("right", "left")),
    "tracked_kx": P(float, "N/m", "coupling of each intermediate bone to its tracked bone, linear (paper: 50)", positive=True),
    "tracked_ktheta": P(float, "N*m/rad", "coupling to the tracked bone, angular (paper: 200)", positive=True),
    "sim_kx": P(float, "N/m", "palm coupling to the full-simulation copy, linear (paper: 50; phalanxes 0)", positive=True),
    "sim_ktheta": P(float, "N*m/rad", "coupling to the full-simulation copy, angular (paper: 200)", positive=True),
    "damping_ratio": P(float, "-", "critical-damping fraction of each tracked coupling (0: the paper's plain springs overshoot 67%)", 0.0, 5.0),
    "tracker_timeout": P(float, "s", "hold the last target when no valid frame arrived for this long", positive=True),
    "sim_timeout": P(float, "s", "forget the full-simulation copy when /hand/bones is older than this", positive=True),
    "tracker_to_world": P(list, "m, quaternion", "tracker->world transform [px py pz qx qy qz qw]"),
    "min_bone_length": P(float, "m", "shorter tracked bones reject the frame", 0.0),
    "max_bone_length": P(float, "m", "longer tracked bones reject the frame", positive=True),
    "diagnostics_rate": P(float, "Hz", "rate of /diagnostics", positive=True),
}

WORLD = {
    "engine_rate": P(float, "Hz", "pybullet step rate (paper: 60-120)", 60, 120),
    "scene_file": P(str, "-", "scene file (empty: config/scene.yaml)"),
    "coupling_kx": P(float, "N/m", "engine<->hand object coupling, linear, Eq. 14 (paper: 170)", positive=True),
    "coupling_ktheta": P(float, "N*m/rad", "engine<->hand object coupling, angular, Eq. 14 (paper: 70)", positive=True),
    "coupling_damping": P(float, "-", "damping ratio of the engine-side coupling spring (0: the paper's plain spring)", 0.0, 2.0),
    "coupling_mode": P(str, "-", "implicit: backward-Euler coupling force (stable); explicit: the paper's plain spring at t",
                       choices=("implicit", "explicit")),
    "coupling_max_omega": P(float, "rad/s", "cap on sqrt(k/m) and sqrt(ktheta/I) of the coupling: keeps the copy exchange stable "
                            "for light objects (the paper's 70 N*m/rad on a 4 cm ball is ~1200 rad/s)", positive=True),
    "copy_timeout": P(float, "s", "a hand copy older than this decouples its object", positive=True),
    "extrapolate": P(bool, "-", "extrapolate hand copies with constant acceleration (Sect. 3.7)"),
    "gravity": P(float, "m/s^2", "gravity along -z", 0.0),
    "marker_rate": P(float, "Hz", "rate of /world/markers", positive=True),
    "diagnostics_rate": P(float, "Hz", "rate of /diagnostics", positive=True),
}

PLAY = {
    "bag": P(str, "-", "tracker rosbag2 directory (mcap or sqlite3) to replay"),
    "rate": P(float, "-", "playback speed factor (1 = recorded timing)", positive=True),
    "loop": P(bool, "-", "start again at the end"),
    "start": P(float, "s", "skip this much of the bag", 0.0),
    "topic": P(str, "-", "tracker topic in the bag"),
    "publish_clock": P(bool, "-", "publish /clock with the bag time"),
    "clock_rate": P(float, "Hz", "/clock ticks per second between messages (0: only with messages)", 0.0, 1e4),
    "wait_subscribers": P(int, "-", "wait until this many subscribers match the topic before playing", 0, 1000),
    "wait_timeout": P(float, "s", "give up waiting for subscribers after this long", 0.0),
}

RECORD = {
    "output": P(str, "-", "rosbag2 directory to create (empty: runs/<stamp>/bag)"),
    "topics": P(list, "-", "topics to record (empty: every softhand topic but /hand/skin_vertices)"),
    "record_skin_vertices": P(bool, "-", "also record /hand/skin_vertices (large)"),
    "progress_period": P(float, "s", "how often to log messages/MB written", 0.1, 3600.0),
    "flush_period": P(float, "s", "write the pending mcap chunk this often (bounds what a SIGKILL loses)", 0.05, 3600.0),
    "discovery_period": P(float, "s", "look for newly published wanted topics this often", 0.01, 60.0),
    "stamp_source": P(str, "-", "bag timestamp of each message", choices=("receive", "header")),
}

SCHEMA = {
    "sim_node": SIM,
    "tracking_node": TRACKING,
    "world_node": WORLD,
    "play_node": PLAY,
    "record_node": RECORD,
}


def check_value(node: str, key: str, value, schema=None):
    """Validate one value; returns it converted (int -> float where a float is expected)."""
    schema = SCHEMA[node] if schema is None else schema
    if key not in schema:
        raise ParamError(f"{node}: unknown parameter {key!r} (known: {', '.join(sorted(schema))})")
    p = schema[key]
    where = f"{node}: parameter {key!r}"
    if p.kind is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ParamError(f"{where} must be a number [{p.unit}], got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise ParamError(f"{where} must be finite, got {value!r}")
    elif p.kind is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ParamError(f"{where} must be an integer, got {value!r}")
    elif p.kind is bool:
        if not isinstance(value, bool):
            raise ParamError(f"{where} must be true or false, got {value!r}")
    elif p.kind is str:
        if not isinstance(value, str):
            raise ParamError(f"{where} must be a string, got {value!r}")
    elif p.kind is list:
        if not isinstance(value, (list, tuple)):
            raise ParamError(f"{where} must be a list, got {value!r}")
        value = list(value)
    if p.kind in (int, float):
        if p.positive and value <= 0:
            raise ParamError(f"{where} must be > 0 [{p.unit}], got {value!r}")
        if p.low is not None and value < p.low:
            raise ParamError(f"{where} must be >= {p.low} [{p.unit}], got {value!r}")
        if p.high is not None and value > p.high:
            raise ParamError(f"{where} must be <= {p.high} [{p.unit}], got {value!r}")
    if p.choices is not None and value not in p.choices:
        raise ParamError(f"{where} must be one of {list(p.choices)}, got {value!r}")
    return value


def read_params_file(path) -> dict:
    """The raw {node: {key: value}} of a ROS 2 params file (node: ros__parameters: {...})."""
    path = Path(path)
    if not path.is_file():
        raise ParamError(f"parameter file not found: {path}")
    try:
        raw = safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise ParamError(f"parameter file {path} is not valid YAML: {exc}") from None
    out = {}
    for node, section in raw.items():
        node_name = node.lstrip("/").split("/")[-1]  # "/**", "/ns/node" -> node name
        if not isinstance(section, dict) or not isinstance(section.get("ros__parameters"), dict):
            raise ParamError(f"parameter file {path}: section {node!r} needs a 'ros__parameters' mapping")
        out.setdefault(node_name, {}).update(section["ros__parameters"])
    return out


def defaults(node: str) -> dict:
    """The validated default parameters of `node` from the project's config/softhand.yaml."""
    path = default_config_file("softhand.yaml")
    section = read_params_file(path).get(node)
    if section is None:
        raise ParamError(f"{path} has no section for node {node!r}")
    missing = sorted(set(SCHEMA[node]) - set(section))
    if missing:
        raise ParamError(f"{path}: node {node!r} lacks default(s) for {missing}")
    return {k: check_value(node, k, v) for k, v in section.items()}


def load_params(node: str, params_file=None, overrides=None) -> dict:
    """Defaults, then a user params file's section for `node`, then overrides; all validated."""
    if node not in SCHEMA:
        raise ParamError(f"unknown node {node!r} (known: {', '.join(SCHEMA)})")
    values = defaults(node)
    if params_file is not None:
        for k, v in read_params_file(params_file).get(node, {}).items():
            values[k] = check_value(node, k, v)
    for k, v in (overrides or {}).items():
        values[k] = check_value(node, k, v)
    return values
