"""A training loop killed part-way and run again goes on from its last save (planner.checkpoint) and
ends at the weights of a run that was never stopped: base pretraining and LoRA finetuning."""

import json

import pytest
import torch

pytest.importorskip("peft")
pytest.importorskip("accelerate")

from safetensors.torch import load_file  # noqa: E402
from synthetic_world import make_episodes  # noqa: E402

from planner import train  # noqa: E402
from planner.checkpoint import DONE_FILE, STATE_FILE  # noqa: E402
from planner.config import PlannerConfig  # noqa: E402
from planner.train import LOG_FILE, finetune_lora, pretrain_base, training_examples  # noqa: E402


class Killed(Exception):
    """Stands for the job being stopped (a guard's time budget) in the middle of training."""


def _cfg() -> PlannerConfig:
    # LoRA dropout on: the resumed loop must also draw the same dropout masks (torch's random state)
    return PlannerConfig(kind="tiny_llava", vocab_size=400, max_new_tokens=16,
                         pretrain=dict(lr=5e-3, epochs=3, batch_size=4, warmup_ratio=0.1),
                         finetune=dict(lr=1e-2, epochs=3, batch_size=2, warmup_ratio=0.1, slot_swap_copies=1),
                         lora=dict(r=8, alpha=16, dropout=0.1))


def _counting(monkeypatch, kill_after: int | None = None) -> dict:
    """Count the next loops' training batches (their loss computations); with ``kill_after``, every
    training step saves and the loop dies when it asks for batch ``kill_after + 1``'s loss."""
    real, seen = train.answer_loss, {"n": 0}

    def loss(model, batch):
        seen["n"] += 1
        if kill_after is not None and seen["n"] > kill_after:
            raise Killed
        return real(model, batch)

    monkeypatch.setattr(train, "answer_loss", loss)
    if kill_after is not None:
        monkeypatch.setattr(train, "EVERY_S", 0.0)
    return seen


def _same_weights(a, b) -> None:
    wa, wb = load_file(str(a)), load_file(str(b))
    assert wa.keys() == wb.keys()
    for name in wa:
        torch.testing.assert_close(wa[name], wb[name], rtol=0, atol=1e-6, msg=name)


def _batches_per_epoch(n_examples: int, batch_size: int) -> int:
    return -(-n_examples // batch_size)


@pytest.fixture(scope="module")
def examples():
    cfg = _cfg()
    pre = training_examples(make_episodes(["pick_and_lift", "push_button"], range(3)), cfg.pretrain)
    tune = training_examples(make_episodes(["push_buttons"], [100, 101]), cfg.finetune)
    return pre, tune


def test_pretraining_killed_midway_goes_on_to_the_same_weights(tmp_path, monkeypatch, examples):
    torch.set_num_threads(1)
    cfg, (pre, _) = _cfg(), examples
    straight = pretrain_base(cfg, pre, tmp_path / "straight", progress=False)

    saves = tmp_path / "saves"
    per_epoch = _batches_per_epoch(len(pre), 4)
    _counting(monkeypatch, kill_after=per_epoch + 2)  # inside the second epoch
    with pytest.raises(Killed):
        pretrain_base(cfg, pre, tmp_path / "killed", progress=False, checkpoint_dir=saves)
    assert (saves / "pretrain" / STATE_FILE).is_file() and not (saves / "pretrain" / DONE_FILE).exists()
    monkeypatch.undo()

    resumed = pretrain_base(cfg, pre, tmp_path / "resumed", progress=False, checkpoint_dir=saves)
    _same_weights(straight / "model.safetensors", resumed / "model.safetensors")
    log, straight_log = (json.loads((d / LOG_FILE).read_text()) for d in (resumed, straight))
    assert log["resumed_at_step"] == per_epoch + 2 and "resumed_at_step" not in straight_log
    assert log["epoch_losses"] == pytest.approx(straight_log["epoch_losses"], abs=1e-6)
    assert (saves / "pretrain" / DONE_FILE).is_file() and not (saves / "pretrain" / STATE_FILE).exists()

    # a loop that finished is not trained again: its saved result is taken as it is
    _counting(monkeypatch, kill_after=0)
    again = pretrain_base(cfg, pre, tmp_path / "again", progress=False, checkpoint_dir=saves)
    _same_weights(straight / "model.safetensors", again / "model.safetensors")


def test_lora_finetune_killed_midway_goes_on_to_the_same_adapter(tmp_path, monkeypatch, examples):
    torch.set_num_threads(1)
    cfg, (pre, tune) = _cfg(), examples
    base = pretrain_base(cfg, pre, tmp_path / "base", progress=False)
    calls = _counting(monkeypatch)
    straight = finetune_lora(cfg, base, tune, tmp_path / "straight", seed=3, progress=False)
    monkeypatch.undo()
    per_epoch = calls["n"] // 3
    assert per_epoch >= 2

    saves = tmp_path / "saves"
    _counting(monkeypatch, kill_after=2 * per_epoch - 1)  # before the last batch of the second epoch
    with pytest.raises(Killed):
        finetune_lora(cfg, base, tune, tmp_path / "killed", seed=3, progress=False, checkpoint_dir=saves)
    monkeypatch.undo()
    resumed = finetune_lora(cfg, base, tune, tmp_path / "resumed", seed=3, progress=False, checkpoint_dir=saves)
    _same_weights(straight / "adapter_model.safetensors", resumed / "adapter_model.safetensors")


@pytest.mark.parametrize("save, why", [
    (b"not a save", "is unreadable"),
    ({"model": {"no.such.weight": torch.zeros(2)}, "optimizer": {}, "scheduler": {}, "rng": {}, "progress": {}},
     "does not fit this training"),
])
def test_a_save_that_cannot_be_used_starts_the_loop_over(tmp_path, examples, caplog, save, why):
    torch.set_num_threads(1)
    cfg, (pre, _) = _cfg(), examples
    straight = pretrain_base(cfg, pre, tmp_path / "straight", progress=False)
    saves = tmp_path / "saves"
    (saves / "pretrain").mkdir(parents=True)
    if isinstance(save, bytes):
        (saves / "pretrain" / STATE_FILE).write_bytes(save)
    else:
        torch.save(save, saves / "pretrain" / STATE_FILE)
    again = pretrain_base(cfg, pre, tmp_path / "again", progress=False, checkpoint_dir=saves)
    assert why in caplog.text and str(saves / "pretrain" / STATE_FILE) in caplog.text
    _same_weights(straight / "model.safetensors", again / "model.safetensors")
