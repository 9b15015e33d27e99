"""Object-centric keyframe network: the instruction picks an anchor object, the net adds an offset.

Every scene object (plus two pseudo-anchors: the gripper itself and the world origin) is an
*anchor*. For each anchor the network predicts a keyframe expressed in that anchor's yaw frame
(position offset, orientation, gripper state) and a score saying how well the instruction matches
the anchor. Training maximises the likelihood of the expert keyframe under the resulting mixture;
inference returns the best-scoring anchor's keyframe. Predicting *relative to objects* is what lets
one network serve unseen object placements, and the score's dependence on the instruction
embedding (compared with each object's own description embedding) is what makes the policy follow
language rather than memorise a task.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import ClassVar

import torch
from torch import nn
from torch.nn import functional as F

from rdd.checks import FLAG, check_fields, number, whole


@dataclass(frozen=True)
class NetConfig:
    """Sizes of the keyframe network."""

    text_dim: int = 384
    proprio_dim: int = 8  # ee xyz + quat xyzw + gripper
    state_dim: int = 9  # per-anchor extra state (policy.features.STATE_DIM)
    hidden: int = 96
    pos_sigma: float = 0.005  # metres; width of the mixture's position likelihood
    rot_kappa: float = 20.0  # concentration of the orientation likelihood
    gripper_weight: float = 2.0
    match_scale: float = 20.0  # initial gain of the instruction-name cosine similarity
    # Treat the two finger directions (a half turn about the approach axis) as one target. Off by
    # default: the expert picks between them by reachability, which the net learns from the scene,
    # and choosing the other one often runs the arm into joint limits or the cabinet.
    symmetric_gripper: bool = False
    # Read the task goal L beside the sub-task instruction, as the paper's policy pi(a | s, o, l, L)
    # does (RACER's actor reads both): the goal can tell what a loose instruction leaves open.
    read_goal: bool = True
    # each field's range (checked when built: the harness builds it while validating the config)
    OPTION_RULES: ClassVar = {
        "text_dim": whole(1), "proprio_dim": whole(1), "state_dim": whole(1), "hidden": whole(1),
        "pos_sigma": number(0.0, exclusive_min=True), "rot_kappa": number(0.0, exclusive_min=True),
        "gripper_weight": number(0.0), "match_scale": number(0.0, exclusive_min=True), "symmetric_gripper": FLAG,
        "read_goal": FLAG,
    }

    def __post_init__(self) -> None:
        check_fields(self, "policy net", self.OPTION_RULES)

    def to_dict(self) -> dict:
        """Plain dict (for checkpoints and cache keys)."""
        return asdict(self)


HALF_TURN_Z = torch.tensor([0.0, 0.0, 1.0, 0.0])  # xyzw: rotation by pi about the local z axis


def gripper_equivalent(q: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
    """Of ``q`` and ``q`` turned by pi about the approach axis, the one nearer ``reference``."""
    alt = quat_multiply(q, HALF_TURN_Z.to(q))
    keep = (q * reference).sum(-1).abs() >= (alt * reference).sum(-1).abs()
    return torch.where(keep[..., None], q, alt)


def yaw_quaternion(yaw: torch.Tensor) -> torch.Tensor:
    """Quaternions xyzw of rotations by ``yaw`` about +z."""
    half = 0.5 * yaw
    zero = torch.zeros_like(yaw)
    return torch.stack([zero, zero, torch.sin(half), torch.cos(half)], dim=-1)


def quat_multiply(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product of xyzw quaternions (broadcasting)."""
    ax, ay, az, aw = a.unbind(-1)
    bx, by, bz, bw = b.unbind(-1)
    return torch.stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        dim=-1,
    )


def rotate_by_yaw(vec: torch.Tensor, yaw: torch.Tensor) -> torch.Tensor:
    """Rotate (..., 3) vectors about +z by ``yaw`` (...)."""
    c, s = torch.cos(yaw), torch.sin(yaw)
    x, y, z = vec.unbind(-1)
    return torch.stack([c * x - s * y, s * x + c * y, z], dim=-1)


class KeyframeNet(nn.Module):
    """Scores anchors against the instruction and predicts a keyframe relative to each anchor."""

    def __init__(self, cfg: NetConfig) -> None:
        super().__init__()
        if cfg.proprio_dim != 8:
            raise ValueError(f"NetConfig.proprio_dim must be 8 (ee xyz, quat xyzw, gripper), got {cfg.proprio_dim}")
        self.cfg = cfg
        h = cfg.hidden
        self.text = nn.Sequential(nn.Linear(cfg.text_dim, h), nn.GELU(), nn.Linear(h, h))
        self.name = nn.Sequential(nn.Linear(cfg.text_dim, h), nn.GELU(), nn.Linear(h, h))
        # Geometry of an anchor as seen from the hand, in the anchor's yaw frame, plus its state.
        geo_dim = 3 + 3 + 2 + cfg.state_dim + 4 + 1 + 3
        self.geo = nn.Sequential(nn.Linear(geo_dim, h), nn.GELU(), nn.Linear(h, h))
        self.trunk = nn.Sequential(nn.Linear(4 * h, 2 * h), nn.GELU(), nn.Linear(2 * h, h), nn.GELU())
        self.score = nn.Linear(h, 1)
        # Bilinear instruction-name match, initialised to a sharp cosine similarity: MiniLM already
        # places "grasp the red block" nearer "red block" than "blue block", but the gap is small,
        # and an MLP on concatenated features is slow to find it on its own.
        self.match = nn.Linear(cfg.text_dim, cfg.text_dim, bias=False)
        with torch.no_grad():
            self.match.weight.copy_(torch.eye(cfg.text_dim) * cfg.match_scale)
        if cfg.read_goal:
            # The goal joins the instruction's features and its match with the anchors. The match
            # starts as the instruction's (a sharp cosine similarity): a goal names the objects that
            # matter, and decides where the instruction leaves a choice (starting it at zero, the
            # net learned layouts instead). The features start at zero and add what training finds.
            self.goal = nn.Sequential(nn.Linear(cfg.text_dim, h), nn.GELU(), nn.Linear(h, h))
            self.goal_match = nn.Linear(cfg.text_dim, cfg.text_dim, bias=False)
            with torch.no_grad():
                self.goal[-1].weight.zero_()
                self.goal[-1].bias.zero_()
                self.goal_match.weight.copy_(torch.eye(cfg.text_dim) * cfg.match_scale)
        self.head = nn.Sequential(nn.Linear(h, h), nn.GELU(), nn.Linear(h, 3 + 4))
        self.gripper = nn.Sequential(nn.Linear(2 * h + cfg.proprio_dim, h), nn.GELU(), nn.Linear(h, 1))

    def forward(
        self,
        instr: torch.Tensor,  # (B, D) instruction embedding
        proprio: torch.Tensor,  # (B, 8)
        names: torch.Tensor,  # (B, K, D) anchor description embeddings
        pos: torch.Tensor,  # (B, K, 3) anchor positions (world)
        yaw: torch.Tensor,  # (B, K) anchor yaw
        state: torch.Tensor,  # (B, K, S)
        mask: torch.Tensor,  # (B, K) bool, True where the anchor exists
        goal: torch.Tensor | None = None,  # (B, D) task goal embedding (read_goal)
    ) -> dict[str, torch.Tensor]:
        """Per-anchor log-weights (B, K), positions (B, K, 3), quaternions (B, K, 4); gripper logit (B,)."""
        rows = torch.arange(instr.shape[0])
        return self.forward_indexed(instr, rows, names.reshape(-1, names.shape[-1]),
                                    torch.arange(names.shape[0] * names.shape[1]).reshape(names.shape[:2]),
                                    proprio, pos, yaw, state, mask, goal, None if goal is None else rows)

    def forward_indexed(
        self,
        instr_table: torch.Tensor,  # (I, D) distinct instruction embeddings
        instr_idx: torch.Tensor,  # (B,) rows of instr_table
        name_table: torch.Tensor,  # (M, D) distinct anchor description embeddings
        name_idx: torch.Tensor,  # (B, K) rows of name_table (any value where mask is False)
        proprio: torch.Tensor,
        pos: torch.Tensor,
        yaw: torch.Tensor,
        state: torch.Tensor,
        mask: torch.Tensor,
        goal_table: torch.Tensor | None = None,  # (G, D) distinct goal embeddings
        goal_idx: torch.Tensor | None = None,  # (B,) rows of goal_table
    ) -> dict[str, torch.Tensor]:
        """:meth:`forward` with text embeddings given once per distinct text (the training path:
        the 384-d projections run on the few distinct texts, not on every anchor of every sample)."""
        if self.cfg.read_goal and (goal_table is None or goal_idx is None):
            raise ValueError("this keyframe network reads the task goal (NetConfig.read_goal): pass goal_table and goal_idx")
        k = name_idx.shape[1]
        ee = proprio[:, None, :3]
        rel_local = rotate_by_yaw(ee - pos, -yaw)  # hand relative to the anchor, in its yaw frame
        ee_local = quat_multiply(yaw_quaternion(-yaw), proprio[:, None, 3:7].expand(-1, k, -1))
        geo_in = torch.cat(
            [
                rel_local,
                pos,
                torch.stack([torch.sin(yaw), torch.cos(yaw)], -1),
                state,
                ee_local,
                proprio[:, None, 7:8].expand(-1, k, -1),
                ee.expand(-1, k, -1),
            ],
            dim=-1,
        )
        t_all = self.text(instr_table)
        t1 = t_all[instr_idx]
        if self.cfg.read_goal:
            t1 = t1 + self.goal(goal_table)[goal_idx]
        t = t1[:, None, :].expand(-1, k, -1)
        safe_idx = name_idx.clamp(min=0)
        n = self.name(name_table)[safe_idx]
        g = self.geo(geo_in)
        feats = self.trunk(torch.cat([t * n, t, n, g], dim=-1))
        query = self.match(instr_table)[instr_idx]
        if self.cfg.read_goal:
            query = query + self.goal_match(goal_table)[goal_idx]
        match = (query[:, None, :] * name_table[safe_idx]).sum(-1)
        logits = (self.score(feats).squeeze(-1) + match).masked_fill(~mask, float("-inf"))
        log_w = torch.log_softmax(logits, dim=-1)
        out = self.head(feats)
        offset_local = out[..., :3]
        q_local = F.normalize(out[..., 3:7] + torch.tensor([0.0, 0.0, 0.0, 1e-3]), dim=-1)
        # The gripper command depends on the instruction and on the hand, not on which anchor
        # carries the position, so it is one head over the instruction and the attended anchors.
        pooled = (log_w.exp().masked_fill(~mask, 0.0)[..., None] * feats).sum(1)
        grip = self.gripper(torch.cat([t1, pooled, proprio], dim=-1)).squeeze(-1)
        return {
            "log_weights": log_w,
            "position": pos + rotate_by_yaw(offset_local, yaw),
            "quaternion": quat_multiply(yaw_quaternion(yaw), q_local),
            "gripper_logit": grip,
        }

    def loss(self, pred: dict[str, torch.Tensor], target_pos: torch.Tensor,
             target_quat: torch.Tensor, target_open: torch.Tensor,
             pos_sigma: float | None = None, rot_kappa: float | None = None) -> torch.Tensor:
        """Negative log-likelihood of the expert keyframe under the anchor mixture (mean over batch).

        ``pos_sigma`` overrides the configured width (training anneals it from wide to narrow so
        that early on every anchor gets gradient, not only the one that happens to start closest);
        ``rot_kappa`` the orientation concentration (optionally raised late in training).
        """
        c = self.cfg
        sigma = c.pos_sigma if pos_sigma is None else pos_sigma
        kappa = c.rot_kappa if rot_kappa is None else rot_kappa
        d2 = ((pred["position"] - target_pos[:, None, :]) ** 2).sum(-1)
        # Sign-invariant; optionally also invariant to the parallel gripper's half turn about its
        # approach axis (the two finger directions grasp alike).
        cos2 = (pred["quaternion"] * target_quat[:, None, :]).sum(-1) ** 2
        if c.symmetric_gripper:
            flipped = quat_multiply(target_quat, HALF_TURN_Z.to(target_quat))
            cos2 = torch.maximum(cos2, (pred["quaternion"] * flipped[:, None, :]).sum(-1) ** 2)
        comp = -d2 / (2 * sigma**2) + kappa * (cos2 - 1.0)
        nll = -(torch.logsumexp(pred["log_weights"] + comp, dim=-1)).mean()
        grip = F.binary_cross_entropy_with_logits(pred["gripper_logit"], target_open)
        return nll + c.gripper_weight * grip

    @staticmethod
    def select(pred: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """The best-scoring anchor's keyframe per batch row."""
        idx = pred["log_weights"].argmax(-1)
        rows = torch.arange(idx.shape[0])
        return {
            "position": pred["position"][rows, idx],
            "quaternion": pred["quaternion"][rows, idx],
            "gripper_open": torch.sigmoid(pred["gripper_logit"]),
            "anchor": idx,
        }
