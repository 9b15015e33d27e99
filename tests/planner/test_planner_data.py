"""Planner prompts, examples from decomposed episodes, collation with prompt-masked labels, config."""

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("transformers")
pytest.importorskip("tokenizers")

from synthetic_world import EVAL_TASKS, PRETRAIN_TASKS, make_episode  # noqa: E402

from planner.config import PlannerConfig  # noqa: E402
from planner.dataset import PlannerCollator, encode_example, examples_from_episode  # noqa: E402
from planner.models import build_processor, load_model, train_tokenizer  # noqa: E402
from planner.prompts import clean_output, render_prompt, render_target, user_prompt  # noqa: E402
from rdd.data.episode import Episode  # noqa: E402

CONF = Path(__file__).resolve().parents[2] / "conf" / "planner"


def _episode() -> Episode:
    # frame t is filled with the value t, so each example's image says which frame it came from
    frames = np.stack([np.full((8, 8, 3), t, dtype=np.uint8) for t in range(10)])
    return Episode(name="ep", views={"front": frames}, goal="stack the red block on the blue block",
                   segments=[(0, 3), (3, 7), (7, 10)],
                   instructions=["move to the red block", "grasp the red block", "lift it"])


def test_one_example_per_segment_start_with_previous_instruction():
    ex = examples_from_episode(_episode())
    assert [e.frame for e in ex] == [0, 3, 7]
    assert [int(e.image[0, 0, 0]) for e in ex] == [0, 3, 7]
    assert [e.previous_instruction for e in ex] == [None, "move to the red block",
                                                    "grasp the red block"]
    assert [e.target for e in ex] == ["move to the red block", "grasp the red block", "lift it"]


def test_inner_frames_keep_their_segment_instruction():
    ex = examples_from_episode(_episode(), include_inner_frames=True)
    assert [e.frame for e in ex] == list(range(10))
    seg_of = [0, 0, 0, 1, 1, 1, 1, 2, 2, 2]
    names = _episode().instructions
    assert [e.target for e in ex] == [names[s] for s in seg_of]
    assert [e.previous_instruction for e in ex] == [None if s == 0 else names[s - 1] for s in seg_of]


def test_inner_frame_stride_counts_from_each_segment_start():
    ex = examples_from_episode(_episode(), include_inner_frames=True, inner_frame_stride=2)
    # segments (0, 3), (3, 7), (7, 10): every 2nd frame of each, its start always included
    assert [e.frame for e in ex] == [0, 2, 3, 5, 7, 9]
    assert [e.target for e in ex] == ["move to the red block"] * 2 + ["grasp the red block"] * 2 + [
        "lift it"] * 2
    with pytest.raises(ValueError, match="inner_frame_stride"):
        examples_from_episode(_episode(), include_inner_frames=True, inner_frame_stride=0)


def test_ambiguous_frame_stride_adds_inner_frames_of_image_decided_segments_only():
    from planner.config import TrainSettings
    from planner.train import training_examples

    frames = np.stack([np.full((8, 8, 3), t, dtype=np.uint8) for t in range(20)])
    # "lift" precedes both "above the plate" and "above the stack": only the image decides
    names = ["lift", "above the plate", "place", "lift", "above the stack", "place"]
    ep = Episode(name="ep", views={"front": frames}, goal="stack two blocks",
                 segments=[(0, 2), (2, 6), (6, 8), (8, 10), (10, 16), (16, 20)], instructions=names)
    plain = training_examples([ep], TrainSettings())
    assert [e.frame for e in plain] == [0, 2, 6, 8, 10, 16]
    more = training_examples([ep], TrainSettings(ambiguous_frame_stride=2))
    extra = more[len(plain):]
    # inner frames of (2, 6) and (10, 16) only, every 2nd from each start, starts not repeated
    assert [e.frame for e in extra] == [4, 12, 14]
    assert [e.target for e in extra] == ["above the plate", "above the stack", "above the stack"]
    assert all(e.previous_instruction == "lift" for e in extra)
    assert [int(e.image[0, 0, 0]) for e in extra] == [4, 12, 14]
    with pytest.raises(ValueError, match="ambiguous_frame_stride"):
        TrainSettings(ambiguous_frame_stride=-1)


def test_decomposer_segmentation_overrides_expert_and_is_validated():
    ex = examples_from_episode(_episode(), [(0, 5), (5, 10)], ["a", "b"])
    assert [(e.frame, e.previous_instruction, e.target) for e in ex] == [(0, None, "a"), (5, "a", "b")]
    with pytest.raises(ValueError, match="segments but"):
        examples_from_episode(_episode(), [(0, 5), (5, 10)], ["a"])
    with pytest.raises(ValueError, match="must end at 10"):
        examples_from_episode(_episode(), [(0, 5), (5, 9)], ["a", "b"])


def test_prompts_follow_racer_wording():
    first = user_prompt("open the drawer", None)
    later = user_prompt("open the drawer", "grasp the handle")
    assert first.startswith("<image>\nThe task goal is: open the drawer.")
    assert "about to start the task" in first and "previous step" not in first
    assert ("In the previous step, the robot arm was given the following instruction: "
            "grasp the handle.") in later
    assert later.endswith("what's the next instruction for the robot?")
    assert clean_output("  pull the drawer open.\nUSER: junk") == "pull the drawer open"
    with pytest.raises(ValueError, match="goal"):
        user_prompt("  ", None)


@pytest.fixture(scope="module")
def processor():
    eps = [make_episode(t, s) for t in PRETRAIN_TASKS + EVAL_TASKS for s in range(2)]
    corpus = [user_prompt(e.goal, None) for e in eps] + [i for e in eps for i in e.instructions]
    tok = train_tokenizer(corpus, vocab_size=400)
    return build_processor(PlannerConfig(kind="tiny_llava"), tok)


def test_tokenizer_round_trips_and_target_follows_prompt(processor):
    tok = processor.tokenizer
    text = "move the yellow block above the bin"
    assert tok.decode(tok(text, add_special_tokens=False)["input_ids"]) == text
    prompt = render_prompt(tok, "pick up the red block", None)
    answer = render_target(tok, "pick up the red block", None, text)
    assert prompt.startswith(tok.bos_token + "USER: <image>\nThe task goal is: pick up the red block.")
    assert prompt.endswith("ASSISTANT:")
    assert answer == " " + text + tok.eos_token


def test_collator_masks_prompt_and_counts_image_tokens(processor):
    ep = make_episode("put_in_bin", 5)
    items = [encode_example(processor, e) for e in examples_from_episode(ep)[:3]]
    batch = PlannerCollator(processor.tokenizer.pad_token_id)(items)
    tok = processor.tokenizer
    img_id = tok.convert_tokens_to_ids("<image>")
    # 64 px / 16 px patches = 16 patch tokens (CLIP's CLS is dropped by the "default" strategy)
    assert ((batch["input_ids"] == img_id).sum(1) == 16).all()
    assert batch["pixel_values"].shape == (3, 3, 64, 64)
    for i, ex in enumerate(examples_from_episode(ep)[:3]):
        lab = batch["labels"][i]
        learned = lab[lab != -100].tolist()
        assert tok.decode(learned, skip_special_tokens=True).strip() == ex.target
        assert learned[-1] == tok.eos_token_id
        # everything before the answer is masked, padding too
        first = int((lab != -100).nonzero()[0])
        assert (lab[:first] == -100).all()
        assert (batch["attention_mask"][i].sum() == len(items[i]["input_ids"]))


def test_llava_next_collator_keeps_image_sizes():
    eps = [make_episode("push_button", 1)]
    tok = train_tokenizer([i for e in eps for i in e.instructions] + [e.goal for e in eps], 300)
    proc = build_processor(PlannerConfig(kind="tiny_llava_next"), tok)
    items = [encode_example(proc, e) for e in examples_from_episode(eps[0])]
    batch = PlannerCollator(tok.pad_token_id)(items)
    assert batch["image_sizes"].tolist() == [[64, 64]] * len(items)
    assert batch["pixel_values"].ndim == 5


def test_yaml_configs_instantiate_and_reject_typos():
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    from planner.llava import LlavaPlanner

    for name in ("tiny_llava", "tiny_llava_next", "llava_next_8b"):
        planner = instantiate(OmegaConf.load(CONF / f"{name}.yaml"))  # the class fixes the model
        assert isinstance(planner, LlavaPlanner) and planner.config.kind == name
    big = instantiate(OmegaConf.load(CONF / "llava_next_8b.yaml")).config
    assert (big.lora.r, big.lora.alpha, big.finetune.lr, big.finetune.epochs) == (128, 256, 2e-5, 2)
    assert (big.finetune.schedule, big.finetune.warmup_ratio) == ("cosine", 0.08)
    with pytest.raises(ValueError, match="unknown option"):
        PlannerConfig.from_dict({"kind": "tiny_llava", "lora": {"rank": 4}})
    with pytest.raises(ValueError, match="kind"):
        PlannerConfig(kind="llava_13b")


def test_missing_8b_checkpoint_names_the_path(tmp_path):
    cfg = PlannerConfig(kind="llava_next_8b", checkpoint_path=str(tmp_path / "nowhere"))
    with pytest.raises(FileNotFoundError, match="nowhere"):
        load_model(tmp_path / "nowhere", cfg)
    from planner.train import pretrain_base

    with pytest.raises(FileNotFoundError, match="llama3-llava-next-8b"):
        pretrain_base(cfg, [], tmp_path)
