"""The visual encoder interface."""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np


class Encoder(ABC):
    """Maps uint8 RGB images (N, H, W, 3) to float32 embeddings (N, dim)."""

    name: str = "encoder"
    dim: int = 0
    # Describes the input preprocessing (resize, crop, normalisation); part of every cache key.
    preprocess_id: str = ""

    @property
    @abstractmethod
    def weights_id(self) -> str:
        """A hash of the weights actually loaded (part of every cache key)."""

    @abstractmethod
    def encode(self, images: np.ndarray) -> np.ndarray:
        """Embed ``images`` (N, H, W, 3) uint8 into a float32 array (N, dim)."""
