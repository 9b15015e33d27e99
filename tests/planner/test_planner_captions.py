"""Scene captions from the privileged record (planner.captions) and their place in training data."""

import numpy as np
import pytest

pytest.importorskip("transformers")
pytest.importorskip("tokenizers")

from planner.augment import slot_swap  # noqa: E402
from planner.captions import CAPTION_QUESTION, caption_examples, scene_caption  # noqa: E402
from planner.config import PlannerConfig  # noqa: E402
from planner.dataset import PlannerExample, encode_example, examples_fingerprint  # noqa: E402
from planner.models import build_processor, train_tokenizer  # noqa: E402
from rdd.data.episode import Episode  # noqa: E402

PLATE_TOP = 0.01
BLOCK = 0.05


def _meta(frames: int = 3) -> dict:
    """A plate, two red blocks and a drawer: frame 0 all apart, 1 one block held on the plate and the
    drawer open, 2 both blocks stacked on the plate."""
    objects = [{"name": "plate", "type": "plate", "color": "grey", "size": [0.1, 0.1, 0.01]},
               {"name": "red_block_0", "type": "block", "color": "red", "size": [BLOCK] * 3},
               {"name": "red_block_1", "type": "block", "color": "red", "size": [BLOCK] * 3}]
    pos = np.zeros((frames, 3, 3), np.float32)
    pos[:, 0] = (0.5, 0.0, 0.005)
    pos[0, 1], pos[0, 2] = (0.4, 0.2, 0.025), (0.4, -0.2, 0.025)
    # held, just grasped where it rests on the plate: a held object is never said to rest
    pos[1, 1], pos[1, 2] = (0.5, 0.0, PLATE_TOP + BLOCK / 2), (0.4, -0.2, 0.025)
    pos[2, 1] = (0.501, 0.002, PLATE_TOP + BLOCK / 2 + 0.003)  # settled a few mm off
    pos[2, 2] = (0.499, -0.003, PLATE_TOP + 1.5 * BLOCK)
    states = np.array([[0.0], [0.2], [0.05]], np.float32)[:frames]
    priv = {"object_positions": pos, "held_object": np.array([-1, 1, -1], np.int32)[:frames],
            "articulation_states": states[:, :1]}
    return {"objects": objects, "privileged": priv,
            "articulations": [{"name": "top_drawer", "kind": "drawer", "closed": 0.0, "open": 0.2}]}


def test_caption_states_what_rests_on_what_and_what_is_open():
    meta = _meta()
    assert scene_caption(meta, 0) == "the top drawer is shut."
    assert scene_caption(meta, 1) == "the top drawer is open."
    assert scene_caption(meta, 2) == ("the red block is on the grey plate. "
                                      "the red block is on the red block. the top drawer is shut.")
    assert scene_caption({**meta, "articulations": []}, 0) == "no object rests on another."


def test_buttons_are_left_out_of_captions():
    """The tiny base misreads which button is lit, and any caption of buttons misled the planner."""
    travel = 0.015
    states = np.array([[0.0, 0.0], [0.012, 0.0], [0.0, 0.0]], np.float32)
    meta = {"objects": [], "privileged": {"object_positions": np.zeros((3, 0, 3), np.float32),
                                          "articulation_states": states},
            "articulations": [{"name": "red_button", "kind": "button", "closed": 0.0, "open": travel},
                              {"name": "top_drawer", "kind": "drawer", "closed": 0.0, "open": 0.2}]}
    assert [scene_caption(meta, f) for f in range(3)] == ["the top drawer is shut."] * 3


def test_caption_without_privileged_record_says_what_is_missing():
    with pytest.raises(ValueError, match="privileged"):
        scene_caption({"objects": []}, 0)


def _episode() -> Episode:
    frames = np.stack([np.full((8, 8, 3), t, dtype=np.uint8) for t in range(3)])
    return Episode(name="ep", views={"front": frames}, goal="stack two red blocks on the plate",
                   task="stack_blocks", segments=[(0, 2), (2, 3)],
                   instructions=["reach for the red block", "move the red block above the plate"],
                   meta=_meta())


def test_caption_examples_every_kth_frame_and_the_last():
    ex = caption_examples([_episode()], stride=2)
    assert [e.frame for e in ex] == [0, 2]
    assert [int(e.image[0, 0, 0]) for e in ex] == [0, 2]
    assert all(e.question == CAPTION_QUESTION for e in ex)
    assert "on the grey plate" in ex[1].target
    with pytest.raises(ValueError, match="stride"):
        caption_examples([_episode()], stride=0)


def test_real_episodes_without_a_record_are_skipped_only_when_asked():
    """Vocabulary episodes from real robots carry no simulator record: read for words, not captioned."""
    real = _episode()
    real.meta = {k: v for k, v in real.meta.items() if k != "privileged"}
    real.name = "real"
    with pytest.raises(ValueError, match="'real'.*privileged"):
        caption_examples([real], stride=1)
    ex = caption_examples([real, _episode()], stride=1, skip_unrecorded=True)
    assert {e.episode for e in ex} == {"ep"} and len(ex) == 3
    broken = _episode()
    broken.meta["privileged"] = {}
    with pytest.raises(ValueError, match="privileged"):
        caption_examples([broken], stride=1, skip_unrecorded=True)


def test_slot_swap_never_renames_a_caption():
    step = PlannerExample(image=np.zeros((8, 8, 3), np.uint8), goal="stack two red blocks on the plate",
                          previous_instruction=None, target="reach for the red block", task="stack_blocks")
    other = PlannerExample(image=np.zeros((8, 8, 3), np.uint8), goal="stack two blue blocks on the plate",
                           previous_instruction=None, target="reach for the blue block", task="stack_blocks")
    caption = caption_examples([_episode()], stride=2)[1]
    out = slot_swap([step, other, caption], copies=3, seed=0)
    renamed = out[3:]
    assert renamed and all(e.question is None for e in renamed)  # the steps got copies
    assert [e for e in out if e.question is not None] == [caption]  # the caption none


def test_caption_example_is_asked_its_question_not_the_planner_prompt():
    cap = caption_examples([_episode()], stride=2)[1]
    tok = train_tokenizer([CAPTION_QUESTION, cap.target, "stack two red blocks"], vocab_size=400)
    proc = build_processor(PlannerConfig(), tok)
    enc = encode_example(proc, cap)
    text = tok.decode(enc["input_ids"])
    assert CAPTION_QUESTION in text and "task goal" not in text
    answer = tok.decode(enc["input_ids"][enc["labels"] != -100])
    assert answer.strip().startswith(cap.target)
    # the question is part of the data's fingerprint (it keys the trained base)
    plain = PlannerExample(image=cap.image, goal=cap.goal, previous_instruction=None, target=cap.target)
    assert examples_fingerprint([cap]) != examples_fingerprint([plain])


def test_scene_is_stated_in_the_planner_prompt_and_renamed_with_the_goal():
    from planner.prompts import user_prompt

    prompt = user_prompt("stack two red blocks on the plate", "lift the red block",
                         scene="the gripper holds the red block. the red block is on the grey plate.")
    assert "The scene: the gripper holds the red block. the red block is on the grey plate." in prompt
    assert prompt.index("The scene") > prompt.index("lift the red block")
    assert "The scene" not in user_prompt("stack two red blocks on the plate", None)
    steps = [PlannerExample(image=np.zeros((8, 8, 3), np.uint8), goal=f"stack two {c} blocks on the plate",
                            previous_instruction=f"lift the {c} block",
                            target=f"move the {c} block above the stack of {c} blocks", task="stack_blocks",
                            scene=f"the gripper holds the {c} block. the {c} block is on the grey plate.")
             for c in ("red", "blue", "green")]
    for ex in slot_swap(steps, copies=4, seed=1)[3:]:
        colour = ex.goal.split()[2]
        assert ex.scene == f"the gripper holds the {colour} block. the {colour} block is on the grey plate."


def test_describe_scene_needs_captions_and_a_tiny_base():
    with pytest.raises(ValueError, match="caption_frame_stride"):
        PlannerConfig(describe_scene=True)
    PlannerConfig(describe_scene=True, pretrain={"caption_frame_stride": 8})
    with pytest.raises(ValueError, match="describe_scene"):
        PlannerConfig(kind="llava_next_8b", describe_scene=True, pretrain={"caption_frame_stride": 8})
    # off, the option leaves the base's cache key as it was before it existed
    assert "describe_scene" not in PlannerConfig().model_dict()
    assert "caption_frame_stride" not in PlannerConfig().model_dict()["pretrain"]
