"""The independent hand annotation (benchmarks/annotate_hand_hysteresis.py): on synthetic hand signals
with boundaries known by construction, and end to end on a small LeRobot dataset whose annotated copy
``build-db --segments subtasks`` reads back."""

from __future__ import annotations

import json

import numpy as np
import pytest


@pytest.fixture(scope="module")
def hyst(benchmark_module):
    return benchmark_module("annotate_hand_hysteresis")


def ramp(start: float, stop: float, frames: int) -> np.ndarray:
    """``frames`` values from ``start`` towards ``stop`` (the last one is ``stop``), 0.04 apart for 10 frames."""
    return np.linspace(start, stop, frames + 1)[1:]


def right_hand() -> np.ndarray:
    """Rest 0.5 (closed), a 3-frame flicker to 0.8, wiggles between the thresholds, open, grasp, release, close.

    By construction (thresholds 0.75 / 0.65, steps of 0.04 on each 10-frame ramp from 0.5 or 0.9):
    the opening ramp starting after frame 59 first exceeds 0.75 at 0.5 + 7 * 0.04 = 0.78, frame 66;
    the closing ramp after frame 119 first falls under 0.65 at 0.9 - 7 * 0.04 = 0.62, frame 126;
    the reopening after 179 at frame 186, the final closing after 239 at frame 246.
    """
    parts = [np.full(20, 0.5), np.full(3, 0.8), np.full(17, 0.5),  # flicker: frames 20-22
             np.tile([0.7, 0.68, 0.72, 0.66], 5),  # frames 40-59: between the thresholds, no change
             ramp(0.5, 0.9, 10), np.full(50, 0.9),  # opens: frames 60-69, then open until 119
             ramp(0.9, 0.5, 10), np.full(50, 0.5),  # grasps: 120-129
             ramp(0.5, 0.9, 10), np.full(50, 0.9),  # releases: 180-189
             ramp(0.9, 0.5, 10), np.full(50, 0.5)]  # closes: 240-249, then rests until 299
    return np.concatenate(parts)


def test_known_boundaries_of_one_hand(hyst):
    x = right_hand()
    assert x.size == 300 and x[66] > 0.75 >= x[65] and x[126] < 0.65 <= x[125]
    segments, instructions = hyst.annotate({"right": x}, fps=30)  # dwell 0.2 s = 6 frames: the flicker goes
    assert segments == [(0, 66), (66, 126), (126, 186), (186, 246), (246, 300)]
    assert instructions == ["open the right hand", "close the right hand", "open the right hand",
                            "close the right hand", "hold the right hand closed"]
    # At 10 fps the dwell is 2 frames and the 3-frame flicker counts as an opening and a closing.
    segments, _ = hyst.annotate({"right": x}, fps=10)
    assert segments == [(0, 20), (20, 23), (23, 66), (66, 126), (126, 186), (186, 246), (246, 300)]


def test_two_hands_merge_and_ends_are_kept_clear(hyst):
    x = right_hand()
    left = np.full(300, 0.5)
    left[128:] = 0.9  # opens 2 frames after the right hand closes: one cut at their mean frame, 127
    left[297:] = 0.5  # closes 3 frames before the end: the state does not last the dwell, no change
    segments, instructions = hyst.annotate({"left": left, "right": x}, fps=30)
    assert segments == [(0, 66), (66, 127), (127, 186), (186, 246), (246, 300)]
    assert instructions[1] == "close the right hand and open the left hand"
    assert instructions[-1] == "hold the left hand open and hold the right hand closed"
    with pytest.raises(ValueError, match="--closed-below 0.8 must be below --open-above 0.75"):
        hyst.annotate({"right": x}, fps=30, closed_below=0.8)


def test_debounce_undoes_flickers_and_a_cut_short_state(hyst):
    s = np.array([0] * 5 + [1] * 2 + [0] * 5 + [1] * 6 + [0] * 2, dtype=bool)
    assert hyst.debounced_changes(s, 3) == [(12, True)]  # 5-6: flicker; 18-19: cut short by the end
    assert hyst.debounced_changes(s, 2) == [(5, True), (7, False), (12, True), (18, False)]


def test_annotated_copy_reads_back_through_build_db(hyst, lerobot_factory, tmp_path, capsys):
    from rdd.cli import main
    from rdd.database.model import SubtaskDatabase

    # The factory's gripper dim (3) is 1 (open) for frames < n // 2 and 0 after; 10 fps, dwell 2 frames.
    lengths = (30, 36, 24)
    src = lerobot_factory("v2.1", lengths=lengths)
    result = hyst.main(["--data", str(src), "--copies", str(tmp_path / "copies"), "--json",
                        str(tmp_path / "hands.json"), "--hand", "gripper=3"])
    expected = {f"episode_{k:06d}": [[0, n // 2], [n // 2, n]] for k, n in enumerate(lengths)}
    assert {r["episode"]: r["segments"] for r in result["episodes"]} == expected
    assert json.loads((tmp_path / "hands.json").read_text()) == result
    copy = tmp_path / "copies" / src.name
    assert json.loads((copy / "meta/info.json").read_text())["codebase_version"] == "v3.0"
    assert main(["build-db", "--format", "lerobot", "--data", str(copy), "--segments", "subtasks", "--encoder",
                 "pixels", "--encoder-option", "size=4", "--cache-dir", str(tmp_path / "cache"),
                 "--out", str(tmp_path / "db")]) == 0
    db = SubtaskDatabase.load(tmp_path / "db")
    got = {}
    for ep, s, e, label in zip(db.episodes, db.starts, db.ends, db.labels, strict=True):
        got.setdefault(ep, []).append(([int(s), int(e)], label))
    assert got == {ep: list(zip(segs, ["close the gripper", "hold the gripper closed"], strict=True))
                   for ep, segs in expected.items()}
    with pytest.raises(ValueError, match="already exists"):
        hyst.main(["--data", str(src), "--copies", str(tmp_path / "copies"), "--json", str(tmp_path / "x.json"),
                   "--hand", "gripper=3"])
    with pytest.raises(ValueError, match="no observation.state name holds a side"):
        hyst.main(["--data", str(src), "--copies", str(tmp_path / "c2"), "--json", str(tmp_path / "y.json")])
