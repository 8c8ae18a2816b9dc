"""Parameter files: defaults complete and valid, bad values refused with the key and value named."""
import pytest

from softhand_sim.params import SCHEMA, ParamError, defaults, load_params, read_params_file
from softhand_sim.paths import default_config_file


@pytest.mark.parametrize("node", sorted(SCHEMA))
def test_defaults_cover_schema(node):
    """config/softhand.yaml gives a valid default for every key of every node, and no other key."""
    section = read_params_file(default_config_file("softhand.yaml"))[node]
    assert set(section) == set(SCHEMA[node])
    assert set(defaults(node)) == set(SCHEMA[node])


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
