"""The ROS launch file compiles and starts the same process set as `softhand demo`."""
import importlib.util
import py_compile
from pathlib import Path

from softhand_sim.commands.demo import NODE_SET

LAUNCH = Path(__file__).resolve().parents[2] / "softhand_sim" / "launch" / "softhand.launch.py"


def test_launch_file_compiles_and_matches_demo(tmp_path):
    """py_compile succeeds; NODES equals the demo's NODE_SET; every node has a console script."""
    py_compile.compile(str(LAUNCH), cfile=str(tmp_path / "launch.pyc"), doraise=True)
    spec = importlib.util.spec_from_file_location("softhand_launch", LAUNCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)  # launch packages are imported lazily, inside the function
    assert tuple(module.NODES) == tuple(NODE_SET)
    assert callable(module.generate_launch_description)
    setup_text = {pkg: (LAUNCH.parents[2] / pkg / "setup.py").read_text() for pkg, _ in NODE_SET}
    for pkg, exe in NODE_SET:
        assert f'"{exe} = {pkg}.{exe}:main"' in setup_text[pkg]
