"""`softhand demo` stops at once, in the words of the process that failed, when a run cannot go
on: a run directory that holds a recording already, or a node that exits while the bag plays.
Before, the recorder refused an existing --out only after every node was up, and the demo waited
for the player to give up on its subscription (30 s) and reported "play_node failed"."""
import sys
import time

import pytest

from softhand_sim.commands.demo import ProcessSet, run_demo, wait_watching


def test_an_out_directory_with_a_recording_is_refused_before_any_node_starts(tmp_path):
    out = tmp_path / "run"
    (out / "bag").mkdir(parents=True)
    t0 = time.monotonic()
    with pytest.raises(SystemExit) as exc:
        run_demo("grasp_lift", out, preview=False, quiet=True)
    assert str(exc.value).startswith(f"error: --out {out} holds a recording already ({out / 'bag'})")
    assert not (out / "logs").exists()  # nothing was started
    assert time.monotonic() - t0 < 5.0


def _python(code):
    return [sys.executable, "-c", code]


def test_a_child_that_exits_while_the_bag_plays_ends_the_wait_with_its_log(tmp_path):
    procs = ProcessSet(env=None, log_dir=tmp_path)
    try:
        procs.start("play", _python("import time; time.sleep(60)"))
        procs.start("view", _python("raise SystemExit(5)"))  # skipped: the run goes on without it
        procs.start("world", _python("import time; time.sleep(60)"))
        procs.start("record", _python("import time; time.sleep(0.5); "
                                      "raise SystemExit('softhand-record: error: output exists already')"))
        t0 = time.monotonic()
        with pytest.raises(SystemExit) as exc:
            wait_watching(procs, "play", skip=("view",), what="grasp_lift played", poll_s=0.05)
        assert time.monotonic() - t0 < 10.0  # not the player's 60 s
        text = str(exc.value)
        assert text.startswith("error: record exited (code 1) while grasp_lift played:"), text
        assert "output exists already" in text, text
        assert procs.exited() == ["view", "record"]
        assert procs.alive("play") and procs.alive("world")
    finally:
        procs.stop_all()


def test_the_wait_ends_with_the_player_when_every_other_child_lives(tmp_path):
    procs = ProcessSet(env=None, log_dir=tmp_path)
    try:
        procs.start("play", _python("import time; time.sleep(0.3); raise SystemExit(3)"))
        procs.start("sim", _python("import time; time.sleep(60)"))
        assert wait_watching(procs, "play", poll_s=0.05) == 3
        assert procs.exited() == ["play"]
    finally:
        procs.stop_all()
