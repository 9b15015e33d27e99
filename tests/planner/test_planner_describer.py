"""Describe, then plan: a finetuned planner may share the loaded base as its scene describer."""

import pytest
import torch

pytest.importorskip("peft")
pytest.importorskip("accelerate")

from synthetic_world import make_episodes  # noqa: E402

from planner.captions import CAPTION_QUESTION  # noqa: E402
from planner.config import PlannerConfig  # noqa: E402
from planner.dataset import PlannerExample  # noqa: E402
from planner.planner import VLMPlanner  # noqa: E402
from planner.train import finetune_lora, pretrain_base, training_examples  # noqa: E402


def _captions(examples: list[PlannerExample]) -> list[PlannerExample]:
    """A caption example per planner example's image (the text only needs to be learnable)."""
    return [PlannerExample(image=e.image, goal="", previous_instruction=None, target=f"the scene of {e.task}.",
                           task=e.task, episode=e.episode, frame=e.frame, question=CAPTION_QUESTION)
            for e in examples]


def test_shared_describer_captions_each_image_once_and_answers_the_same(tmp_path, monkeypatch):
    torch.set_num_threads(1)
    cfg = PlannerConfig(kind="tiny_llava", vocab_size=400, max_new_tokens=16, describe_scene=True,
                        pretrain=dict(lr=5e-3, epochs=4, batch_size=8, caption_frame_stride=8),
                        finetune=dict(lr=1e-2, epochs=2, batch_size=4), lora=dict(r=4, alpha=8, dropout=0.0))
    pre = training_examples(make_episodes(["pick_and_lift"], range(2)), cfg.pretrain)
    base_dir = pretrain_base(cfg, pre, tmp_path / "base", captions=_captions(pre), progress=False)
    tune = training_examples(make_episodes(["push_buttons"], [100]), cfg.finetune)
    adapter = finetune_lora(cfg, base_dir, tune, tmp_path / "lora", seed=0, progress=False)

    asked: list[int] = []
    base = VLMPlanner(cfg, base_dir)
    predict = base.predict

    def counting(queries, *args, **kwargs):
        asked.extend(1 for q in queries if len(q) > 3 and q[3] == CAPTION_QUESTION)
        return predict(queries, *args, **kwargs)

    monkeypatch.setattr(base, "predict", counting)
    shared = VLMPlanner(cfg, base_dir, adapter, describer=base)
    images = {e.image.tobytes() for e in tune}
    base_preds, _ = base.hits(tune)
    shared_preds, _ = shared.hits(tune)
    assert len(asked) == len(images)  # the second planner's scenes came from the first's captions
    own_preds, _ = VLMPlanner(cfg, base_dir, adapter).hits(tune)  # its own copy of the base describing
    assert shared_preds == own_preds
    assert base_preds == VLMPlanner(cfg, base_dir).hits(tune)[0]
    with pytest.raises(ValueError, match="describer must be a base planner"):
        VLMPlanner(cfg, base_dir, adapter, describer=shared)
