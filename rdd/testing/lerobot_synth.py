"""Synthetic LeRobot datasets written with pyarrow and PyAV as LeRobot lays them out (tests, benchmarks).

Each episode: a 4-joint arm moves, rests for 4 frames after a third of the episode, and its gripper
(state column 3) closes halfway; one camera (``observation.images.top``) sees a flat colour whose red
level rises from 20 to 220 over the episode (green is 255 minus red), so a decoded frame tells which
frame it is. :func:`write_synthetic_v30` writes any number of episodes file by file (memory flat in
the episode count); the tests' fixtures build their small layouts from the same rows and files.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

FPS = 10
KEY = "observation.images.top"
STATE_NAMES = ["shoulder", "elbow", "wrist", "gripper"]
TASK = "stack the cups"


def write_video(path: Path, levels: Sequence[int], size: tuple[int, int] = (16, 24), fps: int = FPS) -> None:
    """An MPEG-4 video of flat frames (``size`` = height, width), frame i's red level ``levels[i]``."""
    import av

    path.parent.mkdir(parents=True, exist_ok=True)
    with av.open(str(path), "w") as out:
        stream = out.add_stream("mpeg4", rate=fps)
        stream.width, stream.height = size[1], size[0]
        stream.pix_fmt = "yuv420p"
        stream.options = {"qscale": "2"}
        img = np.zeros((size[0], size[1], 3), dtype=np.uint8)
        for lv in levels:
            img[..., 0] = lv
            img[..., 1] = 255 - lv
            for packet in stream.encode(av.VideoFrame.from_ndarray(img, format="rgb24")):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)


def episode_rows(ep: int, n: int, start: int, fps: int = FPS) -> tuple[list[dict], list[int]]:
    """Rows and red levels of one ``n``-frame episode whose first frame is dataset row ``start``."""
    rows, levels = [], []
    for i in range(n):
        pos = min(i, n // 3) + max(0, i - n // 3 - 4)  # rests for 4 frames after a third
        rows.append({
            "observation.state": [0.2 * pos, -0.1 * pos, 0.05 * pos, 1.0 if i < n // 2 else 0.0],
            "action": [0.0, 0.0, 0.0, 1.0],
            "timestamp": np.float32(i / fps).item(), "frame_index": i, "episode_index": ep,
            "index": start + i, "task_index": 0,
        })
        levels.append(int(20 + 200 * i / max(n - 1, 1)))
    return rows, levels


def write_data(path: Path, rows: list[dict], episodes_in_file: list[int]) -> None:
    """One parquet file, one row group per episode (as LeRobot writes them)."""
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    schema = pa.schema([
        ("observation.state", pa.list_(pa.float32(), 4)), ("action", pa.list_(pa.float32(), 4)),
        ("timestamp", pa.float32()), ("frame_index", pa.int64()), ("episode_index", pa.int64()),
        ("index", pa.int64()), ("task_index", pa.int64()),
    ])
    table = pa.Table.from_pylist(rows, schema=schema)
    path.parent.mkdir(parents=True, exist_ok=True)
    with pq.ParquetWriter(path, schema) as writer:
        for ep in episodes_in_file:
            part = table.filter(pc.equal(table["episode_index"], ep))
            writer.write_table(part, row_group_size=part.num_rows)


def info_json(version: str, episodes: int, size: tuple[int, int], fps: int = FPS) -> dict:
    """``meta/info.json`` of a dataset of ``episodes`` episodes (paths added by the caller)."""
    features = {
        "observation.state": {"dtype": "float32", "shape": [4], "names": STATE_NAMES},
        "action": {"dtype": "float32", "shape": [4], "names": STATE_NAMES},
        KEY: {"dtype": "video", "shape": [size[0], size[1], 3], "names": ["height", "width", "channels"]},
        "timestamp": {"dtype": "float32", "shape": [1], "names": None},
        "frame_index": {"dtype": "int64", "shape": [1], "names": None},
        "episode_index": {"dtype": "int64", "shape": [1], "names": None},
        "index": {"dtype": "int64", "shape": [1], "names": None},
        "task_index": {"dtype": "int64", "shape": [1], "names": None},
    }
    return {"codebase_version": version, "robot_type": "toy", "fps": fps, "chunks_size": 1000,
            "total_episodes": episodes, "features": features}


def write_synthetic_v30(root: str | Path, files: Sequence[Sequence[int]], *, size: tuple[int, int] = (16, 24),
                        fps: int = FPS) -> Path:
    """A LeRobot v3.0 dataset at ``root`` (a new folder): ``files[f]`` lists the lengths of the
    consecutive episodes stored in data and video file ``f``."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    root = Path(root)
    info = info_json("v3.0", sum(len(f) for f in files), size, fps)
    info["data_path"] = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
    info["video_path"] = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
    (root / "meta/episodes/chunk-000").mkdir(parents=True)
    (root / "README.md").write_text("toy dataset\n")
    ep_meta, ep, start = [], 0, 0
    for fi, lengths in enumerate(files):
        if not lengths:
            continue
        rows, levels, t0, eps = [], [], 0.0, []
        for n in lengths:
            r, lv = episode_rows(ep, int(n), start, fps)
            ep_meta.append({
                "episode_index": ep, "tasks": [TASK], "length": int(n),
                "data/chunk_index": 0, "data/file_index": fi,
                "dataset_from_index": start, "dataset_to_index": start + int(n),
                f"videos/{KEY}/chunk_index": 0, f"videos/{KEY}/file_index": fi,
                f"videos/{KEY}/from_timestamp": t0, f"videos/{KEY}/to_timestamp": t0 + int(n) / fps,
            })
            rows += r
            levels += lv
            eps.append(ep)
            t0 += int(n) / fps
            start += int(n)
            ep += 1
        write_data(root / f"data/chunk-000/file-{fi:03d}.parquet", rows, eps)
        write_video(root / f"videos/{KEY}/chunk-000/file-{fi:03d}.mp4", levels, size, fps)
    pq.write_table(pa.Table.from_pylist(ep_meta), root / "meta/episodes/chunk-000/file-000.parquet")
    pq.write_table(pa.Table.from_pylist([{"task_index": 0, "task": TASK}]), root / "meta/tasks.parquet")
    (root / "meta/info.json").write_text(json.dumps(info, indent=4))
    return root
