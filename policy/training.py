"""Training the keyframe network on flat arrays; checkpoints are written atomically."""

from __future__ import annotations

import hashlib
import json
import logging
import math
import sys
import time
from dataclasses import dataclass, fields
from pathlib import Path
from typing import ClassVar

import numpy as np
import torch
from tqdm import tqdm

from policy.network import KeyframeNet, NetConfig, gripper_equivalent
from rdd.atomic import atomic_file
from rdd.checks import check_fields, number, whole
from rdd.encoders._checkpoint import unreadable_reason
from rdd.errors import InputError

log = logging.getLogger(__name__)


@dataclass
class KeyframeDataset:
    """Training samples; anchors reference rows of ``name_table`` (index -1 = no anchor)."""

    instr_idx: np.ndarray  # (N,) int rows of instr_table
    instr_table: np.ndarray  # (I, D) float32 instruction embeddings
    instr_texts: list[str]  # (I,) the instructions themselves
    proprio: np.ndarray  # (N, 8) ee xyz, quat xyzw, gripper open
    name_idx: np.ndarray  # (N, K) int rows of name_table, -1 for padding
    name_table: np.ndarray  # (M, D) anchor description embeddings
    name_texts: list[str]  # (M,)
    pos: np.ndarray  # (N, K, 3)
    yaw: np.ndarray  # (N, K)
    state: np.ndarray  # (N, K, S)
    target: np.ndarray  # (N, 8) keyframe: xyz, quat xyzw, gripper open
    goal_idx: np.ndarray  # (N,) int rows of goal_table: each sample's task goal
    goal_table: np.ndarray  # (G, D) float32 goal embeddings
    goal_texts: list[str]  # (G,) the goals themselves

    def __post_init__(self) -> None:
        n = len(self.instr_idx)
        for f in ("proprio", "name_idx", "pos", "yaw", "state", "target", "goal_idx"):
            if len(getattr(self, f)) != n:
                raise ValueError(f"KeyframeDataset.{f} has {len(getattr(self, f))} rows, expected {n}")
        if n and (self.instr_idx.max() >= len(self.instr_table) or self.instr_idx.min() < 0):
            raise ValueError("KeyframeDataset.instr_idx points outside instr_table")
        if n and (self.goal_idx.max() >= len(self.goal_table) or self.goal_idx.min() < 0):
            raise ValueError("KeyframeDataset.goal_idx points outside goal_table")
        if n and self.name_idx.max() >= len(self.name_table):
            raise ValueError("KeyframeDataset.name_idx points outside name_table")

    def __len__(self) -> int:
        return len(self.instr_idx)

    def fingerprint(self) -> str:
        """Content hash of every array and text list."""
        h = hashlib.sha256()
        for f in fields(self):
            v = getattr(self, f.name)
            h.update(f.name.encode())
            if isinstance(v, np.ndarray):
                h.update(str(v.dtype).encode() + str(v.shape).encode())
                h.update(np.ascontiguousarray(v).tobytes())
            else:
                h.update(json.dumps(v).encode())
        return h.hexdigest()


@dataclass(frozen=True)
class TrainConfig:
    """Optimisation settings."""

    epochs: int = 100
    min_steps: int = 1500  # small datasets run more epochs so the optimiser takes at least this many steps
    batch_size: int = 256
    lr: float = 2e-3
    weight_decay: float = 1e-4
    seed: int = 0
    threads: int = 1
    # Optional time budget: past it the schedule is compressed to finish in time. Off by default:
    # with it the trained policy (and every figure after it) depends on how loaded the machine was,
    # which its cache key cannot see. Stats record steps run vs planned.
    max_seconds: float | None = None
    sigma_start: float = 0.2  # metres; the mixture width anneals from here to NetConfig.pos_sigma
    anneal_fraction: float = 0.5  # share of the epochs spent annealing
    # Optional: once the width has annealed (anchors chosen), the orientation concentration rises
    # from NetConfig.rot_kappa to this over the rest of the schedule; None keeps it constant.
    kappa_end: float | None = None

    # each field's range (checked when built: the harness builds it while validating the config)
    OPTION_RULES: ClassVar = {
        "epochs": whole(1), "min_steps": whole(0), "batch_size": whole(1), "lr": number(0.0, exclusive_min=True),
        "weight_decay": number(0.0), "seed": whole(0), "threads": whole(1),
        "max_seconds": number(0.0, exclusive_min=True, allow_none=True),
        "sigma_start": number(0.0, exclusive_min=True), "anneal_fraction": number(0.0, 1.0),
        "kappa_end": number(0.0, exclusive_min=True, allow_none=True),
    }

    def __post_init__(self) -> None:
        check_fields(self, "policy train", self.OPTION_RULES)


def train_network(data: KeyframeDataset, net_cfg: NetConfig, train_cfg: TrainConfig,
                  progress: bool = False) -> tuple[KeyframeNet, dict]:
    """Fit a :class:`KeyframeNet` to ``data``; returns the model and a stats dict (``progress``: a bar)."""
    if len(data) == 0:
        raise ValueError("cannot train the keyframe policy on an empty dataset")
    torch.manual_seed(train_cfg.seed)
    prev_threads = torch.get_num_threads()
    torch.set_num_threads(max(1, train_cfg.threads))
    try:
        net = KeyframeNet(net_cfg)
        t = _tensors(data)
        opt = torch.optim.AdamW(net.parameters(), lr=train_cfg.lr, weight_decay=train_cfg.weight_decay)
        n = len(data)
        steps_per_epoch = max(1, (n + train_cfg.batch_size - 1) // train_cfg.batch_size)
        epochs = max(train_cfg.epochs, -(-train_cfg.min_steps // steps_per_epoch))
        total_steps = epochs * steps_per_epoch
        gen = torch.Generator().manual_seed(train_cfg.seed)
        start = time.perf_counter()
        history: list[float] = []
        stopped_early = False
        step = 0
        done = 0.0  # fraction of the schedule, from steps (or time, under max_seconds)
        for epoch in tqdm(range(epochs), desc="policy", unit="epoch", leave=False, file=sys.stderr,
                          disable=not progress, dynamic_ncols=True):
            perm = torch.randperm(n, generator=gen)
            total, seen = 0.0, 0
            for b in range(steps_per_epoch):
                # Progress is the larger of the step and the time fractions, so when max_seconds
                # binds the schedule (warm-up, cosine decay, sigma annealing) still completes.
                done = step / total_steps
                if train_cfg.max_seconds is not None:
                    done = max(done, (time.perf_counter() - start) / train_cfg.max_seconds)
                if done >= 1.0:
                    break
                for group in opt.param_groups:
                    group["lr"] = _lr(train_cfg.lr, done)
                frac = min(1.0, done / max(train_cfg.anneal_fraction, 1e-6))
                sigma = train_cfg.sigma_start * (net_cfg.pos_sigma / train_cfg.sigma_start) ** frac
                idx = perm[b * train_cfg.batch_size:(b + 1) * train_cfg.batch_size]
                pred = net.forward_indexed(*_inputs(t, idx))
                kappa = None
                if train_cfg.kappa_end is not None:
                    late = max(0.0, (done - train_cfg.anneal_fraction) / max(1.0 - train_cfg.anneal_fraction, 1e-6))
                    kappa = net_cfg.rot_kappa * (train_cfg.kappa_end / net_cfg.rot_kappa) ** min(1.0, late)
                loss = net.loss(pred, t["target"][idx, :3], t["target"][idx, 3:7], t["target"][idx, 7],
                                pos_sigma=sigma, rot_kappa=kappa)
                opt.zero_grad()
                loss.backward()
                torch.nn.utils.clip_grad_norm_(net.parameters(), 5.0)
                opt.step()
                step += 1
                total += float(loss.detach()) * len(idx)
                seen += len(idx)
            if seen:
                history.append(total / seen)
                log.debug("policy epoch %d/%d loss %.4f", epoch + 1, epochs, history[-1])
            if done >= 1.0 and step < total_steps:
                stopped_early = True
                log.warning("policy training compressed into max_seconds: %d of %d steps", step, total_steps)
                break
        net.eval()
        stats = {
            "samples": n,
            "epochs_run": len(history),
            "steps": step,
            "planned_steps": total_steps,
            "stopped_early": stopped_early,
            "loss_history": history,
            "train_seconds": time.perf_counter() - start,
        }
        stats.update(evaluate_network(net, data))
        return net, stats
    finally:
        torch.set_num_threads(prev_threads)


def _lr(base: float, progress: float, warmup: float = 0.05) -> float:
    """Linear warm-up then cosine decay to zero over ``progress`` in [0, 1]."""
    if progress < warmup:
        return base * (progress / warmup)
    return base * 0.5 * (1.0 + math.cos(math.pi * (progress - warmup) / (1.0 - warmup)))


def _tensors(data: KeyframeDataset) -> dict[str, torch.Tensor]:
    name_idx = torch.as_tensor(data.name_idx, dtype=torch.long)
    return {
        "instr_table": torch.as_tensor(data.instr_table, dtype=torch.float32),
        "instr_idx": torch.as_tensor(data.instr_idx, dtype=torch.long),
        "proprio": torch.as_tensor(data.proprio, dtype=torch.float32),
        "name_table": torch.as_tensor(data.name_table, dtype=torch.float32),
        "name_idx": name_idx,
        "pos": torch.as_tensor(data.pos, dtype=torch.float32),
        "yaw": torch.as_tensor(data.yaw, dtype=torch.float32),
        "state": torch.as_tensor(data.state, dtype=torch.float32),
        "target": torch.as_tensor(data.target, dtype=torch.float32),
        "goal_table": torch.as_tensor(data.goal_table, dtype=torch.float32),
        "goal_idx": torch.as_tensor(data.goal_idx, dtype=torch.long),
    }


def _inputs(t: dict[str, torch.Tensor], idx: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """Arguments of ``KeyframeNet.forward_indexed`` for the samples ``idx``."""
    name_idx = t["name_idx"][idx]
    return (t["instr_table"], t["instr_idx"][idx], t["name_table"], name_idx, t["proprio"][idx],
            t["pos"][idx], t["yaw"][idx], t["state"][idx], name_idx >= 0, t["goal_table"], t["goal_idx"][idx])


@torch.no_grad()
def evaluate_network(net: KeyframeNet, data: KeyframeDataset, batch: int = 4096) -> dict:
    """Mean position error (m), orientation error (deg) and gripper accuracy of the selected keyframes."""
    t = _tensors(data)
    pos_err, rot_err, grip_ok = [], [], []
    for s in range(0, len(data), batch):
        idx = torch.arange(s, min(s + batch, len(data)))
        sel = KeyframeNet.select(net.forward_indexed(*_inputs(t, idx)))
        tgt = t["target"][idx]
        pos_err.append((sel["position"] - tgt[:, :3]).norm(dim=-1))
        q = sel["quaternion"]
        if net.cfg.symmetric_gripper:
            q = gripper_equivalent(q, tgt[:, 3:7])
        dot = (q * tgt[:, 3:7]).sum(-1).abs().clamp(max=1.0)
        rot_err.append(torch.rad2deg(2 * torch.acos(dot)))
        grip_ok.append(((sel["gripper_open"] >= 0.5).float() == (tgt[:, 7] >= 0.5).float()).float())
    pe, re_, go = torch.cat(pos_err), torch.cat(rot_err), torch.cat(grip_ok)
    return {
        "pos_err_mean_m": float(pe.mean()),
        "pos_err_p90_m": float(pe.quantile(0.9)),
        "rot_err_mean_deg": float(re_.mean()),
        "gripper_acc": float(go.mean()),
    }


def save_checkpoint(path: Path, net: KeyframeNet, meta: dict) -> None:
    """Write ``{state_dict, net config, meta}`` atomically: tensors and plain containers only, so that
    :func:`load_checkpoint` reads it with ``weights_only=True``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_file(path) as fh:
        torch.save({"state_dict": net.state_dict(), "net_cfg": net.cfg.to_dict(), "meta": meta}, fh)


def load_checkpoint(path: Path) -> tuple[KeyframeNet, dict]:
    """Inverse of :func:`save_checkpoint`."""
    if not Path(path).is_file():
        raise FileNotFoundError(f"no policy checkpoint at {path}")
    try:
        # weights only: a checkpoint is tensors and plain containers, and loading must never run pickled code
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - re-raised in one line naming the file
        raise InputError(f"policy checkpoint {path} {unreadable_reason(Path(path), exc)}; "
                         "retrain the policy to write a checkpoint of weights only") from exc
    # A checkpoint from before the network read the goal says nothing of it: it reads the instruction only.
    net = KeyframeNet(NetConfig(**{"read_goal": False, **blob["net_cfg"]}))
    net.load_state_dict(blob["state_dict"])
    net.eval()
    return net, blob["meta"]
