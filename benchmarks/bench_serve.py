"""Load test of ``python -m rdd serve`` on the loopback address: C concurrent clients x R requests each
on W-frame windows (default 8 x 25 on 20-frame windows), bounded in count and in time; prints the
errors and the p50 / p95 latency.

The server runs as a subprocess on 127.0.0.1 and a free port, over a small database built here
from synthetic episodes (three sub-tasks of drifting colours, two 16x16 views) with the ``pixels``
encoder, or from RLBench episode folders with ``--rlbench DIR`` (every episode but the last builds
the database; windows come from the last one's ``front_rgb`` / ``wrist_rgb`` images). The clients
are plain ``urllib`` in threads: each answer must be 200 with segments partitioning the window.

    python benchmarks/bench_serve.py                       # synthetic, 8 x 25, 20-frame windows
    python benchmarks/bench_serve.py --rlbench $RDD_TEST_DATA/rlbench/open_drawer/all_variations/episodes
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ENCODER_ARGS = ("--encoder-option", "size=4")  # the pixels encoder the database is built with


def synthetic_setup(root: Path) -> dict[str, Any]:
    """Native episodes ep0..ep4 under ``root/native`` (ep4 held out), a pixels database built from
    ep0..ep3 by ``python -m rdd build-db``, and ep4's frames as PNG files (one folder per view)."""
    from PIL import Image

    from rdd.cli import main
    from rdd.data.native import save_episode
    from rdd.testing.native_synth import colour_episode

    data = root / "native"
    lengths = [(12, 15, 13), (14, 12, 15), (13, 14, 12), (15, 13, 14), (18, 16, 17)]
    episodes = [colour_episode(f"ep{k}", n, k) for k, n in enumerate(lengths)]
    for ep in episodes:
        save_episode(ep, data / ep.name)
    db = root / "db"
    if main(["build-db", "--format", "native", "--data", str(data), "--exclude", "ep4", "--encoder", "pixels",
             *ENCODER_ARGS, "--no-cache", "--out", str(db)]) != 0:
        raise RuntimeError("build-db failed")
    held = episodes[-1]
    frames: list[list[str]] = [[] for _ in range(held.num_frames)]
    for view in ("front", "wrist"):
        (root / "png" / view).mkdir(parents=True)
        for i, img in enumerate(held.frames(view)):
            path = root / "png" / view / f"{i}.png"
            Image.fromarray(img).save(path)
            frames[i].append(str(path))
    return {"db": db, "frames": frames, "format": "native", "data": data, "episode": "ep4"}


def rlbench_setup(root: Path, episodes: Path, encoder: str = "pixels") -> dict[str, Any]:
    """A database (``encoder``, default pixels) from every RLBench episode under ``episodes`` but the
    last; that one's images."""
    from rdd.cli import main
    from rdd.data.rlbench import episode_names, image_paths

    names = episode_names(episodes)
    held = names[-1]
    db = root / "db"
    encoder_args = ENCODER_ARGS if encoder == "pixels" else ()
    if main(["build-db", "--format", "rlbench", "--data", str(episodes), "--exclude", held, "--encoder", encoder,
             *encoder_args, "--no-cache", "--out", str(db)]) != 0:
        raise RuntimeError("build-db failed")
    frames = image_paths(episodes / held, ("front", "wrist"))
    return {"db": db, "frames": frames, "format": "rlbench", "data": episodes, "episode": held,
            "encoder_args": encoder_args}


def free_port() -> int:
    """A TCP port free on 127.0.0.1 now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def call(url: str, body: dict | None = None, timeout: float = 60.0) -> tuple[int, Any]:
    """GET (``body`` None) or POST JSON to ``url``: (status, decoded JSON answer)."""
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(url, data=data, headers={"Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(req, timeout=timeout) as resp:
            return resp.status, json.loads(resp.read())
    except urllib.error.HTTPError as exc:
        text = exc.read()
        try:
            return exc.code, json.loads(text)
        except ValueError:
            return exc.code, text.decode(errors="replace")


class Server:
    """``python -m rdd serve --db DB ...`` as a subprocess on 127.0.0.1 and a free port; a context manager."""

    def __init__(self, db: Path, *extra: str, workers: int = 1, log: Path | None = None, start_s: float = 120.0):
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.argv = [sys.executable, "-m", "rdd", "serve", "--db", str(db), "--host", "127.0.0.1",
                     "--port", str(self.port), "--workers", str(workers), *extra]
        self.log = log or Path(tempfile.mkstemp(prefix="rdd-serve-", suffix=".log")[1])
        self.start_s = start_s
        self.proc: subprocess.Popen | None = None

    def __enter__(self) -> Server:
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
        with open(self.log, "wb") as log:
            self.proc = subprocess.Popen(self.argv, stdout=log, stderr=subprocess.STDOUT, env=env, cwd=ROOT)
        deadline = time.monotonic() + self.start_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited with {self.proc.returncode}: {self.log.read_text()[-2000:]}")
            try:
                if call(self.url + "/health", timeout=2)[0] == 200:
                    return self
            except OSError:
                pass
            time.sleep(0.2)
        self.__exit__(None, None, None)
        raise RuntimeError(f"server not up after {self.start_s} s: {self.log.read_text()[-2000:]}")

    def __exit__(self, *exc: Any) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def check_answer(status: int, answer: Any, n: int, method: str) -> str | None:
    """Why an answer to an ``n``-frame request is wrong (None when it is a 200 whose segments partition it)."""
    if status != 200:
        return f"status {status}: {answer}"
    segs = answer.get("segments") if isinstance(answer, dict) else None
    if not segs or [i for s in segs for i in s] != list(range(n)):
        return f"segments do not partition 0..{n - 1}: {segs}"
    if method == "rdd" and len(answer.get("nn_list", [])) != len(segs):
        return "nn_list has not one item per segment"
    return None


def load_test(url: str, windows: Sequence[list[list[str]]], clients: int = 8, per_client: int = 25,
              method: str = "rdd", timeout: float = 60.0, deadline_s: float = 300.0) -> dict[str, Any]:
    """``clients`` threads each sending ``per_client`` requests in turn (window ``k % len(windows)``);
    no request starts after ``deadline_s``: those left unsent count as errors."""
    latencies: list[float] = []
    errors: list[str] = []
    lock = threading.Lock()
    stop_at = time.monotonic() + deadline_s

    def client(c: int) -> None:
        for r in range(per_client):
            window = windows[(c * per_client + r) % len(windows)]
            if time.monotonic() > stop_at:
                with lock:
                    errors.append("not sent: deadline")
                continue
            t0 = time.perf_counter()
            try:
                status, answer = call(url + "/decompose", {"paths": window, "method": method,
                                                           "preprocessor": "pixels"}, timeout=timeout)
                why = check_answer(status, answer, len(window), method)
            except OSError as exc:
                why = f"{type(exc).__name__}: {exc}"
            elapsed = time.perf_counter() - t0
            with lock:
                (errors.append(why) if why else latencies.append(elapsed))

    start = time.perf_counter()
    threads = [threading.Thread(target=client, args=(c,)) for c in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    wall = time.perf_counter() - start
    ms = np.array(latencies) * 1000
    return {"clients": clients, "requests_per_client": per_client, "requests": clients * per_client,
            "ok": len(latencies), "errors": len(errors), "error_samples": sorted(set(errors))[:5],
            "p50_ms": float(np.percentile(ms, 50)) if ms.size else None,
            "p95_ms": float(np.percentile(ms, 95)) if ms.size else None,
            "max_ms": float(ms.max()) if ms.size else None, "wall_s": wall,
            "requests_per_s": len(latencies) / wall if wall > 0 else None}


def windows_of(frames: Sequence[list[str]], size: int) -> list[list[list[str]]]:
    """Every ``size``-frame window of ``frames`` (step 1)."""
    if len(frames) < size:
        raise ValueError(f"{len(frames)} frames, fewer than a {size}-frame window")
    return [list(frames[s:s + size]) for s in range(len(frames) - size + 1)]


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    """Build the database, start the server, run the load test; print and return the figures."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rlbench", type=Path, help="RLBench episodes folder (default: synthetic episodes)")
    p.add_argument("--clients", type=int, default=8)
    p.add_argument("--requests", type=int, default=25, help="requests per client")
    p.add_argument("--window", type=int, default=20, help="frames per request")
    p.add_argument("--workers", type=int, default=1, help="server workers")
    p.add_argument("--method", choices=("rdd", "uvd"), default="rdd")
    p.add_argument("--encoder", default="pixels", help="with --rlbench: the database's encoder (default pixels)")
    p.add_argument("--deadline", type=float, default=300.0, help="seconds after which no request starts")
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="bench-serve-") as tmp:
        setup = rlbench_setup(Path(tmp), args.rlbench, args.encoder) if args.rlbench else synthetic_setup(Path(tmp))
        windows = windows_of(setup["frames"], args.window)
        with Server(setup["db"], *setup.get("encoder_args", ENCODER_ARGS), workers=args.workers) as server:
            res = load_test(server.url, windows, args.clients, args.requests, args.method,
                            deadline_s=args.deadline)
    res.update(window=args.window, workers=args.workers, method=args.method, encoder=args.encoder,
               data="rlbench" if args.rlbench else "synthetic", cores=len(os.sched_getaffinity(0)))
    print(json.dumps(res, indent=1))
    return res


if __name__ == "__main__":
    main()
