"""``resnet``: ImageNet ResNet-50 (torchvision ``IMAGENET1K_V2``), its 1000 logits as features.

The official RDD code (through UVD's ``ResNetPreprocessor``) uses torchvision's ``resnet50`` with
``ResNet50_Weights.DEFAULT`` and keeps the classifier, so the embedding is the 1000 logits; inputs use
those weights' transform: ``Resize(232)``, ``CenterCrop(224)``, ImageNet normalisation. The checkpoint
is torchvision's own file in torchvision's key layout (``conv1.weight`` ... ``fc.bias``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rdd.encoders._official import OfficialSpec, official_builder
from rdd.encoders._preprocess import IMAGENET_MEAN, IMAGENET_STD


def _make_model():
    """torchvision-layout ResNet-50 with its 1000-way classifier."""
    from rdd.encoders._resnet import ResNet50

    return ResNet50(fc_out=1000)


def _extract(obj: Any, path: Path) -> dict:
    """The official checkpoint object -> this model's state dict."""
    if not isinstance(obj, dict):
        raise ValueError(f"encoder 'resnet': checkpoint {str(path)!r} is not a state dict")
    return obj


SPEC = OfficialSpec(
    name="resnet",
    dim=1000,
    filename="resnet50-11ad3fa6.pth",
    source="https://download.pytorch.org/models/resnet50-11ad3fa6.pth (torchvision ResNet50_Weights.IMAGENET1K_V2)",
    mean=IMAGENET_MEAN,
    std=IMAGENET_STD,
    resize=232,
    make_model=_make_model,
    extract=_extract,
)


build = official_builder(SPEC, __name__)
