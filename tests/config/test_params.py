"""Parameters: one schema (params.SCHEMA) whose defaults are valid, which config/softhand.yaml and
`softhand params` reproduce and the solver model reads by its own names; bad values refused with
the key and value named."""
import subprocess
import sys
from pathlib import Path

import pytest

from softhand_sim.params import (SCHEMA, ParamError, check_value, defaults, descriptions, load_params,
                                 params_yaml, read_params_file)
from softhand_sim.paths import REPO_ROOT

YAML = REPO_ROOT / "config" / "softhand.yaml"
VENV_BIN = Path(sys.executable).parent


@pytest.mark.parametrize("node", sorted(SCHEMA))
def test_schema_defaults_are_valid(node):
    """Every schema default passes its own check unchanged (type, range, choices, list length)."""
    for key, value in defaults(node).items():
        assert check_value(node, key, value) == value, key


@pytest.mark.parametrize("node", sorted(SCHEMA))
def test_yaml_has_exactly_the_schema_defaults(node):
    """config/softhand.yaml, read as ROS reads a params file, gives each key of the schema its
    default (same value, same type) and no other key."""
    section = read_params_file(YAML)[node]
    assert set(section) == set(SCHEMA[node])
    for key, value in section.items():
        expected = defaults(node)[key]
        assert (type(value), value) == (type(expected), expected), f"{node}.{key}: yaml {value!r}, schema {expected!r}"


def test_yaml_is_generated_from_schema():
    """The file is byte for byte what `softhand params --yaml` writes (comments too: units and
    meanings come from the schema). Regenerate with `softhand params --yaml config/softhand.yaml`."""
    assert YAML.read_text() == params_yaml(), "config/softhand.yaml is stale: run `softhand params --yaml config/softhand.yaml`"


def test_params_command_writes_the_yaml(tmp_path):
    """`softhand params --yaml FILE` (the installed console script) writes the params file, which
    loads back to the defaults; `softhand params sim_node` lists every key with its unit."""
    out = tmp_path / "softhand.yaml"
    subprocess.run([str(VENV_BIN / "softhand"), "params", "--yaml", str(out)], check=True, timeout=60)
    assert out.read_text() == params_yaml()
    for node in SCHEMA:
        assert load_params(node, params_file=out) == defaults(node)
    text = subprocess.run([str(VENV_BIN / "softhand"), "params", "sim_node"], check=True, timeout=60,
                          capture_output=True, text=True).stdout
    for key, p in SCHEMA["sim_node"].items():
        line = next(ln for ln in text.splitlines() if ln.split()[:1] == [key])
        assert f"[{p.unit}]" in line and p.doc in line


def test_descriptions_carry_meaning_unit_and_range():
    """descriptions(node): per key a text with the meaning and unit, and the inclusive range."""
    d = descriptions("sim_node")
    assert set(d) == set(SCHEMA["sim_node"])
    text, (low, high) = d["poisson_ratio"]
    assert "Poisson" in text and "[-]" in text and (low, high) == (0.0, 0.49)
    text, (low, high) = d["sim_rate"]
    assert "[Hz]" in text and "by hand count" in text and (low, high) == (0, 2000)
    assert "jacobi" in d["preconditioner"][0] and d["preconditioner"][1] == (None, None)


def test_paper_defaults():
    """The paper's Sect. 5.1 values are the defaults."""
    sim = defaults("sim_node")
    assert sim["youngs_modulus"] == 1e5 and sim["poisson_ratio"] == 0.33
    assert sim["bone_tissue_k_total"] == 3.2e6 and sim["joint_stiffness"] == 2e5
    assert sim["nonlinear_w_max"] == 2500 and sim["nonlinear_k"] == 1000
    # Deliberate departure (config/softhand.yaml): the palm's linear tracking coupling is 10x the
    # paper's 50 N/m, which lets a hand holding the two-instance ball sag ~8 cm; angular as the paper.
    assert sim["tracking_ktheta"] == 200 and sim["tracking_kx"] == 500
    assert (sim["object_kx"], sim["object_ktheta"]) == (170, 70)
    assert sim["cg_tolerance"] == 1e-5
    assert defaults("tracking_node")["rate"] == 250
    assert defaults("world_node")["engine_rate"] == 120


@pytest.mark.parametrize(
    "key,value,words",
    [
        ("bogus_key", 1.0, ["unknown parameter", "bogus_key"]),
        ("joint_stiffness", "stiff", ["joint_stiffness", "'stiff'", "number"]),
        ("joint_stiffness", -5.0, ["joint_stiffness", "-5.0", "> 0"]),
        ("youngs_modulus", 0.0, ["youngs_modulus", "0.0"]),
        ("poisson_ratio", 0.6, ["poisson_ratio", "0.6", "<= 0.49"]),
        ("cg_max_iterations", 2.5, ["cg_max_iterations", "integer"]),
        ("preconditioner", "magic", ["preconditioner", "magic", "jacobi"]),
        ("gravity_bones", "yes", ["gravity_bones", "true or false"]),
        ("sim_rate", float("nan"), ["sim_rate", "finite"]),
        ("gravity", [0.0, -9.81], ["gravity", "3 values", "-9.81"]),
        ("friction", 0.5, ["unknown parameter", "friction"]),
    ],
)
def test_bad_values_refused(key, value, words):
    """Unknown keys, wrong types and out-of-range values are refused, naming key and value."""
    with pytest.raises(ParamError) as err:
        load_params("sim_node", overrides={key: value})
    for w in words:
        assert w in str(err.value)


def test_user_params_file(tmp_path):
    """A user file overrides only what it names; a bad value in it is refused."""
    good = tmp_path / "p.yaml"
    good.write_text("sim_node:\n  ros__parameters:\n    sim_rate: 40\n    youngs_modulus: 2.0e5\n")
    p = load_params("sim_node", params_file=good)
    assert p["sim_rate"] == 40.0 and p["youngs_modulus"] == 2e5 and p["joint_stiffness"] == 2e5
    bad = tmp_path / "bad.yaml"
    bad.write_text("world_node:\n  ros__parameters:\n    engine_rate: 500\n")
    with pytest.raises(ParamError, match="engine_rate.*500"):
        load_params("world_node", params_file=bad)
    with pytest.raises(ParamError, match="not found"):
        load_params("world_node", params_file=tmp_path / "missing.yaml")


# where each node's code lives (the node, its library and the offline pipeline that mirrors it)
_READERS = {"sim_node": ["softhand_sim/softhand_sim"], "tracking_node": ["softhand_tracking/softhand_tracking"],
            "world_node": ["softhand_world/softhand_world"], "play_node": ["softhand_tracking/softhand_tracking"],
            "record_node": ["softhand_sim/softhand_sim"]}


@pytest.mark.parametrize("node", sorted(SCHEMA))
def test_every_parameter_is_read(node):
    """Each schema key is looked up by name (`...["key"]`) somewhere in its node's code besides
    params.py: a parameter nobody reads is a setting that silently does nothing."""
    import re
    schema_file = REPO_ROOT / "softhand_sim" / "softhand_sim" / "params.py"
    sources = [f for d in _READERS[node] for f in (REPO_ROOT / d).rglob("*.py") if f != schema_file]
    text = "\n".join(f.read_text() for f in sources)
    unread = [k for k in SCHEMA[node] if not re.search(rf"\[[\"']{re.escape(k)}[\"']\]", text)]
    assert not unread, f"{node}: nobody reads {unread}"


def test_sim_rate_by_hand_count():
    """sim_rate 0 (the default) is 200 Hz for one hand and 50 Hz for two (README, "Following
    without lag"); a rate given is kept for any hand count; 0 < rate < 10 Hz is refused by name,
    and the runtime's params carry the rate it steps at."""
    from softhand_sim.params import sim_rate_hz
    from softhand_sim.runtime import SimRuntime
    p = defaults("sim_node")
    assert p["sim_rate"] == 0.0
    assert sim_rate_hz(p, 1) == 200.0 and sim_rate_hz(p, 2) == 50.0
    assert sim_rate_hz({**p, "sim_rate": 90.0}, 1) == 90.0 == sim_rate_hz({**p, "sim_rate": 90.0}, 2)
    with pytest.raises(ParamError, match="sim_rate.*5.0"):
        sim_rate_hz({**p, "sim_rate": 5.0}, 1)
    with pytest.raises(ParamError, match="sim_rate"):
        load_params("sim_node", overrides={"sim_rate": -1.0})
    assert SimRuntime(p).params["sim_rate"] == 200.0 and p["sim_rate"] == 0.0  # the caller's dict untouched
