"""Imports flow one way: skin core <- sim, decoder <- canbus <- skin/cli.py (README)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("skin", "sim", "decoder", "canbus", "bench")
FORBIDDEN = {
    "skin": {"sim", "decoder", "canbus", "bench"},
    "sim": {"decoder", "canbus", "bench"},
    "decoder": {"sim", "canbus", "bench"},
    "canbus": {"bench"},
    "bench": set(),  # benchmarks measure every layer
}

def _imports(tree: ast.AST) -> set[str]:
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module.split(".")[0])
    return found

def _is_command(path: Path) -> bool:
    rel = path.relative_to(ROOT).as_posix()
    return rel == "skin/cli.py" or rel.startswith("skin/commands/")

def _modules() -> list[Path]:
    return sorted(p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py"))

@pytest.mark.parametrize("path", _modules(), ids=lambda p: p.relative_to(ROOT).as_posix())
def test_imports_flow_one_way(path: Path) -> None:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = path.relative_to(ROOT).parts[0]
    if _is_command(path):
        # Commands may use every package, but only inside the handler, lazily.
        eager = {
            n
            for node in tree.body
            if isinstance(node, ast.Import | ast.ImportFrom)
            for n in _imports(node)
        }
        assert not eager & {"sim", "decoder", "canbus", "bench"}, \
            f"{path}: import heavy packages lazily"
        return
    wrong = _imports(tree) & FORBIDDEN[package]
    assert not wrong, f"{path} imports {sorted(wrong)}, against the layering"


# Inside canbus: the wire-level modules beside the subpackages use none of them; the device
# side uses only those; the master side also the device side (its force nodes are local
# devices) and the bus tools (it decodes recordings); the bus tools and the timed bus only
# the wire-level modules.
CANBUS_SIDES = ("device", "master", "tools", "timed")
CANBUS_ALLOWED = {
    "": set(),
    "device": {"device"},
    "master": {"device", "master", "tools"},
    "tools": {"tools"},
    "timed": {"timed"},
}


def _canbus_side(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 2 and parts[1] in CANBUS_SIDES else ""


def _canbus_imports(tree: ast.AST) -> set[str]:
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
    return {name for name in found if name.startswith("canbus.")}


@pytest.mark.parametrize("path", sorted((ROOT / "canbus").rglob("*.py")),
                         ids=lambda p: p.relative_to(ROOT).as_posix())
def test_canbus_sides_import_one_way(path: Path) -> None:
    rel = path.relative_to(ROOT).with_suffix("")
    side = _canbus_side(".".join(rel.parts))
    if rel.parts[-1] == "__init__" and len(rel.parts) == 2:
        return  # canbus/__init__.py names the public API of every side, lazily
    if rel.parts[-1] == "_moved":
        return  # the old module paths, lazily
    used = {_canbus_side(name) for name in _canbus_imports(ast.parse(path.read_text()))}
    wrong = used - {""} - CANBUS_ALLOWED[side]
    assert not wrong, f"{path} ({side or 'wire level'}) imports canbus.{sorted(wrong)}"


def test_canbus_exports_what_it_names() -> None:
    import canbus

    assert sorted(canbus.__all__) == sorted(canbus._PUBLIC)
    for name in canbus.__all__:
        assert getattr(canbus, name).__name__ == name
