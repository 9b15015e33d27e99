"""Policy checkpoints are read with ``weights_only=True``: a saved policy loads back exactly, and a
checkpoint holding pickled objects (an old or foreign file) is a one-line error naming it, never run."""

from __future__ import annotations

import os

import pytest
import torch

from policy.network import KeyframeNet, NetConfig
from policy.training import load_checkpoint, save_checkpoint
from rdd.errors import InputError


class Payload:
    """Unpickling this would create ``marker`` (it must never happen)."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def test_saved_policy_loads_back_exactly(tmp_path):
    torch.manual_seed(0)
    net = KeyframeNet(NetConfig(hidden=16))
    meta = {"stats": {"steps": 3, "loss_history": [0.5, 0.25], "stopped_early": False}, "instructions": ["a", "b"]}
    save_checkpoint(tmp_path / "p.pt", net, meta)
    again, got = load_checkpoint(tmp_path / "p.pt")
    assert got == meta and again.cfg == net.cfg
    a, b = net.state_dict(), again.state_dict()
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_pickled_objects_are_refused_in_one_line(tmp_path):
    path, marker = tmp_path / "old.pt", tmp_path / "ran"
    net = KeyframeNet(NetConfig(hidden=16))
    torch.save({"state_dict": net.state_dict(), "net_cfg": net.cfg.to_dict(), "meta": {"x": Payload(marker)}}, path)
    with pytest.raises(InputError) as info:
        load_checkpoint(path)
    text = str(info.value)
    assert str(path) in text and "refused" in text and "retrain" in text
    assert "\n" not in text and "weights_only=False" not in text
    assert not marker.exists()
