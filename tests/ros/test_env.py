"""The environment every ROS process of the tests, demo and benchmarks gets (softhand_sim.ros.env)."""
from softhand_sim.ros.env import PROFILE_VARIABLES, isolated_env, release_domain_id


def test_isolated_env_is_loopback_only_even_with_a_lan_profile_exported():
    """A user who followed "Running across machines" has the LAN's Fast DDS profile exported; under
    LOCALHOST rmw would add its loopback transport to that profile's UDP on every interface, so the
    isolated environment replaces it with config/fastdds_local.xml (no transports in it), drops
    the deprecated ROS_LOCALHOST_ONLY, and sets LOCALHOST and a domain id of its own."""
    from softhand_sim.ros.env import names_transports
    from softhand_sim.paths import REPO_ROOT

    base = {name: "/somewhere/fastdds_lan.xml" for name in PROFILE_VARIABLES}
    base.update(ROS_AUTOMATIC_DISCOVERY_RANGE="SUBNET", ROS_LOCALHOST_ONLY="0", ROS_DOMAIN_ID="0", PATH="/usr/bin")
    env = isolated_env(base=base)
    try:
        local = REPO_ROOT / "config" / "fastdds_local.xml"
        assert env[PROFILE_VARIABLES[0]] == str(local) and PROFILE_VARIABLES[1] not in env
        assert not names_transports(local) and names_transports(REPO_ROOT / "config" / "fastdds_lan.xml")
        assert "ROS_LOCALHOST_ONLY" not in env
        assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
        assert 20 <= int(env["ROS_DOMAIN_ID"]) <= 101 and env["PATH"] == "/usr/bin"
        assert base["FASTRTPS_DEFAULT_PROFILES_FILE"]  # the caller's dict is left as it was
    finally:
        release_domain_id(env["ROS_DOMAIN_ID"])


def test_discovery_note_names_the_range_and_warns_of_a_leaking_combination():
    """What a node logs at start: nothing on loopback (the demo and the tests); a warning when a
    Fast DDS profile is exported under LOCALHOST (its transports would stay on every interface);
    on a LAN the range, the domain and the profile in use, or where to find one."""
    from softhand_sim.ros.env import discovery_note

    from softhand_sim.paths import REPO_ROOT

    assert discovery_note({"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "ROS_DOMAIN_ID": "42"}) is None
    local = str(REPO_ROOT / "config" / "fastdds_local.xml")  # names no transport: nothing to warn of
    assert discovery_note({"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "FASTRTPS_DEFAULT_PROFILES_FILE": local}) is None
    level, text = discovery_note({"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
                                  "FASTRTPS_DEFAULT_PROFILES_FILE": "/x/fastdds_lan.xml"})
    assert level == "warn" and "/x/fastdds_lan.xml" in text and "every interface" in text
    level, text = discovery_note({"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET", "ROS_DOMAIN_ID": "42",
                                  "FASTRTPS_DEFAULT_PROFILES_FILE": "/x/fastdds_lan.xml"})
    assert level == "info" and "SUBNET" in text and "42" in text and "/x/fastdds_lan.xml" in text
    level, text = discovery_note({})  # nothing set: ROS's default range, domain 0, no profile
    assert level == "info" and "default" in text and "ROS_DOMAIN_ID 0" in text and "fastdds_lan.xml" in text
