"""Measure the scripted experts: success rate, keyframe-rule agreement, the privileged labeler's
agreement with the expert's instructions, and demo length per task.

    python -m envs.check_expert --seeds 50 [--tasks a b] [--render] [--start 0] [--out table.md]

Without ``--render`` no images are drawn; rendering never touches the physics, so success and
keyframes are the same either way (a test checks this).
"""

from __future__ import annotations

import argparse
import time
from collections import Counter
from pathlib import Path

from rdd.atomic import write_text_atomic


def check_task(task: str, seeds, render: bool = False) -> dict:
    """Success count, keyframe-rule agreement count, labels equal to the expert's instructions
    (over the successful demos' segments) and frame counts over ``seeds``."""
    from envs.expert import run_expert
    from envs.labeler import PrivilegedLabeler
    from rdd.decomposers.expert import keypoint_discovery
    from rdd.segments import segments_to_keyframes

    ok = agree = segments = 0
    frames, failures, mismatches = [], [], Counter()
    labeler = PrivilegedLabeler()
    start = time.perf_counter()
    for seed in seeds:
        res = run_expert(task, seed, render=render)
        ep = res.episode
        ok += res.success
        agree += keypoint_discovery(ep.gripper_open, ep.joint_velocities) == segments_to_keyframes(ep.segments)
        frames.append(ep.num_frames)
        if not res.success:
            failures.append((seed, res.failure))
            continue
        ep.meta["privileged"] = res.privileged
        segments += len(ep.segments)
        labels = labeler.label_all(ep, ep.segments)
        mismatches.update(pair for pair in zip(ep.instructions, labels, strict=True) if pair[0] != pair[1])
    n = len(list(seeds))
    return {"task": task, "n": n, "success": ok, "keyframes_agree": agree, "min_frames": min(frames),
            "mean_frames": sum(frames) / n, "max_frames": max(frames), "failures": failures,
            "labels_equal": segments - mismatches.total(), "segments": segments, "label_mismatches": mismatches,
            "seconds": time.perf_counter() - start}


def main(argv=None) -> int:
    """CLI entry point: prints a Markdown table."""
    from envs.tasks import TASKS, task_names

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tasks", nargs="*", default=None)
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--start", type=int, default=0, help="first seed")
    ap.add_argument("--render", action="store_true")
    ap.add_argument("--out", default=None, help="also write the table to this file")
    args = ap.parse_args(argv)
    seeds = range(args.start, args.start + args.seeds)
    lines = ["| task | pretraining | success | keyframe rule = waypoints | label = instruction "
             "| frames min/mean/max | s/demo |", "|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    for task in args.tasks or task_names():
        r = check_task(task, seeds, args.render)
        line = (f"| {task} | {'yes' if TASKS[task].pretraining else 'no'} | {r['success']}/{r['n']} "
                f"({100 * r['success'] / r['n']:.0f}%) | {r['keyframes_agree']}/{r['n']} | "
                f"{r['labels_equal']}/{r['segments']} | "
                f"{r['min_frames']}/{r['mean_frames']:.0f}/{r['max_frames']} | {r['seconds'] / r['n']:.2f} |")
        lines.append(line)
        print(line + (f"  failures: {r['failures']}" if r["failures"] else ""), flush=True)
        for (said, label), count in sorted(r["label_mismatches"].items()):
            print(f"    {count} x expert '{said}', labeler '{label}'", flush=True)
    if args.out:
        write_text_atomic(Path(args.out), "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
