"""``python -m rdd review`` in a real browser (issue 63): headless Chromium opens the page on real
RLBench and Unitree G1 episodes, drags a boundary and moves it with the keys, renames a label, marks
the episode reviewed, saves, and the saved JSON says so. Skipped, with the install line, without
Chromium or selenium.

``RDD_REVIEW_SCREENSHOTS=docs`` also writes the page's screenshots there (docs/review.md shows them).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from rdd.cli import main
from rdd.review import browser

pytestmark = [pytest.mark.slow, pytest.mark.skipif(browser.missing() is not None, reason=str(browser.missing()))]
SHOTS = os.environ.get("RDD_REVIEW_SCREENSHOTS")
LEAST = "const c = state.rec.confidence; return c.indexOf(Math.min(...c))"


def decompose_real(tmp: Path, data: list[str], build: list[str], decompose: list[str]) -> Path:
    """A database of some real episodes and rdd's decomposition of others against it."""
    cache = ["--cache-dir", str(tmp / "cache")]
    assert main(["build-db", *data, *cache, *build, "--encoder", "effnet_lite0", "--out", str(tmp / "db")]) == 0
    assert main(["decompose", *data, *cache, *decompose, "--decomposer", "rdd", "--db", str(tmp / "db"),
                 "--out", str(tmp / "rdd.json")]) == 0
    return tmp / "rdd.json"


def edit_in_browser(fmt: str, data: Path, pred: Path, db: Path, out: Path, reader_options=None,
                    shots: str | None = None) -> dict:
    """Open the page, edit the first listed episode (drag its first boundary, then move it 3 frames with
    the keys, rename its first segment, mark it reviewed), save; what changed, as the page saw it."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys
    from selenium.webdriver.support.ui import WebDriverWait

    from rdd.review.app import create_app
    from rdd.review.session import ReviewSession

    session = ReviewSession(fmt, data, pred, out, db=db, reader_options=reader_options)
    with browser.served(create_app(session)) as url, browser.chromium() as d:
        wait = WebDriverWait(d, 60)
        d.get(url)
        rows = wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, "#list tbody tr"))
        name = rows[0].get_attribute("data-episode")
        if shots:
            d.save_screenshot(str(Path(shots) / "review_list.png"))
        rows[0].click()
        wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, "#timeline .handle"))
        loaded = "return [...document.images].every((i) => i.complete && i.naturalWidth > 0)"
        if shots:  # the episode as RDD cut it: the lowest-confidence segment beside its match
            d.find_element(By.CSS_SELECTOR, f'.seg[data-k="{d.execute_script(LEAST)}"]').click()
            wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#match img")) == 4)
            wait.until(lambda d: d.execute_script(loaded))
            d.save_screenshot(str(Path(shots) / "review_episode.png"))
        before = d.execute_script("return state.rec.segments.map((s) => s.slice())")
        settled = "return state.pending === 0 && state.rec.segments[0][1]"
        # drag the first boundary a fifth of the way into the next segment, then move it with the keys
        handle = d.find_element(By.CSS_SELECTOR, '.handle[data-b="0"]')
        width = d.find_element(By.ID, "timeline").size["width"]
        n = d.execute_script("return state.rec.num_frames")
        frames = max(2, (before[1][1] - before[1][0]) // 5)
        ActionChains(d).click_and_hold(handle).move_by_offset(round(frames * width / n), 0).release().perform()
        wait.until(lambda d: d.execute_script(settled) not in (before[0][1], None))
        dragged = d.execute_script("return state.rec.segments.map((s) => s.slice())")
        assert before[0][1] < dragged[0][1] < before[1][1]
        key, shift = ("d", 3) if dragged[1][1] - dragged[1][0] > 4 else ("a", -3)
        ActionChains(d).send_keys(key * 3).perform()
        wait.until(lambda d: d.execute_script(settled) == dragged[0][1] + shift)
        d.find_element(By.CSS_SELECTOR, '.seg[data-k="0"]').click()
        label = d.find_element(By.ID, "label")
        label.clear()
        label.send_keys("grasp the handle", Keys.TAB)
        wait.until(lambda d: d.execute_script("return state.pending === 0 && state.rec.instructions[0]")
                   == "grasp the handle")
        d.find_element(By.ID, "reviewed").click()
        wait.until(lambda d: d.execute_script("return state.pending === 0 && state.rec.reviewed") is True)
        d.find_element(By.ID, "save").click()
        wait.until(lambda d: d.find_element(By.ID, "status").text.startswith("saved"))
        assert d.execute_script(loaded)  # every frame shown decoded
        errors = [e for e in d.get_log("browser") if e["level"] == "SEVERE"]
    assert not errors, errors
    return {"episode": name, "before": dragged, "shift": shift}


def check_saved(out: Path, pred: Path, edit: dict) -> None:
    saved = {r["episode"]: r for r in json.loads(out.read_text())["episodes"]}
    original = {r["episode"]: r for r in json.loads(pred.read_text())["episodes"]}
    rec = saved[edit["episode"]]
    want = [list(s) for s in edit["before"]]
    want[0][1] += edit["shift"]
    want[1][0] += edit["shift"]
    assert rec["segments"] == want
    assert rec["instructions"][0] == "grasp the handle" and rec["reviewed"] is True
    assert rec["sources"][:2] == ["person", "person"]
    assert rec["sources"][2:] == ["rdd"] * (len(want) - 2)
    assert all(saved[n]["segments"] == original[n]["segments"] for n in saved if n != edit["episode"])


def test_review_rlbench_in_chromium(real_data, tmp_path):
    data = real_data("rlbench/open_drawer/all_variations/episodes")
    args = ["--format", "rlbench", "--data", str(data)]
    pred = decompose_real(tmp_path, args, ["--exclude", "episode0"], ["--include", "episode0", "episode1"])
    out = tmp_path / "reviewed.json"
    edit = edit_in_browser("rlbench", data, pred, tmp_path / "db", out)
    check_saved(out, pred, edit)


def test_review_g1_in_chromium(real_data, tmp_path):
    data = real_data("lerobot/unitree_g1_pick_bottle_30")
    args = ["--format", "lerobot", "--data", str(data), "--reader-option", "skip_missing=true"]
    pred = decompose_real(tmp_path, [*args, "--views", "state"],
                          ["--include", *[f"episode_0000{k}" for k in range(16, 26)]],
                          ["--include", *[f"episode_0000{k}" for k in range(36, 46)], "--labeler", "signals"])
    out = tmp_path / "reviewed.json"
    edit = edit_in_browser("lerobot", data, pred, tmp_path / "db", out, {"skip_missing": True}, SHOTS)
    check_saved(out, pred, edit)
