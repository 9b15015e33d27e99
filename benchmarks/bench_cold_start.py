"""Cold-start stages of ``python -m rdd decompose`` (issue 65), this tree beside an earlier one.

Each stage is a whole CLI process on a real RLBench episode (default: ``open_drawer``, the database
built from every episode but ``--query``, which is decomposed), timed from outside, median of
``--runs``; with ``--baseline DIR`` (an earlier source tree holding ``rdd/``, e.g. made by
``git archive <commit> rdd | tar -x -C DIR``) the same commands run on it in turn (A B A B ...)
and the ratio baseline / this tree is printed per stage. Stages:

- ``warm``: embeddings of the query cached; the encoder's identity is all the run needs of it.
- ``onnx-cached``: a fresh embedding cache (the query is encoded) but the ONNX export cached.
- ``first-query``: a fresh copy of the database as ``build-db`` wrote it (before any query).
- ``first-load-N``: a synthetic database of N entries as ``save()`` wrote it, loaded and fitted by a
  fresh process (the first query's cost before any encoding; N=12700 is the paper's RLBench size).

Each tree has its own ``$RDD_CACHE_DIR`` (records one writes are not the other's); the outputs of
the two trees are compared byte for byte. Example:

    python benchmarks/bench_cold_start.py --baseline /tmp/base --runs 5
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DATA = Path(os.environ.get("RDD_TEST_DATA", "/work/shared/data")) / "rlbench/open_drawer/all_variations/episodes"


def rdd_cmd(*args: str) -> list[str]:
    """``python -m rdd ARGS`` with this interpreter."""
    return [sys.executable, "-m", "rdd", *args]


def run(cmd: list[str], src: Path, cache: Path) -> float:
    """Wall seconds of ``cmd`` with ``src`` first on the path and ``cache`` as $RDD_CACHE_DIR."""
    env = {**os.environ, "PYTHONPATH": str(src), "RDD_CACHE_DIR": str(cache)}
    t0 = time.perf_counter()
    subprocess.run(cmd, env=env, check=True, cwd=src, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def imports_torch(cmd: list[str], src: Path, cache: Path) -> bool:
    """Whether ``cmd`` (a ``python -m`` command) imports torch."""
    env = {**os.environ, "PYTHONPATH": str(src), "RDD_CACHE_DIR": str(cache)}
    out = subprocess.run([cmd[0], "-X", "importtime", *cmd[1:]], env=env, cwd=src, capture_output=True,
                         text=True, check=True)
    return any(line.split("|")[-1].strip() == "torch" for line in out.stderr.splitlines())


class Tree:
    """One source tree, its cache, database and outputs under ``work``."""

    def __init__(self, name: str, src: Path, work: Path, data: Path, query: str):
        self.name, self.src, self.work = name, src, work / name
        self.cache = self.work / "cache"
        self.common = ["--format", "rlbench", "--data", str(data)]
        self.query = query

    def build_db(self, given: Path | None) -> Path:
        db = self.work / "db"
        if given is not None:  # the same database for both trees (build-db gives them the same bytes)
            shutil.copytree(given, db, ignore=shutil.ignore_patterns("exact-cells-*", "fingerprint.json"))
        if not db.exists():
            run(rdd_cmd("build-db", *self.common, "--exclude", self.query, "--encoder", "effnet_lite0",
                        "--out", str(db)), self.src, self.cache)
        return db

    def decompose(self, db: Path, out: str, cache_dir: Path | None = None) -> list[str]:
        extra = ["--cache-dir", str(cache_dir)] if cache_dir is not None else []
        return rdd_cmd("decompose", *self.common, "--include", self.query, "--decomposer", "rdd", "--db", str(db),
                       "--out", str(self.work / out), "--force", *extra)

    def stage(self, stage: str) -> tuple[list[str], Path]:
        """The command of ``stage`` and the fresh state it needs, made now (not timed)."""
        db = self.work / "db"
        if stage == "warm":
            return self.decompose(db, "warm.json"), self.cache
        if stage == "onnx-cached":
            fresh = self.work / "fresh-embeddings"
            shutil.rmtree(fresh, ignore_errors=True)
            return self.decompose(db, "onnx.json", cache_dir=fresh), self.cache
        if stage == "first-query":
            fresh_db = self.work / "db-fresh"
            shutil.rmtree(fresh_db, ignore_errors=True)
            shutil.copytree(self.work / "db-as-built", fresh_db)
            return self.decompose(fresh_db, "first.json"), self.cache
        # first-load-N: a synthetic database of N entries as this tree's save() writes it, loaded and
        # fitted by a fresh process (what a first query against it pays before any encoding).
        fresh_db = self.work / f"synthetic-{stage}"
        if not (self.work / f"{fresh_db.name}-as-built").exists():
            run([sys.executable, "-c", SYNTHETIC.format(n=int(stage.rsplit("-", 1)[1]),
                                                        out=self.work / f"{fresh_db.name}-as-built")],
                self.src, self.cache)
        shutil.rmtree(fresh_db, ignore_errors=True)
        shutil.copytree(self.work / f"{fresh_db.name}-as-built", fresh_db)
        return [sys.executable, "-c", FIRST_LOAD.format(db=fresh_db)], self.cache


# The paper's RLBench database size is 12,700 entries; 2 views x 1280-d (effnet_lite0) frame vectors,
# in clusters as real sub-task endpoints are.
SYNTHETIC = """
import numpy as np
from rdd.database.model import SubtaskDatabase
rng = np.random.default_rng(0)
n, d = {n}, 2560
centres = rng.normal(size=(n // 16 + 1, d))
def pts():
    x = centres[rng.integers(0, len(centres), n)] + 0.3 * rng.normal(size=(n, d))
    return (x / np.linalg.norm(x, axis=1, keepdims=True)).astype(np.float32)
SubtaskDatabase.from_arrays(pts(), pts(), rng.integers(5, 60, n), [f"t{{i % 50}}" for i in range(n)]).save("{out}")
"""
FIRST_LOAD = """
from rdd.database.model import SubtaskDatabase
from rdd.decomposers.rdd import RDDDecomposer
RDDDecomposer(SubtaskDatabase.load("{db}"))
"""


def main() -> None:
    """Time the stages on this tree (and ``--baseline``) and print medians and ratios."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", type=Path, help="an earlier source tree holding rdd/")
    ap.add_argument("--data", type=Path, default=DATA, help="RLBench episodes folder")
    ap.add_argument("--query", default="episode0", help="the episode decomposed (left out of the database)")
    ap.add_argument("--db", type=Path, help="a database built from --data without --query (else built here)")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--stages", default="warm,onnx-cached,first-query")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="rdd-cold-") as tmp:
        trees = [Tree("this", ROOT, Path(tmp), args.data, args.query)]
        if args.baseline is not None:
            trees.append(Tree("baseline", args.baseline.resolve(), Path(tmp), args.data, args.query))
        for tree in trees:
            db = tree.build_db(args.db)
            if "first-query" in args.stages.split(","):
                as_built = tree.work / "db-as-built"  # before any query saved anything beside it
                run(rdd_cmd("build-db", *tree.common, "--exclude", tree.query, "--encoder", "effnet_lite0",
                            "--out", str(as_built)), tree.src, tree.cache)
            run(tree.decompose(db, "warm.json"), tree.src, tree.cache)  # fills caches and records
        print(f"{'stage':<12} " + " ".join(f"{t.name + ' s':>12}" for t in trees)
              + ("   baseline/this  torch imported (this, baseline)" if len(trees) > 1 else "   torch imported"))
        for stage in args.stages.split(","):
            times: dict[str, list[float]] = {t.name: [] for t in trees}
            for _ in range(args.runs):
                for tree in trees:
                    cmd, cache = tree.stage(stage)
                    times[tree.name].append(run(cmd, tree.src, cache))
            med = {name: statistics.median(v) for name, v in times.items()}
            torch_used = [imports_torch(*tree.stage(stage)[:1], tree.src, tree.stage(stage)[1]) for tree in trees]
            row = f"{stage:<12} " + " ".join(f"{med[t.name]:>12.2f}" for t in trees)
            if len(trees) > 1:
                row += f"   {med['baseline'] / med['this']:>13.2f}x"
            print(row + f"  {torch_used}", flush=True)
        if len(trees) > 1:
            for out in ("warm.json", "onnx.json", "first.json"):
                a, b = trees[0].work / out, trees[1].work / out
                if a.exists() and b.exists():  # each names its own database folder
                    same = a.read_text().replace(str(trees[0].work), "W") == b.read_text().replace(str(trees[1].work), "W")
                    print(f"{out}: {'identical' if same else 'DIFFERENT'} bytes (the database's path aside)")


if __name__ == "__main__":
    main()
