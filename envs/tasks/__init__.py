"""The tasks of the suite: name -> Task class, one module each, registered in ``rdd.registry`` as kind ``task``."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

from envs.tasks.base import Task
from rdd import registry

# A task is one module of this package whose Task subclass is registered as ``task`` NAME.
registry.define_kind("task", ("envs.tasks",), "envs.tasks.base:Task")
TASKS: dict[str, type[Task]] = dict(sorted(registry.entries("task").items(), key=lambda kv: (kv[1].order, kv[0])))


def get_task(name: str) -> Task:
    """A fresh instance of the task called ``name``."""
    if name not in TASKS:
        raise KeyError(f"unknown task {name!r}; known tasks: {sorted(TASKS)}")
    return TASKS[name]()


def task_names(pretraining: bool | None = None) -> list[str]:
    """Registered task names; ``pretraining`` True/False selects planner-pretraining/evaluation tasks."""
    return [n for n, c in TASKS.items() if pretraining is None or c.pretraining == pretraining]


def task_sources(name: str) -> list[str]:
    """Repository-relative files that define task ``name``: its module and the envs.tasks modules it imports.

    Cache keys hold these, so adding or editing one task leaves the other tasks' demos valid.
    """
    if name not in TASKS:
        raise KeyError(f"unknown task {name!r}; known tasks: {sorted(TASKS)}")
    here = Path(__file__).resolve().parent
    root = here.parents[1]
    todo = [Path(sys.modules[TASKS[name].__module__].__file__).resolve()]
    seen: set[Path] = set()
    while todo:
        f = todo.pop()
        if f in seen:
            continue
        seen.add(f)
        for node in ast.walk(ast.parse(f.read_text(), str(f))):
            mods = ([node.module] if isinstance(node, ast.ImportFrom) and node.module
                    else [a.name for a in node.names] if isinstance(node, ast.Import) else [])
            for m in mods:
                if m.startswith("envs.tasks.") and (here / f"{m.rsplit('.', 1)[1]}.py").is_file():
                    todo.append(here / f"{m.rsplit('.', 1)[1]}.py")
    # a task from outside the checkout (RDD_PLUGINS, docs/extending.md) is keyed by its absolute path
    return sorted(str(f.relative_to(root)) if root in f.parents else str(f) for f in seen)
