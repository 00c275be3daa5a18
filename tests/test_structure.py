"""The house stays readable: no import cycle between modules (read from the source with ast,
function-level and TYPE_CHECKING imports included), modules under 450 lines and functions under
80, few top-level modules in tools/ and onboard/ (the rest in subpackages named for what they
hold), imports at the top of modules but for a few lazy ones that say why, and tools/ taking from
onboard/ only the CLI runner, the configuration and the sweep plan. The layers between packages
are tests/test_lean.py's.
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


def imported(tree: ast.AST, known: set[str]) -> set[str]:
    """The modules of `known` that a module's body imports anywhere, for annotations too (`from
    a import b` may name module a.b): a cycle closed through a function or `TYPE_CHECKING` is
    still a cycle of the design."""
    names = set()
    for node in ast.walk(tree):
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


# -- the shape of the tree --------------------------------------------------------------------
MAX_TOP_LEVEL_MODULES = 8  # in tools/ and onboard/; the rest live in subpackages
MAX_LAZY_IMPORTS = 40  # project imports inside functions, each saying why


def test_tools_and_onboard_keep_few_modules_at_their_top_level():
    for package in ("tools", "onboard"):
        top = sorted(p.name for p in (ROOT / package).glob("*.py"))
        assert len(top) <= MAX_TOP_LEVEL_MODULES, f"{package}/ has {len(top)} top-level modules: {top}"


def lazy_imports(root: pathlib.Path = ROOT) -> dict[str, bool]:
    """'path:line' of every project import inside a function -> whether it says why (a comment
    on its line, on the line above, or on the first import of the group it opens)."""
    out = {}
    for path in modules(root).values():
        text = path.read_text(encoding="utf-8")
        lines = text.splitlines()
        tree = ast.parse(text)
        functions = [n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))]
        blocks = [getattr(n, field) for fn in functions for n in ast.walk(fn)
                  for field in ("body", "orelse", "finalbody") if isinstance(getattr(n, field, None), list)]
        for block in blocks:
            reason = False
            previous = None
            for node in block:
                if not isinstance(node, (ast.Import, ast.ImportFrom)):
                    previous = None
                    continue
                module = node.module if isinstance(node, ast.ImportFrom) else node.names[0].name
                own = "#" in lines[node.lineno - 1] or lines[node.lineno - 2].strip().startswith("#")
                reason = own or (previous is not None and reason)
                previous = node
                if module and module.split(".")[0] in PACKAGES:
                    out[f"{path.relative_to(root)}:{node.lineno}"] = reason
    return out


def test_imports_sit_at_the_top_but_a_few_lazy_ones_that_say_why():
    lazy = lazy_imports()
    assert len(lazy) <= MAX_LAZY_IMPORTS, f"{len(lazy)} project imports inside functions: {sorted(lazy)}"
    silent = sorted(k for k, said in lazy.items() if not said)
    assert not silent, f"lazy imports that do not say why: {silent}"


def test_the_lazy_import_count_sees_an_import_in_a_function(tmp_path):
    pkg = tmp_path / "tools"
    pkg.mkdir()
    (pkg / "a.py").write_text("def f():\n    from tools import b  # heavy\n    from tools import c\n\n"
                              "def g():\n    import tools.b\n")
    assert lazy_imports(tmp_path) == {"tools/a.py:2": True, "tools/a.py:3": True, "tools/a.py:6": False}


# tools/ takes from onboard/ only these: the fitter is btf.fit, shared by robot and host.
TOOLS_FROM_ONBOARD = {"onboard.cli", "onboard.cli.runner", "onboard.config", "onboard.sweep.plan"}


def test_tools_take_from_onboard_only_the_cli_runner_the_configuration_and_the_sweep_plan():
    mods = modules()
    used = {}
    for name, path in mods.items():
        if name.split(".")[0] == "tools":
            got = {m for m in imported(ast.parse(path.read_text(encoding="utf-8")), set(mods))
                   if m.split(".")[0] == "onboard"} - TOOLS_FROM_ONBOARD
            if got:
                used[name] = sorted(got)
    assert not used, f"tools modules that reach into the robot's runtime: {used}"


def test_test_modules_share_helpers_through_tests_support_only():
    borrowed = {}
    for path in sorted((ROOT / "tests").rglob("test_*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("tests."):
                if node.module != "tests.support" and not node.module.startswith("tests.support."):
                    borrowed.setdefault(str(path.relative_to(ROOT)), []).append(node.module)
    assert not borrowed, f"test modules importing other test modules (move the helper to tests/support): {borrowed}"
