"""The suite's report of reruns (tests/conftest.py): a test that passes on its rerun has its first
failure printed, not only its name."""
import os
import subprocess
import sys

from tests.conftest import REPO


def test_a_rerun_test_prints_its_first_failure(tmp_path):
    (tmp_path / "conftest.py").write_text("from tests.conftest import pytest_terminal_summary  # noqa: F401\n")
    (tmp_path / "test_flaky.py").write_text(
        "import pytest\n"
        "@pytest.mark.flaky(reruns=1)\n"
        "def test_once(tmp_path_factory):\n"
        f"    flag = {str(tmp_path / 'flag')!r}\n"
        "    import os\n"
        "    if not os.path.exists(flag):\n"
        "        open(flag, 'w').close()\n"
        "        assert 1 == 2, 'first attempt fails: the reason'\n")
    out = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(tmp_path)],
                         cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(REPO)},
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    assert "1 passed, 1 rerun" in out.stdout, out.stdout[-2000:]
    assert "the failures that were rerun" in out.stdout and "first attempt fails: the reason" in out.stdout, \
        out.stdout[-2000:]
