"""No module of the live host (canbus/master) keeps state of its own: what changes belongs
to the object that owns it (a publisher's kept compositions and layouts, a host's
subscribers), never to a module-level variable every instance shares.

:func:`module_state` reads a module's source and names each binding that could change at
run time: a list, dict or set (literal, comprehension or built by a call), a call whose
result it cannot tell is immutable, a ``global`` statement, a module-level ``+=``, loop or
call run at import, a cache decorator (``functools.cache``, ``lru_cache``), a lowercase
module variable. Allowed: UPPER_CASE constants bound to immutable values (numbers, strings,
tuples, frozensets, ``MappingProxyType`` over a literal, frozen dataclass instances of the
module, compiled regexes, ``struct.Struct``, ``np.dtype``; a call annotated with an
immutable type, which mypy checks), ``logger = logging.getLogger(...)``, type aliases,
``TypeVar``s and ``__all__`` as a tuple.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

ROOT = Path(__file__).resolve().parents[2]
MASTER = ROOT / "canbus" / "master"

COPYING = frozenset({"tuple", "frozenset"})
"""Calls that copy what they are given into an immutable container."""
PROXIES = frozenset({"MappingProxyType", "types.MappingProxyType"})
IMMUTABLE_CALLS = frozenset({
    "re.compile", "struct.Struct", "logging.getLogger", "np.dtype", "numpy.dtype", "int",
    "float", "str", "bytes", "bool", "complex", "range", "slice", "operator.attrgetter",
    "operator.itemgetter"})
TYPE_CALLS = frozenset({"TypeVar", "typing.TypeVar", "NewType", "typing.NewType",
                        "ParamSpec", "typing.ParamSpec"})
IMMUTABLE_TYPES = frozenset({
    "int", "float", "str", "bytes", "bool", "complex", "tuple", "frozenset", "range",
    "MappingProxyType", "types.MappingProxyType", "Final", "typing.Final", "re.Pattern",
    "Pattern", "struct.Struct"})
CACHES = frozenset({"functools.cache", "functools.lru_cache", "cache", "lru_cache"})
HINT = ("make it an UPPER_CASE constant of an immutable value (tuple, frozenset, "
        "MappingProxyType) or an attribute of the object that owns it")


def _dotted(node: ast.expr) -> str:
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        return f"{_dotted(node.value)}.{node.attr}"
    if isinstance(node, ast.Call):
        return _dotted(node.func)
    return ""


def _upper(name: str) -> bool:
    bare = name.strip("_")
    return bool(bare) and bare == bare.upper() and any(c.isalpha() for c in bare)


def _camel(name: str) -> bool:
    bare = name.lstrip("_")
    return bool(bare) and bare[0].isupper() and not _upper(name)


def _frozen_classes(tree: ast.Module) -> set[str]:
    """The module's frozen dataclasses and named tuples: their instances are values."""
    found = set()
    for node in tree.body:
        if not isinstance(node, ast.ClassDef):
            continue
        if any(_dotted(b) in ("NamedTuple", "typing.NamedTuple") for b in node.bases):
            found.add(node.name)
        for deco in node.decorator_list:
            dataclass = isinstance(deco, ast.Call) and \
                _dotted(deco) in ("dataclass", "dataclasses.dataclass")
            if dataclass and any(k.arg == "frozen" and isinstance(k.value, ast.Constant)
                                 and k.value.value is True for k in deco.keywords):
                found.add(node.name)
    return found


class _Checker:
    def __init__(self, tree: ast.Module, name: str) -> None:
        self.name = name
        self.frozen = _frozen_classes(tree)
        self.problems: list[str] = []

    def problem(self, node: ast.AST, what: str) -> None:
        self.problems.append(f"{self.name}:{getattr(node, 'lineno', 0)}: {what}")

    # -- values -----------------------------------------------------------------------

    def immutable(self, node: ast.expr) -> bool:
        if isinstance(node, ast.Constant | ast.Name | ast.Attribute | ast.JoinedStr):
            return True  # a name is checked where it is bound
        if isinstance(node, ast.Tuple):
            return all(self.copied(e.value) if isinstance(e, ast.Starred) else self.immutable(e)
                       for e in node.elts)
        if isinstance(node, ast.BinOp):
            return self.immutable(node.left) and self.immutable(node.right)
        if isinstance(node, ast.UnaryOp):
            return self.immutable(node.operand)
        if isinstance(node, ast.BoolOp):
            return all(self.immutable(v) for v in node.values)
        if isinstance(node, ast.Compare):
            return True  # a bool
        if isinstance(node, ast.IfExp):
            return self.immutable(node.body) and self.immutable(node.orelse)
        if isinstance(node, ast.Subscript):
            return self.immutable(node.value)
        if isinstance(node, ast.Call):
            return self.call(node)
        return False  # list, dict, set, comprehension, generator, lambda, ...

    def copied(self, node: ast.expr) -> bool:
        """Whether the elements of an iterable copied into a tuple or frozenset are values."""
        if isinstance(node, ast.List | ast.Set | ast.Tuple):
            return all(self.copied(e.value) if isinstance(e, ast.Starred) else self.immutable(e)
                       for e in node.elts)
        if isinstance(node, ast.ListComp | ast.SetComp | ast.GeneratorExp):
            return self.immutable(node.elt)
        if isinstance(node, ast.Dict):
            return all(k is not None and self.immutable(k) for k in node.keys)
        if isinstance(node, ast.DictComp):
            return self.immutable(node.key)
        return isinstance(node, ast.Name | ast.Attribute | ast.Call | ast.Subscript)

    def call(self, node: ast.Call) -> bool:
        callee = _dotted(node.func)
        if callee in COPYING:
            return all(self.copied(a) for a in node.args) and not node.keywords
        if callee in PROXIES:  # over a literal only: a named dict stays mutable through its name
            (arg,) = node.args or (None,)
            if isinstance(arg, ast.Dict):
                return all(k is not None and self.immutable(k) for k in arg.keys) and \
                    all(self.immutable(v) for v in arg.values)
            if isinstance(arg, ast.DictComp):
                return self.immutable(arg.key) and self.immutable(arg.value)
            return False
        if callee in IMMUTABLE_CALLS or callee in self.frozen:
            return all(self.immutable(a) for a in node.args) and \
                all(self.immutable(k.value) for k in node.keywords)
        return False

    @staticmethod
    def type_expression(node: ast.expr) -> bool:
        if isinstance(node, ast.Subscript | ast.Name | ast.Attribute):
            return True
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.BitOr):
            return _Checker.type_expression(node.left) and _Checker.type_expression(node.right)
        return isinstance(node, ast.Constant) and (node.value is None or
                                                   isinstance(node.value, str))

    @staticmethod
    def immutable_type(annotation: ast.expr | None) -> bool:
        if annotation is None:
            return False
        head = annotation.value if isinstance(annotation, ast.Subscript) else annotation
        return _dotted(head) in IMMUTABLE_TYPES

    # -- bindings ---------------------------------------------------------------------

    def bind(self, target: ast.expr, value: ast.expr, annotation: ast.expr | None = None
             ) -> None:
        if isinstance(target, ast.Tuple | ast.List):
            if isinstance(value, ast.Tuple) and len(value.elts) == len(target.elts) and \
                    not any(isinstance(e, ast.Starred) for e in value.elts):
                for t, v in zip(target.elts, value.elts, strict=True):
                    self.bind(t, v)
            elif isinstance(value, ast.ListComp | ast.GeneratorExp):
                for t in target.elts:
                    self.bind(t, value.elt)
            else:
                self.problem(target, f"{ast.unparse(target)} = {ast.unparse(value)[:60]}: "
                             f"cannot tell the parts are immutable; {HINT}")
            return
        if not isinstance(target, ast.Name):
            self.problem(target, f"{ast.unparse(target)} changed at import: {HINT}")
            return
        self.name_bound(target, target.id, value, annotation)

    def name_bound(self, node: ast.AST, name: str, value: ast.expr,
                   annotation: ast.expr | None) -> None:
        shown = f"{name} = {ast.unparse(value)[:60]}"
        if name == "__all__":
            if not isinstance(value, ast.Tuple):
                self.problem(node, f"{shown}: make __all__ a tuple")
            return
        if isinstance(value, ast.Call) and _dotted(value) == "logging.getLogger":
            return
        if isinstance(value, ast.Call) and _dotted(value) in TYPE_CALLS:
            return
        if _camel(name):
            if not self.type_expression(value):
                self.problem(node, f"{shown}: a CamelCase name binds a type alias; {HINT}")
            return
        if not _upper(name):
            self.problem(node, f"{shown}: a module-level variable; {HINT}")
            return
        if self.immutable(value):
            return
        if isinstance(value, ast.Call) and self.immutable_type(annotation):
            return  # mypy checks that the call gives what the annotation says
        self.problem(node, f"{shown}: not an immutable value; {HINT}")

    def statements(self, body: list[ast.stmt]) -> None:
        for node in body:
            if isinstance(node, ast.Assign):
                for target in node.targets:
                    self.bind(target, node.value)
            elif isinstance(node, ast.AnnAssign):
                if node.value is not None:
                    self.bind(node.target, node.value, node.annotation)
            elif isinstance(node, ast.AugAssign):
                self.problem(node, f"{ast.unparse(node)}: module state changed at import")
            elif isinstance(node, ast.Expr):
                if not (isinstance(node.value, ast.Constant) and
                        isinstance(node.value.value, str)):
                    self.problem(node, f"{ast.unparse(node)[:60]}: run at import")
            elif isinstance(node, ast.For | ast.AsyncFor | ast.While):
                self.problem(node, "a loop at import: build the value in one expression")
            elif isinstance(node, ast.If | ast.Try | ast.With):
                self.statements(node.body)
                for handler in getattr(node, "handlers", []):
                    self.statements(handler.body)
                self.statements(getattr(node, "orelse", []))
                self.statements(getattr(node, "finalbody", []))

    def everywhere(self, tree: ast.Module) -> None:
        for node in ast.walk(tree):
            if isinstance(node, ast.Global):
                self.problem(node, f"global {', '.join(node.names)}: module state written "
                             f"by a function; {HINT}")
            elif isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                for deco in node.decorator_list:
                    if _dotted(deco) in CACHES:
                        self.problem(deco, f"{node.name}: a cache every caller shares; keep "
                                     "it on the object that owns it")


def module_state(source: str, name: str = "<module>") -> list[str]:
    """Every binding of the module ``source`` that could change at run time (module
    docstring), as ``name:line: what``."""
    tree = ast.parse(source)
    checker = _Checker(tree, name)
    checker.statements(tree.body)
    checker.everywhere(tree)
    return checker.problems


@pytest.mark.parametrize("path", sorted(MASTER.glob("*.py")), ids=lambda p: p.name)
def test_no_module_of_the_live_host_keeps_state(path: Path) -> None:
    found = module_state(path.read_text(encoding="utf-8"), path.name)
    assert not found, "\n".join(found)


MUTABLE = (
    "_CACHE = {}", "_CACHE: dict[int, int] = {}", "SEEN = []", "SEEN = set()", "TABLE = dict()",
    "TABLE = {k: k for k in range(3)}", "ROWS = [k for k in range(3)]",
    "ROWS = (k for k in range(3))", "BY_ID = collections.defaultdict(list)",
    "BY_ID = defaultdict(list)", "ORDER = collections.OrderedDict()",
    "LAYOUTS = weakref.WeakKeyDictionary()", "QUEUE = collections.deque()",
    "ZEROS = np.zeros(3)", "COUNTS = np.array([1.0, 2.0])", "LOCK = threading.Lock()",
    "TABLE = make_table()", "TABLE = MappingProxyType(_TABLE)",
    "PAIRS = (1, [2, 3])", "NAMES = tuple([[1], [2]])",
    "TABLE = MappingProxyType({1: []})", "A, B = make_pair()", "cache = {}",
    "counter = 0", "Handler = make_handler()", "__all__ = ['a', 'b']",
    "COUNT = 0\nCOUNT += 1", "TABLE[0] = 1", "REGISTRY.append(1)",
    "for k in range(3):\n    pass",
    "def f():\n    global COUNT\n    COUNT = 1",
    "import functools\n@functools.lru_cache(maxsize=8)\ndef f(x):\n    return x",
    "import functools\n@functools.cache\ndef f(x):\n    return x",
    "class C:\n    def m(self):\n        global SEEN",
    "if TYPE_CHECKING:\n    pass\nelse:\n    CACHE = {}",
    "try:\n    import x\nexcept ImportError:\n    FALLBACK = []",
)
IMMUTABLE = (
    "LIMIT = 3", "PERIOD_S = 0.05", "NAME = 'host'", "MASK = 1 << 15", "NEG = -0x8000",
    "MODES = ('z', 'xyz')", "A, B = (1, 2)", "SEVERAL = (*MODES, 'fd')",
    "IDS = frozenset({1, 2, 3})", "IDS = frozenset((NMT, SYNC, *range(0x81, 0x100)))",
    "KEYS = tuple(f.name for f in fields(Config))",
    "TEXT = MappingProxyType({1: 'open', 2: 'short'})",
    "COLUMN = MappingProxyType({s: k for k, s in enumerate(ORDER)})",
    "PATTERN = re.compile(r'[0-9]+')", "U16 = struct.Struct('<H')",
    "TABLE_DTYPE = np.dtype('<i8')", "logger = logging.getLogger(__name__)",
    "F64 = NDArray[np.float64]", "Frame = tuple[int, bytes]",
    "Buses = can.BusABC | Mapping[str, can.BusABC]", "T = TypeVar('T')",
    "__all__ = ('a', 'b')", "ALIAS = other.CONSTANT", "FIRST = ORDER[:2]",
    "ENTRIES: tuple[int, ...] = make_entries()", "COUNT: int",
    "from dataclasses import dataclass\n@dataclass(frozen=True)\nclass P:\n    x: int\n"
    "DEFAULT = P(1)",
    "from typing import NamedTuple\nclass P(NamedTuple):\n    x: int\nORIGIN = P(0)",
    "if TYPE_CHECKING:\n    from x import Y", "'''A docstring.'''",
    "def f():\n    local = {}\n    return local",
)


@pytest.mark.parametrize("source", MUTABLE)
def test_the_checker_finds_module_state(source: str) -> None:
    assert module_state(source), source


@pytest.mark.parametrize("source", IMMUTABLE)
def test_the_checker_lets_constants_be(source: str) -> None:
    assert module_state(source) == [], source


@settings(max_examples=100)
@given(body=st.lists(st.sampled_from(IMMUTABLE), max_size=8), bad=st.sampled_from(MUTABLE),
       at=st.integers(0, 8), nest=st.sampled_from(["", "if TYPE_CHECKING:\n", "try:\n"]))
def test_one_piece_of_state_anywhere_among_constants_is_found_on_its_line(
        body: list[str], bad: str, at: int, nest: str) -> None:
    pieces = [*body]
    at = min(at, len(pieces))
    if nest and not bad.startswith(("def ", "class ", "import ", "if ", "try:", "for ")):
        wrapped = nest + "\n".join("    " + line for line in bad.splitlines())
        wrapped += "\nexcept ImportError:\n    pass" if nest == "try:\n" else ""
    else:
        wrapped = bad
    pieces.insert(at, wrapped)
    source = "\n".join(pieces)
    first = sum(piece.count("\n") + 1 for piece in pieces[:at]) + 1
    last = first + wrapped.count("\n")
    found = module_state(source)
    assert found, source
    assert all(first <= int(f.split(":")[1]) <= last for f in found), (source, found)
