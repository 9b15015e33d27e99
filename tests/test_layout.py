"""The house's rules, read from the source: folders by concept, imports one way, no loops, no private
names taken across modules, no module over 400 lines (docs/architecture.md)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("rdd", "envs", "policy", "planner", "experiments")
# Each package may import only those below it.
LAYERS = {"rdd": set(), "envs": {"rdd"}, "policy": {"rdd", "envs"}, "planner": {"rdd", "envs"},
          "experiments": {"rdd", "envs", "policy", "planner"}}


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


MODULES = _modules()


def _imports(path: Path, type_hints: bool = False) -> list[tuple[str, str | None]]:
    """(module, name) pairs that ``path`` imports from the project's packages (names None for ``import x``).
    Imports under ``if TYPE_CHECKING:`` count only with ``type_hints``."""
    tree = ast.parse(path.read_text(), str(path))
    hinted = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            hinted.update(id(n) for stmt in node.body for n in ast.walk(stmt))
    out = []
    for node in ast.walk(tree):
        if id(node) in hinted and not type_hints:
            continue
        if isinstance(node, ast.Import):
            out += [(a.name, None) for a in node.names if a.name.split(".")[0] in PACKAGES]
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level \
                and node.module.split(".")[0] in PACKAGES:
            for a in node.names:
                full = f"{node.module}.{a.name}"
                out.append((full, None) if full in MODULES else (node.module, a.name))
    return out


def _target(module: str) -> str | None:
    """The project module an import names (a package's __init__ for a name taken from it)."""
    while module and module not in MODULES:
        module = module.rpartition(".")[0]
    return module or None


def test_package_roots_stay_small() -> None:
    def loose(pkg: str) -> list[str]:
        return sorted(p.name for p in (ROOT / pkg).glob("*.py"))
    assert len(loose("rdd")) <= 14, loose("rdd")
    assert len(loose("experiments")) <= 12, loose("experiments")


def test_no_module_over_400_lines() -> None:
    long = {str(p.relative_to(ROOT)): n for p in MODULES.values() if (n := len(p.read_text().splitlines())) > 400}
    assert not long


def test_imports_flow_one_way() -> None:
    back = [f"{m} imports {i}" for m, p in MODULES.items() for i, _ in _imports(p)
            if i.split(".")[0] != m.split(".")[0] and i.split(".")[0] not in LAYERS[m.split(".")[0]]]
    assert not back


def test_no_private_name_taken_from_another_module() -> None:
    taken = [f"{m} takes {src}.{name}" for m, p in MODULES.items() for src, name in _imports(p)
             if name and name.startswith("_") and not name.startswith("__") and _target(src) != m]
    assert not taken


def test_no_file_level_import_circle() -> None:
    graph = {m: {t for i, _ in _imports(p) if (t := _target(i)) and t != m} for m, p in MODULES.items()}
    # A package's face (__init__) hands names on; going through it is not a loop of the modules.
    faces = {m for m, p in MODULES.items() if p.name == "__init__.py"}
    graph = {m: {t for t in ts if t not in faces} for m, ts in graph.items()}
    seen: dict[str, int] = {}
    stack: list[str] = []
    circles = []

    def visit(m: str) -> None:
        seen[m] = 1
        stack.append(m)
        for t in sorted(graph.get(m, ())):
            if seen.get(t) == 1:
                circles.append(stack[stack.index(t):] + [t])
            elif t not in seen:
                visit(t)
        stack.pop()
        seen[m] = 2

    for m in sorted(graph):
        if m not in seen:
            visit(m)
    assert not circles, [" -> ".join(c) for c in circles]


@pytest.mark.parametrize("package", ["rdd.testing"])
def test_test_fixtures_are_not_imported_by_the_product(package: str) -> None:
    users = [m for m, p in MODULES.items() if not m.startswith(package)
             and any(i == package or i.startswith(package + ".") for i, _ in _imports(p, type_hints=True))]
    assert not users
