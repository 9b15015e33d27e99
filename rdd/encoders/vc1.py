"""``vc1``: VC-1 base (Majumdar et al. 2023), an MAE ViT-B/16; the CLS token after the final norm, 768-d.

Official checkpoint: ``vc1_vitb.pth`` (facebookresearch/eai-vc, ``model_utils.load_model("vc1_vitb")``),
a dict ``{"model": <MAE state dict>}``; as in ``vc_models.models.vit.vit.load_mae_encoder``, keys with
``decoder`` or ``mask_token`` are dropped and the rest load strictly into the timm-layout ViT
(``use_cls=True``, no head). Inputs: ``Resize(224)`` and ImageNet normalisation.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rdd.encoders._official import OfficialSpec, official_builder
from rdd.encoders._preprocess import IMAGENET_MEAN, IMAGENET_STD


def _make_model():
    """MAE ViT-B/16 at 224x224."""
    from rdd.encoders._vit import VisionTransformer

    return VisionTransformer(img_size=224, patch_size=16, embed_dim=768, depth=12, num_heads=12)


def _extract(obj: Any, path: Path) -> dict:
    """The official checkpoint object -> this model's state dict."""
    from rdd.encoders._checkpoint import take_entry

    sd = take_entry(obj, "model", "vc1", path)
    return {k: v for k, v in sd.items() if "decoder" not in k and "mask_token" not in k}


SPEC = OfficialSpec(
    name="vc1",
    dim=768,
    filename="vc1_vitb.pth",
    source="https://dl.fbaipublicfiles.com/eai-vc/vc1_vitb.pth (facebookresearch/eai-vc)",
    mean=IMAGENET_MEAN,
    std=IMAGENET_STD,
    make_model=_make_model,
    extract=_extract,
)


build = official_builder(SPEC, __name__)
