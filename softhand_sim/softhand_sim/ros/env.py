"""Environment for every process that starts rclpy from this project's tests, demo and benchmarks.

Without ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, Fast DDS multicasts discovery on every network
interface; with it, no packet leaves loopback. A ROS_DOMAIN_ID of its own keeps parallel runs
(two test sessions, a demo beside the tests) from hearing each other. ROS_LOCALHOST_ONLY is
deprecated in Jazzy, so it is removed rather than set. A Fast DDS profile file named by the user's
environment (config/fastdds_lan.xml for a LAN) is replaced by config/fastdds_local.xml: under
LOCALHOST, rmw adds its loopback transport to a profile's transports, so a profile's UDP on every
interface would stay; the local profile names no transport (it only shortens the writers'
heartbeat, see the file).
"""
import fcntl
import os
import random
import tempfile

# Fast DDS ports are 7400 + 250 * domain (+ offsets). Above domain 101 they fall in Linux's
# ephemeral port range (32768..60999), where a socket the kernel gave any process a port from can
# hold a participant's port: ROS's "About Domain ID" page names 0..101 the safe ids. We keep off the
# low ids that people's real robots use (0 is ROS's default).
_DOMAIN_LOW, _DOMAIN_HIGH = 20, 101
_LOCK_DIR = os.path.join(tempfile.gettempdir(), "softhand-ros-domains")
_held = {}  # domain id -> open lock file (the flock lasts while this process keeps it open)
# Fast DDS 2.x reads the first, 3.x the second
PROFILE_VARIABLES = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")
LOCAL_PROFILE = "fastdds_local.xml"


def pick_domain_id(seed=None) -> int:
    """A domain id that no other softhand run on this machine holds, claimed by this process.

    Each id is claimed with an exclusive flock on a file under the temp dir: two test sessions, a
    demo and a soak running at once never share a domain. The claim ends with release_domain_id()
    or when this process exits (the kernel drops the lock), so a crash leaves nothing stale.
    """
    rng = random.Random(seed if seed is not None else os.getpid() ^ int.from_bytes(os.urandom(2), "little"))
    ids = list(range(_DOMAIN_LOW, _DOMAIN_HIGH + 1))
    rng.shuffle(ids)
    os.makedirs(_LOCK_DIR, exist_ok=True)
    for domain in ids:
        if domain in _held:
            continue
        f = open(os.path.join(_LOCK_DIR, f"{domain}.lock"), "w")
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            f.close()
            continue
        _held[domain] = f
        return domain
    raise RuntimeError(f"no free ROS domain id in {_DOMAIN_LOW}..{_DOMAIN_HIGH} (all held by other runs)")


def release_domain_id(domain) -> None:
    """Give back a domain id claimed by pick_domain_id (no-op for ids not held here)."""
    f = _held.pop(int(domain), None)
    if f is not None:
        f.close()


def isolated_env(domain_id=None, base=None) -> dict:
    """A copy of `base` (default os.environ) with loopback-only discovery and its own domain id."""
    env = dict(os.environ if base is None else base)
    set_loopback(env)
    env["ROS_DOMAIN_ID"] = str(pick_domain_id() if domain_id is None else int(domain_id))
    env.setdefault("PYTHONUNBUFFERED", "1")
    return env


def set_loopback(env) -> None:
    """Loopback-only discovery in the mapping `env` (a dict, or os.environ for this process): the
    range LOCALHOST, no ROS_LOCALHOST_ONLY, the local Fast DDS profile instead of any other. The
    domain id is left as it is."""
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    for name in ("ROS_LOCALHOST_ONLY", *PROFILE_VARIABLES):
        env.pop(name, None)
    local = local_profile()
    if local is not None:
        env[PROFILE_VARIABLES[0]] = str(local)


def local_profile():
    """config/fastdds_local.xml (the path found by softhand_sim.paths), or None without one."""
    from softhand_sim.paths import default_config_file

    path = default_config_file(LOCAL_PROFILE)
    return path if path.is_file() else None


def names_transports(profile) -> bool:
    """Whether a Fast DDS profile file defines transports (unreadable: assume it does)."""
    try:
        with open(profile, encoding="utf-8", errors="replace") as f:
            text = f.read()
    except OSError:
        return True
    return "<userTransports>" in text or "<transport_descriptor>" in text


def apply_isolated_env(domain_id=None) -> dict:
    """Apply `isolated_env` to this process (call before rclpy.init)."""
    env = isolated_env(domain_id)
    set_loopback(os.environ)
    for key in ("ROS_DOMAIN_ID", "PYTHONUNBUFFERED"):
        os.environ[key] = env[key]
    return env


def discovery_note(environ=None):
    """(level, message) a node logs at start about how it meets the others, or None on loopback as
    the demo and the tests run it. level is "warn" for the combination that leaks: LOCALHOST with
    a Fast DDS profile exported (rmw adds its loopback transport to the profile's, so the profile's
    UDP on every interface stays); "info" for a LAN range, naming the profile in use or the README
    section that gives one (without it a send to a host whose link is down blocks the node)."""
    env = os.environ if environ is None else environ
    rng = env.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "") or "SUBNET (ROS's default)"
    domain = env.get("ROS_DOMAIN_ID", "") or "0"
    profile = next((env[name] for name in PROFILE_VARIABLES if env.get(name)), None)
    if rng == "LOCALHOST":
        if profile and names_transports(profile):
            return ("warn", f"ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST with the Fast DDS profile {profile}: "
                            "rmw adds loopback to the profile's transports, so DDS still uses every interface "
                            "the profile names; unset the profile variable for a loopback-only run")
        return None
    how = (f"Fast DDS profile {profile}" if profile else
           "Fast DDS's default transports (across machines, export FASTRTPS_DEFAULT_PROFILES_FILE="
           "config/fastdds_lan.xml: README, 'Running across machines')")
    return ("info", f"discovery range {rng}, ROS_DOMAIN_ID {domain}, {how}")
