"""Rendering cost of one demonstration: 150 frames x 2 views (front + wrist) on one core.

    python benchmarks/bench_render.py [--task stack_blocks] [--frames 150] [--size 128]

Replays the first ``--frames`` frames of a recorded expert demo (arm and objects set from the
record) and times only ``Scene.render`` for both views. Prints seconds and the ratio to the
5-second budget.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
# The harness (envs/) is not installed: import it from this checkout.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main(argv=None) -> int:
    """Time the rendering of one demo."""
    from envs.expert import build_task, run_expert
    from envs.panda import ARM_JOINTS
    from envs.scene import CameraSpec

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--task", default="stack_blocks")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--size", type=int, default=128)
    args = ap.parse_args(argv)
    res = run_expert(args.task, args.seed, render=False)
    ep, priv = res.episode, res.privileged
    n = min(args.frames, ep.num_frames)
    scene, task = build_task(args.task, args.seed, camera=CameraSpec(args.size, args.size))
    try:
        total = cpu = 0.0
        for _rep in range((args.frames + n - 1) // n):
            for i in range(n):
                for j, q in zip(ARM_JOINTS, ep.joint_positions[i], strict=True):
                    scene.p.resetJointState(scene.robot, j, q)
                for k, o in enumerate(task.objects):
                    if o.link < 0:
                        scene.p.resetBasePositionAndOrientation(
                            o.body, priv["object_positions"][i, k], priv["object_quaternions"][i, k])
                t0, c0 = time.perf_counter(), time.process_time()
                views = scene.render()
                total += time.perf_counter() - t0
                cpu += time.process_time() - c0
                assert set(views) == {"front", "wrist"}
    finally:
        scene.close()
    frames = max(args.frames, n)
    # CPU time of this (single-threaded) process is the one-core cost even on a busy machine.
    print(f"task={args.task} frames={frames} views=2 size={args.size}: render CPU {cpu:.2f} s "
          f"({1000 * cpu / (2 * frames):.1f} ms/image), wall {total:.2f} s; "
          f"budget 5 s on one core -> CPU is {cpu / 5.0:.2f}x of budget")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
