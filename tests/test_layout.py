"""The shape of the code base, read with ``ast`` (nothing is imported): test files share builders
through tests/helpers/ only."""

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
