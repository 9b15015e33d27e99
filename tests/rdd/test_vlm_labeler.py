"""VLM labeler against a real HTTP server on 127.0.0.1 that answers like a chat endpoint (fixture
``endpoint``, tests/rdd/conftest.py): what it is shown, what it keeps of an answer, its one-line
errors, and ``decompose --write-lerobot --labeler vlm`` writing all or nothing."""

from __future__ import annotations

import base64
import io
import json
import socket

import numpy as np
import pytest

from rdd.data.episode import Episode
from rdd.labelers.vlm import VLMLabeler, instruction_from_answer
from rdd.labelers.vlm_backends import VLMError


def episode(t=40) -> Episode:
    """Two views whose pixels say the frame (red = index) and the view (green: 10 front, 200 wrist)."""
    front = np.zeros((t, 6, 8, 3), dtype=np.uint8)
    front[..., 0] = np.arange(t, dtype=np.uint8)[:, None, None]
    wrist = front.copy()
    front[..., 1], wrist[..., 1] = 10, 200
    return Episode(name="demo", views={"front": front, "wrist": wrist}, goal="stack the cups")


def shown_images(request: dict) -> list[tuple[str, int, int]]:
    """(label, frame index, view green value) of each image of a recorded request, decoded from its PNG."""
    from PIL import Image

    content = request["body"]["messages"][0]["content"]
    out = []
    for label, image in zip(content[1::2], content[2::2], strict=True):
        png = base64.b64decode(image["image_url"]["url"].split(",", 1)[1])
        pixels = np.asarray(Image.open(io.BytesIO(png)))
        out.append((label["text"], int(pixels[0, 0, 0]), int(pixels[0, 0, 1])))
    return out


def labeler(endpoint, **options) -> VLMLabeler:
    return VLMLabeler(base_url=endpoint.base_url, model="tiny-vlm", api_key_env=None, retries=0, **options)


def test_shows_evenly_spaced_frames_of_every_view_and_keeps_the_instruction(endpoint):
    endpoint.script = [(200, '"Pick up the red cup."', 0), (200, "```\nplace it on the blue cup\n```", 0)]
    got = labeler(endpoint, frames=4).label_all(episode(), [(10, 30), (30, 33)])
    assert got == ["Pick up the red cup", "place it on the blue cup"]
    first, second = endpoint.requests
    assert first["path"] == "/v1/chat/completions" and first["body"]["model"] == "tiny-vlm"
    prompt = first["body"]["messages"][0]["content"][0]["text"]
    assert "stack the cups" in prompt and "4 frames" in prompt and "front, wrist" in prompt
    # [10, 30) with 4 frames: 10, 10 + 19/3, 10 + 38/3, 29 rounded; each frame shows both views.
    assert shown_images(first) == [(f"Frame {j + 1} ({v}):", f, g) for j, f in enumerate([10, 16, 23, 29])
                                   for v, g in (("front", 10), ("wrist", 200))]
    assert [f for _, f, _ in shown_images(second)] == [30, 30, 31, 31, 32, 32]  # 3 frames: all of them


def test_a_chosen_view_and_one_frame(endpoint):
    endpoint.script = [(200, "open the drawer", 0)]
    assert labeler(endpoint, view="wrist", frames=1).label(episode(), (0, 9)) == "open the drawer"
    assert shown_images(endpoint.requests[0]) == [("Frame 1 (wrist):", 4, 200)]  # the middle frame
    with pytest.raises(ValueError, match=r"view='top'.*\['front', 'wrist'\]"):
        labeler(endpoint, view="top").label(episode(), (0, 9))


def test_answers_that_are_not_one_short_instruction():
    assert instruction_from_answer("Instruction: grasp the bottle.\n", 16) == "grasp the bottle"
    assert instruction_from_answer("- release the bottle", 16) == "release the bottle"
    for text, why in (("", "empty"), ("  \n``` \n```", "empty"), ('"."', "empty"),
                      ("grasp it\nthen lift it", "2 lines"), ("word " * 17, "17 words")):
        with pytest.raises(VLMError, match=why):
            instruction_from_answer(text, 16)


def closed_port_url() -> str:
    """A URL on 127.0.0.1 where nothing listens (a port just bound and released)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    return f"http://127.0.0.1:{port}/v1"


@pytest.mark.parametrize("status, content, why", [
    (400, "x", "refused the request: HTTP 400"),
    (503, "x", r"failed after 1 attempts \(HTTP 503"),
    (200, b"not json {", "invalid JSON"),
    (200, json.dumps({"id": "x", "choices": []}).encode(), r"lacks choices\[0\].message.content"),
    (200, "", "the answer is empty"),
    (200, "The robot first moves its arm to the left and then it grasps the bottle firmly "
          "with all five fingers of its right hand", "words, not a short instruction"),
])
def test_each_failure_is_one_line_naming_the_endpoint_and_segment(endpoint, status, content, why):
    endpoint.script = [(status, content, 0)]
    with pytest.raises(VLMError, match=why) as exc:
        labeler(endpoint).label(episode(), (5, 20))
    msg = str(exc.value)
    assert len(msg.splitlines()) == 1 and endpoint.base_url in msg and "'demo' segment [5, 20)" in msg


def test_unreachable_endpoint_names_it():
    url = closed_port_url()
    lab = VLMLabeler(base_url=url, model="m", api_key_env=None, retries=1, backoff=0.01)
    with pytest.raises(VLMError, match=r"failed after 2 attempts \(URLError") as exc:
        lab.label(episode(), (0, 10))
    assert url in str(exc.value) and len(str(exc.value).splitlines()) == 1


def test_options_are_checked_before_any_call():
    with pytest.raises(ValueError, match="frames must be >= 1"):
        VLMLabeler(base_url="http://127.0.0.1:9/v1", model="m", frames=0)
    with pytest.raises(ValueError, match=r"prompt .*\{task\}.*\{goal\}, \{num_frames\}, \{views\}"):
        VLMLabeler(base_url="http://127.0.0.1:9/v1", model="m", prompt="do {task}")
    with pytest.raises(ValueError, match=r"unknown option\(s\) \['modle'\].*frames.*base_url"):
        VLMLabeler(base_url="http://127.0.0.1:9/v1", modle="m")
    with pytest.raises(ValueError, match="needs base_url"):
        VLMLabeler(model="m")


# --- through the CLI: decompose --write-lerobot --labeler vlm ---


def decompose(src, out, endpoint_url, *extra):
    from rdd.cli import main

    return main([str(a) for a in (
        "decompose", "--format", "lerobot", "--data", src, "--decomposer", "uniform", "--option", "n_segments=2",
        "--labeler", "vlm", "--labeler-option", f"base_url={endpoint_url}", "--labeler-option", "model=m",
        "--labeler-option", "api_key_env=null", "--labeler-option", "retries=0", "--write-lerobot", out, *extra)])


def test_write_lerobot_is_all_or_nothing(lerobot_factory, tmp_path, endpoint, capsys):
    from rdd.data.lerobot.reader import load_episodes

    src = lerobot_factory("v3.0")  # 3 episodes, 2 segments each: 6 calls
    out = tmp_path / "labelled"
    # Episode 0 is named; episode 1's first answer is empty: the command fails and writes no dataset.
    endpoint.script = [(200, "pick up the cup", 0), (200, "put the cup down", 0), (200, "  ", 0)]
    assert decompose(src, out, endpoint.base_url) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "the answer is empty" in err and endpoint.base_url in err
    assert "episode_000001" in err and not out.exists()
    # The same command resumes: episode 0 is not asked again, and the copy holds every answer.
    endpoint.requests.clear()
    endpoint.script = [(200, f"step {k}", 0) for k in range(4)]
    assert decompose(src, out, endpoint.base_url) == 0
    assert len(endpoint.requests) == 4
    back = {e.name: e.instructions for e in load_episodes(out)}
    assert back == {"episode_000000": ["pick up the cup", "put the cup down"],
                    "episode_000001": ["step 0", "step 1"], "episode_000002": ["step 2", "step 3"]}


def cli_fails(capsys, *argv, expect: tuple[str, ...]) -> None:
    """Exit status 2 and the error as one line (the reader's dims line is for -v only)."""
    from rdd.cli import main

    capsys.readouterr()
    assert main([str(a) for a in argv]) == 2, argv
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert "Traceback" not in err and len(lines) == 1 and lines[0].startswith("error"), err
    for word in expect:
        assert word in lines[0], (word, err)


def test_cli_errors_are_one_line(lerobot_factory, tmp_path, capsys):
    src = lerobot_factory("v3.0", lengths=(20, 20))
    url = closed_port_url()
    cli_fails(capsys, "decompose", "--format", "lerobot", "--data", src, "--decomposer", "uniform", "--labeler", "vlm",
              "--labeler-option", f"base_url={url}", "--labeler-option", "model=m", "--labeler-option", "retries=0",
              "--labeler-option", "api_key_env=null", "--write-lerobot", tmp_path / "o",
              expect=(url, "URLError", "episode_000000"))
    assert not (tmp_path / "o").exists()
    cli_fails(capsys, "decompose", "--format", "lerobot", "--data", src, "--decomposer", "uniform", "--labeler", "vlm",
              "--write-lerobot", tmp_path / "o", expect=("--labeler vlm", "base_url", "--labeler-option"))
    cli_fails(capsys, "decompose", "--format", "lerobot", "--data", src, "--decomposer", "uniform", "--labeler", "vlm",
              "--labeler-option", "base_url=http://127.0.0.1:9/v1", "--labeler-option", "model=m",
              "--labeler-option", "frames=0", "--write-lerobot", tmp_path / "o", expect=("--labeler-option frames=0",))
    cli_fails(capsys, "decompose", "--format", "lerobot", "--data", src, "--decomposer", "uniform", "--labeler", "retrieval",
              "--labeler-option", "frames=2", "--out", tmp_path / "o.json", expect=("--labeler retrieval",))
    cli_fails(capsys, "decompose", "--format", "lerobot", "--data", src, "--decomposer", "uniform", "--labeler",
              "signals", "--labeler-option", "hand_dleta=0.2", "--out", tmp_path / "o.json",
              expect=("--labeler signals", "hand_dleta", "hand_delta"))
    cli_fails(capsys, "decompose", "--format", "lerobot", "--data", src, "--decomposer", "uniform", "--labeler",
              "signals", "--labeler-option", "hand_delta=0", "--out", tmp_path / "o.json",
              expect=("--labeler-option hand_delta=0", "must be > 0"))
