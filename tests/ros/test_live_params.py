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


@pytest.mark.parametrize("node_name, script, live_key, live_value, start_key", [
    ("tracking_node", "softhand-tracking", "tracked_kx", 800.0, "rate"),
    ("world_node", "softhand-world", None, None, "engine_rate"),
])
def test_parameter_services_of_a_running_node(ros_env, node_name, script, live_key, live_value, start_key):
    """Through the node's standard /<node>/set_parameters and describe_parameters services (what
    `ros2 param set/describe` call): an out-of-range value and a start-only key are refused with the
    reason and leave the value as it was; a live key takes effect (get_parameters reads it back)."""
    from rcl_interfaces.srv import DescribeParameters, GetParameters, SetParameters

    from tests.support.rosproc import RosGraph

    def call(g, client, request, proc):
        future = client.call_async(request)
        # the services exist from the node's first line; the node answers once it spins (after its warm-up)
        g.wait_until(future.done, 120, f"{client.srv_name} reply", proc)
        return future.result()

    with RosGraph(ros_env) as g:
        proc = g.start([script])
        setter = g.node.create_client(SetParameters, f"/{node_name}/set_parameters")
        getter = g.node.create_client(GetParameters, f"/{node_name}/get_parameters")
        describer = g.node.create_client(DescribeParameters, f"/{node_name}/describe_parameters")
        g.wait_until(lambda: setter.service_is_ready() and getter.service_is_ready()
                     and describer.service_is_ready(), 90, f"{node_name} parameter services", proc)
        before = call(g, getter, GetParameters.Request(names=[start_key]), proc).values[0].double_value
        desc = call(g, describer, DescribeParameters.Request(names=[start_key]), proc).descriptors[0]
        assert SCHEMA[node_name][start_key].unit in desc.description
        refused = call(g, setter, SetParameters.Request(parameters=[
            Parameter(start_key, value=-5.0).to_parameter_msg()]), proc).results[0]
        assert not refused.successful and start_key in refused.reason
        refused = call(g, setter, SetParameters.Request(parameters=[
            Parameter(start_key, value=before * 0.75).to_parameter_msg()]), proc).results[0]
        assert not refused.successful and "only at start" in refused.reason
        after = call(g, getter, GetParameters.Request(names=[start_key]), proc).values[0].double_value
        assert after == before
        if live_key is not None:
            ok = call(g, setter, SetParameters.Request(parameters=[
                Parameter(live_key, value=live_value).to_parameter_msg()]), proc).results[0]
            assert ok.successful, ok.reason
            got = call(g, getter, GetParameters.Request(names=[live_key]), proc).values[0].double_value
            assert got == live_value
        assert proc.alive()
