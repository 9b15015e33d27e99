"""ONNX Runtime inference for torch encoders: the graph exported once per weights and code, cached.

The export is ``torch.onnx.export(dynamo=False)`` of the encoder's own forward, fp32, with a dynamic
batch axis. Its file is cached under ``$RDD_CACHE_DIR/onnx`` (``~/.cache/rdd/onnx``), named by a
hash of everything that determines the graph: the weights' hash, the source files of the model's
modules and forward, the input shape and the torch, onnx and opset versions. A fresh export is
checked against fp32 torch on the first real batch before it is used or written, so a cached file
is always one that reproduced torch's features (cosine >= ``MIN_COSINE`` per frame). Its sha256 is
written beside it (``.onnx.sha256``) and checked on the bytes that the session is made from, so a
damaged file is exported again, with a warning, and never used.
"""

from __future__ import annotations

import hashlib
import inspect
import io
import json
import logging
import sys
import warnings
from collections.abc import Sequence
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from rdd.atomic import read_verified, write_bytes_atomic, write_json_atomic, write_sha256

if TYPE_CHECKING:
    import torch

log = logging.getLogger(__name__)

INSTALL = "pip install onnxruntime onnx"
EXPORT_FORMAT = 2  # bump when the export or its key changes meaning (2: a .sha256 file beside each export)
OPSET = 17
INPUT, OUTPUT = "images", "features"
MIN_COSINE = 0.999  # per frame, to fp32 torch; measured: 1 - 1e-7 for the Lite models
CHECK_FRAMES = 2  # frames of the first batch compared with torch after an export


class ExportError(RuntimeError):
    """The encoder could not be exported, or the export does not reproduce torch's features."""


def import_ort():
    """The ``onnxruntime`` module, or an ImportError with the pip line to run."""
    try:
        import onnxruntime
    except ImportError as exc:
        raise ImportError(f"runtime onnx needs ONNX Runtime: {INSTALL}") from exc
    return onnxruntime


def default_onnx_dir() -> Path:
    """``$RDD_CACHE_DIR/onnx`` if set, else ``~/.cache/rdd/onnx`` (beside the embedding cache)."""
    from rdd.encoders.cache import default_cache_dir

    return default_cache_dir().parent / "onnx"


def _source_files(model: torch.nn.Module, forward: Any) -> list[str]:
    files = set()
    for obj in [type(m) for m in model.modules()] + [forward]:
        try:
            files.add(inspect.getsourcefile(obj))
        except TypeError:  # built-in: no Python source, covered by the torch version
            continue
    return sorted(f for f in files if f)


def code_hash(model: torch.nn.Module, forward: Any) -> str:
    """SHA-256 of the source files defining ``model``'s modules and ``forward`` (names and bytes)."""
    return files_hash(_source_files(model, forward))


def files_hash(paths: Sequence[str]) -> str:
    """SHA-256 of the names and bytes of ``paths``, in the given order."""
    h = hashlib.sha256()
    for path in paths:
        h.update(Path(path).name.encode() + b"\0" + Path(path).read_bytes() + b"\0")
    return h.hexdigest()


def _torch_version() -> str:
    # The installed distribution's version is torch.__version__, read without importing torch.
    if "torch" in sys.modules:
        return str(sys.modules["torch"].__version__)
    return metadata.version("torch")


def _key_without_code(encoder, shape: Sequence[int]) -> dict:
    try:
        onnx_version = metadata.version("onnx")
    except metadata.PackageNotFoundError:
        onnx_version = None
    return {
        "format": EXPORT_FORMAT,
        "encoder": encoder.name,
        "weights_id": encoder.weights_id,
        "input": [int(s) for s in shape],
        "torch": _torch_version(),
        "onnx": onnx_version,
        "opset": OPSET,
    }


def export_key(encoder, shape: Sequence[int]) -> dict:
    """What determines the exported graph of ``encoder`` for inputs of ``shape`` (C, H, W)."""
    return {**_key_without_code(encoder, shape), "code": code_hash(encoder.model, encoder._forward)}


def _record_path(root: Path, partial: dict) -> Path:
    digest = hashlib.sha256(json.dumps(partial, sort_keys=True).encode()).hexdigest()
    return root / f"{partial['encoder']}-{digest[:32]}.key.json"


def known_key(encoder, shape: Sequence[int], root: Path) -> dict | None:
    """``export_key`` without building the model: from the record written beside an earlier export,
    valid while the source files it names still hash to its code hash (None otherwise)."""
    partial = _key_without_code(encoder, shape)
    try:
        record = json.loads(_record_path(root, partial).read_text())
        sources, code = list(record["sources"]), record["code"]
        if files_hash(sources) == code:
            return {**partial, "code": code}
    except (OSError, ValueError, KeyError, TypeError):
        pass
    return None


def remember_key(encoder, key: dict, root: Path) -> None:
    """Record which source files make ``key``'s code hash, for :func:`known_key` (skipped if unwritable)."""
    partial = {k: v for k, v in key.items() if k != "code"}
    try:
        write_json_atomic(_record_path(root, partial),
                          {"sources": _source_files(encoder.model, encoder._forward), "code": key["code"]})
    except OSError as exc:
        log.debug("could not record the ONNX key of %s: %s", encoder.name, exc)


def export_path(root: Path, key: dict) -> Path:
    """The cache file of ``key``."""
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()
    return root / f"{key['encoder']}-{digest[:32]}.onnx"


def _wrapped(encoder):
    """The encoder's forward as a module owning the model (the exporter traces modules)."""
    from torch import nn

    class Forward(nn.Module):
        def __init__(self):
            super().__init__()
            self.model = encoder.model

        def forward(self, x):
            y = encoder._forward(x)
            return y.reshape(y.shape[0], -1)

    return Forward().eval()


def export_bytes(encoder, example: torch.Tensor) -> bytes:
    """The ONNX graph of ``encoder``'s forward (fp32, batch axis dynamic), traced on ``example``."""
    import torch

    if _missing("onnx"):
        raise ExportError(f"exporting to ONNX needs the onnx package: {INSTALL}")
    buf = io.BytesIO()
    with warnings.catch_warnings(), torch.inference_mode(False), torch.no_grad():
        # The TorchScript exporter's deprecation and tracer notes say nothing about this graph.
        warnings.simplefilter("ignore")
        # A clone made outside inference mode: the tracer cannot record inference tensors.
        x = example[:1].detach().float().cpu().clone().contiguous()
        torch.onnx.export(
            _wrapped(encoder), (x,), buf, dynamo=False,
            input_names=[INPUT], output_names=[OUTPUT], opset_version=OPSET,
            dynamic_axes={INPUT: {0: "batch"}, OUTPUT: {0: "batch"}},
        )
    return buf.getvalue()


def _missing(module: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(module) is None


def open_session(model: str | Path | bytes, threads: int, providers: Sequence[Any]):
    """An fp32 ONNX Runtime session with ``threads`` intra-op threads on ``providers``."""
    ort = import_ort()
    so = ort.SessionOptions()
    so.intra_op_num_threads = int(threads)
    so.inter_op_num_threads = 1
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    so.log_severity_level = 3  # errors only: its optimiser notes are not the user's business
    # Idle threads sleep instead of spinning: on a shared or oversubscribed CPU spinning workers took
    # cycles from the frame decoder and other processes (2 threads, loaded machine: 49-68 img/s
    # spinning, 80-85 not).
    so.add_session_config_entry("session.intra_op.allow_spinning", "0")
    source = model if isinstance(model, bytes) else str(model)
    return ort.InferenceSession(source, so, providers=list(providers))


def per_frame_cosine(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cosine similarity of corresponding rows of ``a`` and ``b``."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    den = np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-30)
    return (a * b).sum(axis=1) / den


class OnnxRunner:
    """Runs an encoder's forward in ONNX Runtime: one session per input shape, from cached exports."""

    name = "onnx"

    def __init__(self, encoder, providers: Sequence[Any], threads: int, root: str | Path | None = None):
        self.encoder = encoder
        self.providers = list(providers)
        self.threads = int(threads)
        self.root = Path(root) if root is not None else default_onnx_dir()
        self.exports = 0  # graphs exported by this runner (0 when every one came from the cache)
        self._sessions: dict[tuple[int, ...], Any] = {}

    def prepare(self, x: torch.Tensor | np.ndarray) -> None:
        """Load (or export, check and cache) the session for inputs shaped like ``x``."""
        self._session(x)

    def _session(self, x: torch.Tensor | np.ndarray):
        shape = tuple(int(s) for s in x.shape[1:])
        if shape in self._sessions:
            return self._sessions[shape]
        # A key recorded beside an earlier export spares building the model (its source files are
        # hashed from the record's list); without one the model is built to list them.
        known = known_key(self.encoder, shape, self.root)
        key = known or export_key(self.encoder, shape)
        path = export_path(self.root, key)
        session = None
        if path.is_file():
            try:
                session = open_session(read_verified(path), self.threads, self.providers)
            except Exception as exc:  # noqa: BLE001 - a damaged file is exported again
                log.warning("ONNX file %s is unreadable (%s); exporting again", path, str(exc).splitlines()[0])
        if session is None:
            session = self._export(x, path)
        if known is None:
            remember_key(self.encoder, key, self.root)
        self._sessions[shape] = session
        return session

    def _export(self, x: torch.Tensor | np.ndarray, path: Path):
        import torch

        if isinstance(x, np.ndarray):
            x = torch.from_numpy(np.ascontiguousarray(x))
        try:
            data = export_bytes(self.encoder, x)
            session = open_session(data, self.threads, self.providers)
        except ExportError:
            raise
        except Exception as exc:  # noqa: BLE001 - any exporter or runtime failure means: no ONNX path
            raise ExportError(f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}") from exc
        probe = x[:CHECK_FRAMES].contiguous().float().cpu()
        with torch.inference_mode():
            ref = self.encoder._forward(probe.to(_model_device(self.encoder.model)))
        ref = ref.reshape(ref.shape[0], -1).float().cpu().numpy()
        got = session.run([OUTPUT], {INPUT: probe.numpy()})[0]
        cos = per_frame_cosine(got, ref) if got.shape == ref.shape else np.array([-1.0])
        if not np.all(np.isfinite(got)) or cos.min() < MIN_COSINE:
            raise ExportError(f"the exported graph does not reproduce torch (per-frame cosine {cos.min():.6f} "
                              f"< {MIN_COSINE})")
        self.exports += 1
        try:
            write_bytes_atomic(path, data)
            write_sha256(path)
        except OSError as exc:  # still usable in this process; the next one exports again
            log.warning("could not cache the ONNX export of %s at %s: %s", self.encoder.name, path, exc)
        return session

    def __call__(self, x: torch.Tensor | np.ndarray) -> np.ndarray:
        """Features (N, D) of the preprocessed batch ``x`` (N, C, H, W)."""
        if isinstance(x, np.ndarray):
            data = np.ascontiguousarray(x, dtype=np.float32)
        else:
            data = x.contiguous().float().cpu().numpy()
        out = self._session(x).run([OUTPUT], {INPUT: data})[0]
        return out.reshape(out.shape[0], -1).astype(np.float32, copy=False)


def _model_device(model: torch.nn.Module):
    for p in model.parameters():
        return p.device
    return "cpu"
