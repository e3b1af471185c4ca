"""No document, docstring or comment names a file or module that does not exist.

A reader follows a name (``canbus/master/dataplane.py``, ``canbus.master.host.HostManager``,
``docs/host.md``) to read on: every such name in the README, docs/, examples/ and the
Python sources of the product and the tests must lead somewhere. A name under ``tmp``, made
by a command (``out.json``) or standing for any file (``docs/NAME.md``) is not a reference.
"""

from __future__ import annotations

import ast
import re
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("skin", "sim", "decoder", "canbus", "tests")
FOLDERS = ("skin", "sim", "decoder", "canbus", "tests", "docs", "eds", "examples", ".ci")
PATH = re.compile(r"(?<![\w./-])((?:" + "|".join(re.escape(f) for f in FOLDERS)
                  + r")/(?>[\w./@-]*\w))(?![*{<])")
MODULE = re.compile(r"(?<![\w./-])((?:skin|sim|decoder|canbus|tests\.support)"
                    r"(?>(?:\.[A-Za-z_]\w*)+))(?![*{<])")
NOT_NAMES = {"json", "toml", "png", "log", "eds", "md", "mcap", "blf", "asc", "pcap", "pcapng",
             "csv", "npz", "py", "txt", "yaml", "dcf", "html", "svg", "gif", "mp4", "msgpack"}


def _documents() -> list[Path]:
    docs = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")),
            *sorted((ROOT / "examples").rglob("*.toml"))]
    sources = sorted(p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")
                     if "files" not in p.relative_to(ROOT).parts)
    return docs + sources


def _prose(path: Path) -> str:
    """What a reader reads: a document but its Python blocks (run by tests/test_docs.py, their
    names are variables as often as modules); of a source, its docstrings and comments."""
    text = path.read_text(encoding="utf-8")
    if path.suffix != ".py":
        return PYTHON_BLOCK.sub("", text)
    tree = ast.parse(text)
    parts = [ast.get_docstring(node, clean=False) or "" for node in ast.walk(tree)
             if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef
                           | ast.AsyncFunctionDef)]
    parts += [line.partition("#")[2] for line in text.splitlines() if "#" in line]
    return "\n".join(parts)


def _is_pattern(name: str) -> bool:
    return any(ch in name for ch in "*{}<>") or any(part.isupper() and len(part) > 1
                                                     for part in re.split(r"[/.]", name))


PYTHON_BLOCK = re.compile(r"^```python\n.*?^```$", re.S | re.M)
MAKES = re.compile(r'makes="([^"]*)"|makes=(\S+)')


def _made_by_the_docs() -> frozenset[str]:
    """What a documented command writes (a doc-test's ``makes=``): named before it exists."""
    texts = [p.read_text(encoding="utf-8") for p in (ROOT / "docs").glob("*.md")]
    return frozenset(name for text in texts for m in MAKES.finditer(text)
                     for name in (m.group(1) or m.group(2)).split())


MADE = _made_by_the_docs()


def missing_paths(text: str) -> list[str]:
    found = []
    for match in PATH.finditer(text):
        name = match.group(1).rstrip(".")
        if _is_pattern(name) or "tmp" in name.split("/") or name in MADE:
            continue
        if not (ROOT / name).exists():
            found.append(name)
    return found


@cache
def _top_level_names(path: Path) -> frozenset[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            names.add(node.name)
        elif isinstance(node, ast.Assign):
            names.update(t.id for t in node.targets if isinstance(t, ast.Name))
            names.update(t.attr for t in node.targets if isinstance(t, ast.Attribute))
        elif isinstance(node, ast.AnnAssign):
            if isinstance(node.target, ast.Name):
                names.add(node.target.id)
            elif isinstance(node.target, ast.Attribute):
                names.add(node.target.attr)
        elif isinstance(node, ast.Import | ast.ImportFrom):
            names.update((a.asname or a.name).split(".")[0] for a in node.names)
    return frozenset(names)


def _module_file(parts: list[str]) -> Path | None:
    base = ROOT.joinpath(*parts)
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return path
    return None


def module_exists(name: str) -> bool:
    """``name`` is a module of this checkout, or a name its longest module defines (its
    functions, classes, constants and the attributes they set)."""
    parts = name.split(".")
    for cut in range(len(parts), 0, -1):
        path = _module_file(parts[:cut])
        if path is not None:
            return all(rest in _top_level_names(path) for rest in parts[cut:])
    return False


def missing_modules(text: str) -> list[str]:
    found = []
    for match in MODULE.finditer(text):
        name = match.group(1).rstrip(".")
        if name.rpartition(".")[2] in NOT_NAMES or _is_pattern(name):
            continue
        if not module_exists(name):
            found.append(name)
    return found


@pytest.mark.parametrize("path", _documents(), ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_name_leads_somewhere(path: Path) -> None:
    text = _prose(path)
    missing = sorted(set(missing_paths(text)) | set(missing_modules(text)))
    assert not missing, f"{path.relative_to(ROOT)} names what does not exist: {missing}"


@pytest.mark.parametrize("path", _documents(), ids=lambda p: p.relative_to(ROOT).as_posix())
def test_the_design_is_docs_architecture(path: Path) -> None:
    """The project's design document is docs/architecture.md; nothing cites another."""
    assert "DESIGN" not in _prose(path), f"{path.relative_to(ROOT)}: cite docs/architecture.md"


@pytest.mark.parametrize(("text", "missing"), [
    ("see canbus/master/offline.py", ["canbus/master/offline.py"]),
    ("see canbus/master/dataplane.py", []),
    ("the listen-only host (canbus.master.offline)", ["canbus.master.offline"]),
    ("canbus.master.host.HostManager and canbus.master.host.NoSuchThing",
     ["canbus.master.host.NoSuchThing"]),
    ("docs/NAME.md and out/tmp/x.json and skin.json", []),
    ("[host.md](docs/hosts.md)", ["docs/hosts.md"]),
])
def test_the_check_finds_what_is_missing(text: str, missing: list[str]) -> None:
    assert sorted(missing_paths(text) + missing_modules(text)) == missing  # exact: names, text
