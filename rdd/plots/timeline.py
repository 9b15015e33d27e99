"""Timeline figures like the RDD paper's qualitative figure: one row per method (and ground truth),
coloured segments with their boundaries, and the keyframe of each segment as a thumbnail."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from rdd.atomic import atomic_file
from rdd.data.episode import Episode
from rdd.plots.signals import draw_signals, has_signals
from rdd.segments import Segment, validate_segments

FIGURE_FORMATS = {".png": "png", ".pdf": "pdf", ".svg": "svg"}
PanelSpec = tuple[Episode, Mapping[str, Sequence[Segment]], Sequence[Segment] | None]


def figure_format(path: str | Path) -> str:
    """The figure format a file name asks for; other suffixes are an error naming the file."""
    suffix = Path(path).suffix.lower()
    if suffix not in FIGURE_FORMATS:
        raise ValueError(f"{path}: unsupported figure format {suffix or '(none)'!r}; "
                         f"use one of {', '.join(FIGURE_FORMATS)}")
    return FIGURE_FORMATS[suffix]


def drawable(text: str) -> str:
    """``text`` as a font can draw it. A name that is not UTF-8 on disk reaches Python with its bad
    bytes as lone surrogates (surrogateescape), which fonts refuse; they are drawn as ``\\xff``
    escapes, as ``ls -b`` shows them, so the episode stays recognisable and distinct."""
    try:
        return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
    except UnicodeEncodeError:  # a lone surrogate that was not a byte (JSON "\\ud800"): its code point
        return text.encode("utf-8", "backslashreplace").decode("utf-8")


def _thumbnail(image: np.ndarray, height: int = 48) -> np.ndarray:
    """Nearest-neighbour downscale to ``height`` pixels tall (keeps aspect ratio)."""
    h, w = image.shape[:2]
    if h <= height:
        return image
    rows = (np.arange(height) * h / height).astype(int)
    width = max(1, round(w * height / h))
    cols = (np.arange(width) * w / width).astype(int)
    return image[rows][:, cols]


def _draw_row(ax, segments: Sequence[Segment], num_frames: int, thumbs: dict[int, np.ndarray],
              y: float, max_thumbs: int) -> None:
    """Segments as alternating bars at height ``y``, boundaries as lines, keyframe thumbnails."""
    from matplotlib.offsetbox import AnnotationBbox, OffsetImage

    colours = ["#4C72B0", "#DD8452"]
    for j, (s, e) in enumerate(segments):
        ax.broken_barh([(s, e - s)], (y - 0.18, 0.36), facecolors=colours[j % 2], alpha=0.85)
        if j:
            ax.vlines(s, y - 0.45, y + 0.45, colors="k", linewidth=1.0)
    keyframes = [e - 1 for _, e in segments]
    shown = keyframes if len(keyframes) <= max_thumbs else [
        keyframes[int(i)] for i in np.linspace(0, len(keyframes) - 1, max_thumbs).round()
    ]
    zoom = min(1.0, 8.0 / max(len(shown), 1))
    for k in shown:
        box = AnnotationBbox(OffsetImage(thumbs[k], zoom=zoom), (k, y + 0.62), frameon=True,
                             pad=0.1, box_alignment=(0.5, 0.5))
        ax.add_artist(box)
        ax.plot([k, k], [y + 0.18, y + 0.4], color="0.4", linewidth=0.6)


def plot_timelines(
    panels: Sequence[PanelSpec],
    out: str | Path,
    view: str | None = None,
    gt_label: str = "ground truth",
    max_thumbs: int = 10,
    thumb_height: int = 48,
    overwrite: bool = True,
) -> Path:
    """Draw one panel per (episode, {method: segments}, ground truth or None) and save it in the
    format its file name asks for (.png, .pdf or .svg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    fmt = figure_format(out)
    if not panels:
        raise ValueError("nothing to plot: no episodes given")
    n_rows = [len(rows) + (gt is not None) for _, rows, gt in panels]
    # Episodes with hand/arm signals (LeRobot) get an axis under their timeline: the signals and the cuts.
    signals = [has_signals(ep) for ep, _, _ in panels]
    heights = [h for r, sig in zip(n_rows, signals, strict=True) for h in ([r, 1.6] if sig else [r])]
    fig, grid = plt.subplots(len(heights), 1, figsize=(14, sum(1.25 * h + 0.6 for h in heights)),
                             squeeze=False, gridspec_kw={"height_ratios": heights})
    axes_iter = iter(grid[:, 0])
    for (episode, rows, gt), count, sig in zip(panels, n_rows, signals, strict=True):
        ax = next(axes_iter)
        sig_ax = next(axes_iter) if sig else None
        t = episode.num_frames
        named = ([(gt_label, gt)] if gt is not None else []) + list(rows.items())
        checked = []
        for label, segs in named:
            try:
                checked.append((label, validate_segments(segs, t)))
            except ValueError as exc:
                raise ValueError(f"episode {episode.name!r}, row {label!r}: {exc}") from exc
        cam = view or next(iter(episode.views), None)
        keys = sorted({e - 1 for _, segs in checked for _, e in segs})
        thumbs: dict[int, np.ndarray] = {}
        if cam is not None:
            if cam not in episode.views:
                raise ValueError(f"episode {episode.name!r} has no view {cam!r}; has {sorted(episode.views)}")
            for k, img in zip(keys, episode.frames(cam, keys), strict=True):
                thumbs[k] = _thumbnail(img, thumb_height)
        else:
            thumbs = {k: np.zeros((thumb_height, thumb_height, 3), np.uint8) for k in keys}
        for i, (_label, segs) in enumerate(checked):
            _draw_row(ax, segs, t, thumbs, y=count - 1 - i, max_thumbs=max_thumbs)
        ax.set_yticks([count - 1 - i for i in range(count)])
        ax.set_yticklabels([drawable(f"{label} ({len(segs)})") for label, segs in checked])
        ax.set_xlim(-0.5, t - 0.5)
        ax.set_ylim(-0.6, count - 1 + 1.1)
        ax.set_xlabel("frame")
        goal = f": {episode.goal}" if episode.goal else ""
        ax.set_title(drawable(f"{episode.name} ({t} frames){goal}"), fontsize=10, loc="left")
        ax.grid(axis="x", alpha=0.3)
        if sig_ax is not None:
            # The first method's cuts (the ground truth's when there is no method row).
            label, segs = next(((lab, sg) for lab, sg in checked if lab in rows), checked[0])
            draw_signals(sig_ax, episode, [s for s, _ in segs[1:]], drawable(label))
    fig.tight_layout()
    try:
        with atomic_file(out, "wb", overwrite=overwrite) as fh:
            fig.savefig(fh, dpi=110, format=fmt)
    finally:
        plt.close(fig)
    return out
