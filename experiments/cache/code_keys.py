"""Stage code keys derived from the imports of the code that builds each stage.

A stage's key holds a fingerprint of the source that makes it: the functions of
``experiments.run.components`` its build calls (``STAGE_BUILDERS``), the modules of the components its
spec names by ``_target_``, and everything of this repository those import, followed through
``import`` statements (lazy ones inside functions too). A module that only reaches a stage through
an upstream stage is covered by that stage's key, which the downstream spec contains.

Two boundaries keep keys as narrow as the code: ``experiments.run.components`` is followed per function
(a stage depends on the calls it makes, not on the whole facade), and the task modules of
``envs.tasks`` join only the keys of the stages made per task (``envs.tasks.task_sources``), so
editing one task keeps the other tasks' demos, policy and evaluations.
"""

from __future__ import annotations

import ast
import functools
import hashlib
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

REPO_ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("rdd", "envs", "policy", "planner", "experiments")
FACADE = "experiments.run.components"
TASK_PREFIX = "envs.tasks."
SHARED_TASK_MODULES = frozenset({"envs.tasks.base"})

# The functions of the facade each stage's build calls (``module:function`` entries) and any module
# it calls directly. Components named by ``_target_`` in a stage's spec join it on their own.
STAGE_BUILDERS: dict[str, tuple[str, ...]] = {
    "demos": ("episodes_for", "rdd.data.native"),
    "expert_labels": ("expert_segments",),
    "oracle_plans": ("expert_plan", "expert_segments"),
    "policy": ("train_policy",),
    "database_part": ("build_database",),
    "database": ("merge_databases",),
    "calibration": ("calibrate_database",),
    "decompositions": ("rdd.metrics",),
    "planner_base": ("pretrain_planner",),
    "planner_finetune": ("finetune_planner",),
    "evaluation": ("experiments.run.evaluation", "make_env", "load_policy", "load_planner"),
    "planner_eval": ("load_planner",),
}


def module_file(name: str, root: Path = REPO_ROOT) -> Path | None:
    """The source file of repository module ``name`` (None for a third-party or unknown module)."""
    parts = name.split(".")
    if parts[0] not in PACKAGES:
        return None
    base = root.joinpath(*parts)
    if (base / "__init__.py").is_file():
        return base / "__init__.py"
    return base.with_suffix(".py") if base.with_suffix(".py").is_file() else None


def _tree(path: Path) -> ast.Module:
    return _parse(str(path), path.read_text())


@functools.cache
def _parse(name: str, text: str) -> ast.Module:
    return ast.parse(text, name)


def _entry(name: str) -> str:
    """``name`` as an entry: a bare function name is the facade's ``module:function``."""
    return name if "." in name or ":" in name else f"{FACADE}:{name}"


def _imports(node: ast.AST, module: str, root: Path) -> Iterator[str]:
    """Entries ``node`` imports: modules, and ``FACADE:function`` for each facade call it makes."""
    path = module_file(module, root)
    package = module if path is not None and path.name == "__init__.py" else module.rpartition(".")[0]
    facade_aliases = set()
    for n in ast.walk(node):
        if isinstance(n, ast.Import):
            for a in n.names:
                yield a.name
                if a.name == FACADE and a.asname:
                    facade_aliases.add(a.asname)
        elif isinstance(n, ast.ImportFrom):
            base = n.module or ""
            if n.level:
                anchor = package.split(".")[: len(package.split(".")) - (n.level - 1)]
                base = ".".join([*anchor, base] if base else anchor)
            for a in n.names:
                full = f"{base}.{a.name}"
                if full == FACADE:
                    facade_aliases.add(a.asname or a.name)
                elif base == FACADE:
                    yield f"{FACADE}:{a.name}"
                    continue
                yield full if module_file(full, root) else base
    for n in ast.walk(node):
        if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name) and n.value.id in facade_aliases:
            yield f"{FACADE}:{n.attr}"


def _definition(tree: ast.Module, name: str) -> ast.stmt | None:
    """The module-level function, class or assignment that defines ``name``."""
    for n in tree.body:
        if isinstance(n, ast.FunctionDef | ast.ClassDef) and n.name == name:
            return n
        targets = n.targets if isinstance(n, ast.Assign) else [n.target] if isinstance(n, ast.AnnAssign) else []
        if any(isinstance(t, ast.Name) and t.id == name for t in targets):
            return n
    return None


@functools.cache
def closure(entries: tuple[str, ...], root: Path = REPO_ROOT) -> tuple[tuple[str, bytes], ...]:
    """The sources ``entries`` reach through imports: ``(name, source bytes)`` sorted by name.

    A module entry contributes its whole file; a ``module:function`` entry that function's source.
    A package's ``__init__.py`` counts only where the package itself is imported.
    """
    todo = [_entry(e) for e in entries]
    seen: set[str] = set()
    out: dict[str, bytes] = {}
    while todo:
        entry = todo.pop()
        if entry in seen:
            continue
        seen.add(entry)
        module, _, func = entry.partition(":")
        if module.startswith(TASK_PREFIX) and module not in SHARED_TASK_MODULES:
            continue  # a task module joins per-task keys only
        path = module_file(module, root)
        if path is None:
            continue
        rel = str(path.relative_to(root))
        if module == FACADE and not func:
            continue  # the facade is followed per function
        if func:
            tree = _tree(path)
            node = _definition(tree, func)
            if node is None:
                raise ValueError(f"stage code: {module} defines no {func!r} (experiments.cache.code_keys)")
            out[f"{rel}:{func}"] = (ast.get_source_segment(path.read_text(), node) or "").encode()
            # the facade's own helpers and constants that this definition uses
            todo.extend(f"{module}:{n.id}" for n in ast.walk(node)
                        if isinstance(n, ast.Name) and n.id != func and _definition(tree, n.id))
        else:
            node = _tree(path)
            out[rel] = path.read_bytes()
        todo.extend(_imports(node, module, root))
    return tuple(sorted(out.items()))


def target_modules(spec: Any) -> list[str]:
    """Modules of the ``_target_`` callables named anywhere in ``spec`` (nested dicts and lists)."""
    found: list[str] = []
    if isinstance(spec, dict):
        target = spec.get("_target_")
        if isinstance(target, str):
            module = target
            while module and module_file(module) is None:
                module = module.rpartition(".")[0]
            if module:
                found.append(module)
        for value in spec.values():
            found += target_modules(value)
    elif isinstance(spec, list | tuple):
        for value in spec:
            found += target_modules(value)
    return found


def code_key(entries: Iterable[str], files: Iterable[str] = (), root: Path = REPO_ROOT) -> str:
    """SHA-256 (16 hex digits) of the sources ``entries`` reach and of the repository ``files``."""
    h = hashlib.sha256()
    for name, source in closure(tuple(sorted(set(entries))), root):
        h.update(name.encode() + b"\0" + source + b"\0")
    for rel in sorted(set(files)):
        path = root / rel
        if not path.is_file():
            raise FileNotFoundError(f"stage code file {rel!r} is not in {root}")
        h.update(rel.encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()[:16]


def stage_code_key(stage: str, files: Iterable[str] = (), spec: Any = None,
                   modules: Iterable[str] = ()) -> str | None:
    """Fingerprint of the code that makes ``stage``: its builders, the ``_target_`` components of
    ``spec``, ``modules`` and ``files`` (e.g. one task's modules); None for a stage without builders."""
    builders = STAGE_BUILDERS.get(stage)
    if builders is None:
        return None
    return code_key([*builders, *target_modules(spec), *modules], files)


class StageCodes:
    """The code fingerprints of one stage cache's stages, each computed once per stage, task files and
    components: a stage looked up once per episode or task would otherwise hash its sources each time."""

    def __init__(self) -> None:
        self._known: dict[tuple[str, tuple[str, ...], tuple[str, ...]], str | None] = {}

    def key(self, stage: str, files: Iterable[str] = (), spec: Any = None, uses: Any = None) -> str | None:
        """:func:`stage_code_key` of ``stage`` and ``files`` with the modules of the ``_target_``
        components that ``spec`` names and that ``uses`` names (components the stage runs that its
        spec does not hold)."""
        files = tuple(files)
        modules = (*target_modules(spec), *target_modules(uses))
        known = (stage, tuple(sorted(set(files))), tuple(sorted(set(modules))))
        if known not in self._known:
            self._known[known] = stage_code_key(stage, files, modules=modules)
        return self._known[known]
