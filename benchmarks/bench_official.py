"""The official RDD pipeline (tasl-lab/RDD, a local checkout) beside ours on the same inputs, per stage.

    RDD_OFFICIAL_DIR=/path/to/RDD .venv/bin/python benchmarks/bench_official.py [--data EPISODES]
        [--query episode0] [--rounds 3]

Without ``$RDD_OFFICIAL_DIR`` it says so and exits 0. The checkout is only read, by a separate
process (both projects' packages are named ``rdd``), never copied here. Inputs: a database built by
``build-db`` from every RLBench episode but ``--query`` (effnet_lite0, front + wrist), and that
episode, decomposed with the paper's settings (alpha 1, min_len 2, no max_len, default mode, beta 0).

What of the official runs here, unmodified: its DP (``rdd/algorithms.py``: ``max_sum_partition`` with
``rdd_score``) over its Annoy searcher (``rdd/ann.py``: ``AnnoySearcher``, 10 trees, angular), fed
our database's entry vectors and our frame vectors, so that segments compare on equal inputs; the
searcher returns entries as its ``RLBenchAnnoySearcher.query`` does (``duration`` = last minus first
frame). What cannot run here: its encoding, ``uvd_embed``, goes through UVD (zcczhang/UVD), whose
preprocessors need torchvision, which is never installed on this machine (it pulls CUDA torch or
fails at import); its SQL vector database needs sqlmodel. Its encoding stage is therefore timed as
``uvd_embed`` runs a preprocessor: plain torch fp32, the same EfficientNet-Lite0 weights, torch
preprocessing, each view's frames in one batch. ``uvd``, ``cv2`` and ``imageio`` (imported by its
modules, unused on this path) are stubs that raise if called; ``loguru`` is stubbed when absent.
Stages are medians of ``--rounds``, in turn; ratios are official / ours.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
DATA = Path(os.environ.get("RDD_TEST_DATA", "/work/shared/data")) / "rlbench/open_drawer/all_variations/episodes"
RAISE = "def {0}(*a, **k):\n    raise RuntimeError('UVD is not installed here')\n"
STUBS = {
    "uvd/__init__.py": "from . import decomp, models, utils\n",
    "uvd/utils.py": "",
    "uvd/decomp/__init__.py": RAISE.format("decomp_trajectories"),
    "uvd/decomp/kernel_reg.py": "class KernelRegression:\n    pass\n",
    "uvd/models.py": "class Preprocessor:\n    pass\n" + RAISE.format("get_preprocessor"),
    "cv2.py": "", "imageio.py": "",
}
LOGURU = "import logging\nlogger = logging.getLogger('official')\n"
# Run with the checkout first on the path: times loading its index (the Annoy file its server opens
# for every request) and its DP, prints JSON.
OFFICIAL = """
import json, sys, time, numpy as np
from rdd.ann import AnnoySearcher
from rdd.algorithms import max_sum_partition, rdd_score
d = np.load(sys.argv[1]); fv, begin, end, dur = d["fv"], d["begin"], d["end"], d["durations"]
path = sys.argv[2]
if not __import__("os").path.exists(path):  # built once, as build_vec_database.py saves it
    s = AnnoySearcher(begin.shape[1] * 2, path, n_trees=10)
    for i in range(len(begin)): s.add(np.concatenate([begin[i], end[i]]), i)
    s.save()
class Entry:
    def __init__(self, duration): self.duration = int(duration)
class Searcher:  # RLBenchAnnoySearcher.query without its SQL rows: per-view entries of the hit
    def __init__(self, path, dim): self.ann = AnnoySearcher(dim, path)
    def query(self, x, num_neighbors=1):
        idx, dist = self.ann.query(x, num_neighbors)
        return [[Entry(dur[i])] for i in idx.tolist()], dist.tolist()
t0 = time.perf_counter(); searcher = Searcher(path, begin.shape[1] * 2); t1 = time.perf_counter()
_, parts = max_sum_partition(list(range(len(fv))), rdd_score, min_len=2, max_len=None, alpha=1.0, beta=0.0,
                             searcher=searcher, embeds=fv, nn_list={}, mode="default", uvd_cache={})
t2 = time.perf_counter()
print(json.dumps({"load": t1 - t0, "dp": t2 - t1, "segments": [[p[0], p[-1] + 1] for p in parts]}))
"""


def official_env(official: Path, stubs: Path) -> dict[str, str]:
    """The environment of the official process: its checkout, then the stubs; none of this project."""
    import importlib.util

    for rel, text in STUBS.items():
        (stubs / rel).parent.mkdir(parents=True, exist_ok=True)
        (stubs / rel).write_text(text)
    if importlib.util.find_spec("loguru") is None:
        (stubs / "loguru.py").write_text(LOGURU)
    return {**os.environ, "PYTHONPATH": f"{official}{os.pathsep}{stubs}"}


def plain_torch_encode(episode, views) -> float:
    """Seconds to embed ``views`` of ``episode`` as ``uvd_embed`` would: torch fp32, a view at a time."""
    import torch

    from rdd.encoders import load_encoder
    from rdd.encoders._effnet_lite import VARIANTS, make_torch_preprocess

    model = load_encoder("effnet_lite0", runtime="torch").model.eval()
    pre = make_torch_preprocess(VARIANTS[0].resolution)
    t0 = time.perf_counter()
    with torch.inference_mode():
        for view in views:
            model.extract_features(pre(episode.frames(view, None))).mean(dim=(2, 3))
    return time.perf_counter() - t0


def main() -> None:
    """Build the inputs, time both pipelines' stages in turn, print the table."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA, help="RLBench episodes folder")
    ap.add_argument("--query", default="episode5", help="the episode decomposed (open_drawer's episode5: 96 frames)")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    official = os.environ.get("RDD_OFFICIAL_DIR")
    if not official:
        print("skipped: set RDD_OFFICIAL_DIR to a local checkout of https://github.com/tasl-lab/RDD")
        return
    official_dir = Path(official).expanduser().resolve()
    if not (official_dir / "rdd" / "algorithms.py").is_file():
        sys.exit(f"error: RDD_OFFICIAL_DIR={official}: no rdd/algorithms.py there (not a tasl-lab/RDD checkout)")
    from rdd.data.load import load_episodes
    from rdd.database.model import SubtaskDatabase
    from rdd.decomposers.rdd import RDDDecomposer
    from rdd.encoders import load_encoder
    from rdd.encoders.embed import episode_frame_vectors

    views = ("front", "wrist")
    with tempfile.TemporaryDirectory(prefix="rdd-official-") as tmp:
        work = Path(tmp)
        db_dir = work / "db"
        subprocess.run([sys.executable, "-m", "rdd", "build-db", "--format", "rlbench", "--data", str(args.data),
                        "--exclude", args.query, "--encoder", "effnet_lite0", "--no-calibrate", "--out", str(db_dir)],
                       check=True, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        env = official_env(official_dir, work / "stubs")
        times: dict[str, dict[str, list[float]]] = {"official": {}, "ours": {}}

        def add(side: str, stage: str, seconds: float) -> None:
            times[side].setdefault(stage, []).append(seconds)

        for _ in range(args.rounds):
            episode = load_episodes("rlbench", args.data, names=[args.query])[0]
            add("official", "encode", plain_torch_encode(episode, views))
            t0 = time.perf_counter()
            db = SubtaskDatabase.load(db_dir)
            encoder = load_encoder("effnet_lite0")
            rdd = RDDDecomposer(db, encoder, alpha=1.0, min_len=2, max_len=None)
            episode = load_episodes("rlbench", args.data, names=[args.query])[0]  # its images read below
            t1 = time.perf_counter()
            fv = episode_frame_vectors(episode, encoder, views=views)
            t2 = time.perf_counter()
            ours = rdd.decompose_embeddings(fv)
            t3 = time.perf_counter()
            for stage, s in (("load", t1 - t0), ("encode", t2 - t1), ("dp", t3 - t2)):
                add("ours", stage, s)
            np.savez(work / "inputs.npz", fv=fv, begin=db.begin, end=db.end, durations=db.durations)
            out = subprocess.run([sys.executable, "-c", OFFICIAL, str(work / "inputs.npz"), str(work / "index.ann")],
                                 env=env, cwd=official_dir, capture_output=True, text=True)
            if out.returncode != 0:
                sys.exit(f"error: the official code failed in {official_dir}: {out.stderr.strip().splitlines()[-1]}")
            got = json.loads(out.stdout.strip().splitlines()[-1])
            add("official", "load", got["load"])
            add("official", "dp", got["dp"])
        same = [list(s) for s in ours.segments] == got["segments"]
        print(f"{args.data.name}/{args.query}: {len(fv)} frames x {len(views)} views, database of {len(db.begin)} "
              f"entries; median of {args.rounds}; load average {os.getloadavg()}")
        print(f"{'stage':<10} {'official s':>11} {'ours s':>9} {'official/ours':>14}")
        for stage in ("load", "encode", "dp"):
            a, b = (statistics.median(times[s][stage]) for s in ("official", "ours"))
            print(f"{stage:<10} {a:>11.4f} {b:>9.4f} {a / b:>13.2f}x")
        a, b = (sum(statistics.median(v) for v in times[s].values()) for s in ("official", "ours"))
        print(f"{'total':<10} {a:>11.4f} {b:>9.4f} {a / b:>13.2f}x")
        print(f"segments: {'identical' if same else 'DIFFERENT'} (official {got['segments']}, ours "
              f"{[list(s) for s in ours.segments]})")


if __name__ == "__main__":
    main()
