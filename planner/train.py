"""Base pretraining of the tiny planners and LoRA finetuning of any planner, both cached on disk.

Base pretraining trains every weight of a freshly built tiny model on expert-decomposed
demonstrations of the pretraining tasks (the caller guarantees they exclude the evaluation tasks);
the result is the "w/o finetune" planner. LoRA finetuning (peft) adapts a base, tiny or
llama3-llava-next-8b, to one decomposer's demonstrations. Each result lives in a directory named by a
hash of everything that made it, written atomically; asking again returns it without work.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Iterable, Sequence
from pathlib import Path

import torch

from planner.augment import slot_swap
from planner.checkpoint import EVERY_S, load_done, load_state, save_done, save_state
from planner.config import PlannerConfig, TrainSettings
from planner.dataset import (
    PlannerCollator,
    PlannerExample,
    encode_example,
    examples_from_episode,
)
from planner.models import (
    build_pretrained_lm_model,
    build_processor,
    build_tiny_model,
    load_model,
    resolve_checkpoint,
    save_model,
    train_tokenizer,
)
from planner.prompts import user_prompt
from rdd.atomic import write_json_atomic

CONFIG_FILE = "planner_config.json"
LOG_FILE = "train_log.json"
VOCABULARY_FILE = "slot_vocabulary.json"


def _json_text(obj) -> str:
    return json.dumps(obj, indent=2, sort_keys=True, default=str)


def _within(folder: str | Path | None, name: str) -> Path | None:
    return None if folder is None else Path(folder) / name


def _fresh_dir(out_dir: str | Path) -> Path:
    """``out_dir`` created if missing; a folder that already holds a planner is never overwritten."""
    out = Path(out_dir)
    if (out / CONFIG_FILE).exists():
        raise FileExistsError(f"{out} already holds a trained planner ({CONFIG_FILE}); pick another folder")
    out.mkdir(parents=True, exist_ok=True)
    return out


def answer_loss(model, batch: dict) -> torch.Tensor:
    """Mean cross-entropy over the answer tokens, with logits computed only from the first answer on.

    The output layer is the largest matrix of a pretrained language model (49,152 words); the
    prompt's positions need no logits, so the head runs only where the loss reads it.
    """
    batch = dict(batch)
    labels = batch.pop("labels")
    seq = labels.shape[1]
    answer = labels != -100
    if not bool(answer.any()):
        raise ValueError("a training batch without answer tokens")
    first = int(torch.where(answer.any(0))[0][0])  # the earliest answer position in the batch
    keep = seq - first + 1  # logits at positions first-1 .. seq-1 predict tokens first .. seq-1
    logits = model(**batch, logits_to_keep=keep).logits
    target = labels[:, seq - keep + 1:]
    return torch.nn.functional.cross_entropy(logits[:, :-1].reshape(-1, logits.shape[-1]).float(),
                                             target.reshape(-1), ignore_index=-100)


def autocast_context(dtype: str):
    """The context the training steps run in: fp32 as is, or bf16 autocast (weights stay fp32)."""
    import contextlib

    if dtype == "float32":
        return contextlib.nullcontext()
    return torch.autocast("cuda" if torch.cuda.is_available() else "cpu", dtype=torch.bfloat16)


def native_bf16() -> bool:
    """Whether bf16 runs natively here (a CUDA device that has it, or a CPU with AVX512-BF16 or AMX).

    Elsewhere bf16 is emulated: on a 2-core AVX2 machine one timing step of SmolLM2 in bf16 autocast
    ran for over 20 minutes, so "auto" must not even try it there.
    """
    if torch.cuda.is_available():
        return bool(torch.cuda.is_bf16_supported())
    try:
        return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):  # a torch build without oneDNN
        return False


def pick_train_dtype(model, batch: dict, choice: str, repeats: int = 2) -> tuple[str, dict[str, float]]:
    """``choice``, or for "auto" the faster of fp32 and bf16 autocast on ``batch`` (seconds per step);
    fp32 without timing where bf16 is not native (:func:`native_bf16`).

    Timed on forward + backward without an optimiser step, so the weights are untouched.
    """
    if choice != "auto":
        return choice, {}
    if not native_bf16():
        return "float32", {}
    seconds = {}
    for dtype in ("float32", "bfloat16"):
        times = []
        for _ in range(repeats + 1):  # the first run warms up
            start = time.perf_counter()
            with autocast_context(dtype):
                answer_loss(model, batch).backward()
            times.append(time.perf_counter() - start)
        model.zero_grad(set_to_none=True)
        seconds[dtype] = min(times[1:])
    return min(seconds, key=seconds.get), seconds


def _train(model, processor, examples: Sequence[PlannerExample], settings: TrainSettings,
           desc: str, progress: bool, vocabulary: dict[str, list[str]] | None = None,
           train_dtype: str = "float32", checkpoint: Path | None = None) -> dict:
    """The one training loop of both stages: AdamW, warm-up + schedule, accelerate placement.

    ``checkpoint``: a folder that outlives a killed job (:mod:`planner.checkpoint`): the loop saves
    its state there every ``EVERY_S`` seconds of training and, run again, goes on from the last save
    (a finished loop only loads its result).
    """
    from accelerate import Accelerator
    from accelerate.utils import set_seed
    from tqdm.auto import tqdm
    from transformers import get_scheduler

    if not examples:
        raise ValueError(f"{desc}: no training examples")
    if checkpoint is not None and (done := load_done(checkpoint, model)) is not None:
        model.eval()
        return done
    set_seed(settings.seed)
    examples = slot_swap(examples, settings.slot_swap_copies, settings.seed,
                         settings.slot_swap_pool, vocabulary, settings.state_jitter_cm)
    accelerator = Accelerator(cpu=not torch.cuda.is_available(),
                              gradient_accumulation_steps=settings.grad_accum)
    encoded = [encode_example(processor, ex) for ex in examples]
    collate = PlannerCollator(processor.tokenizer.pad_token_id, padding_side="right")
    order = torch.Generator().manual_seed(settings.seed)  # the batches' order, saved with each epoch
    loader = torch.utils.data.DataLoader(
        encoded, batch_size=settings.batch_size, shuffle=True, collate_fn=collate, generator=order)
    params = [p for p in model.parameters() if p.requires_grad]
    optimizer = torch.optim.AdamW(params, lr=settings.lr, weight_decay=settings.weight_decay)
    total = math.ceil(len(loader) / settings.grad_accum) * settings.epochs
    scheduler = get_scheduler(settings.schedule, optimizer,
                              num_warmup_steps=int(round(settings.warmup_ratio * total)),
                              num_training_steps=total)
    model, optimizer, loader, scheduler = accelerator.prepare(model, optimizer, loader, scheduler)
    model.train()
    timed: dict[str, float] = {}
    saved = load_state(checkpoint, model, optimizer, scheduler) if checkpoint is not None else None
    if saved is not None:
        order.set_state(saved["generator"])
        accelerator.step = saved["accumulated"]
        train_dtype = saved["train_dtype"]
    elif train_dtype == "auto":  # a batch drawn only then: the shuffle order of fixed numerics stays
        train_dtype, timed = pick_train_dtype(model, next(iter(loader)), train_dtype)
    first_epoch, skip = (saved["epoch"], saved["batch"]) if saved else (0, 0)
    losses: list[float] = list(saved["losses"]) if saved else []
    epoch_loss, n = (saved["epoch_loss"], saved["n"]) if saved else (0.0, 0)
    done_steps = saved["steps"] if saved else 0
    start = time.process_time()
    wall = last_save = time.perf_counter()
    bar = tqdm(total=total, initial=done_steps, desc=desc, disable=not progress, leave=False)
    for epoch in range(first_epoch, settings.epochs):
        epoch_order = order.get_state()  # before this epoch's shuffle: a resume draws the same one
        if not skip:
            epoch_loss, n = 0.0, 0
        for i, batch in enumerate(accelerator.skip_first_batches(loader, skip) if skip else loader, start=skip):
            with accelerator.accumulate(model):
                with autocast_context(train_dtype):
                    loss = answer_loss(model, batch)
                accelerator.backward(loss)
                if accelerator.sync_gradients:
                    accelerator.clip_grad_norm_(params, settings.max_grad_norm)
                optimizer.step()
                scheduler.step()
                optimizer.zero_grad()
            epoch_loss += float(loss.detach())
            n += 1
            bar.set_postfix(loss=f"{loss.item():.3f}")
            if accelerator.sync_gradients:
                bar.update(1)
                done_steps += 1
                if checkpoint is not None and time.perf_counter() - last_save >= EVERY_S:
                    save_state(checkpoint, model, optimizer, scheduler, {
                        "epoch": epoch, "batch": i + 1, "generator": epoch_order, "losses": losses,
                        "epoch_loss": epoch_loss, "n": n, "steps": done_steps, "train_dtype": train_dtype,
                        "accumulated": accelerator.step})
                    last_save = time.perf_counter()
        skip = 0
        losses.append(epoch_loss / max(n, 1))
    bar.close()
    model.eval()
    result = {"epoch_losses": losses, "steps": total, "examples": len(examples), "train_dtype": train_dtype,
              **({"seconds_per_step_measured": timed} if timed else {}),
              **({"resumed_at_step": saved["steps"]} if saved else {}),
              "cpu_seconds": time.process_time() - start, "wall_seconds": time.perf_counter() - wall}
    if checkpoint is not None:
        save_done(checkpoint, model, result)
    return result


def training_examples(episodes: Iterable, settings: TrainSettings, view: str = "front",
                      segmentations: Sequence | None = None, read_state: bool = True) -> list[PlannerExample]:
    """Examples of a training stage from labelled episodes (own segments/instructions unless given).

    ``segmentations``: optional (segments, instructions) per episode, e.g. one decomposer's output.
    ``read_state``: the prompts state the robot's state (``PlannerConfig.read_state``).
    """
    episodes = list(episodes)
    if segmentations is not None and len(segmentations) != len(episodes):
        raise ValueError(f"{len(segmentations)} segmentations for {len(episodes)} episodes")
    labelled = [segmentations[i] if segmentations is not None else (None, None) for i in range(len(episodes))]
    out: list[PlannerExample] = []
    for ep, (segs, instr) in zip(episodes, labelled, strict=True):
        out.extend(examples_from_episode(ep, segs, instr, view=view,
                                         include_inner_frames=settings.include_inner_frames,
                                         inner_frame_stride=settings.inner_frame_stride, read_state=read_state))
    if settings.ambiguous_frame_stride and not settings.include_inner_frames:
        out += ambiguous_inner_examples(episodes, labelled, out, settings.ambiguous_frame_stride, view, read_state)
    return out


def _context(ex: PlannerExample) -> tuple:
    return ex.task, ex.goal, ex.previous_instruction


def ambiguous_inner_examples(episodes: Sequence, labelled: Sequence[tuple], boundary: Sequence[PlannerExample],
                             stride: int, view: str, read_state: bool = True) -> list[PlannerExample]:
    """Every ``stride``-th inner frame of the segments whose context (task, goal, previous
    instruction) precedes more than one next instruction among the ``boundary`` examples."""
    targets: dict[tuple, set[str]] = {}
    for ex in boundary:
        targets.setdefault(_context(ex), set()).add(ex.target)
    ambiguous = {c for c, t in targets.items() if len(t) > 1}
    if not ambiguous:
        return []
    starts = {(ex.episode, ex.frame) for ex in boundary}
    holding = {ex.episode for ex in boundary if _context(ex) in ambiguous}
    out = []
    for ep, (segs, instr) in zip(episodes, labelled, strict=True):
        if ep.name not in holding:  # no frame of it to add: decode none
            continue
        inner = examples_from_episode(ep, segs, instr, view=view, include_inner_frames=True,
                                      inner_frame_stride=stride, read_state=read_state)
        out += [ex for ex in inner if _context(ex) in ambiguous and (ex.episode, ex.frame) not in starts]
    return out


def tokenizer_corpus(examples: Iterable[PlannerExample]) -> list[str]:
    """Texts the tiny tokenizer is trained on: prompts (goals, previous instructions) and targets."""
    out = []
    for ex in examples:
        out.append(user_prompt(ex.goal, ex.previous_instruction, ex.question, ex.scene, ex.state))
        out.append(ex.target)
    return out


def pretrain_base(cfg: PlannerConfig, examples: Sequence[PlannerExample], out_dir: str | Path,
                  *, captions: Sequence[PlannerExample] = (), extra_corpus: Sequence[str] = (),
                  slot_vocabulary: dict[str, list[str]] | None = None, progress: bool = True,
                  checkpoint_dir: str | Path | None = None) -> Path:
    """The base planner directory: pretrained here into ``out_dir`` (tiny kinds) or the real checkpoint.

    ``captions`` (scene-caption examples, :mod:`planner.captions`) are trained on with the planner
    ``examples``; with a projector-alignment stage (smollm2_llava) that stage reads them alone, as
    LLaVA's first stage aligns on image-caption pairs; with ``instruction_tuning`` false the base is
    that stage alone (a vanilla VLM).

    ``slot_vocabulary`` (per task, the slot words of the corpus the tokenizer also saw) is saved with
    the base; LoRA finetuning renames slot words onto it (:func:`planner.augment.slot_swap`).
    ``checkpoint_dir``: where the training loops save their state, to go on after a killed job.
    """
    if cfg.kind == "llava_next_8b":
        return resolve_checkpoint(cfg)  # pretrained elsewhere; we only finetune it
    torch.manual_seed(cfg.pretrain.seed)
    if cfg.kind == "smollm2_llava":
        model, processor = build_pretrained_lm_model(cfg)
        out = _fresh_dir(out_dir)
        # LLaVA's two stages: the projector alone aligns the image tokens to the pretrained
        # language model, then projector and language model are tuned on the instructions
        for name, p in model.named_parameters():
            p.requires_grad_("multi_modal_projector" in name)
        align = _train(model, processor, list(captions) or examples, cfg.align, "align projector", progress,
                       train_dtype=cfg.train_dtype, checkpoint=_within(checkpoint_dir, "align"))
        if cfg.instruction_tuning:
            for name, p in model.named_parameters():
                p.requires_grad_("vision_tower" not in name)
            examples = [*examples, *captions]
            log = {"align": align, **_train(model, processor, examples, cfg.pretrain, f"pretrain {cfg.kind}",
                                            progress, train_dtype=cfg.train_dtype,
                                            checkpoint=_within(checkpoint_dir, "pretrain"))}
        else:
            log = {"align": align}  # the vanilla VLM: no instruction was ever trained on
    else:
        examples = [*examples, *captions]
        tokenizer = train_tokenizer(tokenizer_corpus(examples) + list(extra_corpus), cfg.vocab_size)
        processor = build_processor(cfg, tokenizer)
        model = build_tiny_model(cfg, tokenizer)
        out = _fresh_dir(out_dir)
        log = _train(model, processor, examples, cfg.pretrain, f"pretrain {cfg.kind}", progress,
                     checkpoint=_within(checkpoint_dir, "pretrain"))
    save_model(model, processor, out)
    write_json_atomic(out / VOCABULARY_FILE, dict(slot_vocabulary or {}), dumps=_json_text)
    write_json_atomic(out / LOG_FILE, log, dumps=_json_text)
    write_json_atomic(out / CONFIG_FILE, {"stage": "base", "config": cfg.to_dict()},  # written last
                      dumps=_json_text)
    return out


def lora_config(cfg: PlannerConfig):
    from peft import LoraConfig

    target = cfg.lora.target_modules
    modules_to_save = list(cfg.lora.train_modules)
    if cfg.lora.projector == "lora":
        target = f"({target})|(.*multi_modal_projector\\.linear_[12])"
    elif cfg.lora.projector == "train":
        modules_to_save.append("multi_modal_projector")
    return LoraConfig(r=cfg.lora.r, lora_alpha=cfg.lora.alpha, lora_dropout=cfg.lora.dropout,
                      target_modules=target, modules_to_save=modules_to_save or None, bias="none")


def finetune_lora(cfg: PlannerConfig, base_dir: str | Path, examples: Sequence[PlannerExample],
                  out_dir: str | Path, *, seed: int | None = None, progress: bool = True,
                  checkpoint_dir: str | Path | None = None) -> Path:
    """LoRA-finetune the base in ``base_dir`` on ``examples``; the adapter goes into ``out_dir``
    (``checkpoint_dir``: where the loop saves its state, to go on after a killed job)."""
    from peft import get_peft_model

    base_dir = Path(base_dir)
    settings = cfg.finetune
    if seed is not None:
        settings = TrainSettings(**{**settings.__dict__, "seed": int(seed)})
    out = _fresh_dir(out_dir)
    device = "cuda" if torch.cuda.is_available() else None
    model, processor = load_model(base_dir, cfg, device=device)
    torch.manual_seed(settings.seed)
    model = get_peft_model(model, lora_config(cfg))
    if cfg.kind == "llava_next_8b":
        model.gradient_checkpointing_enable()
        model.enable_input_require_grads()
    vocab_file = base_dir / VOCABULARY_FILE  # absent for a real checkpoint: the demos' words only
    vocabulary = json.loads(vocab_file.read_text()) if vocab_file.is_file() else None
    log = _train(model, processor, examples, settings, f"lora {cfg.kind}", progress, vocabulary,
                 train_dtype=cfg.train_dtype, checkpoint=_within(checkpoint_dir, "lora"))
    model.save_pretrained(out, safe_serialization=True)
    write_json_atomic(out / LOG_FILE, log, dumps=_json_text)
    write_json_atomic(out / CONFIG_FILE, {"stage": "lora", "config": cfg.to_dict(),  # written last
                                          "base_dir": str(base_dir), "seed": settings.seed},
                      dumps=_json_text)
    return out
