"""Run-time parameter changes through rclpy's parameter interface (the set_parameters service calls the same
callback): descriptors carry the schema's meaning, unit and range; a live key takes effect, a bad value and a
start-only key are refused with the reason; nothing is accepted and ignored."""
import pytest
import rclpy
from rclpy.parameter import Parameter

from softhand_sim.params import SCHEMA
from softhand_sim.ros.params import declare_node_params

pytestmark = pytest.mark.ros


@pytest.fixture
def node(ros_env):
    rclpy.init()
    made = []

    def make(live=None):
        n = rclpy.create_node("tracking_node")
        made.append(n)
        return n, declare_node_params(n, "tracking_node", live=live)

    yield make
    for n in made:
        n.destroy_node()
    rclpy.shutdown()


def test_descriptors_carry_meaning_unit_and_range(node):
    n, cfg = node()
    desc = n.describe_parameter("damping_ratio")
    p = SCHEMA["tracking_node"]["damping_ratio"]
    assert p.doc in desc.description and f"[{p.unit}]" in desc.description
    if p.low is not None and p.high is not None:
        rng = desc.floating_point_range[0]
        assert (rng.from_value, rng.to_value) == (p.low, p.high)
    assert cfg["rate"] == SCHEMA["tracking_node"]["rate"].default


def test_live_key_applied_bad_value_and_start_only_key_refused(node):
    applied = []
    n, _ = node(live={"tracked_kx": applied.append})
    ok = n.set_parameters([Parameter("tracked_kx", value=120.0)])[0]
    assert ok.successful and applied == [120.0]
    bad = n.set_parameters([Parameter("tracked_kx", value=-5.0)])[0]
    assert not bad.successful and "tracked_kx" in bad.reason and "-5.0" in bad.reason
    start_only = n.set_parameters([Parameter("rate", value=300.0)])[0]
    assert not start_only.successful and "only at start" in start_only.reason
    assert n.get_parameter("rate").value == SCHEMA["tracking_node"]["rate"].default
    assert applied == [120.0]


def test_apply_may_refuse(node):
    def refuse(value):
        raise ValueError("not while a hand is held")
    n, _ = node(live={"tracked_kx": refuse})
    res = n.set_parameters([Parameter("tracked_kx", value=60.0)])[0]
    assert not res.successful and "not while a hand is held" in res.reason
