"""Measure the planner on the pybullet task suite (envs/): base vs LoRA-finetuned exact match.

    python -m planner.evaluate_suite --cache-dir DIR [--config conf/planner/tiny_llava.yaml]
        [--pretrain-episodes 20] [--demos 3] [--heldout 10] [--threads 1] [--workers 1]

Expert demonstrations are generated once into ``DIR/episodes`` (``envs.generate`` layout, resumable):
train-split episodes of the pretraining tasks, val-split demos and test-split held-out episodes of
the evaluation tasks (split seed ranges never overlap). The base is pretrained on the pretraining
tasks only; one LoRA adapter is finetuned on ``--demos`` expert-decomposed demos per evaluation task;
both are scored by exact match of the next instruction at every segment-start frame of the held-out
episodes, queried exactly as the harness queries the planner (image, goal, previous instruction).
Trained models are cached under ``DIR`` keyed by config and data, so a re-run only evaluates.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import torch

from planner.config import PlannerConfig, TrainSettings, digest
from planner.planner import Planner
from planner.train import finetune_lora, pretrain_base, training_examples


def suite_episodes(out: Path, tasks: list[str], split: str, n: int, workers: int,
                   image_size: int) -> list:
    """``n`` successful expert episodes per task of ``split`` (generated on first use, then cached)."""
    from envs.generate import episode_dir, generate
    from rdd.data.native import load_episode

    used = generate(tasks, split, n, out, workers=workers, image_size=image_size, progress=True)
    return [load_episode(episode_dir(out, split, t, s)) for t in tasks for s in used[t]]


def _table(rows: list[tuple[str, int, float, float]]) -> str:
    lines = [f"{'task':<30} {'boundaries':>10} {'base':>7} {'finetuned':>10}"]
    for task, n, b, f in rows:
        lines.append(f"{task:<30} {n:>10d} {100 * b:>6.1f}% {100 * f:>9.1f}%")
    return "\n".join(lines)


def run(cfg: PlannerConfig, cache_dir: Path, pretrain_episodes: int, demos: int, heldout: int,
        workers: int = 1, image_size: int = 128, progress: bool = True) -> dict:
    """Generate (cached), pretrain, finetune, evaluate; returns the measured figures."""
    from envs.tasks import task_names

    pre_tasks, eval_tasks = task_names(pretraining=True), task_names(pretraining=False)
    ep_dir = cache_dir / "episodes"
    pre = suite_episodes(ep_dir, pre_tasks, "train", pretrain_episodes, workers, image_size)
    demo = suite_episodes(ep_dir, eval_tasks, "val", demos, workers, image_size)
    test = suite_episodes(ep_dir, eval_tasks, "test", heldout, workers, image_size)

    # the tokenizer also sees the evaluation tasks' demo texts (as the harness passes its corpus):
    # words never seen at pretraining then still get whole-word tokens
    corpus = sorted({ep.goal for ep in demo} | {s for ep in demo for s in ep.instructions})
    base = pretrain_base(cfg, training_examples(pre, cfg.pretrain, cfg.view), cache_dir,
                         extra_corpus=corpus, progress=progress)
    adapter = finetune_lora(cfg, base, training_examples(demo, cfg.finetune, cfg.view), cache_dir,
                            progress=progress)
    test_ex = training_examples(test, TrainSettings(), cfg.view)  # segment starts only
    _, base_hit = Planner(cfg, base).hits(test_ex)
    tuned_pred, tuned_hit = Planner(cfg, base, adapter).hits(test_ex)

    rows, errors = [], []
    for task in eval_tasks:
        idx = [i for i, e in enumerate(test_ex) if e.task == task]
        hit_b = [base_hit[i] for i in idx]
        hit_f = [tuned_hit[i] for i in idx]
        rows.append((task, len(idx), sum(hit_b) / len(idx), sum(hit_f) / len(idx)))
        errors += [{"task": task, "episode": test_ex[i].episode, "frame": test_ex[i].frame,
                    "previous": test_ex[i].previous_instruction, "target": test_ex[i].target,
                    "finetuned": tuned_pred[i]} for i, h in zip(idx, hit_f, strict=True) if not h]
    n = len(test_ex)
    total_b = sum(r[1] * r[2] for r in rows) / n
    total_f = sum(r[1] * r[3] for r in rows) / n
    rows.append(("all evaluation tasks", n, total_b, total_f))
    ft_log = json.loads((Path(adapter) / "train_log.json").read_text())
    pre_log = json.loads((Path(base) / "train_log.json").read_text())
    return {"config": cfg.to_dict(), "pretrain_episodes_per_task": pretrain_episodes,
            "demos_per_task": demos, "heldout_episodes_per_task": heldout,
            "table": [{"task": t, "boundaries": k, "base": b, "finetuned": f} for t, k, b, f in rows],
            "base_exact_match": total_b, "finetuned_exact_match": total_f,
            "finetune_cpu_seconds": ft_log["cpu_seconds"], "finetune_wall_seconds": ft_log["wall_seconds"],
            "finetune_examples": ft_log["examples"], "finetune_steps": ft_log["steps"],
            "pretrain_cpu_seconds": pre_log["cpu_seconds"], "pretrain_examples": pre_log["examples"],
            "base_dir": str(base), "adapter_dir": str(adapter), "finetuned_errors": errors,
            "rows": rows}


def main(argv: list[str] | None = None) -> dict:
    """CLI entry point; prints the per-task table and writes the figures as JSON under the cache dir."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--config", default="conf/planner/tiny_llava.yaml", help="planner YAML")
    ap.add_argument("--cache-dir", required=True, help="episodes, models and results live here")
    ap.add_argument("--pretrain-episodes", type=int, default=20, help="train-split demos per pretraining task")
    ap.add_argument("--demos", type=int, default=3, help="val-split finetuning demos per evaluation task")
    ap.add_argument("--heldout", type=int, default=10, help="test-split episodes per evaluation task")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (the machine is shared)")
    ap.add_argument("--workers", type=int, default=1, help="episode generation processes")
    ap.add_argument("--image-size", type=int, default=128, help="rendered camera size")
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                    help="config overrides in OmegaConf dot-list form, e.g. finetune.epochs=30")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    from omegaconf import OmegaConf

    conf = OmegaConf.merge(OmegaConf.load(args.config), OmegaConf.from_dotlist(args.set))
    cfg = PlannerConfig.from_dict(OmegaConf.to_container(conf, resolve=True))
    cache = Path(args.cache_dir)
    res = run(cfg, cache, args.pretrain_episodes, args.demos, args.heldout, args.workers,
              args.image_size)
    print(_table(res.pop("rows")))
    print(f"finetuning: {res['finetune_examples']} examples, {res['finetune_steps']} steps, "
          f"{res['finetune_cpu_seconds']:.1f} s CPU ({res['finetune_wall_seconds']:.1f} s wall); "
          f"pretraining: {res['pretrain_examples']} examples, {res['pretrain_cpu_seconds']:.1f} s CPU")
    for e in res["finetuned_errors"][:20]:
        print(f"  miss {e['episode']}@{e['frame']}: after {e['previous']!r} expected "
              f"{e['target']!r}, got {e['finetuned']!r}")
    out = cache / f"results-{digest([res['config'], args.pretrain_episodes, args.demos, args.heldout])}.json"
    tmp = out.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(res, indent=2, default=str))
    os.replace(tmp, out)
    print(f"results: {out}")
    return res


if __name__ == "__main__":
    main()
