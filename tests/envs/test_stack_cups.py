"""stack_cups, the pretraining task whose next step only the scene tells: order and destinations."""

from __future__ import annotations

import pytest

pytest.importorskip("pybullet")

from envs.expert import run_expert  # noqa: E402
from envs.labeler import PrivilegedLabeler  # noqa: E402

SEEDS = range(8)


@pytest.fixture(scope="module")
def demos():
    """Expert runs of the red-base variation (no images), privileged record attached."""
    out = []
    for seed in SEEDS:
        res = run_expert("stack_cups", seed, variation=0, render=False)
        assert res.success, f"expert failed on stack_cups seed {seed}: {res.failure}"
        res.episode.meta["privileged"] = res.privileged
        out.append(res)
    return out


def _start_y(res, colour: str) -> float:
    names = [o["name"] for o in res.episode.meta["objects"]]
    return float(res.privileged["object_positions"][0, names.index(f"{colour}_cup"), 1])


def test_cups_are_stacked_in_the_order_they_stand_along_the_table(demos):
    for res in demos:
        reached = [i.removeprefix("reach for the ").removesuffix(" cup")
                   for i in res.episode.instructions if i.startswith("reach for")]
        assert len(reached) == 2 and "red" not in reached
        assert _start_y(res, reached[0]) < _start_y(res, reached[1])


def test_each_cup_goes_onto_the_top_of_the_stack(demos):
    for res in demos:
        ins = res.episode.instructions
        first, second = [i.split()[2] for i in ins if i.startswith("lift the")]
        assert f"move the {first} cup above the red cup" in ins
        assert f"move the {second} cup above the {first} cup" in ins


def test_the_same_prompt_text_leads_to_different_steps(demos):
    # goal and previous instruction alike, next instruction different: only the image settles it
    nexts: dict[tuple[str, str], set[str]] = {}
    for res in demos:
        ep = res.episode
        for prev, nxt in zip(ep.instructions, ep.instructions[1:], strict=False):
            nexts.setdefault((ep.goal, prev), set()).add(nxt)
    assert any(len(v) > 1 for (_, prev), v in nexts.items() if prev.startswith("lift"))
    assert len(nexts[("stack the other cups on the red cup", "move the gripper up")]) > 1


def test_the_labeller_says_the_experts_words(demos):
    for res in demos:
        assert PrivilegedLabeler().label_all(res.episode, res.episode.segments) == res.episode.instructions
