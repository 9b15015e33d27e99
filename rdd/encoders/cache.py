"""On-disk embedding cache: one file per (episode content, view, encoder, weights, preprocessing).

Entries are ``.npz`` files holding the embeddings and a SHA-256 of their bytes; a file that fails to
load, fails its checksum or has the wrong shape is treated as a miss, recomputed and rewritten; an
entry that cannot be written (a full disk) is skipped with a warning and the run goes on.
Writes go through :func:`rdd.atomic.atomic_file` (a temporary file in the same folder, renamed into
place, with the umask's permissions), so a reader never sees a half-written entry, and two
processes filling the same entry cannot corrupt it.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rdd.atomic import atomic_file
from rdd.data.episode import Episode
from rdd.encoders._stream import encode_view
from rdd.encoders.base import Encoder

log = logging.getLogger(__name__)

CACHE_ENV = "RDD_CACHE_DIR"
# Bump when the entry format or the meaning of a key field changes, so old entries are never reused.
FORMAT_VERSION = 1


def default_cache_dir() -> Path:
    """``$RDD_CACHE_DIR/embeddings`` if set, else ``~/.cache/rdd/embeddings``."""
    root = os.environ.get(CACHE_ENV)
    base = Path(root).expanduser() if root else Path.home() / ".cache" / "rdd"
    return base / "embeddings"


@dataclass
class CacheStats:
    """Counts of what the cache did since it was created."""

    hits: int = 0
    misses: int = 0
    corrupt: int = 0
    unwritten: int = 0  # entries that could not be stored (the run went on without them)


class EmbeddingCache:
    """Embeddings of one episode view under one encoder, stored under ``root``."""

    def __init__(self, root: str | os.PathLike | None = None):
        self.root = Path(root).expanduser() if root is not None else default_cache_dir()
        self.stats = CacheStats()

    def key_fields(self, episode: Episode, encoder: Encoder, view: str) -> dict:
        """Everything that determines the embeddings: frames' content, view, encoder and its weights."""
        if view not in episode.views:
            raise KeyError(f"episode {episode.name!r} has no view {view!r}; available: {sorted(episode.views)}")
        # Where the encoder ran (runtime onnx or torch, CPU or CUDA) is deliberately not a key field:
        # every runtime computes the same fp32 network, and ONNX Runtime's embeddings differ from
        # torch's by about 1e-5 (per-frame cosine 1 - 1e-7, checked on every export). RDD compares
        # angular distances between frame vectors, which such a difference cannot reorder in any
        # practical sense, so an entry computed by either runtime serves both and a cache shared
        # by machines with and without onnxruntime stays shared.
        return {
            "format": FORMAT_VERSION,
            "frames": episode.fingerprint([view]),
            "view": view,
            "encoder": encoder.name,
            "weights_id": encoder.weights_id,
            "preprocess_id": getattr(encoder, "preprocess_id", ""),
            "dim": int(encoder.dim),
        }

    def path_for(self, fields: dict) -> Path:
        """Entry file of the given key fields (grouped by encoder for easy pruning)."""
        digest = hashlib.sha256(json.dumps(fields, sort_keys=True).encode()).hexdigest()
        return self.root / fields["encoder"] / digest[:2] / f"{digest}.npz"

    def get(self, episode: Episode, encoder: Encoder, view: str) -> np.ndarray | None:
        """Cached embeddings of ``episode``'s ``view`` (T, dim), or None when absent or unreadable."""
        fields = self.key_fields(episode, encoder, view)
        path = self.path_for(fields)
        if not path.exists():
            return None
        emb = self._read(path, (episode.num_frames, int(encoder.dim)))
        if emb is not None:
            self.stats.hits += 1
        return emb

    def get_or_compute(self, episode: Episode, encoder: Encoder, view: str) -> np.ndarray:
        """Cached float32 embeddings (T, dim) of ``episode``'s ``view``; encode and store on a miss."""
        fields = self.key_fields(episode, encoder, view)
        path = self.path_for(fields)
        expected_shape = (episode.num_frames, int(encoder.dim))
        if path.exists():
            emb = self._read(path, expected_shape)
            if emb is not None:
                self.stats.hits += 1
                return emb
            self.stats.corrupt += 1
        self.stats.misses += 1
        emb = np.asarray(encode_view(encoder, episode, view), dtype=np.float32)
        if emb.shape != expected_shape:
            raise RuntimeError(
                f"encoder {encoder.name!r} returned shape {emb.shape} for episode {episode.name!r} "
                f"view {view!r}, expected {expected_shape}"
            )
        self._write(path, emb, fields)
        return emb

    @staticmethod
    def _checksum(emb: np.ndarray) -> str:
        h = hashlib.sha256(str(emb.shape).encode())
        h.update(np.ascontiguousarray(emb, dtype=np.float32).tobytes())
        return h.hexdigest()

    def _read(self, path: Path, expected_shape: tuple[int, int]) -> np.ndarray | None:
        """The stored embeddings, or None (with a warning) when the entry is unreadable or corrupt."""
        try:
            with np.load(path, allow_pickle=False) as data:
                emb = np.asarray(data["embeddings"], dtype=np.float32)
                stored = str(data["checksum"])
        except Exception as exc:  # noqa: BLE001 - any unreadable entry is recomputed
            log.warning("embedding cache entry %s is unreadable (%s); recomputing", path, exc)
            return None
        if emb.shape != expected_shape or self._checksum(emb) != stored:
            log.warning("embedding cache entry %s fails its checksum or shape; recomputing", path)
            return None
        return emb

    def _write(self, path: Path, emb: np.ndarray, fields: dict) -> None:
        """Atomically store ``emb`` with its checksum and key fields at ``path`` (``rdd.atomic``); a
        cache that cannot be written (a full disk, a quota, no permission) is skipped with a warning."""
        try:
            with atomic_file(path, "wb") as fh:
                np.savez(
                    fh,
                    embeddings=emb,
                    checksum=np.array(self._checksum(emb)),
                    key=np.array(json.dumps(fields, sort_keys=True)),
                )
        except OSError as exc:
            self.stats.unwritten += 1
            # once per cache: the cause is the same for every entry after the first
            log.log(logging.WARNING if self.stats.unwritten == 1 else logging.DEBUG,
                    "embedding cache: cannot write %s (%s); going on without caching it", exc.filename or path,
                    exc.strerror or exc)
