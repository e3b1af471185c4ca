"""Rule 6 of the suite (docs/testing.md): a value read from a stored file (tests/files,
docs/) is compared within a tolerance, not exactly, unless the comparison says why
exactness is the promise (``# exact: <why>``). :func:`exact_comparisons_of_stored_values`
is the checker ``tests/test_suite_rules.py`` runs over every test module."""

from __future__ import annotations

import ast
from collections.abc import Iterator

from tests.support.taint import bindings, spread

GOLDEN_DIRS = ("files", "docs")
"""Path segments of what is stored in the repository (tests/files, docs/*.md): written on
another machine, by another version, through another BLAS."""
EXACT_CALLS = {"assert_array_equal", "assert_equal", "array_equal", "array_equiv"}
TOLERANT_CALLS = {"assert_allclose": ("rtol", "atol"), "allclose": ("rtol", "atol"),
                  "isclose": ("rtol", "atol"), "approx": ("rel", "abs")}


def _names_stored(node: ast.AST, stored: set[str]) -> bool:
    """``node`` names a stored file (a golden folder's segment) or a name bound to one."""
    for sub in ast.walk(node):
        if isinstance(sub, ast.BinOp) and isinstance(sub.op, ast.Div) and \
                isinstance(sub.right, ast.Constant) and sub.right.value in GOLDEN_DIRS:
            return True  # ... / "files"
        if isinstance(sub, ast.Constant) and isinstance(sub.value, str) and \
                sub.value.startswith(("tests/files/", "docs/")):
            return True
        if isinstance(sub, ast.Name) and sub.id in stored:
            return True
    return False


def _stored_names(tree: ast.Module) -> set[str]:
    """Module names bound to stored files or to what is read from them, and the module's
    functions (helpers, fixtures) that read them, to a fixed point."""
    stored: set[str] = set()
    changed = True
    while changed:
        changed = False
        for node in tree.body:
            names: list[str] = []
            if isinstance(node, ast.Assign | ast.AnnAssign) and node.value is not None and \
                    _names_stored(node.value, stored):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                names = [n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)]
            elif isinstance(node, ast.FunctionDef) and _names_stored(node, stored):
                names = [node.name]
            for name in names:
                if name not in stored:
                    stored.add(name)
                    changed = True
    return stored


def _read_from_storage(function: ast.FunctionDef | ast.AsyncFunctionDef,
                       stored: set[str]) -> set[str]:
    """Names that hold a stored file or what was read from it, in ``function``: the module's
    (a fixture's name as a parameter too), and those set from them."""
    return spread(function, stored, _names_stored, bindings)


def _called(node: ast.Call) -> str:
    func = node.func
    return func.attr if isinstance(func, ast.Attribute) else \
        func.id if isinstance(func, ast.Name) else ""


def _literal_without_floats(node: ast.AST) -> bool:
    """A written-out value with no float in it (text, integers, keys): exact is its meaning."""
    if isinstance(node, ast.Constant):
        return not isinstance(node.value, float | complex)
    if isinstance(node, ast.List | ast.Tuple | ast.Set):
        return all(_literal_without_floats(e) for e in node.elts)
    if isinstance(node, ast.Dict):
        return all(_literal_without_floats(e) for e in [*node.keys, *node.values]
                   if e is not None)
    if isinstance(node, ast.BinOp):
        return _literal_without_floats(node.left) and _literal_without_floats(node.right)
    if isinstance(node, ast.Call):  # a count or a text
        return _called(node) in ("len", "str", "repr", "bytes")
    if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name):
        return node.attr.isupper() and node.value.id[:1].isupper()  # Reason.EXTRAPOLATED
    return isinstance(node, ast.JoinedStr)


def _zero_tolerance(call: ast.Call) -> bool:
    """``assert_allclose(..., rtol=0)`` and the like: an exact comparison in disguise."""
    tolerances = TOLERANT_CALLS.get(_called(call))
    if tolerances is None:
        return False
    given = {kw.arg: kw.value for kw in call.keywords if kw.arg in tolerances}
    zero = [isinstance(v, ast.Constant) and v.value == 0 for v in given.values()]
    if _called(call) == "assert_allclose":  # atol is 0 unless given
        return tolerances[0] in given and all(zero)
    return len(given) == 2 and all(zero)


def _exact_sides(node: ast.AST) -> list[ast.expr] | None:
    """The compared values of an exact comparison (a call, or ``==`` in an assert), else
    None."""
    if isinstance(node, ast.Call) and (_called(node) in EXACT_CALLS or _zero_tolerance(node)):
        return list(node.args[:2])
    if isinstance(node, ast.Compare) and \
            all(isinstance(op, ast.Eq | ast.NotEq) for op in node.ops):
        sides = [node.left, *node.comparators]
        if any(isinstance(s, ast.Call) and _called(s) == "approx" and not _zero_tolerance(s)
               for s in sides):
            return None
        return sides
    return None


def _comparisons(function: ast.AST) -> Iterator[tuple[ast.AST, ast.AST]]:
    """(comparison, the statement whose lines may mark it): calls anywhere, ``==`` in
    asserts."""
    for node in ast.walk(function):
        if isinstance(node, ast.Call):
            yield node, node
        elif isinstance(node, ast.Assert):
            for sub in ast.walk(node.test):
                if isinstance(sub, ast.Compare):
                    yield sub, node


def exact_comparisons_of_stored_values(source: str, name: str = "<snippet>") -> list[str]:
    """Where ``source`` compares a value read from a stored file (tests/files, docs/) for
    exact equality, with no ``# exact: <why>`` on the comparison's lines."""
    tree = ast.parse(source)
    lines = source.splitlines()
    stored = _stored_names(tree)
    found = set()
    for function in ast.walk(tree):
        if not isinstance(function, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        tainted = _read_from_storage(function, stored)
        for node, statement in _comparisons(function):
            sides = _exact_sides(node)
            if not sides or not any(_names_stored(s, tainted) for s in sides):
                continue
            if any(_literal_without_floats(s) for s in sides):
                continue  # a written-out value without floats, a count, a text
            if not marked(statement, lines, "# exact:"):
                line = int(getattr(node, "lineno", 0))
                found.add(f"{name}:{line}: {lines[line - 1].strip()}")
    return sorted(found)


def marked(node: ast.AST, lines: list[str], mark: str) -> bool:
    first, last = getattr(node, "lineno", 0), getattr(node, "end_lineno", 0) or 0
    return any(mark in lines[k - 1] for k in range(first, last + 1))
