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


def test_a_describer_config_is_checked_and_leaves_the_base_key_alone():
    own = dict(describe_scene=True, pretrain={"caption_frame_stride": 8})
    describer = PlannerConfig(**own)
    with pytest.raises(ValueError, match="describer needs describe_scene"):
        PlannerConfig(describer=describer)
    with pytest.raises(ValueError, match="describes scenes itself"):
        PlannerConfig(**own, describer=PlannerConfig())
    with pytest.raises(ValueError, match="describes scenes itself"):
        PlannerConfig(**own, describer=PlannerConfig(**own, describer=describer))
    cfg = PlannerConfig(kind="smollm2_llava", **own, describer=describer.to_dict())
    assert cfg.describer == describer
    assert PlannerConfig.from_dict(cfg.to_dict()) == cfg  # as a base folder saves and reads it
    # the base trains on the simulator's true captions, whoever describes at run time
    assert cfg.model_dict() == PlannerConfig(kind="smollm2_llava", **own).model_dict()


def test_another_models_base_describes_for_the_planner_and_its_finetune(tmp_path, monkeypatch):
    import planner.train as train_module
    from planner.llava import SmolLlava, TinyLlava

    torch.set_num_threads(1)
    own = dict(vocab_size=400, max_new_tokens=16, describe_scene=True,
               pretrain=dict(lr=5e-3, epochs=2, batch_size=8, caption_frame_stride=8),
               finetune=dict(lr=1e-2, epochs=1, batch_size=4), lora=dict(r=4, alpha=8, dropout=0.0))
    describer_cfg = PlannerConfig(kind="tiny_llava", **own)
    cfg = PlannerConfig(kind="tiny_llava", **own, describer=describer_cfg)
    pre = training_examples(make_episodes(["pick_and_lift"], range(2)), cfg.pretrain)
    base_dir = pretrain_base(cfg, pre, tmp_path / "base", captions=_captions(pre), progress=False)

    said = "the one thing the describer says."
    describer = VLMPlanner(describer_cfg, base_dir)
    monkeypatch.setattr(describer, "describe", lambda images, batch_size=16: [said] * len(images))
    with pytest.raises(ValueError, match="names a describer"):
        VLMPlanner(cfg, base_dir)
    stated: list = []
    import planner.planner as planner_module

    encode = planner_module.encode_prompt
    monkeypatch.setattr(planner_module, "encode_prompt", lambda *a: stated.append(a[5]) or encode(*a))
    tune = training_examples(make_episodes(["push_buttons"], [100]), cfg.finetune)
    VLMPlanner(cfg, base_dir, describer=describer).hits(tune)
    assert stated == [said] * len(tune)

    # the finetune trains on what the describer states (a TinyLlava: LlavaPlanner's class for the kind)
    learned = TinyLlava(**{k: v for k, v in cfg.to_dict().items() if k != "kind"})
    assert isinstance(learned.describer(), TinyLlava) and learned.describer().config == describer_cfg
    assert SmolLlava(**own, describer=learned.describer()).config.describer == describer_cfg
    trained: list = []
    monkeypatch.setattr(train_module, "finetune_lora", lambda cfg, base, examples, out, **kw: trained.extend(examples))
    episodes = make_episodes(["push_buttons"], [100])
    with pytest.raises(ValueError, match="describer's loaded base"):
        learned.finetune(base_dir, episodes, tmp_path / "lora", seed=0, progress=False)
    learned.finetune(base_dir, episodes, tmp_path / "lora", seed=0, progress=False, describer=describer)
    assert trained and {e.scene for e in trained} == {said}
