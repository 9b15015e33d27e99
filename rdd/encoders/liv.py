"""``liv``: LIV (Ma et al. 2023) image encoder: CLIP RN50 architecture fine-tuned by LIV, 1024-d.

Official checkpoint: ``model.pt`` (penn-pal-lab/LIV, ``load_liv("resnet50")``; Hugging Face
``jasonyma/LIV``), a dict ``{"liv": {"module.model.visual.*", "module.model.<text tower>"}}``; the
image features are ``model.encode_image`` = the visual tower. Inputs: ``Resize(224)`` and CLIP's
normalisation (LIV's ``transforms_tensor`` and RDD/UVD's LIV preprocessor). Snapshots written by
LIV's own trainer (``model.visual.*``, no ``module.`` prefix) load too.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rdd.encoders._official import OfficialSpec, official_builder
from rdd.encoders._preprocess import CLIP_MEAN, CLIP_STD


def _make_model():
    """CLIP RN50 visual tower (LIV ships OpenAI's clip/model.py unchanged)."""
    from rdd.encoders._clip_resnet import ModifiedResNet

    return ModifiedResNet()


def _extract(obj: Any, path: Path) -> dict:
    """The official checkpoint object -> this model's state dict."""
    from rdd.encoders._checkpoint import take_entry, take_prefix

    sd = take_entry(obj, "liv", "liv", path)
    # The released file was saved from the DataParallel wrapper ("module." prefix, which load_liv
    # expects); LIV's trainer saves the unwrapped module, so its own snapshots lack the prefix.
    prefix = "module.model." if any(k.startswith("module.") for k in sd) else "model."
    return take_prefix(sd, prefix + "visual.", "liv", path, ignore=(prefix,))


SPEC = OfficialSpec(
    name="liv",
    dim=1024,
    filename="model.pt",
    source="https://huggingface.co/jasonyma/LIV/blob/main/model.pt (penn-pal-lab/LIV, liv/__init__.py)",
    mean=CLIP_MEAN,
    std=CLIP_STD,
    make_model=_make_model,
    extract=_extract,
)


build = official_builder(SPEC, __name__)
