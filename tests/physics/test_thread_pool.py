"""A cached kernel that calls a `prange` kernel, loaded by a fresh process (softhand_sim.physics's
docstring has the story). Three processes write the cache the way two test workers did: one
compiles the parallel callee, the next compiles its caller with the callee from the cache, and a
third loads the caller first. Without softhand_sim.physics imported that third process crashes
(numba's bug, still there in the locked version: when this control stops crashing, the
workaround can go); with it imported it runs."""
import os
import signal
import subprocess
import sys
import textwrap

import pytest

KERNELS = textwrap.dedent("""
    import numpy as np
    from numba import njit, prange

    @njit(parallel=True, cache=True)
    def add_one(x):
        for i in prange(x.shape[0]):
            x[i] += 1.0

    @njit(cache=True)
    def add_one_and_sum(x):
        add_one(x)
        return x.sum()
""")


def _run(tmp_path, code):
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    return subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=300)


@pytest.fixture
def cache_written_in_two_processes(tmp_path):
    (tmp_path / "kernels.py").write_text(KERNELS)
    for code in ("import numpy as np, kernels; kernels.add_one(np.zeros(4))",
                 "import numpy as np, kernels; print(kernels.add_one_and_sum(np.zeros(4)))"):
        r = _run(tmp_path, code)
        assert r.returncode == 0, r.stderr
    return tmp_path


def test_the_caller_from_the_cache_crashes_without_the_pool(cache_written_in_two_processes):
    r = _run(cache_written_in_two_processes,
             "import numpy as np, kernels; print(kernels.add_one_and_sum(np.zeros(1000)))")
    assert r.returncode == -signal.SIGSEGV, (r.returncode, r.stdout, r.stderr[-1000:])


def test_importing_the_physics_starts_the_pool(cache_written_in_two_processes):
    r = _run(cache_written_in_two_processes, "import softhand_sim.physics, numpy as np, kernels; "
                                             "print(kernels.add_one_and_sum(np.zeros(1000)))")
    assert r.returncode == 0, (r.returncode, r.stderr[-1000:])
    assert r.stdout.strip() == "1000.0"
