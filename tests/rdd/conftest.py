"""Small LeRobot datasets (v2.1 and v3.0) written with rdd.testing.lerobot_synth, as LeRobot lays them out;
a stand-in chat-completions server for the VLM tests."""

from __future__ import annotations

import importlib.util
import json
import re
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from rdd.testing.lerobot_synth import (
    KEY,
    TASK,
    episode_rows,
    info_json,
    write_data,
    write_synthetic_v30,
    write_video,
)


def make_lerobot(root: Path, version: str = "v2.1", lengths=(30, 36, 24)) -> Path:
    """A LeRobot dataset at ``root``: v2.1 (one file per episode) or v3.0 (episodes 0-1 share a file)."""
    if version != "v2.1":
        return write_synthetic_v30(root, [lengths[:2], lengths[2:]])
    info = info_json(version, len(lengths), (16, 24))
    info["data_path"] = "data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet"
    info["video_path"] = "videos/chunk-{episode_chunk:03d}/{video_key}/episode_{episode_index:06d}.mp4"
    (root / "meta").mkdir(parents=True)
    (root / "README.md").write_text("toy dataset\n")
    start = 0
    for ep, n in enumerate(lengths):
        rows, levels = episode_rows(ep, n, start)
        write_data(root / f"data/chunk-000/episode_{ep:06d}.parquet", rows, [ep])
        write_video(root / f"videos/chunk-000/{KEY}/episode_{ep:06d}.mp4", levels)
        start += n
    (root / "meta/episodes.jsonl").write_text("".join(
        json.dumps({"episode_index": ep, "tasks": [TASK], "length": n}) + "\n" for ep, n in enumerate(lengths)))
    (root / "meta/tasks.jsonl").write_text(json.dumps({"task_index": 0, "task": TASK}) + "\n")
    (root / "meta/episodes_stats.jsonl").write_text("".join(
        json.dumps({"episode_index": ep, "stats": {}}) + "\n" for ep in range(len(lengths))))
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


@pytest.fixture
def lerobot_copy_argv(lerobot_factory, tmp_path):
    """``argv(name)``: the CLI arguments that cut a four-episode v3.0 dataset (data files: episodes
    0-1 and 2-3) into thirds and write its LeRobot copy to ``tmp_path / name``."""
    src = lerobot_factory("v3.0", lengths=(30, 36, 24, 20))

    def argv(name: str) -> list[str]:
        return ["decompose", "--format", "lerobot", "--data", str(src), "--decomposer", "uniform",
                "--option", "n_segments=3", "--fallback-instruction", "{task} ({index}/{count})",
                "--write-lerobot", str(tmp_path / name)]

    return argv


BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


@pytest.fixture(scope="session")
def benchmark_module():
    """Import a script of ``benchmarks/`` by its name (they are scripts, not a package)."""
    def load(name: str):
        spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module

    return load


@pytest.fixture(scope="module")
def toy_native(tmp_path_factory) -> Path:
    """``<tmp>/ds``: three 12-frame native episodes ep0-ep2 (front and wrist views; the gripper
    closes for the middle third, so the expert rule finds three sub-tasks)."""
    from rdd.testing.native_synth import write_noise_episodes

    return write_noise_episodes(tmp_path_factory.mktemp("native") / "ds", 3, [1.0, 0.0, 1.0], 4)


@pytest.fixture(scope="session")
def native_six(tmp_path_factory) -> Path:
    """``<tmp>/ds``: six 16-frame native episodes ep0-ep5 (front and wrist views; the gripper is closed
    for the second quarter), shared by the resume and Ray executor tests, which only read it."""
    from rdd.testing.native_synth import write_noise_episodes

    return write_noise_episodes(tmp_path_factory.mktemp("six") / "ds", 6, [1.0, 0.0, 1.0, 1.0], 4)


# A tqdm bar's line: "calibration:  40%|####      | 2/5 [...]".
PROGRESS_BAR = re.compile(r"^[^|\n]*:\s+\d+%\|")


@pytest.fixture
def cli_fails(capsys):
    """``cli_fails(*argv, expect=(...), absent=(...))``: run ``python -m rdd`` in process and assert
    exit status 2 and one line on stderr, no traceback, naming every ``expect`` and no ``absent``."""
    from rdd.cli import main

    def fails(*argv, expect: tuple[str, ...], absent: tuple[str, ...] = ()) -> str:
        capsys.readouterr()
        assert main([str(a) for a in argv]) == 2, argv
        err = capsys.readouterr().err
        # A progress bar may have drawn before the error (a slow machine shows it): not an error line.
        lines = [ln for ln in err.strip().splitlines() if not PROGRESS_BAR.match(ln)]
        assert "Traceback" not in err and len(lines) == 1, err
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
