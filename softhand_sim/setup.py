"""ament_python package softhand_sim; also installs as a plain Python package (see README)."""
import glob
import os

from setuptools import find_packages, setup

package_name = "softhand_sim"
here = os.path.dirname(os.path.abspath(__file__))


def repo_files(pattern):
    """Files of the repository's top level (config/, bags/), shipped into share/ for ROS users."""
    return sorted(os.path.relpath(p, here) for p in glob.glob(os.path.join(here, "..", pattern)))


setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "tests"]),
    package_data={package_name: ["py.typed"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", repo_files("config/*.yaml") + repo_files("config/*.xml")),
        ("share/" + package_name + "/launch", sorted(glob.glob("launch/*.launch.py"))),
    ],
    install_requires=[],
    zip_safe=False,
    maintainer="softhand developers",
    maintainer_email="dev@softhand.invalid",
    description="Soft hand simulation (skeleton, co-rotational FEM tissue, SDF contact) as ROS 2 nodes",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "sim_node = softhand_sim.sim_node:main",
            "record_node = softhand_sim.record_node:main",
            "softhand-sim = softhand_sim.sim_node:main",
            "softhand-record = softhand_sim.record_node:main",
            "softhand = softhand_sim.commands.cli:main",
        ],
    },
)
