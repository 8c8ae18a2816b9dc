"""The core libraries import without rclpy: only node, ROS-helper and CLI modules may use it."""
import importlib
import pkgutil
import subprocess
import sys


PACKAGES = ("softhand_sim", "softhand_tracking", "softhand_world")
# Module names allowed to import rclpy (docs/ARCHITECTURE.md: nodes stay thin, the core never imports rclpy).
ROS_MODULE_SUFFIXES = ("_node", ".cli")
ROS_MODULES = ("softhand_sim.ros.common", "softhand_sim.ros.params")


def core_modules():
    names = []
    for pkg_name in PACKAGES:
        pkg = importlib.import_module(pkg_name)
        for info in pkgutil.walk_packages(pkg.__path__, pkg_name + "."):
            if info.name.endswith(ROS_MODULE_SUFFIXES) or info.name in ROS_MODULES:
                continue
            names.append(info.name)
    return names


BLOCKER = r"""
import importlib, sys
class BlockRclpy:
    def find_spec(self, name, path=None, target=None):
        if name == "rclpy" or name.startswith("rclpy."):
            raise ImportError("rclpy is blocked: core module imported it")
        return None
sys.meta_path.insert(0, BlockRclpy())
failed = []
for name in sys.argv[1:]:
    try:
        importlib.import_module(name)
    except Exception as exc:
        failed.append(f"{name}: {type(exc).__name__}: {exc}")
print("\n".join(failed))
sys.exit(1 if failed else 0)
"""


def test_core_modules_import_without_rclpy():
    """Every core module imports in a fresh interpreter where importing rclpy raises."""
    names = core_modules()
    assert len(names) >= 5, names
    proc = subprocess.run([sys.executable, "-c", BLOCKER, *names], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_blocker_really_blocks():
    """The blocker itself fails an import that needs rclpy (so the test above can fail)."""
    proc = subprocess.run([sys.executable, "-c", BLOCKER, "rclpy.node"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1 and "blocked" in proc.stdout
