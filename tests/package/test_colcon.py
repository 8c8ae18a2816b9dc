"""The ROS way in: `colcon build` of ros_ws gives install/<pkg>/lib/<pkg>/<node> executables that run."""
import subprocess
import sys
from pathlib import Path

import pytest

from softhand_sim.ros.env import isolated_env

REPO = Path(__file__).resolve().parents[2]
EXPECTED = {
    "softhand_sim": {"sim_node", "record_node"},
    "softhand_tracking": {"tracking_node", "play_node"},
    "softhand_world": {"world_node"},
}


@pytest.fixture(scope="module")
def colcon_install(tmp_path_factory):
    colcon = Path(sys.executable).parent / "colcon"
    assert colcon.exists(), "colcon-core is part of requirements.lock"
    base = tmp_path_factory.mktemp("colcon")
    proc = subprocess.run(
        [str(colcon), "--log-base", str(base / "log"), "build", "--base-paths", str(REPO / "ros_ws" / "src"),
         "--build-base", str(base / "build"), "--install-base", str(base / "install")],
        cwd=base, capture_output=True, text=True, timeout=300, env=isolated_env(),
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return base / "install"


def test_packages_and_executables(colcon_install):
    """Every package of ros_ws/src installs its node executables under lib/<pkg>, plus share/ files."""
    for pkg, nodes in EXPECTED.items():
        lib = colcon_install / pkg / "lib" / pkg
        assert nodes <= {p.name for p in lib.iterdir()}, (pkg, sorted(p.name for p in lib.iterdir()))
        share = colcon_install / pkg / "share" / pkg
        assert (share / "package.xml").is_file()
        assert (colcon_install / pkg / "share" / "ament_index" / "resource_index" / "packages" / pkg).is_file()
    config = colcon_install / "softhand_sim" / "share" / "softhand_sim" / "config"
    assert (config / "softhand.yaml").is_file() and (config / "scene.yaml").is_file()
    assert (config / "fastdds_local.xml").is_file() and (config / "fastdds_lan.xml").is_file()


@pytest.mark.parametrize("pkg,node", sorted((p, n) for p, ns in EXPECTED.items() for n in ns))
def test_installed_executable_help(colcon_install, pkg, node):
    """After sourcing install/setup.sh, `<node> --help` runs the installed copy and exits 0."""
    exe = colcon_install / pkg / "lib" / pkg / node
    script = f'. "{colcon_install}/setup.sh" && "{exe}" --help'
    env = isolated_env()
    env["PATH"] = f"{Path(sys.executable).parent}:{env['PATH']}"
    proc = subprocess.run(["sh", "-c", script], capture_output=True, text=True, timeout=120, env=env)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "usage" in (proc.stdout + proc.stderr).lower()
