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

With ``reorder`` a copy also moves its goal's slot words into another of the task's goal shapes
(the task's goals with their slot words cut out, e.g. one, two and three buttons in order), keeping
the previous instruction's and the answer's slot words the same distance apart and filling the
other places with other slot words. Three demos put the button just released always first or
second of the goal; the copies put it anywhere, so the answer ("the next one") can only be found by
finding that word in the goal. This assumes what an ordered goal means: the slot words before the
previous instruction's are done, those after the answer's are still to do.
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


def goal_shapes(examples: Sequence[PlannerExample],
                slots: Mapping[str, Sequence[str]]) -> dict[str, dict[int, list[list[str]]]]:
    """Per task and number of slot words, its goals split around their slot words (text, slot,
    text, ..., text); goals naming a slot word twice are left out."""
    shapes: dict[str, dict[int, list[list[str]]]] = defaultdict(lambda: defaultdict(list))
    for ex in examples:
        words = slots.get(ex.task, [])
        if not words:
            continue
        parts = re.split(r"\b(" + "|".join(map(re.escape, words)) + r")\b", ex.goal)
        named = parts[1::2]
        if named and len(set(named)) == len(named) and parts not in shapes[ex.task][len(named)]:
            shapes[ex.task][len(named)].append(parts)
    return {t: dict(by_n) for t, by_n in shapes.items()}


def _reordered_goal(ex: PlannerExample, words: Sequence[str], shapes: Mapping[int, list[list[str]]],
                    rng: np.random.Generator) -> str | None:
    """``ex``'s goal in a random shape of its task, the previous instruction's and the answer's
    slot words the same distance apart; None where the example has no such anchor."""
    order = [w for w in _WORD.findall(ex.goal) if w in words]
    answer = [w for w in order if w in _words(ex.target)]
    before = [w for w in order if w in _words(ex.previous_instruction)]
    if len(set(order)) != len(order) or len(answer) != 1 or len(before) > 1:
        return None
    j = order.index(answer[0])
    if before:
        i = order.index(before[0])
    elif ex.previous_instruction is None and j == 0:
        i = 0  # the first step: the answer's word stays first
    else:
        return None
    gap = j - i
    lengths = [n for n in shapes if n > gap]
    if gap < 0 or not lengths:
        return None
    n = int(lengths[rng.integers(len(lengths))])
    parts = shapes[n][int(rng.integers(len(shapes[n])))]
    start = 0 if ex.previous_instruction is None else int(rng.integers(n - gap))
    anchors = {start: order[i], start + gap: order[j]}
    others = [w for w in words if w not in anchors.values()]
    if len(others) < n - len(anchors):
        return None
    fill = iter(rng.permutation(others).tolist())
    named = [anchors[k] if k in anchors else next(fill) for k in range(n)]
    out = list(parts)
    out[1::2] = named
    return "".join(out)


def slot_swap(examples: Sequence[PlannerExample], copies: int, seed: int,
              pool: str = "task", vocabulary: Mapping[str, Sequence[str]] | None = None,
              state_jitter_cm: int = 0, reorder: bool = False) -> list[PlannerExample]:
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
    ``reorder``: each copy's goal also takes another of its task's goal shapes (module docstring).
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
    shapes = goal_shapes(steps, slots) if reorder else {}
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
            copy = replace(ex, goal=_rename(ex.goal, mapping),
                           previous_instruction=_rename(ex.previous_instruction, mapping),
                           target=_rename(ex.target, mapping), scene=_rename(ex.scene, mapping),
                           state=shift_height(ex.state, shift))
            if ex.task in shapes:
                goal = _reordered_goal(copy, names, shapes[ex.task], rng)
                copy = copy if goal is None else replace(copy, goal=goal)
            out.append(copy)
    return out
