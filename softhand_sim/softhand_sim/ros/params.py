"""Node parameters: declared from the one schema (params.py), checked at start and at run time.

Every value a node receives (`-p key:=value`, `--params-file`) is checked by the same validator as
the plain library; unknown keys and bad values stop the node at start with a message naming the
key and the value (instead of rclpy's default of silently ignoring undeclared overrides).

Each descriptor carries the schema's meaning, unit and range, so `ros2 param describe` shows them.
At run time (`ros2 param set`, the standard set_parameters service) a change either takes effect or
is refused with the reason: a node names the keys it can change while running (`live`: key ->
function applying the new value); every other key takes effect only at start and is refused, and a
value the schema rejects is refused with the validator's message. Nothing is accepted and ignored.
"""
from __future__ import annotations

from typing import Callable, Mapping

from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node

from softhand_sim.params import SCHEMA, ParamError, check_value, defaults, descriptions
from softhand_sim.ros.common import declare_parameters_from_schema

# Parameters rclpy itself declares on every node.
_ROS_OWN = {"use_sim_time", "start_type_description_service"}


def declare_node_params(node: Node, node_name: str,
                        live: Mapping[str, Callable[[object], None]] | None = None,
                        flags: Mapping[str, object] | None = None) -> dict:
    """Declare the schema of `node_name` on `node`; return validated values (raises ParamError).

    live: the keys this node applies while running, each with a function taking the checked new
    value (it may raise ValueError to refuse it); run-time changes of other keys are refused.
    flags: the node's own command-line flags (key -> value, None where not given), which take the
    place of the parameters of the same names, checked as they are.
    """
    schema = SCHEMA[node_name]
    base = defaults(node_name)
    text = descriptions(node_name)
    spec = {}
    for k, p in schema.items():
        doc, (low, high) = text[k]
        spec[k] = {"default": base[k], "description": doc
                   + ("" if live is None or k not in live else " (changeable at run time)")}
        if low is not None and high is not None:
            spec[k]["range"] = (low, high)
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
    out.update({k: check_value(node_name, k, v) for k, v in (flags or {}).items() if v is not None})
    node.add_on_set_parameters_callback(_runtime_guard(node_name, dict(live or {})))
    return out


def _runtime_guard(node_name: str, live: dict):
    """on_set_parameters callback: apply live keys after the schema's check, refuse the rest."""
    schema = SCHEMA[node_name]

    def on_set(params) -> SetParametersResult:
        changes = []
        for param in params:
            key, value = param.name, param.value
            if key in _ROS_OWN:
                continue  # rclpy's own (use_sim_time) are rclpy's business
            if schema[key].kind is float and isinstance(value, int) and not isinstance(value, bool):
                value = float(value)
            try:
                value = check_value(node_name, key, value)
            except ParamError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
            if key not in live:
                return SetParametersResult(successful=False, reason=(
                    f"{node_name}: {key} takes effect only at start; restart the node with -p {key}:=VALUE"))
            changes.append((key, value))
        for key, value in changes:  # all checked: apply together
            try:
                live[key](value)
            except ValueError as exc:
                return SetParametersResult(successful=False, reason=f"{node_name}: {key}={value!r}: {exc}")
        return SetParametersResult(successful=True)

    return on_set
