"""Remembered weights ids: the state-dict hash of a weights file, kept so that a later run knows an
encoder's identity (its cache keys) without importing torch or building the network.

A record is keyed by the sha256 of the weights file's bytes and the versions of the packages that
turn those bytes into a state dict, and it holds the ``state_dict_hash`` computed from them when
the model was last really built. Records live under ``$RDD_CACHE_DIR/weights`` (beside the
embeddings and ONNX exports); one that is missing or unreadable only means the model is built
and hashed as before, and a record that cannot be written is skipped.
"""

from __future__ import annotations

import hashlib
import json
import logging
from collections.abc import Sequence
from importlib import metadata
from pathlib import Path

from rdd.atomic import write_json_atomic

log = logging.getLogger(__name__)

FORMAT = 1  # bump when what a record vouches for changes


def default_weights_dir() -> Path:
    """``$RDD_CACHE_DIR/weights`` if set, else ``~/.cache/rdd/weights``."""
    from rdd.encoders.cache import default_cache_dir

    return default_cache_dir().parent / "weights"


def weights_key(name: str, path: str | Path, packages: Sequence[str]) -> dict:
    """What determines the state dict loaded from the weights file ``path`` by encoder ``name``."""
    with open(path, "rb") as fh:
        digest = hashlib.file_digest(fh, "sha256").hexdigest()
    versions = {}
    for package in packages:
        try:
            versions[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            versions[package] = None
    return {"format": FORMAT, "encoder": name, "file_sha256": digest, "versions": versions}


def _record_path(root: Path, key: dict) -> Path:
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()
    return root / f"{key['encoder']}-{digest[:32]}.json"


def remembered(key: dict, root: Path | None = None) -> str | None:
    """The weights id recorded for ``key``, or None when there is no readable record of it."""
    path = _record_path(root or default_weights_dir(), key)
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    wid = record.get("weights_id") if isinstance(record, dict) and record.get("key") == key else None
    return wid if isinstance(wid, str) and len(wid) == 64 else None


def remember(key: dict, weights_id: str, root: Path | None = None) -> None:
    """Record ``weights_id`` for ``key``; a record that cannot be written is skipped (logged)."""
    path = _record_path(root or default_weights_dir(), key)
    try:
        write_json_atomic(path, {"key": key, "weights_id": weights_id})
    except OSError as exc:
        log.debug("could not record the weights id of %s at %s: %s", key["encoder"], path, exc)
