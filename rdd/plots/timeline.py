"""Timeline figures like the RDD paper's qualitative figure: the ground truth above one row per
method, each segment coloured by its instruction (a legend beside) and written on it, each method's
mIoU against the ground truth, and the first method's keyframes as thumbnails in a strip of their own."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rdd.atomic import atomic_file
from rdd.data.episode import Episode
from rdd.metrics import miou
from rdd.plots.signals import draw_signals, has_signals
from rdd.segments import Segment, validate_segments

FIGURE_FORMATS = {".png": "png", ".pdf": "pdf", ".svg": "svg"}
# A row: its segments, or a decompose record ({"segments", "instructions"}) whose instructions are drawn.
Row = Sequence[Segment] | Mapping[str, Any]
PanelSpec = tuple[Episode, Mapping[str, Row], Row | None]
ROW_INCHES = 0.5  # height of one row of the timeline
THUMB_POINTS = 40  # height of a thumbnail (it fits the strip of 1.5 rows above the timeline)
AXES_INCHES = 10.2  # width of a timeline axes in the 14-inch figure, its legend beside it


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


def _row(value: Row) -> tuple[Sequence[Segment], list[str] | None]:
    """(segments, instructions or None) of a row given as segments or as a decompose record."""
    if isinstance(value, Mapping):
        texts = value.get("instructions")
        return value["segments"], [str(t or "") for t in texts] if texts else None
    return value, None


def spaced(frames: Sequence[int], min_gap: float) -> list[int]:
    """``frames`` (sorted) thinned so that no two kept ones are closer than ``min_gap``: thumbnails
    centred on them do not overlap. The last frame is preferred to its close predecessor."""
    kept: list[int] = []
    for f in frames:
        if not kept or f - kept[-1] >= min_gap:
            kept.append(f)
        elif len(kept) > 1 and f - kept[-2] >= min_gap and f == frames[-1]:
            kept[-1] = f
    return kept


def _fit(text: str, frames: float, frames_per_point: float, size: float) -> str:
    """``text`` cut to the characters a segment ``frames`` long holds at font ``size`` (points)."""
    room = int(frames / frames_per_point / (0.55 * size))
    if room < 4:
        return ""
    return text if len(text) <= room else text[: room - 1].rstrip() + "\u2026"


def _draw_row(ax, segments, texts, y: float, colours: Mapping[str, Any], frames_per_point: float) -> None:
    """Segments as bars at height ``y`` coloured by instruction (alternating without), their cuts,
    and each instruction written on its segment where it fits."""
    plain = ["#8da0cb", "#5a6fa8"]
    for j, (s, e) in enumerate(segments):
        text = texts[j] if texts else ""
        colour = colours.get(text, plain[j % 2]) if text else plain[j % 2]
        ax.broken_barh([(s - 0.5, e - s)], (y - 0.3, 0.6), facecolors=colour, edgecolors="white", linewidth=0.6)
        shown = _fit(text, e - s, frames_per_point, 6.5)
        if shown:
            ax.text((s + e - 1) / 2, y, shown, ha="center", va="center", fontsize=6.5, clip_on=True)
        if j:
            ax.vlines(s - 0.5, y - 0.42, y + 0.42, colors="k", linewidth=1.2)


def _legend_colours(texts: Sequence[str]) -> dict[str, Any]:
    """One colour per distinct instruction, in order of appearance."""
    import matplotlib

    cmap = matplotlib.colormaps["tab20"]
    order = list(dict.fromkeys(t for t in texts if t))
    return {t: cmap(i % 20) for i, t in enumerate(order)}


def plot_timelines(
    panels: Sequence[PanelSpec],
    out: str | Path,
    view: str | None = None,
    gt_label: str = "ground truth",
    max_thumbs: int = 10,
    thumb_height: int = 48,
    overwrite: bool = True,
) -> Path:
    """Draw one panel per (episode, {method: row}, ground-truth row or None) and save it in the
    format its file name asks for (.png, .pdf or .svg); a row is its segments or a decompose record."""
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
    heights = [h for r, sig in zip(n_rows, signals, strict=True) for h in ([r + 1.6, 2.6] if sig else [r + 1.6])]
    fig, grid = plt.subplots(len(heights), 1, figsize=(14, sum(ROW_INCHES * h + 0.9 for h in heights)),
                             squeeze=False, gridspec_kw={"height_ratios": heights})
    axes_iter = iter(grid[:, 0])
    for (episode, rows, gt), count, sig in zip(panels, n_rows, signals, strict=True):
        ax = next(axes_iter)
        sig_ax = next(axes_iter) if sig else None
        t = episode.num_frames
        named = ([(gt_label, _row(gt))] if gt is not None else []) + [(k, _row(v)) for k, v in rows.items()]
        checked = []
        for label, (segs, texts) in named:
            try:
                checked.append((label, validate_segments(segs, t), texts))
            except ValueError as exc:
                raise ValueError(f"episode {episode.name!r}, row {label!r}: {exc}") from exc
        truth = checked[0][1] if gt is not None else None
        frames_per_point = t / (AXES_INCHES * 72)
        colours = _legend_colours([x for _, _, texts in checked for x in texts or ()])
        for i, (_label, segs, texts) in enumerate(checked):
            _draw_row(ax, segs, texts, count - 1 - i, colours, frames_per_point)
        if truth is not None and len(truth) > 1:
            # the ground truth's cuts across every method row: where a method cuts early or late
            ax.vlines([s - 0.5 for s, _ in truth[1:]], -0.5, count - 1.5 if count > 1 else count - 0.5,
                      colors="#d62728", linestyles=(0, (3, 2)), linewidth=0.9, zorder=3)
        labels = []
        for label, segs, _ in checked:
            score = "" if truth is None or label == gt_label else f", mIoU {miou(segs, truth):.2f}"
            labels.append(drawable(f"{label}\n{len(segs)} segments{score}"))
        # the thumbnails' own strip above the rows: the first method's keyframes (else the ground truth's)
        source_label, source, _ = next(((lab, sg, tx) for lab, sg, tx in checked if lab in rows), checked[0])
        zoom = THUMB_POINTS / thumb_height
        cam = view or next(iter(episode.views), None)
        if cam is not None and cam not in episode.views:
            raise ValueError(f"episode {episode.name!r} has no view {cam!r}; has {sorted(episode.views)}")
        ticks = [count - 1 - i for i in range(count)]
        if cam is not None:
            keys = [e - 1 for _, e in source]
            first = _thumbnail(episode.frames(cam, keys[:1])[0], thumb_height)
            gap = (first.shape[1] * zoom + 4) * frames_per_point
            # a thumbnail is centred on its keyframe, pulled inside the axes near either end; thinned
            # on those centres so that no two overlap
            at = {k: min(max(k, gap / 2 - 0.5), t - 0.5 - gap / 2) if gap < t else (t - 1) / 2 for k in keys}
            kept = spaced(sorted(set(at.values())), gap)[:max_thumbs]
            shown = [(next(k for k in keys if at[k] == x), x) for x in kept]
            _draw_thumbnails(ax, episode, cam, shown, count - 0.5 + 0.8, zoom, thumb_height)
            ticks.insert(0, count - 0.5 + 0.8)
            labels.insert(0, drawable(f"keyframes\n({source_label})"))
        ax.set_yticks(ticks, labels, fontsize=8)
        ax.set_xlim(-0.5, t - 0.5)
        ax.set_ylim(-0.6, count - 0.5 + 1.5)
        ax.set_xlabel("frame")
        goal = f": {episode.goal}" if episode.goal else ""
        ax.set_title(drawable(f"{episode.name} ({t} frames){goal}"), fontsize=10, loc="left")
        ax.grid(axis="x", alpha=0.3)
        for side in ("top", "right"):
            ax.spines[side].set_visible(False)
        handles = [matplotlib.patches.Patch(color=c, label=drawable(x)) for x, c in colours.items()]
        if truth is not None and len(truth) > 1:
            handles.append(matplotlib.lines.Line2D([], [], color="#d62728", linestyle=(0, (3, 2)),
                                                   label=drawable(f"{gt_label} cuts")))
        if handles:
            ax.legend(handles=handles, fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False,
                      title="instructions" if colours else None, title_fontsize=7, alignment="left")
        if sig_ax is not None:
            draw_signals(sig_ax, episode, (drawable(source_label), [s for s, _ in source[1:]]),
                         (drawable(gt_label), [s for s, _ in truth[1:]]) if truth is not None and source is not truth
                         else None)
    fig.tight_layout()
    try:
        with atomic_file(out, "wb", overwrite=overwrite) as fh:
            fig.savefig(fh, dpi=110, format=fmt, bbox_inches="tight")
    finally:
        plt.close(fig)
    return out


def _draw_thumbnails(ax, episode: Episode, cam: str, shown: Sequence[tuple[int, float]], y: float, zoom: float,
                     thumb_height: int) -> None:
    """Thumbnails of frames ``k`` centred at ``(x, y)`` for each ``(k, x)`` of ``shown``, each tied to
    its frame by a tick."""
    from matplotlib.offsetbox import AnnotationBbox, OffsetImage

    keys = [k for k, _ in shown]
    for (_k, x), img in zip(shown, episode.frames(cam, keys), strict=True):
        box = AnnotationBbox(OffsetImage(_thumbnail(img, thumb_height), zoom=zoom), (x, y), frameon=True,
                             pad=0.1, box_alignment=(0.5, 0.5))
        ax.add_artist(box)
    for k, x in shown:
        ax.plot([k, x], [y - 1.0, y - 0.58], color="0.45", linewidth=0.7)
