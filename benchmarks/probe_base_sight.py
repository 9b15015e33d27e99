"""Does a pretrained base planner read the image? Its exact match on held-out demos of a task it was pretrained on.

    .venv/bin/python benchmarks/probe_base_sight.py --base .cache/rdd/planner_base/<key> \
        --task close_jar [--first-seed 20000] [--episodes 12] [--out f.json]

The base has seen the task's training demos, so the words are no obstacle: what it misses on fresh
scenes of the same task is what it cannot read from them. The segment starts of ``--episodes``
freshly recorded expert demos (test-range env seeds, labelled by the expert) are split as
``planner_eval`` splits them: *image-dependent* where another start with the same goal and previous
instruction has a different next instruction (only the image settles it), text-settled otherwise.
Figures are printed (never asserted); ``--out`` writes them and every miss as JSON.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from rdd.atomic import write_text_atomic


def main(argv: list[str] | None = None) -> int:
    """CLI entry point."""
    from envs.expert import run_expert
    from experiments.pipeline import image_dependent
    from planner.config import PlannerConfig
    from planner.dataset import examples_from_episode
    from planner.planner import Planner
    from planner.train import CONFIG_FILE

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--base", type=Path, required=True, help="a planner_base stage folder")
    parser.add_argument("--task", required=True, help="one of the base's pretraining tasks")
    parser.add_argument("--first-seed", type=int, default=20000, help="first env seed (test range)")
    parser.add_argument("--episodes", type=int, default=12)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    config_file = args.base / CONFIG_FILE
    if not config_file.is_file():
        raise SystemExit(f"--base {args.base}: no {CONFIG_FILE} (not a planner_base stage folder)")
    cfg = PlannerConfig.from_dict(json.loads(config_file.read_text())["config"])
    examples = []
    for seed in range(args.first_seed, args.first_seed + args.episodes):
        res = run_expert(args.task, seed, render=True)
        if res.success:
            examples += examples_from_episode(res.episode, view=cfg.view)
    if not examples:
        raise SystemExit(f"--task {args.task}: the expert failed on every seed")
    preds, hits = Planner(cfg, args.base).hits(examples)
    rows = [{"goal": e.goal, "previous": e.previous_instruction, "target": e.target, "task": e.task}
            for e in examples]
    dep = np.array(image_dependent(rows))
    hits = np.array(hits, dtype=bool)
    figures = {"base": str(args.base), "task": args.task, "boundaries": len(rows),
               "exact_match": float(hits.mean()),
               "image_dependent": {"boundaries": int(dep.sum()),
                                   "exact_match": float(hits[dep].mean()) if dep.any() else None},
               "text_settled": {"boundaries": int((~dep).sum()),
                                "exact_match": float(hits[~dep].mean()) if (~dep).any() else None}}
    print(json.dumps(figures, indent=2))
    if args.out:
        misses = [{**r, "said": p, "image_dependent": bool(d)}
                  for r, p, h, d in zip(rows, preds, hits, dep, strict=True) if not h]
        write_text_atomic(args.out, json.dumps({**figures, "misses": misses}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
