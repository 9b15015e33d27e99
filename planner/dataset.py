"""Planner training examples from decomposed and labelled demonstrations, and their batching."""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch.nn.utils.rnn import pad_sequence

from planner.prompts import render_prompt, render_target, robot_state
from rdd.data.episode import Episode
from rdd.segments import Segment, validate_segments


@dataclass(frozen=True)
class PlannerExample:
    """One planner query and its answer: image (uint8 HxWx3), goal, previous instruction, target.

    ``question`` set: an image question (a scene caption's) asked instead of the planner prompt.
    ``scene``: a description of the image stated in the planner prompt (``describe_scene``).
    ``state``: the robot's proprioceptive state at the frame, in words (``planner.prompts.robot_state``).
    """

    image: np.ndarray
    goal: str
    previous_instruction: str | None
    target: str
    task: str = ""
    episode: str = ""
    frame: int = -1
    question: str | None = None
    scene: str | None = None
    state: str | None = None


def examples_from_episode(episode: Episode, segments: Sequence[Segment] | None = None,
                          instructions: Sequence[str] | None = None, view: str = "front",
                          include_inner_frames: bool = False,
                          inner_frame_stride: int = 1, read_state: bool = True) -> list[PlannerExample]:
    """One example per segment start (plus inner frames if asked), previous instruction None first.

    Inner frames are every ``inner_frame_stride``-th frame of a segment, counted from its start.
    ``read_state``: each example states the robot's state at its frame (where the episode records
    the hand's pose and the gripper).

    ``segments``/``instructions`` default to the episode's own (expert) annotation.
    """
    segments = list(episode.segments if segments is None else segments)
    instructions = list(episode.instructions if instructions is None else instructions)
    if not segments:
        raise ValueError(f"episode {episode.name!r}: no segments to build planner examples from")
    if len(segments) != len(instructions):
        raise ValueError(f"episode {episode.name!r}: {len(segments)} segments but "
                         f"{len(instructions)} instructions")
    validate_segments(segments, episode.num_frames)
    if inner_frame_stride < 1:
        raise ValueError(f"inner_frame_stride must be >= 1, got {inner_frame_stride}")
    if not episode.goal.strip():
        raise ValueError(f"episode {episode.name!r}: empty goal; the planner prompt needs it")
    picks: list[tuple[int, int]] = []  # (frame, segment index)
    for i, (start, end) in enumerate(segments):
        frames = range(start, end, inner_frame_stride) if include_inner_frames else [start]
        picks.extend((f, i) for f in frames)
    images = episode.frames(view, [f for f, _ in picks])
    states = read_state and episode.ee_poses is not None and episode.gripper_open is not None
    out = []
    for img, (f, i) in zip(images, picks, strict=True):
        out.append(PlannerExample(image=np.ascontiguousarray(img), goal=episode.goal,
                                  previous_instruction=instructions[i - 1] if i > 0 else None,
                                  target=instructions[i], task=episode.task,
                                  episode=episode.name, frame=int(f),
                                  state=robot_state(episode.ee_poses[f], episode.gripper_open[f]) if states else None))
    return out


def examples_fingerprint(examples: Sequence[PlannerExample]) -> str:
    """Content hash of images and texts (cache key for trained models)."""
    h = hashlib.sha256()
    for ex in examples:
        h.update(str(ex.image.shape).encode())
        h.update(np.ascontiguousarray(ex.image).tobytes())
        for s in (ex.goal, ex.previous_instruction or "\x00", ex.target):
            h.update(s.encode() + b"\x01")
        if ex.question is not None:  # absent from the keys of models trained before questions
            h.update(b"\x02" + ex.question.encode())
        if ex.scene is not None:
            h.update(b"\x03" + ex.scene.encode())
        if ex.state is not None:
            h.update(b"\x04" + ex.state.encode())
    return h.hexdigest()


def encode_prompt(processor, image: np.ndarray, goal: str, previous_instruction: str | None,
                  question: str | None = None, scene: str | None = None, state: str | None = None) -> dict:
    """Processor outputs for one prompt (image tokens expanded), batch dimension removed."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[-1] != 3 or image.dtype != np.uint8:
        raise ValueError(f"planner image must be uint8 (H, W, 3), got {image.dtype} {image.shape}")
    text = render_prompt(processor.tokenizer, goal, previous_instruction, question, scene, state)
    enc = processor(images=[image], text=[text], return_tensors="pt", add_special_tokens=False)
    return {k: v[0] for k, v in enc.items()}


def encode_example(processor, ex: PlannerExample) -> dict:
    """Prompt plus answer token ids with labels -100 on the prompt (only the answer is learned)."""
    enc = encode_prompt(processor, ex.image, ex.goal, ex.previous_instruction, ex.question, ex.scene, ex.state)
    answer = render_target(processor.tokenizer, ex.goal, ex.previous_instruction, ex.target,
                           ex.question, ex.scene, ex.state)
    ans_ids = torch.tensor(processor.tokenizer(answer, add_special_tokens=False)["input_ids"],
                           dtype=torch.long)
    prompt_ids = enc["input_ids"]
    enc["input_ids"] = torch.cat([prompt_ids, ans_ids])
    enc["attention_mask"] = torch.ones_like(enc["input_ids"])
    enc["labels"] = torch.cat([torch.full_like(prompt_ids, -100), ans_ids])
    return enc


class PlannerCollator:
    """Pads token sequences (right for training, left for generation) and stacks images.

    LLaVA-NeXT's per-image tile stacks are zero-padded to the longest; ``image_sizes`` tells the
    model how many tiles are real, so it is always passed through.
    """

    def __init__(self, pad_token_id: int, padding_side: str = "right"):
        if padding_side not in ("left", "right"):
            raise ValueError(f"padding_side must be left or right, got {padding_side!r}")
        self.pad_token_id = int(pad_token_id)
        self.padding_side = padding_side

    def _pad(self, seqs: list[torch.Tensor], value: int) -> torch.Tensor:
        return pad_sequence(seqs, batch_first=True, padding_value=value, padding_side=self.padding_side)

    def __call__(self, items: list[dict]) -> dict:
        """Batch encoded examples."""
        batch = {"input_ids": self._pad([it["input_ids"] for it in items], self.pad_token_id),
                 "attention_mask": self._pad([it["attention_mask"] for it in items], 0)}
        if "labels" in items[0]:
            batch["labels"] = self._pad([it["labels"] for it in items], -100)
        pix = [it["pixel_values"] for it in items]
        if pix[0].ndim == 4:  # LLaVA-NeXT: (tiles, 3, H, W)
            batch["pixel_values"] = pad_sequence(pix, batch_first=True)
        else:
            batch["pixel_values"] = torch.stack(pix)
        if "image_sizes" in items[0]:
            batch["image_sizes"] = torch.stack([torch.as_tensor(it["image_sizes"]) for it in items])
        return batch
