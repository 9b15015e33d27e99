"""VLM labeler: a vision-language model names each segment from a few of its frames.

For a segment ``[start, end)`` it shows the model ``frames`` evenly spaced frames of the segment
(first and last included) of every view the episode has, or of the one chosen by ``view``, and asks
for one short imperative instruction. The model is reached through ``rdd.labelers.vlm_backends``, the
backends the VLM decomposer uses: an OpenAI-compatible chat-completions endpoint or a local
transformers checkpoint. A failed call (unreachable endpoint, HTTP error, malformed payload) and an
answer that is empty or not one short instruction are :class:`~rdd.labelers.vlm_backends.VLMError`, one line
naming the endpoint and the segment; nothing is guessed in its place.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from rdd.checks import check_options, whole
from rdd.data.episode import Episode
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
from rdd.segments import Segment

PROMPT = (
    "A robot is doing the task: {goal}. "
    "Below are {num_frames} frames of one step of it, in temporal order ({views}); "
    "each image is preceded by its frame number and camera. "
    "Reply with one short imperative instruction that names this step, for example "
    "\"pick up the red cup\", and nothing else."
)
PROMPT_FIELDS = ("goal", "num_frames", "views")
OWN_OPTIONS = ("backend", "view", "frames", "max_side", "max_words", "prompt")
# Wrapping a model may put around its one line: quotes, code fences, a list bullet.
_STRIP = " \t\"'`*-•"


def instruction_from_answer(text: str, max_words: int) -> str:
    """The instruction in a model's answer: its only non-empty line, without quotes, bullets or a final
    period. Raises :class:`VLMError` for an empty answer, several lines or more than ``max_words`` words."""
    lines = [ln.strip(_STRIP) for ln in str(text or "").splitlines()]
    lines = [ln for ln in lines if ln and not ln.startswith("```")]
    if not lines:
        raise VLMError(f"the answer is empty: {str(text)[:200]!r}")
    if len(lines) > 1:
        raise VLMError(f"the answer is {len(lines)} lines, not one instruction: {str(text)[:200]!r}")
    line = lines[0].rstrip(".").strip(_STRIP)
    if line.lower().startswith("instruction:"):
        line = line.split(":", 1)[1].strip(_STRIP)
    if not line:
        raise VLMError(f"the answer is empty: {str(text)[:200]!r}")
    words = len(line.split())
    if words > max_words:
        raise VLMError(f"the answer is {words} words, not a short instruction (option max_words={max_words}): "
                       f"{line[:200]!r}")
    return line


@register("labeler", "vlm")
class VLMLabeler:
    """Names intervals with a VLM's one-line instruction for a few frames of each."""

    name = "vlm"
    OPTION_RULES = {"frames": whole(1), "max_side": whole(1, allow_none=True), "max_words": whole(1)}

    @classmethod
    def check_options(cls, **options: Any) -> dict[str, Any]:
        """Its own options' ranges and, for a backend given by name, the backend's options."""
        own = {k: v for k, v in options.items() if k in OWN_OPTIONS}
        opts = check_options("labeler vlm", cls.OPTION_RULES,
                             {k: v for k, v in own.items() if k in cls.OPTION_RULES})
        prompt = own.get("prompt", PROMPT)
        if not isinstance(prompt, str):
            raise InputError(f"labeler vlm: option prompt must be text, got {prompt!r}", option="prompt")
        try:
            prompt.format(**{f: "" for f in PROMPT_FIELDS})
        except (KeyError, IndexError, ValueError) as exc:
            raise InputError(f"labeler vlm: option prompt {prompt[:80]!r}: {exc!r}; its fields are "
                             + ", ".join("{" + f + "}" for f in PROMPT_FIELDS), option="prompt") from None
        view = own.get("view")
        if view is not None and not isinstance(view, str):
            raise InputError(f"labeler vlm: option view must be a view name or null, got {view!r}", option="view")
        backend = own.get("backend", "openai")
        backend_options = {k: v for k, v in options.items() if k not in OWN_OPTIONS}
        if isinstance(backend, str):
            check_backend_options(backend, OWN_OPTIONS, **backend_options)
        elif backend_options:
            raise InputError("labeler vlm: backend options apply only when backend is given by name",
                             option="backend")
        return {**own, **opts, **backend_options}

    def __init__(
        self,
        backend: str | VLMBackend = "openai",
        view: str | None = None,
        frames: int = 4,
        max_side: int | None = 256,
        max_words: int = 16,
        prompt: str = PROMPT,
        **backend_options: Any,
    ) -> None:
        opts = self.check_options(backend=backend, view=view, frames=frames, max_side=max_side,
                                  max_words=max_words, prompt=prompt, **backend_options)
        self.backend = make_backend(backend, OWN_OPTIONS, **backend_options) if isinstance(backend, str) else backend
        self.view = view
        self.frames, self.max_side, self.max_words = opts["frames"], opts["max_side"], opts["max_words"]
        self.prompt = prompt

    @property
    def where(self) -> str:
        """The model this labeler asks: the endpoint's URL, or the backend's name."""
        return str(getattr(self.backend, "url", None) or getattr(self.backend, "name", type(self.backend).__name__))

    def _views(self, episode: Episode) -> list[str]:
        if self.view is not None:
            if self.view not in episode.views:
                raise InputError(f"labeler vlm: option view={self.view!r}: episode {episode.name!r} has the views "
                                 f"{sorted(episode.views)}", option="view")
            return [self.view]
        if not episode.views:
            raise InputError(f"labeler vlm: episode {episode.name!r} has no camera view to show the VLM")
        return list(episode.views)

    def shown_frames(self, segment: Segment) -> np.ndarray:
        """Frame indices shown for ``segment``: up to ``frames`` evenly spaced, first and last included."""
        start, end = int(segment[0]), int(segment[1])
        if end <= start:
            raise ValueError(f"labeler vlm: empty segment [{start}, {end})")
        if self.frames == 1:
            return np.array([(start + end - 1) // 2])
        return start + subsample_indices(end - start, self.frames)

    def label(self, episode: Episode, segment: Segment) -> str:
        """The VLM's instruction for frames ``[start, end)``."""
        return self.label_all(episode, [segment])[0]

    def label_all(self, episode: Episode, segments: Sequence[Segment]) -> list[str]:
        """Instructions of several intervals of one episode (each view's frames read once)."""
        views = self._views(episode)
        shown = [self.shown_frames(s) for s in segments]
        wanted = np.unique(np.concatenate(shown)) if shown else np.zeros(0, dtype=np.int64)
        images = {}
        for v in views:
            loaded = resize_max_side(episode.frames(v, wanted), self.max_side)
            images[v] = dict(zip(wanted.tolist(), loaded, strict=True))
        return [self._ask(episode, seg, idx, views, images) for seg, idx in zip(segments, shown, strict=True)]

    def _ask(self, episode: Episode, segment: Segment, idx: np.ndarray, views: list[str],
             images: dict[str, dict[int, np.ndarray]]) -> str:
        pics, labels = [], []
        for j, f in enumerate(idx.tolist()):
            for v in views:
                pics.append(images[v][f])
                labels.append(f"Frame {j + 1} ({v}):")
        prompt = self.prompt.format(goal=episode.goal or episode.task or "unknown", num_frames=len(idx),
                                    views=", ".join(views))
        where = f"VLM labeler, episode {episode.name!r} segment [{int(segment[0])}, {int(segment[1])})"
        try:
            answer = self.backend.ask(prompt, pics, labels)
        except VLMError as exc:  # it names the endpoint
            raise VLMError(f"{where}: {exc}") from None
        try:
            return instruction_from_answer(answer, self.max_words)
        except VLMError as exc:
            raise VLMError(f"{where}: {self.where}: {exc}") from None
