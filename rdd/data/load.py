"""One entry point for every episode format: ``load_episodes(format, path, **options)``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rdd.data.episode import Episode

FORMATS = ("rlbench", "lerobot", "native")


def load_episodes(format: str, path: str | Path, **options: Any) -> list[Episode]:
    """Episodes at ``path`` (one episode or a folder of them) in ``format``."""
    if format == "rlbench":
        from rdd.data import rlbench

        return rlbench.load_episodes(path, **options)
    if format == "lerobot":
        from rdd.data import lerobot

        return lerobot.load_episodes(path, **options)
    if format == "native":
        from rdd.data import native

        if options:
            raise TypeError(f"the native format takes no reader options, got {sorted(options)}")
        return native.load_episodes(path)
    raise ValueError(f"unknown episode format {format!r}; choose one of {', '.join(FORMATS)}")
