"""The package layout keeps data flowing one way (read from the source with ast, nothing imported):

* no import circle among tmr's modules (module-level imports: the ones run when a module is imported);
* the shared packages never import a system package (``tmr.mcdpr``, ``tmr.ccma``), not even lazily inside a
  function: each system turns its own plan into a Motion and its own run.json section.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parent.parent / "src"
#: Packages every system uses; they must not know the systems.
SHARED = ("tmr.model", "tmr.world", "tmr.route", "tmr.control", "tmr.checks", "tmr.views", "tmr.io", "tmr.errors",
          "tmr.files")  # fmt: skip
SYSTEMS = ("tmr.mcdpr", "tmr.ccma")


def module_name(path: Path) -> str:
    parts = path.relative_to(SRC).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(p): p for p in (SRC / "tmr").rglob("*.py")}


def _targets(node: ast.Import | ast.ImportFrom) -> list[str]:
    """Modules of tmr an import statement loads (``from tmr.x import y`` loads tmr.x.y too when it is a module)."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names if a.name.split(".")[0] == "tmr"]
    if node.level or not node.module or node.module.split(".")[0] != "tmr":
        return []
    out = [node.module]
    out += [f"{node.module}.{a.name}" for a in node.names if f"{node.module}.{a.name}" in MODULES]
    return out


def imports(path: Path, module_level: bool) -> set[str]:
    """tmr modules imported by the file: at module level only (not in functions, not under TYPE_CHECKING), or all."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found: set[str] = set()

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if module_level and isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda):
                continue
            if module_level and isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                continue
            if isinstance(child, ast.Import | ast.ImportFrom):
                found.update(_targets(child))
            visit(child)

    visit(tree)
    return {m for m in found if m in MODULES}


def _parents(name: str) -> list[str]:
    """Packages Python imports before ``name`` (tmr.a.b -> tmr, tmr.a)."""
    parts = name.split(".")
    return [".".join(parts[:k]) for k in range(1, len(parts))]


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import circle of ``graph`` (module -> modules it imports), or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def dfs(m: str) -> list[str] | None:
        state[m] = 1
        stack.append(m)
        for n in sorted(graph.get(m, ())):
            if state.get(n) == 1:
                return stack[stack.index(n) :] + [n]
            if n not in state and (cycle := dfs(n)):
                return cycle
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state and (cycle := dfs(m)):
            return cycle
    return None


def test_no_import_circle():
    graph = {}
    for name, path in MODULES.items():
        deps = imports(path, module_level=True)
        # importing tmr.a.b runs tmr/__init__ and tmr/a/__init__ first: a package's own submodules don't count
        graph[name] = {d for d in deps if not name.startswith(d + ".")} - {name}
    assert find_cycle(graph) is None, " -> ".join(find_cycle(graph) or [])


def test_find_cycle_finds_one():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


@pytest.mark.parametrize("shared", SHARED)
def test_shared_packages_never_import_a_system(shared):
    offenders = [
        f"{name} imports {dep}"
        for name, path in sorted(MODULES.items())
        if name == shared or name.startswith(shared + ".")
        for dep in sorted(imports(path, module_level=False))
        if any(dep == s or dep.startswith(s + ".") for s in SYSTEMS)
    ]
    assert not offenders, "; ".join(offenders)


def test_the_checks_see_the_imports():
    """The walker finds lazy imports in functions (so the direction test can fail) and skips them for circles."""
    path = MODULES["tmr.mcdpr.rundir"]
    assert "tmr.mcdpr.motion" in imports(path, module_level=False)
    assert "tmr.mcdpr.motion" not in imports(path, module_level=True)
    assert "tmr.io.rundir" in imports(path, module_level=True)
