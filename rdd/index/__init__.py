"""Nearest-neighbour retrieval backends: ``load_index(name, **options)`` resolves ``rdd.index.<name>``.

Each backend is one module exposing ``build(**options) -> NearestIndex`` plus one
``conf/index/<name>.yaml``; there is no central table to edit.
"""

from __future__ import annotations

import pkgutil
import re
from pathlib import Path

from rdd.index.base import NearestIndex
from rdd.registry import build_from_module

_NAME_RE = re.compile(r"^[a-z][a-z0-9_]*$")
_NOT_BACKENDS = {"base"}


def available_indexes() -> list[str]:
    """Names of the backend modules in this package."""
    return sorted(
        info.name for info in pkgutil.iter_modules([str(Path(__file__).parent)])
        if not info.ispkg and not info.name.startswith("_") and info.name not in _NOT_BACKENDS
    )


def load_index(name: str, **options) -> NearestIndex:
    """Build the (unfitted) backend ``name`` (module ``rdd.index.<name>``) with ``options``."""
    if not isinstance(name, str) or not _NAME_RE.match(name) or name not in available_indexes():
        raise ValueError(f"unknown index backend {name!r}; available: {available_indexes()}")
    return build_from_module(__name__, name, NearestIndex, available_indexes(), options)


__all__ = ["NearestIndex", "available_indexes", "load_index"]
