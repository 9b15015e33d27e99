"""The sub-task vector database: begin/end frame vectors of expert-labelled training sub-tasks.

On disk a database is a directory with ``begin.npy``, ``end.npy``, ``durations.npy``,
``entries.json`` (episode, task, instruction, start, end per entry) and ``manifest.json``
(format version, encoder name and weights hash, views, dimensions, entry count, sha256 checksums).
Files are written to temporary names and renamed, the manifest last, so a crash never leaves a
directory that loads.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rdd.data.episode import Episode
from rdd.data.frames import update_with_file
from rdd.encoders.base import Encoder
from rdd.encoders.embed import DEFAULT_VIEWS, episode_frame_vectors
from rdd.segments import Segment, validate_segments

FORMAT_VERSION = 1
MANIFEST = "manifest.json"
_ARRAYS = ("begin.npy", "end.npy", "durations.npy")
_ENTRIES = "entries.json"
_PER_ENTRY = ("episodes", "tasks", "starts", "ends")


class DatabaseError(ValueError):
    """A database directory that cannot be used (missing, corrupt or mismatched)."""


def _sha256(path: Path) -> str:
    return update_with_file(hashlib.sha256(), path).hexdigest()


def _atomic_write(path: Path, write) -> None:
    """Write via ``write(file_object)`` to a temporary file beside ``path``, then rename it."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


class SubtaskDatabase:
    """N sub-task entries: begin and end frame vectors (N, D), durations, and their provenance."""

    def __init__(
        self,
        begin: np.ndarray,
        end: np.ndarray,
        durations: np.ndarray,
        labels: list[str],
        episodes: list[str],
        tasks: list[str],
        starts: list[int],
        ends: list[int],
        meta: dict[str, Any],
    ) -> None:
        self.begin = begin
        self.end = end
        self.durations = durations
        self.labels = labels
        self.episodes = episodes
        self.tasks = tasks
        self.starts = starts
        self.ends = ends
        self.meta = meta
        self.directory: Path | None = None  # set by save()/load(); backends may cache beside it

    # ----------------------------------------------------------------- construction
    @classmethod
    def from_arrays(
        cls,
        begin: np.ndarray,
        end: np.ndarray,
        durations: Sequence[int] | np.ndarray,
        labels: Sequence[str] | None = None,
        meta: Mapping[str, Any] | None = None,
    ) -> SubtaskDatabase:
        """A database from ready frame vectors (N, D) each and durations (N,).

        ``meta`` holds database-level facts (``encoder``, ``weights_id``, ``views``) and may hold the
        per-entry lists ``episodes``, ``tasks``, ``starts``, ``ends`` (length N each).
        """
        b = np.ascontiguousarray(begin, dtype=np.float32)
        e = np.ascontiguousarray(end, dtype=np.float32)
        if b.ndim != 2 or e.ndim != 2:
            raise ValueError(f"begin and end must be (N, D) arrays, got shapes {b.shape} and {e.shape}")
        if b.shape != e.shape:
            raise ValueError(f"begin {b.shape} and end {e.shape} frame vectors differ in shape")
        n = b.shape[0]
        if n == 0:
            raise ValueError("a sub-task database needs at least one entry")
        if not (np.isfinite(b).all() and np.isfinite(e).all()):
            raise ValueError("begin/end frame vectors contain NaN or inf")
        d = np.asarray(durations)
        if d.shape != (n,):
            raise ValueError(f"durations must have shape ({n},), got {d.shape}")
        if not np.issubdtype(d.dtype, np.integer) and not np.all(d == np.round(d)):
            raise ValueError("durations must be whole numbers of frames (end - 1 - start)")
        d = d.astype(np.int64)
        if (d < 0).any():
            raise ValueError(f"durations must be >= 0, got {int(d.min())}")
        labels = [""] * n if labels is None else [str(x) for x in labels]
        if len(labels) != n:
            raise ValueError(f"labels has {len(labels)} items, expected one per entry ({n})")
        meta = dict(meta or {})
        per_entry: dict[str, list] = {}
        for key in _PER_ENTRY:
            values = meta.pop(key, None)
            if values is None:
                values = [""] * n if key in ("episodes", "tasks") else [-1] * n
            values = list(values)
            if len(values) != n:
                raise ValueError(f"meta[{key!r}] has {len(values)} items, expected one per entry ({n})")
            per_entry[key] = values
        meta.setdefault("encoder", None)
        meta.setdefault("weights_id", None)
        meta["views"] = list(meta["views"]) if meta.get("views") is not None else None
        return cls(
            b, e, d, labels,
            episodes=[str(x) for x in per_entry["episodes"]],
            tasks=[str(x) for x in per_entry["tasks"]],
            starts=[int(x) for x in per_entry["starts"]],
            ends=[int(x) for x in per_entry["ends"]],
            meta=meta,
        )

    @classmethod
    def build(
        cls,
        episodes: Sequence[Episode],
        segmentations: Sequence[Sequence[Segment]] | None,
        encoder: Encoder,
        views: Sequence[str] = DEFAULT_VIEWS,
        cache=None,
        instructions: Sequence[Sequence[str]] | None = None,
    ) -> SubtaskDatabase:
        """Embed ``episodes`` and add one entry per segment of their segmentation.

        ``segmentations``: one list of segments per episode, or None to use each ``episode.segments``.
        Instructions come from ``instructions`` when given, else from ``episode.instructions`` when
        the segmentation is the episode's own (or the episode has none), else are empty.
        """
        if segmentations is not None and len(segmentations) != len(episodes):
            raise ValueError(
                f"{len(segmentations)} segmentations given for {len(episodes)} episodes"
            )
        if instructions is not None and len(instructions) != len(episodes):
            raise ValueError(f"{len(instructions)} instruction lists given for {len(episodes)} episodes")
        begin, end, durations, labels = [], [], [], []
        meta_lists: dict[str, list] = {k: [] for k in _PER_ENTRY}
        for i, ep in enumerate(episodes):
            segs = segmentations[i] if segmentations is not None else ep.segments
            if segs is None:
                raise ValueError(f"episode {ep.name!r} has no segmentation (pass segmentations=)")
            try:
                segs = validate_segments(segs, ep.num_frames)
            except ValueError as exc:
                raise ValueError(f"episode {ep.name!r}: {exc}") from exc
            if instructions is not None:
                instr = list(instructions[i])
            elif ep.instructions is not None and (
                ep.segments is None or [tuple(int(v) for v in s) for s in ep.segments] == segs
            ):
                # the episode's instructions describe this segmentation (its own, or it has none)
                instr = list(ep.instructions)
            else:
                instr = [""] * len(segs)
            if len(instr) != len(segs):
                raise ValueError(
                    f"episode {ep.name!r}: {len(instr)} instructions for {len(segs)} segments"
                )
            fv = episode_frame_vectors(ep, encoder, views=views, cache=cache)
            for (s, e), text in zip(segs, instr, strict=True):
                begin.append(fv[s])
                end.append(fv[e - 1])
                durations.append(e - 1 - s)
                labels.append(text)
                meta_lists["episodes"].append(ep.name)
                meta_lists["tasks"].append(ep.task)
                meta_lists["starts"].append(s)
                meta_lists["ends"].append(e)
        if not begin:
            raise ValueError("no segments to build a database from (no episodes given)")
        meta = {
            "encoder": encoder.name,
            "weights_id": encoder.weights_id,
            "views": list(views),
            **meta_lists,
        }
        return cls.from_arrays(np.stack(begin), np.stack(end), np.asarray(durations), labels, meta)

    # ----------------------------------------------------------------- access
    def __len__(self) -> int:
        return int(self.begin.shape[0])

    @property
    def frame_dim(self) -> int:
        """Dimension D of one frame vector (interval vectors have 2D)."""
        return int(self.begin.shape[1])

    def interval_vectors(self) -> np.ndarray:
        """(N, 2D) interval vectors ``concat(begin, end)``."""
        return np.concatenate([self.begin, self.end], axis=1)

    def entry(self, i: int) -> dict[str, Any]:
        """Provenance of entry ``i``: id, episode, task, instruction, start, end, duration."""
        i = int(i)
        return {
            "entry": i,
            "episode": self.episodes[i],
            "task": self.tasks[i],
            "instruction": self.labels[i],
            "start": self.starts[i],
            "end": self.ends[i],
            "duration": int(self.durations[i]),
        }

    def fingerprint(self) -> str:
        """Content hash of the vectors, durations and labels (keys caches built from this database)."""
        h = hashlib.sha256()
        for arr in (self.begin, self.end, self.durations):
            h.update(str(arr.shape).encode())
            h.update(np.ascontiguousarray(arr).tobytes())
        h.update(json.dumps(self.labels).encode())
        return h.hexdigest()

    def check_compatible(self, encoder: Encoder | None = None, views: Sequence[str] | None = None,
                         where: str = "database") -> None:
        """Raise DatabaseError when ``encoder``/``views`` differ from those that built the database."""
        if encoder is not None and self.meta.get("encoder") is not None:
            if encoder.name != self.meta["encoder"] or encoder.weights_id != self.meta.get("weights_id"):
                raise DatabaseError(
                    f"{where} was built with encoder {self.meta['encoder']!r} "
                    f"(weights {self.meta.get('weights_id')}), not {encoder.name!r} "
                    f"(weights {encoder.weights_id})"
                )
        if views is not None and self.meta.get("views") is not None:
            if list(views) != list(self.meta["views"]):
                raise DatabaseError(
                    f"{where} was built with views {self.meta['views']}, not {list(views)}"
                )

    # ----------------------------------------------------------------- persistence
    def save(self, directory: str | Path) -> Path:
        """Write the database to ``directory`` (created if needed); return the directory."""
        out = Path(directory)
        out.mkdir(parents=True, exist_ok=True)
        stale = out / MANIFEST
        if stale.exists():
            stale.unlink()  # the old manifest must not vouch for half-replaced files
        for name, arr in zip(_ARRAYS, (self.begin, self.end, self.durations), strict=True):
            _atomic_write(out / name, lambda f, a=arr: np.save(f, a, allow_pickle=False))
        entries = {
            "labels": self.labels, "episodes": self.episodes, "tasks": self.tasks,
            "starts": self.starts, "ends": self.ends,
        }
        _atomic_write(out / _ENTRIES, lambda f: f.write(json.dumps(entries).encode()))
        manifest = {
            "format_version": FORMAT_VERSION,
            "encoder": self.meta.get("encoder"),
            "weights_id": self.meta.get("weights_id"),
            "views": self.meta.get("views"),
            "frame_dim": self.frame_dim,
            "count": len(self),
            "extra": {k: v for k, v in self.meta.items() if k not in ("encoder", "weights_id", "views")},
            "checksums": {name: _sha256(out / name) for name in (*_ARRAYS, _ENTRIES)},
        }
        _atomic_write(out / MANIFEST, lambda f: f.write(json.dumps(manifest, indent=2).encode()))
        self.directory = out
        return out

    @classmethod
    def load(
        cls,
        directory: str | Path,
        encoder: Encoder | None = None,
        views: Sequence[str] | None = None,
    ) -> SubtaskDatabase:
        """Read a saved database, verifying checksums, dimensions and (when given) encoder and views."""
        root = Path(directory)
        if not root.is_dir():
            raise DatabaseError(f"database directory {root} does not exist")
        mpath = root / MANIFEST
        if not mpath.is_file():
            raise DatabaseError(f"{mpath} is missing (not a saved database, or an interrupted save)")
        try:
            manifest = json.loads(mpath.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise DatabaseError(f"{mpath} is not valid JSON: {exc}") from exc
        if manifest.get("format_version") != FORMAT_VERSION:
            raise DatabaseError(
                f"{mpath}: format_version {manifest.get('format_version')!r}, this code reads {FORMAT_VERSION}"
            )
        for key in ("frame_dim", "count", "checksums", "encoder", "weights_id", "views"):
            if key not in manifest:
                raise DatabaseError(f"{mpath}: field {key!r} is missing")
        for name in (*_ARRAYS, _ENTRIES):
            path = root / name
            if not path.is_file():
                raise DatabaseError(f"database file {path} is missing")
            expected = manifest["checksums"].get(name)
            if expected is None:
                raise DatabaseError(f"{mpath}: no checksum recorded for {name}")
            if _sha256(path) != expected:
                raise DatabaseError(f"database file {path} is corrupt (sha256 does not match the manifest)")
        begin = np.load(root / "begin.npy", allow_pickle=False)
        end = np.load(root / "end.npy", allow_pickle=False)
        durations = np.load(root / "durations.npy", allow_pickle=False)
        n, d = manifest["count"], manifest["frame_dim"]
        for name, arr in (("begin.npy", begin), ("end.npy", end)):
            if arr.shape != (n, d):
                raise DatabaseError(
                    f"database file {root / name} has shape {arr.shape}, manifest says ({n}, {d})"
                )
        if durations.shape != (n,):
            raise DatabaseError(f"database file {root / 'durations.npy'} has shape {durations.shape}, expected ({n},)")
        entries = json.loads((root / _ENTRIES).read_text())
        meta = {
            "encoder": manifest["encoder"], "weights_id": manifest["weights_id"],
            "views": manifest["views"], **manifest.get("extra", {}),
            **{k: entries[k] for k in _PER_ENTRY},
        }
        db = cls.from_arrays(begin, end, durations, entries["labels"], meta)
        db.check_compatible(encoder, views, where=f"database {root}")
        if encoder is not None and encoder.dim and manifest["views"]:
            expected_dim = encoder.dim * len(manifest["views"])
            if expected_dim != d:
                raise DatabaseError(
                    f"database {root} has {d}-d frame vectors but encoder {encoder.name!r} "
                    f"({encoder.dim}-d) over {len(manifest['views'])} views gives {expected_dim}-d"
                )
        db.directory = root
        return db
