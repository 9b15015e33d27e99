"""The planner reads its image: same goal and previous instruction, different image -> different answer.

Smoke scale, on the rendered synthetic world (planner.synthetic), whose drawer tasks make the first
step depend on what only the image shows: which side the drawer is on. Held-out scenes, so the
answer cannot be recalled from a training example.
"""

import numpy as np
import pytest
import torch

pytest.importorskip("peft")
pytest.importorskip("accelerate")

from synthetic_world import make_episode, make_episodes  # noqa: E402

from planner.config import PlannerConfig  # noqa: E402
from planner.planner import VLMPlanner  # noqa: E402
from planner.train import pretrain_base, training_examples  # noqa: E402


def _first_step_scene(side: str, seeds) -> tuple[np.ndarray, str]:
    """The first frame and goal of a held-out open_drawer scene with the drawer on ``side``."""
    for seed in seeds:
        ep = make_episode("open_drawer", seed)
        if ep.instructions[0].endswith(f"on the {side}"):
            return ep.frames("front", [0])[0], ep.goal
    raise AssertionError(f"no open_drawer scene with the drawer on the {side} among seeds {seeds}")


def test_same_text_different_image_gives_a_different_next_instruction(tmp_path):
    torch.set_num_threads(1)
    # lr 2e-3: at 3e-3 the base collapsed to one side on one machine of this kind (0.33 on the
    # held-out scenes) and learnt it on another; at 2e-3, 40/40 with pretraining seeds 0, 1 and 2
    cfg = PlannerConfig(kind="tiny_llava", vocab_size=400, max_new_tokens=16,
                        pretrain=dict(lr=2e-3, epochs=25, batch_size=8, warmup_ratio=0.1))
    # One task: mixed with pick_and_lift at this budget the tiny base had not yet learnt the side
    # (0.33 on the held-out scenes, measured), on its own it has (40/40).
    train = make_episodes(["open_drawer"], range(48))
    base = pretrain_base(cfg, training_examples(train, cfg.pretrain), tmp_path / "base", progress=False)
    planner = VLMPlanner(cfg, base)

    held_out = range(1000, 1040)
    answers = {}
    for side in ("left", "right"):
        image, goal = _first_step_scene(side, held_out)
        # The same text for both images: the goal of the left scene, no previous instruction.
        answers[side] = planner.next_instruction(image, _first_step_scene("left", held_out)[1], None)
    assert answers["left"] != answers["right"], answers
    assert answers["left"] == "move to the drawer handle on the left"
    assert answers["right"] == "move to the drawer handle on the right"

    # And over many held-out scenes, the side named is the side drawn (not one answer for all).
    hits = []
    for seed in held_out:
        ep = make_episode("open_drawer", seed)
        said = planner.next_instruction(ep.frames("front", [0])[0], ep.goal, None)
        hits.append(said == ep.instructions[0])
    assert np.mean(hits) >= 0.9, hits


@pytest.mark.slow
def test_smollm2_planner_reads_the_image(tmp_path, monkeypatch):
    """The pretrained planner (SmolLM2 inside LLaVA): same text, drawer drawn left or right -> the
    side drawn, on held-out scenes, after a smoke-scale base and LoRA finetune on the first steps."""
    import importlib.util

    from planner import smollm2
    from planner.train import finetune_lora

    if importlib.util.find_spec(smollm2.PACKAGE) is None:
        pytest.skip(f"SmolLM2 is not installed: {smollm2.INSTALL_LINE}")
    monkeypatch.setenv("RDD_CACHE_DIR", str(tmp_path / "cache"))
    cfg = PlannerConfig(kind="smollm2_llava", vision_tower="effnet_lite0_mid", image_size=224,
                        patch_size=32, max_new_tokens=12,
                        align=dict(lr=1e-3, epochs=2, batch_size=8),
                        pretrain=dict(lr=5e-5, epochs=1, batch_size=8),
                        finetune=dict(lr=1e-3, epochs=6, batch_size=8),
                        lora=dict(r=8, alpha=16, dropout=0.0))
    # the first step only: its text (goal, no previous instruction) never tells the side
    first = [ex for ex in training_examples(make_episodes(["open_drawer"], range(40), image_size=224),
                                            cfg.pretrain)
             if ex.previous_instruction is None]
    assert {ex.target for ex in first} == {f"move to the drawer handle on the {s}" for s in ("left", "right")}
    base = pretrain_base(cfg, first, tmp_path / "base", progress=False)
    adapter = finetune_lora(cfg, base, first, tmp_path / "lora", seed=0, progress=False)
    planner = VLMPlanner(cfg, base, adapter)

    held_out = range(1000, 1030)
    goal = make_episode("open_drawer", 1000, image_size=224).goal
    answers = {}
    for side in ("left", "right"):
        for seed in held_out:
            ep = make_episode("open_drawer", seed, image_size=224)
            if ep.instructions[0].endswith(f"on the {side}"):
                answers[side] = planner.next_instruction(ep.frames("front", [0])[0], goal, None)
                break
    assert answers == {s: f"move to the drawer handle on the {s}" for s in ("left", "right")}, answers
    hits = [planner.next_instruction(ep.frames("front", [0])[0], ep.goal, None) == ep.instructions[0]
            for ep in (make_episode("open_drawer", s, image_size=224) for s in held_out)]
    assert np.mean(hits) >= 0.9, hits
