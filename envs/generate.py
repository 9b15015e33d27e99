"""Generate expert demonstrations into native episode directories.

    python -m envs.generate --tasks open_drawer stack_blocks --split train --episodes 10 --out DIR
                            [--workers 2] [--image-size 128] [--no-render]

Layout: ``DIR/<split>/<task>/<task>_seed<NNNNN>/`` (``rdd.data.native`` format, written
atomically). Seeds come from the split's range (``SPLIT_SEEDS``), which never overlap, and the
variation of seed s is ``s mod number_of_variations``. A seed whose expert fails is recorded in
``DIR/<split>/<task>/failed_seeds.json`` and replaced by the next seed of the range, so each task
gets N successful demonstrations, unless more than ``--max-failures`` new seeds fail for one task
(default ``2 * episodes + 10``): then generation stops with an error that names the task and its
commonest failures, since a task that fails that often is broken rather than unlucky. Re-running
resumes: finished episodes and known failures are skipped (and not counted again).
"""

from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from rdd.atomic import write_text_atomic

SPLIT_SEEDS: dict[str, range] = {
    "train": range(0, 10_000),
    "val": range(10_000, 20_000),
    "test": range(20_000, 30_000),
}


def split_of_seed(seed: int) -> str:
    """The split whose seed range holds ``seed``."""
    for name, r in SPLIT_SEEDS.items():
        if seed in r:
            return name
    raise ValueError(f"seed {seed} lies in no split range {SPLIT_SEEDS}")


def episode_dir(out: str | Path, split: str, task: str, seed: int) -> Path:
    """Directory of one generated episode."""
    return Path(out) / split / task / f"{task}_seed{seed:05d}"


def generate_one(task: str, seed: int, split: str, out: str, image_size: int, render: bool,
                 ticks_per_frame: int = 12, motion_timeout: float = 3.0) -> tuple[int, bool, str | None]:
    """Record and save one demonstration (saved only when the expert succeeds)."""
    import torch

    torch.set_num_threads(1)
    from envs.expert import run_expert
    from envs.scene import CameraSpec
    from rdd.data.native import save_episode

    res = run_expert(task, seed, render=render, split=split,
                     camera=CameraSpec(width=image_size, height=image_size),
                     ticks_per_frame=ticks_per_frame, motion_timeout=motion_timeout)
    if res.success:
        save_episode(res.episode, episode_dir(out, split, task, seed), privileged=res.privileged)
    return seed, res.success, res.failure


def _read_failed(path: Path) -> dict[str, str]:
    if not path.is_file():
        return {}
    try:
        return {str(k): str(v) for k, v in json.loads(path.read_text()).items()}
    except (json.JSONDecodeError, AttributeError) as exc:
        raise ValueError(f"{path}: not a JSON object of seed -> failure ({exc})") from exc


def _write_failed(path: Path, failed: dict[str, str]) -> None:
    write_text_atomic(path, json.dumps(failed, indent=1, sort_keys=True))


def default_max_failures(episodes: int) -> int:
    """New expert failures per task tolerated before generation gives up on the task."""
    return 2 * episodes + 10


def _too_many_failures(task: str, split: str, new: list[str], done: int, episodes: int,
                       path: Path) -> RuntimeError:
    from collections import Counter

    common = "; ".join(f"{n}x {why}" for why, n in Counter(new).most_common(3))
    return RuntimeError(f"{task}: the expert failed on {len(new)} new {split} seeds with only {done} of "
                        f"{episodes} demos made (commonest: {common}); every failure is in {path}. "
                        f"Raise --max-failures to keep trying.")


def generate(tasks, split: str, episodes: int, out: str | Path, workers: int = 1, image_size: int = 128,
             render: bool = True, progress: bool = True, max_failures: int | None = None,
             ticks_per_frame: int = 12, motion_timeout: float = 3.0) -> dict[str, list[int]]:
    """Make ``episodes`` successful demonstrations per task; returns the seeds used per task.

    ``ticks_per_frame`` and ``motion_timeout`` are the gym env's (``envs.gym_env``) of the same name.

    Gives up on a task (RuntimeError) once more than ``max_failures`` new seeds failed for it.
    """
    from tqdm import tqdm

    from envs.tasks import TASKS

    if split not in SPLIT_SEEDS:
        raise ValueError(f"--split must be one of {sorted(SPLIT_SEEDS)}, got {split!r}")
    unknown = [t for t in tasks if t not in TASKS]
    if unknown:
        raise ValueError(f"unknown tasks {unknown}; known: {sorted(TASKS)}")
    if episodes < 1:
        raise ValueError(f"--episodes must be positive, got {episodes}")
    from envs.gym_env import RLBenchStyleEnv

    # the env's own ranges for the physics and camera options it shares with demo generation
    RLBenchStyleEnv.check_options(image_size=image_size, render_images=render, ticks_per_frame=ticks_per_frame,
                                  motion_timeout=motion_timeout)
    if max_failures is None:
        max_failures = default_max_failures(episodes)
    if max_failures < 0:
        raise ValueError(f"--max-failures must be >= 0, got {max_failures}")
    seeds_range = SPLIT_SEEDS[split]
    used: dict[str, list[int]] = {}
    bar = tqdm(total=episodes * len(tasks), desc=f"{split} demos", disable=not progress, file=sys.stderr,
               leave=False)
    pool = ProcessPoolExecutor(max_workers=workers) if workers > 1 else None
    try:
        for task in tasks:
            task_dir = Path(out) / split / task
            task_dir.mkdir(parents=True, exist_ok=True)
            failed_path = task_dir / "failed_seeds.json"
            failed = _read_failed(failed_path)
            done: list[int] = []
            new_failures: list[str] = []
            it = iter(seeds_range)
            while len(done) < episodes:
                batch = []
                for seed in it:
                    if str(seed) in failed:
                        continue
                    if (episode_dir(out, split, task, seed) / "episode.json").is_file():
                        done.append(seed)
                        bar.update(1)
                        if len(done) >= episodes:
                            break
                        continue
                    batch.append(seed)
                    if len(done) + len(batch) >= episodes:
                        break
                if not batch:
                    if len(done) < episodes:
                        raise RuntimeError(f"{task}: split {split!r} ran out of seeds with {len(done)} demos")
                    break
                args = [(task, s, split, str(out), image_size, render, ticks_per_frame, motion_timeout)
                        for s in batch]
                results = pool.map(generate_one, *zip(*args, strict=True)) if pool else (generate_one(*a) for a in args)
                for seed, ok, failure in results:
                    if ok:
                        done.append(seed)
                        bar.update(1)
                    else:
                        failed[str(seed)] = str(failure or "success detector false")
                        _write_failed(failed_path, failed)
                        new_failures.append(failed[str(seed)])
                if len(new_failures) > max_failures:
                    raise _too_many_failures(task, split, new_failures, len(done), episodes,
                                             failed_path)
            used[task] = sorted(done)[:episodes]
    finally:
        bar.close()
        if pool is not None:
            pool.shutdown()
    return used


def main(argv=None) -> int:
    """CLI entry point."""
    from envs.tasks import task_names

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tasks", nargs="*", default=None, help="task names (default: all)")
    ap.add_argument("--split", required=True, choices=sorted(SPLIT_SEEDS))
    ap.add_argument("--episodes", type=int, required=True, help="successful demos per task")
    ap.add_argument("--out", required=True, help="output root directory")
    ap.add_argument("--workers", type=int, default=1, help="parallel worker processes")
    ap.add_argument("--image-size", type=int, default=128)
    ap.add_argument("--no-render", action="store_true", help="skip images (low-dim data only)")
    ap.add_argument("--ticks-per-frame", type=int, default=12, help="240 Hz physics ticks per frame")
    ap.add_argument("--motion-timeout", type=float, default=3.0,
                    help="seconds a keyframe motion may overrun before it fails")
    ap.add_argument("--max-failures", type=int, default=None,
                    help="new expert failures per task before giving up (default 2*episodes+10)")
    args = ap.parse_args(argv)
    used = generate(args.tasks or task_names(), args.split, args.episodes, args.out, args.workers,
                    args.image_size, not args.no_render, max_failures=args.max_failures,
                    ticks_per_frame=args.ticks_per_frame, motion_timeout=args.motion_timeout)
    for task, seeds in used.items():
        print(f"{task}: {len(seeds)} episodes, seeds {seeds[0]}..{seeds[-1]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
