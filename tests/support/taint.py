"""Names a function binds from a value that is tainted (a wall-clock reading, a stored
file), followed through its assignments to a fixed point: what the suite's rules check."""

from __future__ import annotations

import ast
from collections.abc import Callable, Iterable, Iterator

Binder = Callable[[ast.AST], Iterable[tuple[list[ast.expr], ast.AST]]]


def spread(node: ast.AST, seeds: set[str], taints: Callable[[ast.AST, set[str]], bool],
           binder: Binder) -> set[str]:
    """``seeds`` and every name ``binder`` binds in ``node`` from a value that ``taints``,
    given the names tainted so far."""
    tainted = set(seeds)
    changed = True
    while changed:
        changed = False
        for targets, value in binder(node):
            if not taints(value, tainted):
                continue
            for target in targets:
                for name in ast.walk(target):
                    if isinstance(name, ast.Name) and name.id not in tainted:
                        tainted.add(name.id)
                        changed = True
    return tainted


def assignments(node: ast.AST) -> Iterator[tuple[list[ast.expr], ast.AST]]:
    """(targets, value) of every assignment in ``node`` (``=``, annotated, augmented, ``:=``)."""
    for sub in ast.walk(node):
        if isinstance(sub, ast.Assign | ast.AnnAssign | ast.AugAssign | ast.NamedExpr) and \
                sub.value is not None:
            yield (list(sub.targets) if isinstance(sub, ast.Assign) else [sub.target]), sub.value


def bindings(node: ast.AST) -> Iterator[tuple[list[ast.expr], ast.AST]]:
    """(targets, value) of every binding in ``node``: assignments, loops, ``with ... as``."""
    for sub in ast.walk(node):
        if isinstance(sub, ast.Assign) and sub.value is not None:
            yield list(sub.targets), sub.value
        elif isinstance(sub, ast.AnnAssign | ast.AugAssign | ast.NamedExpr) and \
                sub.value is not None:
            yield [sub.target], sub.value
        elif isinstance(sub, ast.For | ast.AsyncFor | ast.comprehension):
            yield [sub.target], sub.iter
        elif isinstance(sub, ast.withitem) and sub.optional_vars is not None:
            yield [sub.optional_vars], sub.context_expr
