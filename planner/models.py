"""Build or load the planner's LLaVA model and processor: tiny LLaVA / LLaVA-NeXT or llama3-llava-next-8b.

Tiny models are built from a config with random weights and a BPE tokenizer trained locally on the
instruction and goal corpus (nothing comes from a hub). Images are preprocessed by transformers' PIL
image processors, never the torchvision fast path.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import torch

from planner.config import PlannerConfig
from planner.prompts import IMAGE_TOKEN
from planner.vision import EffNetVisionTower, install_vision_tower, without_vision_tower

SPECIAL_TOKENS = ["<pad>", "<s>", "</s>", "<unk>", IMAGE_TOKEN]
# A Vicuna-like template (as LLaVA-1.5 uses): "USER: ... ASSISTANT: answer</s>".
TINY_CHAT_TEMPLATE = (
    "{{ bos_token }}{% for m in messages %}{% if m['role'] == 'user' %}USER: {{ m['content'] }} "
    "{% else %}ASSISTANT: {{ m['content'] }}{{ eos_token }}{% endif %}{% endfor %}"
    "{% if add_generation_prompt %}ASSISTANT:{% endif %}"
)
CHECKPOINT_HELP = (
    "put llama3-llava-next-8b in transformers format there (e.g. the files of the hub repository "
    "'llava-hf/llama3-llava-next-8b-hf': config.json, *.safetensors, tokenizer and processor files) "
    "or set planner.checkpoint_path"
)


def _require(module: str) -> None:
    try:
        __import__(module)
    except ImportError as exc:  # pragma: no cover - depends on the installation
        raise ImportError(f"the planner needs {module}: make install (or pip install -c constraints.txt -e '.[planner]')") from exc


def train_tokenizer(corpus: Iterable[str], vocab_size: int):
    """A byte-level BPE tokenizer trained on ``corpus`` with LLaVA's special tokens and chat template."""
    _require("tokenizers")
    from tokenizers import Tokenizer, decoders, models, pre_tokenizers, trainers
    from transformers import PreTrainedTokenizerFast

    texts = [t for t in corpus if t]
    if not texts:
        raise ValueError("cannot train the planner tokenizer on an empty corpus")
    tok = Tokenizer(models.BPE(unk_token="<unk>"))
    tok.pre_tokenizer = pre_tokenizers.ByteLevel(add_prefix_space=False)
    tok.decoder = decoders.ByteLevel()
    trainer = trainers.BpeTrainer(vocab_size=vocab_size, special_tokens=SPECIAL_TOKENS,
                                  initial_alphabet=pre_tokenizers.ByteLevel.alphabet(),
                                  show_progress=False)
    tok.train_from_iterator(texts, trainer)
    fast = PreTrainedTokenizerFast(tokenizer_object=tok, bos_token="<s>", eos_token="</s>",
                                   pad_token="<pad>", unk_token="<unk>",
                                   extra_special_tokens={"image_token": IMAGE_TOKEN})
    fast.chat_template = TINY_CHAT_TEMPLATE
    return fast


def _image_processor(cfg: PlannerConfig):
    from transformers.models.clip.image_processing_pil_clip import CLIPImageProcessorPil
    from transformers.models.llava_next.image_processing_pil_llava_next import (
        LlavaNextImageProcessorPil,
    )

    s = cfg.image_size
    kw = dict(size={"shortest_edge": s}, crop_size={"height": s, "width": s})
    if cfg.vision_tower != "clip":
        from planner.vision import EFFNET_MEAN, EFFNET_STD

        # the Lite models' own preprocessing (bilinear resize, x * 2 - 1), as rdd.encoders does it
        kw.update(image_mean=list(EFFNET_MEAN), image_std=list(EFFNET_STD), resample=2)
    if cfg.kind in ("tiny_llava", "smollm2_llava"):
        return CLIPImageProcessorPil(**kw)
    return LlavaNextImageProcessorPil(image_grid_pinpoints=cfg.image_grid_pinpoints, **kw)


def build_processor(cfg: PlannerConfig, tokenizer):
    """The LLaVA (or LLaVA-NeXT) processor of a model built here; CLIP's CLS token counted.

    The chat template is the tokenizer's: the tiny one's Vicuna-like template, or the pretrained
    language model's own.
    """
    from transformers import LlavaNextProcessor, LlavaProcessor

    cls = LlavaNextProcessor if cfg.kind == "tiny_llava_next" else LlavaProcessor
    return cls(image_processor=_image_processor(cfg), tokenizer=tokenizer,
               patch_size=cfg.patch_size, vision_feature_select_strategy="default",
               num_additional_image_tokens=1, chat_template=tokenizer.chat_template or TINY_CHAT_TEMPLATE)


def build_tiny_model(cfg: PlannerConfig, tokenizer) -> torch.nn.Module:
    """A randomly initialised tiny LLaVA / LLaVA-NeXT sized by ``cfg``."""
    _require("transformers")
    from transformers import (
        CLIPVisionConfig,
        LlamaConfig,
        LlavaConfig,
        LlavaForConditionalGeneration,
        LlavaNextConfig,
        LlavaNextForConditionalGeneration,
    )

    if cfg.kind not in ("tiny_llava", "tiny_llava_next"):
        raise ValueError(f"build_tiny_model cannot build kind {cfg.kind!r}")
    n_img = (cfg.image_size // cfg.patch_size) ** 2
    text = LlamaConfig(
        vocab_size=len(tokenizer), hidden_size=cfg.text_hidden,
        intermediate_size=cfg.text_intermediate, num_hidden_layers=cfg.text_layers,
        num_attention_heads=cfg.text_heads, num_key_value_heads=cfg.text_heads,
        # room for LLaVA-NeXT's tiles (up to 4 + base, plus newline tokens) and the text
        max_position_embeddings=max(512, 8 * n_img + 256),
        pad_token_id=tokenizer.pad_token_id, bos_token_id=tokenizer.bos_token_id,
        eos_token_id=tokenizer.eos_token_id, tie_word_embeddings=False)
    vision_hidden, vision_layers = cfg.vision_hidden, cfg.vision_layers
    if cfg.vision_tower != "clip":
        from planner.vision import TOWER_DIMS

        # the CLIP tower is only a placeholder replaced by the frozen encoder (install_vision_tower);
        # its width sets the projector's input size
        vision_hidden, vision_layers = TOWER_DIMS[cfg.vision_tower], 0
    vision = CLIPVisionConfig(
        hidden_size=vision_hidden, intermediate_size=2 * vision_hidden,
        num_hidden_layers=vision_layers, num_attention_heads=cfg.vision_heads,
        image_size=cfg.image_size, patch_size=cfg.patch_size, projection_dim=vision_hidden)
    common = dict(vision_config=vision, text_config=text,
                  image_token_id=tokenizer.convert_tokens_to_ids(IMAGE_TOKEN),
                  vision_feature_select_strategy="default", vision_feature_layer=-1)
    if cfg.kind == "tiny_llava":
        model = LlavaForConditionalGeneration(LlavaConfig(**common))
    else:
        model = LlavaNextForConditionalGeneration(
            LlavaNextConfig(image_grid_pinpoints=cfg.image_grid_pinpoints, **common))
    model.generation_config.pad_token_id = tokenizer.pad_token_id
    model.generation_config.eos_token_id = tokenizer.eos_token_id
    return install_vision_tower(model, cfg.vision_tower)


def build_pretrained_lm_model(cfg: PlannerConfig):
    """(model, processor): LLaVA on SmolLM2-135M-Instruct, a frozen pretrained tower and a new projector.

    As LLaVA is built: the language model keeps its pretrained weights, tokenizer and chat template
    (one ``<image>`` token is added), the image encoder is EfficientNet-Lite0 from PyPI, and only
    the projector starts from random weights.
    """
    _require("transformers")
    from transformers import (
        AutoModelForCausalLM,
        AutoTokenizer,
        CLIPVisionConfig,
        LlavaConfig,
        LlavaForConditionalGeneration,
    )

    from planner.smollm2 import language_model_dir
    from planner.vision import TOWER_DIMS

    if cfg.kind != "smollm2_llava":
        raise ValueError(f"build_pretrained_lm_model cannot build kind {cfg.kind!r}")
    if cfg.vision_tower not in TOWER_DIMS:
        raise ValueError(f"planner kind smollm2_llava needs a pretrained vision tower "
                         f"({', '.join(TOWER_DIMS)}), got vision_tower={cfg.vision_tower!r}")
    lm_dir = language_model_dir()
    tokenizer = AutoTokenizer.from_pretrained(lm_dir)
    tokenizer.add_special_tokens({"additional_special_tokens": [IMAGE_TOKEN]})
    tokenizer.image_token = IMAGE_TOKEN
    if tokenizer.pad_token_id is None:
        tokenizer.pad_token = tokenizer.eos_token  # padding is masked out anyway
    lm = AutoModelForCausalLM.from_pretrained(lm_dir, dtype=torch.float32)
    dim = TOWER_DIMS[cfg.vision_tower]
    # a placeholder the frozen tower replaces (install_vision_tower); its width sizes the projector
    vision = CLIPVisionConfig(hidden_size=dim, intermediate_size=2 * dim, num_hidden_layers=0,
                              num_attention_heads=cfg.vision_heads, image_size=cfg.image_size,
                              patch_size=cfg.patch_size, projection_dim=dim)
    model = LlavaForConditionalGeneration(LlavaConfig(
        vision_config=vision, text_config=lm.config, vision_feature_select_strategy="default",
        vision_feature_layer=-1, image_token_id=tokenizer.convert_tokens_to_ids(IMAGE_TOKEN),
        tie_word_embeddings=lm.config.tie_word_embeddings))
    model.model.language_model.load_state_dict(lm.model.state_dict())
    model.resize_token_embeddings(len(tokenizer))  # the <image> row; tied to lm_head as in SmolLM2
    model.generation_config.pad_token_id = tokenizer.pad_token_id
    model.generation_config.eos_token_id = tokenizer.eos_token_id
    processor = build_processor(cfg, tokenizer)
    return install_vision_tower(model, cfg.vision_tower), processor


def _model_class(kind: str):
    from transformers import LlavaForConditionalGeneration, LlavaNextForConditionalGeneration

    return LlavaNextForConditionalGeneration if kind in ("tiny_llava_next", "llava_next_8b") \
        else LlavaForConditionalGeneration


def resolve_checkpoint(cfg: PlannerConfig) -> Path:
    """The local llama3-llava-next-8b directory, or a clear error saying where it must be."""
    if not cfg.checkpoint_path:
        raise FileNotFoundError(f"planner kind {cfg.kind!r} needs checkpoint_path; {CHECKPOINT_HELP}")
    path = Path(cfg.checkpoint_path).expanduser()
    if not (path / "config.json").is_file():
        raise FileNotFoundError(f"no llama3-llava-next-8b checkpoint at {path} (config.json missing); "
                                f"{CHECKPOINT_HELP}")
    return path


def load_model(path: str | Path, cfg: PlannerConfig, device: str | torch.device | None = None):
    """(model, processor) from a saved base directory or the real checkpoint; eval mode."""
    _require("transformers")
    from transformers import AutoProcessor

    path = Path(path)
    if not (path / "config.json").is_file():
        raise FileNotFoundError(f"no planner model at {path} (config.json missing)")
    dtype = {"float32": torch.float32, "bfloat16": torch.bfloat16, "float16": torch.float16}[cfg.dtype]
    if cfg.kind == "llava_next_8b" and not torch.cuda.is_available() and dtype != torch.float32:
        raise RuntimeError("llava_next_8b is meant to run in bf16 on a GPU; no CUDA device here "
                           "(set planner.dtype=float32 to try it on CPU anyway)")
    if cfg.vision_tower != "clip":
        from transformers.utils import logging as hf_logging

        # the saved base holds no tower weights (they come from PyPI): silence the missing-key report
        verbosity = hf_logging.get_verbosity()
        hf_logging.set_verbosity_error()
        try:
            model = _model_class(cfg.kind).from_pretrained(path, dtype=dtype)
        finally:
            hf_logging.set_verbosity(verbosity)
        model = install_vision_tower(model, cfg.vision_tower)
    else:
        model = _model_class(cfg.kind).from_pretrained(path, dtype=dtype)
    # backend="pil": transformers' torchvision fast path is not usable here
    processor = AutoProcessor.from_pretrained(path, backend="pil")
    tok = processor.tokenizer
    if tok.pad_token_id is None:
        # some released checkpoints ship without a pad token; padding is masked out anyway
        tok.pad_token = tok.eos_token
    if device is not None:
        model.to(device)
    model.eval()
    return model, processor


def save_model(model, processor, path: str | Path) -> None:
    """Write model weights (safetensors) and the processor (tokenizer included) into ``path``."""
    tower = getattr(getattr(model, "model", model), "vision_tower", None)
    if isinstance(tower, EffNetVisionTower):
        model.save_pretrained(path, safe_serialization=True, state_dict=without_vision_tower(model.state_dict()))
    else:
        model.save_pretrained(path, safe_serialization=True)
    processor.save_pretrained(path)
