"""Bad input to `softhand offline` and `softhand view` ends in one line naming the bad value, not
a Python traceback: a missing bag, a bad parameter or params file, a scene object or scenario
that does not exist, a port or domain id out of range, a port another process holds."""
import socket

import pytest

from softhand_sim.commands import offline, view


@pytest.mark.parametrize("argv, message", [
    (["nobag"], "error: bag not found: "),
    (["grasp_lift", "--sim", "mesh=nope"], "error: sim_node: parameter 'mesh' must be one of"),
    (["grasp_lift", "--sim", "nokey=1"], "error: sim_node: unknown parameter 'nokey'"),
    (["grasp_lift", "--params-file", "/nonexistent/params.yaml"],
     "error: parameter file not found: /nonexistent/params.yaml"),
    (["grasp_lift", "--sim", "scene_file=/nonexistent/scene.yaml"],
     "error: scene file not found: /nonexistent/scene.yaml"),
    (["grasp_lift", "--object", "teapot"],
     "error: object 'teapot' is not among the scene's movable objects (ball, "),
    (["nope", "--synth"], "error: unknown scenario 'nope' (--synth); known: grasp_lift, "),
    (["grasp_lift", "--synth", "--hands", "right", "left"], "error: two hands run from a bag only"),
])
def test_offline_names_the_bad_input(argv, message):
    with pytest.raises(SystemExit) as exc:
        offline.main(argv)
    assert str(exc.value).startswith(message), exc.value


@pytest.mark.parametrize("argv, message", [
    (["--port", "99999"], "argument --port: 99999 is outside 0..65535 (a TCP port)"),
    (["--port", "x"], "argument --port: 'x' is not an integer"),
    (["--domain-id", "300"], "argument --domain-id: 300 is outside 0..232"),
])
def test_view_refuses_an_out_of_range_argument(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        view.build_parser().parse_args(argv)
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def test_view_names_a_port_another_process_holds():
    """The Foxglove server cannot bind: the viewer exits with the address and a way out, before it
    starts rclpy (so no ROS environment is needed here)."""
    from softhand_sim.ros.foxglove import serve

    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        port = held.getsockname()[1]
        with pytest.raises(SystemExit) as exc:
            serve({}, host="127.0.0.1", port=port)
    text = str(exc.value)
    assert text.startswith(f"softhand view: cannot serve on ws://127.0.0.1:{port}: "), text
    assert "--port 0 takes any free port" in text, text


def test_hand_refuses_an_unknown_view_before_building(capsys):
    from softhand_sim.commands import hand

    with pytest.raises(SystemExit) as exc:
        hand.main(["--views", "dorsal,top"])
    assert exc.value.code == 2
    assert "--views dorsal,top: unknown view(s) 'top'; known: dorsal, palmar, side, front" in capsys.readouterr().err


@pytest.mark.parametrize("text, message", [
    (None, "error: --params-file: parameter file not found: "),
    ("sim_node: [\n", "is not valid YAML"),
    ("sim_node:\n  mesh: fine\n", "section 'sim_node' needs a 'ros__parameters' mapping"),
])
def test_demo_checks_its_params_file_before_any_node_starts(tmp_path, text, message):
    from softhand_sim.commands.demo import run_demo

    path = tmp_path / "params.yaml"
    if text is not None:
        path.write_text(text)
    out = tmp_path / "run"
    with pytest.raises(SystemExit) as exc:
        run_demo("grasp_lift", out, params_file=path, preview=False, quiet=True)
    assert message in str(exc.value), exc.value
    assert not out.exists()  # nothing was started, nothing written


def test_a_node_names_a_params_file_rcl_cannot_read(tmp_path, capsys):
    """Every node's command line goes through split_cli: rcl's refusal of --ros-args is argparse's
    exit 2 with rcl's words, without the C source locations rcl appends."""
    import argparse

    from softhand_sim.ros.common import split_cli

    missing = tmp_path / "none.yaml"
    with pytest.raises(SystemExit) as exc:
        split_cli(argparse.ArgumentParser(prog="world_node"), ["softhand-world", "--ros-args", "--params-file",
                                                                str(missing)])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(f"world_node: error: Failed to parse ROS arguments: Couldn't parse params file: "
                          f"'--params-file {missing}'"), err
    assert "/project/src" not in err, err


@pytest.mark.parametrize("argv, message", [
    (["--until", "-1"], "--until -1.0: must be > 0 [s]"),  # an IndexError at the summary before
    (["--until", "nan"], "--until nan: must be > 0 [s]"),
    (["--every", "0"], "--every 0.0: must be > 0 [s]"),
    (["--latency", "-0.01"], "--latency -0.01: must be >= 0 [s]"),  # accepted silently before
])
def test_offline_refuses_times_out_of_range(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        offline.main(["grasp_lift", *argv])
    assert exc.value.code == 2
    assert message in capsys.readouterr().err
