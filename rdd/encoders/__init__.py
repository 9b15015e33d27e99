"""Visual encoders: ``load_encoder(name, **options)`` builds the encoder registered as ``name``.

An encoder is a factory ``build(**options) -> Encoder`` registered with
``@rdd.registry.register("encoder", NAME)`` in a module of this package; adding one is that module
plus one ``conf/encoder/<name>.yaml`` whose ``_target_`` is the factory (no central table). Modules
whose names start with an underscore hold shared helpers and architectures.
"""

from __future__ import annotations

from rdd.encoders.base import Encoder
from rdd.registry import available, build


def available_encoders() -> list[str]:
    """Names of the registered encoders."""
    return available("encoder")


def load_encoder(name: str, **options) -> Encoder:
    """Build the encoder registered as ``name`` with ``options``."""
    return build("encoder", name, **options)


__all__ = ["Encoder", "available_encoders", "load_encoder"]
