"""Sub-tasks written into LeRobot datasets (v2.1, v3.0) and read back: schema checked with pyarrow
alone, broadcast per episode, frame timestamps, untouched files byte-identical, and the round trip
decompose -> --write-lerobot -> build-db --segments subtasks."""

from __future__ import annotations

import filecmp
import json
from pathlib import Path

import numpy as np
import pytest

pa = pytest.importorskip("pyarrow")
pytest.importorskip("av")
import pyarrow.parquet as pq  # noqa: E402

from rdd.cli import main  # noqa: E402
from rdd.data.lerobot.reader import load_episodes  # noqa: E402
from rdd.data.lerobot.write import write_subtasks  # noqa: E402
from rdd.database.model import SubtaskDatabase  # noqa: E402

LANG = {"dtype": "language", "shape": [1], "names": None}


def run(*argv) -> int:
    return main([str(a) for a in argv])


def data_files(root: Path) -> list[Path]:
    return sorted((root / "data").rglob("*.parquet"))


def check_copy(src: Path, out: Path, subtasks: dict[int, tuple[list, list[str]]]) -> None:
    """Everything the issue asks of a written dataset, read with pyarrow and json only."""
    info_src = json.loads((src / "meta/info.json").read_text())
    info = json.loads((out / "meta/info.json").read_text())
    assert info["features"]["language_persistent"] == LANG and info["features"]["language_events"] == LANG
    assert {k: v for k, v in info["features"].items() if not k.startswith("language_")} == info_src["features"]
    assert {k: v for k, v in info.items() if k != "features"} == {k: v for k, v in info_src.items() if k != "features"}
    # Every other file: byte-identical.
    for path in src.rglob("*"):
        rel = path.relative_to(src)
        if path.is_file() and rel.parts[0] != "data" and rel != Path("meta/info.json"):
            assert filecmp.cmp(path, out / rel, shallow=False), rel
    seen = set()
    for path in data_files(src):
        rel = path.relative_to(src)
        before, after = pq.read_table(path), pq.read_table(out / rel)
        assert after.select(before.column_names).equals(before)  # source columns unchanged
        p_type = after.schema.field("language_persistent").type
        assert pa.types.is_list(p_type)
        row = p_type.value_type
        assert [row.field(i).name for i in range(row.num_fields)] == [
            "role", "content", "style", "timestamp", "camera", "tool_calls"]
        assert row.field("timestamp").type == pa.float32()
        e_row = after.schema.field("language_events").type.value_type
        assert [e_row.field(i).name for i in range(e_row.num_fields)] == [
            "role", "content", "style", "camera", "tool_calls"]
        eps = after.column("episode_index").to_pylist()
        ts = after.column("timestamp").to_numpy()
        persistent = after.column("language_persistent").to_pylist()
        assert after.column("language_events").to_pylist() == [[] for _ in eps]
        meta = pq.ParquetFile(out / rel).metadata
        order = list(dict.fromkeys(eps))
        assert meta.num_row_groups == len(order)  # one row group per episode
        assert [meta.row_group(i).num_rows for i in range(len(order))] == [eps.count(e) for e in order]
        for ep in order:
            rows_of_ep = [i for i, e in enumerate(eps) if e == ep]
            lists = [persistent[i] for i in rows_of_ep]
            if ep not in subtasks:
                assert all(x == [] for x in lists)
                continue
            seen.add(ep)
            assert all(x == lists[0] for x in lists)  # the same slice on every frame
            segments, instructions = subtasks[ep]
            frame_ts = ts[rows_of_ep]
            expected = [{"role": "assistant", "content": text, "style": "subtask",
                         "timestamp": float(np.float32(frame_ts[s])), "camera": None, "tool_calls": None}
                        for (s, _e), text in zip(segments, instructions, strict=True)]
            assert lists[0] == expected
            assert {r["timestamp"] for r in lists[0]} <= {float(t) for t in frame_ts}
    assert seen == set(subtasks)


@pytest.mark.parametrize("version", ["v2.1", "v3.0"])
def test_write_schema_broadcast_and_untouched_files(lerobot_factory, tmp_path, version):
    src = lerobot_factory(version)
    subtasks = {0: ([(0, 10), (10, 22), (22, 30)], ["reach the cup", "grasp the cup", "lift the cup"]),
                2: ([(0, 24)], ["put it down"])}
    out = write_subtasks(src, tmp_path / "out", subtasks)
    check_copy(src, out, subtasks)
    # The reader gives the segments and instructions back; the episode without sub-tasks has none.
    eps = {e.meta["episode_index"]: e for e in load_episodes(out)}
    for ep, (segments, instructions) in subtasks.items():
        assert eps[ep].segments == segments and eps[ep].instructions == instructions
    assert eps[1].segments is None
    # Writing again over an annotated copy replaces the subtask rows (no duplicates).
    again = write_subtasks(out, tmp_path / "again", {0: ([(0, 30)], ["do it all"])})
    assert load_episodes(again)[0].instructions == ["do it all"]
    assert load_episodes(again)[2].instructions == ["put it down"]  # kept


def test_write_refusals(lerobot_factory, tmp_path):
    src = lerobot_factory("v3.0")
    with pytest.raises(ValueError, match="source dataset"):
        write_subtasks(src, src / "inside", {0: ([(0, 30)], ["x"])})
    with pytest.raises(ValueError, match="source dataset"):
        write_subtasks(src, src, {0: ([(0, 30)], ["x"])})
    with pytest.raises(ValueError, match="no instruction"):
        write_subtasks(src, tmp_path / "o", {0: ([(0, 10), (10, 30)], ["x", " "])})
    with pytest.raises(ValueError, match="must end at 30"):
        write_subtasks(src, tmp_path / "o", {0: ([(0, 10)], ["x"])})
    assert not (tmp_path / "o").exists()
    (tmp_path / "exists").mkdir()
    with pytest.raises(FileExistsError, match="exists"):
        write_subtasks(src, tmp_path / "exists", {0: ([(0, 30)], ["x"])})


@pytest.mark.parametrize("version", ["v2.1", "v3.0"])
def test_copy_shares_no_editable_file_with_the_source(lerobot_factory, tmp_path, version):
    src = lerobot_factory(version)
    before = {p.relative_to(src): p.read_bytes() for p in src.rglob("*") if p.is_file()}
    out = write_subtasks(src, tmp_path / "out", {0: ([(0, 30)], ["do it"])})
    shared = [p.relative_to(out) for p in out.rglob("*")
              if p.is_file() and (src / p.relative_to(out)).is_file() and p.samefile(src / p.relative_to(out))]
    assert shared and all(p.suffix == ".mp4" for p in shared)  # only the videos are hard-linked
    for p in out.rglob("*"):  # edit every non-video file of the copy in place
        if p.is_file() and p.suffix != ".mp4":
            with open(p, "ab") as fh:
                fh.write(b"edited")
    assert {p.relative_to(src): p.read_bytes() for p in src.rglob("*") if p.is_file()} == before


def test_copy_without_links_shares_nothing(lerobot_factory, tmp_path):
    src = lerobot_factory("v2.1")
    out = write_subtasks(src, tmp_path / "out", {0: ([(0, 30)], ["do it"])}, link=False)
    assert not any(p.samefile(src / p.relative_to(out)) for p in out.rglob("*")
                   if p.is_file() and (src / p.relative_to(out)).is_file())


@pytest.mark.parametrize("version", ["v2.1", "v3.0"])
def test_round_trip_through_the_cli(lerobot_factory, tmp_path, capsys, version):
    src = lerobot_factory(version)
    cache = ["--cache-dir", tmp_path / "cache"]
    out = tmp_path / "annotated"
    # No instruction from the uniform decomposer and no fallback: the signals labeler names what the
    # robot does. Episode 0 (30 frames): the arm moves but for frames 11-13, the gripper closes at 15.
    assert run("decompose", "--format", "lerobot", "--data", src, "--decomposer", "uniform",
               "--option", "n_segments=3", "--write-lerobot", tmp_path / "signals", "--out", tmp_path / "s.json") == 0
    recs = json.loads((tmp_path / "s.json").read_text())["episodes"]
    assert all(set(r["instruction_sources"]) == {"labeler"} for r in recs)
    assert recs[0]["instructions"] == ["arm moves", "arm moves and gripper closes", "arm moves"]
    assert load_episodes(tmp_path / "signals")[0].instructions == recs[0]["instructions"]
    assert run("decompose", "--format", "lerobot", "--data", src, "--decomposer", "uniform",
               "--option", "n_segments=3", "--fallback-instruction", "{task}, step {index} of {count}",
               "--out", tmp_path / "u.json", "--write-lerobot", out,
               *(["--lerobot-version", "2.1"] if version == "v2.1" else [])) == 0  # the source's layout
    written = json.loads((tmp_path / "u.json").read_text())["episodes"]
    subtasks = {int(r["episode"].split("_")[-1]): ([tuple(s) for s in r["segments"]], r["instructions"])
                for r in written}
    assert subtasks[0][1] == [f"stack the cups, step {i} of 3" for i in (1, 2, 3)]
    check_copy(src, out, subtasks)
    assert run("build-db", "--format", "lerobot", "--data", out, "--segments", "subtasks", "--encoder", "pixels",
               "--encoder-option", "size=4", *cache, "--out", tmp_path / "db") == 0
    db = SubtaskDatabase.load(tmp_path / "db")
    got = {}
    for ep, s, e, label in zip(db.episodes, db.starts, db.ends, db.labels, strict=True):
        got.setdefault(int(ep.split("_")[-1]), ([], []))
        got[int(ep.split("_")[-1])][0].append((s, e))
        got[int(ep.split("_")[-1])][1].append(label)
    assert got == subtasks  # the round trip reproduces segments and instructions exactly
    # rdd's instructions are its matched entries': no fallback needed, and they come back as written.
    assert run("decompose", "--format", "lerobot", "--data", src, "--decomposer", "rdd", "--db", tmp_path / "db",
               "--encoder-option", "size=4", *cache, "--out", tmp_path / "r.json",
               "--write-lerobot", tmp_path / "rdd_out") == 0
    recs = json.loads((tmp_path / "r.json").read_text())["episodes"]
    back = {e.name: e for e in load_episodes(tmp_path / "rdd_out")}
    for r in recs:
        assert set(r["instructions"]) <= set(db.labels)
        assert back[r["episode"]].segments == [tuple(s) for s in r["segments"]]
        assert back[r["episode"]].instructions == r["instructions"]
    # A decomposer without instructions may name a labeler: the nearest entry's instruction.
    assert run("decompose", "--format", "lerobot", "--data", src, "--decomposer", "uniform", "--option",
               "n_segments=2", "--labeler", "retrieval", "--label-db", tmp_path / "db", "--encoder-option", "size=4",
               *cache, "--out", tmp_path / "l.json", "--write-lerobot", tmp_path / "labelled") == 0
    recs = json.loads((tmp_path / "l.json").read_text())["episodes"]
    assert all(r["instruction_sources"] == ["labeler", "labeler"] for r in recs)
    assert all(set(r["instructions"]) <= set(db.labels) for r in recs)
    assert [e.instructions for e in load_episodes(tmp_path / "labelled")] == [r["instructions"] for r in recs]


def test_cli_write_refusals(lerobot_factory, tmp_path, capsys):
    src = lerobot_factory("v2.1")
    common = ["decompose", "--format", "lerobot", "--data", src, "--decomposer", "uniform", "--option",
              "n_segments=2", "--fallback-instruction", "part {index}"]
    assert run(*common, "--write-lerobot", src / "copy") == 2
    assert "source dataset" in capsys.readouterr().err and not (src / "copy").exists()
    (tmp_path / "there").mkdir()
    assert run(*common, "--write-lerobot", tmp_path / "there") == 2
    assert "already exists" in capsys.readouterr().err
    assert run(*common, "--fallback-instruction", "{nope}", "--write-lerobot", tmp_path / "n") == 2
    assert "{task}" in capsys.readouterr().err
    assert run("decompose", "--format", "native", "--data", src, "--decomposer", "uniform",
               "--write-lerobot", tmp_path / "n") == 2
    assert "--format lerobot" in capsys.readouterr().err


def test_build_db_segments_default_and_required(lerobot_factory, tmp_path, capsys):
    src = lerobot_factory("v2.1")
    enc = ["--encoder", "pixels", "--encoder-option", "size=4", "--cache-dir", tmp_path / "cache"]
    assert run("build-db", "--format", "lerobot", "--data", src, "--segments", "subtasks", *enc,
               "--out", tmp_path / "db") == 2
    assert "carry no sub-task annotations" in capsys.readouterr().err
    assert run("build-db", "--format", "lerobot", "--data", src, *enc, "--out", tmp_path / "db") == 0
    assert "segments: expert" in capsys.readouterr().err
    assert SubtaskDatabase.load(tmp_path / "db").meta["source"]["segmenter"] == "expert"
    # An existing database is not replaced without --force.
    assert run("build-db", "--format", "lerobot", "--data", src, *enc, "--out", tmp_path / "db") == 2
    assert "--force" in capsys.readouterr().err
    assert run("build-db", "--format", "lerobot", "--data", src, *enc, "--out", tmp_path / "db", "--force") == 0


def test_reader_option_typos_are_one_line_errors(lerobot_factory, tmp_path, capsys):
    src = lerobot_factory("v3.0")
    for option, expect in [("gripper_indx=[3]", "unknown LeRobot reader option(s) ['gripper_indx']"),
                           ("gripper_indices=3", "gripper_indices=3: expected"),
                           ("episodes=[7]", "episodes: [7] are not listed")]:
        capsys.readouterr()
        assert run("decompose", "--format", "lerobot", "--data", src, "--reader-option", option,
                   "--decomposer", "expert", "--out", tmp_path / "x.json") == 2
        err = capsys.readouterr().err
        assert expect in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "x.json").exists()
