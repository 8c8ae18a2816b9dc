"""Fixtures of the node-level tests: one `softhand demo` run of the README's default bag, shared.

A demo run costs 30-50 s on 2 cores; the end-to-end check, the grasp through the nodes and the
viewing check read the same run instead of making one each.
"""
import json
import subprocess
import sys
from pathlib import Path

import pytest

SOFTHAND = str(Path(sys.executable).parent / "softhand")


@pytest.fixture(scope="session")
def demo_run(tmp_path_factory):
    """(run directory, summary.json, stdout, failed attempts) of `softhand demo` exactly as `make
    demo` runs it (grasp_lift, the preview drawn).

    Tried up to three times, and a run whose ball was not lifted or one of whose nodes exited
    non-zero counts as failed: a stall of the shared machine can fail one run over real DDS (the
    grasp slip seen on fresh clones, README "What the tests prove"; a node not stopping within
    the demo's grace, README "Recordings and recovery"), and a session fixture's failure is not
    retried by the tests' rerun marker. The failed attempts are returned, so a test can report them.
    """
    failures = []
    for attempt in range(3):
        out = tmp_path_factory.mktemp("demo") / "grasp_lift"
        proc = subprocess.run([SOFTHAND, "demo", "--out", str(out)], capture_output=True, text=True, timeout=900)
        if proc.returncode == 0:
            summary = json.loads((out / "summary.json").read_text())
            killed = {name: code for name, code in summary["exit_codes"].items() if code != 0}
            if killed:
                # a node that did not stop in time (once in the suite: tracking_node, SIGKILLed after
                # 10 s): its log ends with its stack (SIGUSR1 before the kill); kept in the report
                tails = "\n".join(f"--- {name}.log:\n" + "\n".join(
                    (out / "logs" / f"{name}.log").read_text(errors="replace").splitlines()[-40:]) for name in killed)
                failures.append(f"attempt {attempt + 1}: nodes exited {killed}\n{tails}")
            elif summary.get("ball_lifted"):
                return out, summary, proc.stdout, failures
            else:
                failures.append(f"attempt {attempt + 1}: ball rose only {100 * summary['ball_lift_m']:.1f} cm")
        else:
            failures.append(f"attempt {attempt + 1}: exit {proc.returncode}\n{proc.stdout[-2000:]}{proc.stderr[-2000:]}")
    pytest.fail("softhand demo failed three times:\n" + "\n".join(failures))
