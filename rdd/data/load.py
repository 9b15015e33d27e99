"""One entry point for every episode format: ``load_episodes(format, path, **options)``."""

from __future__ import annotations

from collections.abc import Collection
from pathlib import Path
from typing import Any

from rdd.data.episode import Episode

FORMATS = ("rlbench", "lerobot", "native")


def _reader(format: str, options: dict[str, Any]):
    """The reader module of ``format``, after checking that it takes ``options``."""
    if format == "rlbench":
        from rdd.data import rlbench

        return rlbench
    if format == "lerobot":
        from rdd.data.lerobot import reader as lerobot

        return lerobot
    if format == "native":
        from rdd.data import native

        if options:
            raise TypeError(f"the native format takes no reader options, got {sorted(options)}")
        return native
    raise ValueError(f"unknown episode format {format!r}; choose one of {', '.join(FORMATS)}")


def episode_names(format: str, path: str | Path, **options: Any) -> list[str]:
    """Names of the episodes at ``path`` that :func:`load_episodes` would read, without reading them."""
    return _reader(format, options).episode_names(path, **options)


def load_episodes(format: str, path: str | Path, names: Collection[str] | None = None,
                  **options: Any) -> list[Episode]:
    """Episodes at ``path`` (one episode or a folder of them) in ``format``; with ``names`` only
    those episodes, and no other episode's files are opened."""
    return _reader(format, options).load_episodes(path, names=names, **options)
