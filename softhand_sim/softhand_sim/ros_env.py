"""Environment for every process that starts rclpy from this project's tests, demo and benchmarks.

Without ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, Fast DDS multicasts discovery on every network
interface; with it, no packet leaves loopback. A ROS_DOMAIN_ID of its own keeps parallel runs
(two test sessions, a demo beside the tests) from hearing each other. ROS_LOCALHOST_ONLY is
deprecated in Jazzy, so it is removed rather than set.
"""
import os
import random

# Domain ids 0..101 and 215..232 are valid for Fast DDS on Linux with default ports; we keep to
# a band that does not collide with the usual default (0) used by people's real robots.
_DOMAIN_LOW, _DOMAIN_HIGH = 40, 100


def pick_domain_id(seed=None) -> int:
    """A domain id for one isolated run (random unless seeded)."""
    rng = random.Random(seed if seed is not None else os.getpid() ^ int.from_bytes(os.urandom(2), "little"))
    return rng.randint(_DOMAIN_LOW, _DOMAIN_HIGH)


def isolated_env(domain_id=None, base=None) -> dict:
    """A copy of `base` (default os.environ) with loopback-only discovery and its own domain id."""
    env = dict(os.environ if base is None else base)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["ROS_DOMAIN_ID"] = str(pick_domain_id() if domain_id is None else int(domain_id))
    env.pop("ROS_LOCALHOST_ONLY", None)
    env.setdefault("PYTHONUNBUFFERED", "1")
    return env


def apply_isolated_env(domain_id=None) -> dict:
    """Apply `isolated_env` to this process (call before rclpy.init)."""
    env = isolated_env(domain_id)
    for key in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_DOMAIN_ID", "PYTHONUNBUFFERED"):
        os.environ[key] = env[key]
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
    return env
