"""Imports flow one way: skin core <- sim, decoder <- canbus <- skin/cli.py (DESIGN.md §1)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("skin", "sim", "decoder", "canbus")
FORBIDDEN = {
    "skin": {"sim", "decoder", "canbus"},
    "sim": {"decoder", "canbus"},
    "decoder": {"sim", "canbus"},
    "canbus": set(),
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
        assert not eager & {"sim", "decoder", "canbus"}, f"{path}: import heavy packages lazily"
        return
    wrong = _imports(tree) & FORBIDDEN[package]
    assert not wrong, f"{path} imports {sorted(wrong)}, against the layering"
