"""The environment every ROS process of the tests, demo and benchmarks gets (softhand_sim.ros.env)."""
from softhand_sim.ros.env import PROFILE_VARIABLES, isolated_env, release_domain_id


def test_isolated_env_is_loopback_only_even_with_a_lan_profile_exported():
    """A user who followed "Running across machines" has the LAN's Fast DDS profile exported; under
    LOCALHOST rmw would add its loopback transport to that profile's UDP on every interface, so the
    isolated environment drops the profile (and the deprecated ROS_LOCALHOST_ONLY), and sets
    LOCALHOST and a domain id of its own."""
    base = {name: "/somewhere/fastdds_lan.xml" for name in PROFILE_VARIABLES}
    base.update(ROS_AUTOMATIC_DISCOVERY_RANGE="SUBNET", ROS_LOCALHOST_ONLY="0", ROS_DOMAIN_ID="0", PATH="/usr/bin")
    env = isolated_env(base=base)
    try:
        assert not set(PROFILE_VARIABLES) & set(env) and "ROS_LOCALHOST_ONLY" not in env
        assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
        assert 20 <= int(env["ROS_DOMAIN_ID"]) <= 230 and env["PATH"] == "/usr/bin"
        assert base["FASTRTPS_DEFAULT_PROFILES_FILE"]  # the caller's dict is left as it was
    finally:
        release_domain_id(env["ROS_DOMAIN_ID"])
