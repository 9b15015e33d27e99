"""Ordered-list exercises: the answer is the item after the one done last, in the demos' words only."""

import numpy as np
import pytest

from planner.config import TrainSettings
from planner.dataset import PlannerExample
from planner.exercises import list_exercises

IMG = np.zeros((4, 4, 3), dtype=np.uint8)


def _pretraining():
    def ex(task, goal, target):
        return PlannerExample(image=IMG, goal=goal, previous_instruction=None, target=target, task=task)

    return [ex("close_jar", f"close the {c} jar", f"move above the {c} jar") for c in ("red", "blue", "lime")] + [
        ex("peg", f"put the {c} peg in the square", f"grasp the {c} peg") for c in ("green", "olive")]


def _parse(question):
    listing, done = question.removeprefix("In order: ").split(". Done last: ")
    items = [s.removeprefix("the ") for s in listing.split(", then ")]
    return items, done.removesuffix(". Which is next?")


def test_the_answer_is_the_item_after_the_one_done_last():
    out = list_exercises(_pretraining(), 300, seed=0)
    assert len(out) == 300
    places = set()
    for ex in out:
        items, done = _parse(ex.question)
        assert 2 <= len(items) <= 4 and len(set(items)) == len(items)
        nouns = {item.split()[1] for item in items}
        assert len(nouns) == 1 and nouns <= {"jar", "peg"}
        assert {item.split()[0] for item in items} <= {"red", "blue", "lime", "green", "olive"}
        nxt = 0 if done == "nothing yet" else items.index(done.removeprefix("the ")) + 1
        assert ex.target == f"the {items[nxt]}"
        assert ex.previous_instruction is None and ex.task == "ordered_list"
        places.add((len(items), nxt))
    # the next item stands anywhere in lists of every length
    assert places == {(n, k) for n in (2, 3, 4) for k in range(n)}


def test_exercises_are_off_by_default_and_need_enough_words():
    assert list_exercises(_pretraining(), 0, seed=0) == []
    assert "list_exercises" not in TrainSettings().key_dict()
    assert TrainSettings(list_exercises=5).key_dict()["list_exercises"] == 5
    with pytest.raises(ValueError, match="list_exercises"):
        TrainSettings(list_exercises=-1)
    with pytest.raises(ValueError, match=">= 4 slot words"):
        list_exercises(_pretraining()[:3], 5, seed=0)
