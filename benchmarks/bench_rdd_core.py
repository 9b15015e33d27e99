"""The RDD core's cost figures in one run: build-db, decomposition per backend and database size, OOD.

Runs, in one process and one after the other (so the machine state is the same for all):

1. ``bench_build_db``: encoder images and wall time of a cold build-db, every frame (before) vs
   boundary frames only (after), calibrated, and a cold UVD decomposition of the same episodes;
2. ``bench_decompose``: T=500 frames, L_max=100, 12,700 entries (1024-d frame vectors): pruned exact,
   dense exact, faiss flat and the paper's per-candidate Annoy loop (extrapolated from its first
   ``--naive-limit`` end frames); OOD mode vs default mode; then decomposition time at 12.7k, 100k
   and 1M entries (``--scale-embed-dim``-d frame vectors) per backend with recall@1 against exact.

Prints every figure and the ratios, and writes ``build_db.json``, ``results.json`` and ``summary.md``
under ``--out``. Example (RLBench episodes under ``$RDD_TEST_DATA``, docs/testing.md):

    python benchmarks/bench_rdd_core.py --data $RDD_TEST_DATA/rlbench/open_drawer/all_variations/episodes
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_build_db  # noqa: E402  (sibling script)
import bench_decompose  # noqa: E402

from rdd.atomic import write_text_atomic  # noqa: E402


def main(argv: list[str] | None = None) -> dict:
    """Run both benchmarks; print a summary and return their figures."""
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--data", default=None, help="episodes folder for the build-db part (skipped when absent)")
    p.add_argument("--format", default="rlbench")
    p.add_argument("--encoder", default="effnet_lite0")
    p.add_argument("--frames", default="500")
    p.add_argument("--max-len", default="100")
    p.add_argument("--entries", default="12700")
    p.add_argument("--embed-dim", default="1024")
    p.add_argument("--scale", default="12700,100000,1000000")
    p.add_argument("--approx-max-entries", default="100000")
    p.add_argument("--scale-embed-dim", default="256")
    p.add_argument("--scale-backends", default="exact,exact-dense,faiss-flat,faiss-ivf,faiss-hnsw,annoy")
    p.add_argument("--naive-limit", default="50")
    p.add_argument("--out", type=Path, default=Path("outputs/bench_rdd_core"))
    args = p.parse_args(argv)
    if args.data is not None and not Path(args.data).is_dir():
        # before any work: the build-db part runs first and would fail deep in the CLI with a traceback
        print(f"bench_rdd_core: --data {args.data}: no such folder", file=sys.stderr)
        sys.exit(2)
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    build = None
    if args.data:
        build = bench_build_db.main(["--data", args.data, "--format", args.format, "--encoder", args.encoder,
                                     "--out", str(args.out)])
    else:
        print("build-db part skipped (no --data)")
    dec = bench_decompose.main([
        "--frames", args.frames, "--max-len", args.max_len, "--entries", args.entries, "--embed-dim", args.embed_dim,
        "--backends", "exact,exact-dense,faiss-flat", "--naive-limit", args.naive_limit, "--scaling", "",
        "--approx-max-entries", args.approx_max_entries,
        "--ood", "--scale", args.scale, "--scale-embed-dim", args.scale_embed_dim,
        "--scale-backends", args.scale_backends, "--out", str(args.out),
    ])
    md = _summary(build, dec, time.perf_counter() - t0)
    write_text_atomic(args.out / "summary.md", md)
    print("\n" + md)
    return {"build_db": build, "decompose": dec}


def _summary(build: dict | None, dec: dict, seconds: float) -> str:
    lines = [f"# RDD core benchmark ({os.cpu_count()} cores, {seconds / 60:.1f} min)", ""]
    if build:
        lines += ["| build-db | encoder images | s |", "|---|---:|---:|"]
        lines += [f"| {k} | {v['images']} | {v['seconds']:.1f} |" for k, v in build["rows"].items()]
        r = build["ratios"]
        lines += ["", f"before/after --no-calibrate: {r['images_before_over_after']:.1f}x fewer images, "
                      f"{r['time_before_over_after']:.1f}x faster; cold UVD decomposition / build: "
                      f"{r['uvd_time_over_build_no_calibrate']:.1f}x", ""]
    b = dec["backends"]
    lines += [f"T={dec['setting']['frames']}, {dec['setting']['entries']} entries, {dec['frame_dim']}-d frames:",
              "", "| backend | decompose s | searched share |", "|---|---:|---:|"]
    lines += [f"| {k} | {v['decompose_s']:.3f} | {v['searched_fraction'] if v['searched_fraction'] is not None else '-'} |"
              for k, v in b.items()]
    if "naive_annoy_loop" in dec:
        lines += [f"| paper's per-candidate Annoy loop | {dec['naive_annoy_loop']['wall_s']:.1f} | |"]
    o = dec.get("ood_vs_default")
    if o:
        lines += ["", f"OOD {o['ood_s']:.3f} s vs default {o['default_s']:.3f} s: {o['ratio']:.2f}x"]
    if dec.get("scale"):
        lines += ["", "| entries | d | backend | decompose s | index build s | recall@1 | same partition |",
                  "|---:|---:|---|---:|---:|---:|---|"]
        lines += [f"| {r['entries']} | {r['frame_dim']} | {r['backend']} | {r['decompose_s']:.2f} | {r['build_s']:.1f} "
                  f"| {r.get('recall_at_1', float('nan')):.4f} | {r.get('same_partition_as_exact', '-')} |"
                  for r in dec["scale"]]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(0 if main() else 1)
