"""Visual encoders: ``load_encoder(name, **options)`` builds ``rdd.encoders.<name>`` via ``rdd.registry``.

Each encoder lives in its own module exposing ``build(**options) -> Encoder``; adding an encoder is
one module plus one ``conf/encoder/<name>.yaml`` whose ``_target_`` is ``rdd.encoders.<name>.build``
(no central table). Modules whose names start with an underscore hold shared helpers and
architectures; ``base``, ``embed`` and ``cache`` are not encoders.
"""

from __future__ import annotations

from rdd.encoders.base import Encoder
from rdd.registry import available, build


def available_encoders() -> list[str]:
    """Names of the encoder modules in this package."""
    return available("encoder")


def load_encoder(name: str, **options) -> Encoder:
    """Build the encoder ``name`` (module ``rdd.encoders.<name>``, its ``build``) with ``options``."""
    return build("encoder", name, **options)


__all__ = ["Encoder", "available_encoders", "load_encoder"]
