"""Stage code keys follow the imports of the code that builds each stage."""

import json
from pathlib import Path

import pytest

from experiments.cache.code_keys import (
    STAGE_BUILDERS,
    closure,
    code_key,
    stage_code_key,
    target_modules,
)
from experiments.cache.store import StageCache, spec_key


def _write(root: Path, files: dict[str, str]) -> None:
    for rel, text in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)


def _names(entries, root):
    closure.cache_clear()
    return [name for name, _ in closure(tuple(entries), root)]


def test_closure_follows_lazy_imports_and_only_this_repository(tmp_path: Path):
    _write(tmp_path, {
        "rdd/__init__.py": "from rdd import unused\n",
        "rdd/a.py": "import numpy\nfrom rdd import b\n\ndef f():\n    from rdd.c import g\n",
        "rdd/b.py": "from .c import g\n",
        "rdd/c.py": "def g():\n    pass\n",
        "rdd/unused.py": "x = 1\n",
    })
    assert _names(["rdd.a"], tmp_path) == ["rdd/a.py", "rdd/b.py", "rdd/c.py"]
    before = code_key(["rdd.a"], root=tmp_path)
    (tmp_path / "rdd/unused.py").write_text("x = 2\n")
    closure.cache_clear()
    assert code_key(["rdd.a"], root=tmp_path) == before
    (tmp_path / "rdd/c.py").write_text("def g():\n    return 1\n")  # reached only by lazy/relative imports
    closure.cache_clear()
    assert code_key(["rdd.a"], root=tmp_path) != before
    closure.cache_clear()


def test_the_facade_is_followed_per_function(tmp_path: Path):
    _write(tmp_path, {
        "experiments/run/components.py": (
            "FILE = 'x.json'\n\n"
            "def helper():\n    from rdd.b import x\n    return FILE\n\n"
            "def used():\n    return helper()\n\n"
            "def other():\n    from rdd.c import y\n"),
        "experiments/run/evaluation.py": "from experiments.run import components as comp\n\ndef run():\n    comp.used()\n",
        "rdd/b.py": "x = 1\n", "rdd/c.py": "y = 1\n",
    })
    assert _names(["experiments.run.evaluation"], tmp_path) == [
        "experiments/run/components.py:FILE", "experiments/run/components.py:helper",
        "experiments/run/components.py:used", "experiments/run/evaluation.py", "rdd/b.py"]
    assert _names(["other"], tmp_path) == ["experiments/run/components.py:other", "rdd/c.py"]
    with pytest.raises(ValueError, match="defines no 'missing'"):
        _names(["missing"], tmp_path)
    closure.cache_clear()


def test_task_modules_join_only_per_task_keys(tmp_path: Path):
    _write(tmp_path, {
        "envs/tasks/__init__.py": "from envs.tasks.base import Task\nfrom envs.tasks.drawer import Drawer\n",
        "envs/tasks/base.py": "class Task:\n    pass\n",
        "envs/tasks/drawer.py": "from envs.tasks.base import Task\n",
    })
    assert _names(["envs.tasks"], tmp_path) == ["envs/tasks/__init__.py", "envs/tasks/base.py"]
    plain = code_key(["envs.tasks"], root=tmp_path)
    assert code_key(["envs.tasks"], ["envs/tasks/drawer.py"], root=tmp_path) != plain
    closure.cache_clear()


def test_every_stage_of_the_repository_has_a_key_and_components_join_it(tmp_path: Path):
    pytest.importorskip("pybullet")
    from envs.tasks import task_sources

    for stage in STAGE_BUILDERS:  # every builder named exists
        assert len(stage_code_key(stage)) == 16
    # the demos never depend on the labeler; the labels stage does, through its _target_
    assert not any("labeler" in n for n, _ in closure(tuple(STAGE_BUILDERS["demos"])))
    spec = {"labeler": {"_target_": "envs.labeler.PrivilegedLabeler"}}
    assert target_modules(spec) == ["envs.labeler"]
    assert stage_code_key("expert_labels", spec=spec) != stage_code_key("expert_labels")
    keys = {t: stage_code_key("demos", tuple(task_sources(t))) for t in ("open_drawer", "push_buttons")}
    assert keys["open_drawer"] != keys["push_buttons"] != stage_code_key("demos")
    cache = StageCache(tmp_path)
    path, key = cache.get_or_build("planner_base", {"a": 1}, lambda d: None)
    recorded = json.loads((path / "spec.json").read_text())
    assert recorded["code"] == stage_code_key("planner_base")
    assert key == spec_key({"a": 1, "code": stage_code_key("planner_base")}) != spec_key({"a": 1})


def test_a_stage_s_code_key_is_computed_once_per_stage_and_components(tmp_path: Path, monkeypatch):
    """A stage looked up per episode hashes its sources once; ``uses`` adds a component's code to the key."""
    import experiments.cache.code_keys as code_keys

    real, calls = code_keys.stage_code_key, []
    monkeypatch.setattr(code_keys, "stage_code_key", lambda stage, *a, **k: calls.append(stage) or real(stage, *a, **k))
    cache = StageCache(tmp_path)
    labeler = {"_target_": "envs.labeler.PrivilegedLabeler"}
    for n in range(3):
        cache.get_or_build("expert_labels", {"episode": n, "labeler": labeler}, lambda d: None)
    assert calls == ["expert_labels"]
    path, _ = cache.get_or_build("planner_base", {"a": 1}, lambda d: None, uses=labeler)
    assert json.loads((path / "spec.json").read_text())["code"] == real("planner_base", modules=["envs.labeler"])
    assert real("planner_base", modules=["envs.labeler"]) != real("planner_base")
    assert calls == ["expert_labels", "planner_base"]


def test_each_task_keys_its_stages_by_its_own_module():
    pytest.importorskip("pybullet")
    from envs.tasks import task_sources

    # a task's module and the task modules it imports (the shared cabinet), never the registry
    assert task_sources("open_drawer") == ["envs/tasks/base.py", "envs/tasks/cabinet.py",
                                           "envs/tasks/open_drawer.py"]
    assert task_sources("push_buttons") == ["envs/tasks/base.py", "envs/tasks/push_buttons.py"]
    with pytest.raises(KeyError, match="unknown task"):
        task_sources("no_such_task")
