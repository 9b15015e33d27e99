"""How fast ``python -m rdd review`` shows thousands of episodes (issue 63), on a synthetic LeRobot v3.0
dataset (rdd.testing.lerobot_synth, as the scale benchmark's) and a decompose-style file of it whose
confidences are drawn at random (seeded): nothing is decomposed, only the page is measured.

The review command runs as a subprocess (``--no-browser``); its peak memory is the summed RSS of its
process tree, sampled every 0.1 s. Figures, one line each and in ``OUT/results.json``:

1. start: from launching the command to its first answer of ``/api/episodes``;
2. first page: from a headless Chromium's navigation to the page until the list's rows are drawn
   (the median of ``--repeats`` fresh page loads), and the next page likewise (a click);
3. first episode: from a click on a row until its first frame is decoded and shown.

    python benchmarks/bench_review.py --episodes 5000 --out /tmp/bench_review
"""

from __future__ import annotations

import argparse
import json
import os
import random
import statistics
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path
from typing import Any

from bench_scale import tree_rss  # a script beside this one: its directory is on sys.path

from rdd.atomic import write_json_atomic
from rdd.data.lerobot.reader import episode_name
from rdd.review import browser
from rdd.testing.lerobot_synth import write_synthetic_v30

ROOT = Path(__file__).resolve().parents[1]


def predictions(n: int, frames: int, seed: int = 0) -> dict[str, Any]:
    """A decompose-style file: each episode cut into 3-5 segments with random confidences."""
    rng = random.Random(seed)
    episodes = []
    for e in range(n):
        k = rng.randint(3, 5)
        cuts = sorted(rng.sample(range(2, frames - 1), k - 1))
        bounds = [0, *cuts, frames]
        segs = [[a, b] for a, b in zip(bounds, bounds[1:], strict=False)]
        episodes.append({"episode": episode_name(e), "num_frames": frames, "segments": segs,
                         "keyframes": [b - 1 for _, b in segs], "scores": None,
                         "instructions": [f"step {j + 1}" for j in range(k)], "instruction_sources": None,
                         "novelty": -rng.random(), "confidence": [round(rng.random(), 4) for _ in segs]})
    return {"config": {"decomposer": "synthetic"}, "episodes": episodes}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run the benchmark; return (and write) its figures."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=5000)
    ap.add_argument("--frames", type=int, default=60, help="frames per episode")
    ap.add_argument("--per-file", type=int, default=100, help="episodes per data/video file")
    ap.add_argument("--repeats", type=int, default=5, help="fresh page loads timed")
    ap.add_argument("--out", type=Path, default=Path("outputs/bench_review"))
    args = ap.parse_args(argv)
    why = browser.missing()
    if why:
        ap.error(why)
    out = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    n, t = args.episodes, args.frames
    data = out / f"ds_{n}x{t}"
    if not (data / "meta/info.json").exists():
        start = time.monotonic()
        write_synthetic_v30(data, [[t] * min(args.per_file, n - i) for i in range(0, n, args.per_file)])
        print(f"dataset: {n} episodes x {t} frames in {time.monotonic() - start:.1f} s", flush=True)
    pred = write_json_atomic(out / "pred.json", predictions(n, t))
    reviewed = out / "reviewed.json"
    port = browser.free_port()
    url = f"http://127.0.0.1:{port}/"
    cmd = [sys.executable, "-m", "rdd", "review", "--format", "lerobot", "--data", str(data), "--pred", str(pred),
           "--out", str(reviewed), "--force", "--no-browser", "--port", str(port)]
    env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    launched = time.monotonic()
    proc = subprocess.Popen(cmd, env=env, stderr=subprocess.PIPE, text=True)
    peak = [0]
    done = threading.Event()

    def sample() -> None:
        while not done.is_set():
            peak[0] = max(peak[0], tree_rss(proc.pid))
            time.sleep(0.1)

    threading.Thread(target=sample, daemon=True).start()
    results: dict[str, Any] = {"episodes": n, "frames": t}
    try:
        while True:
            try:
                with urllib.request.urlopen(url + "api/episodes", timeout=5) as answer:
                    total = json.loads(answer.read())["episodes"]
                break
            except OSError:
                if proc.poll() is not None:
                    raise SystemExit(f"review exited: {proc.stderr.read()}") from None
                time.sleep(0.05)
        results["start_s"] = time.monotonic() - launched
        assert total == n, (total, n)
        loads, nexts, opens = [], [], []
        from selenium.webdriver.common.by import By

        with browser.chromium() as d:
            for _ in range(args.repeats):
                t0 = time.monotonic()
                d.get(url)
                while not d.find_elements(By.CSS_SELECTOR, "#list tbody tr"):
                    time.sleep(0.01)
                loads.append(time.monotonic() - t0)
                row = "const r = document.querySelector('#list tbody tr'); return r ? r.dataset.episode : null"
                first = d.execute_script(row)
                t0 = time.monotonic()
                d.find_element(By.ID, "next").click()
                while d.execute_script(row) in (first, None):
                    time.sleep(0.01)
                nexts.append(time.monotonic() - t0)
                t0 = time.monotonic()
                d.find_element(By.CSS_SELECTOR, "#list tbody tr").click()
                shown = "const i = document.querySelector('#frames img'); return !!i && i.complete && i.naturalWidth > 0"
                while not d.execute_script(shown):
                    time.sleep(0.01)
                opens.append(time.monotonic() - t0)
        results.update(first_page_s=statistics.median(loads), first_page_all_s=loads,
                       next_page_s=statistics.median(nexts), first_episode_s=statistics.median(opens))
    finally:
        proc.terminate()
        proc.wait(10)
        done.set()
    results["peak_rss_gib"] = peak[0] / 2**30
    print(f"review of {n} episodes: started in {results['start_s']:.2f} s; first page {results['first_page_s']:.3f} s "
          f"(median of {args.repeats}), next page {results['next_page_s']:.3f} s, an episode's first frame "
          f"{results['first_episode_s']:.3f} s; peak memory {results['peak_rss_gib']:.2f} GiB")
    write_json_atomic(out / "results.json", results)
    return results


if __name__ == "__main__":
    main()
