"""``r3m``: R3M (Nair et al. 2022) ResNet-50 trunk, fc removed, 2048-d pooled features.

Official checkpoint: ``model.pt`` of ``r3m_50`` (facebookresearch/r3m, ``load_r3m("resnet50")``), a dict
``{"r3m": {"module.convnet.*", "module.lang_enc.*", "module.lang_rew.*"}}``; the language head is
dropped as in ``r3m.remove_language_head``. Inputs: ``Resize(224)`` and ImageNet normalisation.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rdd.encoders._official import OfficialSpec, official_builder
from rdd.encoders._preprocess import IMAGENET_MEAN, IMAGENET_STD


def _make_model():
    """torchvision-layout ResNet-50 with ``fc = Identity``."""
    from rdd.encoders._resnet import ResNet50

    return ResNet50(fc_out=None)


def _extract(obj: Any, path: Path) -> dict:
    """The official checkpoint object -> this model's state dict."""
    from rdd.encoders._checkpoint import take_entry, take_prefix

    sd = take_entry(obj, "r3m", "r3m", path)
    return take_prefix(sd, "module.convnet.", "r3m", path, ignore=("module.lang_enc.", "module.lang_rew."))


SPEC = OfficialSpec(
    name="r3m",
    dim=2048,
    filename="model.pt",
    source="the R3M ResNet-50 release linked from https://github.com/facebookresearch/r3m (r3m/__init__.py, load_r3m(\"resnet50\"): Google Drive id 1Xu0ssuG0N1zjZS54wmWzJ7-nb0-7XzbA)",
    mean=IMAGENET_MEAN,
    std=IMAGENET_STD,
    make_model=_make_model,
    extract=_extract,
)


build = official_builder(SPEC, __name__)
