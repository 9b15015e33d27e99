"""Issue 65's four figures in one run: the official RDD pipeline (tasl-lab/RDD, a local checkout) beside ours.

    RDD_OFFICIAL_DIR=/path/to/RDD .venv/bin/python benchmarks/bench_official.py [--data EPISODES]
        [--query episode5] [--rounds 3] [--long-frames 500] [--db-size 12700] [--long-rounds 1]

Without ``$RDD_OFFICIAL_DIR`` it says so and exits 0. The checkout runs unmodified in processes of its
own, never copied here (``official_runs.py``). Rows, each official / ours:

1. ``server``: a warm request to ``python -m rdd serve`` (started here, 1 worker, one request first to
   warm it; median of ``--rounds``) for the ``--query`` episode (two views, its image files) against the
   official decompose of it (encoding + index load + DP).
2. ``cold CLI``: ``python -m rdd decompose`` in a fresh process (ONNX export cached, embeddings not, a
   fresh copy of the database as saved) on a ``--long-frames`` episode (the RLBench episodes one after
   another, written as a native episode) against a ``--db-size`` database (the short database's
   entries plus intervals of real frame vectors, noised; ``official_runs.long_database``), beside the
   official end to end in fresh processes: its encoding (torch imported, network built, files read),
   then its DP over its Annoy index (built once before, as its database build does). Median of
   ``--long-rounds``.
3. ``library``: in process, the ``--query`` episode: our database and encoder loaded, encoding, DP;
   official: encoding in plain torch (network built before), its index load and DP.
4. ``encoder``: ``bench_encode.py`` (a process of its own): the library's images/s against the best
   plain-torch fp32 configuration of the same weights, per-frame cosine.

What of the official runs here, unmodified: its DP (``rdd/algorithms.py``: ``max_sum_partition`` with
``rdd_score``) over its Annoy searcher (``rdd/ann.py``: ``AnnoySearcher``, 10 trees, angular), fed
our database's entry vectors and our frame vectors, so segments compare on equal inputs. Its
encoding, ``uvd_embed``, goes through UVD, whose preprocessors need torchvision (never installed
here), so it is timed as ``uvd_embed`` runs a preprocessor: plain torch fp32, the same
EfficientNet-Lite0 weights, torch preprocessing, a view at a time. Paper settings throughout (alpha
1, min_len 2, no max_len, default mode, beta 0). Stages of the short episode alternate sides per
round; ratios are official / ours.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_serve import Server, call  # noqa: E402
from official_runs import (  # noqa: E402
    Official,
    long_database,
    long_episode,
    machine,
    official_encode_cold,
    official_env,
    plain_torch_encode,
)

ROOT = Path(__file__).resolve().parent.parent
DATA = Path(os.environ.get("RDD_TEST_DATA", "data")) / "rlbench/open_drawer/all_variations/episodes"
VIEWS = ("front", "wrist")


def quiet(cmd: list[str]) -> float:
    """Wall seconds of ``cmd`` run in this tree (output dropped; an error stops the benchmark)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    t0 = time.perf_counter()
    out = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
    if out.returncode != 0:
        sys.exit(f"error: {' '.join(cmd[:4])} ... failed: {out.stderr.strip()[-2000:]}")
    return time.perf_counter() - t0


def rdd(*args: str) -> list[str]:
    """``python -m rdd ARGS`` with this interpreter."""
    return [sys.executable, "-m", "rdd", *args]


def short_rounds(args: argparse.Namespace, db_dir: Path, official: Official) -> dict:
    """Row 3 (and row 1's official side): the short episode in process, both sides, ``--rounds`` times."""
    from rdd.data.load import load_episodes
    from rdd.database.model import SubtaskDatabase
    from rdd.decomposers.rdd import RDDDecomposer
    from rdd.encoders import load_encoder
    from rdd.encoders.embed import episode_frame_vectors

    times: dict[str, list[float]] = {}
    for _ in range(args.rounds):
        episode = load_episodes("rlbench", args.data, names=[args.query])[0]
        off_encode = plain_torch_encode(episode, VIEWS)
        t0 = time.perf_counter()
        db = SubtaskDatabase.load(db_dir)
        encoder = load_encoder("effnet_lite0")
        decomposer = RDDDecomposer(db, encoder, alpha=1.0, min_len=2, max_len=None)
        episode = load_episodes("rlbench", args.data, names=[args.query])[0]  # its images read below
        t1 = time.perf_counter()
        fv = episode_frame_vectors(episode, encoder, views=VIEWS)
        t2 = time.perf_counter()
        ours = decomposer.decompose_embeddings(fv)
        t3 = time.perf_counter()
        got = official.decompose(fv)
        for key, s in (("off encode", off_encode), ("off load", got["load"]), ("off dp", got["dp"]),
                       ("ours load", t1 - t0), ("ours encode", t2 - t1), ("ours dp", t3 - t2)):
            times.setdefault(key, []).append(s)
    med = {k: statistics.median(v) for k, v in times.items()}
    med["official"] = med["off encode"] + med["off load"] + med["off dp"]
    med["ours"] = med["ours load"] + med["ours encode"] + med["ours dp"]
    return {"median": med, "frames": len(fv), "official_segments": got["segments"],
            "segments": [list(s) for s in ours.segments]}


def server_rounds(args: argparse.Namespace, db_dir: Path) -> dict:
    """Row 1: warm requests for the short episode to our server, started and stopped here."""
    from rdd.data.rlbench import image_paths

    body = {"paths": image_paths(args.data / args.query, VIEWS), "method": "rdd"}
    with Server(db_dir, "--no-calibration", workers=1, start_s=300) as server:
        status, answer = call(server.url + "/decompose", body, timeout=600)  # warm-up: first-call costs
        if status != 200:
            sys.exit(f"error: the server answered {status}: {answer}")
        seconds = []
        for _ in range(args.rounds):
            t0 = time.perf_counter()
            status, answer = call(server.url + "/decompose", body, timeout=600)
            seconds.append(time.perf_counter() - t0)
    return {"median": statistics.median(seconds), "all": seconds,
            "segments": [[s[0], s[-1] + 1] for s in answer["segments"]]}


def long_rounds(args: argparse.Namespace, work: Path, official: Official, files: dict, db_long: Path) -> dict:
    """Row 2: the long episode, our cold CLI against the official end to end, ``--long-rounds`` times."""
    from rdd.data.native import load_episodes as native_episodes
    from rdd.encoders import load_encoder
    from rdd.encoders.cache import EmbeddingCache
    from rdd.encoders.embed import episode_frame_vectors

    times: dict[str, list[float]] = {}
    out = work / "long.json"
    for r in range(args.long_rounds):
        off_encode = official_encode_cold(files, work, args.official_chunk)
        fresh_db, fresh_cache = work / "db-long-fresh", work / f"embeddings-{r}"
        shutil.rmtree(fresh_db, ignore_errors=True)
        shutil.copytree(db_long, fresh_db)  # as saved, before any query wrote beside it
        ours = quiet(rdd("decompose", "--format", "native", "--data", str(work / "long-episode"), "--decomposer",
                         "rdd", "--db", str(fresh_db), "--no-calibration", "--cache-dir", str(fresh_cache),
                         "--out", str(out), "--force"))
        # The official DP gets the frame vectors our CLI computed (read back from its cache).
        episode = native_episodes(work / "long-episode")[0]
        fv = episode_frame_vectors(episode, load_encoder("effnet_lite0"), views=VIEWS, cache=EmbeddingCache(fresh_cache))
        got = official.decompose(fv)
        for key, s in (("off encode", off_encode), ("off dp", got["wall"]), ("off dp inside", got["dp"]),
                       ("ours", ours)):
            times.setdefault(key, []).append(s)
    med = {k: statistics.median(v) for k, v in times.items()}
    med["official"] = med["off encode"] + med["off dp"]
    ours_segs = json.loads(out.read_text())["episodes"][0]["segments"]
    return {"median": med, "frames": len(fv), "official_segments": got["segments"],
            "segments": [list(s) for s in ours_segs]}


def encoder_row(args: argparse.Namespace, work: Path) -> dict:
    """Row 4: ``bench_encode.py`` in a process of its own; its JSON."""
    out = work / "encode.json"
    quiet([sys.executable, str(ROOT / "benchmarks" / "bench_encode.py"), "--frames", str(args.encode_frames),
           "--rounds", str(args.encode_rounds), "--out", str(out)])
    return json.loads(out.read_text())


def main() -> None:
    """Build the inputs, time the four rows, print the table with the machine."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA, help="RLBench episodes folder (default under $RDD_TEST_DATA)")
    ap.add_argument("--query", default="episode5", help="the short episode (open_drawer's episode5: 96 frames)")
    ap.add_argument("--rounds", type=int, default=3, help="rounds of the short episode and server requests")
    ap.add_argument("--long-frames", type=int, default=500, help="frames of the long episode")
    ap.add_argument("--db-size", type=int, default=12700, help="entries of the long episode's database")
    ap.add_argument("--long-rounds", type=int, default=1, help="rounds of the long episode (the official DP "
                    "takes minutes at T=500)")
    ap.add_argument("--official-chunk", type=int, default=128, help="frames per batch of the official encoding")
    ap.add_argument("--encode-frames", type=int, default=64, help="bench_encode.py --frames")
    ap.add_argument("--encode-rounds", type=int, default=2, help="bench_encode.py --rounds")
    ap.add_argument("--json", type=Path, help="also write every figure to this file")
    args = ap.parse_args()
    official = os.environ.get("RDD_OFFICIAL_DIR")
    if not official:
        print("skipped: set RDD_OFFICIAL_DIR to a local checkout of https://github.com/tasl-lab/RDD")
        return
    official_dir = Path(official).expanduser().resolve()
    if not (official_dir / "rdd" / "algorithms.py").is_file():
        sys.exit(f"error: RDD_OFFICIAL_DIR={official}: no rdd/algorithms.py there (not a tasl-lab/RDD checkout)")
    from rdd.database.model import SubtaskDatabase

    load_start, t_start = os.getloadavg(), time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="rdd-official-") as tmp:
        work = Path(tmp)
        env = official_env(official_dir, work / "stubs")
        print("setting up: databases, the long episode, the official indexes", file=sys.stderr, flush=True)
        db_dir = work / "db"
        quiet(rdd("build-db", "--format", "rlbench", "--data", str(args.data), "--exclude", args.query,
                  "--encoder", "effnet_lite0", "--no-calibrate", "--out", str(db_dir)))
        db = SubtaskDatabase.load(db_dir)
        _, files = long_episode(args.data, args.long_frames, work / "long-episode", VIEWS)
        db_long = long_database(db, args.data, args.db_size, work / "db-long", VIEWS)
        official_short = Official(official_dir, env, work, db)
        (work / "long").mkdir()
        official_long = Official(official_dir, env, work / "long", db_long)
        print("timing", file=sys.stderr, flush=True)
        short = short_rounds(args, db_dir, official_short)
        served = server_rounds(args, db_dir)
        long = long_rounds(args, work, official_long, files, work / "db-long")
        enc = encoder_row(args, work)
    report(args, short, served, long, enc, load_start, time.perf_counter() - t_start, len(db.begin), len(db_long.begin))


def report(args: argparse.Namespace, short: dict, served: dict, long: dict, enc: dict, load_start: tuple,
           wall: float, n_db: int, n_long: int) -> None:
    """Print the table (Markdown) with the machine and the segments' agreement."""
    s, g = short["median"], long["median"]
    best = max((r for r in enc["rows"] if r["config"].startswith("plain")), key=lambda r: r["images_per_s"])
    lib = next(r for r in enc["rows"] if r["config"].startswith("library") and "runtime=torch" not in r["config"])

    def same(a: list, b: list) -> str:
        return "identical" if [list(x) for x in a] == [list(x) for x in b] else "DIFFERENT"

    rows = [
        (f"warm server request, {short['frames']} frames x 2 views (median of {args.rounds})", s["official"],
         served["median"], 10, same(served["segments"], short["official_segments"])),
        (f"cold CLI, T={long['frames']} x 2 views, {n_long} entries (median of {args.long_rounds})",
         g["official"], g["ours"], 25, same(long["segments"], long["official_segments"])),
        (f"library in process, {short['frames']} frames (median of {args.rounds})", s["official"], s["ours"], 10,
         same(short["segments"], short["official_segments"])),
    ]
    print(f"machine: {machine()}; load average at start {load_start}, at end {os.getloadavg()}; wall {wall:.0f} s")
    print(f"short: {args.data.name}/{args.query} against {n_db} entries; long: the episodes one after another")
    print("\n| stage | official | ours | official / ours | target | segments |\n| --- | --- | --- | --- | --- | --- |")
    for label, a, b, target, seg in rows:
        print(f"| {label} | {a:.3f} s | {b:.3f} s | {a / b:.1f}x | >= {target}x | {seg} |")
    print(f"| effnet_lite0 encoder, {enc['frames']} frames, images/s (best of {enc['rounds']}) | "
          f"{best['images_per_s']:.1f} ({best['config']}) | {lib['images_per_s']:.1f} | {enc['ratio']:.2f}x | "
          f">= 4x | cosine {enc['min_cosine']:.6f} |")
    print(f"\nshort, official: encode {s['off encode']:.3f} s, index load {s['off load']:.4f} s, DP {s['off dp']:.3f} s;"
          f" ours: load {s['ours load']:.3f} s, encode {s['ours encode']:.3f} s, DP {s['ours dp']:.4f} s;"
          f" server requests {[round(x, 3) for x in served['all']]}")
    print(f"long, official: encode (fresh process) {g['off encode']:.2f} s, DP process {g['off dp']:.2f} s "
          f"(DP {g['off dp inside']:.2f} s); ours: the whole CLI {g['ours']:.2f} s")
    print(f"segments: short {short['segments']}, official {short['official_segments']}, server {served['segments']};"
          f" long {long['segments']}, official {long['official_segments']}")
    if args.json:
        args.json.write_text(json.dumps({"short": short, "server": served, "long": long, "encoder": enc,
                                         "machine": machine(), "load_start": load_start,
                                         "load_end": os.getloadavg(), "wall_s": wall}, indent=1, default=str))


if __name__ == "__main__":
    main()
