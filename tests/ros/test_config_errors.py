"""Configuration errors (issue #10 item 6): every node refuses a bad configuration at start, exit
code 1, one message naming the key and the bad value, no traceback. Real node processes; the
cases of one test start in parallel (each is a second or two of rclpy start-up).

The validator itself is tested in tests/config/test_params.py; this checks that each node
runs it, and the scene errors only nodes see (missing scene file, missing mesh).
"""
import subprocess
import time

import pytest

from tests.support.rosproc import VENV_BIN

pytestmark = pytest.mark.ros

MISSING_MESH_SCENE = """\
objects:
  - name: cup
    shape: mesh
    file: meshes/missing_cup.obj
    mass: 0.1
    position: [0.0, 0.0, 0.8]
"""

# (node command and own arguments, ROS parameter, words the message must contain)
CASES = [
    (["softhand-sim"], "bogus_key:=1", ["bogus_key", "1"]),
    (["softhand-sim"], "sim_rate:=fast", ["sim_rate", "fast"]),
    (["softhand-sim"], "contact_kn:=-1.0", ["contact_kn", "-1.0"]),
    (["softhand-sim"], "object_kx:=0.0", ["object_kx", "0.0"]),
    (["softhand-sim"], "mesh:=ultra", ["mesh", "ultra"]),
    (["softhand-sim"], "scene_file:=/nonexistent/scene.yaml", ["scene_file", "/nonexistent/scene.yaml"]),
    (["softhand-sim"], "scene_file:={mesh_scene}", ["scene_file", "cup", "missing_cup.obj"]),
    # two ROS argument blocks: both parameters of the refused combination
    (["softhand-sim", "--ros-args", "-p", "hands:=[right, left]", "--"], "hand_measures:=auto",
     ["hand_measures", "auto", "hands", "['right', 'left']"]),
    (["softhand-world"], "bogus_key:=1", ["bogus_key", "1"]),
    (["softhand-world"], "coupling_kx:=0.0", ["coupling_kx", "0.0"]),
    (["softhand-world"], "coupling_ktheta:=-70.0", ["coupling_ktheta", "-70.0"]),
    (["softhand-world"], "scene_file:=/nonexistent/scene.yaml", ["scene_file", "/nonexistent/scene.yaml"]),
    (["softhand-world"], "scene_file:={mesh_scene}", ["scene_file", "cup", "missing_cup.obj"]),
    (["softhand-tracking"], "bogus_key:=1", ["bogus_key", "1"]),
    (["softhand-tracking"], "rate:=abc", ["rate", "abc"]),
    (["softhand-tracking"], "tracked_kx:=-5.0", ["tracked_kx", "-5.0"]),
    (["softhand-play", "{bag}"], "bogus_key:=1", ["bogus_key", "1"]),
    (["softhand-play", "{bag}"], "rate:=-1.0", ["rate", "-1.0"]),
    (["softhand-play", "{bag}"], "loop:=sometimes", ["loop", "sometimes"]),
    # the players' and recorders' own flags, checked as the parameters of the same names (--repeat 0
    # played the bag once), and an output the recorder cannot create (a traceback before)
    (["softhand-play", "{bag}", "--repeat", "0"], "rate:=1.0", ["repeat", "0"]),
    (["softhand-play", "{bag}", "--start", "-1"], "rate:=1.0", ["start", "-1.0"]),
    (["softhand-record", "-o", "/proc/softhand/bag"], "flush_period:=1.0", ["/proc/softhand/bag"]),
    (["softhand-record", "-o", "{out}"], "bogus_key:=x", ["bogus_key", "x"]),
    (["softhand-record", "-o", "{out}"], "flush_period:=0.0", ["flush_period", "0.0"]),
]


def test_every_node_refuses_bad_configuration(ros_env, tmp_path, repo_root):
    """Each case (unknown key, wrong type, zero or negative stiffness / rate, bad choice, missing scene
    file, scene with a missing mesh) for sim, world, tracking, play and record nodes: exit code 1
    within 60 s, the message names the key and the value, no Python traceback."""
    scene = tmp_path / "scene.yaml"
    scene.write_text(MISSING_MESH_SCENE)
    fill = {"mesh_scene": str(scene), "bag": str(repo_root / "bags" / "grasp_short")}
    procs = []
    for i, (cmd, param, words) in enumerate(CASES):
        fill["out"] = str(tmp_path / f"rec{i}")
        argv = [str(VENV_BIN / cmd[0]), *[a.format(**fill) for a in cmd[1:]], "--ros-args", "-p", param.format(**fill)]
        procs.append((argv, [w.format(**fill) for w in words],
                      subprocess.Popen(argv, env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                       stdin=subprocess.DEVNULL, text=True)))
    failures = []
    deadline = time.monotonic() + 90
    for argv, words, proc in procs:
        try:
            out, _ = proc.communicate(timeout=max(1.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            proc.kill()
            out, _ = proc.communicate()
            failures.append(f"{argv[0]} {argv[-1]}: still running (accepted a bad configuration?)")
            continue
        last = out.strip().splitlines()[-1] if out.strip() else ""
        print(f"{argv[0].split('/')[-1]} {argv[-1]} -> {proc.returncode}: {last[:160]}")
        if proc.returncode != 1 or "Traceback" in out or not all(w in last for w in words):
            failures.append(f"{argv[0]} {argv[-1]}: exit {proc.returncode}, want words {words} in: {out[-600:]}")
    assert not failures, "\n".join(failures)
    assert not any((tmp_path / f"rec{i}").exists() for i in range(len(CASES)))  # no bag started
