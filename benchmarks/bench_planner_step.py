"""Seconds per training step of the smollm2_llava planner, fp32 against bf16 autocast, in one run.

    python benchmarks/bench_planner_step.py [--batch 8] [--threads 2]

One batch of planner examples (50 image tokens and a prompt as the harness renders it) on the base
built from SmolLM2-135M-Instruct: a full step (projector and language model trained, the base's
instruction tuning) and a LoRA step (r=16 on q/k/v/o, the finetune), forward and backward with the
loss on the answer tokens only; then greedy generation of the batch with the KV cache. Prints each
figure and the bf16 / fp32 ratio; nothing is asserted (numerics win differently on each machine).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
# The harness (planner/) is not installed: import it, and the tests' helpers, from this checkout.
sys.path[:0] = [str(ROOT), str(ROOT / "tests" / "planner")]


def _seconds(fn, repeats: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def main(argv: list[str] | None = None) -> dict:
    """Run the measurements and print them."""
    from peft import get_peft_model
    from synthetic_world import make_episodes

    from planner.config import PlannerConfig
    from planner.dataset import PlannerCollator, encode_example
    from planner.models import build_pretrained_lm_model
    from planner.train import answer_loss, autocast_context, lora_config, training_examples

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    cfg = PlannerConfig(kind="smollm2_llava", vision_tower="effnet_lite0_mid", image_size=224, patch_size=32)
    model, processor = build_pretrained_lm_model(cfg)
    examples = training_examples(make_episodes(["push_buttons", "pick_and_lift"], range(4), image_size=224),
                                 cfg.finetune)[: args.batch]
    batch = PlannerCollator(processor.tokenizer.pad_token_id)([encode_example(processor, e) for e in examples])
    print(f"batch {len(examples)} x {batch['input_ids'].shape[1]} tokens, {args.threads} threads")
    out: dict[str, float] = {}

    def step(dtype: str):
        def run():
            with autocast_context(dtype):
                answer_loss(model, batch).backward()
            model.zero_grad(set_to_none=True)
        return run

    model.train()
    for dtype in ("float32", "bfloat16"):
        out[f"full_{dtype}"] = _seconds(step(dtype), args.repeats)
    model = get_peft_model(model, lora_config(cfg))
    for dtype in ("float32", "bfloat16"):
        out[f"lora_{dtype}"] = _seconds(step(dtype), args.repeats)
    model = model.merge_and_unload().eval()
    gen = {k: v for k, v in batch.items() if k != "labels"}
    with torch.no_grad():
        out["generate_12_tokens_fp32"] = _seconds(
            lambda: model.generate(**gen, max_new_tokens=12, min_new_tokens=12, do_sample=False), 1)
    for name in ("full", "lora"):
        f32, b16 = out[f"{name}_float32"], out[f"{name}_bfloat16"]
        print(f"{name} step: fp32 {f32:.2f} s, bf16 autocast {b16:.2f} s, bf16 / fp32 {b16 / f32:.2f}")
    print(f"greedy 12 tokens for the batch (KV cache, fp32): {out['generate_12_tokens_fp32']:.2f} s, "
          f"{out['generate_12_tokens_fp32'] / len(examples):.2f} s per request")
    return out


if __name__ == "__main__":
    main()
