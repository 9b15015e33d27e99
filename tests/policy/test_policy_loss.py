"""The keyframe network's mixture likelihood, against values worked out by hand."""

import math

import pytest
import torch

from policy.network import KeyframeNet, NetConfig
from policy.training import TrainConfig


def _pred(angle: float) -> dict[str, torch.Tensor]:
    # One anchor (log-weight 0), position on target, orientation turned by `angle` about z.
    return {"log_weights": torch.zeros(1, 1), "position": torch.zeros(1, 1, 3),
            "quaternion": torch.tensor([[[0.0, 0.0, math.sin(angle / 2), math.cos(angle / 2)]]]),
            "gripper_logit": torch.zeros(1)}


def test_orientation_term_scales_with_the_concentration_given():
    net = KeyframeNet(NetConfig(rot_kappa=20.0))
    target = (torch.zeros(1, 3), torch.tensor([[0.0, 0.0, 0.0, 1.0]]), torch.ones(1))
    angle = math.radians(30)
    base = net.loss(_pred(angle), *target)
    # -log N(0; 0, sigma) terms and the gripper term are the same; the orientation term is
    # kappa * sin^2(angle / 2) (cos^2 of the half angle is the squared quaternion product).
    assert float(net.loss(_pred(angle), *target, rot_kappa=100.0) - base) == pytest.approx(
        80.0 * math.sin(angle / 2) ** 2, rel=1e-5)
    assert float(net.loss(_pred(0.0), *target, rot_kappa=100.0)) == pytest.approx(
        float(net.loss(_pred(0.0), *target)), rel=1e-6)


def test_kappa_end_must_be_positive():
    with pytest.raises(ValueError, match="kappa_end"):
        TrainConfig(kappa_end=0.0)
    assert TrainConfig(kappa_end=100.0).kappa_end == 100.0
