"""The suite's own rules (docs/testing.md), checked over every test module and every rig
(``tests.support.rigs``, below as ``rigs``):

* no ``time.sleep`` waits for something to happen: wait for the event with
  ``rigs.waiting.wait_until`` (or a child's line with ``Child.wait_for``); a sleep that
  keeps a pace is marked ``# pacing: <why>`` on its line;
* every process is started by ``rigs.children`` (it dies with the test, its output is
  shown when the test fails);
* every port and multicast group comes from ``rigs.ports`` (unique on the machine,
  outside the ephemeral range), never spelt out or derived from the process id (a value
  no socket is opened on is marked ``# no socket: <why>``);
* Hypothesis settings come from the profiles of tests/conftest.py: no per-test deadline,
  database or derandomize;
* a test asserts behaviour, not wall-clock time: an assert that reads a wall clock
  (directly or through a name set from one) is a benchmark in disguise; measure it in
  a benchmark (``skin bench``), or on a clock the test controls (the timed bus's ``now()``),
  or, where the comparison holds on any machine however loaded (an order, not a bound), say
  so with ``# any machine: <why>`` on the assert's line.
"""

from __future__ import annotations

import ast
import re
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.support.stored_values import exact_comparisons_of_stored_values, marked
from tests.support.taint import assignments, spread

ROOT = Path(__file__).resolve().parents[1]
SLEEP_HOME = "tests/support/rigs/waiting.py"
PROCESS_HOME = "tests/support/rigs/children.py"
PORT_HOME = "tests/support/rigs/ports.py"
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
    # The scripts directly in tests/support (figures, the mutants runner) run outside the
    # suite, by hand; its rigs are the suite's own.
    scripts = ROOT / "tests" / "support"
    return sorted(p for p in (ROOT / "tests").rglob("*.py") if p.parent != scripts)


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


@pytest.mark.parametrize("path", _modules(), ids=_rel)
def test_no_sleep_waits_for_something(path: Path) -> None:
    if _rel(path) == SLEEP_HOME:
        return
    tree, lines = _parse(path)
    found = [_where(path, call, lines) for call in _calls(tree, "time", {"sleep"})
             if not marked(call, lines, "# pacing:")]
    assert not found, (
        "time.sleep as synchronisation: wait for the event itself with "
        "tests.support.rigs.waiting.wait_until(condition, what=...) (a child's output: "
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
        "start processes with tests.support.rigs.children.spawn(args) or .run(args, timeout=...): "
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
             and not marked(spot := node.value if isinstance(node, ast.keyword) else node,
                             lines, "# no socket:")]
    assert not found, (
        "take ports and multicast groups from tests.support.rigs.ports (udp_bus(), tcp_port(); the "
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
    return spread(function, set(), _reads_wall_clock, assignments)


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
                  and not marked(node, lines, "# any machine:")]
    assert not found, (
        "an assert on wall-clock time fails on a busy machine: assert what happened (order, "
        "counts, values), measure time in a benchmark (skin bench), or on the timed bus's own "
        "clock; an order that holds however loaded the machine is, mark "
        "'# any machine: <why>':\n" + "\n".join(sorted(set(found))))


@pytest.mark.parametrize("path", _modules(), ids=_rel)
def test_stored_floats_are_compared_within_a_tolerance(path: Path) -> None:
    found = exact_comparisons_of_stored_values(path.read_text(encoding="utf-8"), _rel(path))
    assert not found, (
        "a value read from a stored file (tests/files, docs/) was computed on another "
        "machine, by another version, through another BLAS: compare floats within a "
        "tolerance that says what it protects (np.testing.assert_allclose(got, stored, "
        "rtol=..., atol=...)  # <what it protects>); where exactness is the promise (text, "
        "integers, flags, bytes, a codec), mark the comparison '# exact: <why>':\n"
        + "\n".join(found))


GOLDEN_TEST = """
import numpy as np
from pathlib import Path

FILES = Path(__file__).parents[1] / "files"
STORED = {mode: FILES / f"model_{mode}_decoded.npz" for mode in ("z", "xyz")}


def _then(mode):
    return np.load(STORED[mode])


def test_decodes_as_it_did(mode):
    then = _then(mode)
    out = decode(then["resistance_ohm"])
    np.testing.assert_array_equal(out.reason, then["reason"])  # exact: integer flags
    np.testing.assert_allclose(out.force_N, then["force_N"], rtol=1e-9)  # what it protects
    assert then["force_N"].shape == (60, 9, 3)
"""
MUTANTS = {
    "assert_array_equal": ("np.testing.assert_allclose(out.force_N, then[\"force_N\"], "
                           "rtol=1e-9)", "np.testing.assert_array_equal(out.force_N, "
                           "then[\"force_N\"])"),
    "array_equal": ("assert then[\"force_N\"].shape == (60, 9, 3)",
                    "assert np.array_equal(then[\"force_N\"], out.force_N)"),
    "==": ("assert then[\"force_N\"].shape == (60, 9, 3)",
           "assert (out.force_N == then[\"force_N\"]).all() and then[\"force_N\"][0, 0, 0] "
           "== out.force_N[0, 0, 0]"),
    "rtol=0": ("rtol=1e-9)", "rtol=0)"),
    "approx(rel=0, abs=0)": ("assert then[\"force_N\"].shape == (60, 9, 3)",
                             "assert out.force_N[0, 0, 0] == pytest.approx("
                             "then[\"force_N\"][0, 0, 0], rel=0, abs=0)"),
    "a reason": ("  # exact: integer flags", ""),
}


def test_the_golden_rule_passes_tolerant_and_marked_comparisons() -> None:
    assert exact_comparisons_of_stored_values(GOLDEN_TEST) == []


@pytest.mark.parametrize("mutant", MUTANTS)
def test_the_golden_rule_refuses_an_exact_comparison_of_stored_floats(mutant: str) -> None:
    """The mutant of a golden-file test that makes it exact again, each way it can be
    spelt, is refused, naming its line."""
    old, new = MUTANTS[mutant]
    assert old in GOLDEN_TEST
    found = exact_comparisons_of_stored_values(GOLDEN_TEST.replace(old, new, 1))
    assert len(found) == 1 and found[0].startswith("<snippet>:"), found


def test_the_golden_rule_leaves_values_made_in_the_run_alone() -> None:
    """Two decodes of one run compared bit for bit, read through a fixture of files
    written in tmp_path: not stored, so exact."""
    source = GOLDEN_TEST.replace('Path(__file__).parents[1] / "files"', 'Path("/tmp")')
    mutated = source.replace("rtol=1e-9)", "rtol=0)")
    assert exact_comparisons_of_stored_values(mutated) == []
