"""The house stays readable: no import cycle between modules, modules under 450 lines and
functions under 80 in btf/, radio/, hal/, onboard/ and tools/ (read from the source with ast,
function-level imports included). The layers between packages are tests/test_lean.py's.
"""
from __future__ import annotations

import ast
import pathlib

ROOT = pathlib.Path(__file__).resolve().parent.parent
PACKAGES = ("btf", "radio", "hal", "onboard", "tools")
MAX_MODULE_LINES = 450
MAX_FUNCTION_LINES = 80
# Each exception names why it stands; remove an entry once its module or function is split.
TOO_LONG_ALLOWED: dict[str, str] = {}


def modules(root: pathlib.Path = ROOT) -> dict[str, pathlib.Path]:
    """Dotted module name -> source file, for every module of the packages."""
    out = {}
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def _type_checking_only(tree: ast.AST) -> set[int]:
    """ids of the nodes inside `if TYPE_CHECKING:` blocks: imports for annotations only, which
    run at no import time and so close no cycle."""
    inside = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            inside |= {id(n) for stmt in node.body for n in ast.walk(stmt)}
    return inside


def imported(tree: ast.AST, known: set[str]) -> set[str]:
    """The modules of `known` that a module's body imports anywhere at run time (`from a import b`
    may name module a.b)."""
    names = set()
    typing_only = _type_checking_only(tree)
    for node in ast.walk(tree):
        if id(node) in typing_only:
            continue
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names |= {node.module} | {f"{node.module}.{a.name}" for a in node.names}
    return names & known


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            part = []
            while True:
                w = stack.pop()
                part.append(w)
                if w == v:
                    break
            if len(part) > 1:
                found.append(sorted(part))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_cycle_finder_finds_a_cycle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_two_modules_import_each_other_even_through_others():
    mods = modules()
    graph = {name: imported(ast.parse(path.read_text(encoding="utf-8")), set(mods)) - {name}
             for name, path in mods.items()}
    assert not cycles(graph), f"import cycles: {cycles(graph)}"


def too_long(root: pathlib.Path = ROOT) -> dict[str, int]:
    """'path' -> lines of each module over the limit, 'path::function' -> lines of each function
    over it (from its first decorator to its last line)."""
    out = {}
    for path in modules(root).values():
        text = path.read_text(encoding="utf-8")
        rel = str(path.relative_to(root))
        if len(text.splitlines()) > MAX_MODULE_LINES:
            out[rel] = len(text.splitlines())
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                first = min([node.lineno, *(d.lineno for d in node.decorator_list)])
                if node.end_lineno - first + 1 > MAX_FUNCTION_LINES:
                    out[f"{rel}::{node.name}"] = node.end_lineno - first + 1
    return out


def test_modules_and_functions_are_short_enough_to_read_in_one_sitting():
    over = {k: n for k, n in too_long().items() if k not in TOO_LONG_ALLOWED}
    assert not over, (f"over {MAX_MODULE_LINES} lines a module or {MAX_FUNCTION_LINES} a function: {over}; "
                      "split them (or add a reason to TOO_LONG_ALLOWED)")


def test_the_size_check_sees_a_long_function_and_a_long_module(tmp_path):
    pkg = tmp_path / "btf"
    pkg.mkdir()
    (pkg / "long.py").write_text("def f():\n" + "    x = 1\n" * 80 + "\n\ndef g():\n    pass\n")
    (pkg / "big.py").write_text("x = 1\n" * 451)
    (pkg / "fits.py").write_text("x = 1\n" * 450)
    assert too_long(tmp_path) == {"btf/long.py::f": 81, "btf/big.py": 451}
