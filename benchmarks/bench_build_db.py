"""build-db cost: encoder images and wall time, every frame (before) vs boundary frames only (after).

All runs are cold (no embedding cache) on the same episodes and encoder, in one process:

* ``before``: every frame of every episode encoded (what build-db did before boundary-only builds);
* ``after, --no-calibrate``: only each expert segment's first and last frame encoded;
* ``after, calibrated``: boundary frames plus every frame of the calibration sample (<= 10
  episodes), then leave-one-episode-out calibration;
* ``UVD decompose``: a cold UVD decomposition of the same episodes (every frame encoded + UVD),
  the baseline the issue compares build-db to.

Example (RLBench episodes, e.g. the 6 of open_drawer under ``$RDD_TEST_DATA``, docs/testing.md):

    python benchmarks/bench_build_db.py --data $RDD_TEST_DATA/rlbench/open_drawer/all_variations/episodes
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from rdd.atomic import write_text_atomic
from rdd.core.calibrate import calibrate, sample_episodes
from rdd.data.load import load_episodes
from rdd.database.model import SubtaskDatabase
from rdd.decomposers.expert import ExpertDecomposer
from rdd.decomposers.uvd import UVDDecomposer
from rdd.encoders import load_encoder
from rdd.encoders.embed import DEFAULT_VIEWS


class Counting:
    """Wraps an encoder and counts the images it encodes."""

    def __init__(self, encoder) -> None:
        self._enc = encoder
        self.images = 0

    def __getattr__(self, name):
        return getattr(self._enc, name)

    def encode(self, images: np.ndarray) -> np.ndarray:
        self.images += int(images.shape[0])
        return self._enc.encode(images)


def main(argv: list[str] | None = None) -> dict:
    """Run the comparison; print and return the figures."""
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--data", required=True, help="episodes folder")
    p.add_argument("--format", default="rlbench")
    p.add_argument("--encoder", default="effnet_lite0")
    p.add_argument("--out", type=Path, default=None, help="also write results.json here")
    args = p.parse_args(argv)
    episodes = load_episodes(args.format, args.data)
    views = DEFAULT_VIEWS
    segs = [ExpertDecomposer().decompose(ep).segments for ep in episodes]
    enc = load_encoder(args.encoder)
    enc.encode(episodes[0].frames(views[0], [0]))  # load weights before timing anything
    frames = sum(ep.num_frames for ep in episodes)
    print(f"{len(episodes)} episodes, {frames} frames x {len(views)} views, encoder {args.encoder}; "
          f"cpu {os.cpu_count()} cores, load average {os.getloadavg()}")
    rows: dict[str, dict] = {}

    def timed(name: str, fn) -> None:
        counter = Counting(enc)
        t0 = time.perf_counter()
        fn(counter)
        rows[name] = {"images": counter.images, "seconds": time.perf_counter() - t0}
        print(f"{name:>26}: {counter.images:6d} encoder images, {rows[name]['seconds']:7.1f} s")

    def before(counter) -> None:
        # Every frame of every episode embedded, entries sliced from them: the old build-db.
        SubtaskDatabase.build(episodes, segs, counter, views=views, keep_frames=[e.name for e in episodes])

    def after(counter) -> None:
        SubtaskDatabase.build(episodes, segs, counter, views=views)

    def calibrated(counter) -> None:
        keep = sample_episodes([e.name for e in episodes])
        db = SubtaskDatabase.build(episodes, segs, counter, views=views, keep_frames=keep)
        calibrate(db)

    def uvd(counter) -> None:
        dec = UVDDecomposer(encoder=counter, views=views)
        for ep in episodes:
            dec.decompose(ep)

    timed("before (every frame)", before)
    timed("after, --no-calibrate", after)
    timed("after, calibrated", calibrated)
    timed("UVD decompose (cold)", uvd)
    b, a, u = rows["before (every frame)"], rows["after, --no-calibrate"], rows["UVD decompose (cold)"]
    ratios = {
        "images_before_over_after": b["images"] / max(a["images"], 1),
        "time_before_over_after": b["seconds"] / a["seconds"],
        "uvd_time_over_build_no_calibrate": u["seconds"] / a["seconds"],
    }
    print(f"encoder images before/after --no-calibrate: {ratios['images_before_over_after']:.1f}x fewer; "
          f"time {ratios['time_before_over_after']:.1f}x faster; a cold UVD decomposition takes "
          f"{ratios['uvd_time_over_build_no_calibrate']:.1f}x the --no-calibrate build")
    result = {"episodes": len(episodes), "frames": frames, "encoder": args.encoder, "rows": rows,
              "ratios": ratios, "load_average": os.getloadavg()}
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        write_text_atomic(args.out / "build_db.json", json.dumps(result, indent=2))
    return result


if __name__ == "__main__":
    sys.exit(0 if main() else 1)
