"""Ordered-list exercises for a tiny base: which item of a list follows a named one.

A pretrained language model has read countless ordered lists. The tiny planner's language model
is trained from scratch on the pretraining tasks, whose goals name one object each, so it never
needs to find a word in its prompt and say the one after it, which an ordered goal asks ("push the
red button, then the green button": after the red one, the green one; docs/tried.md). These
exercises ask that in a question of their own, in the pretraining demos' words only (their slot
words and the nouns after them), never an evaluation task's goal or instruction.
"""

from __future__ import annotations

import re
from collections.abc import Sequence

import numpy as np

from planner.augment import slot_words
from planner.dataset import PlannerExample

EXERCISE_TASK = "ordered_list"
_WORD = re.compile(r"[A-Za-z]+")


def _nouns(examples: Sequence[PlannerExample], slots: set[str]) -> list[str]:
    """The words right after a slot word in the examples' goals (the jar of "the red jar")."""
    found = set()
    for ex in examples:
        words = _WORD.findall(ex.goal)
        found |= {b for a, b in zip(words, words[1:], strict=False) if a in slots and b not in slots}
    return sorted(found)


def list_exercises(examples: Sequence[PlannerExample], count: int, seed: int) -> list[PlannerExample]:
    """``count`` questions "in order: the A x, then the B x, ...; done last: the B x; which is next?"
    over the slot words and nouns of ``examples`` (planner steps), each on one of their images.

    The list holds 2-4 distinct slot words; the item done last is none yet or any but the last, so
    the answer is the first item or the one after the named one, wherever it stands.
    """
    if count < 0:
        raise ValueError(f"list exercises count must be >= 0, got {count}")
    steps = [ex for ex in examples if ex.question is None]
    words = sorted(set().union(*slot_words(steps).values())) if steps else []
    nouns = _nouns(steps, set(words))
    if count and (len(words) < 4 or not nouns):
        raise ValueError(f"list exercises need >= 4 slot words and a noun after one in the pretraining "
                         f"goals; found words {words} and nouns {nouns}")
    rng = np.random.default_rng(seed)
    out = []
    for k in range(count):
        n = int(rng.integers(2, 5))
        items = [str(w) for w in rng.choice(words, size=n, replace=False)]
        noun = str(nouns[int(rng.integers(len(nouns)))])
        listing = ", then ".join(f"the {w} {noun}" for w in items)
        last = int(rng.integers(-1, n - 1))  # -1: nothing done yet
        done = "nothing yet" if last < 0 else f"the {items[last]} {noun}"
        out.append(PlannerExample(
            image=steps[k % len(steps)].image, goal=listing, previous_instruction=None,
            target=f"the {items[last + 1]} {noun}", task=EXERCISE_TASK,
            question=f"In order: {listing}. Done last: {done}. Which is next?"))
    return out
