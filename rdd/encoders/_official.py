"""Builder shared by the paper's seven encoders: architecture + official checkpoint + preprocessing.

Preprocessing follows how the official RDD code calls these encoders (``rdd/embed.py`` through UVD's
preprocessors): a non-square frame is first resized (bicubic) to a square of its longer side, as
RDD's ``uvd_embed`` does; then ``Resize(224)`` (bilinear, antialiased) and the model's normalisation.
torchvision's ImageNet ResNet-50 uses its weights' own transform instead (``Resize(232)``,
``CenterCrop(224)``). Square frames (RLBench's 128x128) skip the squaring step.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rdd.encoders._common import TorchEncoder
from rdd.registry import register

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class OfficialSpec:
    """What defines one of the paper's encoders."""

    name: str
    dim: int
    filename: str  # the official checkpoint's file name
    source: str  # where the official project publishes it
    make_model: Callable[[], Any]  # -> torch.nn.Module with random weights
    extract: Callable[[Any, Path], dict]  # loaded checkpoint object -> the model's state dict
    mean: tuple[float, float, float]
    std: tuple[float, float, float]
    resize: int = 224
    crop: int = 224
    interpolation: str = "bilinear"


def make_preprocess(spec: OfficialSpec) -> tuple[Callable[[np.ndarray], Any], str]:
    """The preprocessing function of ``spec`` and a string describing it (part of cache keys)."""
    from rdd.encoders._preprocess import (
        center_crop,
        normalize,
        resize_exact,
        resize_shorter,
        to_float_tensor,
    )

    def preprocess(images: np.ndarray):
        x = to_float_tensor(images)
        h, w = x.shape[-2:]
        if h != w:
            side = max(h, w)
            x = resize_exact(x, (side, side), "bicubic")
        x = resize_shorter(x, spec.resize, spec.interpolation)
        return normalize(center_crop(x, spec.crop), spec.mean, spec.std)

    pid = (f"square-bicubic/resize{spec.resize}-{spec.interpolation}-aa/centercrop{spec.crop}/"
           f"mean{list(spec.mean)}/std{list(spec.std)}")
    return preprocess, pid


def build_official(
    spec: OfficialSpec,
    *,
    checkpoint: str | None = None,
    random_weights: bool = False,
    seed: int = 0,
    batch_size: int = 16,
    num_threads: int | None = None,
    runtime: str = "auto",
    device: str = "auto",
) -> TorchEncoder:
    """Build ``spec``'s encoder with its official weights (``checkpoint`` or ``$RDD_WEIGHTS_DIR``);
    ``runtime``/``device``: where it runs (``rdd.encoders._runtime``).

    ``random_weights=True`` skips the checkpoint and uses a seeded random initialisation: only for
    checking the architecture and measuring its speed; its embeddings carry no pretrained meaning.
    """
    import torch

    from rdd.encoders._checkpoint import load_state, load_strict, resolve_checkpoint

    if random_weights:
        if checkpoint is not None:
            raise ValueError(f"encoder {spec.name!r}: give either checkpoint or random_weights=true, not both")
        log.warning("encoder %s built with RANDOM weights (architecture/speed checks only)", spec.name)
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(int(seed))
            model = spec.make_model()
        path = None
    else:
        path = resolve_checkpoint(spec.name, checkpoint, spec.filename, spec.source)
        state = load_state(path, spec.name, spec.filename, spec.source)  # before building: a bad file fails fast
        model = spec.make_model()
        load_strict(model, spec.extract(state, path), spec.name, path)
    model = model.float().eval()
    preprocess, pid = make_preprocess(spec)
    return TorchEncoder(
        name=spec.name,
        dim=spec.dim,
        model=model,
        preprocess=preprocess,
        preprocess_id=pid,
        batch_size=batch_size,
        num_threads=num_threads,
        checkpoint=None if path is None else str(path),
        runtime=runtime,
        device=device,
    )


def official_builder(spec: OfficialSpec, module: str):
    """The ``build(**options)`` of module ``module``, an official encoder: ``build_official`` bound to
    ``spec``, registered as encoder ``spec.name``."""
    build = functools.partial(build_official, spec)
    build.__doc__ = f"The ``{spec.name}`` encoder from its official checkpoint (see the module docstring)."
    build.__module__, build.__qualname__ = module, "build"  # its _target_: <module>.build
    return register("encoder", spec.name)(build)
