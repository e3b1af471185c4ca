"""Imports only go down the layers of docs/architecture.md, at module granularity:

0. the core (``skin``'s sensor model, constants, errors, inputs),
1. the simulator (``sim``) and the decoders (``decoder``), side by side,
2. the wire (``canbus``: its wire-level modules, then device, master, tools, timed, zenoh,
   offline, each side importing only those named in ``CANBUS_ALLOWED``),
3. the benchmarks (``skin.benchmarks``),
4. the command line (``skin.cli``, ``skin.commands``).

No module imports one of a higher layer, no two modules reach each other through their
imports (type-only and lazy imports count: they are arrows a reader follows), no module takes
a private name of another. There is no exemption: a module that needs something above it
shows that the something belongs lower. Test support (rigs, children, ports) lives in
``tests/support``, which no product module imports.
"""

from __future__ import annotations

import ast
import sys
from collections.abc import Iterable, Mapping
from pathlib import Path

import pytest

from tests.support.rigs import children

ROOT = Path(__file__).resolve().parents[1]
PRODUCT = ("skin", "sim", "decoder", "canbus")
LAYERS = ("core", "simulator and decoders", "wire", "benchmarks", "command line")
SIDE_BY_SIDE = (frozenset({"sim", "decoder"}),)
CANBUS_SIDES = ("device", "master", "offline", "tools", "timed", "zenoh")
CANBUS_ALLOWED = {
    "": set(),
    "device": {"device"},
    "master": {"device", "master"},
    "offline": {"device", "master", "offline", "tools"},
    "tools": {"tools"},
    "timed": {"timed"},
    "zenoh": {"master", "zenoh"},
}
"""Inside canbus, what each side may import besides the wire-level modules beside the
subpackages: the device side only itself; the master (the live host) also the device side
(its force nodes are local devices); the Zenoh side publishes and reads the master's frames
and events; the offline side feeds recordings (read with the bus tools) to the listen-only
host; the bus tools and the timed bus only themselves."""


def module_name(path: Path, root: Path = ROOT) -> str:
    return ".".join(path.relative_to(root).with_suffix("").parts).removesuffix(".__init__")


def product_sources(root: Path = ROOT) -> dict[str, str]:
    return {module_name(p, root): p.read_text(encoding="utf-8")
            for pkg in PRODUCT for p in sorted((root / pkg).rglob("*.py"))}


def layer(module: str) -> int:
    top = module.split(".")[0]
    if module in ("skin.cli", "skin.__main__") or module.startswith("skin.commands"):
        return 4
    if module.startswith("skin.benchmarks"):
        return 3
    return {"skin": 0, "sim": 1, "decoder": 1, "canbus": 2}[top]


def _resolve(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    base = module.split(".")
    base = base if is_package else base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join([*base, *([node.module] if node.module else [])])


def imported_modules(module: str, source: str, known: Iterable[str]) -> set[str]:
    """The modules of ``known`` that ``module`` imports anywhere in its source: ``from a
    import b`` imports module ``a.b`` when there is one, else ``a``."""
    known = set(known)
    is_package = any(k.startswith(module + ".") for k in known)
    targets: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            for alias in node.names:
                name = alias.name
                while name and name not in known:
                    name = name.rpartition(".")[0]
                targets.add(name)
        elif isinstance(node, ast.ImportFrom):
            base = _resolve(module, is_package, node)
            for alias in node.names:
                sub = f"{base}.{alias.name}"
                targets.add(sub if sub in known else base)
    return {t for t in targets if t in known and t != module}


def import_graph(sources: Mapping[str, str]) -> dict[str, set[str]]:
    return {m: imported_modules(m, s, sources) for m, s in sources.items()}


def _canbus_side(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in CANBUS_SIDES else ""


def wrong_arrows(graph: Mapping[str, set[str]]) -> list[str]:
    """Every import that goes up a layer, between modules side by side, or between canbus
    sides that ``CANBUS_ALLOWED`` keeps apart; ``canbus/__init__.py`` names the public API of
    every side (lazily) and is the one module above its own sides."""
    wrong = []
    for module, targets in graph.items():
        for target in sorted(targets):
            if target == "canbus" or (module == "canbus" and target.startswith("canbus.")):
                continue
            if layer(target) > layer(module):
                wrong.append(f"{module} ({LAYERS[layer(module)]}) imports {target} "
                             f"({LAYERS[layer(target)]}), a layer above it")
            tops = frozenset({module.split(".")[0], target.split(".")[0]})
            if tops in SIDE_BY_SIDE:
                wrong.append(f"{module} imports {target}: {' and '.join(sorted(tops))} sit side "
                             "by side")
            if module.startswith("canbus.") and target.startswith("canbus."):
                side, other = _canbus_side(module), _canbus_side(target)
                if other and other not in CANBUS_ALLOWED[side]:
                    wrong.append(f"{module} ({side or 'wire level'}) imports {target} "
                                 f"({other} side)")
    return wrong


def import_loops(graph: Mapping[str, set[str]]) -> list[list[str]]:
    """The groups of modules that reach one another through their imports (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    loops: list[list[str]] = []

    def visit(start: str) -> None:
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, edges = work[-1]
            for nxt in edges:
                if nxt not in index:
                    index[nxt] = low[nxt] = len(index)
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(sorted(graph[nxt]))))
                    break
                if nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    group = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        group.append(member)
                        if member == node:
                            break
                    if len(group) > 1:
                        loops.append(sorted(group))

    for module in sorted(graph):
        if module not in index:
            visit(module)
    return sorted(loops)


SOURCES = product_sources()
GRAPH = import_graph(SOURCES)


@pytest.mark.parametrize("module", sorted(GRAPH))
def test_imports_go_down(module: str) -> None:
    wrong = wrong_arrows({module: GRAPH[module]})
    assert not wrong, "\n".join(wrong)


def test_no_two_modules_reach_each_other() -> None:
    loops = import_loops(GRAPH)
    assert not loops, f"import loops: {loops}"


def _mutant(module: str, line: str) -> dict[str, str]:
    sources = product_sources()
    sources[module] = line + "\n" + sources[module]
    return sources


@pytest.mark.parametrize(("module", "line"), [
    ("canbus.codes", "import skin.commands.run"),
    ("skin.tripod", "from canbus import pdo_codec"),
    ("decoder.mlp", "from sim.params import SimParams"),
    ("skin.benchmarks.dataplane", "from skin.commands.common import tables"),
    ("canbus.tools.sniffer", "from canbus.master.dataplane import DataPlane"),
    ("canbus.device.patch_node", "def f():\n    from canbus.master import host"),
])
def test_an_upward_import_is_caught(module: str, line: str) -> None:
    assert wrong_arrows(import_graph(_mutant(module, line))), f"{line!r} in {module}"


def test_two_modules_importing_each_other_are_caught() -> None:
    below = sorted(GRAPH["canbus.master.dataplane"] - {"canbus"})[0]
    sources = _mutant(below, "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                             "    import canbus.master.dataplane")
    loops = import_loops(import_graph(sources))
    assert any({"canbus.master.dataplane", below} <= set(loop) for loop in loops), loops


def test_the_command_line_starts_light() -> None:
    """``skin --help`` and argument errors answer at once: building the parser imports none of
    the simulator, the decoders, the benchmarks or the wire's sides (only ``canbus``'s lazy
    package and wire-level constants); a command imports them inside its handler."""
    code = ("import sys\nimport skin.cli\nskin.cli.build_parser()\n"
            "print(' '.join(sorted(sys.modules)))\n")
    run = children.run([sys.executable, "-c", code], cwd=ROOT, timeout=120)
    assert run.returncode == 0, run.stderr
    heavy = sorted(m for m in run.stdout.split()
                   if m.split(".")[0] in {"sim", "decoder"}
                   or m.startswith("skin.benchmarks") or _canbus_side(m))
    assert not heavy, f"building skin's parser imports {heavy}"


def _top_names(node: ast.Import | ast.ImportFrom) -> list[str]:
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names]
    return [node.module] if node.module and node.level == 0 else []


def test_canbus_exports_what_it_names() -> None:
    import canbus

    assert sorted(canbus.__all__) == sorted(canbus._PUBLIC)
    for name in canbus.__all__:
        assert getattr(canbus, name).__name__ == name


def test_import_canbus_adds_only_itself() -> None:
    """``import canbus`` puts nothing in ``sys.modules`` but itself and what it imports (no
    stand-ins for other module paths), and replaces nothing already there."""
    tree = ast.parse(SOURCES["canbus"])
    eager = [node for node in tree.body if isinstance(node, ast.Import | ast.ImportFrom)]
    outside = sorted({n.split(".")[0] for node in eager for n in _top_names(node)} - {"canbus"})
    own = {"canbus"} | {n for node in eager for n in _top_names(node) if n.startswith("canbus.")}
    code = (f"import sys\nfor name in {outside!r}:\n    __import__(name)\n"
            "before = dict(sys.modules)\nimport canbus\n"
            "print(sorted(set(sys.modules) - set(before)))\n"
            "print(sorted(n for n, m in before.items() if sys.modules.get(n) is not m))\n")
    run = children.run([sys.executable, "-c", code], cwd=ROOT, timeout=120)
    assert run.returncode == 0, run.stderr
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


def _all_modules() -> list[Path]:
    return sorted(p for top in (*PRODUCT, "tests/support") for p in (ROOT / top).rglob("*.py"))


@pytest.mark.parametrize("path", _all_modules(), ids=lambda p: p.relative_to(ROOT).as_posix())
def test_no_private_name_taken_from_another_module(path: Path) -> None:
    """A name with a leading underscore is its module's own: no module imports one."""
    taken = _private_imports(ast.parse(path.read_text(encoding="utf-8")))
    assert not taken, f"{path} imports private names {taken}"


@pytest.mark.parametrize("module", sorted(GRAPH))
def test_the_product_uses_no_test_support(module: str) -> None:
    """Nothing installed imports the tests' support or pytest-benchmark, and only the
    benchmarks ``skin bench`` runs are benchmarks by name."""
    used = {n.split(".")[0] for node in ast.walk(ast.parse(SOURCES[module]))
            if isinstance(node, ast.Import | ast.ImportFrom) for n in _top_names(node)}
    assert not used & {"tests", "pytest_benchmark", "pytest", "hypothesis"}, (
        f"{module} uses test support: it belongs in tests/support")
    if layer(module) < 3:
        assert "bench" not in module.rpartition(".")[2], f"{module}: a benchmark, in the product"


def _runnable(tree: ast.Module) -> bool:
    return any(isinstance(node, ast.If) and "__main__" in ast.unparse(node.test)
               for node in tree.body)


def test_tests_hold_tests_only() -> None:
    """Rigs and scripts are in tests/support; the rest of tests/ holds test modules,
    conftest.py and the helpers tests share, none of them a script, a benchmark or a rig."""
    others = {p.relative_to(ROOT).as_posix(): ast.parse(p.read_text(encoding="utf-8"))
              for p in (ROOT / "tests").rglob("*.py")
              if not p.name.startswith("test_") and p.name != "conftest.py"
              and ROOT / "tests" / "support" not in p.parents}
    wrong = [path for path, tree in others.items()
             if _runnable(tree) or any(word in Path(path).stem for word in ("bench", "rig"))
             or "pytest_benchmark" in {n for node in ast.walk(tree)
                                       if isinstance(node, ast.Import | ast.ImportFrom)
                                       for n in _top_names(node)}]
    assert not wrong, f"not tests: {wrong}"


@pytest.mark.parametrize("module", sorted(m for m in GRAPH if layer(m) == 4))
def test_command_functions_are_short(module: str) -> None:
    """No function of the command line is over 60 lines: a command reads as its steps."""
    long = [f"{node.name} ({node.end_lineno - node.lineno + 1} lines)"
            for node in ast.walk(ast.parse(SOURCES[module]))
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and node.end_lineno
            and node.end_lineno - node.lineno + 1 > 60]
    assert not long, f"{module}: {long}"


def test_no_test_module_imports_another() -> None:
    """What tests share is a helper module (``tests/support``, or a folder's own helpers), not
    another test module: a test module is collected for its tests, not imported for its
    helpers."""
    wrong = []
    for path in sorted((ROOT / "tests").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom | ast.Import):
                names = [node.module or ""] if isinstance(node, ast.ImportFrom) else \
                    [a.name for a in node.names]
                wrong += [f"{path.relative_to(ROOT)}: {n}" for n in names
                          if n.startswith("tests.") and n.rpartition(".")[2].startswith("test_")]
    assert not wrong, "\n".join(wrong)
