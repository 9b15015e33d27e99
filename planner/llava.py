"""The learned planners a config names: one class per LLaVA model, which trains, keys and loads it.

``conf/planner/<name>.yaml`` names one of these classes as its ``_target_``; its keys are the
options of :class:`planner.config.PlannerConfig` (sizes, tokenizer, both training stages, LoRA),
except ``kind``, which the class fixes. The pipeline calls :meth:`LlavaPlanner.pretrain`,
:meth:`LlavaPlanner.finetune` and :meth:`LlavaPlanner.load` with the stage folders it owns.
"""

from __future__ import annotations

import dataclasses
import inspect
import typing
from collections.abc import Sequence
from pathlib import Path
from typing import Any, ClassVar

from planner.config import PlannerConfig, TrainSettings


def _options_signature() -> inspect.Signature:
    """PlannerConfig's fields but ``kind``, keyword-only and typed (what a config may set)."""
    hints = typing.get_type_hints(PlannerConfig)
    params = [inspect.Parameter(
        f.name, inspect.Parameter.KEYWORD_ONLY, annotation=hints[f.name],
        default=f.default if f.default is not dataclasses.MISSING else f.default_factory())
        for f in dataclasses.fields(PlannerConfig) if f.name != "kind"]
    return inspect.Signature(params)


class LlavaPlanner:
    """A LLaVA-family planner: its settings, base pretraining, LoRA finetuning and the trained model."""

    kind: ClassVar[str]  # the model (planner.models builds or loads it)
    learned: ClassVar[bool] = True  # trained in the pipeline's planner stages (the oracle is not)
    __signature__ = _options_signature()  # the options below, as validation and Hydra see them

    def __init__(self, **options: Any) -> None:
        describer = options.get("describer")
        if isinstance(describer, LlavaPlanner):  # Hydra builds a nested planner node as its object
            options["describer"] = describer.config
        self.config = PlannerConfig(kind=self.kind, **options)

    def describer(self) -> LlavaPlanner | None:
        """The planner whose base describes scenes for this one (``describer``); None: its own base does."""
        cfg = self.config.describer
        if cfg is None:
            return None
        cls = next(c for c in _planner_classes() if c.kind == cfg.kind)
        return cls(**{f.name: getattr(cfg, f.name) for f in dataclasses.fields(cfg) if f.name != "kind"})

    @property
    def view(self) -> str:
        """The camera view the planner sees."""
        return self.config.view

    def base_spec(self) -> dict[str, Any]:
        """What makes the base model (finetuning settings excluded): the base stage's key."""
        return {"model": self.config.model_dict()}

    def examples(self, episodes: Sequence, settings: TrainSettings | None = None) -> list:
        """Boundary examples of episodes carrying their segments and instructions."""
        from planner.train import training_examples

        return training_examples(episodes, settings or TrainSettings(), self.config.view,
                                 read_state=self.config.read_state)

    def pretrain(self, episodes: Sequence, out_dir: Path, *, extra_corpus: Sequence[str] = (),
                 vocabulary_episodes: Sequence = (), progress: bool = True,
                 checkpoint_dir: Path | None = None) -> Path:
        """The base planner in ``out_dir`` (a tiny model trained here) or the real checkpoint's folder.

        ``vocabulary_episodes``: labelled episodes whose words the base knows without training on
        them (their slot words join the finetune's slot swapping); with ``caption_frame_stride``
        their frames, like the pretraining demos', are captioned (scene facts, no instruction)
        where they carry a simulator record (real robot episodes are only read for their words).
        ``checkpoint_dir``: where training saves its state, so a killed job goes on from there.
        """
        from planner.augment import slot_vocabulary
        from planner.captions import caption_examples, with_true_scenes
        from planner.train import pretrain_base

        examples = self.examples(episodes, self.config.pretrain)
        if self.config.describe_scene:
            examples = with_true_scenes(examples, episodes)
        stride = self.config.pretrain.caption_frame_stride
        captions = [] if not stride else [
            *caption_examples(episodes, stride, self.config.view),
            *caption_examples(vocabulary_episodes, stride, self.config.view, skip_unrecorded=True)]
        return pretrain_base(self.config, examples, out_dir, captions=captions,
                             extra_corpus=list(extra_corpus),
                             slot_vocabulary=slot_vocabulary(vocabulary_episodes), progress=progress,
                             checkpoint_dir=checkpoint_dir)

    def finetune(self, base_dir: Path, episodes: Sequence, out_dir: Path, *, seed: int,
                 progress: bool = True, checkpoint_dir: Path | None = None, describer=None) -> Path:
        """The LoRA adapter of the base in ``base_dir`` trained on ``episodes``, in ``out_dir``
        (``checkpoint_dir``: where training saves its state, so a killed job goes on from there;
        ``describer``: the loaded base of :meth:`describer`, when the config names one)."""
        from planner.train import finetune_lora

        examples = self.examples(episodes, self.config.finetune)
        if self.config.describe_scene:
            from planner.planner import VLMPlanner

            # the describer states the demos' frames as it will state the robot's at run time
            # (no simulator record needed: real demonstrations work the same way)
            if describer is None and self.config.describer is not None:
                raise ValueError("planner with a describer: finetune needs the describer's loaded base")
            examples = (describer or VLMPlanner(self.config, base_dir)).with_scenes(examples)
        return finetune_lora(self.config, base_dir, examples, out_dir, seed=seed, progress=progress,
                             checkpoint_dir=checkpoint_dir)

    def load(self, base_dir: Path, adapter_dir: Path | None = None, describer=None):
        """The trained planner (:class:`planner.planner.VLMPlanner`): the base, plus the adapter if given.

        ``describer``: the already loaded base that describes scenes (``describe_scene``): this
        base, instead of loading a second copy, or the base of :meth:`describer`.
        """
        from planner.planner import VLMPlanner

        return VLMPlanner(self.config, base_dir, adapter_dir, describer=describer)


class TinyLlava(LlavaPlanner):
    """Tiny LLaVA (tiny Llama + CLIP tower or frozen EfficientNet-Lite0), pretrained here on CPU."""

    kind = "tiny_llava"


class TinyLlavaNext(LlavaPlanner):
    """Tiny LLaVA-NeXT: as TinyLlava, plus AnyRes tiling over ``image_grid_pinpoints``."""

    kind = "tiny_llava_next"


class SmolLlava(LlavaPlanner):
    """LLaVA on the pretrained SmolLM2-135M-Instruct with a frozen EfficientNet-Lite0 tower (planner.smollm2)."""

    kind = "smollm2_llava"


class LlavaNext8B(LlavaPlanner):
    """llama3-llava-next-8b from a local transformers-format folder (not pretrained here)."""

    kind = "llava_next_8b"


def _planner_classes() -> list[type[LlavaPlanner]]:
    return [TinyLlava, TinyLlavaNext, SmolLlava, LlavaNext8B]
