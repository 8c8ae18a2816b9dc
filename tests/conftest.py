"""Shared fixtures. Every ROS process a test starts gets loopback-only discovery and its own domain."""
import os
from pathlib import Path

import pytest

from softhand_sim.ros.env import apply_isolated_env, isolated_env, release_domain_id

REPO = Path(__file__).resolve().parents[1]

# The test process itself may start rclpy (in-process subscribers that watch the nodes): give it
# an isolated domain before anything imports rclpy.
apply_isolated_env()


@pytest.fixture
def ros_env():
    """Environment for subprocesses of one test: LOCALHOST discovery and a fresh ROS_DOMAIN_ID.

    The test process itself is moved to the same domain so that in-process listeners hear them.
    """
    env = isolated_env()
    old = os.environ.get("ROS_DOMAIN_ID")
    os.environ["ROS_DOMAIN_ID"] = env["ROS_DOMAIN_ID"]
    yield env
    if old is not None:
        os.environ["ROS_DOMAIN_ID"] = old
    release_domain_id(env["ROS_DOMAIN_ID"])


@pytest.fixture(scope="session")
def repo_root():
    return REPO


def pytest_terminal_summary(terminalreporter):
    """The first failure of every test that passed on a rerun (rerunfailures prints only its
    name, even with -rR): a node-level test's rerun on a fresh clone is then a cause, not a guess."""
    reruns = terminalreporter.stats.get("rerun", [])
    if reruns:
        terminalreporter.section("the failures that were rerun")
        for rep in reruns:
            terminalreporter.write_line(f"{rep.nodeid} ({rep.when}):")
            terminalreporter.write_line(rep.longreprtext[-4000:])
