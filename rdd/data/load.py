"""One entry point for every episode format: ``load_episodes(format, path, **options)``.

A format is a reader module: its ``load_episodes`` is registered as ``reader`` NAME (``rdd.registry``)
and ``episode_names`` stands beside it; reader options are the keyword arguments of both.
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Collection
from pathlib import Path
from typing import Any

from rdd import registry
from rdd.data.episode import Episode

# Parameters of a reader's load_episodes that are not reader options.
_NOT_OPTIONS = ("names",)


def formats() -> list[str]:
    """The episode formats there are readers for."""
    return registry.available("reader")


def _reader(format: str, options: dict[str, Any]):
    """The reader module of ``format``, after checking that it takes ``options``."""
    try:
        load = registry.component("reader", format)
    except ValueError:
        raise ValueError(f"unknown episode format {format!r}; choose one of {', '.join(formats())}") from None
    params = list(registry.parameters(load))[1:]  # the first is the path
    if options and not [p for p in params if p not in _NOT_OPTIONS] and not any(
            p.kind is inspect.Parameter.VAR_KEYWORD for p in inspect.signature(load).parameters.values()):
        raise TypeError(f"the {format} format takes no reader options, got {sorted(options)}")
    return importlib.import_module(load.__module__)


def episode_names(format: str, path: str | Path, **options: Any) -> list[str]:
    """Names of the episodes at ``path`` that :func:`load_episodes` would read, without reading them."""
    return _reader(format, options).episode_names(path, **options)


def load_episodes(format: str, path: str | Path, names: Collection[str] | None = None,
                  **options: Any) -> list[Episode]:
    """Episodes at ``path`` (one episode or a folder of them) in ``format``; with ``names`` only
    those episodes, and no other episode's files are opened."""
    return _reader(format, options).load_episodes(path, names=names, **options)
