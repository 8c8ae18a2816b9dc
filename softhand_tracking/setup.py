"""ament_python package softhand_tracking; also installs as a plain Python package (see README)."""
import glob
import os

from setuptools import find_packages, setup

package_name = "softhand_tracking"
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
    description="Elastic tracking: 250 Hz intermediate-bone loop, tracker bag replay",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "tracking_node = softhand_tracking.tracking_node:main",
            "play_node = softhand_tracking.play_node:main",
            "softhand-tracking = softhand_tracking.tracking_node:main",
            "softhand-play = softhand_tracking.play_node:main",
        ],
    },
)
