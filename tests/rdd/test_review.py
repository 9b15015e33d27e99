"""``python -m rdd review`` without a browser (issue 63): the list, an episode, edits with who-changed-what,
atomic saves that never replace an input, one-line errors, and nothing read outside --data and the database."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rdd.cli import main

pytest.importorskip("fastapi")
from fastapi.testclient import TestClient  # noqa: E402

from rdd.review.app import create_app  # noqa: E402
from rdd.review.session import ReviewSession  # noqa: E402


@pytest.fixture(scope="module")
def decomposed(toy_native, tmp_path_factory) -> dict[str, Path]:
    """The toy episodes, a database of them and rdd's decomposition of them against it."""
    tmp = tmp_path_factory.mktemp("review")
    base = ["--format", "native", "--data", str(toy_native), "--no-cache"]
    assert main(["build-db", *base, "--encoder", "pixels", "--out", str(tmp / "db")]) == 0
    assert main(["decompose", *base, "--decomposer", "rdd", "--db", str(tmp / "db"), "--out", str(tmp / "rdd.json")]) == 0
    return {"data": toy_native, "db": tmp / "db", "pred": tmp / "rdd.json", "tmp": tmp}


@pytest.fixture
def client(decomposed, tmp_path):
    session = ReviewSession("native", decomposed["data"], decomposed["pred"], tmp_path / "out.json", db=decomposed["db"])
    return TestClient(create_app(session)), session


def test_list_is_sorted_by_lowest_confidence_and_pages(client, decomposed):
    c, _ = client
    records = json.loads(decomposed["pred"].read_text())["episodes"]
    lowest = sorted((min(r["confidence"]), r["episode"]) for r in records)
    page = c.get("/api/episodes", params={"size": 2}).json()
    assert page["total"] == page["episodes"] == 3
    assert [row["episode"] for row in page["items"]] == [n for _, n in lowest[:2]]
    assert [row["episode"] for row in c.get("/api/episodes", params={"size": 2, "page": 1}).json()["items"]] == \
        [lowest[2][1]]
    assert [row["episode"] for row in c.get("/api/episodes", params={"q": "ep1"}).json()["items"]] == ["ep1"]
    assert c.get("/api/episodes", params={"only": "nonsense"}).status_code == 422
    assert "rdd review" in c.get("/").text and c.get("/static/review.js").status_code == 200


def test_episode_frames_and_matched_entry_frames(client):
    c, session = client
    ep = c.get("/api/episode/ep0").json()
    assert ep["views"] == ["front", "wrist"] and ep["record"]["episode"] == "ep0"
    assert "gripper open" in ep["signals"] and len(ep["signals"]["gripper open"]) == 12
    jpeg = c.get("/api/frame/ep0/front/3")
    assert jpeg.status_code == 200 and jpeg.content[:2] == b"\xff\xd8"
    entry = ep["record"]["neighbours"][0]["entry"]
    assert c.get(f"/api/neighbour/{entry}/end/wrist").content[:2] == b"\xff\xd8"
    assert c.get("/api/frame/ep0/front/12").status_code == 404
    assert c.get("/api/frame/nope/front/0").status_code == 404


def test_edits_keep_who_changed_what_and_save_atomically(client, decomposed, tmp_path):
    c, session = client
    rec = c.get("/api/episode/ep2").json()["record"]
    segs = rec["segments"]
    moved = [list(s) for s in segs]
    if len(moved) == 1:
        moved = [[0, 6], [6, 12]]
        labels = ["first half", "second half"]
    else:
        moved[0][1] += 1 if moved[0][1] + 1 < moved[1][1] else -1
        moved[1][0] = moved[0][1]
        labels = ["renamed"] + list(rec["instructions"][1:])
    answer = c.put("/api/episode/ep2", json={"segments": moved, "instructions": labels, "reviewed": True})
    assert answer.status_code == 200, answer.text
    edited = answer.json()["record"]
    assert edited["sources"][:2] == ["person", "person"] and edited["reviewed"] is True
    assert edited["confidence"][:2] == [None, None]
    bad = c.put("/api/episode/ep2", json={"segments": [[0, 7], [5, 12]], "instructions": ["a", "b"]})
    assert bad.status_code == 422 and "segments" in bad.json()["error"]
    before = decomposed["pred"].read_bytes()
    assert c.post("/api/save").status_code == 200
    assert c.post("/api/save").status_code == 200  # its own file: saved again
    saved = json.loads((tmp_path / "out.json").read_text())
    assert decomposed["pred"].read_bytes() == before
    got = {r["episode"]: r for r in saved["episodes"]}
    assert got["ep2"]["segments"] == moved and got["ep2"]["instructions"] == labels
    assert got["ep0"]["sources"] == ["rdd"] * len(got["ep0"]["segments"])
    # The saved file is a --pred for evaluate (and rdd's own as ground truth).
    assert main(["evaluate", "--pred", f"person={tmp_path / 'out.json'}", "--gt", str(decomposed["pred"])]) == 0


def test_reads_nothing_outside_data_and_the_database(client, decomposed):
    c, _ = client
    assert c.get("/files/ep0/episode.json").status_code == 200
    assert c.get("/files/..%2F..%2F..%2Fetc%2Fpasswd").status_code == 403
    assert c.get("/files/%2Fetc%2Fpasswd").status_code == 403
    outside = decomposed["tmp"] / "secret.txt"
    outside.write_text("no")
    (decomposed["data"] / "link").symlink_to(outside)
    try:
        assert c.get("/files/link").status_code == 403
    finally:
        (decomposed["data"] / "link").unlink()
    assert c.get("/files/nothing_here").status_code == 404


def test_bad_input_is_one_line_naming_the_file_and_field(decomposed, tmp_path, cli_fails, capsys):
    base = ["review", "--format", "native", "--data", decomposed["data"], "--no-browser"]
    with pytest.raises(SystemExit):
        main([str(a) for a in base])
    assert capsys.readouterr().err.strip().splitlines()[-1].endswith("required: --pred")
    cli_fails(*base, "--pred", decomposed["pred"], "--out", decomposed["pred"], expect=("--out", "--pred"))
    doc = json.loads(decomposed["pred"].read_text())
    doc["episodes"][0]["segments"] = [[0, 7], [5, 12]]
    overlap = tmp_path / "overlap.json"
    overlap.write_text(json.dumps(doc))
    cli_fails(*base, "--pred", overlap, expect=(str(overlap), "episodes[0]", "'segments'"))
    doc = json.loads(decomposed["pred"].read_text())
    doc["episodes"][0]["episode"] = "episode_000007"
    other = tmp_path / "other.json"
    other.write_text(json.dumps(doc))
    cli_fails(*base, "--pred", other, expect=(str(other), "episode_000007", "--data"))
    taken = tmp_path / "taken.json"
    taken.write_text("{}")
    cli_fails(*base, "--pred", decomposed["pred"], "--out", taken, expect=("--out", "--force"))


def test_reviewed_file_round_trips_into_lerobot_language_rows(lerobot_factory, tmp_path):
    """review -> decompose --decomposer given --write-lerobot -> the copy's language_persistent rows are the
    reviewed segments and labels, read back by the reader build-db --segments subtasks uses."""
    import pyarrow.parquet as pq

    from rdd.data.load import load_episodes
    from rdd.database.model import SubtaskDatabase

    src = lerobot_factory("v3.0", lengths=(30, 36, 24))
    base = ["--format", "lerobot", "--data", str(src)]
    assert main(["decompose", *base, "--decomposer", "uniform", "--option", "n_segments=3",
                 "--out", str(tmp_path / "u.json")]) == 0
    session = ReviewSession("lerobot", src, tmp_path / "u.json", tmp_path / "reviewed.json")
    want = {}
    for name in session.order:
        rec = session.record(name)
        segs = [list(s) for s in rec["segments"]]
        segs[0][1] -= 2
        segs[1][0] -= 2  # the first cut 2 frames earlier
        labels = [f"{name}: step {k}" for k in range(len(segs))]
        session.update(name, segs, labels, reviewed=True)
        want[name] = ([tuple(s) for s in segs], labels)
    session.save()
    assert main(["decompose", *base, "--decomposer", "given", "--option", f"file={tmp_path / 'reviewed.json'}",
                 "--write-lerobot", str(tmp_path / "copy")]) == 0
    back = {e.name: (e.segments, e.instructions) for e in load_episodes("lerobot", tmp_path / "copy")}
    assert back == want
    rows = pq.read_table(sorted((tmp_path / "copy/data").rglob("*.parquet"))[0]).column("language_persistent")
    assert [r["content"] for r in rows.to_pylist()[0]] == want["episode_000000"][1]
    # ... and a database's entries: build-db --segments takes the reviewed file as it is
    assert main(["build-db", *base, "--segments", str(tmp_path / "reviewed.json"), "--encoder", "pixels",
                 "--no-cache", "--no-calibrate", "--out", str(tmp_path / "db")]) == 0
    db = SubtaskDatabase.load(tmp_path / "db")
    for name, (segs, labels) in want.items():
        assert db.episode_segments(name) == segs
        assert [db.labels[i] for i in sorted((i for i, n in enumerate(db.episodes) if n == name),
                                             key=lambda i: db.starts[i])] == labels


def test_given_decomposer_refuses_a_file_of_other_episodes(toy_native, decomposed, tmp_path, cli_fails):
    doc = json.loads(decomposed["pred"].read_text())
    doc["episodes"][0]["num_frames"] = 13
    doc["episodes"][0]["segments"][-1][1] = 13
    other = tmp_path / "other.json"
    other.write_text(json.dumps(doc))
    cli_fails("decompose", "--format", "native", "--data", toy_native, "--decomposer", "given", "--option",
              f"file={other}", "--out", tmp_path / "x.json", expect=(str(other), "num_frames", "ep0"))


def test_build_db_segments_file_errors_name_the_option(toy_native, decomposed, tmp_path, cli_fails):
    base = ["build-db", "--format", "native", "--data", toy_native, "--encoder", "pixels", "--no-cache"]
    cli_fails(*base, "--segments", tmp_path / "none.json", "--out", tmp_path / "db", expect=("--segments", "none.json"))
    doc = json.loads(decomposed["pred"].read_text())
    doc["episodes"] = doc["episodes"][1:]
    part = tmp_path / "part.json"
    part.write_text(json.dumps(doc))
    cli_fails(*base, "--segments", part, "--out", tmp_path / "db", expect=("--segments", "part.json", "'ep0'"))


def test_review_command_serves_the_page_on_localhost(decomposed, tmp_path):
    """``python -m rdd review --no-browser`` as a user runs it: the page and its list answer on 127.0.0.1."""
    import os
    import subprocess
    import sys
    import time
    import urllib.request

    from rdd.review.browser import free_port

    port = free_port()
    root = Path(__file__).resolve().parents[2]
    env = {**os.environ, "PYTHONPATH": f"{root}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    proc = subprocess.Popen([sys.executable, "-m", "rdd", "review", "--format", "native", "--data",
                             str(decomposed["data"]), "--pred", str(decomposed["pred"]), "--out",
                             str(tmp_path / "out.json"), "--no-browser", "--port", str(port)],
                            env=env, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/episodes", timeout=5) as answer:
                    page = json.loads(answer.read())
                break
            except OSError:
                assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read() if proc.poll() else ""
                time.sleep(0.1)
        assert page["episodes"] == 3
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=5) as answer:
            assert b"rdd review" in answer.read()
    finally:
        proc.terminate()
        proc.wait(30)
    assert not (tmp_path / "out.json").exists()  # nothing saved, nothing written
