"""Bad LeRobot data is an InputError whose one line names the file, the episode and the field
(issue 39): fps that is not a positive number or disagrees with the timestamps, NaN/inf in the
state, timestamps that go back, a parquet shorter than its recorded length, malformed metadata."""

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
from rdd.errors import InputError  # noqa: E402

EP0 = "data/chunk-000/episode_000000.parquet"


def edit_info(root: Path, **fields) -> None:
    path = root / "meta/info.json"
    info = json.loads(path.read_text())
    info.update(fields)
    path.write_text(json.dumps(info))


def edit_column(path: Path, name: str, change) -> None:
    """Rewrite column ``name`` of parquet ``path`` as ``change(values)`` (a Python list)."""
    table = pq.read_table(path)
    i = table.column_names.index(name)
    values = change(table.column(name).to_pylist())
    pq.write_table(table.set_column(i, table.schema.field(name), pa.array(values, type=table.schema.field(name).type)),
                   path)


def error_of(root: Path) -> str:
    with pytest.raises(InputError) as info:
        load_episodes(root)
    message = str(info.value)
    assert "\n" not in message
    return message


@pytest.mark.parametrize("fps", [60, -5, 0, "thirty", True, None, [30]])
def test_bad_fps_names_info_json_and_the_field(lerobot_factory, fps):
    root = lerobot_factory()
    edit_info(root, fps=fps)
    message = error_of(root)
    assert "meta/info.json" in message and "'fps'" in message
    if fps == 60:  # usable as a number, but the timestamps say 10 fps
        assert "episode 0" in message and "10 fps" in message


def test_fps_close_to_the_timestamps_is_accepted(lerobot_factory):
    root = lerobot_factory(lengths=(12,))
    edit_info(root, fps=10.4)  # within the tolerance for recorded timestamps
    assert load_episodes(root)[0].meta["fps"] == 10.4


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_state_names_file_episode_and_field(lerobot_factory, bad):
    root = lerobot_factory()
    edit_column(root / EP0, "observation.state", lambda rows: [r if i != 7 else [0.0, bad, 0.0, 1.0]
                                                              for i, r in enumerate(rows)])
    message = error_of(root)
    assert EP0 in message and "episode 0" in message and "'observation.state'" in message and "frame 7" in message


def test_timestamps_going_back_name_file_episode_and_field(lerobot_factory):
    root = lerobot_factory()
    edit_column(root / EP0, "timestamp", lambda ts: [t if i != 5 else ts[3] for i, t in enumerate(ts)])
    message = error_of(root)
    assert EP0 in message and "episode 0" in message and "'timestamp'" in message and "not increasing" in message


def test_non_finite_timestamp_is_named(lerobot_factory):
    root = lerobot_factory()
    edit_column(root / EP0, "timestamp", lambda ts: [t if i != 2 else float("nan") for i, t in enumerate(ts)])
    assert "'timestamp'" in error_of(root)


def test_parquet_shorter_than_recorded_length(lerobot_factory):
    root = lerobot_factory()
    table = pq.read_table(root / EP0)
    pq.write_table(table.slice(0, 20), root / EP0)
    message = error_of(root)
    assert EP0 in message and "episode 0" in message and "'length' 30" in message
    assert "meta/episodes.jsonl" in message and "20 rows" in message


def test_parquet_shorter_than_recorded_length_v3(lerobot_factory):
    root = lerobot_factory("v3.0")
    path = root / "data/chunk-000/file-001.parquet"  # episode 2 alone
    pq.write_table(pq.read_table(path).slice(0, 10), path)
    message = error_of(root)
    assert "file-001.parquet" in message and "episode 2" in message and "meta/episodes/chunk-000" in message


@pytest.mark.parametrize("features, field", [
    (["observation.state"], "'features'"),
    ("observation.state", "'features'"),
    ({"observation.state": "float32"}, "'features.observation.state'"),
    ({"observation.state": {"dtype": 32}}, "'features.observation.state.dtype'"),
])
def test_features_of_the_wrong_type(lerobot_factory, features, field):
    root = lerobot_factory()
    edit_info(root, features=features)
    message = error_of(root)
    assert "meta/info.json" in message and field in message


@pytest.mark.parametrize("fields, named", [
    ({"chunks_size": "many"}, "'chunks_size'"),
    ({"data_path": 7}, "'data_path'"),
    ({"data_path": "data/{chunk}/episode_{episode_index}.parquet"}, "'data_path'"),
    ({"video_path": "videos/{nope}.mp4"}, "'video_path'"),
])
def test_bad_info_fields_are_named(lerobot_factory, fields, named):
    root = lerobot_factory()
    edit_info(root, **fields)
    message = error_of(root)
    assert "meta/info.json" in message and named in message


def test_info_json_not_an_object(lerobot_factory):
    root = lerobot_factory()
    (root / "meta/info.json").write_text("[1, 2]")
    assert "meta/info.json" in error_of(root)


def test_bad_task_record_names_the_line(lerobot_factory):
    root = lerobot_factory()
    (root / "meta/tasks.jsonl").write_text('{"task_index": 0, "task": "x"}\n{"task": "no index"}\n')
    assert "meta/tasks.jsonl:2" in error_of(root)


def test_bad_episode_metadata_field_v3(lerobot_factory):
    root = lerobot_factory("v3.0")
    path = next((root / "meta/episodes").rglob("*.parquet"))
    table = pq.read_table(path)
    i = table.column_names.index("data/file_index")
    pq.write_table(table.set_column(i, "data/file_index", pa.array(["zero"] * table.num_rows)), path)
    message = error_of(root)
    assert str(path.relative_to(root)) in message and "'data/file_index'" in message and "episode 0" in message


def test_cli_prints_one_line(lerobot_factory, tmp_path, capsys):
    root = lerobot_factory()
    edit_info(root, fps="thirty")
    code = main(["decompose", "--format", "lerobot", "--data", str(root), "--decomposer", "uniform",
                 "--out", str(tmp_path / "o.json"), "--no-cache"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "'fps'" in err[0] and "info.json" in err[0]
    assert not (tmp_path / "o.json").exists()


def test_good_data_reads_as_before(lerobot_factory):
    eps = load_episodes(lerobot_factory("v3.0"))
    assert [e.num_frames for e in eps] == [30, 36, 24]
    assert all(np.isfinite(e.joint_positions).all() for e in eps)
