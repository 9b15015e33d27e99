"""The suite evaluation runs end to end on the real pybullet tasks at a tiny size."""

import pytest

pytest.importorskip("pybullet")
pytest.importorskip("peft")


@pytest.mark.slow
def test_evaluate_suite_end_to_end(tmp_path, capsys):
    from envs.tasks import task_names
    from planner.evaluate_suite import main

    res = main(["--cache-dir", str(tmp_path), "--pretrain-episodes", "1", "--demos", "1",
                "--heldout", "1", "--image-size", "64",
                "--set", "pretrain.epochs=1", "finetune.epochs=1", "text_layers=1"])
    eval_tasks = task_names(pretraining=False)
    rows = {r["task"]: r for r in res["table"]}
    assert set(rows) == set(eval_tasks) | {"all evaluation tasks"}
    # one held-out episode per task: its boundaries are its expert segments
    from rdd.data.native import load_episodes

    test_eps = load_episodes(tmp_path / "episodes" / "test")
    assert {e.task for e in test_eps} == set(eval_tasks)
    for ep in test_eps:
        assert rows[ep.task]["boundaries"] == len(ep.segments)
    for r in res["table"]:
        assert 0.0 <= r["base"] <= 1.0 and 0.0 <= r["finetuned"] <= 1.0
    assert res["finetune_cpu_seconds"] > 0
    # pretraining never saw an evaluation task
    trained_on = {p.name for p in (tmp_path / "episodes" / "train").iterdir() if p.is_dir()}
    assert trained_on == set(task_names(pretraining=True))
    out = capsys.readouterr().out
    assert "all evaluation tasks" in out and "s CPU" in out
    assert list(tmp_path.glob("results-*.json"))
