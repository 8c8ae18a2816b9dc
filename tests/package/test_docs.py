"""The docs stand alone and match the code.

README.md and docs/*.md: every relative markdown link resolves, every backticked repository path
exists, the package map of docs/ARCHITECTURE.md names only existing files, and every function of its
"One tracker message, end to end" walk is defined in the file the walk names. No tracked file
refers to a path outside the repository.
"""
import ast
import re
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
DOCS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
ARCHITECTURE = REPO / "docs" / "ARCHITECTURE.md"
# Written in two pieces so that this file does not contain what it looks for.
OUTSIDE = "../" + "shared"
# File name endings that make a backticked word a path.
PATH_SUFFIXES = (".py", ".yaml", ".yml", ".md", ".mcap", ".png", ".gif", ".json", ".txt", ".cfg",
                 ".xml", ".lock", ".toml", ".ini", ".npz", ".sh")
# Outputs of a run, named in the README but (rightly) not in the repository.
RUN_OUTPUTS = {"bag/", "logs/", "summary.json", "preview.png", "preview.gif"}

FENCE = re.compile(r"^```.*?^```", re.S | re.M)
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
CODE = re.compile(r"`([^`\n]+)`")
PATHLIKE = re.compile(r"^[A-Za-z0-9_.][A-Za-z0-9_./-]*$")


def tracked_files():
    """Repository-relative paths of the tracked files (every file when git is not available)."""
    try:
        out = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, capture_output=True, check=True,
                             timeout=60).stdout
        return [p for p in out.decode().split("\0") if p]
    except (OSError, subprocess.CalledProcessError):
        return [str(p.relative_to(REPO)) for p in REPO.rglob("*")
                if p.is_file() and ".git" not in p.parts and ".venv" not in p.parts]


TRACKED = tracked_files()
TOP_LEVEL = {p.split("/")[0] for p in TRACKED}
TRACKED_DIRS = {"/".join(p.split("/")[:i]) for p in TRACKED for i in range(1, p.count("/") + 1)}


def prose(text: str) -> str:
    """Markdown without its fenced code blocks."""
    return FENCE.sub("", text)


def repo_path_candidates(text: str):
    """Backticked words that look like repository paths (module-relative ones included)."""
    for word in CODE.findall(prose(text)):
        word = word.strip()
        if not PATHLIKE.match(word) or word.startswith("..") or word in RUN_OUTPUTS:
            continue
        first = word.split("/")[0]
        if "/" in word and (first in TOP_LEVEL or word.endswith("/")):
            yield word
        elif word.rstrip("/").endswith(PATH_SUFFIXES) and not word.startswith("."):
            yield word


def exists_in_repo(word: str) -> bool:
    """True if `word` is a tracked file or folder, from the root or as a trailing path."""
    w = word.rstrip("/")
    if w in TRACKED or w in TRACKED_DIRS or (REPO / w).exists():
        return True
    return any(p.endswith("/" + w) for p in TRACKED) or any(d.endswith("/" + w) for d in TRACKED_DIRS)


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_relative_links_resolve(doc):
    """Every markdown link that is not a URL or an anchor points at an existing file or folder."""
    text = prose(doc.read_text())
    targets = [t for t in LINK.findall(text) if not re.match(r"^[a-z]+:|^#", t)]
    missing = [t for t in targets if not (doc.parent / t.split("#")[0]).exists()]
    assert not missing, f"{doc.name}: links to missing paths {missing}"


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_backticked_paths_exist(doc):
    """Every `path/like/this.py` or `config/scene.yaml` written in the prose exists in the repo."""
    words = sorted(set(repo_path_candidates(doc.read_text())))
    missing = [w for w in words if not exists_in_repo(w)]
    assert not missing, f"{doc.name}: names paths that do not exist: {missing}"


def test_path_check_can_fail():
    """The two checks above really flag a path that is not there and pass one that is."""
    sample = ("See `softhand_sim/softhand_sim/no_such_module.py`, `config/scene.yaml`, `physics/solver.py`, "
              "`handmodel/` and `runs/<stamp>/bag`.")
    words = list(repo_path_candidates(sample))
    assert words == ["softhand_sim/softhand_sim/no_such_module.py", "config/scene.yaml",
                     "physics/solver.py", "handmodel/"]
    assert [exists_in_repo(w) for w in words] == [False, True, True, True]


def test_no_file_refers_outside_the_repository():
    """No tracked file mentions the folder outside the repository the project began from."""
    hits = []
    for rel in TRACKED:
        path = REPO / rel
        if path.is_file() and OUTSIDE.encode() in path.read_bytes():
            hits.append(rel)
    assert not hits, f"files refer to {OUTSIDE}: {hits}"


def package_map_entries(text: str):
    """Repository paths of the package map: the first fenced block after '## Package map'."""
    section = text.split("## Package map", 1)[1]
    block = re.search(r"^```\n(.*?)^```", section, re.S | re.M).group(1)
    stack = []  # (indent, folder path)
    for line in block.splitlines():
        if not line.strip():
            continue
        indent = len(line) - len(line.lstrip(" "))
        name = line.split()[0]
        while stack and stack[-1][0] >= indent:
            stack.pop()
        path = (stack[-1][1] + name) if stack else name
        if name.endswith("/"):
            stack.append((indent, path))
        yield path


def test_package_map_entries_exist():
    """Every file and folder of ARCHITECTURE.md's package map exists where the map puts it."""
    entries = list(package_map_entries(ARCHITECTURE.read_text()))
    assert len(entries) > 60, entries  # the map is parsed, not skipped
    assert "softhand_sim/softhand_sim/physics/contact/sdf_mesh.py" in entries
    missing = [e for e in entries if not (REPO / e).exists()]
    assert not missing, f"ARCHITECTURE.md package map names missing paths: {missing}"


def walk_rows(text: str):
    """(file, function) of each row of the table under '## One tracker message, end to end'."""
    section = text.split("## One tracker message, end to end", 1)[1].split("\n## ", 1)[0]
    rows = []
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) >= 4 and cells[0].isdigit():
            rows.append((cells[1].strip("`"), cells[2].strip("`")))
    return rows


def defines(path: Path, name: str) -> bool:
    """True if the module at `path` defines function `name` or method `Class.method`."""
    tree = ast.parse(path.read_text())
    if "." in name:
        cls, meth = name.split(".", 1)
        return any(isinstance(n, ast.ClassDef) and n.name == cls and
                   any(isinstance(m, (ast.FunctionDef, ast.AsyncFunctionDef)) and m.name == meth for m in n.body)
                   for n in tree.body)
    return any(isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) and n.name == name for n in tree.body)


def test_walk_functions_exist_in_named_files():
    """Each step of the tracker-message walk names a function that its file really defines."""
    rows = walk_rows(ARCHITECTURE.read_text())
    assert len(rows) >= 20, rows
    files = {f for f, _ in rows}
    assert {"softhand_tracking/softhand_tracking/play_node.py", "softhand_tracking/softhand_tracking/tracking_node.py",
            "softhand_sim/softhand_sim/sim_node.py", "softhand_sim/softhand_sim/runtime.py",
            "softhand_sim/softhand_sim/physics/solver.py"} <= files
    bad = [(f, fn) for f, fn in rows if not (REPO / f).is_file() or not defines(REPO / f, fn)]
    assert not bad, f"walk rows whose function is not defined in the named file: {bad}"


def test_defines_can_fail():
    """The definition check tells a real method from a made-up one."""
    runtime = REPO / "softhand_sim" / "softhand_sim" / "runtime.py"
    assert defines(runtime, "SimRuntime.step")
    assert not defines(runtime, "SimRuntime.no_such_method")
    assert not defines(runtime, "step")  # a method is not a module-level function


def test_package_map_lists_every_module():
    """Every module of the three packages is in the package map (a new file gets its line)."""
    text = (REPO / "docs" / "ARCHITECTURE.md").read_text()
    missing = []
    for pkg in ("softhand_sim/softhand_sim", "softhand_tracking/softhand_tracking", "softhand_world/softhand_world"):
        for f in sorted((REPO / pkg).rglob("*.py")):
            if f.name == "__init__.py":
                continue
            if not re.search(rf"^\s+{re.escape(f.name)}\s", text, flags=re.M):
                missing.append(str(f.relative_to(REPO)))
    assert not missing, f"modules missing from the package map of docs/ARCHITECTURE.md: {missing}"
