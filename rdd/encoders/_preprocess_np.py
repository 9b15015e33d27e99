"""Resize and centre-crop without torch: PIL's float ("F") images, torch's antialiased bilinear within
float rounding.

torch's antialiased ``interpolate`` is PIL's resampling code, so resizing each channel as a 32-bit
float PIL image gives the same values (max abs difference 2e-5 on [-1, 1], per-frame embedding cosine
1 - 1e-11) at 3.4x the speed on 128 px RLBench frames (0.72 against 2.41 ms per frame) and 1.5x on
640x512 ones, and a process that only needs the ONNX graph never imports torch. Resizing the uint8
frames before the float conversion was faster still (0.59 ms) but rounds every pixel to 1/255 and
moved embeddings to a per-frame cosine of 0.9987, below the 0.9999 the embeddings must keep.
"""

from __future__ import annotations

import numpy as np


def shorter_side_geometry(h: int, w: int, size: int) -> tuple[int, int, int, int]:
    """(new_h, new_w, top, left): the shorter side resized to ``size`` as torchvision's ``Resize(int)``
    rounds, and the offsets of a central ``size`` x ``size`` crop as ``CenterCrop`` rounds them."""
    if min(h, w) == size:
        new_h, new_w = h, w
    elif h <= w:
        new_h, new_w = size, int(size * w / h)
    else:
        new_h, new_w = int(size * h / w), size
    return new_h, new_w, int(round((new_h - size) / 2.0)), int(round((new_w - size) / 2.0))


def resized_center_crop(images: np.ndarray, size: int, scale: float = 1.0 / 255.0,
                        offset: float = 0.0) -> np.ndarray:
    """uint8 (N, H, W, 3) -> float32 (N, 3, size, size): ``x * scale`` resized (shorter side, bilinear,
    antialiased), centre-cropped, plus ``offset``."""
    from PIL import Image

    n, h, w, _ = images.shape
    new_h, new_w, top, left = shorter_side_geometry(h, w, size)
    out = np.empty((n, 3, size, size), dtype=np.float32)
    for k in range(n):
        # One frame at a time: a batch of large frames in float32 would be several times its uint8 size.
        chw = images[k].transpose(2, 0, 1).astype(np.float32)
        chw *= np.float32(scale)  # scaling before the resize, as torch does; resizing is linear
        for c in range(3):
            plane = chw[c]
            if (new_h, new_w) != (h, w):
                plane = np.asarray(Image.fromarray(plane).resize((new_w, new_h), Image.BILINEAR))
            out[k, c] = plane[top : top + size, left : left + size]
    if offset:
        out += np.float32(offset)
    return out
