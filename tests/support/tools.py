"""The repository's tools/ scripts as modules (they are not a package): tests that check what a
tool draws or writes load it here."""
import importlib.util
from pathlib import Path

TOOLS = Path(__file__).resolve().parents[2] / "tools"


def load_tool(name: str):
    """A fresh module of tools/<name>.py (each call its own: a test may patch it)."""
    spec = importlib.util.spec_from_file_location(name, TOOLS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
