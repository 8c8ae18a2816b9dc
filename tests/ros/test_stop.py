"""A node that does not stop says where it hangs: SIGUSR1 prints every thread's Python stack into
its log and the node goes on (run_node registers it), and the demo's reaper asks for that stack
before it kills a process that ignored SIGINT for its grace period."""
from __future__ import annotations

import signal
import sys
import time

import pytest

from softhand_sim.commands.demo import ProcessSet
from tests.support.rosproc import RosGraph

STACK_HEADER = "(most recent call first)"


def _wait_for(read, text, timeout, what):
    deadline = time.monotonic() + timeout
    while text not in read():
        if time.monotonic() > deadline:
            raise AssertionError(f"no {what!r} after {timeout} s:\n{read()}")
        time.sleep(0.05)


@pytest.mark.ros
def test_sigusr1_prints_the_stack_of_a_running_node_which_goes_on(ros_env):
    with RosGraph(ros_env) as g:
        proc = g.start(["softhand-tracking"])
        _wait_for(proc.output, "tracking the right hand", 60, "start-up line")
        proc.popen.send_signal(signal.SIGUSR1)
        _wait_for(proc.output, STACK_HEADER, 10, "stack dump")
        out = proc.output()
        assert "run_node" in out and "common.py" in out, out  # the spin loop's frame
        time.sleep(0.5)
        assert proc.alive(), out
        assert proc.stop() == 0, proc.output()


def test_the_demo_reaper_dumps_the_stack_then_kills(tmp_path):
    """A child that ignores SIGINT: after the grace period its stack is in its log, then it is killed."""
    child = ("import faulthandler, signal, time\n"
             "faulthandler.register(signal.SIGUSR1, all_threads=True)\n"
             "signal.signal(signal.SIGINT, signal.SIG_IGN)\n"
             "print('up', flush=True)\n"
             "def stuck_in_teardown():\n"
             "    time.sleep(60)\n"
             "stuck_in_teardown()\n")
    ps = ProcessSet(env=None, log_dir=tmp_path)
    ps.start("stubborn", [sys.executable, "-c", child])
    log = tmp_path / "stubborn.log"
    _wait_for(log.read_text, "up", 30, "start-up line")
    t0 = time.monotonic()
    code = ps.stop("stubborn", grace=1.0)
    assert code == -signal.SIGKILL
    assert time.monotonic() - t0 < 5.0
    text = log.read_text()
    assert STACK_HEADER in text and "stuck_in_teardown" in text, text
    assert "stubborn did not stop within 1 s of SIGINT: killed" in text, text
