"""``vip``: VIP (Ma et al. 2023) ResNet-50 with its 2048->1024 linear head, 1024-d features.

Official checkpoint: ``model.pt`` (facebookresearch/vip, ``load_vip("resnet50")``), a dict
``{"vip": {"module.convnet.*"}}`` whose ``convnet.fc`` is the 1024-d head. Inputs: ``Resize(224)``
and ImageNet normalisation.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rdd.encoders._official import OfficialSpec, official_builder
from rdd.encoders._preprocess import IMAGENET_MEAN, IMAGENET_STD


def _make_model():
    """torchvision-layout ResNet-50 with ``fc = Linear(2048, 1024)``."""
    from rdd.encoders._resnet import ResNet50

    return ResNet50(fc_out=1024)


def _extract(obj: Any, path: Path) -> dict:
    """The official checkpoint object -> this model's state dict."""
    from rdd.encoders._checkpoint import take_entry, take_prefix

    sd = take_entry(obj, "vip", "vip", path)
    return take_prefix(sd, "module.convnet.", "vip", path)


SPEC = OfficialSpec(
    name="vip",
    dim=1024,
    filename="model.pt",
    source="https://pytorch.s3.amazonaws.com/models/rl/vip/model.pt (facebookresearch/vip, vip/__init__.py)",
    mean=IMAGENET_MEAN,
    std=IMAGENET_STD,
    make_model=_make_model,
    extract=_extract,
)


build = official_builder(SPEC, __name__)
