"""``dinov2``: DINOv2 ViT-L/14 (Oquab et al. 2023), the normed CLS token, 1024-d.

Official checkpoint: ``dinov2_vitl14_pretrain.pth`` (facebookresearch/dinov2, hub ``dinov2_vitl14``), a
flat state dict (``cls_token``, ``pos_embed`` for 518x518, ``mask_token``, ``blocks.N.ls1.gamma`` ...).
The hub model's forward returns ``x_norm_clstoken``; positions are interpolated to the 16x16 grid of a
224x224 input as DINOv2 does (bicubic, offset 0.1). Inputs: ``Resize(224)`` and ImageNet normalisation.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rdd.encoders._official import OfficialSpec, official_builder
from rdd.encoders._preprocess import IMAGENET_MEAN, IMAGENET_STD


def _make_model():
    """DINOv2 ViT-L/14 (img_size 518, LayerScale, block_chunks=0 key layout)."""
    from rdd.encoders._vit import VisionTransformer

    return VisionTransformer(
        img_size=518, patch_size=14, embed_dim=1024, depth=24, num_heads=16,
        layerscale=True, mask_token=True, pos_interp="dinov2",
    )


def _extract(obj: Any, path: Path) -> dict:
    """The official checkpoint object -> this model's state dict."""
    if not isinstance(obj, dict):
        raise ValueError(f"encoder 'dinov2': checkpoint {str(path)!r} is not a state dict")
    return obj


SPEC = OfficialSpec(
    name="dinov2",
    dim=1024,
    filename="dinov2_vitl14_pretrain.pth",
    source="https://dl.fbaipublicfiles.com/dinov2/dinov2_vitl14/dinov2_vitl14_pretrain.pth (facebookresearch/dinov2)",
    mean=IMAGENET_MEAN,
    std=IMAGENET_STD,
    make_model=_make_model,
    extract=_extract,
)


build = official_builder(SPEC, __name__)
