"""The shape of the code base, read with ``ast`` (nothing is imported): test files share builders
through tests/helpers/ only, and the import graph of funrec and funrec_robot has no circle."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TESTS = ROOT / "tests"


def _imported_modules(path: Path, package: str) -> set[str]:
    """Absolute names of every module ``path`` imports, anywhere in the file (lazy imports too).

    ``from a.b import c`` yields both ``a.b`` and ``a.b.c`` (c may be a module); relative imports are
    resolved against ``package``, the dotted package holding ``path``.
    """
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = package.split(".")[: len(package.split(".")) - node.level + 1] if node.level else []
            module = ".".join([*base, *([node.module] if node.module else [])])
            names.add(module)
            names.update(f"{module}.{alias.name}" for alias in node.names)
    return names


def test_no_test_file_imports_another() -> None:
    """Shared builders live in tests/helpers/ (or conftest.py fixtures); a test file imported by
    another runs its module-level setup twice and hides which tests depend on which."""
    test_modules = {path.stem for path in TESTS.glob("test_*.py")}
    offenders = set()
    for path in sorted([*TESTS.glob("test_*.py"), *TESTS.glob("conftest.py"), *TESTS.glob("helpers/*.py")]):
        package = ".".join(path.relative_to(ROOT).parent.parts)
        for name in _imported_modules(path, package):
            parts = name.split(".")
            # ``test_x`` (tests/ on sys.path) or ``tests.test_x`` (tests as a package).
            imported = parts[0] if parts[0] != "tests" else parts[1] if len(parts) > 1 else ""
            if imported in test_modules:
                offenders.add(f"{path.relative_to(ROOT)} imports {imported}")
    assert not offenders, "move shared builders to tests/helpers/: " + "; ".join(sorted(offenders))


def _module_graph() -> dict[str, set[str]]:
    """Module -> the modules of funrec and funrec_robot it imports (the same edges as the import
    graph used to lay out the packages: every import statement, lazy ones included)."""
    files = {}
    for package in ("funrec", "funrec_robot"):
        for path in (ROOT / package).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            files[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    graph = {}
    for module, path in files.items():
        package = module if path.name == "__init__.py" else module.rpartition(".")[0]
        graph[module] = {name for name in _imported_modules(path, package) if name in files and name != module}
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            v, children = work[-1]
            w = next(children, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                component = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    component.append(w)
                    if w == v:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def test_cycle_finder_on_a_known_graph() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": {"e"}, "e": {"d"}, "f": {"a"}}
    assert sorted(_cycles(graph)) == [["a", "b", "c"], ["d", "e"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_import_graph() -> None:
    graph = _module_graph()
    assert "funrec.pipeline" in graph and "funrec_robot.cli" in graph, "packages not found"
    cycles = _cycles(graph)
    assert not cycles, f"import circles: {cycles}"
