"""Does a pretrained base planner read the image? Its exact match on held-out demos of a task it was pretrained on.

    .venv/bin/python benchmarks/probe_base_sight.py --base .cache/rdd/planner_base/<key> \
        --task close_jar [--first-seed 20000] [--episodes 12] [--out f.json] [--captions K]

The base has seen the task's training demos, so the words are no obstacle: what it misses on fresh
scenes of the same task is what it cannot read from them. The segment starts of ``--episodes``
freshly recorded expert demos (test-range env seeds, labelled by the expert) are split as
``planner_eval`` splits them: *image-dependent* where another start with the same goal and previous
instruction has a different next instruction (only the image settles it), text-settled otherwise.
Figures are printed (never asserted); ``--out`` writes them and every miss as JSON.

``--captions K`` (a base pretrained with ``caption_frame_stride``) scores its scene captions
(``planner.captions``) of every K-th frame of the fresh demos instead, any task: the whole caption,
and its "X is on Y" facts alone (the set of them, which e.g. stack_blocks' plate / stack choice needs).
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
    from experiments.result_blocks import image_dependent
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
    parser.add_argument("--captions", type=int, default=0, metavar="K",
                        help="score scene captions of every K-th frame instead of planner steps")
    args = parser.parse_args(argv)
    config_file = args.base / CONFIG_FILE
    if not config_file.is_file():
        raise SystemExit(f"--base {args.base}: no {CONFIG_FILE} (not a planner_base stage folder)")
    cfg = PlannerConfig.from_dict(json.loads(config_file.read_text())["config"])
    episodes = []
    for seed in range(args.first_seed, args.first_seed + args.episodes):
        res = run_expert(args.task, seed, render=True)
        if res.success:
            res.episode.meta["privileged"] = res.privileged  # where load_episode puts it
            episodes.append(res.episode)
    if not episodes:
        raise SystemExit(f"--task {args.task}: the expert failed on every seed")
    if args.captions:
        return _captions(cfg, args, episodes)
    examples = [ex for ep in episodes for ex in examples_from_episode(ep, view=cfg.view)]
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


def _on_facts(caption: str) -> set[str]:
    return {p.strip() for p in caption.rstrip(".").split(". ") if " is on " in p}


def _captions(cfg, args, episodes) -> int:
    """Caption figures of the base on the fresh demos' frames (every ``--captions``-th)."""
    from planner.captions import caption_examples
    from planner.planner import Planner
    from planner.prompts import clean_output

    examples = caption_examples(episodes, args.captions, cfg.view)
    # the caption path describe_scene uses (its token limit included)
    preds = Planner(cfg, args.base).describe([e.image for e in examples])
    targets = [clean_output(e.target) for e in examples]
    hits = [p == t for p, t in zip(preds, targets, strict=True)]
    facts = [_on_facts(p) == _on_facts(t) for p, t in zip(preds, targets, strict=True)]
    figures = {"base": str(args.base), "task": args.task, "frames": len(examples),
               "caption_exact_match": float(np.mean(hits)), "on_facts_match": float(np.mean(facts))}
    print(json.dumps(figures, indent=2))
    if args.out:
        misses = [{"episode": e.episode, "frame": e.frame, "target": e.target, "said": p}
                  for e, p, f in zip(examples, preds, facts, strict=True) if not f]
        write_text_atomic(args.out, json.dumps({**figures, "misses": misses}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
