"""softhand_sim.ros.common: rate meter, parameter schema, diagnostics publisher, CLI split, topic table."""
import argparse

import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.parameter import Parameter

from tests.support.rosproc import RosGraph
from softhand_sim.ros import common as rc
from softhand_sim.ros.msgs import diagnostic_values


def test_rate_meter_against_known_periods():
    """Rate and period percentiles of a synthetic 100 Hz series with one 30 ms hiccup match hand-computed values."""
    meter = rc.RateMeter(window=1000)
    t = 0.0
    for i in range(101):
        meter.tick(t)
        t += 0.03 if i == 50 else 0.01
    s = meter.stats()
    # 100 periods spanning 99 * 10 ms + 30 ms = 1.02 s
    assert s["rate_hz"] == pytest.approx(100 / 1.02)
    assert s["period_p50_ms"] == pytest.approx(10.0)
    assert s["count"] == 101
    assert 10.0 < s["period_p99_ms"] <= 30.0
    assert rc.RateMeter().stats()["rate_hz"] == 0.0


def test_message_class_and_topic_table():
    """Every docs/INTERFACE.md topic type resolves to an rclpy class; a bad name is refused by name."""
    from softhand_sim.ros.tf import tf_message_class

    tf_built = tf_message_class()[0] is not None
    for topic, name in rc.TOPIC_TYPES.items():
        if name.startswith("tf2_msgs/") and not tf_built:  # no compiler: refused by name, not a crash
            with pytest.raises(ValueError, match="tf2_msgs/msg/TFMessage"):
                rc.message_class(name)
            continue
        cls = rc.message_class(name)
        assert cls.__name__ == name.split("/")[-1]
    with pytest.raises(ValueError, match="unknown message type 'nope/msg/X'"):
        rc.message_class("nope/msg/X")
    with pytest.raises(ValueError, match="pkg/msg/Name"):
        rc.message_class("PoseArray")


def test_split_cli_leaves_ros_args():
    """The node's own flags are parsed; --ros-args ... stays for rclpy.init."""
    parser = argparse.ArgumentParser()
    parser.add_argument("--rate", type=float)
    ns, argv = rc.split_cli(parser, ["prog", "--rate", "2", "--ros-args", "-p", "x:=1"])
    assert ns.rate == 2.0 and argv[-3:] == ["--ros-args", "-p", "x:=1"]


def test_schema_parameters_and_diagnostics(ros_env):
    """Parameters declared from a schema carry doc+unit and refuse out-of-range values; the diagnostics
    helper publishes the collected dict at its period, and an exception in collect() becomes an ERROR status."""
    with RosGraph(ros_env) as g:
        node = rclpy.create_node("schema_probe", context=g.context)
        try:
            values = rc.declare_parameters_from_schema(node, {
                "rate": {"default": 250.0, "doc": "loop rate", "unit": "Hz", "min": 1.0, "max": 1000.0},
                "name": "abc",
                "count": {"default": 3, "range": (0, 10)},
            })
            assert values == {"rate": 250.0, "name": "abc", "count": 3}
            desc = node.describe_parameter("rate")
            assert desc.description == "loop rate [Hz]"
            result = node.set_parameters([Parameter("rate", value=5000.0)])[0]
            assert not result.successful
            with pytest.raises(ValueError, match="'bad' has no default"):
                rc.declare_parameters_from_schema(node, {"bad": {"doc": "x"}})

            diags = g.listen("/diagnostics", DiagnosticArray)
            state = {"fail": False}

            def collect():
                if state["fail"]:
                    raise RuntimeError("boom")
                return {"step_ms": 1.5}, "warn", "slow"

            rc.DiagnosticsPublisher(node, collect, period=0.1)
            g.executor.add_node(node)
            g.wait_until(lambda: len(diags) >= 2, 10, "diagnostics")
            st = diags.msgs[0].status[0]
            assert st.name == "schema_probe: status" and st.level == b"\x01" and st.message == "slow"
            assert st.hardware_id.startswith("softhand@")
            assert diagnostic_values(st) == {"step_ms": "1.5"}
            state["fail"] = True
            n = len(diags)
            g.wait_until(lambda: len(diags) >= n + 2, 10, "error diagnostics")
            err = diags.msgs[-1].status[0]
            assert err.level == b"\x02" and "RuntimeError: boom" in err.message
        finally:
            g.executor.remove_node(node)
            node.destroy_node()
