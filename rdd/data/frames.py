"""Lazily loaded frame sequences: an episode's images are read only when asked for."""

from __future__ import annotations

import hashlib
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from rdd.errors import InputError


def update_with_file(h: hashlib._Hash, path: str | Path) -> hashlib._Hash:
    """Feed the bytes of ``path`` into hash ``h`` in 1 MiB blocks (no whole-file read); return ``h``."""
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h


@runtime_checkable
class FrameSource(Protocol):
    """A sequence of uint8 RGB frames (H, W, 3) that loads on demand."""

    def __len__(self) -> int: ...

    def load(self, indices: Sequence[int] | None = None) -> np.ndarray:
        """Frames at ``indices`` (all when None) as a uint8 array (N, H, W, 3)."""
        ...

    def fingerprint(self) -> str:
        """A content hash that changes whenever the frames change (used for cache keys)."""
        ...


class ArrayFrames:
    """Frames already in memory."""

    def __init__(self, array: np.ndarray):
        array = np.asarray(array)
        if array.ndim != 4 or array.shape[-1] != 3:
            raise ValueError(f"frames must have shape (T, H, W, 3), got {array.shape}")
        if array.dtype != np.uint8:
            raise ValueError(f"frames must be uint8, got {array.dtype}")
        self._array = array
        self._fingerprint: str | None = None

    def __len__(self) -> int:
        return int(self._array.shape[0])

    def load(self, indices: Sequence[int] | None = None) -> np.ndarray:
        """Frames at ``indices`` (all when None)."""
        if indices is None:
            return self._array
        return self._array[np.asarray(indices, dtype=np.int64)]

    def fingerprint(self) -> str:
        """SHA-256 of shape and bytes."""
        if self._fingerprint is None:
            h = hashlib.sha256(str(self._array.shape).encode())
            h.update(np.ascontiguousarray(self._array).tobytes())
            self._fingerprint = h.hexdigest()
        return self._fingerprint


def read_image(path: Path, size_only: bool = False) -> np.ndarray | tuple[int, int]:
    """The RGB frame (H, W, 3) in image file ``path``, or its (width, height) from the header alone.

    Any failure is an InputError naming the file, a decompression bomb included: PIL only warns
    between its pixel limit and twice it, and a frame that large is never a camera image.
    """
    from PIL import Image

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            with Image.open(path) as im:
                return im.size if size_only else np.asarray(im.convert("RGB"), dtype=np.uint8)
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
        raise InputError(f"{path}: refused as a frame image ({exc})") from exc
    except (OSError, ValueError, SyntaxError, EOFError) as exc:
        raise InputError(f"cannot read frame image {path}: {exc}") from exc


class ImageFileFrames:
    """One image file per frame (e.g. RLBench's ``front_rgb/N.png``), decoded with PIL on demand.

    Every frame must have the size of the first one (read from its header), so frames loaded in
    different calls stack and embed alike.
    """

    def __init__(self, paths: Sequence[str | Path]):
        self.paths = [Path(p) for p in paths]
        self._fingerprint: str | None = None
        self._size: tuple[int, int] | None = None

    def __len__(self) -> int:
        return len(self.paths)

    def load(self, indices: Sequence[int] | None = None) -> np.ndarray:
        """Decode the frames at ``indices`` (all when None)."""
        idx = range(len(self.paths)) if indices is None else indices
        out = []
        for i in idx:
            path = self.paths[int(i)]
            frame = read_image(path)
            if self._size is None:
                self._size = read_image(self.paths[0], size_only=True)
            width, height = self._size
            if frame.shape[:2] != (height, width):
                raise InputError(f"{path}: frame is {frame.shape[1]}x{frame.shape[0]} pixels, expected "
                                 f"{width}x{height} like the first frame, {self.paths[0].name}")
            out.append(frame)
        if not out:
            return np.zeros((0, 0, 0, 3), dtype=np.uint8)
        return np.stack(out)

    def fingerprint(self) -> str:
        """SHA-256 over the files' bytes in order."""
        if self._fingerprint is None:
            h = hashlib.sha256()
            for p in self.paths:
                h.update(p.name.encode())
                h.update(p.read_bytes())
            self._fingerprint = h.hexdigest()
        return self._fingerprint
