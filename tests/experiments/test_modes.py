"""The oracle planner and the planner-only evaluation run through the one pipeline at smoke scale."""

from __future__ import annotations

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

import experiments.config.schemas  # noqa: F401  (registers base_config)

pytest.importorskip("pybullet")
pytest.importorskip("peft")

CONF = Path(__file__).resolve().parents[2] / "conf"
# The smoke scale, shrunk further: a policy and planners that train in seconds.
FAST = ["experiment=smoke", "threads=1", "policy.train.min_steps=20", "policy.train.epochs=2"]
TINY_PLANNER = ["planner.pretrain.epochs=1", "planner.finetune.epochs=1",
                "planner.finetune.slot_swap_copies=0"]


def _run(overrides: list[str], cache: Path, out: Path) -> dict:
    from experiments.cache.store import read_json
    from experiments.run.pipeline import run

    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(config_name="config", overrides=[*FAST, *overrides, f"paths.cache_dir={cache}"])
    cfg_out = out
    cfg_out.mkdir(parents=True)
    from omegaconf import open_dict

    with open_dict(cfg):
        cfg.output_dir = str(out)
    summary = run(cfg)
    assert summary["status"] == "ok"
    return read_json(out / "results.json")


def _expert_plan(task: str, seed: int) -> list[str]:
    """The expert's labelled instructions, computed here from the simulator and labeler directly."""
    from envs.expert import run_expert
    from envs.labeler import PrivilegedLabeler
    from rdd.decomposers.expert import ExpertDecomposer

    res = run_expert(task, seed, render=False)
    res.episode.meta["privileged"] = res.privileged
    segments = ExpertDecomposer().decompose(res.episode).segments
    labeler = PrivilegedLabeler()
    return [labeler.label(res.episode, tuple(int(v) for v in s)) for s in segments]


def test_oracle_planner_plays_the_expert_plan(tmp_path: Path):
    data = _run(["planner=oracle", "eval.episodes_per_task=2"], tmp_path / "cache", tmp_path / "out")
    assert data["status"] == "ok"
    assert "decomposition" not in data  # nothing was decomposed, no planner trained
    assert not (tmp_path / "cache" / "planner_base").exists()
    assert len(data["episodes"]) == 2
    for ep in data["episodes"]:
        plan = _expert_plan(ep["task"], ep["seed"])
        # one expert instruction per step, in order; the last one repeats once the plan is played out
        want = [plan[min(i, len(plan) - 1)] for i in range(ep["steps"])]
        assert ep["instructions"] == want
    assert set(data["oracle"]["expert_success"]) == set(data["tasks"])
    # a rerun of the finished config does no work
    again = _run(["planner=oracle", "eval.episodes_per_task=2"], tmp_path / "cache", tmp_path / "again")
    assert all(t["cached"] for t in again["timings"].values()), again["timings"]
    assert again["episodes"] == data["episodes"]


def test_planner_eval_scores_every_held_out_boundary(tmp_path: Path):
    from rdd.data.native import load_episodes
    from rdd.decomposers.expert import ExpertDecomposer

    cache = tmp_path / "cache"
    data = _run(["mode=planner_eval", "decomposer=expert", "planner_eval.episodes_per_task=1",
                 *TINY_PLANNER], cache,
                tmp_path / "out")
    pe = data["planner_eval"]
    assert data["status"] == "ok" and data["mode"] == "planner_eval"
    assert not (cache / "policy").exists() and not (cache / "evaluation").exists()
    # every segment start of each held-out test-split episode is one scored query
    # demos are cached per task; the pretraining tasks' folders have no test split
    test_eps = [e for d in sorted((cache / "demos").iterdir()) if (d / "test").is_dir()
                for e in load_episodes(d / "test")]
    assert {e.task for e in test_eps} == set(data["tasks"]) == set(pe["per_task"])
    for task, row in pe["per_task"].items():
        want = sum(len(ExpertDecomposer().decompose(e).segments) for e in test_eps if e.task == task)
        assert row["boundaries"] == want
        assert 0.0 <= row["base"] <= 1.0 and 0.0 <= row["finetuned"] <= 1.0
    assert pe["boundaries"] == sum(r["boundaries"] for r in pe["per_task"].values())
    hits = [m for m in pe["misses"] if m["finetuned"] == m["target"]]
    assert not hits  # a miss is a real miss


def test_planner_eval_refuses_the_oracle(tmp_path: Path):
    with pytest.raises(ValueError, match="planner_eval"):
        _run(["mode=planner_eval", "planner=oracle"], tmp_path / "cache", tmp_path / "out")


def test_planner_eval_states_the_scenes_its_describer_says(tmp_path: Path):
    """planner.describer: another config's base, trained in a stage of its own, describes the scenes."""
    from experiments.cache.store import read_json
    from planner.config import PlannerConfig
    from planner.llava import TinyLlava
    from planner.planner import VLMPlanner
    from rdd.data.native import load_episodes

    cache = tmp_path / "cache"
    data = _run(["mode=planner_eval", "decomposer=expert", "planner_eval.episodes_per_task=1", *TINY_PLANNER,
                 "planner=tiny_llava_describe", "+planner@planner.describer=tiny_llava_describe",
                 "planner.describer.pretrain.epochs=2"], cache, tmp_path / "out")
    assert data["status"] == "ok"
    bases = {read_json(d / "spec.json")["planner"]["model"]["pretrain"]["epochs"]: d
             for d in (cache / "planner_base").iterdir() if not d.name.startswith(".")}
    assert sorted(bases) == [1, 2]  # the planner's own base and its describer's
    (finetune,) = [d for d in (cache / "planner_finetune").iterdir() if not d.name.startswith(".")]
    assert read_json(finetune / "spec.json")["describer"] == bases[2].name
    spec = read_json(bases[2] / "spec.json")["planner"]["model"]
    describer = VLMPlanner(PlannerConfig.from_dict(spec), bases[2])
    planner = TinyLlava(**{k: v for k, v in spec.items() if k != "kind"})
    rows = [r for d in (cache / "planner_eval").iterdir() if not d.name.startswith(".")
            for r in read_json(d / "boundaries.json")]
    test_eps = {e.name: e for d in (cache / "demos").iterdir() if (d / "test").is_dir()
                for e in load_episodes(d / "test")}
    examples = {(e.episode, e.frame): e for e in planner.examples(list(test_eps.values()))}
    said = describer.describe([examples[(r["episode"], r["frame"])].image for r in rows])
    assert rows and [r["scene"] for r in rows] == said
