"""ament_python package softhand_world; also installs as a plain Python package (see README)."""
import glob
import os

from setuptools import find_packages, setup

package_name = "softhand_world"
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

    ],
    install_requires=[],
    zip_safe=False,
    maintainer="softhand developers",
    maintainer_email="dev@softhand.invalid",
    description="pybullet world coupled two-way to the soft hand through copied object states",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "world_node = softhand_world.world_node:main",
            "softhand-world = softhand_world.world_node:main",
        ],
    },
)
