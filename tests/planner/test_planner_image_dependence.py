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
from planner.planner import Planner  # noqa: E402
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
    planner = Planner(cfg, base)

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
