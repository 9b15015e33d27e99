"""Nearest-neighbour retrieval indexes: ``load_index(name, **options)`` builds the index registered as ``name``.

Each index is one module defining a :class:`NearestIndex` subclass registered with
``@rdd.registry.register("index", NAME)``, plus one ``conf/index/<name>.yaml`` whose ``_target_`` is
that class; there is no central table to edit.
"""

from __future__ import annotations

from rdd.index.base import NearestIndex
from rdd.registry import available, build


def available_indexes() -> list[str]:
    """Names of the registered indexes."""
    return available("index")


def load_index(name: str, **options) -> NearestIndex:
    """Build the (unfitted) index registered as ``name`` with ``options``."""
    return build("index", name, **options)


__all__ = ["NearestIndex", "available_indexes", "load_index"]
