"""Imports flow one way: skin core <- sim, decoder <- canbus <- skin/cli.py and bench/
(DESIGN.md section 1); inside canbus, side by side and in no loop; no module takes a
private name of another; benchmarks and rigs live in bench/, tests in tests/."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("skin", "sim", "decoder", "canbus", "bench")
PRODUCT = ("skin", "sim", "decoder", "canbus")
FORBIDDEN = {
    "skin": {"sim", "decoder", "canbus", "bench"},
    "sim": {"decoder", "canbus", "bench"},
    "decoder": {"sim", "canbus", "bench"},
    "canbus": {"bench"},
    "bench": set(),  # benchmarks and rigs may use every package, as the command line does
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
        heavy = {"sim", "decoder", "canbus", "bench"}
        assert not eager & heavy, f"{path}: import heavy packages lazily"
        return
    wrong = _imports(tree) & FORBIDDEN[package]
    assert not wrong, f"{path} imports {sorted(wrong)}, against the layering"


# Inside canbus: the wire-level modules beside the subpackages use none of them; the device
# side uses only those; the master side (the live host) also the device side (its force
# nodes are local devices); the offline side also the master (it feeds recordings to the
# listen-only host) and the bus tools (it reads recordings); the bus tools and the timed bus
# only the wire-level modules. So the master side uses neither offline nor bench/ code.
# The Zenoh side publishes and reads the master's frames and events; the master reaches it
# only through its config hook (hostconfig parses [zenoh] with canbus.zenoh.config).
CANBUS_SIDES = ("device", "master", "offline", "tools", "timed", "zenoh")
CANBUS_ALLOWED = {
    "": set(),
    "device": {"device"},
    "master": {"device", "master", "zenoh"},
    "offline": {"device", "master", "offline", "tools"},
    "tools": {"tools"},
    "timed": {"timed"},
    "zenoh": {"master", "zenoh"},
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
    used = {_canbus_side(name) for name in _canbus_imports(ast.parse(path.read_text()))}
    wrong = used - {""} - CANBUS_ALLOWED[side]
    assert not wrong, f"{path} ({side or 'wire level'}) imports canbus.{sorted(wrong)}"


def test_canbus_exports_what_it_names() -> None:
    import canbus

    assert sorted(canbus.__all__) == sorted(canbus._PUBLIC)
    for name in canbus.__all__:
        assert getattr(canbus, name).__name__ == name


def test_import_canbus_adds_only_itself() -> None:
    """``import canbus`` puts nothing in ``sys.modules`` but itself and what it imports (no
    stand-ins for other module paths), and replaces nothing already there."""
    tree = ast.parse((ROOT / "canbus" / "__init__.py").read_text(encoding="utf-8"))
    eager = [node for node in tree.body if isinstance(node, ast.Import | ast.ImportFrom)]
    outside = sorted({n for node in eager for n in _imports(node)} - {"canbus"})
    own = {"canbus"} | {n for n in _canbus_imports(ast.Module(body=eager, type_ignores=[]))}
    code = (f"import sys\nfor name in {outside!r}:\n    __import__(name)\n"
            "before = dict(sys.modules)\nimport canbus\n"
            "print(sorted(set(sys.modules) - set(before)))\n"
            "print(sorted(n for n, m in before.items() if sys.modules.get(n) is not m))\n")
    run = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, check=True)
    added, replaced = run.stdout.splitlines()
    assert (added, replaced) == (repr(sorted(own)), "[]")



def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _private_imports(tree: ast.AST) -> list[str]:
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            module = "." * node.level + (node.module or "")
            if any(_private(part) for part in module.split(".") if part):
                found.append(module)
            found += [f"{module}.{alias.name}" for alias in node.names if _private(alias.name)]
        elif isinstance(node, ast.Import):
            found += [alias.name for alias in node.names
                      if any(_private(part) for part in alias.name.split("."))]
    return found


@pytest.mark.parametrize("path", _modules(), ids=lambda p: p.relative_to(ROOT).as_posix())
def test_no_private_name_taken_from_another_module(path: Path) -> None:
    """A name with a leading underscore is its module's own: no module imports one."""
    taken = _private_imports(ast.parse(path.read_text(encoding="utf-8")))
    assert not taken, f"{path} imports private names {taken}"


@pytest.mark.parametrize("path", [p for p in _modules() if p.relative_to(ROOT).parts[0] in
                                  PRODUCT and not _is_command(p)],
                         ids=lambda p: p.relative_to(ROOT).as_posix())
def test_no_benchmark_in_the_product(path: Path) -> None:
    """Benchmarks live in bench/ (``skin bench`` runs them): no product module is one by its
    name or uses bench/ or pytest-benchmark."""
    assert "bench" not in path.stem, f"{path}: a benchmark belongs in bench/"
    used = _imports(ast.parse(path.read_text(encoding="utf-8")))
    assert not used & {"bench", "pytest_benchmark"}, f"{path} is a benchmark: move it to bench/"


def _runnable(tree: ast.Module) -> bool:
    return any(isinstance(node, ast.If) and "__main__" in ast.unparse(node.test)
               for node in tree.body)


def test_tests_hold_tests_only() -> None:
    """Rigs and benchmark scripts are in bench/; tests/ holds test modules, conftest.py and
    the helpers tests share, none of them a script, a benchmark or a rig."""
    others = {p.relative_to(ROOT).as_posix(): ast.parse(p.read_text(encoding="utf-8"))
              for p in (ROOT / "tests").rglob("*.py")
              if not p.name.startswith("test_") and p.name != "conftest.py"}
    wrong = [path for path, tree in others.items()
             if _runnable(tree) or any(word in Path(path).stem for word in ("bench", "rig"))
             or "pytest_benchmark" in _imports(tree)]
    assert not wrong, f"not tests: {wrong}"


def _canbus_modules() -> dict[str, Path]:
    modules = {}
    for path in (ROOT / "canbus").rglob("*.py"):
        name = ".".join(path.relative_to(ROOT).with_suffix("").parts)
        modules[name.removesuffix(".__init__")] = path
    return modules


def _canbus_graph() -> dict[str, set[str]]:
    """Module -> the canbus modules it imports, anywhere in it (type-only imports too)."""
    modules = _canbus_modules()
    graph = {}
    for name, path in modules.items():
        targets = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                for alias in node.names:  # `from canbus import codes` imports a module
                    sub = f"{node.module}.{alias.name}"
                    targets.add(sub if sub in modules else node.module)
            elif isinstance(node, ast.Import):
                targets.update(alias.name for alias in node.names)
        graph[name] = {t for t in targets if t in modules and t != name}
    return graph


def _reach(graph: dict[str, set[str]], start: str) -> set[str]:
    seen, todo = set(), [start]
    while todo:
        for nxt in graph[todo.pop()] - seen:
            seen.add(nxt)
            todo.append(nxt)
    return seen


def test_no_import_loop_in_canbus() -> None:
    """No canbus module reaches itself through its imports, type-only ones included."""
    graph = _canbus_graph()
    reach = {name: _reach(graph, name) for name in graph}
    loops = {frozenset(m for m in reach[name] if name in reach[m]) for name in graph
             if name in reach[name]}
    assert not loops, f"import loops: {sorted(sorted(loop) for loop in loops)}"


@pytest.mark.parametrize("path", [p for p in _modules() if _is_command(p)],
                         ids=lambda p: p.relative_to(ROOT).as_posix())
def test_command_functions_are_short(path: Path) -> None:
    """No function of the command line is over 60 lines: a command reads as its steps."""
    long = [f"{node.name} ({node.end_lineno - node.lineno + 1} lines)"
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and node.end_lineno
            and node.end_lineno - node.lineno + 1 > 60]
    assert not long, f"{path}: {long}"
