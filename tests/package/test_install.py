"""The plain install: one venv install gives every console script of docs/INTERFACE.md, and they run."""
import subprocess
import sys
from pathlib import Path

import pytest

BIN = Path(sys.executable).parent
SCRIPTS = ("softhand-sim", "softhand-tracking", "softhand-world", "softhand-play", "softhand-record", "softhand")


@pytest.mark.parametrize("script", SCRIPTS)
def test_console_script_installed_and_helps(script):
    """Each console script is in the venv's bin/ and `--help` exits 0 with a usage line."""
    exe = BIN / script
    assert exe.exists(), f"{exe} missing: the editable install put its scripts elsewhere"
    proc = subprocess.run([str(exe), "--help"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "usage" in proc.stdout.lower()


def test_softhand_subcommands_help():
    """`softhand demo|bench|hand|params --help` each explain themselves."""
    for sub in ("demo", "bench", "hand", "params"):
        proc = subprocess.run([str(BIN / "softhand"), sub, "--help"], capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0 and "usage" in proc.stdout.lower(), (sub, proc.stderr[-1000:])
