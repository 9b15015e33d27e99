"""Preprocessing of the paper's encoders: torchvision/RDD semantics without torchvision."""

import numpy as np
import torch

from rdd.encoders._official import make_preprocess
from rdd.encoders._preprocess import center_crop, resize_shorter


def test_resize_shorter_and_crop_follow_torchvision_rules():
    x = torch.zeros(1, 3, 96, 128)
    assert tuple(resize_shorter(x, 224).shape[-2:]) == (224, 298)  # int(224 * 128 / 96)
    y = torch.arange(232 * 232, dtype=torch.float32).view(1, 1, 232, 232)
    crop = center_crop(y, 224)
    assert crop[0, 0, 0, 0].item() == 4 * 232 + 4  # round((232 - 224) / 2) = 4 on each side


def test_already_224_square_is_only_normalised():
    from rdd.encoders.vc1 import SPEC

    img = np.random.default_rng(0).integers(0, 256, size=(2, 224, 224, 3), dtype=np.uint8)
    pre, _ = make_preprocess(SPEC)
    mean = np.array([0.485, 0.456, 0.406])[:, None, None]
    std = np.array([0.229, 0.224, 0.225])[:, None, None]
    expected = (img.transpose(0, 3, 1, 2) / 255.0 - mean) / std
    np.testing.assert_allclose(pre(img).numpy(), expected, rtol=1e-5, atol=1e-5)


def test_non_square_frames_are_squared_not_cropped():
    """RDD's uvd_embed stretches frames to a square before Resize(224): edges survive."""
    from rdd.encoders.clip import SPEC

    img = np.zeros((1, 480, 640, 3), dtype=np.uint8)
    img[:, :, :80, 1] = 255  # green band on the left eighth
    img[:, :, 80:, 2] = 255  # blue elsewhere
    pre, _ = make_preprocess(SPEC)
    out = pre(img)
    assert out.shape == (1, 3, 224, 224)
    std = torch.tensor([0.26862954, 0.26130258, 0.27577711]).view(3, 1, 1)
    mean = torch.tensor([0.48145466, 0.4578275, 0.40821073]).view(3, 1, 1)
    rgb = out[0] * std + mean
    assert rgb[1, :, :20].mean() > 0.95 and rgb[2, :, :20].mean() < 0.05  # left stays green
    assert rgb[2, :, 40:].mean() > 0.95  # the rest blue
