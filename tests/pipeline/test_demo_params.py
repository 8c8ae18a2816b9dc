"""`softhand demo`'s params file for two hands: what it writes is read by rcl's own parser."""
import yaml


def test_tracking_section_is_given_to_the_left_hand_node_as_rcl_reads_it(tmp_path):
    """A user's file with a tracking_node section, run with both hands: the copy the demo passes
    to every node gives tracking_node_left the same parameters, and rcl's params-file parser (the
    one every node runs) accepts it. A shared dict was written as a YAML anchor and alias, which
    rcl refuses ("Will not support aliasing") and every node then failed to start."""
    from rclpy.utilities import remove_ros_args

    from softhand_sim.commands.demo import params_file_for_hands

    user = tmp_path / "mine.yaml"
    user.write_text("tracking_node:\n  ros__parameters:\n    joint_filter: one_euro\n"
                    "sim_node:\n  ros__parameters:\n    self_contact: true\n")
    out = tmp_path / "run"
    out.mkdir()
    written = params_file_for_hands(user, ["right", "left"], out)
    data = yaml.safe_load(written.read_text())
    assert data["tracking_node_left"] == data["tracking_node"] == {"ros__parameters": {"joint_filter": "one_euro"}}
    assert data["sim_node"] == {"ros__parameters": {"self_contact": True}}
    # raises RCLInvalidROSArgsError naming the file when rcl cannot parse it
    assert remove_ros_args(["softhand-tracking", "--ros-args", "--params-file", str(written)]) == ["softhand-tracking"]
    assert params_file_for_hands(user, ["right"], out) == user  # one hand: the user's own file
