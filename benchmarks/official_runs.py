"""Helpers of ``bench_official.py``: the official code's process, the long episode and its database.

The official checkout runs only in processes of its own (both projects' packages are named ``rdd``);
nothing of it is copied here. ``uvd``, ``cv2`` and ``imageio`` (imported by its modules, unused on
the path timed) are stubs that raise if called; ``loguru`` is stubbed when absent.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
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
# Run with the checkout first on the path: builds its Annoy index once when argv[3] is "build" (as
# build_vec_database.py saves it, before any query), else times loading it (its server opens the
# file for every request) and its DP, and prints JSON.
OFFICIAL = """
import json, os, sys, time, numpy as np
from rdd.ann import AnnoySearcher
from rdd.algorithms import max_sum_partition, rdd_score
d = np.load(sys.argv[1]); fv, begin, end, dur = d["fv"], d["begin"], d["end"], d["durations"]
path = sys.argv[2]
if sys.argv[3] == "build":
    s = AnnoySearcher(begin.shape[1] * 2, path, n_trees=10)
    for i in range(len(begin)): s.add(np.concatenate([begin[i], end[i]]), i)
    s.save()
    sys.exit(0)
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
# A fresh process embedding image files as ``uvd_embed`` runs a preprocessor: torch imported, the
# network built, files decoded (imageio there, PIL here), plain torch fp32, a view at a time in
# chunks of argv[2] frames (uvd_embed takes a view in one batch; chunks bound the memory at T=500).
OFFICIAL_ENCODE = """
import json, sys
import numpy as np, torch
from PIL import Image
from rdd.encoders import load_encoder
from rdd.encoders._effnet_lite import VARIANTS, make_torch_preprocess
model = load_encoder("effnet_lite0", runtime="torch").model.eval()
pre = make_torch_preprocess(VARIANTS[0].resolution)
chunk = int(sys.argv[2])
with torch.inference_mode():
    for files in json.load(open(sys.argv[1])).values():
        frames = np.stack([np.asarray(Image.open(f).convert("RGB")) for f in files])
        for s in range(0, len(frames), chunk):
            model.extract_features(pre(frames[s:s + chunk])).mean(dim=(2, 3)).numpy()
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


class Official:
    """The official checkout's DP over its Annoy index, on one database's vectors, in fresh processes."""

    def __init__(self, official_dir: Path, env: dict[str, str], work: Path, db: Any):
        self.dir, self.env, self.work = official_dir, env, work
        self.inputs, self.index = work / "inputs.npz", work / "index.ann"
        self.db = db
        self.save(np.zeros((1, db.begin.shape[1]), np.float32))
        self._run("build")

    def save(self, fv: np.ndarray) -> None:
        """Write the query's frame vectors beside the database's vectors (the process's input)."""
        np.savez(self.inputs, fv=fv, begin=self.db.begin, end=self.db.end, durations=self.db.durations)

    def _run(self, mode: str) -> subprocess.CompletedProcess:
        out = subprocess.run([sys.executable, "-c", OFFICIAL, str(self.inputs), str(self.index), mode],
                             env=self.env, cwd=self.dir, capture_output=True, text=True)
        if out.returncode != 0:
            last = (out.stderr.strip().splitlines() or ["no message"])[-1]
            sys.exit(f"error: the official code failed in {self.dir}: {last}")
        return out

    def decompose(self, fv: np.ndarray) -> dict[str, Any]:
        """Its DP on ``fv``: {load, dp (seconds inside), wall (the whole process), segments}."""
        self.save(fv)
        t0 = time.perf_counter()
        out = self._run("query")
        got = json.loads(out.stdout.strip().splitlines()[-1])
        got["wall"] = time.perf_counter() - t0
        return got


def official_encode_cold(files: dict[str, list[str]], work: Path, chunk: int) -> float:
    """Wall seconds of a fresh process embedding ``files`` (view -> image paths) as the official does."""
    spec = work / "official-files.json"
    spec.write_text(json.dumps(files))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", OFFICIAL_ENCODE, str(spec), str(chunk)], env=env, cwd=ROOT, check=True)
    return time.perf_counter() - t0


def plain_torch_encode(episode: Any, views: Sequence[str]) -> float:
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


def long_episode(data: Path, frames: int, out: Path, views: Sequence[str]) -> tuple[Path, dict[str, list[str]]]:
    """A ``frames``-frame native episode ``long`` under ``out``: the RLBench episodes of ``data`` one
    after another (again from the first when they run out), cut at ``frames``; and its image files."""
    from rdd.data.episode import Episode
    from rdd.data.load import load_episodes
    from rdd.data.native import save_episode
    from rdd.data.rlbench import episode_names, image_paths

    names = episode_names(data)
    order = [names[k % len(names)] for k in range(frames)]  # more than enough episodes
    parts: dict[str, list[np.ndarray]] = {v: [] for v in views}
    files: dict[str, list[str]] = {v: [] for v in views}
    left = frames
    for name in order:
        if left <= 0:
            break
        ep = load_episodes("rlbench", data, names=[name])[0]
        n = min(left, ep.num_frames)
        paths = image_paths(data / name, views, n)
        for j, v in enumerate(views):
            parts[v].append(ep.frames(v, np.arange(n)))
            files[v] += [frame[j] for frame in paths]
        left -= n
    episode = Episode(name="long", views={v: np.concatenate(p) for v, p in parts.items()},
                      goal="open the drawer", task="open_drawer")
    save_episode(episode, out / "long")
    return out, files


def long_database(db: Any, data: Path, size: int, out: Path, views: Sequence[str], seed: int = 0) -> Any:
    """A database of ``size`` entries saved to ``out`` (its index's clusters built, as build-db does):
    ``db``'s real entries, then entries cut from the real frame vectors of ``data``'s episodes (a random
    interval each, begin and end vectors moved by noise of 0.2 of their norm and renormalised per view),
    so every entry lies near real frames as a large database's do."""
    from rdd.data.load import load_episodes
    from rdd.database.model import SubtaskDatabase
    from rdd.encoders import load_encoder
    from rdd.encoders.cache import EmbeddingCache
    from rdd.encoders.embed import episode_frame_vectors

    rng = np.random.default_rng(seed)
    encoder = load_encoder(db.meta["encoder"])
    cache = EmbeddingCache()  # $RDD_CACHE_DIR: embedded once, then read
    fvs = [episode_frame_vectors(ep, encoder, views=views, cache=cache) for ep in load_episodes("rlbench", data)]
    n_real = min(len(db.begin), size)
    extra = size - n_real
    src = rng.integers(0, len(fvs), extra)
    starts, stops = np.zeros(extra, np.int64), np.zeros(extra, np.int64)
    for k, e in enumerate(src):
        t = len(fvs[e])
        starts[k] = rng.integers(0, t - 1)
        stops[k] = rng.integers(starts[k] + 1, t)  # the last frame, inclusive
    dim = fvs[0].shape[1] // len(views)

    def noisy(rows: np.ndarray) -> np.ndarray:
        x = rows + rng.normal(0, 0.2 / np.sqrt(dim), rows.shape)
        x = x.reshape(len(x), len(views), dim)
        return (x / np.linalg.norm(x, axis=2, keepdims=True)).reshape(len(x), -1).astype(np.float32)

    def rows(frames: np.ndarray) -> np.ndarray:
        return noisy(np.stack([fvs[e][i] for e, i in zip(src, frames, strict=True)])) if extra else \
            np.zeros((0, dim * len(views)), np.float32)

    begin, end = rows(starts), rows(stops)
    meta = {k: db.meta.get(k) for k in ("encoder", "weights_id", "views", "normalize_views")}
    big = SubtaskDatabase.from_arrays(np.concatenate([db.begin[:n_real], begin]), np.concatenate([db.end[:n_real], end]),
                                      np.concatenate([db.durations[:n_real], stops - starts]),
                                      list(db.labels[:n_real]) + ["open the drawer"] * extra, meta)
    big.save(out)
    return big


def machine() -> str:
    """CPU model, cores this process may use, of how many."""
    from rdd.machine import cpu_model

    return f"{cpu_model()}, {len(os.sched_getaffinity(0))} of {os.cpu_count()} cores"
