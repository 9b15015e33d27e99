"""Long CLI runs resume (issue 40): each episode's result is staged beside the output as it is done,
a rerun after a stop (an error, Ctrl-C, ``kill -9``) does only what is missing and writes the same
bytes as an uninterrupted run, with or without the embedding cache; ``--workers 2`` writes the same
bytes as one worker; a rerun with other settings reuses nothing."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from rdd.cli import main
from rdd.data.native import load_episode
from rdd.decomposers.uniform import UniformDecomposer
from rdd.decomposers.uvd import UVDDecomposer
from rdd.testing.trees import tree_bytes

ROOT = Path(__file__).resolve().parents[2]
NAMES = [f"ep{k}" for k in range(6)]  # the episodes of the native_six fixture


def uvd_args(data: Path, out: Path, cache: Path | None) -> list[str]:
    return ["decompose", "--format", "native", "--data", str(data), "--decomposer", "uvd", "--encoder", "pixels",
            "--encoder-option", "size=4", "--option", "min_interval=3", "--out", str(out),
            *(["--cache-dir", str(cache)] if cache is not None else ["--no-cache"])]


def parts_of(out: Path) -> list[Path]:
    folder = out.parent / f".{out.name}.parts"
    # finished parts only: not the hidden temporary of a write in progress
    return sorted(p for p in folder.rglob("*.*") if not p.name.startswith(".")) if folder.exists() else []


def count_calls(monkeypatch, cls, stop_at: int | None = None) -> Counter:
    """Count ``cls.decompose`` calls per episode; raise KeyboardInterrupt (a Ctrl-C) at call ``stop_at``."""
    calls: Counter = Counter()
    original = cls.decompose

    def counted(self, episode):
        if stop_at is not None and sum(calls.values()) == stop_at:
            raise KeyboardInterrupt
        calls[episode.name] += 1
        return original(self, episode)

    monkeypatch.setattr(cls, "decompose", counted)
    return calls


@pytest.mark.parametrize("cached", [True, False], ids=["cache", "no-cache"])
def test_decompose_resumes_after_a_stop(native_six, tmp_path, monkeypatch, cached):
    cache = tmp_path / "cache" if cached else None
    assert main(uvd_args(native_six, tmp_path / "ref.json", cache)) == 0
    out = tmp_path / "out.json"
    first = count_calls(monkeypatch, UVDDecomposer, stop_at=3)
    assert main(uvd_args(native_six, out, cache)) == 130  # stopped at the fourth episode
    assert not out.exists() and len(parts_of(out)) == 3 and sorted(first) == NAMES[:3]
    monkeypatch.undo()
    second = count_calls(monkeypatch, UVDDecomposer)
    assert main(uvd_args(native_six, out, cache)) == 0
    assert sorted(second) == NAMES[3:] and set(second.values()) == {1}  # none twice, none lost
    assert out.read_bytes() == (tmp_path / "ref.json").read_bytes()
    assert not (tmp_path / ".out.json.parts").exists()  # removed with the output written


def test_decompose_resumes_after_kill_9(native_six, tmp_path):
    """A run killed with SIGKILL (no cleanup at all) keeps what it staged; the rerun finishes it."""
    out, ref = tmp_path / "out.json", tmp_path / "ref.json"
    argv = uvd_args(native_six, out, None)
    slow = textwrap.dedent(f"""
        import sys, time
        from rdd.decomposers.uvd import UVDDecomposer
        original = UVDDecomposer.decompose
        UVDDecomposer.decompose = lambda self, ep: (time.sleep(0.4), original(self, ep))[1]
        from rdd.cli import main
        sys.exit(main({argv!r}))
    """)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-c", slow], cwd=ROOT, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while len(parts_of(out)) < 2 and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait()
    staged = len(parts_of(out))
    assert not out.exists() and 2 <= staged < len(NAMES), staged
    assert main(uvd_args(native_six, ref, None)) == 0
    calls: Counter = Counter()
    original = UVDDecomposer.decompose
    try:
        UVDDecomposer.decompose = lambda self, ep: (calls.update([ep.name]), original(self, ep))[1]
        assert main(argv) == 0
    finally:
        UVDDecomposer.decompose = original
    assert sum(calls.values()) == len(NAMES) - staged and set(calls.values()) == {1}
    assert out.read_bytes() == ref.read_bytes()


def test_changed_settings_reuse_no_part(native_six, tmp_path, monkeypatch):
    def uniform(n: int) -> list[str]:
        return ["decompose", "--format", "native", "--data", str(native_six), "--decomposer", "uniform",
                "--option", f"n_segments={n}", "--out", str(tmp_path / "out.json")]

    count_calls(monkeypatch, UniformDecomposer, stop_at=4)
    assert main(uniform(3)) == 130 and len(parts_of(tmp_path / "out.json")) == 4
    monkeypatch.undo()
    calls = count_calls(monkeypatch, UniformDecomposer)
    assert main(uniform(4)) == 0
    assert sorted(calls) == NAMES  # all six again: the staged parts were of n_segments=3
    import json

    episodes = json.loads((tmp_path / "out.json").read_text())["episodes"]
    assert [len(e["segments"]) for e in episodes] == [4] * 6


def test_two_workers_write_the_same_bytes(native_six, tmp_path, capsys):
    assert main(uvd_args(native_six, tmp_path / "one.json", None)) == 0
    assert main([*uvd_args(native_six, tmp_path / "two.json", None), "--workers", "2"]) == 0
    assert (tmp_path / "two.json").read_bytes() == (tmp_path / "one.json").read_bytes()
    build = ["build-db", "--format", "native", "--data", str(native_six), "--encoder", "pixels", "--encoder-option",
             "size=4", "--no-cache", "--calibration-sample", "2"]
    assert main([*build, "--out", str(tmp_path / "db1")]) == 0
    assert main([*build, "--out", str(tmp_path / "db2"), "--workers", "2"]) == 0
    assert tree_bytes(tmp_path / "db2") == tree_bytes(tmp_path / "db1")
    capsys.readouterr()
    assert main([*uvd_args(native_six, tmp_path / "x.json", None), "--workers", "0"]) == 2
    assert "--workers 0: must be >= 1" in capsys.readouterr().err


def test_build_db_resumes_its_embedding(native_six, tmp_path, monkeypatch):
    import rdd.cli.build_db as build_db

    build = ["build-db", "--format", "native", "--data", str(native_six), "--encoder", "pixels", "--encoder-option",
             "size=4", "--no-cache", "--calibration-sample", "2"]
    assert main([*build, "--out", str(tmp_path / "ref")]) == 0
    calls: list[str] = []
    original = build_db.segment_entries

    def counted(episodes, *args, **kwargs):
        if stop[0] is not None and len(calls) == stop[0]:
            raise KeyboardInterrupt
        calls.extend(e.name for e in episodes)
        return original(episodes, *args, **kwargs)

    stop = [4]
    monkeypatch.setattr(build_db, "segment_entries", counted)
    assert main([*build, "--out", str(tmp_path / "db")]) == 130
    assert not (tmp_path / "db").exists() and len(list((tmp_path / ".db.parts").iterdir())) == 4
    stop[0] = None
    assert main([*build, "--out", str(tmp_path / "db")]) == 0
    assert sorted(calls) == NAMES and len(calls) == 6  # each episode embedded once over both runs
    assert tree_bytes(tmp_path / "db") == tree_bytes(tmp_path / "ref")
    assert not (tmp_path / ".db.parts").exists()


def test_write_lerobot_resumes(lerobot_copy_argv, tmp_path, monkeypatch):
    import rdd.data.lerobot.write as writer

    argv = lerobot_copy_argv
    assert main(argv("ref")) == 0
    rewrites: list[str] = []
    original = writer._rewrite_data_file

    def counted(source, *args, **kwargs):
        if stop[0] and len(rewrites) == 1:
            raise KeyboardInterrupt
        rewrites.append(source.name)
        return original(source, *args, **kwargs)

    stop = [True]
    monkeypatch.setattr(writer, "_rewrite_data_file", counted)
    decomposed = count_calls(monkeypatch, UniformDecomposer)
    assert main(argv("copy")) == 130 and not (tmp_path / "copy").exists()
    stop[0] = False
    assert main(argv("copy")) == 0
    assert sorted(rewrites) == ["file-000.parquet", "file-001.parquet"]  # each data file rewritten once
    assert set(decomposed.values()) == {1} and len(decomposed) == 4  # and each episode decomposed once
    assert tree_bytes(tmp_path / "copy") == tree_bytes(tmp_path / "ref")
    assert not (tmp_path / ".copy.parts").exists()


def test_release_forgets_loaded_frames(native_six):
    """Episodes are released one at a time: a native episode's decoded frames are dropped (read again
    on the next load)."""
    ep = load_episode(native_six / "ep0")
    frames = ep.frames("front")
    assert ep.views["front"]._array is not None
    ep.release()
    assert ep.views["front"]._array is None
    assert np.array_equal(ep.frames("front"), frames)
