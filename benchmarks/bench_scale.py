"""Scale benchmark of ``python -m rdd decompose`` (issue 47.2) on a synthetic LeRobot v3.0 dataset.

Writes ``--episodes`` episodes x ``--frames`` frames (one ``--size`` camera, ``--per-file`` episodes
per data/video file; rdd.testing.lerobot_synth), then runs the CLI as a subprocess, each run timed
(wall), its peak memory sampled (the summed RSS of its process tree, every 0.1 s):

1. every episode with uvd and the fast ``pixels`` encoder, ``--workers`` processes: wall, images/s;
2. the first ``--compare-episodes`` episodes the same way with 1 and with 2 workers (same bytes?),
   and the peak memory of that run beside run 1's (flat in the episode count?);
3. the same subset killed with SIGKILL once ``--kill-at`` of its episodes are staged, then rerun:
   how many episodes the rerun redid (from its ``-v`` log), its wall, and whether its output is the
   uninterrupted run's bytes;
4. the first ``--effnet-episodes`` episodes with ``effnet_lite0`` (0 skips it).

Prints one line per figure and writes ``results.json`` under ``--out``. The full benchmark (the
lead's) and a smoke run:

    python benchmarks/bench_scale.py --out outputs/bench_scale
    python benchmarks/bench_scale.py --episodes 20 --frames 50 --compare-episodes 10 --effnet-episodes 2 \\
        --out /tmp/bench_scale_smoke
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

from rdd.atomic import write_json_atomic
from rdd.data.lerobot.reader import episode_name
from rdd.testing.lerobot_synth import write_synthetic_v30

ROOT = Path(__file__).resolve().parents[1]
PAGE = os.sysconf("SC_PAGE_SIZE")


def tree_rss(pid: int) -> int:
    """Resident bytes of ``pid`` and all its descendants now (0 for those gone)."""
    total, stack = 0, [pid]
    while stack:
        p = stack.pop()
        try:
            total += int(Path(f"/proc/{p}/statm").read_text().split()[1]) * PAGE
            for task in Path(f"/proc/{p}/task").iterdir():
                stack += [int(c) for c in (task / "children").read_text().split()]
        except (FileNotFoundError, ProcessLookupError, ValueError):
            continue
    return total


def run_cli(argv: list[str], kill_when=None) -> dict[str, Any]:
    """Run ``python -m rdd ARGV``: wall seconds, peak RSS of its process tree, status, stderr;
    ``kill_when()`` true kills the whole process group with SIGKILL."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    start = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "rdd", *argv], cwd=ROOT, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    peak, killed, err = 0, False, []
    reader = threading.Thread(target=lambda: err.extend(proc.stderr), daemon=True)
    reader.start()
    while proc.poll() is None:
        peak = max(peak, tree_rss(proc.pid))
        if kill_when is not None and not killed and kill_when():
            os.killpg(proc.pid, signal.SIGKILL)
            killed = True
        time.sleep(0.1 if kill_when is None else 0.02)  # a kill on time, between two episodes
    wall = time.monotonic() - start
    reader.join(5)
    return {"wall_s": wall, "peak_tree_bytes": peak, "status": proc.returncode, "killed": killed, "stderr": "".join(err)}


def decompose(data: Path, out: Path, encoder: str, workers: int, names: list[str] | None, *extra: str) -> list[str]:
    """The ``decompose`` command line of one run."""
    return ["decompose", "--format", "lerobot", "--data", str(data), "--decomposer", "uvd", "--encoder", encoder,
            "--no-cache", "--out", str(out), "--workers", str(workers),
            *(["--include", *names] if names else []), *extra]


def parts(out: Path) -> int:
    """Finished staged parts of a run writing ``out``."""
    folder = out.parent / f".{out.name}.parts"
    return sum(1 for p in folder.glob("*.json") if not p.name.startswith(".")) if folder.exists() else 0


def gib(n: float) -> str:
    return f"{n / 2**30:.2f} GiB"


def report(label: str, res: dict[str, Any], episodes: int, frames: int) -> dict[str, Any]:
    """Print and return one run's figures; a failed run (not killed) stops the benchmark."""
    if res["status"] != 0 and not res["killed"]:
        raise SystemExit(f"{label}: exit {res['status']}: {res['stderr'].strip().splitlines()[-1:]}")
    row = {"label": label, "episodes": episodes, "images": episodes * frames, "wall_s": round(res["wall_s"], 2),
           "images_per_s": round(episodes * frames / res["wall_s"], 1),
           "peak_tree_gib": round(res["peak_tree_bytes"] / 2**30, 3)}
    print(f"{label}: {episodes} episodes, {row['images']} images in {row['wall_s']:.1f} s "
          f"({row['images_per_s']:.0f} images/s), peak memory {gib(res['peak_tree_bytes'])}", flush=True)
    return row


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run the benchmark; return (and write) its figures."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=1000)
    ap.add_argument("--frames", type=int, default=300, help="frames per episode")
    ap.add_argument("--per-file", type=int, default=50, help="episodes per data/video file")
    ap.add_argument("--size", default="96x128", help="frame height x width")
    ap.add_argument("--workers", type=int, default=2, help="workers of the full run")
    ap.add_argument("--compare-episodes", type=int, default=100,
                    help="episodes of the 1-vs-2-workers, memory and resume runs")
    ap.add_argument("--kill-at", type=float, default=0.4, help="fraction of staged episodes at the kill")
    ap.add_argument("--effnet-episodes", type=int, default=50)
    ap.add_argument("--out", type=Path, default=Path("outputs/bench_scale"))
    args = ap.parse_args(argv)
    if min(args.episodes, args.frames, args.per_file, args.compare_episodes) < 1:
        ap.error("--episodes, --frames, --per-file and --compare-episodes must be >= 1")
    try:
        size = tuple(int(v) for v in args.size.lower().split("x"))
        assert len(size) == 2 and min(size) > 0
    except (ValueError, AssertionError):
        ap.error(f"--size {args.size}: expected HEIGHTxWIDTH, e.g. 96x128")
    out = args.out.resolve()
    shutil.rmtree(out / "ds", ignore_errors=True)
    out.mkdir(parents=True, exist_ok=True)
    n, t = args.episodes, args.frames
    m = min(args.compare_episodes, n)
    start = time.monotonic()
    lengths = [t] * n
    data = write_synthetic_v30(out / "ds", [lengths[i:i + args.per_file] for i in range(0, n, args.per_file)],
                               size=size)
    print(f"dataset: {n} episodes x {t} frames ({size[0]}x{size[1]}) in {time.monotonic() - start:.1f} s", flush=True)
    subset = [episode_name(e) for e in range(m)]
    results: dict[str, Any] = {"settings": {k: str(v) for k, v in vars(args).items()}, "runs": []}

    def timed(label: str, name: str, encoder: str, workers: int, names, count: int, *extra: str, kill_when=None,
              fresh: bool = True, verbose: bool = False):
        target = out / name
        if fresh:  # nothing left by an earlier benchmark to resume from
            target.unlink(missing_ok=True)
            shutil.rmtree(out / f".{name}.parts", ignore_errors=True)
        res = run_cli([*(["-v"] if verbose else []), *decompose(data, target, encoder, workers, names, *extra)],
                      kill_when=kill_when)
        row = report(label, res, count, t)
        results["runs"].append(row)
        return target, res, row

    _, _, full_row = timed(f"pixels, all, {args.workers} workers", "full.json", "pixels", args.workers, None, n)
    one, _, one_row = timed("pixels, subset, 1 worker", "one.json", "pixels", 1, subset, m)
    two, _, two_row = timed("pixels, subset, 2 workers", "two.json", "pixels", 2, subset, m)
    results["workers_same_bytes"] = one.read_bytes() == two.read_bytes()
    results["speedup_2_workers"] = round(one_row["wall_s"] / two_row["wall_s"], 2)
    print(f"1 vs 2 workers: {one_row['wall_s']:.1f} s vs {two_row['wall_s']:.1f} s "
          f"(x{results['speedup_2_workers']}), same bytes: {results['workers_same_bytes']}")
    results["memory_flat"] = {"episodes": [m, n], "peak_gib": [two_row["peak_tree_gib"], full_row["peak_tree_gib"]]}
    print(f"peak memory, 2 workers: {m} episodes {two_row['peak_tree_gib']:.2f} GiB, "
          f"{n} episodes {full_row['peak_tree_gib']:.2f} GiB")

    resumed = out / "resumed.json"
    need = max(1, int(args.kill_at * m))
    _, killed, _ = timed("pixels, subset, killed", "resumed.json", "pixels", 2, subset, m,
                                     kill_when=lambda: parts(resumed) >= need)
    staged = parts(resumed)
    _, rerun, rerun_row = timed("pixels, subset, resumed", "resumed.json", "pixels", 2, subset, m - staged,
                            fresh=False, verbose=True)
    redone = len(re.findall(r": episode \d+/\d+ ", rerun["stderr"]))
    results["resume"] = {"killed": killed["killed"], "staged_at_kill": staged, "redone": redone,
                         "expected_redone": m - staged, "wall_s": rerun_row["wall_s"],
                         "same_bytes": resumed.exists() and resumed.read_bytes() == two.read_bytes()}
    print(f"resume: killed (SIGKILL) with {staged}/{m} episodes staged; the rerun did {redone} episodes "
          f"in {rerun_row['wall_s']:.1f} s; output same bytes as uninterrupted: {results['resume']['same_bytes']}")

    if args.effnet_episodes:
        e = min(args.effnet_episodes, n)
        timed("effnet_lite0, 2 workers", "effnet.json", "effnet_lite0", 2, [episode_name(i) for i in range(e)], e)
    write_json_atomic(out / "results.json", results)
    print(f"wrote {out / 'results.json'}")
    return results


if __name__ == "__main__":
    main()
