"""``--include`` / ``--exclude`` / ``episodes=`` open only the chosen episodes' files (issue 43, point 5)."""

from __future__ import annotations

import builtins
import json
from pathlib import Path

import pytest

from rdd.cli import main


def _corrupt_episode(root: Path, version: str) -> list[Path]:
    """Break every file of episode 2 (alone in its files in both layouts): garbage parquet and mp4."""
    if version == "v2.1":
        paths = [root / "data/chunk-000/episode_000002.parquet",
                 root / "videos/chunk-000/observation.images.top/episode_000002.mp4"]
    else:
        paths = [root / "data/chunk-000/file-001.parquet",
                 root / "videos/observation.images.top/chunk-000/file-001.mp4"]
    for p in paths:
        p.write_bytes(b"not a parquet or mp4 file")
    return paths


def _record_opens(monkeypatch) -> list[str]:
    """Every path passed to open / pyarrow's file opening, so a test can say what was never touched."""
    import pyarrow.parquet as pq

    seen: list[str] = []
    real_open, real_read = builtins.open, pq.read_table

    def spy_open(file, *a, **k):
        seen.append(str(file))
        return real_open(file, *a, **k)

    def spy_read(source, *a, **k):
        seen.append(str(source))
        return real_read(source, *a, **k)

    monkeypatch.setattr(builtins, "open", spy_open)
    monkeypatch.setattr(pq, "read_table", spy_read)
    return seen


@pytest.mark.parametrize("version", ["v2.1", "v3.0"])
def test_include_never_opens_an_excluded_episode(lerobot_factory, tmp_path, monkeypatch, capsys, version):
    src = lerobot_factory(version)
    broken = _corrupt_episode(src, version)
    seen = _record_opens(monkeypatch)
    for flags in (["--include", "episode_000000"], ["--exclude", "episode_000002"]):
        out = tmp_path / f"{version}_{flags[0][2:]}.json"
        assert main(["decompose", "--format", "lerobot", "--data", str(src), *flags, "--decomposer", "uniform",
                     "--option", "n_segments=2", "--out", str(out)]) == 0
        names = [e["episode"] for e in json.loads(out.read_text())["episodes"]]
        assert names == (["episode_000000"] if flags[0] == "--include" else ["episode_000000", "episode_000001"])
    assert not any(str(b) in s for b in broken for s in seen)
    # Without the selection the broken episode is read and stops the run, as it should.
    capsys.readouterr()
    assert main(["decompose", "--format", "lerobot", "--data", str(src), "--decomposer", "uniform",
                 "--out", str(tmp_path / "all.json")]) != 0
    assert str(broken[0].name) in capsys.readouterr().err


def test_episodes_option_reads_only_those(lerobot_factory):
    from rdd.data.lerobot.reader import episode_names, load_episodes

    src = lerobot_factory("v2.1")
    _corrupt_episode(src, "v2.1")
    assert [e.name for e in load_episodes(src, episodes=[1])] == ["episode_000001"]
    assert [e.name for e in load_episodes(src, names={"episode_000000"})] == ["episode_000000"]
    assert episode_names(src) == ["episode_000000", "episode_000001", "episode_000002"]


def test_unknown_include_names_the_episodes(lerobot_factory, cli_fails, tmp_path):
    src = lerobot_factory("v2.1")
    cli_fails("decompose", "--format", "lerobot", "--data", src, "--include", "episode_000009",
              "--decomposer", "uniform", "--out", tmp_path / "x.json",
              expect=("--include", "episode_000009", "episode_000002"))


def test_rlbench_and_native_read_only_named_episodes(tmp_path, toy_native):
    from rdd.data import native, rlbench

    for k in range(2):  # two RLBench episodes whose low_dim files are garbage
        (tmp_path / "rl" / f"episode{k}").mkdir(parents=True)
        (tmp_path / "rl" / f"episode{k}" / rlbench.LOW_DIM_FILE).write_bytes(b"garbage")
    assert rlbench.episode_names(tmp_path / "rl") == ["episode0", "episode1"]
    assert rlbench.load_episodes(tmp_path / "rl", names=set()) == []
    with pytest.raises(Exception, match="episode1"):  # only the chosen one is opened, and it is broken
        rlbench.load_episodes(tmp_path / "rl", names={"episode1"})
    native_eps = native.load_episodes(toy_native, names={"ep1"})
    assert [e.name for e in native_eps] == ["ep1"]
    assert native.episode_names(toy_native) == ["ep0", "ep1", "ep2"]
