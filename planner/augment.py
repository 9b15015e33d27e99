"""Slot-word swapping: extra planner examples whose goal-specific words are consistently renamed.

With three demonstrations per task the planner can learn each demo's object, colour or order by
heart instead of reading it from the goal. A *slot word* of a task is a goal word that varies
between the task's goals and also appears in some instruction (a colour, a shape, a drawer or tap
side); structural words ("then", "two") and words every goal shares are never slots. An augmented
copy renames each slot word it contains, through one random injective mapping onto the slot words
of its own task (``pool="task"``) or of the whole training set (``pool="all"``), in the goal, the
previous instruction and the target alike; the image is kept. The copy's answer then follows from
the goal alone, which is what the planner must learn. The task pool keeps a colour a colour: with
the pool of all tasks a planner that fails to copy may say "release the top button".
"""

from __future__ import annotations

import re
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import replace

import numpy as np

from planner.config import SLOT_SWAP_POOLS
from planner.dataset import PlannerExample
from planner.prompts import shift_height

_WORD = re.compile(r"[A-Za-z]+")


def _words(text: str | None) -> set[str]:
    return set(_WORD.findall(text or ""))


def slot_words(examples: Sequence[PlannerExample]) -> dict[str, list[str]]:
    """Per task, the goal words that vary across its goals and occur in its instructions (sorted)."""
    return _slot_words((ex.task, ex.goal, [ex.target, ex.previous_instruction]) for ex in examples)


def slot_vocabulary(episodes: Iterable) -> dict[str, list[str]]:
    """:func:`slot_words` of labelled episodes (``task``, ``goal``, ``instructions``): the slot words
    a base planner knows per task from its vocabulary corpus, beyond the few finetuning demos'."""
    return _slot_words((ep.task, ep.goal, list(ep.instructions)) for ep in episodes)


def _slot_words(items: Iterable[tuple[str, str, Sequence[str | None]]]) -> dict[str, list[str]]:
    goals: dict[str, set[str]] = defaultdict(set)
    said: dict[str, set[str]] = defaultdict(set)
    for task, goal, texts in items:
        goals[task].add(goal)
        for text in texts:
            said[task] |= _words(text)
    out = {}
    for task, gs in goals.items():
        word_sets = [_words(g) for g in gs]
        varying = set().union(*word_sets) - set.intersection(*word_sets)
        out[task] = sorted(varying & said[task])
    return out


def _rename(text: str | None, mapping: dict[str, str]) -> str | None:
    if text is None:
        return None
    return _WORD.sub(lambda m: mapping.get(m.group(0), m.group(0)), text)


def slot_swap(examples: Sequence[PlannerExample], copies: int, seed: int,
              pool: str = "task", vocabulary: Mapping[str, Sequence[str]] | None = None,
              state_jitter_cm: int = 0) -> list[PlannerExample]:
    """``examples`` followed by ``copies`` slot-renamed copies of each example that has slot words.

    ``pool``: rename onto the example's own task's slot words ("task") or every task's ("all").
    ``vocabulary``: further slot words per task (:func:`slot_vocabulary` of the base planner's
    corpus), renamed and renamed onto like the examples' own, so that copies also say words no
    finetuning demo used (a colour only the evaluation goal names) and a single demo per task,
    whose goal varies nothing, still gets copies. Deterministic in ``seed``. Examples without slot words (or a
    pool too small to rename them injectively) get no copies.
    ``state_jitter_cm``: each copy states the hand's height moved by a whole number of centimetres
    in [-k, k], so that a closed loop, whose policy stops a centimetre or two from the demo's
    keyframe, does not meet a height the planner never read (the original keeps its own).
    """
    if copies < 0:
        raise ValueError(f"slot_swap copies must be >= 0, got {copies}")
    if pool not in SLOT_SWAP_POOLS:
        raise ValueError(f"slot_swap pool must be one of {SLOT_SWAP_POOLS}, got {pool!r}")
    out = list(examples)
    if copies == 0:
        return out
    # a word the vocabulary knows as a slot of the task is renamed even where the few finetuning
    # goals do not vary it (one demo per task has no varying goal word at all)
    # caption examples (a question instead of the planner prompt) describe their image: renaming
    # a colour there would make the caption false, so they neither get copies nor define slots
    steps = [ex for ex in examples if ex.question is None]
    slots = {t: sorted(set(w) | set((vocabulary or {}).get(t, ()))) for t, w in slot_words(steps).items()}
    every = sorted(set().union(*slots.values())) if slots else []
    rng = np.random.default_rng(seed)
    for ex in steps:
        names = slots.get(ex.task, []) if pool == "task" else every
        said = _words(ex.goal) | _words(ex.target) | _words(ex.previous_instruction)
        present = [w for w in slots.get(ex.task, []) if w in said]
        if not present or len(names) < len(present):
            continue
        for _ in range(copies):
            new = rng.choice(len(names), size=len(present), replace=False)
            mapping = {w: names[j] for w, j in zip(present, new, strict=True)}
            shift = int(rng.integers(-state_jitter_cm, state_jitter_cm + 1)) if state_jitter_cm else 0
            out.append(replace(ex, goal=_rename(ex.goal, mapping),
                               previous_instruction=_rename(ex.previous_instruction, mapping),
                               target=_rename(ex.target, mapping), scene=_rename(ex.scene, mapping),
                               state=shift_height(ex.state, shift)))
    return out
