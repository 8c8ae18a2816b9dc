"""ros2 launch softhand_sim softhand.launch.py bag:=/path/to/tracker_bag [hands:=both] [record:=true] [output:=DIR]

Starts the same process set as `softhand demo`: world_node, sim_node, one tracking_node per hand,
record_node and play_node (which replays `bag`). Parameters come from
share/softhand_sim/config/softhand.yaml. `hands`: right (default), left or both; with both, sim_node
simulates the two hands in one solve and the left hand's tracking node runs as tracking_node_left.
A live tracker instead of a bag: leave `bag` empty and publish /tracker/{right,left}/hand_joints.
The yaml's tracking_node section is keyed by node name: tracking_node_left takes the schema's
defaults and `hand: left` (copy the section under tracking_node_left to change them).

The `launch` packages are not on PyPI, so this file is only exercised on a full ROS 2 Jazzy install;
the test suite checks that it compiles and that NODES matches the demo's node set.
"""
import os

# (package, executable) in start order; the demo starts the same set (softhand_sim/demo.py).
NODES = (
    ("softhand_world", "world_node"),
    ("softhand_sim", "sim_node"),
    ("softhand_tracking", "tracking_node"),
    ("softhand_sim", "record_node"),
    ("softhand_tracking", "play_node"),
)


def generate_launch_description():
    # Imported here so that the module (NODES) can be read without the launch packages.
    from ament_index_python.packages import get_package_share_directory
    from launch import LaunchDescription
    from launch.actions import DeclareLaunchArgument
    from launch.conditions import IfCondition
    from launch.substitutions import LaunchConfiguration, PythonExpression
    from launch_ros.actions import Node

    params = os.path.join(get_package_share_directory("softhand_sim"), "config", "softhand.yaml")
    bag = LaunchConfiguration("bag")
    hands = LaunchConfiguration("hands")
    both = PythonExpression(["'", hands, "' == 'both'"])
    actions = [
        DeclareLaunchArgument("bag", default_value="", description="tracker rosbag2 directory to replay"),
        DeclareLaunchArgument("hands", default_value="right", description="right, left or both"),
        DeclareLaunchArgument("record", default_value="true", description="record the run with record_node"),
        DeclareLaunchArgument("output", default_value="", description="recording directory (empty: runs/<stamp>/bag)"),
    ]
    for package, executable in NODES:
        extra = {}
        condition = None
        if executable == "record_node":
            extra = {"output": LaunchConfiguration("output")}
            condition = IfCondition(LaunchConfiguration("record"))
        elif executable == "play_node":
            extra = {"bag": bag, "hand": PythonExpression(["'left' if '", hands, "' == 'left' else 'right'"])}
            condition = IfCondition(PythonExpression(["'", bag, "' != ''"]))
        elif executable == "sim_node":
            extra = {"hands": PythonExpression(["['right', 'left'] if '", hands, "' == 'both' else ['", hands, "']"])}
        elif executable == "tracking_node":  # the first hand's; the left one of two follows below
            extra = {"hand": PythonExpression(["'right' if '", hands, "' == 'both' else '", hands, "'"])}
            actions.append(Node(package=package, executable=executable, name="tracking_node_left", output="screen",
                                parameters=[params, {"hand": "left"}], condition=IfCondition(both)))
        actions.append(Node(package=package, executable=executable, name=executable, output="screen",
                            parameters=[params, extra] if extra else [params], condition=condition))
    return LaunchDescription(actions)
