"""A database's manifest is covered by its integrity check (issue 39): a hand-edited field is a
one-line DatabaseError naming the file and the field; format-1 databases (no field checksums) still
load, with a warning, and calibrating one seals it."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest

from rdd.cli import main
from rdd.database.model import DatabaseError, SubtaskDatabase
from rdd.database.store import SEAL

CALIBRATION = {"chosen": {"alpha": 0.5, "min_len": 2, "max_len": None}, "score": 0.8}


@pytest.fixture
def saved(tmp_path) -> Path:
    rng = np.random.default_rng(0)
    meta = {"encoder": "pixels", "weights_id": "w1", "views": ["front", "wrist"], "normalize_views": True,
            "episodes": ["a", "a", "b"], "tasks": ["t"] * 3, "starts": [0, 4, 0], "ends": [4, 9, 7]}
    db = SubtaskDatabase.from_arrays(rng.normal(size=(3, 8)), rng.normal(size=(3, 8)), [3, 4, 6],
                                     ["reach", "grasp", "lift"], meta)
    db.save(tmp_path / "db")
    db.save_calibration(CALIBRATION)
    return tmp_path / "db"


def manifest_of(root: Path) -> dict:
    return json.loads((root / "manifest.json").read_text())


def write_manifest(root: Path, manifest: dict) -> None:
    (root / "manifest.json").write_text(json.dumps(manifest, indent=2))


def load_error(root: Path) -> str:
    with pytest.raises(DatabaseError) as info:
        SubtaskDatabase.load(root)
    text = str(info.value)
    assert "\n" not in text and str(root) in text
    return text


def test_untouched_database_loads(saved):
    db = SubtaskDatabase.load(saved)
    assert db.meta["views"] == ["front", "wrist"] and db.calibrated_options()["alpha"] == 0.5
    assert set(manifest_of(saved)[SEAL]) == set(manifest_of(saved)) - {SEAL}


def test_reformatted_manifest_still_loads(saved):
    """Only the values are sealed: indentation and key order may change."""
    (saved / "manifest.json").write_text(json.dumps(manifest_of(saved), indent=7, sort_keys=True))
    assert len(SubtaskDatabase.load(saved)) == 3


@pytest.mark.parametrize("field, value", [
    ("views", ["wrist", "front"]),
    ("encoder", "clip"),
    ("weights_id", "w2"),
    ("normalize_views", False),
    ("calibration", {**CALIBRATION, "chosen": {"alpha": 5.0, "min_len": 2, "max_len": None}}),
    ("extra", {"note": "x"}),
])
def test_edited_field_is_named(saved, field, value):
    manifest = manifest_of(saved)
    manifest[field] = value
    write_manifest(saved, manifest)
    text = load_error(saved)
    assert "manifest.json" in text and f"field '{field}'" in text


def test_removed_field_and_removed_seal_are_named(saved):
    manifest = manifest_of(saved)
    del manifest["normalize_views"]
    write_manifest(saved, manifest)
    assert "'normalize_views' was removed" in load_error(saved)
    del manifest[SEAL]
    write_manifest(saved, manifest)
    assert f"'{SEAL}'" in load_error(saved)


def test_fields_the_files_contradict_keep_their_own_message(saved):
    manifest = manifest_of(saved)
    manifest["count"] = 4
    write_manifest(saved, manifest)
    assert "has shape (3, 8), manifest says (4, 8)" in load_error(saved)


def test_calibrating_never_seals_a_hand_edit(saved):
    db = SubtaskDatabase.load(saved)
    manifest = manifest_of(saved)
    manifest["views"] = ["wrist", "front"]
    write_manifest(saved, manifest)
    with pytest.raises(DatabaseError, match="'views'"):
        db.save_calibration(CALIBRATION)
    assert manifest_of(saved) == manifest


def test_format_1_database_loads_with_a_warning_and_calibration_seals_it(saved, caplog):
    manifest = manifest_of(saved)
    del manifest[SEAL]
    manifest["format_version"] = 1
    write_manifest(saved, manifest)
    with caplog.at_level(logging.WARNING):
        db = SubtaskDatabase.load(saved)
    assert db.meta["views"] == ["front", "wrist"]
    assert "format_version 1" in caplog.text and "rebuild" in caplog.text
    db.save_calibration(CALIBRATION)
    assert manifest_of(saved)["format_version"] == 2 and SEAL in manifest_of(saved)
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        SubtaskDatabase.load(saved)
    assert caplog.text == ""


def test_cli_prints_one_line(saved, capsys):
    manifest = manifest_of(saved)
    manifest["views"] = ["wrist", "front"]
    write_manifest(saved, manifest)
    assert main(["calibrate", "--db", str(saved)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "manifest.json" in err[0] and "'views'" in err[0]
