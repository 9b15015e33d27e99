"""Visual encoders: ``load_encoder(name, **options)`` resolves ``rdd.encoders.<name>``.

Each encoder lives in its own module exposing ``build(**options) -> Encoder``; adding an encoder is
one module plus one ``conf/encoder/<name>.yaml`` (no central table). Modules whose names start with
an underscore hold shared helpers and architectures; ``base``, ``embed`` and ``cache`` are not encoders.
"""

from __future__ import annotations

import importlib
import pkgutil
import re
from pathlib import Path

from rdd.encoders.base import Encoder
from rdd.registry import build_from_module

_NAME_RE = re.compile(r"^[a-z][a-z0-9_]*$")


def available_encoders() -> list[str]:
    """Names of the encoder modules in this package (those that define ``build``)."""
    names = []
    for info in pkgutil.iter_modules([str(Path(__file__).parent)]):
        if info.name.startswith("_") or info.ispkg:
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        if callable(getattr(module, "build", None)):
            names.append(info.name)
    return sorted(names)


def load_encoder(name: str, **options) -> Encoder:
    """Build the encoder ``name`` (a module ``rdd.encoders.<name>``) with ``options``."""
    if not isinstance(name, str) or not _NAME_RE.match(name):
        raise ValueError(
            f"encoder name {name!r} is not a valid module name; available: {available_encoders()}"
        )
    module_path = Path(__file__).parent / f"{name}.py"
    if not module_path.is_file():
        raise ValueError(f"unknown encoder {name!r}; available: {available_encoders()}")
    return build_from_module(__name__, name, Encoder, available_encoders(), options)


__all__ = ["Encoder", "available_encoders", "load_encoder"]
