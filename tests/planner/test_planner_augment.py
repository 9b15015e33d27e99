"""Slot-word swapping: which words are slots, and that renamed copies stay consistent."""

import numpy as np
import pytest

from planner.augment import slot_swap, slot_vocabulary, slot_words
from planner.config import TrainSettings
from planner.dataset import PlannerExample

IMG = np.zeros((4, 4, 3), dtype=np.uint8)


def _ex(task, goal, prev, target):
    return PlannerExample(image=IMG, goal=goal, previous_instruction=prev, target=target, task=task)


def _buttons():
    return [
        _ex("buttons", "push the red button, then the green button", None, "move above the red button"),
        _ex("buttons", "push the red button, then the green button", "release the red button",
            "move above the green button"),
        _ex("buttons", "push the blue button", "push the blue button", "release the blue button"),
        _ex("drawer", "open the top drawer", None, "reach for the top drawer handle"),
        _ex("drawer", "open the bottom drawer", "grasp the bottom drawer handle",
            "pull the bottom drawer open"),
        _ex("tap", "turn left tap", None, "reach for the left tap handle"),  # one goal: no slot
    ]


def test_slots_vary_across_goals_and_are_spoken_in_instructions():
    slots = slot_words(_buttons())
    # "then", "green"... : "then" varies but no instruction says it; "push"/"button" never vary
    assert slots == {"buttons": ["blue", "green", "red"], "drawer": ["bottom", "top"], "tap": []}


def test_copies_rename_consistently_and_keep_the_image():
    base = _buttons()
    out = slot_swap(base, copies=3, seed=0)
    assert out[: len(base)] == base
    extra = out[len(base):]
    # every example but the tap one (no slot word) gets three copies
    assert len(extra) == 3 * 5
    pool = {"blue", "green", "red", "bottom", "top"}
    sources = [b for b in base[:5] for _ in range(3)]  # copies follow their source, in order
    for src, copy in zip(sources, extra, strict=True):
        assert copy.image is src.image
        # word by word, the copy differs from its source only at slot words, and the same source
        # word always maps to the same new word (in goal, previous instruction and target)
        mapping = {}
        for a_text, b_text in [(src.goal, copy.goal), (src.previous_instruction or "",
                                                          copy.previous_instruction or ""),
                               (src.target, copy.target)]:
            a_words, b_words = a_text.replace(",", " ,").split(), b_text.replace(",", " ,").split()
            assert len(a_words) == len(b_words)
            for a, b in zip(a_words, b_words, strict=True):
                if a != b:
                    assert a in pool and b in pool
                mapping.setdefault(a, b)
                assert mapping[a] == b
        renamed = [mapping[w] for w in ("red", "green", "blue", "top", "bottom") if w in mapping]
        assert len(set(renamed)) == len(renamed)  # injective: two buttons never get one colour


def test_task_pool_keeps_words_within_their_task_and_all_pool_mixes_them():
    base = _buttons()
    colours, sides = {"blue", "green", "red"}, {"bottom", "top"}
    for copy in slot_swap(base, copies=20, seed=3)[len(base):]:
        words = set(copy.goal.replace(",", " ").split())
        assert words & (sides if copy.task == "buttons" else colours) == set()
    mixed = slot_swap(base, copies=20, seed=3, pool="all")[len(base):]
    assert any(set(c.goal.split()) & sides for c in mixed if c.task == "buttons")
    with pytest.raises(ValueError, match="pool"):
        slot_swap(base, 1, seed=0, pool="vocabulary")
    with pytest.raises(ValueError, match="slot_swap_pool"):
        TrainSettings(slot_swap_pool="vocabulary")


def test_vocabulary_words_join_their_task_pool_only():
    from types import SimpleNamespace

    # The base's corpus: push_buttons goals naming purple and cyan, which no finetuning demo uses.
    corpus = [SimpleNamespace(task="buttons", goal="push the purple button, then the cyan button",
                              instructions=["move above the purple button", "push the cyan button"]),
              SimpleNamespace(task="buttons", goal="push the red button",
                              instructions=["move above the red button"]),
              SimpleNamespace(task="drawer", goal="open the middle drawer",
                              instructions=["pull the middle drawer open"]),
              SimpleNamespace(task="drawer", goal="open the top drawer",
                              instructions=["pull the top drawer open"])]
    vocab = slot_vocabulary(corpus)
    assert vocab == {"buttons": ["cyan", "purple", "red"], "drawer": ["middle", "top"]}
    base = _buttons()
    copies = slot_swap(base, copies=40, seed=2, vocabulary=vocab)[len(base):]
    said = {w for c in copies if c.task == "buttons" for w in c.target.split()}
    assert {"purple", "cyan"} <= said  # words only the vocabulary knows are now said
    assert not said & {"middle", "top", "bottom"}
    drawer_said = {w for c in copies if c.task == "drawer" for w in c.target.split()}
    assert "middle" in drawer_said and not drawer_said & {"purple", "cyan", "red"}
    # without a vocabulary the pools are the demos' own words, as before
    plain = slot_swap(base, copies=40, seed=2)[len(base):]
    assert not {w for c in plain for w in c.target.split()} & {"purple", "cyan", "middle"}


def test_one_demo_per_task_gets_copies_from_the_vocabulary():
    # M = 1: each task's single goal varies no word, so only the vocabulary says what a slot is
    one = [_ex("buttons", "push the red button, then the green button", "release the red button",
               "move above the green button"),
           _ex("tap", "turn left tap", None, "reach for the left tap handle")]
    assert slot_swap(one, copies=5, seed=0)[len(one):] == []
    vocab = {"buttons": ["blue", "green", "red", "yellow"], "tap": ["left", "right"]}
    copies = slot_swap(one, copies=5, seed=0, vocabulary=vocab)[len(one):]
    assert len(copies) == 10
    for c in copies:
        if c.task == "buttons":
            first, second = c.goal.split()[2], c.goal.split()[6]
            assert first != second and {first, second} <= set(vocab["buttons"])
            assert c.previous_instruction == f"release the {first} button"
            assert c.target == f"move above the {second} button"
        else:
            side = c.goal.split()[1]
            assert side in ("left", "right") and c.target == f"reach for the {side} tap handle"
    assert any(c.task == "tap" and "right" in c.goal for c in copies)


def test_swapping_is_seeded_and_off_at_zero():
    base = _buttons()
    assert slot_swap(base, 0, seed=1) == base
    assert slot_swap(base, 2, seed=5) == slot_swap(base, 2, seed=5)
    assert slot_swap(base, 4, seed=5) != slot_swap(base, 4, seed=6)
    with pytest.raises(ValueError, match="copies"):
        slot_swap(base, -1, seed=0)
    with pytest.raises(ValueError, match="slot_swap_copies"):
        TrainSettings(slot_swap_copies=-2)


def test_off_keeps_the_cache_keys_of_settings_made_before_the_option():
    off = TrainSettings().key_dict()
    assert "slot_swap_copies" not in off and "slot_swap_pool" not in off
    assert TrainSettings(slot_swap_copies=2).key_dict()["slot_swap_copies"] == 2
    assert TrainSettings(slot_swap_copies=2).key_dict()["slot_swap_pool"] == "task"


def test_state_jitter_moves_only_the_copies_hand_height_within_its_bound():
    from dataclasses import replace

    from planner.prompts import robot_state

    state = robot_state([0.4, 0.0, 0.23, 0, 0, 0, 1], [0.0])  # "... the hand is 23 cm high"
    base = [replace(ex, state=state) for ex in _buttons()]
    plain = slot_swap(base, copies=8, seed=3)
    jittered = slot_swap(base, copies=8, seed=3, state_jitter_cm=2)
    assert jittered[: len(base)] == base  # the demos' own examples keep their height
    heights = []
    for ex in jittered[len(base):]:
        words = ex.state.split()
        assert words[:4] == ["the", "gripper", "is", "closed"] and words[-2:] == ["cm", "high"]
        heights.append(int(words[-3]))
    assert set(heights) <= {21, 22, 23, 24, 25} and len(set(heights)) > 1
    assert all(ex.state == state for ex in plain)  # off: every copy states the demo's height
    assert TrainSettings(state_jitter_cm=0).key_dict() == TrainSettings().key_dict()
    with pytest.raises(ValueError, match="state_jitter_cm"):
        TrainSettings(state_jitter_cm=-1)
