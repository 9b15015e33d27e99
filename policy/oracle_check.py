"""Oracle check: the keyframe policy driven by the expert's own sub-task instructions.

For every evaluation task and seed, the expert demonstration of that seed is recorded (without
images), its expert segments are labelled by the labeler, and those instructions are fed to the
policy in order on a fresh copy of the same scene, advancing when the policy's keyframe is
reached (or after ``--attempts`` failed motions). The success rate is the ceiling that the
planners are measured against.

    python -m policy.oracle_check --episodes 25 --train-episodes 20 --out outputs/oracle
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import json
import logging
import multiprocessing
import os
import pickle
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from experiments.labeler import PrivilegedLabeler
from policy.interface import KeyframeAction, Policy
from policy.keyframe import PolicyTrainConfig, train_or_load
from policy.training import TrainConfig
from rdd.data.episode import Episode

log = logging.getLogger("policy.oracle_check")

TRAIN_SEED0 = 0  # training episodes use seeds [0, n); evaluation seeds start far above
EVAL_SEED0 = 1_000_000


def _sim():
    try:
        from envs.control import Controller
        from envs.expert import build_task, run_expert
        from envs.tasks import task_names
    except ImportError as exc:  # pragma: no cover - depends on the installed extras
        raise ImportError("the oracle check needs the simulator: pip install -e '.[sim]'") from exc
    return Controller, build_task, run_expert, task_names


@functools.cache
def envs_fingerprint() -> str:
    """Hash of the simulator suite's source (tasks, experts, controller): keys the demo cache.

    Computed once per process (before any worker forks), so one run never mixes two versions.
    """
    import envs

    root = Path(envs.__file__).resolve().parent
    h = hashlib.sha256()
    for f in sorted(root.rglob("*.py")):
        h.update(str(f.relative_to(root)).encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:16]


def expert_episode(task: str, seed: int, cache_dir: Path | None) -> Episode:
    """The expert demonstration (no images) with its privileged record in ``meta``; cached
    under the suite's source hash, so demos from an older version of a task are never reused."""
    path = None if cache_dir is None else cache_dir / "expert" / envs_fingerprint() / f"{task}_{seed}.pkl"
    if path is not None and path.is_file():
        with open(path, "rb") as f:
            return pickle.load(f)
    _, _, run_expert, _ = _sim()
    res = run_expert(task, seed, render=False)
    ep = res.episode
    ep.meta["privileged"] = res.privileged
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        with os.fdopen(fd, "wb") as f:
            pickle.dump(ep, f)
        os.replace(tmp, path)
    return ep


def live_observation(scene, task) -> dict[str, Any]:
    """The policy observation of the running simulation (same keys as recorded frames)."""
    st = task.state()
    return {
        "ee_pose": scene.ee_pose(),
        "gripper_open": 1.0 if scene.gripper_open else 0.0,
        "object_positions": st["object_positions"],
        "object_quaternions": st["object_quaternions"],
        "articulation_states": st["articulation_states"],
        "held_object": int(st["held_object"]),
        "objects": [o.info.to_json() for o in task.objects],
        "articulations": [a.info.to_json() for a in task.articulations],
    }


def half_turn(action: KeyframeAction) -> KeyframeAction:
    """The same keyframe with the hand turned by pi about its approach (local z) axis."""
    x, y, z, w = action.quaternion
    # q * (0, 0, 1, 0) in xyzw
    return KeyframeAction(action.position, np.array([y, -x, w, -z]), action.gripper_open)


def rollout(policy: Policy, task_name: str, seed: int, instructions: Sequence[str],
            attempts: int = 2) -> dict[str, Any]:
    """Run ``instructions`` in order on (task, seed); returns success, steps and failures."""
    Controller, build_task, _, _ = _sim()
    scene, task = build_task(task_name, seed, render=False)
    try:
        ctrl = Controller(scene)
        policy.reset(task.goal())
        steps, failures = 0, []
        success = bool(task.success())
        for instr in instructions:
            if success:
                break
            for attempt in range(attempts):
                action = policy.act(live_observation(scene, task), instr)
                if attempt % 2 == 1:
                    # The parallel gripper is symmetric under a half turn about its approach
                    # axis; when a motion fails, try the equivalent orientation (as a motion
                    # planner would), since joint limits often allow only one of the two.
                    action = half_turn(action)
                res = ctrl.move(action.position, action.quaternion, action.gripper_open, task.graspable())
                steps += 1
                success = bool(task.success())
                if res.ok or success:
                    break
                failures.append(f"{res.failure}: {instr}")
        return {"task": task_name, "seed": int(seed), "success": success, "steps": steps,
                "failures": failures}
    finally:
        scene.close()


def run(args: argparse.Namespace) -> dict[str, Any]:
    """Train (or load) the policy, roll out the oracle, write ``oracle.json``; return it."""
    torch.set_num_threads(1)
    _, _, _, task_names = _sim()
    log.info("suite source hash %s", envs_fingerprint())
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cache = Path(args.cache)
    labeler = PrivilegedLabeler()
    all_tasks = task_names()
    eval_tasks = args.tasks or task_names(pretraining=False)
    t0 = time.perf_counter()
    jobs = [(t, TRAIN_SEED0 + s) for t in all_tasks for s in range(args.train_episodes)]
    jobs += [(t, EVAL_SEED0 + s) for t in eval_tasks for s in range(args.episodes)]
    _generate(jobs, cache, args.workers)
    train_eps = [expert_episode(t, TRAIN_SEED0 + s, cache) for t in all_tasks
                 for s in range(args.train_episodes)]
    gen_s = time.perf_counter() - t0
    cfg = PolicyTrainConfig(train=TrainConfig(epochs=args.epochs, max_seconds=args.max_train_seconds))
    t1 = time.perf_counter()
    policy = train_or_load(train_eps, labeler, cache, cfg)
    train_s = time.perf_counter() - t1
    log.info("policy ready (%.1f s; stats %s)", train_s,
             {k: v for k, v in policy.meta.get("stats", {}).items() if k != "loss_history"})
    records = []
    for task in eval_tasks:
        for s in range(args.episodes):
            seed = EVAL_SEED0 + s
            demo = expert_episode(task, seed, cache)
            instructions = labeler.label_all(demo, demo.segments)
            rec = rollout(policy, task, seed, instructions, attempts=args.attempts)
            rec["expert_success"] = bool(demo.meta.get("success"))
            rec["instructions"] = instructions
            records.append(rec)
            log.info("%s seed %d: %s", task, seed, "success" if rec["success"] else f"fail {rec['failures']}")
    per_task = {}
    for task in eval_tasks:
        rs = [r for r in records if r["task"] == task]
        per_task[task] = {"episodes": len(rs), "success_rate": float(np.mean([r["success"] for r in rs])),
                          "expert_success_rate": float(np.mean([r["expert_success"] for r in rs]))}
    result = {
        "per_task": per_task,
        "mean_success_rate": float(np.mean([v["success_rate"] for v in per_task.values()])),
        "episodes": records,
        "policy": {"checkpoint": str(policy.checkpoint), "train_episodes_per_task": args.train_episodes,
                   "train_seconds_this_run": train_s, "expert_generation_seconds": gen_s,
                   "stats": policy.meta.get("stats")},
    }
    fd, tmp = tempfile.mkstemp(dir=out, suffix=".tmp")
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        json.dump(result, f, indent=1)
    os.replace(tmp, out / "oracle.json")
    print(format_table(result))
    print(f"wrote {out / 'oracle.json'}")
    return result


def _cached_expert(job: tuple[str, int, str]) -> None:
    expert_episode(job[0], job[1], Path(job[2]))


def _generate(jobs: list[tuple[str, int]], cache: Path, workers: int) -> None:
    """Record (and cache) the expert demos of ``jobs`` with ``workers`` processes."""
    todo = [(t, s, str(cache)) for t, s in jobs]
    if workers <= 1:
        for job in todo:
            _cached_expert(job)
        return
    # fork: workers inherit the already imported suite, so they run the code that was hashed.
    with multiprocessing.get_context("fork").Pool(workers) as pool:
        for i, _ in enumerate(pool.imap_unordered(_cached_expert, todo, chunksize=4)):
            if (i + 1) % 50 == 0:
                log.info("expert demos ready: %d/%d", i + 1, len(todo))


def format_table(result: dict[str, Any]) -> str:
    """Markdown table of per-task oracle success."""
    lines = ["| task | oracle success | expert success | episodes |", "|---|---|---|---|"]
    for task, v in result["per_task"].items():
        lines.append(f"| {task} | {100 * v['success_rate']:.0f}% | {100 * v['expert_success_rate']:.0f}% | {v['episodes']} |")
    lines.append(f"| **mean** | **{100 * result['mean_success_rate']:.1f}%** | | |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """CLI entry point."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--episodes", type=int, default=25, help="evaluation episodes per task")
    p.add_argument("--train-episodes", type=int, default=20, help="expert training episodes per task")
    p.add_argument("--tasks", nargs="*", default=None, help="evaluation tasks (default: all non-pretraining)")
    p.add_argument("--epochs", type=int, default=TrainConfig.epochs)
    p.add_argument("--max-train-seconds", type=float, default=TrainConfig.max_seconds)
    p.add_argument("--attempts", type=int, default=2, help="tries per instruction after a failed motion")
    p.add_argument("--workers", type=int, default=2, help="processes recording expert demos")
    p.add_argument("--out", default="outputs/oracle_check")
    p.add_argument("--cache", default=".cache/policy")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    result = run(p.parse_args(argv))
    return 0 if result["mean_success_rate"] >= 0.8 else 1


if __name__ == "__main__":
    sys.exit(main())
