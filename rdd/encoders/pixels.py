"""``pixels``: area-downsampled raw pixels as a vector. No weights; a floor baseline and a fast test encoder."""

from __future__ import annotations

import hashlib

import numpy as np

from rdd.encoders._common import check_batch_size, check_images
from rdd.encoders._runtime import torch_threads
from rdd.encoders.base import Encoder
from rdd.registry import register


class PixelsEncoder(Encoder):
    """Each image area-averaged to ``size`` x ``size``, scaled to [-1, 1] and flattened (3*size*size)."""

    has_weights = False
    active_runtime = "torch"  # no network: the area average always runs in torch

    def __init__(self, size: int = 16, batch_size: int = 256, num_threads: int | None = None,
                 runtime: str = "auto", device: str = "auto"):
        from rdd.encoders._runtime import check_runtime

        if int(size) != size or int(size) < 1:
            raise ValueError(f"pixels: option size must be a positive integer, got {size!r}")
        # Accepted so every encoder takes the same options; an area average has no network to move
        # to another runtime or device, and it runs at memory speed on the CPU.
        check_runtime(runtime, device, "pixels")
        self.runtime, self.device = runtime, device
        self.name = "pixels"
        self.size = int(size)
        self.dim = 3 * self.size * self.size
        self.batch_size = check_batch_size(batch_size, self.name)
        self.num_threads = num_threads
        # Centring on 0 spreads cosine similarities; raw [0, 1] pixels would all sit in one orthant.
        self.preprocess_id = f"area{self.size}x{self.size}/rgb/x*2-1"

    @property
    def weights_id(self) -> str:
        """No weights: a hash of the encoder's definition, so it still separates cache entries."""
        return hashlib.sha256(f"pixels-no-weights:{self.preprocess_id}".encode()).hexdigest()

    def encode(self, images: np.ndarray) -> np.ndarray:
        """Downsample uint8 images (N, H, W, 3) by area averaging to float32 vectors (N, 3*size*size)."""
        import torch
        import torch.nn.functional as F

        from rdd.encoders._preprocess import to_float_tensor

        images = check_images(images, self.name)
        outs = []
        with torch_threads(self.num_threads), torch.inference_mode():
            for start in range(0, images.shape[0], self.batch_size):
                x = to_float_tensor(images[start : start + self.batch_size])
                # Adaptive average pooling is exact area averaging when H, W are multiples of size.
                x = F.adaptive_avg_pool2d(x, (self.size, self.size)) * 2.0 - 1.0
                outs.append(x.reshape(x.shape[0], -1).numpy())
        if not outs:
            return np.zeros((0, self.dim), dtype=np.float32)
        return np.concatenate(outs, axis=0).astype(np.float32, copy=False)


@register("encoder", "pixels")
def build(
    size: int = 16,
    batch_size: int = 256,
    num_threads: int | None = None,
    checkpoint: str | None = None,
    runtime: str = "auto",
    device: str = "auto",
) -> PixelsEncoder:
    """The ``pixels`` encoder; ``checkpoint`` must stay null (it has no weights)."""
    if checkpoint is not None:
        raise ValueError(f"pixels: has no weights, but option checkpoint={checkpoint!r} was given")
    return PixelsEncoder(size=size, batch_size=batch_size, num_threads=num_threads, runtime=runtime, device=device)
