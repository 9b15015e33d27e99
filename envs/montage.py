"""Montage PNG: first, middle and last frame of one expert demo per task, front and wrist views.

    python -m envs.montage --out montage.png [--tasks a b ...] [--seed 0] [--size 128]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from rdd.atomic import atomic_file


def task_montage(task_names, seed: int = 0, size: int = 128) -> np.ndarray:
    """One row per task: [front first, middle, last | wrist first, middle, last]."""
    from envs.expert import VIEWS, run_expert
    from envs.scene import CameraSpec

    rows = []
    for name in task_names:
        res = run_expert(name, seed, render=True, camera=CameraSpec(width=size, height=size))
        ep = res.episode
        idx = [0, ep.num_frames // 2, ep.num_frames - 1]
        tiles = []
        for view in VIEWS:
            tiles.extend(ep.frames(view, idx))
            tiles.append(np.full((size, 4, 3), 255, np.uint8))
        rows.append(np.concatenate(tiles[:-1], axis=1))
        print(f"{name}: {ep.goal!r} success={res.success} frames={ep.num_frames}", flush=True)
    sep = np.full((4, rows[0].shape[1], 3), 255, np.uint8)
    out = []
    for r in rows:
        out.extend([r, sep])
    return np.concatenate(out[:-1], axis=0)


def main(argv=None) -> int:
    """CLI entry point."""
    from PIL import Image

    from envs.tasks import task_names

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, help="PNG path to write")
    ap.add_argument("--tasks", nargs="*", default=None, help="task names (default: all)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--size", type=int, default=128, help="image side in pixels")
    args = ap.parse_args(argv)
    names = args.tasks or task_names()
    img = task_montage(names, args.seed, args.size)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_file(out) as fh:
        Image.fromarray(img).save(fh, format="PNG")
    print(f"wrote {out} ({img.shape[1]}x{img.shape[0]})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
