"""The sub-task vector database: begin/end frame vectors of expert-labelled training sub-tasks.

Saved as a directory written whole (its layout: :mod:`rdd.database.store`).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rdd.atomic import atomic_dir
from rdd.data.episode import Episode
from rdd.database.build import Entries, segment_entries
from rdd.database.store import (
    PER_ENTRY,
    DatabaseError,
    read_database,
    record_calibration,
    saved_fingerprint,
    write_files,
    write_fingerprint,
)
from rdd.encoders.base import Encoder
from rdd.encoders.embed import DEFAULT_VIEWS, STATE_VIEW, STATE_VIEW_VERSION
from rdd.segments import Segment

__all__ = ["DatabaseError", "SubtaskDatabase"]


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
        # Every frame vector of some episodes (name -> (T, D)), kept for leave-one-out calibration.
        self.frames: dict[str, np.ndarray] = {}
        self.directory: Path | None = None  # set by save()/load(); backends may cache beside it
        self._fingerprint: tuple[tuple[int, ...], str] | None = None  # (identity of the data, hash)

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
        for key in PER_ENTRY:
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
        normalize_views: bool = True,
        keep_frames: Sequence[str] = (),
    ) -> SubtaskDatabase:
        """Embed ``episodes`` and add one entry per segment of their segmentation.

        Only the frames the entries need (each segment's first and last) are encoded, except for
        the episodes named in ``keep_frames``: those are embedded whole and their frame vectors
        kept in ``self.frames`` (leave-one-out calibration decomposes them).
        ``segmentations``: one list of segments per episode, or None to use each ``episode.segments``.
        Instructions come from ``instructions`` when given, else from ``episode.instructions`` when
        the segmentation is the episode's own (or the episode has none), else empty: the episode's goal
        (an RLBench variation description, a LeRobot task string) is kept as the entry's task only.
        ``normalize_views=False`` concatenates raw per-view embeddings (the official code's layout).
        """
        return cls.from_entries(
            segment_entries(episodes, segmentations, encoder, views, cache, instructions, normalize_views,
                            keep_frames),
            encoder, views, normalize_views)

    @classmethod
    def from_entries(cls, entries: Entries, encoder: Encoder, views: Sequence[str] = DEFAULT_VIEWS,
                     normalize_views: bool = True) -> SubtaskDatabase:
        """The database of :func:`rdd.database.build.segment_entries`' result (of :meth:`build`, or
        of episodes embedded apart and joined by :func:`rdd.database.build.merge_entries`)."""
        begin, end, durations, labels, meta_lists, frames = entries
        if not begin:
            raise ValueError("no segments to build a database from (no episodes given)")
        meta = {
            "encoder": encoder.name,
            "weights_id": encoder.weights_id,
            "views": list(views),
            "normalize_views": bool(normalize_views),
            **({"state_view": STATE_VIEW_VERSION} if STATE_VIEW in views else {}),
            **meta_lists,
        }
        db = cls.from_arrays(np.stack(begin), np.stack(end), np.asarray(durations), labels, meta)
        db.frames = frames
        return db

    @classmethod
    def concat(cls, parts: Sequence[SubtaskDatabase]) -> SubtaskDatabase:
        """One database holding the entries (and kept frames) of ``parts`` in order, e.g. per-task
        databases built apart. Parts must share encoder, weights, views and view normalisation;
        a calibration is not carried over (it belongs to the database it was fitted on)."""
        parts = list(parts)
        if not parts:
            raise ValueError("concat needs at least one database")
        first = parts[0]
        for i, db in enumerate(parts[1:], start=1):
            for key in ("encoder", "weights_id", "views", "normalize_views"):
                if db.meta.get(key) != first.meta.get(key):
                    raise ValueError(f"concat: part {i} has {key}={db.meta.get(key)!r}, "
                                     f"part 0 has {first.meta.get(key)!r}")
            if db.frame_dim != first.frame_dim:
                raise ValueError(f"concat: part {i} has frame_dim {db.frame_dim}, part 0 has {first.frame_dim}")
        frames: dict[str, np.ndarray] = {}
        for db in parts:
            clash = sorted(set(frames) & set(db.frames))
            if clash:
                raise ValueError(f"concat: frames of episode(s) {clash} are kept by two parts")
            frames.update(db.frames)
        meta = {k: v for k, v in first.meta.items() if k != "calibration"}
        for key in PER_ENTRY:
            meta[key] = [v for db in parts for v in getattr(db, key)]
        out = cls.from_arrays(np.concatenate([db.begin for db in parts]),
                              np.concatenate([db.end for db in parts]),
                              np.concatenate([db.durations for db in parts]),
                              [label for db in parts for label in db.labels], meta)
        out.frames = frames
        return out

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
        # Hashed once per set of arrays (a load that the saved one vouches for hashes nothing):
        # each use keyed the same caches by the same data, and a pass is ~0.3 s per 100 MB.
        if self._fingerprint is None or self._fingerprint[0] != self._data_identity():
            self._fingerprint = (self._data_identity(), self._hash())
        return self._fingerprint[1]

    def _data_identity(self) -> tuple[int, ...]:
        return (id(self.begin), id(self.end), id(self.durations), id(self.labels), len(self.labels))

    def _hash(self) -> str:
        h = hashlib.sha256()
        for arr in (self.begin, self.end, self.durations):
            h.update(str(arr.shape).encode())
            h.update(np.ascontiguousarray(arr).tobytes())
        h.update(json.dumps(self.labels).encode())
        return h.hexdigest()

    def check_compatible(self, encoder: Encoder | None = None, views: Sequence[str] | None = None,
                         where: str = "database") -> None:
        """Raise DatabaseError when ``encoder``/``views`` differ from those that built the database,
        or its state view is of another version than this code computes."""
        version = self.meta.get("state_view", 1)
        if STATE_VIEW in (self.meta.get("views") or []) and version != STATE_VIEW_VERSION:
            raise DatabaseError(f"{where} holds view {STATE_VIEW!r} of version {version}, but this code computes "
                                f"version {STATE_VIEW_VERSION} (a hand's opening is the median of its finger "
                                "dims): rebuild it with build-db")
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

    def calibrated_options(self) -> dict[str, Any]:
        """``alpha``, ``min_len``, ``max_len`` chosen by the stored calibration (``rdd.core.calibrate``)."""
        cal = self.meta.get("calibration")
        if not cal or not isinstance(cal.get("chosen"), dict):
            where = self.directory or "this database"
            raise DatabaseError(f"{where} has no calibration (run `python -m rdd calibrate --db DIR`, "
                                "or pass alpha/min_len/max_len)")
        chosen = cal["chosen"]
        return {"alpha": float(chosen["alpha"]), "min_len": int(chosen["min_len"]),
                "max_len": None if chosen["max_len"] is None else int(chosen["max_len"])}

    def episode_segments(self, episode: str) -> list[Segment]:
        """The stored segmentation of ``episode``: its entries' ``[start, end)`` in order."""
        segs = sorted((s, e) for n, s, e in zip(self.episodes, self.starts, self.ends, strict=True)
                      if n == episode)
        if not segs:
            raise KeyError(f"no entries of episode {episode!r} in the database")
        return segs

    # ----------------------------------------------------------------- persistence
    def save(self, directory: str | Path, overwrite: bool = False) -> Path:
        """Write the database to ``directory`` in one piece; return the directory.

        An existing ``directory`` is replaced only with ``overwrite=True`` (else
        :class:`rdd.atomic.TargetExistsError`, also when a concurrent writer finished first).
        """
        out = Path(directory)
        with atomic_dir(out, overwrite=overwrite) as tmp:
            write_files(tmp, (self.begin, self.end, self.durations),
                        {"labels": self.labels, "episodes": self.episodes, "tasks": self.tasks,
                         "starts": self.starts, "ends": self.ends},
                        self.frames, self.meta, self.frame_dim)
            # What a query needs is built with the database, not on its first query: the exact
            # index's clusters (saved beside it under the data's fingerprint, which is kept too).
            write_fingerprint(tmp, self.fingerprint())
            from rdd.index.exact import ExactIndex

            ExactIndex().fit(self.begin, self.end, cache_dir=tmp, key=self.fingerprint())
        self.directory = out
        return out

    def save_calibration(self, calibration: dict[str, Any]) -> Path:
        """Record ``calibration`` in the saved database's manifest (one atomic rewrite of it)."""
        if self.directory is None:
            raise DatabaseError("save_calibration needs a saved database (call save() or load() first)")
        mpath = record_calibration(self.directory, calibration)
        self.meta["calibration"] = calibration
        return mpath

    @classmethod
    def load(
        cls,
        directory: str | Path,
        encoder: Encoder | None = None,
        views: Sequence[str] | None = None,
    ) -> SubtaskDatabase:
        """Read a saved database, verifying checksums, dimensions and (when given) encoder and views."""
        root = Path(directory)
        manifest, begin, end, durations, entries, frames = read_database(root)
        d = manifest["frame_dim"]
        meta = {
            "encoder": manifest["encoder"], "weights_id": manifest["weights_id"],
            "views": manifest["views"], **manifest.get("extra", {}),
            "normalize_views": bool(manifest.get("normalize_views", True)),
            "calibration": manifest.get("calibration"),
            **{k: entries[k] for k in PER_ENTRY},
        }
        db = cls.from_arrays(begin, end, durations, entries["labels"], meta)
        db.frames = frames
        fingerprint = saved_fingerprint(root, manifest)
        if fingerprint is not None:
            db._fingerprint = (db._data_identity(), fingerprint)
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
