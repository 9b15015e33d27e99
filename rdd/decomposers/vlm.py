"""VLM-prompt baseline: show a vision-language model the (subsampled) demonstration frames and ask
for the keyframe indices, as the RDD paper's prompt does.

Backends (``rdd.labelers.vlm_backends``, shared with the VLM labeler): an OpenAI-compatible
``/chat/completions`` endpoint and a local transformers VLM checkpoint.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import Any

from rdd.checks import whole
from rdd.data.episode import Episode
from rdd.decomposers.base import Decomposer, Decomposition
from rdd.errors import InputError
from rdd.labelers.vlm_backends import (
    VLMBackend,
    VLMError,
    check_backend_options,
    make_backend,
    resize_max_side,
    subsample_indices,
)
from rdd.registry import register
from rdd.segments import keyframes_to_segments

PROMPT = (
    "There is a robot doing a task, which can be segmented into multiple steps. "
    "The task is: {goal}. "
    "Below are {num_frames} frames of the robot doing the task, in temporal order; "
    "each image is preceded by its frame index. "
    "A keyframe is a frame where the robot finishes one step (sub-task) and the next step begins. "
    "Please return a list of indices of the keyframes, for example [3, 8, 14], "
    "where the frame index starts from 0."
)
# The decomposer's own options, named beside the backend's when an option is unknown.
OWN_OPTIONS = ("backend", "view", "max_frames", "max_side", "prompt")
_INT_LIST = re.compile(r"\[\s*(-?\d+(?:\s*,\s*-?\d+)*)\s*,?\s*\]")


def parse_keyframe_indices(text: str, num_shown: int) -> list[int]:
    """The first bracketed list of integers in ``text``, clamped to [0, num_shown-1], sorted, unique."""
    match = _INT_LIST.search(text or "")
    if match is None:
        raise VLMError(f"the VLM answer holds no list of integers: {text[:200]!r}")
    values = [int(v) for v in match.group(1).split(",")]
    clamped = sorted({min(max(v, 0), num_shown - 1) for v in values})
    if not clamped:
        raise VLMError(f"the VLM answer has no usable frame index: {text[:200]!r}")
    return clamped


@register("decomposer", "vlm")
class VLMDecomposer(Decomposer):
    """Asks a VLM for keyframes among up to ``max_frames`` evenly subsampled frames of one view."""

    name = "vlm"
    OPTION_RULES = {"max_frames": whole(2), "max_side": whole(1, allow_none=True)}

    @classmethod
    def check_options(cls, **options: Any) -> dict[str, Any]:
        """Its own options' ranges and, for a backend given by name, the backend's options."""
        own = {"backend", "view", "views", "max_frames", "max_side", "prompt"}
        opts = super().check_options(**{k: v for k, v in options.items() if k in own})
        prompt = opts.get("prompt", PROMPT)
        if not isinstance(prompt, str) or "{num_frames}" not in prompt:
            raise InputError(f"{cls.option_owner()}: option prompt must contain {{num_frames}}", option="prompt")
        backend_options = {k: v for k, v in options.items() if k not in own}
        backend = opts.get("backend", "openai")
        if isinstance(backend, str):
            check_backend_options(backend, OWN_OPTIONS, **backend_options)
        elif backend_options:
            raise InputError("backend options apply only when backend is given by name", option="backend")
        return {**opts, **backend_options}

    def __init__(
        self,
        backend: str | VLMBackend = "openai",
        view: str | None = None,
        views: Sequence[str] | None = None,
        max_frames: int = 16,
        max_side: int | None = 256,
        prompt: str = PROMPT,
        **backend_options: Any,
    ):
        opts = self.check_options(backend=backend, max_frames=max_frames, max_side=max_side, prompt=prompt,
                                  **backend_options)
        self.backend = make_backend(backend, **backend_options) if isinstance(backend, str) else backend
        self.view = view or (views[0] if views else None)
        self.max_frames, self.max_side = opts["max_frames"], opts["max_side"]
        self.prompt = prompt

    def decompose(self, episode: Episode) -> Decomposition:
        """Keyframes from the VLM's answer, mapped back to the episode's frame indices."""
        view = self.view or ("front" if "front" in episode.views else next(iter(episode.views), None))
        if view is None:
            raise ValueError(f"episode {episode.name!r} has no camera view for the VLM")
        shown = subsample_indices(episode.num_frames, self.max_frames)
        images = resize_max_side(episode.frames(view, shown), self.max_side)
        prompt = self.prompt.format(goal=episode.goal or "unknown", num_frames=len(shown))
        labels = [f"Frame {j}:" for j in range(len(shown))]
        answer = self.backend.ask(prompt, images, labels)
        try:
            picked = parse_keyframe_indices(answer, len(shown))
        except VLMError as exc:
            raise VLMError(f"episode {episode.name!r}: {exc}") from None
        keyframes = sorted({int(shown[j]) for j in picked})
        return Decomposition(
            segments=keyframes_to_segments(keyframes, episode.num_frames),
            meta={"answer": answer, "shown_frames": shown.tolist(), "picked": picked,
                  "backend": self.backend.name, "view": view},
        )
