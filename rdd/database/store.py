"""The on-disk form of a sub-task database (:class:`rdd.database.model.SubtaskDatabase`).

A database is a directory with ``begin.npy``, ``end.npy``, ``durations.npy``,
``entries.json`` (episode, task, instruction, start, end per entry), optionally ``frames.npz``
(every frame vector of the episodes kept for calibration) and ``manifest.json`` (format version,
encoder name and weights hash, views, ``normalize_views``, dimensions, entry count, sha256
checksums, the calibration's chosen options and scores), and ``fingerprint.json`` (the data's
fingerprint, trusted on load only beside the manifest checksums it was made from) and what the
indexes built with it (``exact-cells-*.npz``). The directory is written whole through
``rdd.atomic.atomic_dir``: it appears complete or not at all, and an existing one is replaced only
with ``overwrite=True``.

The manifest's own fields change the segments as much as the arrays do (``views`` in another order
pairs query and entry vectors wrongly), so ``field_checksums`` holds the sha256 of each field's
canonical JSON and a hand-edited field is an error naming it. Databases of format 1, written before
that, still load, with a warning that their manifest is trusted as it is (rebuild to have it
checked): failing them would throw away every database built so far for a check they never had.
"""

from __future__ import annotations

import hashlib
import io
import json
import logging
import os
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rdd.atomic import leftovers, write_json_atomic
from rdd.data.frames import update_with_file
from rdd.errors import InputError

FORMAT_VERSION = 2
UNSEALED_VERSION = 1  # format 1: the same files, without field_checksums
MANIFEST = "manifest.json"
SEAL = "field_checksums"
_ARRAYS = ("begin.npy", "end.npy", "durations.npy")
_ENTRIES = "entries.json"
_FRAMES = "frames.npz"
# Optional, written with the database: the fingerprint of its data (SubtaskDatabase.fingerprint).
_FINGERPRINT = "fingerprint.json"
# The per-entry provenance lists of entries.json besides the instructions (``labels``).
PER_ENTRY = ("episodes", "tasks", "starts", "ends")


log = logging.getLogger(__name__)


class DatabaseError(InputError):
    """A database directory that cannot be used (missing, corrupt or mismatched)."""


def _sha256(path: Path) -> str:
    return update_with_file(hashlib.sha256(), path).hexdigest()


def _field_sha256(value: Any) -> str:
    """sha256 of a manifest value's canonical JSON (as read back, so writing and reading agree)."""
    canonical = json.dumps(json.loads(json.dumps(value)), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(canonical.encode()).hexdigest()


def seal(manifest: dict[str, Any]) -> dict[str, Any]:
    """``manifest`` with ``field_checksums``: the sha256 of every other field."""
    fields = {k: v for k, v in manifest.items() if k != SEAL}
    return {**fields, SEAL: {k: _field_sha256(v) for k, v in fields.items()}}


def check_seal(manifest: dict[str, Any], mpath: Path, skip: tuple[str, ...] = ()) -> None:
    """Raise DatabaseError naming the first field (other than ``skip``) that differs from its checksum."""
    sums = manifest.get(SEAL)
    if not isinstance(sums, dict):
        raise DatabaseError(f"{mpath}: field {SEAL!r} is missing or not an object; rebuild the database")
    for key in sorted(set(sums) | set(manifest) - {SEAL}):
        if key in skip:
            continue
        if key not in manifest:
            raise DatabaseError(f"{mpath}: field {key!r} was removed after the database was written; "
                                "restore it or rebuild the database")
        if sums.get(key) != _field_sha256(manifest[key]):
            raise DatabaseError(f"{mpath}: field {key!r} does not match its checksum in {SEAL!r} (edited after "
                                "the database was written?); restore it or rebuild the database")


def make_manifest(out: Path, meta: Mapping[str, Any], frame_dim: int, count: int,
                  frames_episodes: Sequence[str]) -> dict[str, Any]:
    """The manifest of a database whose other files are already written in ``out``."""
    files = [*_ARRAYS, _ENTRIES] + ([_FRAMES] if frames_episodes else [])
    return seal({
        "format_version": FORMAT_VERSION,
        "encoder": meta.get("encoder"),
        "weights_id": meta.get("weights_id"),
        "views": meta.get("views"),
        "normalize_views": bool(meta.get("normalize_views", True)),
        "frame_dim": frame_dim,
        "count": count,
        "frames_episodes": sorted(frames_episodes),
        "calibration": meta.get("calibration"),
        "extra": {k: v for k, v in meta.items()
                  if k not in ("encoder", "weights_id", "views", "normalize_views", "calibration")},
        "checksums": {name: _sha256(out / name) for name in files},
    })


def write_files(tmp: Path, arrays: Sequence[np.ndarray], entries: Mapping[str, Any],
                frames: Mapping[str, np.ndarray], meta: Mapping[str, Any], frame_dim: int) -> None:
    """Write a database's files into the (temporary, empty) directory ``tmp``, the manifest last:
    ``arrays`` (begin, end, durations), ``entries`` (per-entry fields), ``frames`` (stored frames per episode)."""
    for name, arr in zip(_ARRAYS, arrays, strict=True):
        np.save(tmp / name, arr, allow_pickle=False)
    (tmp / _ENTRIES).write_text(json.dumps(dict(entries)))
    if frames:
        names = sorted(frames)
        np.savez(tmp / _FRAMES, **{f"f{i}": frames[n] for i, n in enumerate(names)})
    manifest = make_manifest(tmp, meta, frame_dim, len(arrays[0]), list(frames))
    (tmp / MANIFEST).write_text(json.dumps(manifest, indent=2))


def record_calibration(directory: Path, calibration: dict[str, Any]) -> Path:
    """Write ``calibration`` into the manifest of the database in ``directory`` (one atomic rewrite,
    resealed; a format-1 manifest becomes format 2)."""
    mpath = directory / MANIFEST
    manifest = json.loads(mpath.read_text())
    if manifest.get("format_version") == FORMAT_VERSION:
        check_seal(manifest, mpath, skip=("calibration",))  # never seal a hand edit as if it were ours
    manifest.update(format_version=FORMAT_VERSION, calibration=calibration)
    write_json_atomic(mpath, seal(manifest), dumps=lambda m: json.dumps(m, indent=2))
    return mpath


def _vouched(manifest: Mapping[str, Any]) -> dict[str, Any]:
    return {name: manifest["checksums"].get(name) for name in (*_ARRAYS, _ENTRIES)}


def write_fingerprint(directory: Path, fingerprint: str) -> None:
    """Keep the data's fingerprint beside the manifest of ``directory``, tied to the checksums it vouches for."""
    manifest = json.loads((directory / MANIFEST).read_text())
    (directory / _FINGERPRINT).write_text(json.dumps({"fingerprint": fingerprint, "checksums": _vouched(manifest)}))


def saved_fingerprint(root: Path, manifest: Mapping[str, Any]) -> str | None:
    """The fingerprint kept in ``root``, if it was made from the files that ``manifest`` (verified) vouches for."""
    try:
        kept = json.loads((root / _FINGERPRINT).read_text())
        fingerprint = kept["fingerprint"]
        if kept["checksums"] == _vouched(manifest) and isinstance(fingerprint, str) and len(fingerprint) == 64:
            return fingerprint
    except (OSError, ValueError, KeyError, TypeError):
        pass
    return None


class _Snapshot:
    """The files of one database directory as one consistent set: opened relative to the directory
    itself (its inode), so a concurrent ``build-db --force``, which renames a whole new directory into
    place and deletes the old one, can never mix files of two builds; each file is read once into
    memory, and those bytes are what is verified and used."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.fd = os.open(root, os.O_RDONLY | os.O_DIRECTORY)

    def read(self, name: str) -> bytes:
        fd = os.open(name, os.O_RDONLY, dir_fd=self.fd)
        with os.fdopen(fd, "rb") as fh:
            return fh.read()

    def close(self) -> None:
        os.close(self.fd)


class _Replaced(Exception):
    """A file vanished while the directory was read: it was replaced and the old one deleted."""


# A load that finds its directory replaced under it starts again on the new one, this many times.
_TRIES = 5


def read_database(root: Path) -> tuple[dict[str, Any], np.ndarray, np.ndarray, np.ndarray, dict[str, Any],
                                      dict[str, np.ndarray]]:
    """Manifest, begin, end, durations, entries and kept frames (name -> (T, d)) of the database in
    ``root``, all from one version of it, checksums verified on the bytes used (DatabaseError otherwise)."""
    for attempt in range(_TRIES):
        try:
            snapshot = _Snapshot(root)
        except FileNotFoundError:
            if attempt + 1 < _TRIES and _being_replaced(root):
                time.sleep(0.05)  # between the old directory's move and the new one's arrival
                continue
            raise DatabaseError(f"database directory {root} does not exist") from None
        except NotADirectoryError:
            raise DatabaseError(f"database directory {root} is a file, not a directory") from None
        try:
            return _read_snapshot(snapshot)
        except _Replaced:
            continue
        finally:
            snapshot.close()
    raise DatabaseError(f"database {root} was replaced {_TRIES} times while it was read (another run is "
                        "rebuilding it); load it again once that run is done")


def _being_replaced(root: Path) -> bool:
    """Whether a directory replace of ``root`` is under way (its temporaries are beside it)."""
    return bool(leftovers(root))


def _read_snapshot(snap: _Snapshot):
    root = snap.root
    mpath = root / MANIFEST
    raw = _read(snap, MANIFEST, f"{mpath} is missing (not a saved database, or an interrupted save)")
    try:
        manifest = json.loads(raw)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DatabaseError(f"{mpath} is not valid JSON: {exc}") from exc
    if not isinstance(manifest, dict):
        raise DatabaseError(f"{mpath}: expected a JSON object, got {type(manifest).__name__}")
    if manifest.get("format_version") not in (FORMAT_VERSION, UNSEALED_VERSION):
        raise DatabaseError(f"{mpath}: format_version {manifest.get('format_version')!r}, this code reads "
                            f"{UNSEALED_VERSION} and {FORMAT_VERSION}")
    for key in ("frame_dim", "count", "checksums", "encoder", "weights_id", "views"):
        if key not in manifest:
            raise DatabaseError(f"{mpath}: field {key!r} is missing")
    frame_names = manifest.get("frames_episodes") or []
    data: dict[str, bytes] = {}
    for name in (*_ARRAYS, _ENTRIES, *([_FRAMES] if frame_names else [])):
        data[name] = _read(snap, name, f"database file {root / name} is missing")
        expected = manifest["checksums"].get(name)
        if expected is None:
            raise DatabaseError(f"{mpath}: no checksum recorded for {name}")
        if hashlib.sha256(data[name]).hexdigest() != expected:
            raise DatabaseError(f"database file {root / name} is corrupt (sha256 does not match the manifest); "
                                "rebuild the database")
    begin, end, durations = (np.load(io.BytesIO(data[name]), allow_pickle=False) for name in _ARRAYS)
    n, d = manifest["count"], manifest["frame_dim"]
    for name, arr in (("begin.npy", begin), ("end.npy", end)):
        if arr.shape != (n, d):
            raise DatabaseError(
                f"database file {root / name} has shape {arr.shape}, manifest says ({n}, {d})"
            )
    if durations.shape != (n,):
        raise DatabaseError(f"database file {root / 'durations.npy'} has shape {durations.shape}, expected ({n},)")
    # Last, so an edit that the files contradict (frame_dim, count) is reported by that check.
    if manifest["format_version"] == FORMAT_VERSION:
        check_seal(manifest, mpath)
    else:
        log.warning("%s: format_version %s, written before manifest fields were checksummed: its views and "
                    "encoder fields are trusted as they are (rebuild the database to have them checked)",
                    mpath, UNSEALED_VERSION)
    entries = json.loads(data[_ENTRIES])
    frames = _frames(root, data[_FRAMES], frame_names, d) if frame_names else {}
    return manifest, begin, end, durations, entries, frames


def _read(snap: _Snapshot, name: str, missing: str) -> bytes:
    """The bytes of ``name`` in the snapshot; a file gone since the manifest was read means the
    directory was replaced meanwhile (_Replaced), one never there is a DatabaseError."""
    try:
        return snap.read(name)
    except FileNotFoundError:
        try:
            replaced = os.stat(snap.root).st_ino != os.fstat(snap.fd).st_ino
        except FileNotFoundError:
            replaced = True
        if replaced:  # the old directory is being deleted under us: read the new one
            raise _Replaced from None
        raise DatabaseError(missing) from None


def _frames(root: Path, data: bytes, frame_names: list[str], d: int) -> dict[str, np.ndarray]:
    """The kept frame vectors (name -> (T, d)) in the bytes of ``frames.npz``."""
    with np.load(io.BytesIO(data), allow_pickle=False) as npz:
        frames = {n: np.asarray(npz[f"f{i}"], dtype=np.float32) for i, n in enumerate(frame_names)}
    for n, fv in frames.items():
        if fv.ndim != 2 or fv.shape[1] != d:
            raise DatabaseError(f"{root / _FRAMES}: frames of {n!r} have shape {fv.shape}, "
                                f"expected (T, {d})")
    return frames
