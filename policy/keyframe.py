"""The default low-level policy: keyframe behaviour cloning on labelled expert sub-tasks.

Training data: every expert segment of every training episode, labelled by the sub-task labeler;
for each (sub-sampled) frame of a segment the target is that segment's keyframe (end-effector
pose and gripper state at frame ``end - 1``). ``train_policy`` trains and saves into the output
folder it is given (the pipeline's stage cache decides when training is needed).
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch

from policy.features import STATE_DIM, Anchors, anchors_from_observation, observation_at
from policy.interface import KeyframeAction, Policy
from policy.network import KeyframeNet, NetConfig, gripper_equivalent
from policy.text import InstructionEmbedder, shared_embedder
from policy.training import (
    KeyframeDataset,
    TrainConfig,
    load_checkpoint,
    save_checkpoint,
    train_network,
)
from rdd.atomic import write_json_atomic
from rdd.checks import FLAG, check_fields, whole
from rdd.data.episode import Episode
from rdd.labelers.base import Labeler

log = logging.getLogger(__name__)


@dataclass
class DatasetConfig:
    """Which frames of each expert segment become training samples."""

    frames_per_segment: int = 8  # evenly spaced, always including the segment's first frame
    skip_failed: bool = True  # drop episodes whose expert did not succeed
    OPTION_RULES: ClassVar = {"frames_per_segment": whole(1), "skip_failed": FLAG}

    def __post_init__(self) -> None:
        check_fields(self, "policy data", self.OPTION_RULES)


def _materialise(episode: Episode) -> Episode:
    """Load the privileged arrays once (readers may hand out lazy npz views)."""
    priv = episode.meta.get("privileged")
    if priv is not None and not isinstance(priv, dict):
        episode.meta["privileged"] = {k: np.asarray(priv[k]) for k in priv}
    return episode


def build_dataset(episodes: Iterable[Episode], labeler: Labeler, embedder: InstructionEmbedder,
                  cfg: DatasetConfig | None = None) -> KeyframeDataset:
    """Samples (observation, labelled instruction, task goal) -> keyframe from expert-segmented episodes."""
    cfg = cfg or DatasetConfig()
    rows: list[tuple[str, Anchors, np.ndarray, str]] = []
    for ep in episodes:
        if cfg.skip_failed and ep.meta.get("success") is False:
            continue
        if not ep.segments:
            raise ValueError(f"episode {ep.name!r} has no expert segments to train the policy on")
        ep = _materialise(ep)
        for seg in ep.segments:
            start, end = int(seg[0]), int(seg[1])
            instr = labeler.label(ep, (start, end))
            key = end - 1
            target = np.concatenate([ep.ee_poses[key, :7], [1.0 if ep.gripper_open[key] >= 0.5 else 0.0]])
            n = min(cfg.frames_per_segment, end - start)
            for t in np.unique(np.linspace(start, end - 1, n).round().astype(int)):
                rows.append((instr, anchors_from_observation(observation_at(ep, int(t))), target, ep.goal))
    if not rows:
        raise ValueError("no training samples: every episode was empty or failed")
    instr_texts = sorted({r[0] for r in rows})
    name_texts = sorted({n for r in rows for n in r[1].names})
    i_of = {t: i for i, t in enumerate(instr_texts)}
    n_of = {t: i for i, t in enumerate(name_texts)}
    kmax = max(len(r[1].names) for r in rows)
    n = len(rows)
    name_idx = -np.ones((n, kmax), dtype=np.int64)
    pos = np.zeros((n, kmax, 3), dtype=np.float32)
    yaw = np.zeros((n, kmax), dtype=np.float32)
    state = np.zeros((n, kmax, STATE_DIM), dtype=np.float32)
    goal_texts = sorted({r[3] for r in rows})
    g_of = {t: i for i, t in enumerate(goal_texts)}
    for r, (_, a, _, _) in enumerate(rows):
        k = len(a.names)
        name_idx[r, :k] = [n_of[x] for x in a.names]
        pos[r, :k], yaw[r, :k], state[r, :k] = a.pos, a.yaw, a.state
    return KeyframeDataset(
        instr_idx=np.array([i_of[r[0]] for r in rows], dtype=np.int64),
        instr_table=embedder.embed(instr_texts),
        instr_texts=instr_texts,
        proprio=np.stack([r[1].proprio for r in rows]).astype(np.float32),
        name_idx=name_idx,
        name_table=embedder.embed(name_texts),
        name_texts=name_texts,
        pos=pos, yaw=yaw, state=state,
        target=np.stack([r[2] for r in rows]).astype(np.float32),
        goal_idx=np.array([g_of[r[3]] for r in rows], dtype=np.int64),
        goal_table=embedder.embed(goal_texts),
        goal_texts=goal_texts,
    )


@dataclass
class PolicyTrainConfig:
    """Everything that determines a trained keyframe policy."""

    net: NetConfig = field(default_factory=NetConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    data: DatasetConfig = field(default_factory=DatasetConfig)


CHECKPOINT_FILE = "keyframe_policy.pt"


def train_policy(episodes: Sequence[Episode], labeler: Labeler, out_dir: str | os.PathLike, *,
                 net: NetConfig | None = None, train: TrainConfig | None = None,
                 data: DatasetConfig | None = None,
                 embedder: InstructionEmbedder | None = None,
                 progress: bool = False) -> KeyframeBCPolicy:
    """Train on ``episodes`` and save the network (``keyframe_policy.pt`` + ``.json``) into ``out_dir``.

    The factory ``conf/policy/keyframe_bc.yaml`` names: its options are ``net``, ``train`` and
    ``data``; the episodes, labeler, folder and instruction embedder come from the caller.
    """
    cfg = PolicyTrainConfig(net=net or NetConfig(), train=train or TrainConfig(),
                            data=data or DatasetConfig())
    out_dir = Path(out_dir)
    embedder = embedder or shared_embedder(None)
    data = build_dataset(episodes, labeler, embedder, cfg.data)
    net, stats = train_network(data, cfg.net, cfg.train, progress=progress)
    meta = {"stats": stats, "config": _jsonable(asdict(cfg)), "instructions": data.instr_texts,
            "anchor_names": data.name_texts}
    path = out_dir / CHECKPOINT_FILE
    save_checkpoint(path, net, meta)
    write_json_atomic(path.with_suffix(".json"), meta)
    log.info("trained keyframe policy in %.1f s", stats["train_seconds"])
    return KeyframeBCPolicy(net, embedder, meta=meta, checkpoint=path)


class KeyframeBCPolicy(Policy):
    """Keyframe BC policy: object anchors scored against the instruction and the task goal, keyframe
    relative to one."""

    def __init__(self, net: KeyframeNet, embedder: InstructionEmbedder, meta: Mapping[str, Any] | None = None,
                 checkpoint: Path | None = None) -> None:
        self.net = net.eval()
        self.embedder = embedder
        self.meta = dict(meta or {})
        self.checkpoint = checkpoint
        self.goal = ""
        self.last_anchor: str | None = None

    @classmethod
    def from_checkpoint(cls, path: str | os.PathLike, text_cache_dir: str | os.PathLike | None = None) -> KeyframeBCPolicy:
        """Load a policy saved by :func:`train_policy`."""
        net, meta = load_checkpoint(Path(path))
        if net.cfg.state_dim != STATE_DIM:
            raise ValueError(f"{path}: policy trained on {net.cfg.state_dim} per-anchor state features, "
                             f"this code makes {STATE_DIM} (policy.features.STATE_DIM); retrain it")
        return cls(net, shared_embedder(text_cache_dir), meta=meta, checkpoint=Path(path))

    def reset(self, goal: str) -> None:
        """Start an episode whose task goal is ``goal`` (the network reads it beside each instruction)."""
        self.goal = str(goal)
        self.last_anchor = None

    @torch.no_grad()
    def act(self, observation: Mapping[str, Any], instruction: str) -> KeyframeAction:
        """Next keyframe for ``instruction``; any text (even unfamiliar) yields a valid action."""
        a = anchors_from_observation(observation)
        emb = self.embedder.embed([str(instruction), self.goal or " "] + a.names)
        pred = self.net(
            torch.as_tensor(emb[:1]),
            torch.as_tensor(a.proprio[None], dtype=torch.float32),
            torch.as_tensor(emb[None, 2:]),
            torch.as_tensor(a.pos[None], dtype=torch.float32),
            torch.as_tensor(a.yaw[None], dtype=torch.float32),
            torch.as_tensor(a.state[None], dtype=torch.float32),
            torch.ones(1, len(a.names), dtype=torch.bool),
            goal=torch.as_tensor(emb[1:2]) if self.net.cfg.read_goal else None,
        )
        sel = KeyframeNet.select(pred)
        self.last_anchor = a.names[int(sel["anchor"][0])]
        quat = sel["quaternion"]
        if self.net.cfg.symmetric_gripper:
            # Trained without preference between the two equivalent finger directions: take the
            # one nearer the hand's current orientation (no needless spin).
            quat = gripper_equivalent(quat, torch.as_tensor(a.proprio[None, 3:7], dtype=torch.float32))
        return KeyframeAction(
            position=sel["position"][0].numpy(),
            quaternion=quat[0].numpy(),
            gripper_open=bool(sel["gripper_open"][0] >= 0.5),
        )


def _jsonable(obj: Any) -> Any:
    return json.loads(json.dumps(obj, default=str))

