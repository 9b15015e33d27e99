"""Measure the planner on the rendered synthetic world: base vs LoRA-finetuned exact match.

    python -m planner.evaluate_synthetic --pretrain-episodes 60 --demos 3 --heldout 20

Pretrains a base on the pretraining tasks only, finetunes it with LoRA on ``--demos`` expert
demonstrations per evaluation task, and reports exact match of both at the segment-start frames of
held-out evaluation episodes (seeds disjoint from the demonstrations).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from planner.config import PlannerConfig, TrainSettings
from planner.planner import Planner
from planner.synthetic import EVAL_TASKS, PRETRAIN_TASKS, make_episodes
from planner.train import finetune_lora, pretrain_base, training_examples


def run(cfg: PlannerConfig, cache_dir: Path, pretrain_episodes: int, demos: int, heldout: int,
        progress: bool = True) -> dict:
    """Pretrain, finetune, evaluate; returns the measured figures."""
    pre = make_episodes(PRETRAIN_TASKS, range(pretrain_episodes), image_size=cfg.image_size)
    demo = make_episodes(EVAL_TASKS, range(10_000, 10_000 + demos), image_size=cfg.image_size)
    test = make_episodes(EVAL_TASKS, range(20_000, 20_000 + heldout), image_size=cfg.image_size)
    pre_test = make_episodes(PRETRAIN_TASKS, range(30_000, 30_000 + heldout // 2),
                             image_size=cfg.image_size)
    t0 = time.process_time()
    base = pretrain_base(cfg, training_examples(pre, cfg.pretrain, cfg.view), Path(cache_dir) / "base",
                         progress=progress)
    t1 = time.process_time()
    adapter = finetune_lora(cfg, base, training_examples(demo, cfg.finetune, cfg.view),
                            Path(cache_dir) / "lora", progress=progress)
    t2 = time.process_time()
    test_ex = training_examples(test, TrainSettings(), cfg.view)
    pre_ex = training_examples(pre_test, TrainSettings(), cfg.view)
    base_planner = Planner(cfg, base)
    _, base_hit = base_planner.hits(test_ex)
    _, tuned_hit = Planner(cfg, base, adapter).hits(test_ex)

    def rate(hit: list[bool], task: str | None = None) -> float:
        picked = [h for h, e in zip(hit, test_ex, strict=True) if task is None or e.task == task]
        if not picked:
            raise ValueError(f"no held-out examples{'' if task is None else f' of {task}'} to score")
        return float(np.mean(picked))

    out = {
        "kind": cfg.kind, "pretrain_episodes_per_task": pretrain_episodes, "demos_per_task": demos,
        "heldout_episodes_per_task": heldout, "heldout_examples": len(test_ex),
        "base_exact_match_eval_tasks": rate(base_hit),
        "finetuned_exact_match_eval_tasks": rate(tuned_hit),
        "base_exact_match_pretrain_tasks_heldout": base_planner.exact_match(pre_ex),
        "per_task_finetuned": {t: rate(tuned_hit, t) for t in EVAL_TASKS},
        "per_task_base": {t: rate(base_hit, t) for t in EVAL_TASKS},
        "pretrain_cpu_seconds_this_call": t1 - t0, "finetune_cpu_seconds_this_call": t2 - t1,
        "base_dir": str(base), "adapter_dir": str(adapter),
        "finetune_log": json.loads((Path(adapter) / "train_log.json").read_text()),
        "pretrain_log": json.loads((Path(base) / "train_log.json").read_text()),
    }
    return out


def main(argv: list[str] | None = None) -> dict:
    """CLI entry point; prints the figures as JSON."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--config", default="conf/planner/tiny_llava.yaml", help="planner YAML")
    ap.add_argument("--cache-dir", default="outputs/planner_cache")
    ap.add_argument("--pretrain-episodes", type=int, default=60)
    ap.add_argument("--demos", type=int, default=3)
    ap.add_argument("--heldout", type=int, default=20)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    cfg = instantiate(OmegaConf.load(args.config)).config  # the config's _target_ fixes the model
    res = run(cfg, Path(args.cache_dir), args.pretrain_episodes, args.demos, args.heldout)
    print(json.dumps({k: v for k, v in res.items() if not k.endswith("_log")}, indent=2))
    print("finetune log:", json.dumps(res["finetune_log"]))
    return res


if __name__ == "__main__":
    main()
