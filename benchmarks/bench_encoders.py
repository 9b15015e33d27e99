"""Encoder throughput on 128x128 front+wrist frames, and the embedding cache's saving on a rerun.

    .venv/bin/python benchmarks/bench_encoders.py [--frames 16] [--threads 1] [--encoders a,b] [--out f.json]

Encoders whose official weights are not on this machine are built with random weights
(``random_weights=True``): their figure is the architecture's speed, labelled as such. Results
are printed (never asserted); ``--out`` also writes them as JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from rdd.atomic import write_text_atomic


def synthetic_episode(frames: int, size: int = 128, seed: int = 0):
    """An episode with smoothly varying front and wrist views (content does not affect speed)."""
    from rdd.data.episode import Episode

    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:size, 0:size] / size
    views = {}
    for v, view in enumerate(("front", "wrist")):
        imgs = []
        for t in range(frames):
            phase = t / max(frames - 1, 1) + v
            base = np.stack([np.sin(6 * xx + 3 * phase), np.cos(5 * yy - 2 * phase), np.sin(4 * (xx + yy) + phase)], -1)
            noise = rng.normal(0, 0.05, base.shape)
            imgs.append(np.clip((base + noise + 1) * 127.5, 0, 255).astype(np.uint8))
        views[view] = np.stack(imgs)
    return Episode(name=f"bench{seed}", views=views)


def build(name: str, threads: int):
    """The encoder, with real weights when available; returns (encoder, weights label)."""
    from rdd.encoders import load_encoder
    from rdd.encoders._checkpoint import MissingCheckpointError

    try:
        enc = load_encoder(name, num_threads=threads)
        return enc, ("pretrained" if getattr(enc, "has_weights", True) else "none (weight-free)")
    except MissingCheckpointError:
        return load_encoder(name, num_threads=threads, random_weights=True), "random (architecture speed)"


def bench_encoder(name: str, episode, threads: int) -> dict:
    """Frames per second of ``episode_frame_vectors`` over both views, after one warm-up batch."""
    from rdd.encoders.embed import episode_frame_vectors

    t0 = time.perf_counter()
    enc, weights = build(name, threads)
    build_s = time.perf_counter() - t0
    enc.encode(episode.frames("front", [0]))  # warm-up: first-call allocations and kernels
    t0 = time.perf_counter()
    vectors = episode_frame_vectors(episode, enc)
    dt = time.perf_counter() - t0
    n = 2 * episode.num_frames
    return {"encoder": name, "weights": weights, "dim": enc.dim, "frame_vector_dim": int(vectors.shape[1]),
            "images": n, "seconds": dt, "images_per_s": n / dt, "frames_per_s": episode.num_frames / dt,
            "build_s": build_s}


def bench_cache(name: str, episode, threads: int) -> dict:
    """Time of a cold run (encode + write) versus a rerun served from the on-disk cache."""
    from rdd.encoders.cache import EmbeddingCache
    from rdd.encoders.embed import episode_frame_vectors

    enc, weights = build(name, threads)
    enc.encode(episode.frames("front", [0]))
    with tempfile.TemporaryDirectory(prefix="rdd-bench-cache-") as root:
        cold_cache = EmbeddingCache(root)
        t0 = time.perf_counter()
        first = episode_frame_vectors(episode, enc, cache=cold_cache)
        cold = time.perf_counter() - t0
        warm_cache = EmbeddingCache(root)  # a fresh object: what a rerun in a new process sees
        t0 = time.perf_counter()
        second = episode_frame_vectors(episode, enc, cache=warm_cache)
        warm = time.perf_counter() - t0
    if not np.array_equal(first, second):
        raise RuntimeError("cached frame vectors differ from the computed ones")
    return {"encoder": name, "weights": weights, "cold_s": cold, "rerun_s": warm, "speedup": cold / warm,
            "saved_s": cold - warm, "cold_misses": cold_cache.stats.misses, "rerun_hits": warm_cache.stats.hits,
            "rerun_misses": warm_cache.stats.misses}


def main(argv: list[str] | None = None) -> dict:
    """Run the benchmark and print a table; returns the results."""
    import torch

    from rdd.encoders import available_encoders

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=16, help="frames per view (front and wrist are both encoded)")
    p.add_argument("--threads", type=int, default=1,
                   help="torch intra-op threads (1 avoids oversubscription on a shared machine)")
    p.add_argument("--encoders", default="", help="comma-separated names (default: all available)")
    p.add_argument("--cache-encoder", default="effnet_lite0", help="encoder used for the cache rerun figure")
    p.add_argument("--out", default="", help="also write the results to this JSON file")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    names = [n for n in args.encoders.split(",") if n] or available_encoders()
    episode = synthetic_episode(args.frames)
    rows = []
    for name in names:
        rows.append(bench_encoder(name, episode, args.threads))
        r = rows[-1]
        print(f"{name:13s} {r['weights']:28s} dim {r['dim']:5d}  {r['images_per_s']:8.1f} images/s "
              f"({r['frames_per_s']:7.1f} front+wrist frames/s)  build {r['build_s']:.1f}s", flush=True)
    cache = bench_cache(args.cache_encoder, episode, args.threads)
    print(f"cache ({cache['encoder']}): cold {cache['cold_s']:.3f}s, rerun {cache['rerun_s']:.4f}s, "
          f"speedup x{cache['speedup']:.0f}, saved {cache['saved_s']:.3f}s "
          f"(rerun hits {cache['rerun_hits']}, misses {cache['rerun_misses']})")
    result = {"frames_per_view": args.frames, "image_size": 128, "threads": args.threads,
              "cpu": platform.processor() or platform.machine(), "cpu_count": os.cpu_count(),
              "torch": torch.__version__, "load_average_1_5_15": list(os.getloadavg()),
              "encoders": rows, "cache": cache}
    print(f"load average (1, 5, 15 min) at the end: {os.getloadavg()}")
    if args.out:
        write_text_atomic(Path(args.out), json.dumps(result, indent=2))
    return result


if __name__ == "__main__":
    main()
