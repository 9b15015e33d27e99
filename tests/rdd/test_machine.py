"""rdd.machine.cpu_model: the one reader of the CPU's model name (runs' results, benchmarks' headers)."""

from __future__ import annotations

import platform
from pathlib import Path

import pytest

from rdd import machine


def test_cpu_model_is_a_non_empty_name():
    model = machine.cpu_model()
    assert isinstance(model, str) and model and model == model.strip()


def test_cpu_model_reads_the_model_name_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nvendor_id\t: GenuineIntel\nmodel name\t: Test CPU @ 2.00GHz \nflags\t: fpu\n"
                    "processor\t: 1\nmodel name\t: Other CPU\n")
    monkeypatch.setattr(machine, "CPUINFO", info)
    assert machine.cpu_model() == "Test CPU @ 2.00GHz"


@pytest.mark.parametrize("content", ["processor\t: 0\nCPU implementer\t: 0x41\n", None])
def test_cpu_model_falls_back_to_platform(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, content: str | None):
    info = tmp_path / "cpuinfo"  # no "model name" line (as on ARM), or no file at all (not Linux)
    if content is not None:
        info.write_text(content)
    monkeypatch.setattr(machine, "CPUINFO", info)
    monkeypatch.setattr(platform, "processor", lambda: "")
    monkeypatch.setattr(platform, "machine", lambda: "aarch64")
    assert machine.cpu_model() == "aarch64"
    monkeypatch.setattr(platform, "processor", lambda: "arm")
    assert machine.cpu_model() == "arm"
