"""The live host's seams (issue 22): the policies and their helpers get a narrow interface
from the facade and keep to it; no module of canbus/master borrows another's private
names."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MASTER = ROOT / "canbus" / "master"
FACADE = "canbus.master.host"
POLICY_SIDE = ("active", "follower", "setup_jobs", "policy", "patchstate", "patchchannels",
               "hoststats", "records", "buslink", "dataplane", "publisher")
"""Modules the facade builds on: none of them may import it, not even for a type."""


def _tree(path: Path) -> ast.AST:
    return ast.parse(path.read_text(encoding="utf-8"))


@pytest.mark.parametrize("path", sorted(MASTER.glob("*.py")), ids=lambda p: p.name)
def test_no_module_imports_a_private_name_from_another(path: Path) -> None:
    for node in ast.walk(_tree(path)):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            private = [a.name for a in node.names if a.name.startswith("_")]
            assert not private, f"{path.name} imports {private} from {node.module}"


@pytest.mark.parametrize("name", POLICY_SIDE)
def test_the_facade_is_imported_by_nothing_it_builds_on(name: str) -> None:
    for node in ast.walk(_tree(MASTER / f"{name}.py")):
        if isinstance(node, ast.ImportFrom) and node.module:
            assert node.module != FACADE, f"{name}.py imports the facade"
        elif isinstance(node, ast.Import):
            assert all(a.name != FACADE for a in node.names), f"{name}.py imports the facade"


@pytest.mark.parametrize("name", [*POLICY_SIDE, "host"])
def test_nothing_reads_another_objects_private_state(name: str) -> None:
    """No ``host._lock`` from a policy, no ``dataplane._publisher.subscribers``: each reads
    only its own private attributes (``self._x``)."""
    for node in ast.walk(_tree(MASTER / f"{name}.py")):
        if isinstance(node, ast.Attribute) and node.attr.startswith("_") \
                and not node.attr.startswith("__"):
            owner = node.value
            assert isinstance(owner, ast.Name) and owner.id in ("self", "cls"), \
                f"{name}.py:{node.lineno} reads {ast.unparse(node)}"
