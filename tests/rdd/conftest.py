"""Small LeRobot datasets (v2.1 and v3.0) written here with pyarrow and PyAV, as LeRobot lays them out;
a stand-in chat-completions server for the VLM tests."""

from __future__ import annotations

import json
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np
import pytest

FPS = 10
KEY = "observation.images.top"
STATE_NAMES = ["shoulder", "elbow", "wrist", "gripper"]


def _write_video(path: Path, levels, size=(16, 24)) -> None:
    import av

    path.parent.mkdir(parents=True, exist_ok=True)
    with av.open(str(path), "w") as out:
        stream = out.add_stream("mpeg4", rate=FPS)
        stream.width, stream.height = size[1], size[0]
        stream.pix_fmt = "yuv420p"
        stream.options = {"qscale": "2"}
        for lv in levels:
            img = np.zeros((size[0], size[1], 3), dtype=np.uint8)
            img[..., 0] = lv
            img[..., 1] = 255 - lv
            for packet in stream.encode(av.VideoFrame.from_ndarray(img, format="rgb24")):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)


def _episode_rows(ep: int, n: int, start: int) -> tuple[list[dict], list[int]]:
    """Frames of one episode: the arm moves, rests for a while, the gripper closes halfway."""
    rows, levels = [], []
    for i in range(n):
        pos = min(i, n // 3) + max(0, i - n // 3 - 4)  # rests for 4 frames after a third
        rows.append({
            "observation.state": [0.2 * pos, -0.1 * pos, 0.05 * pos, 1.0 if i < n // 2 else 0.0],
            "action": [0.0, 0.0, 0.0, 1.0],
            "timestamp": np.float32(i / FPS).item(), "frame_index": i, "episode_index": ep,
            "index": start + i, "task_index": 0,
        })
        levels.append(int(20 + 200 * i / max(n - 1, 1)))
    return rows, levels


def _write_data(path: Path, rows: list[dict], episodes_in_file: list[int]) -> None:
    """One parquet file, one row group per episode (as LeRobot writes them)."""
    import pyarrow as pa
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
            part = table.filter(pa.compute.equal(table["episode_index"], ep))
            writer.write_table(part, row_group_size=part.num_rows)


def make_lerobot(root: Path, version: str = "v2.1", lengths=(30, 36, 24)) -> Path:
    """A LeRobot dataset at ``root``: v2.1 (one file per episode) or v3.0 (episodes 0-1 share a file)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    features = {
        "observation.state": {"dtype": "float32", "shape": [4], "names": STATE_NAMES},
        "action": {"dtype": "float32", "shape": [4], "names": STATE_NAMES},
        KEY: {"dtype": "video", "shape": [16, 24, 3], "names": ["height", "width", "channels"]},
        "timestamp": {"dtype": "float32", "shape": [1], "names": None},
        "frame_index": {"dtype": "int64", "shape": [1], "names": None},
        "episode_index": {"dtype": "int64", "shape": [1], "names": None},
        "index": {"dtype": "int64", "shape": [1], "names": None},
        "task_index": {"dtype": "int64", "shape": [1], "names": None},
    }
    info = {"codebase_version": version, "robot_type": "toy", "fps": FPS, "chunks_size": 1000,
            "total_episodes": len(lengths), "features": features}
    (root / "meta").mkdir(parents=True)
    (root / "README.md").write_text("toy dataset\n")
    task = "stack the cups"
    per_ep = []
    start = 0
    for ep, n in enumerate(lengths):
        per_ep.append((ep, n, start, *_episode_rows(ep, n, start)))
        start += n
    if version == "v2.1":
        info["data_path"] = "data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet"
        info["video_path"] = "videos/chunk-{episode_chunk:03d}/{video_key}/episode_{episode_index:06d}.mp4"
        for ep, _n, _s, rows, levels in per_ep:
            _write_data(root / f"data/chunk-000/episode_{ep:06d}.parquet", rows, [ep])
            _write_video(root / f"videos/chunk-000/{KEY}/episode_{ep:06d}.mp4", levels)
        (root / "meta/episodes.jsonl").write_text("".join(
            json.dumps({"episode_index": ep, "tasks": [task], "length": n}) + "\n" for ep, n, *_ in per_ep))
        (root / "meta/tasks.jsonl").write_text(json.dumps({"task_index": 0, "task": task}) + "\n")
        (root / "meta/episodes_stats.jsonl").write_text("".join(
            json.dumps({"episode_index": ep, "stats": {}}) + "\n" for ep, *_ in per_ep))
    else:
        info["data_path"] = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
        info["video_path"] = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
        files = {0: [e for e in range(len(lengths)) if e < 2], 1: [e for e in range(len(lengths)) if e >= 2]}
        ep_meta = []
        for fi, eps in files.items():
            if not eps:
                continue
            rows, levels, t0 = [], [], 0.0
            for ep in eps:
                _, n, s, r, lv = per_ep[ep]
                ep_meta.append({
                    "episode_index": ep, "tasks": [task], "length": n,
                    "data/chunk_index": 0, "data/file_index": fi,
                    "dataset_from_index": s, "dataset_to_index": s + n,
                    f"videos/{KEY}/chunk_index": 0, f"videos/{KEY}/file_index": fi,
                    f"videos/{KEY}/from_timestamp": t0, f"videos/{KEY}/to_timestamp": t0 + n / FPS,
                })
                rows += r
                levels += lv
                t0 += n / FPS
            _write_data(root / f"data/chunk-000/file-{fi:03d}.parquet", rows, eps)
            _write_video(root / f"videos/{KEY}/chunk-000/file-{fi:03d}.mp4", levels)
        (root / "meta/episodes/chunk-000").mkdir(parents=True)
        pq.write_table(pa.Table.from_pylist(ep_meta), root / "meta/episodes/chunk-000/file-000.parquet")
        pq.write_table(pa.Table.from_pylist([{"task_index": 0, "task": task}]), root / "meta/tasks.parquet")
    (root / "meta/info.json").write_text(json.dumps(info, indent=4))
    return root


@pytest.fixture
def lerobot_factory(tmp_path):
    """``make(version, lengths)`` -> a fresh LeRobot dataset folder under tmp_path."""
    pytest.importorskip("pyarrow")
    pytest.importorskip("av")
    count = [0]

    def make(version: str = "v2.1", lengths=(30, 36, 24)) -> Path:
        count[0] += 1
        return make_lerobot(tmp_path / f"{version}_{count[0]}", version, lengths)

    return make


@pytest.fixture(scope="module")
def toy_native(tmp_path_factory) -> Path:
    """``<tmp>/ds``: three 12-frame native episodes ep0-ep2 (front and wrist views; the gripper
    closes for the middle third, so the expert rule finds three sub-tasks)."""
    from rdd.data.episode import Episode
    from rdd.data.native import save_episode

    root = tmp_path_factory.mktemp("native") / "ds"
    for k in range(3):
        frames = np.random.default_rng(k).integers(0, 255, size=(12, 8, 8, 3), dtype=np.uint8)
        save_episode(Episode(name=f"ep{k}", views={"front": frames, "wrist": frames[:, ::-1].copy()},
                             gripper_open=np.repeat([1.0, 0.0, 1.0], 4), joint_velocities=np.ones((12, 7)),
                             goal="toy", task="toy"), root / f"ep{k}")
    return root


@pytest.fixture
def cli_fails(capsys):
    """``cli_fails(*argv, expect=(...), absent=(...))``: run ``python -m rdd`` in process and assert
    exit status 2 and one line on stderr, no traceback, naming every ``expect`` and no ``absent``."""
    from rdd.cli import main

    def fails(*argv, expect: tuple[str, ...], absent: tuple[str, ...] = ()) -> str:
        capsys.readouterr()
        assert main([str(a) for a in argv]) == 2, argv
        err = capsys.readouterr().err
        assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
        for word in expect:
            assert word in err, (word, err)
        for word in absent:
            assert word not in err, (word, err)
        return err

    return fails


class FakeEndpoint:
    """A chat-completions server whose answers, failures and delays the test scripts."""

    def __init__(self):
        self.requests: list[dict] = []
        # (status, content, delay); content as bytes is sent as the whole body (a malformed payload)
        self.script: list[tuple[int, str | bytes, float]] = []
        server = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self):  # noqa: N802 - http.server API
                body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
                server.requests.append({"path": self.path, "auth": self.headers.get("Authorization"),
                                        "body": body})
                status, content, delay = server.script.pop(0) if server.script else (200, "[]", 0)
                time.sleep(delay)
                payload = content if isinstance(content, bytes) else json.dumps(
                    {"choices": [{"message": {"role": "assistant", "content": content}}]}).encode()
                try:
                    self.send_response(status)
                    self.send_header("Content-Type", "application/json")
                    self.end_headers()
                    self.wfile.write(payload)
                except (BrokenPipeError, ConnectionResetError):
                    pass

            def log_message(self, *args):
                pass

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)
        self.thread.start()
        self.base_url = f"http://127.0.0.1:{self.httpd.server_address[1]}/v1"

    def close(self):
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.fixture
def endpoint():
    """A stand-in chat-completions server on 127.0.0.1 (the VLM decomposer's and labeler's tests)."""
    ep = FakeEndpoint()
    yield ep
    ep.close()
