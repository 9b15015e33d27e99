"""Shared helpers for encoders: input validation, chunked torch inference, weight hashing."""

from __future__ import annotations

import contextlib
import hashlib
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from rdd.encoders.base import Encoder

if TYPE_CHECKING:
    import torch


def check_images(images: np.ndarray, who: str) -> np.ndarray:
    """``images`` as a uint8 (N, H, W, 3) array, or a ValueError naming the encoder and the shape."""
    images = np.asarray(images)
    if images.ndim == 3 and images.shape[-1] == 3:
        raise ValueError(f"{who}: expected a batch (N, H, W, 3), got one image {images.shape}; add a batch axis")
    if images.ndim != 4 or images.shape[-1] != 3:
        raise ValueError(f"{who}: images must have shape (N, H, W, 3), got {images.shape}")
    if images.dtype != np.uint8:
        raise ValueError(f"{who}: images must be uint8 RGB, got dtype {images.dtype}")
    return images


def check_batch_size(batch_size: int, who: str) -> int:
    """A positive int batch size or a ValueError naming the option."""
    if int(batch_size) != batch_size or int(batch_size) < 1:
        raise ValueError(f"{who}: option batch_size must be a positive integer, got {batch_size!r}")
    return int(batch_size)


def state_dict_hash(module: torch.nn.Module) -> str:
    """SHA-256 over names, shapes, dtypes and bytes of every parameter and buffer, in key order."""
    import torch

    h = hashlib.sha256()
    for key, tensor in sorted(module.state_dict().items()):
        t = tensor.detach().cpu().contiguous()
        h.update(key.encode())
        h.update(str(tuple(t.shape)).encode())
        h.update(str(t.dtype).encode())
        # Viewing as bytes covers every dtype (bfloat16 included) without a numpy round trip.
        h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes())
    return h.hexdigest()


class TorchEncoder(Encoder):
    """An encoder made of a numpy->tensor ``preprocess`` and a torch ``forward``, run in chunks.

    Subclasses (or builders) supply the model; this class handles validation, batching, threads,
    ``torch.inference_mode``, the weights hash and where the forward runs (``runtime``: auto, onnx
    or torch; ``device``: auto, cpu or cuda; see ``rdd.encoders._runtime``).
    """

    def __init__(
        self,
        *,
        name: str,
        dim: int,
        model: torch.nn.Module | None = None,
        preprocess: Callable[[np.ndarray], torch.Tensor],
        forward: Callable[[torch.Tensor], torch.Tensor] | None = None,
        preprocess_id: str,
        batch_size: int = 32,
        num_threads: int | None = None,
        checkpoint: str | None = None,
        runtime: str = "auto",
        device: str = "auto",
        load: Callable[[], torch.nn.Module] | None = None,
        weights_id: str | None = None,
    ):
        from rdd.encoders._runtime import check_runtime

        check_runtime(runtime, device, name)
        if (model is None) == (load is None):
            raise TypeError(f"{name}: give the model or a function that loads it (load=), not both or neither")
        self.name = name
        self.dim = int(dim)
        # A loader defers torch and the weights until a frame is really encoded: an encoder whose
        # embeddings all come from the cache never builds its network.
        self._model = model.eval() if model is not None else None
        self._load = load
        self._preprocess = preprocess
        self._forward_fn = forward
        self.preprocess_id = preprocess_id
        self.batch_size = check_batch_size(batch_size, name)
        if num_threads is not None and (int(num_threads) != num_threads or int(num_threads) < 1):
            raise ValueError(f"{name}: option num_threads must be a positive integer or null, got {num_threads!r}")
        self.num_threads = num_threads
        self.checkpoint = checkpoint
        self.runtime = runtime
        self.device = device
        self._runner = None  # chosen on the first batch (rdd.encoders._runtime.make_runner)
        self._weights_id = weights_id  # known beforehand when the loader's weights were hashed before

    @property
    def model(self) -> torch.nn.Module:
        """The network, loaded on first use when the encoder was made with a loader."""
        if self._model is None:
            self._model = self._load().eval()
        return self._model

    @property
    def _forward(self) -> Callable[[torch.Tensor], torch.Tensor]:
        return self._forward_fn if self._forward_fn is not None else self.model

    def __getstate__(self) -> dict:
        # An ONNX Runtime session does not pickle; a copy (e.g. in a worker process) makes its own.
        return {**self.__dict__, "_runner": None}

    @property
    def active_runtime(self) -> str | None:
        """"onnx" or "torch" once the first batch has been encoded (None before)."""
        return None if self._runner is None else self._runner.name

    @property
    def weights_id(self) -> str:
        """SHA-256 of the loaded state dict (computed once, on first use)."""
        if self._weights_id is None:
            self._weights_id = state_dict_hash(self.model)
        return self._weights_id

    def encode(self, images: np.ndarray) -> np.ndarray:
        """Embed uint8 images (N, H, W, 3) into float32 (N, dim), ``batch_size`` images at a time."""
        images = check_images(images, self.name)
        if images.shape[0] == 0:
            return np.zeros((0, self.dim), dtype=np.float32)
        from rdd.encoders._runtime import make_runner, torch_scope

        outs = []
        # A numpy preprocess on ONNX Runtime needs no torch; where torch is loaded anyway (a torch
        # preprocess or runner), its ops run with the encoder's threads and without autograd.
        with torch_scope(self.num_threads) if "torch" in sys.modules else contextlib.nullcontext():
            for start in range(0, images.shape[0], self.batch_size):
                x = self._preprocess(images[start : start + self.batch_size])
                if self._runner is None:
                    self._runner = make_runner(self, x)
                y = self._runner(x)
                if y.shape[1] != self.dim:
                    raise RuntimeError(f"{self.name}: model produced {y.shape[1]}-d features, expected {self.dim}")
                outs.append(y)
        return np.concatenate(outs, axis=0).astype(np.float32, copy=False)

