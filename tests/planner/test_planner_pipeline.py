"""End to end: pretrain a tiny base, LoRA-finetune it, save, load, and query the planner."""

import json

import numpy as np
import pytest
import torch

pytest.importorskip("peft")
pytest.importorskip("accelerate")

from synthetic_world import make_episodes  # noqa: E402

from planner.config import PlannerConfig  # noqa: E402
from planner.planner import VLMPlanner  # noqa: E402
from planner.train import finetune_lora, pretrain_base, training_examples  # noqa: E402


def _cfg(kind: str) -> PlannerConfig:
    return PlannerConfig(
        kind=kind, vocab_size=400, max_new_tokens=16,
        pretrain=dict(lr=5e-3, epochs=15, batch_size=8, warmup_ratio=0.1),
        # LLaVA-NeXT's AnyRes tiles learn the 4 examples more slowly: at 60 epochs it recalled 2 of 4
        # on this machine's CPU (a red/blue swap) even at the commit where it once passed; 120 give 3-4
        finetune=dict(lr=1e-2, epochs=120 if kind == "tiny_llava_next" else 60, batch_size=4, warmup_ratio=0.1),
        lora=dict(r=8, alpha=16, dropout=0.0))


@pytest.mark.parametrize("kind", ["tiny_llava", pytest.param("tiny_llava_next", marks=pytest.mark.slow)])
def test_pretrain_finetune_save_load_infer(tmp_path, kind):
    torch.set_num_threads(1)
    cfg = _cfg(kind)
    pre = training_examples(make_episodes(["pick_and_lift", "push_button"], range(4)), cfg.pretrain)
    demos = make_episodes(["push_buttons"], [100])
    tune = training_examples(demos, cfg.finetune)

    base = pretrain_base(cfg, pre, tmp_path / "base", progress=False)
    assert (base / "model.safetensors").is_file() and (base / "tokenizer.json").is_file()
    adapter = finetune_lora(cfg, base, tune, tmp_path / "lora", seed=1, progress=False)
    assert (adapter / "adapter_model.safetensors").is_file()
    meta = json.loads((adapter / "planner_config.json").read_text())
    assert meta["config"]["lora"]["r"] == 8 and meta["seed"] == 1

    # only the language model's attention and the projector were adapted, never the vision tower
    from safetensors.torch import load_file

    keys = list(load_file(str(adapter / "adapter_model.safetensors")))
    assert any("lora_A" in k and "language_model" in k for k in keys)
    assert any("multi_modal_projector" in k for k in keys)
    assert not any("vision_tower" in k for k in keys)

    # a folder that already holds a trained planner is never overwritten (the stage cache decides
    # when to train; these functions just write where they are told)
    before = (adapter / "adapter_model.safetensors").read_bytes()
    with pytest.raises(FileExistsError, match="already holds"):
        finetune_lora(cfg, base, tune, adapter, seed=2, progress=False)
    with pytest.raises(FileExistsError, match="already holds"):
        pretrain_base(cfg, pre, base, progress=False)
    assert (adapter / "adapter_model.safetensors").read_bytes() == before

    tuned = VLMPlanner(cfg, base, adapter)
    plain = VLMPlanner(cfg, base)
    ex = tune[1]
    out = tuned.next_instruction(ex.image, ex.goal, ex.previous_instruction)
    assert isinstance(out, str) and out.strip() == out and out
    first = tuned.next_instruction(np.zeros((64, 64, 3), np.uint8), "press the red button", None)
    assert isinstance(first, str) and first
    # the finetuned planner reproduces the demonstrations it was finetuned on; the base
    # (never shown push_buttons) does not say the second button's steps
    tuned_acc = tuned.exact_match(tune)
    assert tuned_acc >= 0.75
    assert tuned_acc > plain.exact_match(tune)
