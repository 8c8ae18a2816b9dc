"""tools/fit_picture.py on a short slice of the real leap_grab recording: it writes a picture of
sensible size and the fitted hand's fingertips lie nearer the tracked ones than the default's."""
import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_fit_picture_on_a_short_slice(tmp_path):
    out = tmp_path / "fit.png"
    proc = subprocess.run([sys.executable, str(REPO / "tools" / "fit_picture.py"), str(out), "--until", "0.3",
                           "--time", "0.2"], capture_output=True, text=True, timeout=300, cwd=REPO)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    default, fitted = (json.loads(line) for line in proc.stdout.splitlines() if line.startswith("{"))
    assert 20_000 < out.stat().st_size < 300_000
    assert default["hand_length_mm"] == 190.0 and 150.0 < fitted["hand_length_mm"] < 175.0
    assert 0.2 <= default["state_t_s"] <= 0.2 + 1 / 60 + 0.001  # one sim period (rounded to ms)
    assert default["tracked_t_s"] <= default["state_t_s"]
    assert fitted["fingertip_error_here_mm"] < 0.5 * default["fingertip_error_here_mm"], (default, fitted)
    assert fitted["fingertip_error_median_mm"] < 0.5 * default["fingertip_error_median_mm"], (default, fitted)
