"""``python -m rdd serve`` started as a server on 127.0.0.1 and called over real HTTP (urllib): the
official request and answer shapes, rdd/uvd segments equal to ``python -m rdd decompose`` on the
same frames and database, every kind of bad request, and the 8 x 25 load test."""

from __future__ import annotations

import importlib.util
import json
import os
import pickle
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from rdd.cli import main

pytest.importorskip("fastapi", reason="serve needs its extra: pip install 'rdd[serve]'")
pytest.importorskip("uvicorn", reason="serve needs its extra: pip install 'rdd[serve]'")

BENCH = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_serve.py"
_spec = importlib.util.spec_from_file_location("bench_serve", BENCH)
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """Synthetic episodes, their pixels database and the held-out episode's PNG frames."""
    return bench.synthetic_setup(tmp_path_factory.mktemp("serve"))


@pytest.fixture(scope="module")
def server(setup):
    """One worker, serving only files under the setup's folder."""
    root = setup["db"].parent
    with bench.Server(setup["db"], *bench.ENCODER_ARGS, "--root", str(root), log=root / "server.log") as srv:
        yield srv


def cli_segments(setup, tmp_path, decomposer: str, *extra: str) -> list[list[int]]:
    """``python -m rdd decompose`` on the held-out episode: its segments as lists of frame indices."""
    out = tmp_path / f"{decomposer}.json"
    assert main(["decompose", "--format", setup["format"], "--data", str(setup["data"]), "--include",
                 setup["episode"], "--decomposer", decomposer, *extra, *bench.ENCODER_ARGS, "--no-cache",
                 "--out", str(out)]) == 0
    record = json.loads(out.read_text())["episodes"][0]
    return [list(range(s, e)) for s, e in record["segments"]], record


def test_rdd_segments_equal_decompose(setup, server, tmp_path):
    status, answer = bench.call(server.url + "/decompose", {"paths": setup["frames"], "method": "rdd",
                                                            "preprocessor": "pixels"})
    assert status == 200, answer
    assert set(answer) == {"segments", "nn_list", "confidence"}
    expected, record = cli_segments(setup, tmp_path, "rdd", "--db", str(setup["db"]))
    assert answer["segments"] == expected
    # The server's confidence is decompose's, rounded as its JSON rounds it (issue 63).
    assert [round(c, 4) for c in answer["confidence"]] == record["confidence"]
    # Official shape: per segment, one record per view, naming the entry matched (its instruction too).
    assert [[v["view"] for v in seg] for seg in answer["nn_list"]] == [["front", "wrist"]] * len(expected)
    assert [seg[0]["instruction"] for seg in answer["nn_list"]] == record["instructions"]
    # The database is the four other episodes' 12 expert segments; each match is one of them.
    assert all(0 <= seg[0]["id"] < 12 and seg[0]["episode"] in {"ep0", "ep1", "ep2", "ep3"}
               for seg in answer["nn_list"])


def test_uvd_segments_equal_decompose(setup, server, tmp_path):
    status, answer = bench.call(server.url + "/decompose", {"paths": setup["frames"], "method": "uvd"})
    assert status == 200, answer
    assert set(answer) == {"segments"}
    expected, _ = cli_segments(setup, tmp_path, "uvd", "--encoder", "pixels")
    assert answer["segments"] == expected
    assert [i for s in answer["segments"] for i in s] == list(range(len(setup["frames"])))


def test_config_and_health(setup, server):
    status, config = bench.call(server.url + "/config")
    assert status == 200
    cfg = config["config"]
    assert cfg["decomposer"] == ["rdd", "uvd"] and cfg["preprocessor"] == cfg["encoder"] == "pixels"
    assert cfg["views"] == ["front", "wrist"] and cfg["db_size"] == 12
    assert cfg["root"] == str(setup["db"].parent.resolve())
    status, health = bench.call(server.url + "/health")
    assert status == 200 and health["status"] == "ok" and health["methods"] == ["rdd", "uvd"]


def _bad_files(setup) -> dict[str, Path]:
    """A text file, a pickle that would write a file if anything unpickled it, and a larger frame."""
    from PIL import Image

    folder = setup["db"].parent / "bad"
    if not folder.exists():
        folder.mkdir()
        (folder / "notes.png").write_text("not an image\n")

        class Trap:
            def __reduce__(self):
                return (Path.write_text, (folder / "UNPICKLED", "x"))

        (folder / "trap.pkl").write_bytes(pickle.dumps(Trap()))
        Image.fromarray(np.zeros((32, 32, 3), dtype=np.uint8)).save(folder / "big.png")
    return {p.stem: p for p in folder.iterdir()}


def _with(frames, i: int, j: int, path) -> list[list[str]]:
    out = [list(f) for f in frames]
    out[i][j] = str(path)
    return out


@pytest.mark.parametrize("kind", [
    "no paths", "no method", "paths not a list", "path not a string", "body not JSON", "unknown method",
    "unknown preprocessor", "one frame", "wrong view count", "missing file", "a folder", "not an image",
    "a pickle", "different sizes", "outside root", "relative escape", "empty path", "name too long",
])
def test_bad_requests_name_the_field(setup, server, kind):
    frames, bad = setup["frames"], _bad_files(setup)
    body: object = {"paths": frames, "method": "rdd"}
    expect = {
        "no paths": (422, "paths", {"method": "rdd"}),
        "no method": (422, "method", {"paths": frames}),
        "paths not a list": (422, "paths", {"paths": "front/0.png", "method": "rdd"}),
        "path not a string": (422, "paths[2][1]", {**body, "paths": [f if k != 2 else [f[0], 7]
                                                                     for k, f in enumerate(frames)]}),
        "body not JSON": (422, "body", None),
        "unknown method": (400, "method", {**body, "method": "cut"}),
        "unknown preprocessor": (422, "preprocessor", {**body, "preprocessor": "r4m"}),
        "one frame": (422, "paths", {**body, "paths": frames[:1]}),
        "wrong view count": (422, "paths[4]", {**body, "paths": [f if k != 4 else f[:1] for k, f in enumerate(frames)]}),
        "missing file": (404, "paths[1][0]", {**body, "paths": _with(frames, 1, 0, Path(frames[1][0]).with_name("999.png"))}),
        "a folder": (422, "paths[0][1]", {**body, "paths": _with(frames, 0, 1, Path(frames[0][1]).parent)}),
        "not an image": (422, "paths[5][0]", {**body, "paths": _with(frames, 5, 0, bad["notes"])}),
        "a pickle": (422, "paths[3][1]", {**body, "paths": _with(frames, 3, 1, bad["trap"])}),
        "different sizes": (422, "paths[3][0]", {**body, "paths": _with(frames, 3, 0, bad["big"])}),
        "outside root": (403, "paths[0][0]", {**body, "paths": _with(frames, 0, 0, BENCH)}),
        "relative escape": (403, "paths[1][1]", {**body, "paths": _with(frames, 1, 1, "../../../../etc/hostname")}),
        "empty path": (422, "paths[6][0]", {**body, "paths": _with(frames, 6, 0, "")}),
        "name too long": (422, "paths[2][0]", {**body, "paths": _with(frames, 2, 0, "x" * 5000)}),
    }[kind]
    status, field, payload = expect
    if payload is None:  # a body that is not JSON at all
        req = urllib.request.Request(server.url + "/decompose", data=b"{paths:", headers={"Content-Type": "application/json"})
        try:
            urllib.request.urlopen(req, timeout=30)
            got, answer = 200, None
        except urllib.error.HTTPError as exc:
            got, answer = exc.code, json.loads(exc.read())
    else:
        got, answer = bench.call(server.url + "/decompose", payload)
    assert got == status, answer
    assert set(answer) == {"error"} and answer["error"].startswith(field + ":"), answer
    assert not (setup["db"].parent / "bad" / "UNPICKLED").exists()
    # The server still answers good requests after a bad one.
    assert bench.call(server.url + "/health")[0] == 200


def test_a_window_shorter_than_min_len_is_a_bad_request(setup):
    """No partition of 3 frames into segments of at least 5 exists: a 422 naming paths, not a 500."""
    frames = setup["frames"][:3]
    with bench.Server(setup["db"], *bench.ENCODER_ARGS, "--option", "min_len=5") as srv:
        got, answer = bench.call(srv.url + "/decompose", {"paths": frames, "method": "rdd"})
        assert got == 422 and answer["error"].startswith("paths:") and "min_len=5" in answer["error"], answer
        assert bench.call(srv.url + "/decompose", {"paths": setup["frames"][:6], "method": "rdd"})[0] == 200


def test_load_8_clients_x_25_requests(setup, capsys):
    """The load test on 20-frame windows with two workers: no error (the figures are printed, not asserted)."""
    windows = bench.windows_of(setup["frames"], 20)
    with bench.Server(setup["db"], *bench.ENCODER_ARGS, workers=2) as srv:
        config = bench.call(srv.url + "/config")[1]["config"]
        # the two workers share the cores: each encoder gets half of them (at least one thread)
        assert config["workers"] == 2 and config["encoder_threads"] == max(1, len(os.sched_getaffinity(0)) // 2)
        res = bench.load_test(srv.url, windows, clients=8, per_client=25, deadline_s=240)
    with capsys.disabled():
        print(f"\nserve load test: {json.dumps(res)}")
    assert res["requests"] == 200 and res["errors"] == 0, res["error_samples"]


def test_command_errors_are_one_line(tmp_path, capsys):
    assert main(["serve", "--db", str(tmp_path / "nope"), "--port", "9"]) == 2
    assert main(["serve", "--db", str(tmp_path), "--workers", "0"]) == 2
    assert main(["serve", "--db", str(tmp_path), "--max-body-bytes", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and "nope" in err[0] and "--workers 0" in err[1] and "--max-body-bytes 0" in err[2]


def test_body_over_the_limit_is_413(setup):
    """--max-body-bytes 2048: a larger body answers 413 and one-line JSON, declared or chunked; a smaller one is served."""
    import http.client

    frames = setup["frames"]
    small = json.dumps({"paths": frames[:3], "method": "uvd"}).encode()
    big = json.dumps({"paths": frames, "method": "uvd", "pad": "x" * 4096}).encode()
    assert len(small) <= 2048 < len(big)
    with bench.Server(setup["db"], *bench.ENCODER_ARGS, "--max-body-bytes", "2048") as srv:
        assert bench.call(srv.url + "/decompose", json.loads(small))[0] == 200
        answers = []
        for chunked in (False, True):
            conn = http.client.HTTPConnection("127.0.0.1", srv.port, timeout=30)
            body = iter([big[:1000], big[1000:]]) if chunked else big
            conn.request("POST", "/decompose", body=body, headers={"Content-Type": "application/json"},
                         encode_chunked=chunked)
            res = conn.getresponse()
            answers.append((res.status, res.read()))
            conn.close()
        assert bench.call(srv.url + "/health")[0] == 200  # still serving
    for status, raw in answers:
        assert status == 413, raw
        answer = json.loads(raw)
        assert set(answer) == {"error"} and answer["error"].startswith("body:") and "2048" in answer["error"]
        assert len(raw.decode().splitlines()) == 1


def test_missing_extra_names_the_install_line(monkeypatch):
    import sys

    from rdd.serve import app

    monkeypatch.setitem(sys.modules, "fastapi", None)
    with pytest.raises(ImportError, match=r"pip install 'rdd\[serve\]'"):
        app.create_app(None)


def test_real_rlbench_segments_equal_decompose(real_data, tmp_path):
    """Real RLBench episodes: a pixels database of all but the last; that one served and decomposed."""
    setup = bench.rlbench_setup(tmp_path, real_data("rlbench/open_drawer/all_variations/episodes"))
    with bench.Server(setup["db"], *bench.ENCODER_ARGS, log=tmp_path / "server.log") as srv:
        status, answer = bench.call(srv.url + "/decompose", {"paths": setup["frames"], "method": "rdd"})
        assert status == 200, answer
        res = bench.load_test(srv.url, bench.windows_of(setup["frames"], 20), clients=8, per_client=25,
                              deadline_s=240)
    expected, _ = cli_segments(setup, tmp_path, "rdd", "--db", str(setup["db"]))
    assert answer["segments"] == expected
    assert res["errors"] == 0, res["error_samples"]
