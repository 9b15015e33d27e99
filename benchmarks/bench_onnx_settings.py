"""Where ONNX Runtime's time goes for an encoder on this CPU: each setting against the baseline, same run.

    .venv/bin/python benchmarks/bench_onnx_settings.py [--encoder effnet_lite0] [--frames 64] [--rounds 3]

The baseline is the library before issue 65's encoding step: torch preprocessing (float conversion,
antialiased resize, crop), batch 32, every core, ORT_ENABLE_ALL, memory arena on, no spinning. Each
other row changes one thing: numpy/PIL preprocessing (the library's now), uint8 resize before the
float conversion (rejected: see the cosine), batch size, a static batch axis, threads, graph optimisation level, arena,
spinning, OpenVINO's CPU runtime in fp32 and bf16 where ``openvino`` is installed (not a dependency:
neither is adopted, docs/cli.md); the last rows time whole views of a real episode read from disk, decoded ahead of the
encoder (the library's ``encode_view``) or first and then encoded. Rounds interleave the rows so a
busy machine slows them alike; each keeps its best round. Printed: images/s, ratio to the baseline,
min per-frame cosine to the baseline's embeddings. Frames: RLBench ``open_drawer`` episode0 from
``$RDD_TEST_DATA`` (docs/testing.md), else synthetic. Speed is printed, never asserted.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from rdd.encoders import load_encoder
from rdd.encoders._effnet_lite import VARIANTS, make_torch_preprocess
from rdd.encoders._onnx import INPUT, export_path, known_key, per_frame_cosine
from rdd.encoders._preprocess_np import shorter_side_geometry

RLBENCH = "rlbench/open_drawer/all_variations/episodes"


def uint8_first(resolution: int):
    """Resize the uint8 frames with PIL, then convert to float (fast, but rounds every pixel)."""
    from PIL import Image

    def pre(images: np.ndarray) -> np.ndarray:
        n, h, w, _ = images.shape
        nh, nw, top, left = shorter_side_geometry(h, w, resolution)
        small = np.stack([np.asarray(Image.fromarray(im).resize((nw, nh), Image.BILINEAR)) for im in images])
        x = small[:, top : top + resolution, left : left + resolution].transpose(0, 3, 1, 2).astype(np.float32)
        return x * np.float32(2 / 255) - np.float32(1)

    return pre


def static_batch(path: Path, batch: int) -> bytes:
    """The graph at ``path`` with its batch axis fixed to ``batch`` (shapes inferred again)."""
    import onnx

    model = onnx.load(str(path))
    for t in [*model.graph.input, *model.graph.output]:
        t.type.tensor_type.shape.dim[0].dim_value = batch
    del model.graph.value_info[:]  # inferred again below, from the fixed batch
    return onnx.shape_inference.infer_shapes(model).SerializeToString()


def session(path: Path | bytes, threads: int, level: str = "ALL", arena: bool = True, spinning: bool = False):
    """Features of a preprocessed batch from an ONNX Runtime CPU session on ``path`` with the given settings."""
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads, so.inter_op_num_threads = threads, 1
    so.graph_optimization_level = getattr(ort.GraphOptimizationLevel, f"ORT_ENABLE_{level}")
    so.enable_cpu_mem_arena = arena
    so.log_severity_level = 3
    so.add_session_config_entry("session.intra_op.allow_spinning", "1" if spinning else "0")
    sess = ort.InferenceSession(path if isinstance(path, bytes) else str(path), so, providers=["CPUExecutionProvider"])
    return lambda x: sess.run(None, {INPUT: x})[0]


def openvino_rows(path: Path, threads: int, pre, frames: np.ndarray) -> dict:
    """OpenVINO's CPU runtime on the same graph, fp32 and (where the CPU has it) bf16, batch 32;
    empty, with a line saying so, when ``openvino`` is not installed."""
    try:
        import openvino
    except ImportError:
        print("openvino rows skipped: pip install openvino to time them")
        return {}
    core = openvino.Core()
    model = core.read_model(str(path))
    precisions = ["f32"] + (["bf16"] if "BF16" in core.get_property("CPU", "OPTIMIZATION_CAPABILITIES") else [])
    rows = {}
    for precision in precisions:
        request = core.compile_model(model, "CPU", {"PERFORMANCE_HINT": "LATENCY", "INFERENCE_NUM_THREADS": threads,
                                                    "INFERENCE_PRECISION_HINT": precision}).create_infer_request()
        rows[f"OpenVINO {openvino.__version__.split('-')[0]} {precision}, numpy, batch 32"] = runner(
            pre, lambda x, request=request: request.infer({0: x})[0].copy(), 32, frames)
    return rows


def runner(pre, infer, batch: int, frames: np.ndarray):
    """A function encoding ``frames`` with preprocessing ``pre`` and ``infer`` (a batch's features),
    ``batch`` at a time."""
    def run() -> np.ndarray:
        return np.concatenate([infer(np.ascontiguousarray(pre(frames[s : s + batch])))
                               for s in range(0, len(frames), batch)])
    return run


def main() -> None:
    """Time every setting ``--rounds`` times, interleaved, and print the table."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--encoder", default="effnet_lite0")
    ap.add_argument("--frames", type=int, default=64)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    from rdd.data.load import load_episodes
    from rdd.encoders._runtime import default_threads
    from rdd.encoders._stream import encode_view

    data = Path(os.environ.get("RDD_TEST_DATA", "")) / RLBENCH
    episode = load_episodes("rlbench", data, names=["episode0"])[0] if data.is_dir() else None
    if episode is not None:
        frames = episode.frames("front", None)[: args.frames]
        source = f"{RLBENCH} episode0 front"
    else:
        # benchmarks/ is this script's folder, first on the path
        from bench_encode import synthetic_frames

        frames, source = synthetic_frames(args.frames), "synthetic"
    cores = default_threads()
    lib = load_encoder(args.encoder, num_threads=cores)
    lib.encode(frames[:2])  # the export (or the cached file) and its recorded key
    res = VARIANTS[int(args.encoder[-1])].resolution
    path = export_path(lib._runner.root, known_key(lib, (3, res, res), lib._runner.root))
    torch_pre, np_pre = make_torch_preprocess(res), lib._preprocess

    def torch_np(x):
        return torch_pre(x).numpy()

    # A session of its own per row: ONNX Runtime keeps memory per input shape, and one session fed
    # batches of several sizes in turn was slower at the large ones than a session fed one size.
    rows = {"baseline: torch preprocess, batch 32": runner(torch_np, session(path, cores), 32, frames),
            "numpy/PIL-float preprocess, batch 32": runner(np_pre, session(path, cores), 32, frames),
            "uint8 resize before float, batch 32": runner(uint8_first(res), session(path, cores), 32, frames)}
    rows.update({f"numpy preprocess, batch {b}": runner(np_pre, session(path, cores), b, frames)
                 for b in (1, 4, 8, 16, 64)})
    # A graph whose batch axis is fixed lets ONNX Runtime plan every shape when the session starts.
    if len(frames) % 8 == 0:
        rows["numpy, batch 8, static batch axis"] = runner(np_pre, session(static_batch(path, 8), cores), 8, frames)
    rows[f"numpy, batch 32, 1 thread (of {cores})"] = runner(np_pre, session(path, 1), 32, frames)
    for level in ("BASIC", "EXTENDED"):
        rows[f"numpy, batch 32, ORT_ENABLE_{level}"] = runner(np_pre, session(path, cores, level), 32, frames)
    rows["numpy, batch 32, no memory arena"] = runner(np_pre, session(path, cores, arena=False), 32, frames)
    rows["numpy, batch 32, spinning threads"] = runner(np_pre, session(path, cores, spinning=True), 32, frames)
    rows.update(openvino_rows(path, cores, np_pre, frames))
    if episode is not None:
        enc = load_encoder(args.encoder, num_threads=cores)
        enc.encode(frames[:2])
        from rdd.data.episode import Episode
        from rdd.data.frames import ImageFileFrames

        files = [data / "episode0" / "front_rgb" / f"{i}.png" for i in range(len(frames))]

        def fresh() -> Episode:  # the view's files, read when encoded (as the server reads a request's)
            return Episode(name="episode0", views={"front": ImageFileFrames(files)})

        rows[f"{len(files)} PNG files, decoded ahead (batch 8)"] = lambda: encode_view(enc, fresh(), "front")
        rows[f"{len(files)} PNG files, decoded first (batch 8)"] = lambda: enc.encode(fresh().frames("front", None))
    for fn in rows.values():
        fn()  # warm-up: allocations, kernel choices, file cache
    best: dict[str, float] = {}
    outs: dict[str, np.ndarray] = {}
    for _ in range(args.rounds):
        for label, fn in rows.items():
            t0 = time.perf_counter()
            outs[label] = fn()
            best[label] = max(best.get(label, 0.0), len(outs[label]) / (time.perf_counter() - t0))
    print(f"{len(frames)} frames {frames.shape[1]}x{frames.shape[2]} from {source}; {cores} threads; "
          f"{args.rounds} rounds; load average {os.getloadavg()}")
    first = next(iter(rows))
    for label, ips in best.items():
        ref = outs[first] if len(outs[label]) == len(outs[first]) else None
        cos = f"{per_frame_cosine(outs[label], ref).min():.9f}" if ref is not None else "(whole view)"
        print(f"{label:46s} {ips:7.1f} images/s {ips / best[first]:5.2f}x   min cosine {cos}")


if __name__ == "__main__":
    main()
