"""Where the project's data files are found: config/, bags/, the model cache.

Order for config files: $SOFTHAND_CONFIG_DIR, the source checkout's config/ (plain or editable
install), then the ament share directory (after `colcon build`: share/softhand_sim/config).
"""
import os
from pathlib import Path

_PKG_DIR = Path(__file__).resolve().parent
# softhand_sim/softhand_sim/paths.py -> the repository root, when running from a checkout
REPO_ROOT = _PKG_DIR.parents[1]


def _share_dir():
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory("softhand_sim"))
    except Exception:  # not installed through ament/colcon: no share directory
        return None


def config_dirs():
    dirs = []
    if os.environ.get("SOFTHAND_CONFIG_DIR"):
        dirs.append(Path(os.environ["SOFTHAND_CONFIG_DIR"]))
    dirs.append(REPO_ROOT / "config")
    share = _share_dir()
    if share is not None:
        dirs.append(share / "config")
    return dirs


def default_config_file(name: str) -> Path:
    """The first existing `name` among config_dirs(); the repo path if none exists (for messages)."""
    for d in config_dirs():
        if (d / name).is_file():
            return d / name
    return REPO_ROOT / "config" / name


def bags_dir() -> Path:
    return Path(os.environ.get("SOFTHAND_BAGS_DIR", REPO_ROOT / "bags"))


#: beside a bag: the node parameters its scene needs (tools/make_bags.py writes it, softhand demo
#: and softhand offline read it)
BAG_PARAMS = "params.yaml"


def bag_path(bag) -> Path:
    """A bag's directory: `bag` as a path when it exists, else the sample bag of that name in
    bags_dir() (which may not exist either: the caller's reader says so)."""
    path = Path(bag)
    return path if path.exists() else bags_dir() / str(bag)


def bag_params_file(bag):
    """The bag's params.yaml (BAG_PARAMS) when it has one, else None."""
    path = bag_path(bag) / BAG_PARAMS
    return path if path.is_file() else None


def cache_dir() -> Path:
    """Cache for built hand models and SDFs ($SOFTHAND_CACHE, else ~/.cache/softhand)."""
    d = Path(os.environ.get("SOFTHAND_CACHE", Path.home() / ".cache" / "softhand"))
    d.mkdir(parents=True, exist_ok=True)
    return d
