"""Inference: the planner says the next sub-task instruction from image, goal and previous instruction."""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from planner.captions import CAPTION_MAX_TOKENS, CAPTION_QUESTION
from planner.config import PlannerConfig
from planner.dataset import PlannerCollator, PlannerExample, encode_prompt
from planner.interface import Planner
from planner.models import load_model
from planner.prompts import clean_output, state_text

CAPTION_MEMORY = 100_000  # captions a describer keeps (about 10 MB); past it, it starts afresh


class VLMPlanner(Planner):
    """A base LLaVA planner, optionally with a LoRA adapter, queried greedily with bounded length."""

    def __init__(self, cfg: PlannerConfig, base_dir: str | Path, adapter_dir: str | Path | None = None,
                 device: str | None = None, describer: VLMPlanner | None = None):
        self.cfg = cfg
        self.device = device or ("cuda" if torch.cuda.is_available() else "cpu")
        # describe_scene: the base (not the adapter, which never trained on captions) describes;
        # ``describer``, that base already loaded, saves a second copy and its captions' time.
        # A config naming another describer (cfg.describer) is given that one's loaded base.
        if cfg.describe_scene and describer is not None and describer._describer is not describer:
            raise ValueError("planner describer must be a base planner (no adapter) with describe_scene")
        if cfg.describer is not None and describer is None:
            raise ValueError("planner config names a describer: pass its loaded base as describer")
        self._describer = (None if not cfg.describe_scene else describer if describer is not None
                           else self if adapter_dir is None else VLMPlanner(cfg, base_dir, None, self.device))
        model, self.processor = load_model(base_dir, cfg, device=self.device)
        if adapter_dir is not None:
            from peft import PeftModel

            if not (Path(adapter_dir) / "adapter_config.json").is_file():
                raise FileNotFoundError(f"no LoRA adapter at {adapter_dir} (adapter_config.json missing)")
            # merged: inference runs at the base model's speed
            model = PeftModel.from_pretrained(model, str(adapter_dir)).merge_and_unload()
        self.model = model.to(self.device).eval()
        tok = self.processor.tokenizer
        self._collate = PlannerCollator(tok.pad_token_id, padding_side="left")
        self._stop = [i for i in {tok.eos_token_id, tok.convert_tokens_to_ids("<|eot_id|>")}
                      if isinstance(i, int) and i >= 0 and i != tok.unk_token_id]
        self._captions: dict[bytes, str] = {}  # describe()'s answers by image digest
        self.empty_outputs = 0  # how often a generation was empty and the fallback was used

    @torch.no_grad()
    def predict(self, queries: Sequence[tuple], batch_size: int = 16,
                max_new_tokens: int | None = None) -> list[str]:
        """Next instruction for each (image, goal, previous_instruction[, question[, state]]).

        A query with a question (a scene caption's) asks that instead of the planner prompt; with
        ``describe_scene`` the others state the planner's description of their image first; ``state``
        is the robot's state in words (stated only when the config reads it).
        """
        queries = [(*q, None, None)[:5] for q in queries]
        if not self.cfg.read_state:
            queries = [(*q[:4], None) for q in queries]
        scenes: list[str | None] = [None] * len(queries)
        ask = [i for i, q in enumerate(queries) if q[3] is None]
        if self._describer is not None and ask:
            for i, text in zip(ask, self._describer.describe([queries[i][0] for i in ask], batch_size),
                               strict=True):
                scenes[i] = text
        out: list[str] = []
        tok = self.processor.tokenizer
        for i in range(0, len(queries), batch_size):
            chunk = queries[i: i + batch_size]
            items = [encode_prompt(self.processor, img, goal, prev, question, scene, state)
                     for (img, goal, prev, question, state), scene
                     in zip(chunk, scenes[i: i + batch_size], strict=True)]
            batch = self._collate(items)
            batch = {k: v.to(self.device) for k, v in batch.items()}
            if "pixel_values" in batch:
                batch["pixel_values"] = batch["pixel_values"].to(self.model.dtype)
            gen = self.model.generate(**batch, max_new_tokens=max_new_tokens or self.cfg.max_new_tokens,
                                      do_sample=False, num_beams=1, eos_token_id=self._stop,
                                      pad_token_id=tok.pad_token_id)
            new = gen[:, batch["input_ids"].shape[1]:]
            for (_img, goal, prev, _question, _state), ids in zip(chunk, new, strict=True):
                text = clean_output(tok.decode(ids, skip_special_tokens=True))
                if not text:
                    # an empty answer carries no new sub-task: keep the robot on the previous one
                    # (or on the goal itself at the first step) so the policy always gets text
                    self.empty_outputs += 1
                    text = clean_output(prev) if prev else clean_output(goal)
                out.append(text)
        return out

    def describe(self, images: Sequence[np.ndarray], batch_size: int = 16) -> list[str]:
        """The model's scene caption of each image (``planner.captions``' question); an image seen
        before gets its caption back (greedy decoding gives the same text), so planners sharing
        this describer caption each image once."""
        keys = [hashlib.sha1(np.ascontiguousarray(img).tobytes() + str(np.shape(img)).encode()).digest()
                for img in images]
        todo = list(dict.fromkeys(k for k in keys if k not in self._captions))
        if todo:
            first = {k: img for k, img in zip(keys, images, strict=True)}
            texts = self.predict([(first[k], "", None, CAPTION_QUESTION) for k in todo], batch_size,
                                 max_new_tokens=CAPTION_MAX_TOKENS)
            if len(self._captions) + len(todo) > CAPTION_MEMORY:
                self._captions.clear()  # a long closed loop: bounded memory, recent images recaptioned
            self._captions.update(zip(todo, texts, strict=True))
        return [self._captions[k] for k in keys]

    def with_scenes(self, examples: Sequence[PlannerExample], batch_size: int = 16) -> list[PlannerExample]:
        """``examples`` whose prompts state this model's description of their images."""
        texts = self.describe([e.image for e in examples], batch_size)
        return [replace(e, scene=t) for e, t in zip(examples, texts, strict=True)]

    def next_instruction(self, image: np.ndarray, goal: str, previous_instruction: str | None,
                         state: Any = None) -> str:
        """The next sub-task instruction (greedy, at most ``max_new_tokens`` tokens); ``state``: the
        robot's (an observation's ``ee_pose`` and ``gripper_open``, or their words)."""
        return self.predict([(image, goal, previous_instruction, None, state_text(state))])[0]

    def hits(self, examples: Sequence[PlannerExample],
             batch_size: int = 16) -> tuple[list[str], list[bool]]:
        """Predictions for ``examples`` and whether each equals its target (whitespace/full stop insensitive)."""
        preds = self.predict([(e.image, e.goal, e.previous_instruction, e.question, e.state) for e in examples],
                             batch_size=batch_size)
        return preds, [p == clean_output(e.target) for p, e in zip(preds, examples, strict=True)]

    def exact_match(self, examples: Sequence[PlannerExample], batch_size: int = 16) -> float:
        """Fraction of examples whose prediction equals the target (whitespace/full stop insensitive)."""
        if not examples:
            raise ValueError("exact_match needs at least one example")
        return float(np.mean(self.hits(examples, batch_size)[1]))
