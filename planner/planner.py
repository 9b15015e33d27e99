"""Inference: the planner says the next sub-task instruction from image, goal and previous instruction."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from planner.config import PlannerConfig
from planner.dataset import PlannerCollator, PlannerExample, encode_prompt
from planner.models import load_model
from planner.prompts import clean_output


class Planner:
    """A base LLaVA planner, optionally with a LoRA adapter, queried greedily with bounded length."""

    def __init__(self, cfg: PlannerConfig, base_dir: str | Path, adapter_dir: str | Path | None = None,
                 device: str | None = None):
        self.cfg = cfg
        self.device = device or ("cuda" if torch.cuda.is_available() else "cpu")
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
        self.empty_outputs = 0  # how often a generation was empty and the fallback was used

    @torch.no_grad()
    def predict(self, queries: Sequence[tuple[np.ndarray, str, str | None]],
                batch_size: int = 16) -> list[str]:
        """Next instruction for each (image, goal, previous_instruction)."""
        out: list[str] = []
        tok = self.processor.tokenizer
        for i in range(0, len(queries), batch_size):
            chunk = queries[i: i + batch_size]
            items = [encode_prompt(self.processor, img, goal, prev) for img, goal, prev in chunk]
            batch = self._collate(items)
            batch = {k: v.to(self.device) for k, v in batch.items()}
            if "pixel_values" in batch:
                batch["pixel_values"] = batch["pixel_values"].to(self.model.dtype)
            gen = self.model.generate(**batch, max_new_tokens=self.cfg.max_new_tokens,
                                      do_sample=False, num_beams=1, eos_token_id=self._stop,
                                      pad_token_id=tok.pad_token_id)
            new = gen[:, batch["input_ids"].shape[1]:]
            for (_img, goal, prev), ids in zip(chunk, new, strict=True):
                text = clean_output(tok.decode(ids, skip_special_tokens=True))
                if not text:
                    # an empty answer carries no new sub-task: keep the robot on the previous one
                    # (or on the goal itself at the first step) so the policy always gets text
                    self.empty_outputs += 1
                    text = clean_output(prev) if prev else clean_output(goal)
                out.append(text)
        return out

    def next_instruction(self, image: np.ndarray, goal: str, previous_instruction: str | None) -> str:
        """The next sub-task instruction (greedy, at most ``max_new_tokens`` tokens)."""
        return self.predict([(image, goal, previous_instruction)])[0]

    def hits(self, examples: Sequence[PlannerExample],
             batch_size: int = 16) -> tuple[list[str], list[bool]]:
        """Predictions for ``examples`` and whether each equals its target (whitespace/full stop insensitive)."""
        preds = self.predict([(e.image, e.goal, e.previous_instruction) for e in examples],
                             batch_size=batch_size)
        return preds, [p == clean_output(e.target) for p, e in zip(preds, examples, strict=True)]

    def exact_match(self, examples: Sequence[PlannerExample], batch_size: int = 16) -> float:
        """Fraction of examples whose prediction equals the target (whitespace/full stop insensitive)."""
        if not examples:
            raise ValueError("exact_match needs at least one example")
        return float(np.mean(self.hits(examples, batch_size)[1]))
