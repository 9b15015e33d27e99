"""The library's encoder beside the best plain-torch fp32 configuration of the same weights, in one run.

    .venv/bin/python benchmarks/bench_encode.py [--encoder effnet_lite0] [--frames 64] [--threads 2]
        [--rounds 2] [--out result.json]

Frames are real when ``$RDD_TEST_DATA`` holds the G1 LeRobot episodes (decoded as build-db does with
``max_side=224``) or the RLBench ones (docs/testing.md), else synthetic. Every configuration encodes
the same frames, preprocessing included; the rounds interleave the configurations so a busy machine
slows them alike, and each keeps its best round. Plain torch tries batch 8 and 32, contiguous and
channels-last; the library runs ``load_encoder(name).encode`` with its defaults (and, for
reference, ``runtime="torch"``). The cosine is per frame, library vs plain torch fp32 (contiguous).
Speed is printed, never asserted.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from rdd.atomic import write_text_atomic
from rdd.encoders import load_encoder
from rdd.encoders._onnx import per_frame_cosine

G1 = "lerobot/unitree_g1_pick_bottle"
RLBENCH = "rlbench/open_drawer/all_variations/episodes"


def synthetic_frames(n: int, h: int = 168, w: int = 224, seed: int = 0) -> np.ndarray:
    """Smoothly varying colour fields with noise (content does not change the speed)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w] / max(h, w)
    out = []
    for t in range(n):
        p = t / max(n - 1, 1)
        base = np.stack([np.sin(6 * xx + 3 * p), np.cos(5 * yy - 2 * p), np.sin(4 * (xx + yy) + p)], -1)
        out.append(np.clip((base + rng.normal(0, 0.05, base.shape) + 1) * 127.5, 0, 255).astype(np.uint8))
    return np.stack(out)


def real_frames(n: int) -> tuple[np.ndarray, str] | None:
    """``n`` frames from the shared real data, or None when ``$RDD_TEST_DATA`` has none."""
    from rdd.data.load import load_episodes

    root = os.environ.get("RDD_TEST_DATA")
    if not root:
        return None
    if (Path(root) / G1).is_dir():
        episodes = load_episodes("lerobot", Path(root) / G1, max_side=224, skip_missing=True)
        label = f"{G1} (max_side 224)"
    elif (Path(root) / RLBENCH).is_dir():
        episodes = load_episodes("rlbench", Path(root) / RLBENCH)
        label = RLBENCH
    else:
        return None
    frames, per_ep = [], max(1, -(-n // len(episodes)))
    for ep in episodes:
        view = sorted(ep.views)[0]
        frames.append(ep.frames(view, np.linspace(0, ep.num_frames - 1, per_ep).astype(int)))
    return np.concatenate(frames)[:n], f"{label}: {len(episodes)} episodes"


def plain_torch(name: str):
    """The same weights as the library's encoder, as a plain model plus its preprocessing in torch."""
    enc = load_encoder(name, runtime="torch")  # its encode is never called: the model stays as built
    preprocess = enc._preprocess
    if name.startswith("effnet_lite"):  # the library's is numpy; plain torch resizes in torch
        from rdd.encoders._effnet_lite import VARIANTS, make_torch_preprocess

        preprocess = make_torch_preprocess(VARIANTS[int(name[-1])].resolution)
    return enc.model, enc._forward, preprocess


def run_plain(model, forward, preprocess, frames: np.ndarray, batch: int, channels_last: bool) -> np.ndarray:
    """Embeddings of ``frames`` by plain torch fp32 in one memory format and batch size."""
    import torch

    fmt = torch.channels_last if channels_last else torch.contiguous_format
    model.to(memory_format=fmt)
    outs = []
    with torch.inference_mode():
        for s in range(0, len(frames), batch):
            x = preprocess(frames[s : s + batch]).contiguous(memory_format=fmt)
            outs.append(forward(x).reshape(x.shape[0], -1).numpy())
    return np.concatenate(outs)


def timed(fn) -> tuple[float, np.ndarray]:
    """Seconds ``fn()`` took, and what it returned."""
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def main(argv: list[str] | None = None) -> dict:
    """Run every configuration ``--rounds`` times, print the table; returns the figures."""
    import torch

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--encoder", default="effnet_lite0")
    p.add_argument("--frames", type=int, default=64)
    p.add_argument("--threads", type=int, default=2, help="intra-op threads for every configuration")
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument("--out", default="", help="also write the figures to this JSON file")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    real = real_frames(args.frames)
    frames, source = real if real is not None else (synthetic_frames(args.frames), "synthetic 224x168")
    print(f"{len(frames)} frames {frames.shape[1]}x{frames.shape[2]} from {source}; {args.threads} threads", flush=True)

    model, forward, preprocess = plain_torch(args.encoder)
    lib = load_encoder(args.encoder, num_threads=args.threads)
    lib_torch = load_encoder(args.encoder, num_threads=args.threads, runtime="torch")
    first_s, _ = timed(lambda: lib.encode(frames[:2]))  # export or cached-file load, session start
    lib_torch.encode(frames[:2])
    configs = {f"plain torch, batch {b}, {'channels-last' if cl else 'contiguous'}":
               (lambda b=b, cl=cl: run_plain(model, forward, preprocess, frames, b, cl))
               for b in (8, 32) for cl in (False, True)}
    configs[f"library {args.encoder} ({lib.active_runtime}, batch {lib.batch_size})"] = lambda: lib.encode(frames)
    configs[f"library {args.encoder} runtime=torch (batch {lib_torch.batch_size})"] = lambda: lib_torch.encode(frames)
    for fn in configs.values():
        fn()  # warm-up: first-call allocations and kernel choices
    best: dict[str, float] = {}
    outputs: dict[str, np.ndarray] = {}
    for _ in range(args.rounds):
        for label, fn in configs.items():
            dt, outputs[label] = timed(fn)
            best[label] = max(best.get(label, 0.0), len(frames) / dt)
    ref = outputs["plain torch, batch 8, contiguous"]
    lib_label = next(k for k in configs if k.startswith("library") and "runtime=torch" not in k)
    plain = {k: v for k, v in best.items() if k.startswith("plain")}
    best_plain = max(plain, key=plain.get)
    rows = []
    for label, ips in best.items():
        cos = float(per_frame_cosine(outputs[label], ref).min())
        rows.append({"config": label, "images_per_s": ips, "min_cosine_to_fp32_torch": cos})
        print(f"{label:52s} {ips:8.1f} images/s   min per-frame cosine to fp32 torch {cos:.9f}", flush=True)
    ratio = best[lib_label] / best[best_plain]
    lib_cos = float(per_frame_cosine(outputs[lib_label], ref).min())
    print(f"library / best plain torch ({best_plain}): {ratio:.2f}x; min cosine {lib_cos:.9f}; "
          f"library first call (export or load) {first_s:.1f}s; load average {os.getloadavg()}")
    result = {"encoder": args.encoder, "frames": len(frames), "source": source, "threads": args.threads,
              "rounds": args.rounds, "rows": rows, "best_plain_torch": best_plain, "ratio": ratio,
              "library_runtime": lib.active_runtime, "min_cosine": lib_cos, "first_call_s": first_s,
              "cpu": platform.processor() or platform.machine(), "cpu_count": os.cpu_count(),
              "torch": torch.__version__, "load_average_1_5_15": list(os.getloadavg())}
    if args.out:
        write_text_atomic(Path(args.out), json.dumps(result, indent=2))
    return result


if __name__ == "__main__":
    main()
