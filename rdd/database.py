"""The sub-task vector database: begin/end frame vectors of expert-labelled training sub-tasks.

On disk a database is a directory with ``begin.npy``, ``end.npy``, ``durations.npy``,
``entries.json`` (episode, task, instruction, start, end per entry), optionally ``frames.npz``
(every frame vector of the episodes kept for calibration) and ``manifest.json`` (format version,
encoder name and weights hash, views, ``normalize_views``, dimensions, entry count, sha256
checksums, the calibration's chosen options and scores). The directory is written whole through
``rdd.atomic.atomic_dir``: it appears complete or not at all, and an existing one is replaced only
with ``overwrite=True``.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rdd.atomic import atomic_dir, write_json_atomic
from rdd.data.episode import Episode
from rdd.data.frames import update_with_file
from rdd.encoders.base import Encoder
from rdd.encoders.embed import DEFAULT_VIEWS, episode_frame_vectors
from rdd.segments import Segment, validate_segments

FORMAT_VERSION = 1
MANIFEST = "manifest.json"
_ARRAYS = ("begin.npy", "end.npy", "durations.npy")
_ENTRIES = "entries.json"
_FRAMES = "frames.npz"
_PER_ENTRY = ("episodes", "tasks", "starts", "ends")


class DatabaseError(ValueError):
    """A database directory that cannot be used (missing, corrupt or mismatched)."""


def _sha256(path: Path) -> str:
    return update_with_file(hashlib.sha256(), path).hexdigest()


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
        normalize_views: bool = True,
        keep_frames: Sequence[str] = (),
    ) -> SubtaskDatabase:
        """Embed ``episodes`` and add one entry per segment of their segmentation.

        Only the frames the entries need (each segment's first and last) are encoded, except for
        the episodes named in ``keep_frames``: those are embedded whole and their frame vectors
        kept in ``self.frames`` (leave-one-out calibration decomposes them).
        ``segmentations``: one list of segments per episode, or None to use each ``episode.segments``.
        Instructions come from ``instructions`` when given, else from ``episode.instructions`` when
        the segmentation is the episode's own (or the episode has none), else the episode's goal
        (e.g. an RLBench variation description or a LeRobot task string) for every segment.
        ``normalize_views=False`` concatenates raw per-view embeddings (the official code's layout).
        """
        if segmentations is not None and len(segmentations) != len(episodes):
            raise ValueError(
                f"{len(segmentations)} segmentations given for {len(episodes)} episodes"
            )
        if instructions is not None and len(instructions) != len(episodes):
            raise ValueError(f"{len(instructions)} instruction lists given for {len(episodes)} episodes")
        names = [ep.name for ep in episodes]
        unknown = sorted(set(keep_frames) - set(names))
        if unknown:
            raise ValueError(f"keep_frames names episodes that are not being built: {unknown}")
        if len(set(names)) != len(names) and keep_frames:
            raise ValueError("episode names must be unique to keep frames for calibration")
        begin, end, durations, labels = [], [], [], []
        meta_lists: dict[str, list] = {k: [] for k in _PER_ENTRY}
        frames: dict[str, np.ndarray] = {}
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
                instr = [ep.goal or ""] * len(segs)
            if len(instr) != len(segs):
                raise ValueError(
                    f"episode {ep.name!r}: {len(instr)} instructions for {len(segs)} segments"
                )
            if ep.name in keep_frames:
                fv = episode_frame_vectors(ep, encoder, views=views, cache=cache, normalize=normalize_views)
                frames[ep.name] = fv
                rows = {f: f for f in range(ep.num_frames)}
            else:
                needed = sorted({f for s, e in segs for f in (s, e - 1)})
                fv = episode_frame_vectors(ep, encoder, views=views, cache=cache,
                                           normalize=normalize_views, frames=needed)
                rows = {f: r for r, f in enumerate(needed)}
            for (s, e), text in zip(segs, instr, strict=True):
                begin.append(fv[rows[s]])
                end.append(fv[rows[e - 1]])
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
            "normalize_views": bool(normalize_views),
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
        for key in _PER_ENTRY:
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

    def calibrated_options(self) -> dict[str, Any]:
        """``alpha``, ``min_len``, ``max_len`` chosen by the stored calibration (``rdd.calibrate``)."""
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
    def _manifest(self, out: Path) -> dict[str, Any]:
        files = [*_ARRAYS, _ENTRIES] + ([_FRAMES] if self.frames else [])
        return {
            "format_version": FORMAT_VERSION,
            "encoder": self.meta.get("encoder"),
            "weights_id": self.meta.get("weights_id"),
            "views": self.meta.get("views"),
            "normalize_views": bool(self.meta.get("normalize_views", True)),
            "frame_dim": self.frame_dim,
            "count": len(self),
            "frames_episodes": sorted(self.frames),
            "calibration": self.meta.get("calibration"),
            "extra": {k: v for k, v in self.meta.items()
                      if k not in ("encoder", "weights_id", "views", "normalize_views", "calibration")},
            "checksums": {name: _sha256(out / name) for name in files},
        }

    def save(self, directory: str | Path, overwrite: bool = False) -> Path:
        """Write the database to ``directory`` in one piece; return the directory.

        An existing ``directory`` is replaced only with ``overwrite=True`` (else
        :class:`rdd.atomic.TargetExistsError`, also when a concurrent writer finished first).
        """
        out = Path(directory)
        with atomic_dir(out, overwrite=overwrite) as tmp:
            for name, arr in zip(_ARRAYS, (self.begin, self.end, self.durations), strict=True):
                np.save(tmp / name, arr, allow_pickle=False)
            entries = {
                "labels": self.labels, "episodes": self.episodes, "tasks": self.tasks,
                "starts": self.starts, "ends": self.ends,
            }
            (tmp / _ENTRIES).write_text(json.dumps(entries))
            if self.frames:
                names = sorted(self.frames)
                np.savez(tmp / _FRAMES, **{f"f{i}": self.frames[n] for i, n in enumerate(names)})
            (tmp / MANIFEST).write_text(json.dumps(self._manifest(tmp), indent=2))
        self.directory = out
        return out

    def save_calibration(self, calibration: dict[str, Any]) -> Path:
        """Record ``calibration`` in the saved database's manifest (one atomic rewrite of it)."""
        if self.directory is None:
            raise DatabaseError("save_calibration needs a saved database (call save() or load() first)")
        mpath = self.directory / MANIFEST
        manifest = json.loads(mpath.read_text())
        manifest["calibration"] = calibration
        write_json_atomic(mpath, manifest, dumps=lambda m: json.dumps(m, indent=2))
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
        frame_names = manifest.get("frames_episodes") or []
        for name in (*_ARRAYS, _ENTRIES, *([_FRAMES] if frame_names else [])):
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
            "normalize_views": bool(manifest.get("normalize_views", True)),
            "calibration": manifest.get("calibration"),
            **{k: entries[k] for k in _PER_ENTRY},
        }
        db = cls.from_arrays(begin, end, durations, entries["labels"], meta)
        if frame_names:
            with np.load(root / _FRAMES, allow_pickle=False) as data:
                db.frames = {n: np.asarray(data[f"f{i}"], dtype=np.float32) for i, n in enumerate(frame_names)}
            for n, fv in db.frames.items():
                if fv.ndim != 2 or fv.shape[1] != d:
                    raise DatabaseError(f"{root / _FRAMES}: frames of {n!r} have shape {fv.shape}, "
                                        f"expected (T, {d})")
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
