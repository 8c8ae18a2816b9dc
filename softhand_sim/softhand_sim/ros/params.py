"""Node parameters: declared from the schema of params.py with the defaults of config/softhand.yaml.

Every value a node receives (`-p key:=value`, `--params-file`) is checked by the same validator as
the plain library; unknown keys and bad values stop the node at start with a message naming the
key and the value (instead of rclpy's default of silently ignoring undeclared overrides).
"""
from __future__ import annotations

from rclpy.node import Node

from softhand_sim.params import SCHEMA, ParamError, check_value, defaults
from softhand_sim.ros.common import declare_parameters_from_schema

# Parameters rclpy itself declares on every node.
_ROS_OWN = {"use_sim_time", "start_type_description_service"}


def declare_node_params(node: Node, node_name: str) -> dict:
    """Declare the schema of `node_name` on `node`; return validated values (raises ParamError)."""
    schema = SCHEMA[node_name]
    base = defaults(node_name)
    spec = {k: {"default": base[k], "doc": p.doc, "unit": p.unit} for k, p in schema.items()}
    # An empty list gives ROS no element type: declare lists of strings with one empty entry.
    for k, p in schema.items():
        if p.kind is list and not base[k]:
            spec[k]["default"] = [""]
    # rclpy keeps the overrides of --params-file / -p; undeclared ones would be dropped silently.
    overrides = getattr(node, "_parameter_overrides", {}) or {}
    unknown = sorted(set(overrides) - set(schema) - _ROS_OWN)
    if unknown:
        bad = ", ".join(f"{k}={overrides[k].value!r}" for k in unknown)
        raise ParamError(f"{node_name}: unknown parameter(s) {bad} (known: {', '.join(sorted(schema))})")
    try:
        values = declare_parameters_from_schema(node, spec)
    except Exception as exc:  # wrong type for a declared parameter: rclpy's message names it
        raise ParamError(f"{node_name}: {exc}") from None
    out = {}
    for k, v in values.items():
        if schema[k].kind is list:
            v = [x for x in list(v) if x != ""]
        elif schema[k].kind is float and isinstance(v, int) and not isinstance(v, bool):
            v = float(v)
        out[k] = check_value(node_name, k, v)
    return out
