"""Image preprocessing in torch (torchvision's Resize/CenterCrop/Normalize semantics, without torchvision)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # torch is imported on first use, so listing encoders stays cheap
    import torch

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)
CLIP_STD = (0.26862954, 0.26130258, 0.27577711)


def to_float_tensor(images: np.ndarray) -> torch.Tensor:
    """uint8 (N, H, W, 3) -> float32 (N, 3, H, W) in [0, 1]."""
    import torch

    images = np.ascontiguousarray(images)
    if not images.flags.writeable:
        # torch.from_numpy warns on read-only arrays (e.g. memory-mapped frames); copy those.
        images = images.copy()
    x = torch.from_numpy(images)
    return x.permute(0, 3, 1, 2).float().div_(255.0)


def resize_shorter(x: torch.Tensor, size: int, mode: str = "bilinear") -> torch.Tensor:
    """Resize so the shorter side is ``size`` keeping aspect ratio (torchvision ``Resize(int)``)."""
    h, w = x.shape[-2:]
    if min(h, w) == size:
        return x
    if h <= w:
        new_h, new_w = size, int(size * w / h)
    else:
        new_h, new_w = int(size * h / w), size
    return resize_exact(x, (new_h, new_w), mode)


def resize_exact(x: torch.Tensor, hw: Sequence[int], mode: str = "bilinear") -> torch.Tensor:
    """Resize to exactly (H, W) with antialiasing (torchvision ``Resize((h, w))`` on tensors)."""
    import torch.nn.functional as F

    if tuple(x.shape[-2:]) == tuple(hw):
        return x
    out = F.interpolate(x, size=tuple(int(v) for v in hw), mode=mode, align_corners=False, antialias=True)
    # Bicubic overshoots; torchvision clamps back to the input range for float images in [0, 1].
    return out.clamp_(0.0, 1.0) if mode == "bicubic" else out


def center_crop(x: torch.Tensor, size: int) -> torch.Tensor:
    """Central ``size`` x ``size`` crop (torchvision ``CenterCrop`` rounding)."""
    h, w = x.shape[-2:]
    if h < size or w < size:
        raise ValueError(f"cannot centre-crop {size}x{size} from a {h}x{w} image")
    top = int(round((h - size) / 2.0))
    left = int(round((w - size) / 2.0))
    return x[..., top : top + size, left : left + size]


def normalize(x: torch.Tensor, mean: Sequence[float], std: Sequence[float]) -> torch.Tensor:
    """Per-channel (x - mean) / std."""
    import torch

    m = torch.tensor(mean, dtype=x.dtype).view(1, 3, 1, 1)
    s = torch.tensor(std, dtype=x.dtype).view(1, 3, 1, 1)
    return (x - m) / s
