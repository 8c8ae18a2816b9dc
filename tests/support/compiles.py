"""Which numba kernels a piece of code compiles, measured in a fresh interpreter (a test process
has compiled most kernels already, so only a fresh one shows what a node would compile)."""
import subprocess
import sys
import textwrap


def compiled_by(setup: str, kernels: str, run: str, timeout: float = 120.0) -> str:
    """Run `setup`, then `run`, in a fresh interpreter (source strings); `kernels` is an expression
    (evaluated after setup) listing numba dispatchers. Returns the printed dict {kernel name:
    (signatures before run, after)} of those that `run` compiled: "{}" when none."""
    code = "\n".join([textwrap.dedent(setup), f"kernels = {kernels}",
                      "before = [len(k.signatures) for k in kernels]", textwrap.dedent(run),
                      "print({k.__name__: (b, len(k.signatures)) for k, b in zip(kernels, before)"
                      " if len(k.signatures) != b})"])
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout.strip()
