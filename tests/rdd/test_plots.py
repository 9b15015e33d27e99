"""Timeline figure: a PNG whose rows show each method's segments and keyframe thumbnails."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from rdd.data.episode import Episode
from rdd.plots.timeline import plot_timelines


def test_timeline_png(tmp_path):
    t = 30
    frames = np.zeros((t, 20, 20, 3), dtype=np.uint8)
    frames[:, :, :, 1] = np.linspace(0, 255, t).astype(np.uint8)[:, None, None]
    ep = Episode(name="ep", views={"front": frames}, goal="do it")
    rows = {"rdd": [(0, 10), (10, 30)], "uniform": [(0, 15), (15, 30)]}
    out = plot_timelines([(ep, rows, [(0, 12), (12, 30)]), (ep, {"uvd": [(0, 30)]}, None)],
                         tmp_path / "t.png")
    img = np.asarray(Image.open(out).convert("RGB"))
    assert img.shape[0] > 200 and img.shape[1] > 800
    # Thumbnails carry the green ramp: strongly green pixels appear in the figure.
    green = (img[..., 1] > 150) & (img[..., 0] < 60) & (img[..., 2] < 60)
    assert green.sum() > 50


def test_bad_rows_are_named(tmp_path):
    ep = Episode(name="ep", views={"front": np.zeros((5, 4, 4, 3), np.uint8)})
    with pytest.raises(ValueError, match="'ep', row 'bad'"):
        plot_timelines([(ep, {"bad": [(0, 3)]}, None)], tmp_path / "x.png")
    with pytest.raises(ValueError, match="no view 'wrist'"):
        plot_timelines([(ep, {"ok": [(0, 5)]}, None)], tmp_path / "x.png", view="wrist")
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize("suffix", [".png", ".svg"])
def test_names_that_are_not_utf8_are_drawn_escaped(toy_native, tmp_path, suffix):
    """A native episode folder whose name is not UTF-8 (issue 39): decompose and plot it from the
    command line; the figure draws the bad byte as ``\\xff`` instead of failing in matplotlib."""
    import os
    import shutil

    from rdd.cli import main
    from rdd.plots.timeline import drawable

    data = tmp_path / "ds"
    bad = os.fsdecode(b"ep\xff")
    try:
        shutil.copytree(toy_native / "ep0", data / bad)
    except (OSError, UnicodeEncodeError):
        pytest.skip("this filesystem refuses file names that are not UTF-8")
    pred = tmp_path / "u.json"
    assert main(["decompose", "--format", "native", "--data", str(data), "--decomposer", "uniform",
                 "--option", "n_segments=2", "--out", str(pred)]) == 0
    out = tmp_path / f"fig{suffix}"
    assert main(["plot", "--pred", f"{bad}={pred}", "--format", "native", "--data", str(data),
                 "--out", str(out)]) == 0
    if suffix == ".svg":
        assert "ep\\xff" in out.read_text()
    assert drawable(bad) == "ep\\xff" and drawable("a\ud800b") == "a\\ud800b" and drawable("é") == "é"


def test_lerobot_signals_drawn_under_the_timeline(tmp_path):
    """An episode with hand levels and sided arms gets a signals axis: a taller figure, same timeline."""
    frames = np.zeros((40, 8, 8, 3), np.uint8)
    meta = {"fps": 10, "hand_levels": np.stack([np.full(40, 0.7), np.repeat([0.8, 0.3], 20)], axis=1),
            "gripper": {"sides": ["left", "right"]}, "arm_sides": {"left": [0], "right": [1]}}
    plain = Episode(name="e", views={"front": frames}, joint_velocities=np.ones((40, 2)))
    with_signals = Episode(name="e", views={"front": frames}, joint_velocities=np.ones((40, 2)), meta=meta)
    rows = {"expert": [(0, 20), (20, 40)]}
    a = plot_timelines([(plain, rows, None)], tmp_path / "a.png")
    b = plot_timelines([(with_signals, rows, None)], tmp_path / "b.png")
    assert Image.open(b).size[1] > Image.open(a).size[1]


def test_timeline_says_instructions_miou_and_ground_truth_cuts(tmp_path, monkeypatch):
    """What a talk needs from the figure: instructions on the segments and in a legend, each method's
    mIoU against the ground truth, the ground truth's cuts, and thumbnails in a strip of their own
    above the rows, never closer together than one thumbnail's width."""
    from rdd.plots import timeline

    t = 120
    frames = np.zeros((t, 48, 64, 3), np.uint8)
    ep = Episode(name="ep", views={"front": frames}, goal="open the drawer")
    gt = {"segments": [(0, 40), (40, 80), (80, 120)], "instructions": ["reach the handle", "pull it", "let go"]}
    # the first method's keyframes are the thumbnails: 30, 4 frames apart, so most must go
    rows = {"dense": [(k, k + 4) for k in range(0, t, 4)],
            "rdd": {"segments": [(0, 44), (44, 120)], "instructions": ["reach the handle", "pull it"]}}
    drawn = {}
    real = timeline._draw_thumbnails

    def record(ax, episode, cam, shown, y, zoom, thumb_height):
        drawn["shown"], drawn["y"], drawn["width"] = list(shown), y, 64 * zoom * t / (timeline.AXES_INCHES * 72)
        return real(ax, episode, cam, shown, y, zoom, thumb_height)

    monkeypatch.setattr(timeline, "_draw_thumbnails", record)
    svg = timeline.plot_timelines([(ep, rows, gt)], tmp_path / "t.svg").read_text()
    # mIoU of rdd: (40/44 + 40/76) / 2 = 0.718; of dense: every 4-frame segment's best IoU is 4/40
    for text in ("reach the handle", "pull it", "let go", "ground truth cuts", "instructions",
                 "2 segments, mIoU 0.72", "30 segments, mIoU 0.10", "keyframes"):
        assert text in svg, text
    rows_top = 3 - 1 + 0.3  # the ground-truth row's bar ends there; the strip starts above
    assert drawn["y"] - 0.5 > rows_top
    xs = [x for _, x in drawn["shown"]]
    assert xs == sorted(xs) and all(b - a >= drawn["width"] for a, b in zip(xs, xs[1:], strict=False))
    assert 3 <= len(xs) < 30
    assert all(drawn["width"] / 2 - 0.5 <= x <= t - 0.5 - drawn["width"] / 2 for x in xs)


def test_signal_panel_draws_both_cuts_and_says_its_units(tmp_path):
    frames = np.zeros((40, 8, 8, 3), np.uint8)
    meta = {"fps": 10, "hand_levels": np.stack([np.full(40, 0.7), np.repeat([0.8, 0.3], 20)], axis=1),
            "gripper": {"sides": ["left", "right"]}, "arm_sides": {"left": [0], "right": [1]}}
    ep = Episode(name="e", views={"front": frames}, joint_velocities=np.ones((40, 2)), meta=meta)
    svg = plot_timelines([(ep, {"uvd": [(0, 10), (10, 40)]}, [(0, 20), (20, 40)])], tmp_path / "s.svg",
                         gt_label="hand rule").read_text()
    for text in ("cuts: uvd", "cuts: hand rule", "rad/s", "left hand", "right arm speed"):
        assert text in svg, text
