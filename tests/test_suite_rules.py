"""The suite's own rules (docs/testing.md), checked over every test module and every rig:

* no ``time.sleep`` waits for something to happen: wait for the event with
  ``bench.rigs.waiting.wait_until`` (or a child's line with ``Child.wait_for``); a sleep that
  keeps a pace is marked ``# pacing: <why>`` on its line;
* every process is started by ``bench.rigs.children`` (it dies with the test, its output is
  shown when the test fails);
* every port and multicast group comes from ``bench.rigs.ports`` (unique on the machine,
  outside the ephemeral range), never spelt out or derived from the process id (a value
  no socket is opened on is marked ``# no socket: <why>``);
* Hypothesis settings come from the profiles of tests/conftest.py: no per-test deadline,
  database or derandomize;
* a test asserts behaviour, not wall-clock time: an assert that reads a wall clock
  (directly or through a name set from one) is a benchmark in disguise; measure it in
  bench/, or on a clock the test controls (the timed bus's ``now()``), or, where the
  comparison holds on any machine however loaded (an order, not a bound), say so with
  ``# any machine: <why>`` on the assert's line.
"""

from __future__ import annotations

import ast
import re
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SLEEP_HOME = "bench/rigs/waiting.py"
PROCESS_HOME = "bench/rigs/children.py"
PORT_HOME = "bench/rigs/ports.py"
PROCESS_CALLS = {("subprocess", name) for name in (
    "Popen", "run", "call", "check_call", "check_output", "getoutput", "getstatusoutput")} | {
    ("os", name) for name in ("system", "popen", "fork", "forkpty", "execv", "execvp",
                              "spawnv", "spawnl", "posix_spawn", "posix_spawnp")}
WALL_CLOCKS = {"monotonic", "perf_counter", "time", "process_time", "thread_time",
               "monotonic_ns", "perf_counter_ns", "time_ns"}
MULTICAST = re.compile(r"\b2(?:2[4-9]|3\d)\.\d{1,3}\.\d{1,3}\.\d{1,3}\b")
ENDPOINT_PORT = re.compile(r"\b(?:tcp|udp|tls|quic)/[^\s\"']*:\d+")
PORT_TEXT = re.compile(r"\bport\s*=\s*\d")


def _modules() -> list[Path]:
    return sorted([*(ROOT / "tests").rglob("*.py"), *(ROOT / "bench" / "rigs").glob("*.py")])


def _rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def _dotted(node: ast.expr) -> tuple[str, str] | None:
    if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name):
        return node.value.id, node.attr
    return None


def _imported_names(tree: ast.Module, module: str) -> dict[str, str]:
    """Local name -> original name of every ``from module import name``."""
    return {alias.asname or alias.name: alias.name for node in ast.walk(tree)
            if isinstance(node, ast.ImportFrom) and node.module == module
            for alias in node.names}


def _calls(tree: ast.Module, module: str, names: set[str]) -> Iterator[ast.Call]:
    """Calls of ``module.name`` (or of ``name`` imported from ``module``)."""
    local = {k for k, v in _imported_names(tree, module).items() if v in names}
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        dotted = _dotted(node.func)
        if (dotted and dotted[0] == module and dotted[1] in names) or (
                isinstance(node.func, ast.Name) and node.func.id in local):
            yield node


def _parse(path: Path) -> tuple[ast.Module, list[str]]:
    text = path.read_text(encoding="utf-8")
    return ast.parse(text), text.splitlines()


def _where(path: Path, node: ast.AST, lines: list[str]) -> str:
    line = getattr(node, "lineno", 0)
    return f"{_rel(path)}:{line}: {lines[line - 1].strip() if line else ''}"


def _marked(node: ast.AST, lines: list[str], mark: str) -> bool:
    first, last = getattr(node, "lineno", 0), getattr(node, "end_lineno", 0) or 0
    return any(mark in lines[k - 1] for k in range(first, last + 1))


@pytest.mark.parametrize("path", _modules(), ids=_rel)
def test_no_sleep_waits_for_something(path: Path) -> None:
    if _rel(path) == SLEEP_HOME:
        return
    tree, lines = _parse(path)
    found = [_where(path, call, lines) for call in _calls(tree, "time", {"sleep"})
             if not _marked(call, lines, "# pacing:")]
    assert not found, (
        "time.sleep as synchronisation: wait for the event itself with "
        "bench.rigs.waiting.wait_until(condition, what=...) (a child's output: "
        "Child.wait_for); a sleep that only keeps a pace gets '# pacing: <why>' on its line:\n"
        + "\n".join(found))


@pytest.mark.parametrize("path", _modules(), ids=_rel)
def test_every_process_is_started_by_the_children_helper(path: Path) -> None:
    if _rel(path) == PROCESS_HOME:
        return
    tree, lines = _parse(path)
    found = []
    for module in ("subprocess", "os"):
        names = {name for mod, name in PROCESS_CALLS if mod == module}
        found += [_where(path, call, lines) for call in _calls(tree, module, names)]
    found += [_where(path, node, lines) for node in ast.walk(tree) if _imports_processes(node)]
    assert not found, (
        "start processes with bench.rigs.children.spawn(args) or .run(args, timeout=...): "
        "they die with the test (process group, PR_SET_PDEATHSIG) and their output shows "
        "when it fails:\n" + "\n".join(found))


def _imports_processes(node: ast.AST) -> bool:
    """``import multiprocessing`` (or from it), or a ``ProcessPoolExecutor``."""
    if isinstance(node, ast.Import):
        return any(alias.name.split(".")[0] == "multiprocessing" for alias in node.names)
    if isinstance(node, ast.ImportFrom) and node.module:
        return node.module.split(".")[0] == "multiprocessing" or any(
            alias.name == "ProcessPoolExecutor" for alias in node.names)
    return False


def _pid_arithmetic(node: ast.AST) -> bool:
    return isinstance(node, ast.BinOp) and any(
        isinstance(side, ast.Call) and _dotted(side.func) == ("os", "getpid")
        for side in (node.left, node.right))


def _spells_an_address(node: ast.AST) -> bool:
    """A multicast group, an endpoint with its port, ``port=N`` (text or keyword), or a
    number made from the process id. (The text of an f-string is walked as constants.)"""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return any(p.search(node.value) for p in (MULTICAST, ENDPOINT_PORT, PORT_TEXT))
    if isinstance(node, ast.keyword) and node.arg == "port":
        value = node.value
        return isinstance(value, ast.Constant) and isinstance(value.value, int) and \
            value.value != 0
    return _pid_arithmetic(node)


@pytest.mark.parametrize("path", _modules(), ids=_rel)
def test_ports_and_groups_come_from_the_allocator(path: Path) -> None:
    if _rel(path) == PORT_HOME:
        return
    tree, lines = _parse(path)
    found = [_where(path, spot, lines) for node in ast.walk(tree) if _spells_an_address(node)
             and not _marked(spot := node.value if isinstance(node, ast.keyword) else node,
                             lines, "# no socket:")]
    assert not found, (
        "take ports and multicast groups from bench.rigs.ports (udp_bus(), tcp_port(); the "
        "udp_bus / udp_channel / udp_port fixtures): unique across parallel runs and outside "
        "the ephemeral range; port 0 where the interface says which port it took. A value "
        "no socket is opened on (a config's default checked) gets '# no socket: <why>':\n"
        + "\n".join(found))


@pytest.mark.parametrize("path", sorted((ROOT / "tests").rglob("*.py")), ids=_rel)
def test_hypothesis_settings_come_from_the_profiles(path: Path) -> None:
    tree, lines = _parse(path)
    found = [_where(path, kw.value, lines)
             for call in _calls(tree, "hypothesis", {"settings"})
             for kw in call.keywords
             if kw.arg in ("database", "derandomize")
             or (kw.arg == "deadline" and not (isinstance(kw.value, ast.Constant)
                                                and kw.value.value is None))]
    assert not found, (
        "Hypothesis' deadline, database and derandomize come from the profiles in "
        "tests/conftest.py (dev; ci, derandomized, no database); set max_examples only:\n"
        + "\n".join(found))


def _wall_clock_names(function: ast.AST) -> set[str]:
    """Names a function sets from a wall-clock reading (one level, and their sums)."""
    tainted: set[str] = set()
    changed = True
    while changed:
        changed = False
        for node in ast.walk(function):
            if isinstance(node, ast.Assign | ast.AnnAssign | ast.AugAssign | ast.NamedExpr):
                value = node.value
                targets = (node.targets if isinstance(node, ast.Assign) else [node.target])
                if value is None or not _reads_wall_clock(value, tainted):
                    continue
                for target in targets:
                    for name in ast.walk(target):
                        if isinstance(name, ast.Name) and name.id not in tainted:
                            tainted.add(name.id)
                            changed = True
    return tainted


def _reads_wall_clock(node: ast.AST, tainted: set[str]) -> bool:
    for sub in ast.walk(node):
        if isinstance(sub, ast.Call) and (dotted := _dotted(sub.func)) and \
                dotted[0] == "time" and dotted[1] in WALL_CLOCKS:
            return True
        if isinstance(sub, ast.Name) and sub.id in tainted:
            return True
    return False


@pytest.mark.parametrize("path", sorted((ROOT / "tests").rglob("test_*.py")), ids=_rel)
def test_tests_assert_behaviour_not_wall_clock_time(path: Path) -> None:
    tree, lines = _parse(path)
    found = []
    for function in ast.walk(tree):
        if not isinstance(function, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        tainted = _wall_clock_names(function)
        found += [_where(path, node, lines) for node in ast.walk(function)
                  if isinstance(node, ast.Assert) and _reads_wall_clock(node.test, tainted)
                  and not _marked(node, lines, "# any machine:")]
    assert not found, (
        "an assert on wall-clock time fails on a busy machine: assert what happened (order, "
        "counts, values), measure time in a benchmark (bench/), or on the timed bus's own "
        "clock; an order that holds however loaded the machine is, mark "
        "'# any machine: <why>':\n" + "\n".join(sorted(set(found))))
