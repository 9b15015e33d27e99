"""Scene captions from the simulator's privileged record: image-grounding examples for base pretraining.

LLaVA's first training stage aligns its projector on image-caption pairs; the paper's planner
arrives at finetuning knowing what a plate with a block on it looks like. A tiny base trained only
on planner steps memorises its few hundred images instead (docs/results.md "The planner's sight").
These captions give it that grounding from the frames of the demonstrations it is built from:
which object rests on which and which drawers and taps are open, read from
``episode.meta["privileged"]`` (``envs.record``). They name objects only, never
a sub-task or an instruction, so no decomposition leaks into the base.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import replace

import numpy as np

from planner.dataset import PlannerExample

CAPTION_QUESTION = "Describe the scene: what rests on what?"
CAPTION_MAX_TOKENS = 64  # a caption runs longer than an instruction
# a resting object's centre lies within this of the supporter's top plus its own half height
# (blocks settle and lids seat a few millimetres either way)
REST_Z_TOLERANCE = 0.02
ACTUATED = {"drawer": ("open", "shut"), "tap": ("open", "shut")}
# Buttons are left out. Their lamps (envs.record) are in the image, but the tiny base misreads
# which button is lit (55 % of push_buttons frames right), and any caption of them (each button
# lit / unlit, the lit ones by colour, their number) put wrong colours or counts into the prompt:
# push_buttons 60-81 % in planner_eval against 82.5 without (docs/results.md "Lit buttons").
UNSAID = {"button"}


def _noun(obj: dict) -> str:
    color = str(obj.get("color") or "").strip()
    kind = str(obj.get("type") or obj.get("name")).replace("_", " ").strip()
    return f"the {color} {kind}" if color else f"the {kind}"


def _rests_on(pos: np.ndarray, sizes: np.ndarray, a: int, b: int) -> bool:
    """Object ``a`` rests on ``b``: above ``b``'s footprint, its bottom at ``b``'s top."""
    if np.any(np.abs(pos[a, :2] - pos[b, :2]) > sizes[b, :2] / 2):
        return False
    gap = pos[a, 2] - pos[b, 2] - (sizes[a, 2] + sizes[b, 2]) / 2
    return bool(abs(gap) <= REST_Z_TOLERANCE)


def scene_caption(meta: dict, frame: int) -> str:
    """What rests on what (a held object is left out) and the articulations' states at ``frame``."""
    priv = meta.get("privileged")
    if priv is None or "object_positions" not in priv:
        raise ValueError("scene captions need the simulator's privileged record "
                         "(episode.meta['privileged'] with object_positions; see envs.record)")
    objects = list(meta.get("objects", []))
    pos = np.asarray(priv["object_positions"][frame], dtype=np.float64)
    if len(objects) != len(pos):
        raise ValueError(f"privileged record has {len(pos)} objects but meta lists {len(objects)}")
    sizes = np.asarray([o["size"] for o in objects], dtype=np.float64).reshape(len(objects), 3)
    held = int(priv["held_object"][frame]) if "held_object" in priv else -1
    # what the gripper holds is left out: at a sub-task's first frame it is just closing or opening,
    # and a caption saying either contradicted the previous instruction (docs/results.md)
    parts = []
    for a in range(len(objects)):
        if a == held:
            continue
        for b in range(len(objects)):
            if b != a and b != held and _rests_on(pos, sizes, a, b):
                parts.append(f"{_noun(objects[a])} is on {_noun(objects[b])}")
    states = priv.get("articulation_states")
    for j, art in enumerate(meta.get("articulations", [])):
        if art["kind"] in UNSAID:
            continue
        closed, opened = float(art["closed"]), float(art["open"])
        frac = (float(states[frame][j]) - closed) / (opened - closed) if opened != closed else 0.0
        on, off = ACTUATED.get(art["kind"], ("actuated", "at rest"))
        parts.append(f"the {str(art['name']).replace('_', ' ')} is {on if frac >= 0.5 else off}")
    return ". ".join(parts or ["no object rests on another"]) + "."


def caption_examples(episodes: Iterable, stride: int, view: str = "front", *,
                     skip_unrecorded: bool = False) -> list[PlannerExample]:
    """One caption example every ``stride`` frames of each episode (its last frame included).

    ``skip_unrecorded``: episodes without a privileged record (real robot data) give none
    instead of an error; a record that is there but malformed still fails.
    """
    if stride < 1:
        raise ValueError(f"caption frame stride must be >= 1, got {stride}")
    out: list[PlannerExample] = []
    for ep in episodes:
        if skip_unrecorded and "privileged" not in ep.meta:
            continue
        picks: Sequence[int] = sorted(set(range(0, ep.num_frames, stride)) | {ep.num_frames - 1})
        try:
            texts = [scene_caption(ep.meta, f) for f in picks]
        except (KeyError, IndexError, ValueError) as exc:
            raise ValueError(f"episode {ep.name!r}: cannot caption its frames: {exc}") from exc
        for f, img, text in zip(picks, ep.frames(view, picks), texts, strict=True):
            out.append(PlannerExample(image=np.ascontiguousarray(img), goal="", previous_instruction=None,
                                      target=text, task=ep.task, episode=ep.name, frame=int(f),
                                      question=CAPTION_QUESTION))
    return out


def with_true_scenes(examples: Sequence[PlannerExample], episodes: Iterable) -> list[PlannerExample]:
    """Planner examples whose prompt states the true caption of their frame (simulated demos only)."""
    metas = {ep.name: ep.meta for ep in episodes}
    out = []
    for ex in examples:
        if ex.episode not in metas:
            raise ValueError(f"planner example of episode {ex.episode!r}: that episode was not given")
        out.append(replace(ex, scene=scene_caption(metas[ex.episode], ex.frame)))
    return out
