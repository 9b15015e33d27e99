"""``--write-lerobot`` writes v3.0 by default, also from a v2.1 source (issue 43, point 4): the copy read
back with pyarrow alone (every source column, episode index, LeRobot's language-column rules) and by
the project's own reader."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pa = pytest.importorskip("pyarrow")
pytest.importorskip("av")
import pyarrow.parquet as pq  # noqa: E402

from rdd.cli import main  # noqa: E402
from rdd.data.lerobot.reader import load_episodes  # noqa: E402

# LeRobot's language-column rules (huggingface/lerobot src/lerobot/datasets/language.py), restated.
PERSISTENT_ROW_FIELDS = ("role", "content", "style", "timestamp", "camera", "tool_calls")
EVENT_ROW_FIELDS = ("role", "content", "style", "camera", "tool_calls")
PERSISTENT_STYLES = {"subtask", "plan", "memory", "motion", "task_aug"}
EVENT_ONLY_STYLES = {"interjection", "vqa", "trace"}
VIEW_DEPENDENT_STYLES = {"vqa", "trace"}
LANGUAGE_FEATURE = {"dtype": "language", "shape": [1], "names": None}


def column_for_style(style: str | None) -> str:
    """LeRobot's routing of a style to its column (unknown styles are an error)."""
    if style is None or style in EVENT_ONLY_STYLES:
        return "language_events"
    if style in PERSISTENT_STYLES:
        return "language_persistent"
    raise ValueError(f"Unknown language style: {style!r}")


def check_language_rules(table, info: dict) -> None:
    """Every rule LeRobot's language module states, on a data table and its info.json."""
    for column, fields in (("language_persistent", PERSISTENT_ROW_FIELDS), ("language_events", EVENT_ROW_FIELDS)):
        assert info["features"][column] == LANGUAGE_FEATURE
        row_type = table.schema.field(column).type.value_type
        assert tuple(row_type.field(i).name for i in range(row_type.num_fields)) == fields
        assert not row_type.field("role").nullable
        if column == "language_persistent":
            assert row_type.field("timestamp").type == pa.float32() and not row_type.field("timestamp").nullable
        for rows in table.column(column).to_pylist():
            for r in rows:
                assert r["role"] is not None and column_for_style(r["style"]) == column
                if r["style"] in VIEW_DEPENDENT_STYLES:
                    assert r["camera"]
                else:
                    assert r["camera"] is None


def decompose(src: Path, out: Path, *extra) -> int:
    return main([str(a) for a in ("decompose", "--format", "lerobot", "--data", src, "--decomposer", "uniform",
                                  "--option", "n_segments=3", "--fallback-instruction", "{task}: part {index}",
                                  "--write-lerobot", out, *extra)])


def test_v21_source_is_written_as_v30(lerobot_factory, tmp_path):
    src = lerobot_factory("v2.1", lengths=(30, 36, 24))
    out = tmp_path / "v30"
    assert decompose(src, out) == 0
    info = json.loads((out / "meta/info.json").read_text())
    info_src = json.loads((src / "meta/info.json").read_text())
    assert info["codebase_version"] == "v3.0" and info["total_episodes"] == 3 and info["total_frames"] == 90
    assert info["data_path"] == "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
    assert info["video_path"] == "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
    assert {k: v for k, v in info["features"].items() if not k.startswith("language_")} == info_src["features"]
    files = sorted((out / "data").glob("chunk-*/file-*.parquet"))
    assert [f.relative_to(out).as_posix() for f in files] == ["data/chunk-000/file-000.parquet"]  # many per file
    table = pa.concat_tables([pq.read_table(f) for f in files])
    source = pa.concat_tables([pq.read_table(p) for p in sorted((src / "data").rglob("*.parquet"))])
    assert table.column_names == source.column_names + ["language_persistent", "language_events"]
    assert table.select(source.column_names).equals(source)  # every source column, every row, unchanged
    assert pq.ParquetFile(files[0]).metadata.num_row_groups == 3  # one row group per episode
    check_language_rules(table, info)
    eps = table.column("episode_index").to_pylist()
    persistent = table.column("language_persistent").to_pylist()
    for ep, n in enumerate((30, 36, 24)):
        rows = [persistent[i] for i, e in enumerate(eps) if e == ep]
        assert len(rows) == n and all(r == rows[0] for r in rows)
        assert [r["content"] for r in rows[0]] == [f"stack the cups: part {i}" for i in (1, 2, 3)]
    meta = pq.read_table(out / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert [m["episode_index"] for m in meta] == [0, 1, 2] and [m["length"] for m in meta] == [30, 36, 24]
    assert [(m["dataset_from_index"], m["dataset_to_index"]) for m in meta] == [(0, 30), (30, 66), (66, 90)]
    key = "observation.images.top"
    for m in meta:
        assert (m["data/chunk_index"], m["data/file_index"]) == (0, 0) and m["tasks"] == ["stack the cups"]
        video = out / info["video_path"].format(video_key=key, chunk_index=m[f"videos/{key}/chunk_index"],
                                                file_index=m[f"videos/{key}/file_index"])
        assert video.is_file() and m[f"videos/{key}/from_timestamp"] == 0.0
        assert m[f"videos/{key}/to_timestamp"] == pytest.approx(m["length"] / info["fps"])
    tasks = pq.read_table(out / "meta/tasks.parquet")
    assert tasks.to_pydict() == {"task_index": [0], "task": ["stack the cups"]}
    assert not (out / "meta/episodes.jsonl").exists() and (out / "README.md").read_text() == "toy dataset\n"
    # the project's own reader: the sub-tasks as written, the frames as the source's
    back, before = load_episodes(out), load_episodes(src)
    assert [e.name for e in back] == [e.name for e in before] and back[0].meta["format"] == "lerobot-v3.0"
    for new, old in zip(back, before, strict=True):
        assert new.instructions == [f"stack the cups: part {i}" for i in (1, 2, 3)] and new.task == old.task
        np.testing.assert_array_equal(new.frames("top", [0, new.num_frames - 1]),
                                      old.frames("top", [0, old.num_frames - 1]))


def test_lerobot_version_option(lerobot_factory, tmp_path, capsys):
    src = lerobot_factory("v2.1", lengths=(20, 24))
    assert decompose(src, tmp_path / "v21", "--lerobot-version", "2.1") == 0
    assert json.loads((tmp_path / "v21/meta/info.json").read_text())["codebase_version"] == "v2.1"
    assert (tmp_path / "v21/data/chunk-000/episode_000001.parquet").is_file()
    src3 = lerobot_factory("v3.0", lengths=(20, 24))
    capsys.readouterr()
    assert decompose(src3, tmp_path / "no", "--lerobot-version", "2.1") == 2
    assert "--lerobot-version 2.1" in capsys.readouterr().err and not (tmp_path / "no").exists()
