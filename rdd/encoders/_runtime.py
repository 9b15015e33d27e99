"""Where an encoder's network runs: ONNX Runtime or torch, on the CPU or a CUDA device.

``runtime="auto"`` (the default) takes ONNX Runtime when it is installed and the export reproduces
torch (on a shared 2-core machine it encoded EfficientNet-Lite0 3.7-6x faster than the best plain
torch fp32 configuration in the same run, per-frame cosine 1 - 1e-7; ``benchmarks/bench_encode.py``
measures it anew), else torch with a one-line log saying why. ``runtime="torch"`` forces torch fp32, which is
also the fallback. ``device="auto"`` takes CUDA when torch sees a device: ONNX Runtime's CUDA provider
when that build is installed (``onnxruntime-gpu``), else torch on CUDA, both fp32 (TF32 off).
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import torch

log = logging.getLogger(__name__)

RUNTIMES = ("auto", "onnx", "torch")
DEVICES = ("auto", "cpu", "cuda")
CUDA_PROVIDER = "CUDAExecutionProvider"
CPU_PROVIDER = "CPUExecutionProvider"


def check_runtime(runtime: str, device: str, who: str) -> None:
    """A ValueError naming the option and its accepted values unless both are valid."""
    if runtime not in RUNTIMES:
        raise ValueError(f"{who}: option runtime must be one of {list(RUNTIMES)}, got {runtime!r}")
    if device not in DEVICES:
        raise ValueError(f"{who}: option device must be one of {list(DEVICES)}, got {device!r}")


@contextlib.contextmanager
def torch_threads(num_threads: int | None) -> Iterator[None]:
    """Run the block with ``num_threads`` intra-op torch threads (unchanged when None), then restore."""
    import torch

    if num_threads is None:
        yield
        return
    if int(num_threads) != num_threads or int(num_threads) < 1:
        raise ValueError(f"option num_threads must be a positive integer or null, got {num_threads!r}")
    before = torch.get_num_threads()
    torch.set_num_threads(int(num_threads))
    try:
        yield
    finally:
        torch.set_num_threads(before)


@contextlib.contextmanager
def torch_scope(num_threads: int | None) -> Iterator[None]:
    """``torch_threads(num_threads)`` inside ``torch.inference_mode()``."""
    import torch

    with torch_threads(num_threads), torch.inference_mode():
        yield


@dataclass(frozen=True)
class Plan:
    """The runtime and device chosen, ONNX Runtime's providers, and why torch when it was not asked for."""

    runtime: str  # "onnx" or "torch"
    device: str  # "cpu" or "cuda"
    providers: tuple[Any, ...] = ()
    why: str = ""


def choose(runtime: str, device: str, cuda_available: bool, ort_providers: Sequence[str] | None) -> Plan:
    """The plan for the options ``runtime``/``device`` given what this machine has
    (``ort_providers`` None: onnxruntime is not importable)."""
    if device == "cuda" and not cuda_available:
        raise ValueError("option device=cuda, but torch sees no CUDA device here (use device=auto or cpu)")
    dev = "cuda" if device == "cuda" or (device == "auto" and cuda_available) else "cpu"
    if runtime == "torch":
        return Plan("torch", dev)
    if ort_providers is None:
        if runtime == "onnx":
            from rdd.encoders._onnx import INSTALL

            raise ImportError(f"option runtime=onnx needs ONNX Runtime: {INSTALL}")
        return Plan("torch", dev, why="onnxruntime is not installed (pip install onnxruntime onnx)")
    if dev == "cpu":
        return Plan("onnx", dev, (CPU_PROVIDER,))
    if CUDA_PROVIDER in ort_providers:
        # fp32 throughout: TF32 convolutions changed embeddings more than RDD's scores tolerate.
        return Plan("onnx", dev, ((CUDA_PROVIDER, {"use_tf32": "0"}), CPU_PROVIDER))
    if runtime == "onnx":
        raise ImportError("option runtime=onnx on CUDA needs ONNX Runtime's CUDA build: pip install onnxruntime-gpu")
    return Plan("torch", dev, why="this onnxruntime has no CUDA provider")


def ort_providers() -> list[str] | None:
    """ONNX Runtime's available execution providers, or None when it is not installed."""
    try:
        import onnxruntime
    except ImportError:
        return None
    return list(onnxruntime.get_available_providers())


@contextlib.contextmanager
def no_tf32(device: torch.device) -> Iterator[None]:
    """Keep CUDA convolutions in full fp32 inside the block (cuDNN allows TF32 by default)."""
    import torch

    if device.type != "cuda":
        yield
        return
    before = torch.backends.cudnn.allow_tf32
    torch.backends.cudnn.allow_tf32 = False
    try:
        yield
    finally:
        torch.backends.cudnn.allow_tf32 = before


class TorchRunner:
    """Runs an encoder's forward in torch fp32 on ``device`` (channels-last on the CPU)."""

    name = "torch"

    def __init__(self, encoder, device: str):
        import torch

        self.device = torch.device(device)
        self.forward = encoder._forward
        self.num_threads = encoder.num_threads
        self.channels_last = self.device.type == "cpu"
        # The runner is made inside encode's inference mode; weights moved or re-laid out there
        # would become inference tensors, which autograd (tracing, finetuning the model) refuses.
        with torch.inference_mode(False):
            encoder.model.to(self.device)
            # Channels-last let oneDNN pick faster convolutions: EfficientNet-Lite0 at batch 32,
            # 2 threads, 38.7 images/s vs 25.0 contiguous (9.1 vs 5.6 on a loaded run), same features.
            if self.channels_last:
                encoder.model.to(memory_format=torch.channels_last)

    def __call__(self, x: torch.Tensor | np.ndarray) -> np.ndarray:
        """Features (N, D) of the preprocessed batch ``x``."""
        import torch

        if isinstance(x, np.ndarray):
            x = torch.from_numpy(np.ascontiguousarray(x))
        with torch_scope(self.num_threads):
            return self._run(x)

    def _run(self, x: torch.Tensor) -> np.ndarray:
        import torch

        x = x.to(self.device)
        if self.channels_last and x.dim() == 4:
            x = x.contiguous(memory_format=torch.channels_last)
        with no_tf32(self.device):
            y = self.forward(x)
        return y.reshape(y.shape[0], -1).float().cpu().numpy()


def cuda_available() -> bool:
    """Whether torch sees a CUDA device; on Linux without a GPU device node, known without importing torch."""
    if sys.platform == "linux" and "torch" not in sys.modules:
        nodes = ("/dev/nvidiactl", "/dev/nvidia0", "/dev/kfd", "/dev/dxg")
        if not any(os.path.exists(node) for node in nodes):
            return False
    import torch

    return torch.cuda.is_available()


def default_threads() -> int:
    """torch's intra-op thread count when torch is loaded, else what it would default to here
    (``OMP_NUM_THREADS``, else the CPUs this process may run on)."""
    if "torch" in sys.modules:
        return int(sys.modules["torch"].get_num_threads())
    env = os.environ.get("OMP_NUM_THREADS", "")
    if env.isdigit() and int(env) > 0:
        return int(env)
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def make_runner(encoder, example: torch.Tensor | np.ndarray):
    """The runner for ``encoder`` (options ``runtime``, ``device``, ``num_threads``), its ONNX session
    prepared on ``example`` (the first preprocessed batch); auto falls back to torch, logging why."""
    plan = choose(encoder.runtime, encoder.device, cuda_available(),
                  ort_providers() if encoder.runtime != "torch" else None)
    if plan.runtime == "onnx":
        from rdd.encoders._onnx import OnnxRunner

        runner = OnnxRunner(encoder, plan.providers, encoder.num_threads or default_threads())
        try:
            runner.prepare(example)
            log.info("encoder %s: ONNX Runtime on %s (%d threads)", encoder.name, plan.device, runner.threads)
            return runner
        except Exception as exc:
            if encoder.runtime == "onnx":
                raise
            plan = Plan("torch", plan.device, why=f"the ONNX export failed: {str(exc).splitlines()[0]}")
    if plan.why:
        log.warning("encoder %s: runtime torch on %s (%s)", encoder.name, plan.device, plan.why)
    return TorchRunner(encoder, plan.device)
