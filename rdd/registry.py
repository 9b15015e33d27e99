"""Module-per-component registries: ``<package>.<name>`` exposes ``build(**options)``."""

from __future__ import annotations

import importlib
from typing import Any


def build_from_module(package: str, name: str, base: type, available: list[str], options: dict[str, Any]) -> Any:
    """Import ``package.name``, call its ``build(**options)`` and check the result is a ``base``."""
    module = importlib.import_module(f"{package}.{name}")
    build = getattr(module, "build", None)
    if not callable(build):
        raise ValueError(f"module {package}.{name} has no build(); available: {available}")
    built = build(**options)
    if not isinstance(built, base):
        raise TypeError(f"{package}.{name}.build returned {type(built).__name__}, not {base.__name__}")
    return built
