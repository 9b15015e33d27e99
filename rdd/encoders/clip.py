"""``clip``: OpenAI CLIP RN50 image tower (ModifiedResNet + attention pool), 1024-d features.

Official checkpoint: ``RN50.pt`` (openai/CLIP, ``clip.load("RN50")``), a TorchScript archive whose
state dict holds ``visual.*`` (used) and the text tower (ignored). A plain ``torch.save`` of the
same state dict loads too. Inputs: ``Resize(224)`` and CLIP's normalisation, as RDD/UVD call it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rdd.encoders._official import OfficialSpec, official_builder
from rdd.encoders._preprocess import CLIP_MEAN, CLIP_STD

# Everything in CLIP's state dict that is not the image tower.
_TEXT_KEYS = (
    "transformer.", "token_embedding.", "positional_embedding", "ln_final.", "text_projection",
    "logit_scale", "input_resolution", "context_length", "vocab_size",
)


def _make_model():
    """CLIP RN50 visual tower."""
    from rdd.encoders._clip_resnet import ModifiedResNet

    return ModifiedResNet()


def _extract(obj: Any, path: Path) -> dict:
    """The official checkpoint object -> this model's state dict."""
    from rdd.encoders._checkpoint import take_prefix

    return take_prefix(obj, "visual.", "clip", path, ignore=_TEXT_KEYS)


SPEC = OfficialSpec(
    name="clip",
    dim=1024,
    filename="RN50.pt",
    source="https://openaipublic.azureedge.net/clip/models/afeb0e10f9e5a86da6080e35cf09123aca3b358a0c3e3b6c78a7b63bc04b6762/RN50.pt (openai/CLIP, clip/clip.py)",
    mean=CLIP_MEAN,
    std=CLIP_STD,
    make_model=_make_model,
    extract=_extract,
)


build = official_builder(SPEC, __name__)
