"""A bad encoder checkpoint is an InputError in one line (issue 39): it names the file, the encoder
that wanted it, what is wrong and where the official file comes from, and never repeats torch's
advice to load with weights_only=False."""

from __future__ import annotations

import os
import pickle
import warnings
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from rdd.cli import main  # noqa: E402
from rdd.encoders import load_encoder  # noqa: E402
from rdd.errors import InputError  # noqa: E402

R3M_SOURCE = "facebookresearch/r3m"


class Payload:
    """Pickles as a call of ``os.system`` (it must never run)."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def error_for(path: Path) -> str:
    with pytest.raises(InputError) as info:
        load_encoder("r3m", checkpoint=str(path))
    text = str(info.value)
    assert "\n" not in text and "weights_only" not in text
    assert str(path) in text and "encoder 'r3m'" in text and "'model.pt'" in text and R3M_SOURCE in text
    return text


def test_garbage_file(tmp_path):
    path = tmp_path / "model.pt"
    path.write_bytes(b"hello, this is not a checkpoint\n" * 10)
    assert "not a readable checkpoint" in error_for(path)


def test_truncated_file(tmp_path):
    path = tmp_path / "model.pt"
    torch.save({"r3m": {"w": torch.zeros(64)}}, path)
    path.write_bytes(path.read_bytes()[:200])
    assert "truncated, corrupt" in error_for(path)


def test_empty_file(tmp_path):
    path = tmp_path / "model.pt"
    path.write_bytes(b"")
    assert "is empty" in error_for(path)


def test_git_lfs_pointer(tmp_path):
    path = tmp_path / "model.pt"
    path.write_text("version https://git-lfs.github.com/spec/v1\noid sha256:0123\nsize 98765\n")
    assert "Git LFS pointer" in error_for(path)


def test_pickled_code_is_refused_and_never_runs(tmp_path):
    path, marker = tmp_path / "model.pt", tmp_path / "ran"
    torch.save({"r3m": Payload(marker)}, path)
    text = error_for(path)
    assert "system" in text and "refused" in text
    assert not marker.exists()


def test_whole_pickled_model_is_refused(tmp_path):
    path = tmp_path / "model.pt"
    torch.save(torch.nn.Linear(2, 2), path)
    assert "torch.nn.modules.linear.Linear" in error_for(path)


def test_plain_pickle_gives_no_torch_warning(tmp_path):
    path = tmp_path / "model.pt"
    path.write_bytes(pickle.dumps([1, 2, 3], protocol=4))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        error_for(path)


def test_cli_prints_one_line(tmp_path, capsys):
    from rdd.data.episode import Episode
    from rdd.data.native import save_episode

    rng = np.random.default_rng(0)
    views = {v: rng.integers(0, 255, (6, 8, 8, 3), dtype=np.uint8) for v in ("front", "wrist")}
    save_episode(Episode("ep0", views, segments=[(0, 3), (3, 6)], instructions=["a", "b"]), tmp_path / "ep0")
    ckpt = tmp_path / "model.pt"
    ckpt.write_bytes(b"\x00garbage")
    code = main(["build-db", "--format", "native", "--data", str(tmp_path / "ep0"), "--encoder", "r3m",
                 "--encoder-option", f"checkpoint={ckpt}", "--no-cache", "--out", str(tmp_path / "db")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and str(ckpt) in err[0] and "weights_only" not in err[0]
    assert not (tmp_path / "db").exists()
