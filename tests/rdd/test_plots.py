"""Timeline figure: a PNG whose rows show each method's segments and keyframe thumbnails."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from rdd.data.episode import Episode
from rdd.plots import plot_timelines


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
