"""What the review page shows and edits, without any web framework.

A session holds a ``decompose`` output (``--pred``) and the dataset it describes (``--data``): the
episodes ordered by their lowest segment confidence, each one's segments, labels, signals and
frames on demand, the matched database entries' frames, and the person's edits. ``save`` writes the
edited file atomically to ``--out``: the same shape as ``decompose``'s output, plus per episode
``sources`` (per segment ``rdd`` or ``person``: who placed it or named it last) and ``reviewed``, so
it is a ``--pred`` / ``--gt`` for ``evaluate`` and a segmentation for ``--decomposer given``.

Only files under the allowed roots are read (``--data``, the database and the folder its manifest
says it was built from); nothing from the dataset is run.
"""

from __future__ import annotations

import copy
import io
import json
from collections import OrderedDict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rdd.atomic import write_json_atomic
from rdd.errors import InputError
from rdd.segments import validate_segments

PAGE_SIZE = 50
OPEN_EPISODES = 3  # episodes kept open for their frames (an LRU): the one on screen and its neighbours
FRAME_SIDE = 320  # the longest side of a frame sent to the page


class ReviewError(InputError):
    """A bad request or input: ``status`` is its HTTP status, the message names the file or field."""

    def __init__(self, message: str, status: int = 422) -> None:
        super().__init__(message)
        self.status = status


def read_predictions(path: str | Path, flag: str = "--pred") -> dict[str, Any]:
    """A ``decompose`` output (or a reviewed one), every episode's segments a partition of its frames,
    else one line naming ``flag``, the file, the episode and the field."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise ReviewError(f"{flag} {path}: no such file") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ReviewError(f"{flag} {path}: not JSON ({exc})") from None
    if not isinstance(data, dict) or not isinstance(data.get("episodes"), list):
        raise ReviewError(f"{flag} {path}: expected an object with an 'episodes' list (a decompose output)")
    seen = set()
    for i, rec in enumerate(data["episodes"]):
        where = f"{flag} {path}: episodes[{i}]"
        if not isinstance(rec, dict) or not isinstance(rec.get("episode"), str):
            raise ReviewError(f"{where}: field 'episode' missing")
        where += f" ({rec['episode']!r})"
        if rec["episode"] in seen:
            raise ReviewError(f"{where}: field 'episode' repeats an earlier episode")
        seen.add(rec["episode"])
        check_record(rec, where)
    return data


def check_record(rec: dict[str, Any], where: str) -> None:
    """Segments partition ``[0, num_frames)``; per-segment lists (instructions, confidence, sources)
    have one item per segment."""
    n = rec.get("num_frames")
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        raise ReviewError(f"{where}: field 'num_frames' must be a whole number >= 1, got {n!r}")
    segs = rec.get("segments")
    if not isinstance(segs, list) or not all(isinstance(s, list) and len(s) == 2 and
                                             all(isinstance(v, int) and not isinstance(v, bool) for v in s)
                                             for s in segs):
        raise ReviewError(f"{where}: field 'segments' must be a list of [start, end] whole numbers")
    try:
        validate_segments(segs, n)
    except ValueError as exc:
        raise ReviewError(f"{where}: field 'segments': {exc} (segments must partition [0, {n}) without "
                          "overlaps or gaps)") from None
    for key in ("instructions", "confidence", "sources", "neighbours"):
        value = rec.get(key)
        if value is not None and (not isinstance(value, list) or len(value) != len(segs)):
            raise ReviewError(f"{where}: field {key!r} must have one item per segment ({len(segs)})")


class ReviewSession:
    """The records of ``pred`` over the episodes of ``data`` (read on demand), edited in memory and
    saved to ``out``."""

    def __init__(self, fmt: str, data: str | Path, pred: str | Path, out: str | Path,
                 db: str | Path | None = None, reader_options: dict[str, Any] | None = None,
                 review_below: float = 0.5, force: bool = False) -> None:
        from rdd.data.load import episode_names

        self.format, self.data, self.out = fmt, Path(data).resolve(), Path(out)
        self.reader_options = dict(reader_options or {})
        self.review_below, self.force = float(review_below), force
        self.pred_path = Path(pred)
        self.doc = read_predictions(pred)
        self.config = self.doc.get("config") or {}
        known = set(episode_names(fmt, data, **self.reader_options))
        missing = [r["episode"] for r in self.doc["episodes"] if r["episode"] not in known]
        if missing:
            raise ReviewError(f"--pred {pred}: episodes {missing[:3]}{' ...' if len(missing) > 3 else ''} are not "
                              f"in --data {data} (field 'episode'; a decompose output of another dataset?)")
        self.records = {r["episode"]: self._prepared(r) for r in self.doc["episodes"]}
        self.original = copy.deepcopy(self.records)
        self.order = sorted(self.records, key=lambda n: (self.lowest(n), n))
        self.roots = [self.data]
        self.database = None
        if db is not None:
            from rdd.database.model import SubtaskDatabase

            self.database = SubtaskDatabase.load(db)
            self.roots.append(Path(db).resolve())
            source = (self.database.meta.get("source") or {})
            if source.get("data"):
                self.roots.append(Path(source["data"]).resolve())
        self._open: OrderedDict[tuple[str, str], Any] = OrderedDict()
        self.saved = 0

    @staticmethod
    def _prepared(rec: dict[str, Any]) -> dict[str, Any]:
        rec = copy.deepcopy(rec)
        k = len(rec["segments"])
        rec.setdefault("sources", ["rdd"] * k)
        rec.setdefault("reviewed", False)
        if rec.get("instructions") is None:
            rec["instructions"] = [""] * k
        return rec

    def lowest(self, name: str) -> float:
        """The episode's lowest segment confidence (1 when it has none: nothing says to doubt it)."""
        conf = [c for c in self.records[name].get("confidence") or [] if c is not None]
        return min(conf) if conf else 1.0

    def summary(self, name: str) -> dict[str, Any]:
        """One row of the list: name, frames, segments, lowest confidence, novelty, flags."""
        rec = self.records[name]
        low = self.lowest(name)
        return {"episode": name, "num_frames": rec["num_frames"], "segments": len(rec["segments"]),
                "lowest": low, "novelty": rec.get("novelty"), "flagged": low < self.review_below,
                "reviewed": bool(rec["reviewed"]), "edited": rec != self.original[name]}

    def page(self, page: int = 0, size: int = PAGE_SIZE, query: str = "", only: str = "all") -> dict[str, Any]:
        """One page of the episodes, lowest confidence first; ``query`` keeps names containing it,
        ``only`` = all | flagged | unreviewed | reviewed."""
        if only not in ("all", "flagged", "unreviewed", "reviewed"):
            raise ReviewError(f"only: {only!r} is not one of all, flagged, unreviewed, reviewed")
        if page < 0 or not 1 <= size <= 500:
            raise ReviewError(f"page {page}, size {size}: page must be >= 0 and size in 1..500")
        names = [n for n in self.order if query.lower() in n.lower()]
        if only == "flagged":
            names = [n for n in names if self.lowest(n) < self.review_below]
        elif only != "all":
            names = [n for n in names if bool(self.records[n]["reviewed"]) == (only == "reviewed")]
        rows = [self.summary(n) for n in names[page * size:(page + 1) * size]]
        flagged = sum(1 for n in self.order if self.lowest(n) < self.review_below)
        return {"total": len(names), "page": page, "size": size, "items": rows, "episodes": len(self.order),
                "flagged": flagged, "review_below": self.review_below}

    def record(self, name: str) -> dict[str, Any]:
        """The episode's record (as edited so far)."""
        if name not in self.records:
            raise ReviewError(f"episode {name!r}: not in --pred {self.pred_path}", status=404)
        return self.records[name]

    def _episode(self, fmt: str, data: Path, name: str):
        from rdd.data.load import load_episodes

        key = (str(data), name)
        if key in self._open:
            self._open.move_to_end(key)
            return self._open[key]
        try:
            found = load_episodes(fmt, data, names=[name], **(self.reader_options if data == self.data else {}))
        except (InputError, OSError, ValueError) as exc:
            raise ReviewError(f"episode {name!r} of {data}: cannot be read ({exc})", status=404) from None
        if len(found) != 1:
            raise ReviewError(f"episode {name!r}: not in {data}", status=404)
        self._open[key] = found[0]
        while len(self._open) > OPEN_EPISODES:
            self._open.popitem(last=False)[1].release()
        return found[0]

    def episode(self, name: str) -> dict[str, Any]:
        """What the episode view shows: the record, the views, the fps, the robot's signals."""
        from rdd.plots.signals import episode_signals

        rec = self.record(name)
        ep = self._episode(self.format, self.data, name)
        if ep.num_frames != rec["num_frames"]:
            raise ReviewError(f"--pred {self.pred_path}: episode {name!r} field 'num_frames' is {rec['num_frames']}, "
                              f"but --data has {ep.num_frames} frames (a decompose output of another dataset?)",
                              status=409)
        hands, arms = episode_signals(ep)
        signals = {k: [round(float(x), 4) for x in np.nan_to_num(v)] for k, v in {**hands, **arms}.items()}
        return {"record": rec, "views": list(ep.views), "fps": ep.meta.get("fps"), "signals": signals,
                "lowest": self.lowest(name), "edited": rec != self.original[name],
                "has_database": self.database is not None}

    def frame(self, name: str, view: str, index: int) -> bytes:
        """Frame ``index`` of ``view`` of episode ``name`` as a JPEG."""
        self.record(name)
        return self._jpeg(self._episode(self.format, self.data, name), view, index)

    def neighbour_frame(self, entry: int, which: str, view: str) -> bytes:
        """The first (``begin``) or last (``end``) frame of database entry ``entry``, from the data the
        database was built from."""
        db = self.database
        if db is None:
            raise ReviewError("no --db given: the matched entries' frames need it", status=404)
        if not 0 <= entry < len(db) or which not in ("begin", "end"):
            raise ReviewError(f"entry {entry} / {which}: no such database entry frame", status=404)
        source = db.meta.get("source") or {}
        if not source.get("data") or not source.get("format"):
            raise ReviewError("the database does not record the data it was built from", status=404)
        ep = self._episode(source["format"], Path(source["data"]).resolve(), db.episodes[entry])
        return self._jpeg(ep, view, db.starts[entry] if which == "begin" else db.ends[entry] - 1)

    @staticmethod
    def _jpeg(ep, view: str, index: int) -> bytes:
        from PIL import Image

        if view not in ep.views:
            raise ReviewError(f"view {view!r}: episode {ep.name!r} has views {list(ep.views)}", status=404)
        if not 0 <= index < ep.num_frames:
            raise ReviewError(f"frame {index}: episode {ep.name!r} has frames 0..{ep.num_frames - 1}", status=404)
        image = Image.fromarray(np.asarray(ep.frames(view, [index])[0], dtype=np.uint8))
        image.thumbnail((FRAME_SIDE, FRAME_SIDE))
        buf = io.BytesIO()
        image.convert("RGB").save(buf, format="JPEG", quality=85)
        return buf.getvalue()

    def update(self, name: str, segments: Sequence[Sequence[int]], instructions: Sequence[str],
               reviewed: bool) -> dict[str, Any]:
        """The person's version of an episode: segments (a partition), their labels, reviewed or not.
        A segment that RDD did not cut, or whose label changed, becomes the person's."""
        rec = self.record(name)
        edited = {**rec, "segments": [list(s) for s in segments], "instructions": list(instructions)}
        for key in ("confidence", "neighbours", "sources"):
            edited.pop(key, None)
        check_record(edited, f"episode {name!r}")
        if not all(isinstance(t, str) for t in instructions):
            raise ReviewError(f"episode {name!r}: field 'instructions' must be strings")
        old = {tuple(s): j for j, s in enumerate(self.original[name]["segments"])}
        first = self.original[name]
        sources, confidence, neighbours = [], [], []
        for seg, text in zip(edited["segments"], edited["instructions"], strict=True):
            j = old.get(tuple(seg))
            same = j is not None and text == (first["instructions"][j] or "")
            sources.append(first["sources"][j] if same else "person")
            confidence.append(first["confidence"][j] if same and first.get("confidence") else None)
            neighbours.append(first["neighbours"][j] if j is not None and first.get("neighbours") else None)
        edited["sources"] = sources
        if first.get("confidence") is not None:
            edited["confidence"] = confidence
        if first.get("neighbours") is not None:
            edited["neighbours"] = neighbours
        edited["keyframes"] = [e - 1 for _, e in edited["segments"]]
        edited["reviewed"] = bool(reviewed)
        self.records[name] = edited
        return edited

    def save(self) -> Path:
        """Write every record, edited or not, to ``out`` atomically; a file already there is replaced only
        with ``force`` or when this session wrote it."""
        doc = {**self.doc, "episodes": [self.records[r["episode"]] for r in self.doc["episodes"]]}
        doc["config"] = {**self.config, "reviewed_from": str(self.pred_path)}
        write_json_atomic(self.out, doc, overwrite=self.force or self.saved > 0)
        self.saved += 1
        return self.out

    def allowed(self, raw: str) -> Path:
        """The file ``raw`` names (relative to ``--data``) if it lies under an allowed root, else 403."""
        if not raw or "\x00" in raw:
            raise ReviewError(f"path {raw!r}: not a file path")
        full = (self.data / raw).resolve()
        if not any(full == root or root in full.parents for root in self.roots):
            raise ReviewError(f"path {raw}: outside --data and the database", status=403)
        if not full.is_file():
            raise ReviewError(f"path {raw}: no such file", status=404)
        return full
