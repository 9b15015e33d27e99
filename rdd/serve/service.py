"""What the decomposition server does with a request, without any web framework: check it, read its
frames as an :class:`~rdd.data.episode.Episode`, decompose it, and answer in the official server's shapes.

The request (the official ``rdd_server.py`` of tasl-lab/RDD): ``paths`` is one list per frame of
that frame's image files, one per view, in the order of the database's views; ``method`` is ``rdd``
or ``uvd``; ``preprocessor`` names an encoder. The answer: ``segments`` (one list of frame indices
per segment, the segments partitioning ``0..T-1``) and, for ``rdd``, ``nn_list`` (per segment, per
view, the database entry the segment matched).

Nothing of a request reaches a shell, a pickle or an import: its paths are only resolved, checked
(inside ``root`` when one is set, regular files, image headers of equal sizes) and decoded by PIL.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rdd.data.episode import Episode
from rdd.data.frames import ImageFileFrames, read_image
from rdd.errors import InputError

METHODS = ("rdd", "uvd")
DEFAULT_MAX_FRAMES = 5000


class RequestError(InputError):
    """A bad request: ``status`` is its HTTP status, the message names the field at fault."""

    def __init__(self, message: str, status: int = 422) -> None:
        super().__init__(message)
        self.status = status


def segment_lists(segments: Sequence[tuple[int, int]]) -> list[list[int]]:
    """Half-open segments ``[start, end)`` as the official server's lists of frame indices."""
    return [list(range(int(s), int(e))) for s, e in segments]


class DecomposeService:
    """One worker's loaded decomposers (``rdd`` over the database, ``uvd`` with the same encoder) and
    the checks every request passes; one request computes at a time (``lock``), so the encoder, the
    index and the decomposers never run in two threads at once."""

    def __init__(self, decomposers: dict[str, Any], views: Sequence[str], config: dict[str, Any],
                 root: str | Path | None = None, max_frames: int = DEFAULT_MAX_FRAMES) -> None:
        unknown = sorted(set(decomposers) - set(METHODS))
        if unknown:
            raise ValueError(f"decomposers {unknown} are not served; methods are {list(METHODS)}")
        if int(max_frames) < 2:
            raise ValueError(f"max_frames must be at least 2, got {max_frames}")
        self.decomposers = dict(decomposers)
        self.views = tuple(views)
        self.root = None if root is None else Path(root).expanduser().resolve()
        if self.root is not None and not self.root.is_dir():
            raise ValueError(f"root {root}: no such folder")
        self.max_frames = int(max_frames)
        self.lock = threading.Lock()
        self._config = {**config, "decomposer": list(self.decomposers), "views": list(self.views),
                        "root": None if self.root is None else str(self.root), "max_frames": self.max_frames}

    @property
    def encoder_name(self) -> str:
        """The name of the encoder every method embeds frames with (the official ``preprocessor``)."""
        return str(self._config.get("encoder", ""))

    def config(self) -> dict[str, Any]:
        """The settings in force, for ``GET /config``."""
        return dict(self._config)

    def check_method(self, method: str) -> str:
        """``method`` if this server has it, else a 400 naming the field (the official status)."""
        if method not in self.decomposers:
            raise RequestError(f"method: unknown decomposer {method!r}; expected one of {list(self.decomposers)}",
                               status=400)
        return method

    def check_preprocessor(self, preprocessor: str | None) -> None:
        """A ``preprocessor`` must name an encoder; this server embeds with its database's encoder
        whatever the request names, as the official server uses its configured one."""
        from rdd.encoders import available_encoders

        if preprocessor is not None and preprocessor not in available_encoders():
            raise RequestError(f"preprocessor: unknown encoder {preprocessor!r}; expected one of "
                               f"{available_encoders()} (this server embeds with {self.encoder_name!r})")

    def resolve(self, raw: str, field: str) -> Path:
        """The file a request path names: relative to ``root`` (else the working folder), inside
        ``root`` after resolving links, a regular file (never a folder, device or pipe)."""
        if not raw or "\x00" in raw:
            raise RequestError(f"{field}: {raw!r} is not a file path")
        base = self.root if self.root is not None else Path.cwd()
        try:  # taken literally: no ~ expansion, no globbing
            full = (base / raw).resolve()
            if self.root is not None and full != self.root and self.root not in full.parents:
                raise RequestError(f"{field}: {raw} is outside the served root {self.root}", status=403)
            if not full.exists():
                raise RequestError(f"{field}: {raw}: no such file", status=404)
            regular = full.is_file()
        except (OSError, RuntimeError) as exc:  # a name too long, a loop of links
            raise RequestError(f"{field}: {raw}: cannot be resolved ({exc})") from None
        if not regular:
            raise RequestError(f"{field}: {raw} is not a regular file")
        return full

    def episode(self, paths: Sequence[Sequence[str]]) -> tuple[Episode, dict[str, str]]:
        """The frames ``paths`` names as an Episode with one view per database view, every file
        checked first: a missing, unreadable, non-image or differently sized frame is a 4xx naming
        ``paths[i][j]``. Also each resolved file's field name."""
        if len(paths) < 2:
            raise RequestError(f"paths: at least 2 frames are needed, got {len(paths)}")
        if len(paths) > self.max_frames:
            raise RequestError(f"paths: {len(paths)} frames, more than this server's --max-frames {self.max_frames}")
        n_views = len(self.views)
        files: list[list[Path]] = [[] for _ in self.views]
        fields: dict[str, str] = {}
        sizes: list[tuple[int, int] | None] = [None] * n_views
        for i, frame in enumerate(paths):
            if len(frame) != n_views:
                raise RequestError(f"paths[{i}]: {len(frame)} view path(s), expected {n_views}, one per database "
                                   f"view in order: {', '.join(self.views)}")
            for j, raw in enumerate(frame):
                field = f"paths[{i}][{j}]"
                path = self.resolve(raw, field)
                try:
                    size = read_image(path, size_only=True)
                except InputError as exc:
                    raise RequestError(f"{field}: {raw} is not an image ({exc})") from None
                if sizes[j] is None:
                    sizes[j] = size
                elif size != sizes[j]:
                    raise RequestError(f"{field}: {raw} is {size[0]}x{size[1]} pixels, but paths[0][{j}] is "
                                       f"{sizes[j][0]}x{sizes[j][1]}; every frame of a view must have one size")
                files[j].append(path)
                fields.setdefault(str(path), field)
        views = {v: ImageFileFrames(f) for v, f in zip(self.views, files, strict=True)}
        return Episode(name="request", views=views), fields

    def decompose(self, paths: Sequence[Sequence[str]], method: str, preprocessor: str | None = None
                  ) -> dict[str, Any]:
        """The official server's answer to one request: ``{"segments": ...}``, plus ``nn_list`` for rdd."""
        self.check_method(method)
        self.check_preprocessor(preprocessor)
        episode, fields = self.episode(paths)
        try:
            with self.lock:
                result = self.decomposers[method].decompose(episode)
        except InputError as exc:  # a window shorter than min_len, a frame whose pixels do not decode
            field = next((f for p, f in fields.items() if p in str(exc)), "paths")
            raise RequestError(f"{field}: {exc}") from None
        finally:
            episode.release()
        answer: dict[str, Any] = {"segments": segment_lists(result.segments)}
        if method == "rdd":
            answer["nn_list"] = [self.nn_views(n) for n in result.neighbours or []]
            answer["confidence"] = result.confidence  # per segment, in [0, 1] (rdd.core.confidence)
        return answer

    def nn_views(self, neighbour: dict[str, Any]) -> list[dict[str, Any]]:
        """A segment's matched entry as the official ``nn_list`` item: one record per view (the
        official database stores each view as its own row; ours stores one entry over all views)."""
        record = {"id": neighbour["entry"], "task_name": neighbour["task"], "episode": neighbour["episode"],
                  "frame_indexes": [neighbour["start"], neighbour["end"] - 1], "duration": neighbour["duration"],
                  "instruction": neighbour["instruction"], "distance": neighbour["distance"]}
        return [{**record, "view": view} for view in self.views]

